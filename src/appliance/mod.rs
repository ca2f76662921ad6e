//! The appliance (`lfi-bridge run`): cameras, knowledge bases, the PLC's Modbus server and the
//! robot links, wired together. The imperative shell around [`crate::vision`] and
//! [`crate::handshake`].

pub mod archive;
pub mod camera;
pub mod changes;
pub mod enrol;
pub mod error;
pub mod genicam;
pub mod history;
pub mod job;
pub mod priority;
pub mod source;

use std::net::SocketAddr;
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tokio::net::TcpListener;
use tokio::sync::mpsc::UnboundedReceiver;
use tokio_util::sync::CancellationToken;

use crate::config::{CameraConfig, Config, KbSource, RobotConfig, SourceConfig};
use crate::handshake::{Handshake, Queued, Settings};
use crate::modbus::server::{self, Station, Stations, Stats};
use crate::registers::RobotView;
use crate::sim::Simulator;
use crate::vision::Params;
pub use camera::Live;
use camera::Worker;
pub use changes::{Changes, bump};
use enrol::{EnrolError, EnrolRequest, Enrolled};
pub use error::StartError;
pub use job::{InForce, Loaded, load_job};
pub use priority::{VIEW_NICE, lower_priority};
use source::{DirSource, SimSource, Source, VideoSource};

/// A camera of the running appliance, for the operator view and tests.
pub struct CameraHandle {
    /// The Modbus unit id of its register map.
    pub unit_id: u8,
    /// For the log and the page.
    pub name: String,
    /// The PLC handshake (the state machine behind the registers).
    pub handshake: Arc<Mutex<Handshake>>,
    /// What the operator view shows.
    pub live: Arc<Mutex<Live>>,
    /// The job in force (its templates, estimator, calibration), as the worker last put it.
    job: camera::SharedJob,
    /// The robot link's state, if one is configured.
    pub robot: Option<Arc<Mutex<crate::registers::RobotView>>>,
    /// The image archive (its counters, and where to read it back), if one is configured.
    pub archive: Option<archive::Shelf>,
    /// The last acquisitions in memory, for the operator view's history (None: `[http]
    /// history_frames = 0` or no operator view).
    pub history: Option<history::Shelf>,
    /// Bumped whenever something the operator view shows changes.
    pub changes: Changes,
    /// When the appliance started (the handshake's clock).
    pub started: Instant,
    /// A GenICam camera's model, format and frame counters.
    pub genicam: Option<Arc<genicam::GenicamStats>>,
    /// The configured jobs (id, name), for the operator view.
    pub jobs: Vec<(u16, String)>,
    /// Every completed acquisition, as the PLC got it (subscribe for OPC UA's events).
    pub published: camera::Published,
    /// Into the camera's worker, as the Modbus server sends (job changes from the page).
    commands: std::sync::mpsc::Sender<crate::handshake::Command>,
    /// Into the camera's worker: enrolments.
    orders: std::sync::mpsc::Sender<camera::Order>,
    thread: Mutex<Option<std::thread::JoinHandle<()>>>,
}

/// The running appliance.
pub struct Running {
    /// Where the PLC's server listens (the port chosen when the configuration asked for 0).
    pub modbus_addr: SocketAddr,
    /// The operator view's address, once [`crate::http::attach`] has started it.
    pub http_addr: Option<SocketAddr>,
    /// The OPC UA endpoint, once [`crate::opcua::attach`] has started it.
    pub opcua_url: Option<String>,
    /// Every camera, in configuration order.
    pub cameras: Arc<Vec<CameraHandle>>,
    /// The Modbus unit ids the server answers, and their handshakes.
    pub stations: Arc<Stations>,
    /// Counters of the Modbus server.
    pub stats: Arc<Stats>,
    /// When the appliance started (HEARTBEAT, uptime on the page).
    pub started: Instant,
    /// Cancelled to stop every task.
    pub shutdown: CancellationToken,
    stop: Arc<AtomicBool>,
    tasks: Vec<tokio::task::JoinHandle<()>>,
}

/// A camera's source, and a GenICam camera's counters for the page and `/metrics`.
type SourceWithStats = (Box<dyn Source>, Option<Arc<genicam::GenicamStats>>);

/// The camera's source (see [`SourceWithStats`]).
fn source_for(cam: &CameraConfig) -> Result<SourceWithStats, StartError> {
    if let SourceConfig::Genicam(settings) = &cam.source {
        let src = genicam::GenicamSource::new(&cam.name, settings.clone());
        let stats = src.stats();
        return Ok((Box::new(src), Some(stats)));
    }
    let source: Box<dyn Source> = match &cam.source {
        SourceConfig::Sim { seed, width, height, noise, scenes, interval, cell } => {
            let sim = Simulator::new(SimSource::config(*seed, *width, *height, *noise))
                .map_err(|e| StartError::Sim { camera: cam.name.clone(), message: e.to_string() })?;
            let sim = if *cell { sim.through_cell_camera() } else { sim };
            let through = if *cell { " through the cell's camera (tilt, lens distortion)" } else { "" };
            tracing::info!(camera = %cam.name, "rendering {scenes} simulated scenes of {width} x {height}{through}");
            Box::new(
                SimSource::new(&sim, *scenes, *interval)
                    .map_err(|e| StartError::Sim { camera: cam.name.clone(), message: e.to_string() })?,
            )
        }
        SourceConfig::Dir { path, settle, timeout } => {
            if !path.is_dir() {
                tracing::warn!(camera = %cam.name, "folder {} does not exist (yet): CAMERA_OK stays 0 until it does", path.display());
            }
            Box::new(DirSource::new(path, *settle, *timeout))
        }
        SourceConfig::Video { uri, timeout } => Box::new(VideoSource::new(uri, *timeout)),
        SourceConfig::Genicam(_) => unreachable!("handled above"),
    };
    Ok((source, None))
}

/// A random, non-zero BOOT_ID for this start.
fn draw_boot_id() -> u16 {
    rand::random_range(1..=u16::MAX)
}

/// What every camera of one start shares.
struct Common {
    started: Instant,
    boot_id: u16,
    stop: Arc<AtomicBool>,
    params: Params,
    changes: Changes,
    history_frames: usize,
    queue_depth: usize,
}

/// A camera's robot link, to be run once the runtime's tasks start: (camera name, its
/// configuration, the parts the worker sends, the link's state for the registers).
type RobotLink = (String, RobotConfig, UnboundedReceiver<Queued>, Arc<Mutex<RobotView>>);

/// One camera wired up, its worker running: its handle, the Modbus server's station for it, and
/// its robot link (if configured).
struct Wired {
    handle: CameraHandle,
    station: Station,
    robot_link: Option<RobotLink>,
}

/// Starts everything; returns once the Modbus server listens.
pub async fn start(cfg: &Config) -> Result<Running, StartError> {
    let started = Instant::now();
    let boot_id = draw_boot_id();
    tracing::info!("BOOT_ID {boot_id}");
    let common = Common {
        started,
        boot_id,
        stop: Arc::new(AtomicBool::new(false)),
        params: Params { accept_threshold: cfg.accept_threshold, ..Params::default() },
        changes: Arc::new(tokio::sync::watch::channel(0).0),
        history_frames: cfg.http.as_ref().map_or(0, |h| h.history_frames),
        queue_depth: cfg.queue_depth,
    };
    let (mut cameras, mut stations, mut robot_links) = (Vec::new(), Vec::new(), Vec::new());
    for cam in &cfg.cameras {
        let wired = wire(cam, &common)?;
        cameras.push(wired.handle);
        stations.push(wired.station);
        robot_links.extend(wired.robot_link);
    }
    let stations = Arc::new(Stations::new(stations, started));
    let shutdown = CancellationToken::new();
    let (modbus_addr, stats, server) = serve_modbus(cfg, &stations, &shutdown, cameras.len()).await?;
    let mut tasks = vec![server, heartbeat(&stations, &cameras, &shutdown)];
    for (name, rc, rx, view) in robot_links {
        tasks.push(tokio::spawn(crate::robot::link::run(name, rc, rx, view, shutdown.clone())));
    }
    let cameras = Arc::new(cameras);
    Ok(Running { modbus_addr, http_addr: None, opcua_url: None, cameras, stations, stats, started, shutdown, stop: common.stop, tasks })
}

/// Loads a camera's start-up job and says so; a knowledge base file of another job that is
/// missing now is named now, so that it is not first noticed as a failed change on the line.
fn start_job(cam: &CameraConfig, params: &Params) -> Result<InForce, StartError> {
    let job = cam.start();
    let Loaded { job: in_force, kb_desc } = load_job(&cam.name, job, &cam.source, params)?;
    tracing::info!(
        camera = %cam.name,
        unit_id = cam.unit_id,
        "job {} ({}): knowledge base: {kb_desc}; calibration: {}",
        job.id,
        job.name,
        in_force.calibration.describe()
    );
    for other in cam.jobs.iter().filter(|j| j.id != job.id) {
        if let KbSource::File(p) = &other.kb
            && !p.is_file()
        {
            tracing::warn!(camera = %cam.name, "job {} ({}): knowledge base {} does not exist (a change to it will fail)", other.id, other.name, p.display());
        }
    }
    Ok(in_force)
}

/// One camera: its job, handshake, source, archive, history and robot channel, and its worker
/// thread started on them.
fn wire(cam: &CameraConfig, common: &Common) -> Result<Wired, StartError> {
    let in_force = Arc::new(start_job(cam, &common.params)?);
    let shared: camera::SharedJob = Arc::new(std::sync::RwLock::new(in_force.clone()));
    let handshake = Arc::new(Mutex::new(Handshake::new(Settings {
        queue_depth: common.queue_depth,
        online: cam.online,
        word_order: cam.word_order,
        types_enrolled: in_force.types_enrolled(),
        picking_order: cam.picking_order,
        boot_id: common.boot_id,
        job_id: in_force.id,
    })));
    let (commands, commands_rx) = std::sync::mpsc::channel();
    let (orders, orders_rx) = std::sync::mpsc::channel();
    let live = Arc::new(Mutex::new(Live::default()));
    let (source, genicam) = source_for(cam)?;
    let (robot_tx, robot_link) = match &cam.robot {
        Some(rc) => {
            let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
            (Some(tx), Some((cam.name.clone(), rc.clone(), rx, Arc::new(Mutex::new(RobotView::default())))))
        }
        None => (None, None),
    };
    let archive = match &cam.archive {
        Some(a) => archive::Archive::start(a, &cam.name, cam.unit_id).map_err(|source| StartError::Archive {
            camera: cam.name.clone(),
            dir: a.dir.clone(),
            source,
        })?,
        None => None,
    };
    let shelf = archive.as_ref().map(archive::Archive::shelf);
    let (history, history_shelf) = if common.history_frames > 0 {
        let c = common.changes.clone();
        let (rec, shelf) = history::Recorder::start(&cam.name, common.history_frames, move || bump(&c));
        (Some(rec), Some(shelf))
    } else {
        (None, None)
    };
    let published: camera::Published = tokio::sync::broadcast::channel(camera::PUBLISHED).0;
    let worker = Worker {
        name: cam.name.clone(),
        trigger: cam.trigger,
        job: in_force,
        shared: shared.clone(),
        source,
        handshake: handshake.clone(),
        commands: commands_rx,
        orders: orders_rx,
        live: live.clone(),
        started: common.started,
        stop: common.stop.clone(),
        robot_send: cam.robot.as_ref().map_or(crate::config::RobotSend::Accepted, |r| r.send),
        robot: robot_tx,
        archive,
        history,
        changes: common.changes.clone(),
        jobs: job::Jobs { camera: cam.name.clone(), configured: cam.jobs.clone(), source: cam.source.clone(), base: common.params.clone() },
        published: published.clone(),
    };
    let thread =
        std::thread::Builder::new().name(format!("camera-{}", cam.unit_id)).spawn(move || worker.run()).expect("spawn camera thread");
    let station =
        Station { unit_id: cam.unit_id, handshake: handshake.clone(), commands: commands.clone(), last_writer: Mutex::new((None, None)) };
    let handle = CameraHandle {
        unit_id: cam.unit_id,
        name: cam.name.clone(),
        handshake,
        live,
        job: shared,
        robot: robot_link.as_ref().map(|l| l.3.clone()),
        archive: shelf,
        history: history_shelf,
        changes: common.changes.clone(),
        started: common.started,
        genicam,
        commands,
        orders,
        jobs: cam.jobs.iter().map(|j| (j.id, j.name.clone())).collect(),
        published,
        thread: Mutex::new(Some(thread)),
    };
    Ok(Wired { handle, station, robot_link })
}

/// The PLC's Modbus/TCP server, listening: its address, its counters and its task.
async fn serve_modbus(
    cfg: &Config,
    stations: &Arc<Stations>,
    shutdown: &CancellationToken,
    cameras: usize,
) -> Result<(SocketAddr, Arc<Stats>, tokio::task::JoinHandle<()>), StartError> {
    let listener = TcpListener::bind(cfg.modbus.bind).await.map_err(|source| StartError::Bind { addr: cfg.modbus.bind, source })?;
    let modbus_addr = listener.local_addr().map_err(|source| StartError::Bind { addr: cfg.modbus.bind, source })?;
    tracing::info!(
        "Modbus/TCP server on {modbus_addr} ({cameras} camera(s), max {} clients, idle timeout {} s)",
        cfg.modbus.max_connections,
        cfg.modbus.idle_timeout.as_secs_f64()
    );
    let stats = Arc::new(Stats::default());
    let settings = server::Settings {
        max_connections: cfg.modbus.max_connections,
        idle_timeout: cfg.modbus.idle_timeout,
        frame_timeout: cfg.modbus.frame_timeout,
        write_allow: cfg.modbus.write_allow.clone(),
    };
    let task = tokio::spawn(server::serve(listener, stations.clone(), settings, stats.clone(), shutdown.clone()));
    Ok((modbus_addr, stats, task))
}

/// The heartbeat (and the robot link's state) into every camera's registers, every 100 ms.
fn heartbeat(stations: &Arc<Stations>, cameras: &[CameraHandle], shutdown: &CancellationToken) -> tokio::task::JoinHandle<()> {
    let (stations, shutdown) = (stations.clone(), shutdown.clone());
    let robot_views: Vec<_> = cameras.iter().map(|c| (c.handshake.clone(), c.robot.clone())).collect();
    tokio::spawn(async move {
        let mut iv = tokio::time::interval(Duration::from_millis(100));
        loop {
            tokio::select! {
                _ = shutdown.cancelled() => break,
                _ = iv.tick() => {}
            }
            let t = stations.since_start();
            for (hs, robot) in &robot_views {
                let view = robot.as_ref().map(|r| *r.lock().unwrap_or_else(|p| p.into_inner()));
                let mut hs = hs.lock().unwrap_or_else(|p| p.into_inner());
                hs.tick(t);
                if let Some(v) = view {
                    hs.set_robot(v);
                }
            }
        }
    })
}

/// Why a write from the operator view did not happen.
#[derive(Debug, thiserror::Error)]
pub enum ControlError {
    /// The write a PLC would get an exception for, with the exception.
    #[error("{name} = {value} refused as a PLC's write would be ({exception:?})")]
    Refused {
        /// The register's name.
        name: &'static str,
        /// The value.
        value: u16,
        /// What the Modbus service answered.
        exception: tokio_modbus::ExceptionCode,
    },
    /// The worker is gone (the appliance is stopping).
    #[error("the camera's worker has stopped")]
    Stopped,
}

impl CameraHandle {
    /// The job in force: its templates, the estimator on them, its calibration.
    pub fn job(&self) -> Arc<InForce> {
        self.job.read().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Enrols a part of the current frame (see [`enrol`]): the camera's worker does it between
    /// two frames and puts the job with the new template in force.
    pub async fn enrol(&self, req: EnrolRequest) -> Result<Enrolled, EnrolError> {
        let (reply, answer) = tokio::sync::oneshot::channel();
        self.orders.send(camera::Order::Enrol(req, reply)).map_err(|_| EnrolError::Stopped)?;
        answer.await.map_err(|_| EnrolError::Stopped)?
    }

    /// Writes one register as a PLC's FC6 would (the same checks, the same handshake, the same
    /// commands to the worker), for the operator view's commissioning controls: what the page
    /// does, the PLC sees, and nothing the PLC could not do.
    pub fn write_as_plc(&self, addr: u16, value: u16) -> Result<(), ControlError> {
        let name = crate::registers::lookup(addr).map_or("(no register)", |r| r.name);
        let request = tokio_modbus::Request::WriteSingleRegister(addr, value);
        let (_, commands) = {
            let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
            crate::modbus::service::handle(&mut hs, &request, true, self.started.elapsed())
        }
        .map_err(|exception| ControlError::Refused { name, value, exception })?;
        bump(&self.changes);
        for c in commands {
            self.commands.send(c).map_err(|_| ControlError::Stopped)?;
        }
        Ok(())
    }
}

impl CameraHandle {
    /// One trigger, as a PLC's TRIGGER edge (1 then 0, the same checks): the ACQ_ID of the
    /// acquisition it started, or None when the camera was not READY (counted as missed, as
    /// the PLC's would be).
    /// `before_start` hears the ACQ_ID before the worker is told (whatever must be in place when
    /// the results come).
    pub fn trigger_as_plc(&self, before_start: impl FnOnce(u16)) -> Result<Option<u16>, ControlError> {
        let now = self.started.elapsed();
        let mut commands = Vec::new();
        let started =
            {
                let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
                let before = hs.counters().acquisitions;
                for v in [1, 0] {
                    let request = tokio_modbus::Request::WriteSingleRegister(crate::registers::addr::TRIGGER, v);
                    let (_, c) = crate::modbus::service::handle(&mut hs, &request, true, now)
                        .map_err(|exception| ControlError::Refused { name: "TRIGGER", value: v, exception })?;
                    commands.extend(c);
                }
                if hs.counters().acquisitions > before { hs.running() } else { None }
            };
        if let Some(acq_id) = started {
            before_start(acq_id);
        }
        bump(&self.changes);
        for c in commands {
            self.commands.send(c).map_err(|_| ControlError::Stopped)?;
        }
        Ok(started)
    }
}

impl Running {
    /// Runs `task` with the appliance: [`Running::stop`] waits for it after cancelling
    /// [`Running::shutdown`] (how the operator view joins in without the appliance knowing it).
    pub fn add_task(&mut self, task: tokio::task::JoinHandle<()>) {
        self.tasks.push(task);
    }

    /// Stops accepting, ends sessions and robot links, and joins the camera threads.
    pub async fn stop(mut self) {
        self.shutdown.cancel();
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for t in self.tasks.drain(..) {
            let _ = t.await;
        }
        for c in self.cameras.iter() {
            let thread = c.thread.lock().unwrap_or_else(|p| p.into_inner()).take();
            if let Some(t) = thread {
                let _ = tokio::task::spawn_blocking(move || t.join()).await;
            }
        }
        tracing::info!("appliance stopped");
    }
}

impl Drop for Running {
    /// Dropped without [`Running::stop`] (a panic, an early return): the threads and tasks are
    /// told to end, so that nothing waits for them forever (the operator view's thread is joined
    /// by a blocking task its runtime would otherwise wait for).
    fn drop(&mut self) {
        self.shutdown.cancel();
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
    }
}
