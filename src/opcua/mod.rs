//! The OPC UA server: each camera as an OPC 40100-1 vision system, beside the PLC's Modbus.
//!
//! Isolation, as the operator view's: its own thread and runtime at a lower priority, limits on
//! sessions, subscriptions and monitored items; whatever its clients do, the camera workers and
//! the Modbus service keep their threads. It reads the handshakes and writes to them only as
//! the PLC would (`CameraHandle::write_as_plc`): the state machines stay the only deciders.

pub mod auth;
pub mod model;
pub mod results;
pub mod types;

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Duration;

use async_opcua::server::node_manager::memory::{InMemoryNodeManager, InMemoryNodeManagerBuilder};
use async_opcua::server::{ServerBuilder, ServerEndpoint};
use async_opcua::types::{AttributeId, StatusCode, Variant};

use crate::appliance::{CameraHandle, Running, StartError};
use crate::config::{OpcuaConfig, Trigger};
use crate::registers::addr;
use model::{Call, CameraNodes, Vision};

/// How often the cameras' states are read into the model (a change shows within this).
const STATE_PERIOD: Duration = Duration::from_millis(100);

/// The most events (or values) one monitored item keeps for its client between publishes, and
/// the most a client may ask for. The server's thread runs at a lower priority than the cameras:
/// during a burst of fast cycles it may publish nothing for a second, and a subscriber must still
/// get every ResultReady (async-opcua's default of 10 dropped events 9-17 of 18 quick cycles in
/// `tests/one_truth.rs`). As many as the cameras' result feed holds for the server
/// (`camera::PUBLISHED`); at a few kB per event, 24 sessions with one full item each stay under
/// 30 MB.
const ITEM_QUEUE: usize = crate::appliance::camera::PUBLISHED;
/// Notification messages a subscription keeps waiting for its client's publish requests.
const SUBSCRIPTION_QUEUE: usize = 100;

/// The server's counters, for the operator view and `/metrics`.
#[derive(Debug, Default)]
pub struct Stats {
    /// The endpoint URL, once the server listens.
    pub endpoint: OnceLock<String>,
    /// Sessions open now (the server's own diagnostics, copied every 100 ms).
    pub sessions: AtomicU64,
    /// Subscriptions now.
    pub subscriptions: AtomicU64,
    /// Sessions opened since start.
    pub sessions_total: AtomicU64,
    /// Requests the server rejected (malformed, over a limit, not allowed).
    pub rejected_requests: AtomicU64,
    /// Method calls carried out.
    pub calls_ok: AtomicU64,
    /// Method calls refused by the appliance's checks (not READY, an unknown job, ...).
    pub calls_refused: AtomicU64,
    /// ResultReady events raised.
    pub events: AtomicU64,
    /// Acquisitions not reported because the server fell behind.
    pub events_lost: AtomicU64,
}

/// The endpoint URL clients connect to for `bind`.
pub fn endpoint_url(bind: SocketAddr) -> String {
    let host = if bind.ip().is_unspecified() { hostname() } else { bind.ip().to_string() };
    let host = if host.contains(':') { format!("[{host}]") } else { host };
    format!("opc.tcp://{host}:{}/", bind.port())
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|h| h.trim().to_string()).unwrap_or_else(|_| "localhost".into())
}

/// Starts the OPC UA server beside a running appliance (which stops it with itself), on its own
/// thread and runtime; returns the endpoint URL.
pub async fn attach(running: &mut Running, cfg: &OpcuaConfig, triggers: Vec<Trigger>, stats: Arc<Stats>) -> Result<String, StartError> {
    let bind_err = |source| StartError::Bind { addr: cfg.bind, source };
    let listener = std::net::TcpListener::bind(cfg.bind).map_err(bind_err)?;
    listener.set_nonblocking(true).map_err(bind_err)?;
    let addr = listener.local_addr().map_err(bind_err)?;
    let url = endpoint_url(addr);
    std::fs::create_dir_all(&cfg.pki_dir)
        .map_err(|source| StartError::Opcua { message: format!("cannot make the PKI folder {}: {source}", cfg.pki_dir.display()) })?;
    let cameras = running.cameras.clone();
    let types = Arc::new(types::LateTypes::default());
    let shell = Arc::new(Shell {
        stats: stats.clone(),
        cameras: cameras.clone(),
        types: types.clone(),
        triggers: triggers.clone(),
        pending: Mutex::new(HashMap::new()),
        kept: cameras.iter().map(|_| Mutex::new(results::Store::new(cfg.results_kept))).collect(),
        handles: AtomicU32::new(0),
        limits: Limits {
            sessions: cfg.max_sessions,
            subscriptions: cfg.max_subscriptions_per_session,
            items: cfg.max_monitored_items_per_subscription,
        },
        mv: OnceLock::new(),
    });
    let handler: model::Handler = {
        let shell = shell.clone();
        Arc::new(move |camera, call, args, user| shell.call(camera, call, args, user))
    };
    // Subscribed now, before any acquisition the server should report.
    let feeds: Vec<_> = cameras.iter().map(|c| c.published.subscribe()).collect();
    let imports = model::imports().map_err(|message| StartError::Opcua { message })?;
    let (server, handle) = builder(cfg, addr)
        .with_type_loader(types.clone())
        .with_node_manager(InMemoryNodeManagerBuilder::new(Vision::build(imports, handler)))
        .with_authenticator(Arc::new(auth::Users::new(cfg.users.clone(), cfg.allow_anonymous_read)))
        .build()
        .map_err(|message| StartError::Opcua { message: format!("the OPC UA server cannot be built: {message}") })?;
    let manager = handle
        .node_managers()
        .get_of_type::<InMemoryNodeManager<Vision>>()
        .ok_or_else(|| StartError::Opcua { message: "the vision node manager is missing".into() })?;
    let mut nodes: Vec<CameraNodes> = Vec::new();
    {
        let tt = handle.type_tree().read();
        for (i, c) in cameras.iter().enumerate() {
            nodes.push(model::add_camera(&manager, &*tt, i, &c.name).map_err(|message| StartError::Opcua { message })?);
        }
        let mv =
            handle.get_namespace_index(model::MV_URI).ok_or_else(|| StartError::Opcua { message: "no MachineVision namespace".into() })?;
        let _ = shell.mv.set(mv);
    }
    let _ = stats.endpoint.set(url.clone());
    tracing::info!(
        "OPC UA server on {url} ({} vision system(s) under Objects/DeviceSet; anonymous {}; {} user(s); PKI {})",
        nodes.len(),
        if cfg.allow_anonymous_read { "may read" } else { "refused" },
        cfg.users.len(),
        cfg.pki_dir.display()
    );
    let shutdown = running.shutdown.clone();
    let thread = std::thread::Builder::new()
        .name("opcua".into())
        .spawn(move || {
            crate::appliance::lower_priority("OPC UA server");
            let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
                Ok(rt) => rt,
                Err(e) => return tracing::error!("OPC UA server not started: no runtime: {e}"),
            };
            rt.block_on(async move {
                let listener = match tokio::net::TcpListener::from_std(listener) {
                    Ok(l) => l,
                    Err(e) => return tracing::error!("OPC UA server not started: {e}"),
                };
                let updates = follow_states(&manager, &handle, &shell, &nodes, shutdown.clone());
                let events = futures_util::future::join_all(
                    feeds.into_iter().enumerate().map(|(i, feed)| report_results(&shell, &handle, &nodes[i], i, feed, shutdown.clone())),
                );
                let cancel = handle.token().clone();
                let stop = async move {
                    shutdown.cancelled().await;
                    cancel.cancel();
                };
                let (served, _, _, _) = tokio::join!(server.run_with(listener), updates, events, stop);
                if let Err(e) = served {
                    tracing::error!("OPC UA server stopped: {e}");
                }
            });
        })
        .map_err(bind_err)?;
    running.add_task(tokio::task::spawn_blocking(move || {
        let _ = thread.join();
    }));
    Ok(url)
}

/// The server's settings: endpoints None and Basic256Sha256 (Sign, SignAndEncrypt) at `/`,
/// the certificate made at first start in the PKI folder, the limits.
fn builder(cfg: &OpcuaConfig, addr: SocketAddr) -> ServerBuilder {
    use async_opcua::crypto::SecurityPolicy;
    use async_opcua::types::MessageSecurityMode;
    let host = if addr.ip().is_unspecified() { hostname() } else { addr.ip().to_string() };
    let endpoint = |policy: SecurityPolicy, mode: MessageSecurityMode| {
        let mut e = ServerEndpoint::from(("/", policy, mode, &[][..]));
        e.password_security_policy = Some(auth::password_policy());
        e
    };
    let mut b = ServerBuilder::new()
        .application_name("lfi-bridge")
        .application_uri(format!("urn:{host}:lfi-bridge"))
        .product_uri("urn:lfi-bridge")
        .host(host)
        .port(addr.port())
        .pki_dir(&cfg.pki_dir)
        .create_sample_keypair(true)
        .certificate_path("own/cert.der")
        .private_key_path("private/private.pem")
        .trust_client_certs(cfg.trust_client_certs)
        .discovery_urls(vec!["/".to_owned()])
        .add_endpoint("none", endpoint(SecurityPolicy::None, MessageSecurityMode::None))
        .add_endpoint("basic256sha256_sign", endpoint(SecurityPolicy::Basic256Sha256, MessageSecurityMode::Sign))
        .add_endpoint("basic256sha256_sign_encrypt", endpoint(SecurityPolicy::Basic256Sha256, MessageSecurityMode::SignAndEncrypt))
        .max_sessions(cfg.max_sessions)
        .diagnostics_enabled(true);
    let limits = b.limits_mut();
    limits.subscriptions.max_subscriptions_per_session = cfg.max_subscriptions_per_session;
    limits.subscriptions.max_monitored_items_per_sub = cfg.max_monitored_items_per_subscription;
    limits.subscriptions.max_monitored_item_queue_size = ITEM_QUEUE;
    limits.subscriptions.max_queued_notifications = SUBSCRIPTION_QUEUE;
    b
}

/// Reads every camera's state into the model while the server runs: the handshake decides,
/// this only copies (a change shows within [`STATE_PERIOD`]).
async fn follow_states(
    manager: &InMemoryNodeManager<Vision>,
    handle: &async_opcua::server::ServerHandle,
    shell: &Shell,
    nodes: &[CameraNodes],
    shutdown: tokio_util::sync::CancellationToken,
) {
    let cameras = &shell.cameras;
    let mut last = vec![None; cameras.len()];
    let mut types_failed = false;
    let mut watch = LimitWatch::default();
    let mut tick = tokio::time::interval(STATE_PERIOD);
    loop {
        tokio::select! {
            _ = shutdown.cancelled() => break,
            _ = tick.tick() => {}
        }
        // The MachineVision structures, once the running server's type tree holds them (a
        // call with one of them as an argument is refused as undecodable until then).
        if !types_failed
            && !shell.types.ready()
            && let Some(&mv) = shell.mv.get()
        {
            let filled = shell.types.fill(&manager.address_space().read(), &handle.type_tree().read(), mv);
            match filled {
                Ok(true) => tracing::debug!("OPC UA: MachineVision structure types loaded"),
                Ok(false) => {}
                Err(e) => {
                    tracing::error!(
                        "OPC UA: the MachineVision structure types cannot be loaded (StartSingleJob and ResultReady's identifiers will fail): {e}"
                    );
                    types_failed = true;
                }
            }
        }
        copy_diagnostics(handle, &shell.stats);
        let now = (shell.stats.sessions.load(Relaxed), shell.stats.rejected_requests.load(Relaxed));
        for (warn, line) in watch.look(now.0, now.1, &shell.limits, std::time::Instant::now()) {
            if warn {
                tracing::warn!("OPC UA: {line}");
            } else {
                tracing::info!("OPC UA: {line}");
            }
        }
        for (i, cam) in cameras.iter().enumerate() {
            let free_run = shell.triggers.get(i) == Some(&Trigger::FreeRun);
            let state = cam.handshake.lock().unwrap_or_else(|p| p.into_inner()).vision_state(free_run);
            if last[i] == Some(state) {
                continue;
            }
            last[i] = Some(state);
            tracing::debug!(camera = %cam.name, "OPC UA state: {state:?}");
            let values = model::state_values(&nodes[i], state);
            if let Err(e) = manager.set_attributes(handle.subscriptions(), values.iter().map(|(id, v)| (id, AttributeId::Value, v.clone())))
            {
                tracing::warn!(camera = %cam.name, "OPC UA state not updated: {e}");
            }
        }
    }
}

/// What method calls and result reports share.
struct Shell {
    stats: Arc<Stats>,
    cameras: Arc<Vec<CameraHandle>>,
    types: Arc<types::LateTypes>,
    triggers: Vec<Trigger>,
    /// What StartSingleJob asked to come back with an acquisition's results, by (camera,
    /// ACQ_ID): entered before the acquisition starts, taken when its results are reported.
    pending: Mutex<HashMap<(usize, u16), results::Ids>>,
    /// Each camera's newest results, for the result management's methods.
    kept: Vec<Mutex<results::Store>>,
    /// The last ResultHandle given out (each query gets its own; nothing is held for it).
    handles: AtomicU32,
    /// The configured limits, for the log lines that say a client hit one.
    limits: Limits,
    /// The MachineVision namespace's index.
    mv: OnceLock<u16>,
}

impl Shell {
    /// A method call on camera `camera`, carried out as the PLC's register writes would be
    /// (counted by outcome).
    fn call(&self, camera: usize, call: Call, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        let r = self.carry_out(camera, call, args, user);
        match &r {
            Ok(_) => self.stats.calls_ok.fetch_add(1, Relaxed),
            Err(_) => self.stats.calls_refused.fetch_add(1, Relaxed),
        };
        r
    }

    fn carry_out(&self, camera: usize, call: Call, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        let cam = &self.cameras[camera];
        let free_run = self.triggers.get(camera) == Some(&Trigger::FreeRun);
        let write = |register: u16, value: u16| match cam.write_as_plc(register, value) {
            Ok(()) => {
                tracing::info!(camera = %cam.name, user, "OPC UA {call:?}");
                Ok(Vec::new())
            }
            Err(e) => {
                tracing::warn!(camera = %cam.name, user, "OPC UA {call:?} refused: {e}");
                Err(StatusCode::BadInvalidState)
            }
        };
        match call {
            Call::Halt => write(addr::ONLINE, 0),
            Call::Reset => write(addr::CLEAR_ERROR, 1),
            Call::SelectModeAutomatic => write(addr::ONLINE, 1),
            // A free-running camera's continuous execution stops by going offline; a triggered
            // camera's single job is one frame, finished within its cycle: nothing to stop.
            Call::Stop | Call::Abort if free_run => write(addr::ONLINE, 0),
            Call::Stop | Call::Abort => {
                tracing::info!(camera = %cam.name, user, "OPC UA {call:?}: no continuous execution to stop");
                Ok(vec![Variant::from(0i32)])
            }
            Call::StartSingleJob => self.start_single_job(camera, args, user),
            Call::PrepareRecipe => self.prepare_recipe(camera, args, user),
            Call::GetResultById => self.result_by_id(camera, args, user),
            Call::GetResultListFiltered => self.result_list(camera, args, user),
        }
    }

    /// A ResultHandle: unique while the server runs. The results are answered whole, so the
    /// server holds nothing for a handle (ReleaseResultHandle is not needed).
    fn handle(&self) -> Variant {
        Variant::from(self.handles.fetch_add(1, Relaxed).wrapping_add(1))
    }

    /// A kept result as ResultDataType.
    fn result_data(&self, cam: &CameraHandle, k: &results::Kept) -> Result<Variant, StatusCode> {
        let mv = *self.mv.get().ok_or(StatusCode::BadInternalError)?;
        k.data(&self.types, mv).map_err(|e| {
            tracing::error!(camera = %cam.name, "OPC UA: result {} cannot be encoded: {e}", k.id);
            StatusCode::BadInternalError
        })
    }

    /// GetResultById(ResultId, Timeout) -> (ResultHandle, Result, Error): one of the camera's
    /// kept results (`[opcua] results_kept`); an id it does not keep is `BadNotFound`.
    fn result_by_id(&self, camera: usize, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        let cam = &self.cameras[camera];
        let id = args.first().map(|v| types::field(v, "Id")).unwrap_or_default();
        let found = self.kept[camera].lock().unwrap_or_else(|p| p.into_inner()).by_id(&id).cloned();
        let Some(k) = found else {
            tracing::info!(camera = %cam.name, user, "OPC UA GetResultById: no result {id:?} kept");
            return Err(StatusCode::BadNotFound);
        };
        Ok(vec![self.handle(), self.result_data(cam, &k)?, Variant::from(0i32)])
    }

    /// GetResultListFiltered(ResultState, MeasId, PartId, ExternalRecipeId, InternalRecipeId,
    /// ExternalConfigurationId, InternalConfigurationId, ProductId, JobId, MaxResults,
    /// StartIndex, Timeout) -> (IsComplete, ResultCount, ResultHandle, ResultList, Error): the
    /// kept results matching every filter set, newest first.
    fn result_list(&self, camera: usize, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        let cam = &self.cameras[camera];
        let id = |i: usize| args.get(i).map(|v| types::field(v, "Id")).unwrap_or_default();
        let number = |i: usize| -> Result<i64, StatusCode> {
            match args.get(i) {
                None | Some(Variant::Empty) => Ok(0),
                Some(Variant::Int32(n)) => Ok(i64::from(*n)),
                Some(Variant::UInt32(n)) => Ok(i64::from(*n)),
                Some(other) => {
                    tracing::warn!(camera = %cam.name, user, "OPC UA GetResultListFiltered refused: argument {} is {other:?}, not a number", i + 1);
                    Err(StatusCode::BadTypeMismatch)
                }
            }
        };
        let filter = results::Filter {
            state: number(0)? as i32,
            meas_id: id(1),
            part_id: id(2),
            internal_recipe: id(4),
            internal_configuration: id(6),
            job: id(8),
            unkept: vec![id(3), id(5), id(7)],
        };
        let (max, start) = (number(9)? as usize, number(10)? as usize);
        let (count, complete, list) = {
            let store = self.kept[camera].lock().unwrap_or_else(|p| p.into_inner());
            let page = store.list(&filter, max, start);
            (page.count, page.complete, page.results.into_iter().cloned().collect::<Vec<_>>())
        };
        let list = list.iter().map(|k| self.result_data(cam, k)).collect::<Result<Vec<_>, _>>()?;
        let list = async_opcua::types::Array::new(async_opcua::types::VariantScalarTypeId::ExtensionObject, list).map_err(|e| {
            tracing::error!(camera = %cam.name, "OPC UA GetResultListFiltered: the list cannot be made: {e}");
            StatusCode::BadInternalError
        })?;
        tracing::debug!(camera = %cam.name, user, "OPC UA GetResultListFiltered {filter:?}: {} of {count}", list.values.len());
        Ok(vec![
            Variant::from(complete),
            Variant::from(u32::try_from(count).unwrap_or(u32::MAX)),
            self.handle(),
            Variant::Array(Box::new(list)),
            Variant::from(0i32),
        ])
    }

    /// An identifier structure a method returns (`what` names the method in the log).
    fn id_out(&self, cam: &CameraHandle, what: &str, type_id: u32, id: &str) -> Result<Variant, StatusCode> {
        let mv = *self.mv.get().ok_or(StatusCode::BadInternalError)?;
        self.types.id(mv, type_id, id).map_err(|e| {
            tracing::error!(camera = %cam.name, "OPC UA {what}: its output cannot be made: {e}");
            StatusCode::BadInternalError
        })
    }

    /// PrepareRecipe(ExternalId, InternalIdIn) -> (InternalIdOut, IsCompleted, Error): the
    /// PLC's JOB_REQUEST with the job id `ExternalId.Id` in decimal. An id no `[[camera.job]]`
    /// has is refused (`BadInvalidArgument`) and changes nothing; otherwise the job loads as
    /// for the PLC (the job in force stays if it fails), `IsCompleted` says whether it is in
    /// force already, and the automatic mode shows Initialized until it is.
    fn prepare_recipe(&self, camera: usize, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        let cam = &self.cameras[camera];
        let text = args.first().map(|v| types::field(v, "Id")).unwrap_or_default();
        let Some(id) = text.trim().parse::<u16>().ok().filter(|id| cam.jobs.iter().any(|(j, _)| j == id)) else {
            let known: Vec<u16> = cam.jobs.iter().map(|(j, _)| *j).collect();
            tracing::warn!(camera = %cam.name, user, "OPC UA PrepareRecipe refused: recipe {text:?} is not a configured job ({known:?})");
            return Err(StatusCode::BadInvalidArgument);
        };
        if let Err(e) = cam.write_as_plc(addr::JOB_REQUEST, id) {
            tracing::warn!(camera = %cam.name, user, "OPC UA PrepareRecipe {id} refused: {e}");
            return Err(StatusCode::BadInvalidState);
        }
        tracing::info!(camera = %cam.name, user, "OPC UA PrepareRecipe: job {id} requested");
        let done = cam.handshake.lock().unwrap_or_else(|p| p.into_inner()).job_settled(id);
        let internal = self.id_out(cam, "PrepareRecipe", types::RECIPE_ID_INTERNAL, &id.to_string())?;
        Ok(vec![internal, Variant::from(done), Variant::from(0i32)])
    }

    /// StartSingleJob(MeasId, PartId, RecipeId, ProductId, Parameters) -> (JobId, Error): one
    /// trigger of the job in force (an empty RecipeId; otherwise it must name the job in force,
    /// as JOB_ID). MeasId and PartId come back with the results.
    fn start_single_job(&self, camera: usize, args: &[Variant], user: &str) -> Result<Vec<Variant>, StatusCode> {
        let cam = &self.cameras[camera];
        let arg = |i: usize, f: &str| args.get(i).map(|v| types::field(v, f)).unwrap_or_default();
        let ids = results::Ids { meas_id: arg(0, "Id"), part_id: arg(1, "Id") };
        let (recipe, product) = (arg(2, "Id"), arg(3, "Id"));
        let (job_in_force, boot_id) = {
            let hs = cam.handshake.lock().unwrap_or_else(|p| p.into_inner());
            (hs.job_id(), hs.settings().boot_id)
        };
        if !recipe.is_empty() && recipe != job_in_force.to_string() {
            tracing::warn!(camera = %cam.name, user, "OPC UA StartSingleJob refused: recipe {recipe:?} is not the job in force ({job_in_force}); PrepareRecipe first");
            return Err(StatusCode::BadInvalidArgument);
        }
        if !product.is_empty() {
            tracing::warn!(camera = %cam.name, user, "OPC UA StartSingleJob refused: products are not used (ProductId {product:?})");
            return Err(StatusCode::BadInvalidArgument);
        }
        let started = cam.trigger_as_plc(|acq_id| {
            self.pending.lock().unwrap_or_else(|p| p.into_inner()).insert((camera, acq_id), ids.clone());
        });
        match started {
            Ok(Some(acq_id)) => {
                let job = results::job_id(&cam.name, boot_id, acq_id);
                tracing::info!(camera = %cam.name, user, "OPC UA StartSingleJob: job {job} (MeasId {:?}, PartId {:?})", ids.meas_id, ids.part_id);
                let job_id = self.id_out(cam, "StartSingleJob", types::JOB_ID, &job)?;
                Ok(vec![job_id, Variant::from(0i32)])
            }
            Ok(None) => {
                tracing::warn!(camera = %cam.name, user, "OPC UA StartSingleJob refused: the camera is not READY");
                Err(StatusCode::BadInvalidState)
            }
            Err(e) => {
                tracing::warn!(camera = %cam.name, user, "OPC UA StartSingleJob refused: {e}");
                Err(StatusCode::BadInvalidState)
            }
        }
    }
}

/// Keeps every acquisition camera `index` publishes as a result and raises its ResultReady
/// event on the camera's object (the server hands it to the Server object's subscribers too).
async fn report_results(
    shell: &Shell,
    handle: &async_opcua::server::ServerHandle,
    nodes: &CameraNodes,
    index: usize,
    mut feed: tokio::sync::broadcast::Receiver<Arc<crate::appliance::camera::Acquisition>>,
    shutdown: tokio_util::sync::CancellationToken,
) {
    use tokio::sync::broadcast::error::RecvError;
    let cam = &shell.cameras[index];
    let boot_id = cam.handshake.lock().unwrap_or_else(|p| p.into_inner()).settings().boot_id;
    let Some(&mv) = shell.mv.get() else { return };
    loop {
        let acq = tokio::select! {
            _ = shutdown.cancelled() => break,
            r = feed.recv() => match r {
                Ok(a) => a,
                Err(RecvError::Lagged(n)) => {
                    shell.stats.events_lost.fetch_add(n, Relaxed);
                    tracing::warn!(camera = %cam.name, "OPC UA: {n} acquisition(s) not reported (the server fell behind)");
                    continue;
                }
                Err(RecvError::Closed) => break,
            },
        };
        let ids = shell.pending.lock().unwrap_or_else(|p| p.into_inner()).remove(&(index, acq.acq_id)).unwrap_or_default();
        let kept = results::Kept::new(&cam.name, boot_id, &acq, ids);
        let event = results::ResultReady::new(&shell.types, mv, &nodes.system, &cam.name, &kept);
        shell.kept[index].lock().unwrap_or_else(|p| p.into_inner()).push(kept);
        // Raised on the camera's object; the server hands it to Server's subscribers too.
        handle.subscriptions().notify_events([(&event as &dyn async_opcua::nodes::Event, &nodes.system)].into_iter());
        shell.stats.events.fetch_add(1, Relaxed);
    }
}

/// The limits a client can hit (`[opcua]`).
#[derive(Debug, Clone, Copy)]
struct Limits {
    sessions: usize,
    subscriptions: usize,
    items: usize,
}

/// Turns the server's counts into log lines when a client hits a limit (the OPC UA stack answers
/// the client with a Bad status but logs nothing): the session limit exactly, as it is reached
/// and freed; other refused requests (over a subscription or monitored-item limit, a wrong
/// password, an unknown session) at most once per [`LimitWatch::QUIET`], counted.
#[derive(Debug, Default)]
struct LimitWatch {
    full: bool,
    rejected: u64,
    unreported: u64,
    last: Option<std::time::Instant>,
}

impl LimitWatch {
    const QUIET: Duration = Duration::from_secs(10);

    /// The lines to log (true: a warning) for `sessions` open and `rejected` requests refused
    /// since start, seen at `now`.
    fn look(&mut self, sessions: u64, rejected: u64, limits: &Limits, now: std::time::Instant) -> Vec<(bool, String)> {
        let mut out = Vec::new();
        let full = sessions as usize >= limits.sessions;
        if full && !self.full {
            out.push((
                true,
                format!(
                    "all {} sessions in use (max_sessions): another client's session is refused (BadTooManySessions) until one closes",
                    limits.sessions
                ),
            ));
        } else if !full && self.full {
            out.push((false, format!("{sessions} of {} sessions in use: new sessions are taken again", limits.sessions)));
        }
        self.full = full;
        self.unreported += rejected.saturating_sub(self.rejected);
        self.rejected = rejected;
        if self.unreported > 0 && self.last.is_none_or(|t| now.duration_since(t) >= Self::QUIET) {
            out.push((
                true,
                format!(
                    "{} request(s) refused{}: a client over max_sessions ({}), max_subscriptions_per_session ({}) or max_monitored_items_per_subscription ({}), a wrong password, or a session the server no longer has (the client sees which)",
                    self.unreported,
                    if self.last.is_some() { " in the last 10 s" } else { "" },
                    limits.sessions,
                    limits.subscriptions,
                    limits.items
                ),
            ));
            self.unreported = 0;
            self.last = Some(now);
        }
        out
    }
}

/// The server's session and subscription counts (its diagnostics summary) into `stats`.
fn copy_diagnostics(handle: &async_opcua::server::ServerHandle, stats: &Stats) {
    use async_opcua::types::VariableId as V;
    let read = |id: V| match handle.info().diagnostics.get(id).and_then(|v| v.value) {
        Some(Variant::UInt32(n)) => Some(n as u64),
        _ => None,
    };
    for (id, to) in [
        (V::Server_ServerDiagnostics_ServerDiagnosticsSummary_CurrentSessionCount, &stats.sessions),
        (V::Server_ServerDiagnostics_ServerDiagnosticsSummary_CurrentSubscriptionCount, &stats.subscriptions),
        (V::Server_ServerDiagnostics_ServerDiagnosticsSummary_CumulatedSessionCount, &stats.sessions_total),
        (V::Server_ServerDiagnostics_ServerDiagnosticsSummary_RejectedRequestsCount, &stats.rejected_requests),
    ] {
        if let Some(n) = read(id) {
            to.store(n, Relaxed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_client_at_a_limit_is_logged_once_and_counted() {
        let limits = Limits { sessions: 24, subscriptions: 10, items: 1000 };
        let t0 = std::time::Instant::now();
        let at = |s: u64| t0 + Duration::from_secs(s);
        let mut w = LimitWatch::default();
        assert!(w.look(3, 0, &limits, at(0)).is_empty(), "nothing refused, room left");
        let lines = w.look(24, 0, &limits, at(1));
        assert_eq!(lines.len(), 1);
        assert!(lines[0].0 && lines[0].1.contains("all 24 sessions in use (max_sessions)"), "{lines:?}");
        assert!(w.look(24, 0, &limits, at(2)).is_empty(), "said once while it stays full");
        let lines = w.look(24, 2, &limits, at(3));
        assert!(lines[0].1.starts_with("2 request(s) refused:") && lines[0].1.contains("max_subscriptions_per_session (10)"), "{lines:?}");
        assert!(w.look(24, 5, &limits, at(4)).is_empty(), "quiet for 10 s");
        let lines = w.look(23, 6, &limits, at(13));
        assert_eq!(lines.len(), 2, "{lines:?}");
        assert!(!lines[0].0 && lines[0].1.contains("23 of 24 sessions"), "{lines:?}");
        assert!(lines[1].1.starts_with("4 request(s) refused in the last 10 s"), "the three held back and the new one: {lines:?}");
    }
}
