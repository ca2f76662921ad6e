//! The appliance's configuration file (`config/*.toml`).
//!
//! Two stages, like a command line: `raw` mirrors the TOML (serde rejects unknown keys and
//! wrong types with the line and column), then [`Config::from_toml`] validates ranges and
//! combinations into ready-to-use values. Every error names the file, the key and the value.

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::time::Duration;

pub use crate::handshake::PickingOrder;
use crate::handshake::WordOrder;

/// The file exactly as written.
mod raw {
    use serde::Deserialize;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct File {
        #[serde(default)]
        pub modbus: Modbus,
        #[serde(default)]
        pub result: ResultSection,
        #[serde(default)]
        pub log: Log,
        #[serde(default)]
        pub http: Http,
        #[serde(default)]
        pub opcua: Opcua,
        #[serde(default)]
        pub camera: Vec<Camera>,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Modbus {
        #[serde(default = "default_bind")]
        pub bind: String,
        #[serde(default = "default_max_connections")]
        pub max_connections: i64,
        #[serde(default = "default_idle")]
        pub idle_timeout_s: f64,
        #[serde(default = "default_frame_timeout")]
        pub frame_timeout_s: f64,
        #[serde(default)]
        pub write_allow: Vec<String>,
    }
    fn default_bind() -> String {
        "127.0.0.1:1502".into()
    }
    fn default_frame_timeout() -> f64 {
        3.0
    }
    fn default_max_connections() -> i64 {
        64
    }
    fn default_idle() -> f64 {
        60.0
    }
    impl Default for Modbus {
        fn default() -> Self {
            Self {
                bind: default_bind(),
                max_connections: default_max_connections(),
                idle_timeout_s: default_idle(),
                frame_timeout_s: default_frame_timeout(),
                write_allow: Vec::new(),
            }
        }
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct ResultSection {
        #[serde(default = "default_depth")]
        pub queue_depth: i64,
        #[serde(default = "default_threshold")]
        pub accept_threshold: f64,
    }
    fn default_depth() -> i64 {
        8
    }
    fn default_threshold() -> f64 {
        0.5
    }
    impl Default for ResultSection {
        fn default() -> Self {
            Self { queue_depth: default_depth(), accept_threshold: default_threshold() }
        }
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Log {
        #[serde(default = "default_level")]
        pub level: String,
    }
    fn default_level() -> String {
        "info".into()
    }
    impl Default for Log {
        fn default() -> Self {
            Self { level: default_level() }
        }
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Http {
        #[serde(default = "default_true")]
        pub enabled: bool,
        #[serde(default = "default_http_bind")]
        pub bind: String,
        #[serde(default)]
        pub token: Option<String>,
        #[serde(default = "default_http_connections")]
        pub max_connections: i64,
        #[serde(default = "default_http_in_flight")]
        pub max_in_flight: i64,
        #[serde(default = "default_header_timeout")]
        pub header_timeout_s: f64,
        #[serde(default = "default_request_timeout")]
        pub request_timeout_s: f64,
        #[serde(default = "default_history")]
        pub history_frames: i64,
    }
    fn default_history() -> i64 {
        50
    }
    fn default_true() -> bool {
        true
    }
    fn default_http_connections() -> i64 {
        32
    }
    fn default_http_in_flight() -> i64 {
        8
    }
    fn default_header_timeout() -> f64 {
        5.0
    }
    fn default_request_timeout() -> f64 {
        10.0
    }
    impl Default for Http {
        fn default() -> Self {
            Self {
                enabled: true,
                bind: default_http_bind(),
                token: None,
                max_connections: default_http_connections(),
                max_in_flight: default_http_in_flight(),
                header_timeout_s: default_header_timeout(),
                request_timeout_s: default_request_timeout(),
                history_frames: default_history(),
            }
        }
    }
    fn default_http_bind() -> String {
        "127.0.0.1:8080".into()
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Opcua {
        #[serde(default)]
        pub enabled: bool,
        #[serde(default = "default_opcua_bind")]
        pub bind: String,
        #[serde(default = "default_true")]
        pub allow_anonymous_read: bool,
        #[serde(default)]
        pub pki_dir: Option<String>,
        #[serde(default)]
        pub trust_client_certs: bool,
        #[serde(default = "default_opcua_sessions")]
        pub max_sessions: i64,
        #[serde(default = "default_opcua_subscriptions")]
        pub max_subscriptions_per_session: i64,
        #[serde(default = "default_opcua_items")]
        pub max_monitored_items_per_subscription: i64,
        #[serde(default = "default_opcua_results")]
        pub results_kept: i64,
        #[serde(default)]
        pub users: Vec<OpcuaUser>,
    }
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct OpcuaUser {
        pub name: String,
        pub password_file: String,
    }
    fn default_opcua_bind() -> String {
        "127.0.0.1:4840".into()
    }
    fn default_opcua_sessions() -> i64 {
        32
    }
    fn default_opcua_subscriptions() -> i64 {
        10
    }
    fn default_opcua_items() -> i64 {
        1000
    }
    fn default_opcua_results() -> i64 {
        100
    }
    impl Default for Opcua {
        fn default() -> Self {
            Self {
                enabled: false,
                bind: default_opcua_bind(),
                allow_anonymous_read: true,
                pki_dir: None,
                trust_client_certs: false,
                max_sessions: default_opcua_sessions(),
                max_subscriptions_per_session: default_opcua_subscriptions(),
                max_monitored_items_per_subscription: default_opcua_items(),
                results_kept: default_opcua_results(),
                users: Vec::new(),
            }
        }
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Camera {
        pub unit_id: i64,
        #[serde(default)]
        pub name: Option<String>,
        pub source: Source,
        #[serde(default)]
        pub trigger: super::Trigger,
        #[serde(default = "default_online")]
        pub online: bool,
        #[serde(default)]
        pub kb: Option<String>,
        #[serde(default)]
        pub kb_from_simulator: bool,
        #[serde(default)]
        pub roi: Option<Vec<i64>>,
        #[serde(default)]
        pub mm_per_px: Option<f64>,
        #[serde(default)]
        pub calibration: Option<Calibration>,
        #[serde(default)]
        pub float_word_order: super::WordOrder,
        #[serde(default)]
        pub robot: Option<Robot>,
        #[serde(default = "default_picking_order")]
        pub picking_order: super::PickingOrder,
        #[serde(default)]
        pub archive: Option<Archive>,
        #[serde(default)]
        pub start_job: Option<i64>,
        #[serde(default)]
        pub job: Vec<Job>,
    }

    /// `[[camera.job]]`: what a job changes from the camera's own keys.
    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Job {
        pub id: i64,
        #[serde(default)]
        pub name: Option<String>,
        #[serde(default)]
        pub kb: Option<String>,
        #[serde(default)]
        pub kb_from_simulator: bool,
        #[serde(default)]
        pub expected_type: Option<i64>,
        #[serde(default)]
        pub accept_threshold: Option<f64>,
        #[serde(default)]
        pub roi: Option<Vec<i64>>,
        #[serde(default)]
        pub mm_per_px: Option<f64>,
        #[serde(default)]
        pub calibration: Option<Calibration>,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Archive {
        pub dir: String,
        #[serde(default)]
        pub save: super::ArchiveSave,
        #[serde(default = "default_archive_files")]
        pub max_files: i64,
        #[serde(default = "default_archive_mb")]
        pub max_mb: f64,
    }
    fn default_archive_files() -> i64 {
        1000
    }
    fn default_archive_mb() -> f64 {
        2000.0
    }
    fn default_picking_order() -> super::PickingOrder {
        super::PickingOrder::XDescending
    }
    fn default_online() -> bool {
        true
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Source {
        pub kind: String,
        // sim
        pub seed: Option<i64>,
        pub width: Option<i64>,
        pub height: Option<i64>,
        pub noise: Option<f64>,
        pub scenes: Option<i64>,
        pub interval_ms: Option<i64>,
        pub cell: Option<bool>,
        // dir
        pub path: Option<String>,
        pub settle_ms: Option<i64>,
        pub timeout_ms: Option<i64>,
        // video
        pub uri: Option<String>,
        // genicam
        pub device: Option<String>,
        pub exposure_us: Option<f64>,
        pub gain: Option<f64>,
        pub pixel_format: Option<String>,
        pub hardware_trigger: Option<String>,
        pub packet_size: Option<i64>,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Calibration {
        pub points: Vec<Vec<f64>>,
        pub file: Option<String>,
        pub fit: Option<String>,
        pub max_point_error_mm: Option<f64>,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    pub struct Robot {
        pub address: String,
        #[serde(default = "default_robot_unit")]
        pub unit_id: i64,
        #[serde(default)]
        pub input_words_at: i64,
        #[serde(default)]
        pub output_words_at: i64,
        #[serde(default = "default_output_function")]
        pub output_function: i64,
        #[serde(default = "default_poll")]
        pub poll_ms: i64,
        #[serde(default = "default_ack_timeout")]
        pub ack_timeout_s: f64,
        #[serde(default)]
        pub send: super::RobotSend,
        #[serde(default = "default_robot_queue")]
        pub queue_depth: i64,
    }
    fn default_robot_unit() -> i64 {
        1
    }
    fn default_output_function() -> i64 {
        3
    }
    fn default_poll() -> i64 {
        20
    }
    fn default_ack_timeout() -> f64 {
        30.0
    }
    fn default_robot_queue() -> i64 {
        64
    }
}

/// A configuration error: the file, the key, the value and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file cannot be read at all.
    #[error("cannot read configuration {path}")]
    Read {
        /// The configuration file.
        path: PathBuf,
        /// Why the system refused it.
        source: std::io::Error,
    },
    /// Not TOML, an unknown key or a value of the wrong type (serde's message has line and column).
    #[error("configuration {path}: {message}")]
    Syntax {
        /// The configuration file.
        path: PathBuf,
        /// The parser's complaint.
        message: String,
    },
    /// A well-formed value out of range or in a combination that cannot work.
    #[error("configuration {path}: {key} = {value} {problem}")]
    Value {
        /// The configuration file.
        path: PathBuf,
        /// The key as a user finds it in the file (`camera[0].source.width`).
        key: String,
        /// The value as written.
        value: String,
        /// What is wrong with it, phrased to follow "key = value".
        problem: String,
    },
}

/// Where a camera's frames come from.
#[derive(Debug, Clone, PartialEq)]
pub enum SourceConfig {
    /// The built-in simulated camera: `scenes` frames rendered at start-up and served in turn.
    Sim {
        /// Seed of the scene generator: the same seed, the same scenes.
        seed: u64,
        /// Frame width, pixels.
        width: usize,
        /// Frame height, pixels.
        height: usize,
        /// Gaussian noise sigma (gray levels) on every frame; None: the scenes' own.
        noise: Option<f64>,
        /// Scenes rendered at start-up and served in turn.
        scenes: usize,
        /// Least time between frames in free-run (a real camera's frame rate).
        interval: Duration,
        /// Frames through the simulator's cell camera (tilt, lens distortion; `simulate --cell`).
        cell: bool,
    },
    /// Image files dropped into a folder by the camera's own software.
    Dir {
        /// The inbox folder.
        path: PathBuf,
        /// A file is complete once its size and time have not changed for this long.
        settle: Duration,
        /// A trigger with no complete file within this is a camera fault.
        timeout: Duration,
    },
    /// OpenCV VideoCapture: a device index, a file, an RTSP URL or a GStreamer pipeline.
    Video {
        /// What VideoCapture opens.
        uri: String,
        /// A trigger with no frame within this is a camera fault.
        timeout: Duration,
    },
    /// A GigE Vision or USB3 Vision camera through Aravis.
    Genicam(GenicamSettings),
}

/// What `[camera.source] kind = "genicam"` asks of the camera.
#[derive(Debug, Clone, PartialEq)]
pub struct GenicamSettings {
    /// Aravis device id (`Vendor-Model-Serial`, as `arv-tool-0.8` lists it); None: the only one.
    pub device: Option<String>,
    /// ExposureTime (or ExposureTimeAbs), microseconds.
    pub exposure_us: Option<f64>,
    /// Gain (dB) or GainRaw, whichever the camera has.
    pub gain: Option<f64>,
    /// PixelFormat by name (`Mono8`); None: the camera's current one.
    pub pixel_format: Option<String>,
    /// TriggerSource line for a sensor or encoder (`Line0`); None: software trigger or free-run.
    pub hardware_trigger: Option<String>,
    /// GigE packet size, bytes (9000 for jumbo frames); None: negotiated by Aravis.
    pub packet_size: Option<u32>,
    /// No frame this long after a trigger: camera fault.
    pub timeout: Duration,
    /// Stream continuously and hand out the newest frame (`trigger = "free-run"`).
    pub free_run: bool,
}

/// `"modbus"` or `"free-run"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Trigger {
    /// One acquisition per TRIGGER edge from the PLC.
    #[default]
    Modbus,
    /// Every frame the camera delivers is an acquisition (the newest when the estimator is free).
    FreeRun,
}

/// Pixel to robot-frame millimetres.
#[derive(Debug, Clone, PartialEq)]
pub enum CalibrationConfig {
    /// A plain scale about the frame's origin (`mm_per_px`): a camera square over a flat belt.
    Scale {
        /// Millimetres per pixel.
        mm_per_px: f64,
    },
    /// A homography fitted to touched-up `[x_px, y_px, x_mm, y_mm]` pairs (four or more): tilt.
    Points(Vec<[f64; 4]>),
    /// A plate calibration file (`lfi-bridge calibrate`: lens and plane) placed in the robot
    /// frame by three or more touched-up pairs.
    Plate {
        /// The plate file (resolved against the configuration's folder).
        file: PathBuf,
        /// Touched-up `[x_px, y_px, x_mm, y_mm]` pairs.
        points: Vec<[f64; 4]>,
        /// A similarity (`fit = "similarity"`, the default) or a rigid map (`"rigid"`).
        scaled: bool,
        /// A point farther than this from where the others put it refuses the start-up, mm.
        max_point_error_mm: f64,
    },
}

/// Where a job's templates come from.
#[derive(Debug, Clone, PartialEq)]
pub enum KbSource {
    /// A knowledge-base file (resolved against the configuration's folder).
    File(PathBuf),
    /// Enroll the simulated camera's own templates at start-up.
    Simulator,
}

/// One job: a camera's knowledge base, expected type, accept threshold, ROI and calibration,
/// each the job's own or the camera's.
#[derive(Debug, Clone, PartialEq)]
pub struct JobConfig {
    /// 1..=999, as the PLC writes it to JOB_REQUEST.
    pub id: u16,
    /// For the log and the operator view ("job 3 (housing line B)").
    pub name: String,
    /// The templates this job recognises.
    pub kb: KbSource,
    /// Written into EXPECTED_TYPE when the job comes into force (None: left as it is).
    pub expected_type: Option<u16>,
    /// Least confidence for an accept.
    pub accept_threshold: f64,
    /// `[x, y, width, height]` of the frame the estimator looks at (None: the whole frame).
    pub roi: Option<[usize; 4]>,
    /// Pixels to robot millimetres.
    pub calibration: CalibrationConfig,
}

impl CameraConfig {
    /// The job with this id, if the camera has one.
    pub fn job(&self, id: u16) -> Option<&JobConfig> {
        self.jobs.iter().find(|j| j.id == id)
    }
    /// The job in force at start-up.
    pub fn start(&self) -> &JobConfig {
        self.job(self.start_job).unwrap_or(&self.jobs[0])
    }
}

/// Which frames the image archive keeps.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ArchiveSave {
    /// Frames with at least one rejected result (a no-part or frame-error result is one).
    #[default]
    Rejects,
    /// Every frame (commissioning; the folder's limits still apply).
    All,
    /// No frame: the archive is off.
    None,
}

/// `[camera.archive]`: where and how many frames are kept (see [`crate::appliance::archive`]).
#[derive(Debug, Clone, PartialEq)]
pub struct ArchiveConfig {
    /// The archive folder (resolved against the configuration's folder).
    pub dir: PathBuf,
    /// Which frames are kept.
    pub save: ArchiveSave,
    /// Frames kept (an image and its sidecar are one).
    pub max_files: usize,
    /// Bytes kept (`max_mb`); the oldest frames go first when either limit is reached.
    pub max_bytes: u64,
}

/// `"accepted"` or `"all"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RobotSend {
    /// Only parts the robot may pick.
    #[default]
    Accepted,
    /// Every result, rejects included (the robot program sorts them).
    All,
}

impl RobotSend {
    /// Whether a part result goes to the robot: accepted ones always, rejects with `All`.
    pub fn wants(self, accepted: bool) -> bool {
        accepted || self == RobotSend::All
    }
}

/// `[camera.robot]`: the robot controller this camera hands its parts to.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotConfig {
    /// The controller's Modbus/TCP server, `host:port`.
    pub address: String,
    /// Modbus unit id the controller answers to.
    pub unit_id: u8,
    /// First of the controller's registers the appliance writes (the part data).
    pub input_words_at: u16,
    /// First of the controller's registers the appliance reads (ready, ack).
    pub output_words_at: u16,
    /// 3 read holding registers, 4 read input registers.
    pub output_function: u8,
    /// How often the controller's outputs are read.
    pub poll: Duration,
    /// A part not acknowledged within this counts as an ack timeout and is sent again.
    pub ack_timeout: Duration,
    /// Which results go to the robot.
    pub send: RobotSend,
    /// Parts waiting for the robot; beyond it the newest are dropped and counted.
    pub queue_depth: usize,
    /// Word order of USER_DATA in input words 8-9: the camera's `float_word_order`.
    pub word_order: WordOrder,
}

/// One `[[camera]]`: a camera, its jobs, and the Modbus unit id the PLC reaches it by.
#[derive(Debug, Clone, PartialEq)]
pub struct CameraConfig {
    /// The Modbus unit id of this camera's register map.
    pub unit_id: u8,
    /// For the log and the operator view.
    pub name: String,
    /// Where its frames come from.
    pub source: SourceConfig,
    /// What starts an acquisition.
    pub trigger: Trigger,
    /// ONLINE at start-up (the PLC may change it).
    pub online: bool,
    /// What the camera can be switched between (JOB_REQUEST); a camera without
    /// `[[camera.job]]` tables has one, job 1, of its own keys.
    pub jobs: Vec<JobConfig>,
    /// The job in force at start-up.
    pub start_job: u16,
    /// Word order of floats and 32-bit values (`float_word_order`).
    pub word_order: WordOrder,
    /// The robot link, if the camera has one.
    pub robot: Option<RobotConfig>,
    /// The order a frame's accepted parts are handed out in.
    pub picking_order: PickingOrder,
    /// The image archive, if configured.
    pub archive: Option<ArchiveConfig>,
}

/// `[modbus]`: the PLC's server.
#[derive(Debug, Clone, PartialEq)]
pub struct ModbusConfig {
    /// Address and port the server listens on.
    pub bind: SocketAddr,
    /// Connections served at once; a new client takes the slot of the one idle longest.
    pub max_connections: usize,
    /// A connection silent this long is closed.
    pub idle_timeout: Duration,
    /// A request must be complete within this of its first byte.
    pub frame_timeout: Duration,
    /// Peers whose writes are obeyed (empty: any peer); others get exception 0x01.
    pub write_allow: Vec<IpAddr>,
}

/// `[http]`: the operator view.
#[derive(Debug, Clone, PartialEq)]
pub struct HttpConfig {
    /// Address and port of the page.
    pub bind: SocketAddr,
    /// Bearer token for changes (enrolment, jobs); None: the view is read-only.
    pub token: Option<String>,
    /// Open connections served at once; further ones wait in the kernel's backlog (they use no
    /// descriptor of the appliance's), so HTTP can never take the PLC's or the cameras'.
    pub max_connections: usize,
    /// Requests handled at once (others wait for a turn).
    pub max_in_flight: usize,
    /// A request's headers must arrive within this.
    pub header_timeout: Duration,
    /// A request must be answered within this (408 otherwise).
    pub request_timeout: Duration,
    /// Acquisitions per camera the page's history keeps in memory (0: none).
    pub history_frames: usize,
}

/// `[opcua]`: the OPC UA server (OPC 40100 machine vision).
#[derive(Debug, Clone, PartialEq)]
pub struct OpcuaConfig {
    /// Address and port of the endpoint (`opc.tcp://HOST:PORT/`).
    pub bind: SocketAddr,
    /// Anonymous sessions may browse, read and subscribe (never call a method that changes
    /// anything).
    pub allow_anonymous_read: bool,
    /// Where the application instance certificate and its key are kept (made at first start),
    /// and the trusted and rejected client certificates.
    pub pki_dir: PathBuf,
    /// Trust every client's certificate on the secure endpoints (commissioning only); otherwise
    /// an unknown one is refused and kept in `<pki_dir>/rejected` until it is moved to
    /// `<pki_dir>/trusted`.
    pub trust_client_certs: bool,
    /// Sessions at once (at least 24: a plant's SCADA, MES and gateways together).
    pub max_sessions: usize,
    /// Subscriptions per session.
    pub max_subscriptions_per_session: usize,
    /// Monitored items per subscription.
    pub max_monitored_items_per_subscription: usize,
    /// Results per camera that GetResultById and GetResultListFiltered find (the newest; one
    /// acquisition is one result).
    pub results_kept: usize,
    /// Users who may call methods: name and password (read from its file at start-up).
    pub users: Vec<OpcuaUser>,
}

/// A user of the OPC UA server, from `[[opcua.users]]`.
#[derive(Clone, PartialEq)]
pub struct OpcuaUser {
    /// The user name a client sends.
    pub name: String,
    /// The password, from `password_file` (its first line).
    pub password: String,
}

impl std::fmt::Debug for OpcuaUser {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcuaUser").field("name", &self.name).field("password", &"(hidden)").finish()
    }
}

/// The validated configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The file it was read from (relative paths in it are resolved against its folder).
    pub path: PathBuf,
    /// The PLC's server.
    pub modbus: ModbusConfig,
    /// Results queued per camera for the PLC (`[result] queue_depth`).
    pub queue_depth: usize,
    /// Default least confidence for an accept (a job may set its own).
    pub accept_threshold: f64,
    /// `tracing` filter (`[log] level`).
    pub log_level: String,
    /// The operator view, unless `[http] enabled = false`.
    pub http: Option<HttpConfig>,
    /// The OPC UA server, when `[opcua] enabled = true`.
    pub opcua: Option<OpcuaConfig>,
    /// The cameras, each with its own register map.
    pub cameras: Vec<CameraConfig>,
}

struct Check<'a> {
    path: &'a Path,
}

impl Check<'_> {
    fn err(&self, key: impl Into<String>, value: impl std::fmt::Display, problem: impl Into<String>) -> ConfigError {
        ConfigError::Value { path: self.path.to_path_buf(), key: key.into(), value: value.to_string(), problem: problem.into() }
    }
    fn int<T: TryFrom<i64>>(&self, key: &str, v: i64, lo: i64, hi: i64) -> Result<T, ConfigError> {
        if v < lo || v > hi {
            return Err(self.err(key, v, format!("is out of range ({lo}..={hi})")));
        }
        T::try_from(v).map_err(|_| self.err(key, v, "does not fit"))
    }
    fn real(&self, key: &str, v: f64, lo: f64, hi: f64) -> Result<f64, ConfigError> {
        if !v.is_finite() || v < lo || v > hi {
            return Err(self.err(key, v, format!("is out of range ({lo}..={hi})")));
        }
        Ok(v)
    }
}

impl Config {
    /// Reads and validates the file at `path`.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.into(), source })?;
        Self::from_toml(&text, path)
    }

    /// Validates `text` as the contents of `path` (which names it in errors and anchors its
    /// relative paths). Each section has its own builder below, as a command line hands each
    /// concern to its own: this only sequences them and checks what spans sections.
    pub fn from_toml(text: &str, path: &Path) -> Result<Self, ConfigError> {
        let raw: raw::File = toml::from_str(text).map_err(|e| ConfigError::Syntax { path: path.into(), message: e.to_string() })?;
        let c = Check { path };
        let base = path.parent().unwrap_or(Path::new("."));
        let modbus = modbus_of(&c, &raw.modbus)?;
        let queue_depth = c.int("result.queue_depth", raw.result.queue_depth, 1, 1000)?;
        let accept_threshold = c.real("result.accept_threshold", raw.result.accept_threshold, 0.0, 1.0)?;
        let levels = ["error", "warn", "info", "debug", "trace"];
        if !levels.contains(&raw.log.level.as_str()) {
            return Err(c.err("log.level", format!("{:?}", raw.log.level), format!("is not one of {levels:?}")));
        }
        let http = http_of(&c, &raw.http)?;
        let opcua = opcua_of(&c, &raw.opcua, base)?;
        if raw.camera.is_empty() {
            return Err(c.err("camera", "[]", "must list at least one [[camera]]"));
        }
        let mut cameras: Vec<CameraConfig> = Vec::new();
        for (i, rc) in raw.camera.iter().enumerate() {
            let camera = camera_of(&c, i, rc, base, accept_threshold)?;
            if cameras.iter().any(|o| o.unit_id == camera.unit_id) {
                return Err(c.err(format!("camera[{i}].unit_id"), camera.unit_id, "is used by another camera"));
            }
            cameras.push(camera);
        }
        if let Some(o) = &opcua {
            for (i, cam) in cameras.iter().enumerate() {
                if cameras[..i].iter().any(|other| other.name == cam.name) {
                    return Err(c.err(
                        format!("camera[{i}].name"),
                        format!("{:?}", cam.name),
                        "is another camera's too (OPC UA names each camera's object by it)",
                    ));
                }
            }
            // Port 0 (any free port, as tests ask) never collides.
            let clash = |other: SocketAddr| {
                o.bind.port() != 0
                    && other.port() == o.bind.port()
                    && (other.ip() == o.bind.ip() || other.ip().is_unspecified() || o.bind.ip().is_unspecified())
            };
            if let Some(h) = &http
                && clash(h.bind)
            {
                return Err(c.err("opcua.bind", o.bind, format!("is the operator view's port too ({})", h.bind)));
            }
            if clash(modbus.bind) {
                return Err(c.err("opcua.bind", o.bind, format!("is the PLC's Modbus port too ({})", modbus.bind)));
            }
        }
        Ok(Config {
            path: path.to_path_buf(),
            modbus,
            queue_depth,
            accept_threshold,
            log_level: raw.log.level.clone(),
            http,
            opcua,
            cameras,
        })
    }
}

/// `[modbus]`.
fn modbus_of(c: &Check<'_>, m: &raw::Modbus) -> Result<ModbusConfig, ConfigError> {
    let bind: SocketAddr = m.bind.parse().map_err(|_| c.err("modbus.bind", format!("{:?}", m.bind), "is not an address:port"))?;
    let write_allow = m
        .write_allow
        .iter()
        .enumerate()
        .map(|(i, s)| s.parse::<IpAddr>().map_err(|_| c.err(format!("modbus.write_allow[{i}]"), format!("{s:?}"), "is not an IP address")))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(ModbusConfig {
        bind,
        max_connections: c.int("modbus.max_connections", m.max_connections, 1, 1024)?,
        idle_timeout: Duration::from_secs_f64(c.real("modbus.idle_timeout_s", m.idle_timeout_s, 0.1, 86400.0)?),
        frame_timeout: Duration::from_secs_f64(c.real("modbus.frame_timeout_s", m.frame_timeout_s, 0.05, 60.0)?),
        write_allow,
    })
}

/// `[http]`; None when it is disabled.
fn http_of(c: &Check<'_>, h: &raw::Http) -> Result<Option<HttpConfig>, ConfigError> {
    if !h.enabled {
        return Ok(None);
    }
    let bind = h.bind.parse().map_err(|_| c.err("http.bind", format!("{:?}", h.bind), "is not an address:port"))?;
    if let Some(t) = &h.token
        && t.len() < 8
    {
        return Err(c.err("http.token", "(hidden)", "is shorter than 8 characters"));
    }
    Ok(Some(HttpConfig {
        bind,
        token: h.token.clone(),
        max_connections: c.int("http.max_connections", h.max_connections, 1, 512)?,
        max_in_flight: c.int("http.max_in_flight", h.max_in_flight, 1, 256)?,
        header_timeout: Duration::from_secs_f64(c.real("http.header_timeout_s", h.header_timeout_s, 0.1, 300.0)?),
        request_timeout: Duration::from_secs_f64(c.real("http.request_timeout_s", h.request_timeout_s, 0.1, 300.0)?),
        history_frames: c.int("http.history_frames", h.history_frames, 0, 1000)?,
    }))
}

/// `[opcua]`; None unless it is enabled. Passwords are read from their files now, so that a
/// missing or empty one is named at start-up, not at a client's first call.
fn opcua_of(c: &Check<'_>, o: &raw::Opcua, base: &Path) -> Result<Option<OpcuaConfig>, ConfigError> {
    if !o.enabled {
        return Ok(None);
    }
    let bind = o.bind.parse().map_err(|_| c.err("opcua.bind", format!("{:?}", o.bind), "is not an address:port"))?;
    let pki_dir = match &o.pki_dir {
        Some(d) => base.join(d),
        None => default_state_dir().join("pki"),
    };
    let mut users: Vec<OpcuaUser> = Vec::new();
    for (i, u) in o.users.iter().enumerate() {
        let k = |f: &str| format!("opcua.users[{i}].{f}");
        if u.name.trim().is_empty() || u.name.len() > 64 {
            return Err(c.err(k("name"), format!("{:?}", u.name), "must be 1 to 64 characters"));
        }
        if users.iter().any(|o| o.name == u.name) {
            return Err(c.err(k("name"), format!("{:?}", u.name), "is another user's too"));
        }
        let file = base.join(&u.password_file);
        let text = std::fs::read_to_string(&file).map_err(|e| {
            c.err(k("password_file"), format!("{:?}", u.password_file), format!("cannot be read ({}): {e}", file.display()))
        })?;
        let password = text.lines().next().unwrap_or("").to_string();
        if password.len() < 8 {
            return Err(c.err(
                k("password_file"),
                format!("{:?}", u.password_file),
                "holds a password shorter than 8 characters (its first line)",
            ));
        }
        users.push(OpcuaUser { name: u.name.clone(), password });
    }
    Ok(Some(OpcuaConfig {
        bind,
        allow_anonymous_read: o.allow_anonymous_read,
        pki_dir,
        trust_client_certs: o.trust_client_certs,
        max_sessions: c.int("opcua.max_sessions", o.max_sessions, 24, 1000)?,
        max_subscriptions_per_session: c.int("opcua.max_subscriptions_per_session", o.max_subscriptions_per_session, 1, 100)?,
        max_monitored_items_per_subscription: c.int(
            "opcua.max_monitored_items_per_subscription",
            o.max_monitored_items_per_subscription,
            1,
            100_000,
        )?,
        results_kept: c.int("opcua.results_kept", o.results_kept, 1, 10_000)?,
        users,
    }))
}

/// The appliance's state folder when the configuration names none: systemd's
/// `$STATE_DIRECTORY`, else `$XDG_STATE_HOME/lfi-bridge`, else `~/.local/state/lfi-bridge`
/// (outside any checkout: a certificate's private key is not source).
pub fn default_state_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("STATE_DIRECTORY").filter(|d| !d.is_empty()) {
        return PathBuf::from(d);
    }
    if let Some(d) = std::env::var_os("XDG_STATE_HOME").filter(|d| !d.is_empty()) {
        return PathBuf::from(d).join("lfi-bridge");
    }
    let home = std::env::var_os("HOME").map(PathBuf::from).unwrap_or_else(|| PathBuf::from("."));
    home.join(".local/state/lfi-bridge")
}

/// One `[[camera]]` (the `i`-th, as its keys are named), with `accept_threshold` from
/// `[result]` as its jobs' default.
fn camera_of(c: &Check<'_>, i: usize, rc: &raw::Camera, base: &Path, accept_threshold: f64) -> Result<CameraConfig, ConfigError> {
    let k = |f: &str| format!("camera[{i}].{f}");
    let unit_id: u8 = c.int(&k("unit_id"), rc.unit_id, 1, 247)?;
    let source = source_of(c, &k, &rc.source, base, rc.trigger == Trigger::FreeRun)?;
    // A hardware-triggered camera's frames are its acquisitions, as a free-running one's.
    let trigger = if matches!(&source, SourceConfig::Genicam(g) if g.hardware_trigger.is_some()) { Trigger::FreeRun } else { rc.trigger };
    let kb = kb_source(c, &k, rc.kb.as_deref(), rc.kb_from_simulator, &source, base)?;
    let roi = roi_of(c, &k, rc.roi.as_deref(), &source)?;
    let calibration =
        calibration_of(c, &k, rc.calibration.as_ref(), rc.mm_per_px, base)?.unwrap_or(CalibrationConfig::Scale { mm_per_px: 1.0 });
    let jobs = jobs_of(c, &k, rc, &source, base, JobDefaults { kb, accept_threshold, roi, calibration })?;
    let start_job = match rc.start_job {
        Some(v) => {
            let id: u16 = c.int(&k("start_job"), v, 1, 999)?;
            if !jobs.iter().any(|j| j.id == id) {
                let ids: Vec<String> = jobs.iter().map(|j| j.id.to_string()).collect();
                return Err(c.err(k("start_job"), id, format!("is not a configured job (jobs: {})", ids.join(", "))));
            }
            id
        }
        None => jobs.iter().map(|j| j.id).min().unwrap_or(1),
    };
    let word_order = rc.float_word_order;
    let robot = rc.robot.as_ref().map(|r| robot_of(c, &|f| k(&format!("robot.{f}")), r, word_order)).transpose()?;
    let archive = match &rc.archive {
        None => None,
        Some(a) => {
            if a.dir.trim().is_empty() {
                return Err(c.err(k("archive.dir"), "\"\"", "is empty: name the folder frames are kept in"));
            }
            Some(ArchiveConfig {
                dir: base.join(&a.dir),
                save: a.save,
                max_files: c.int(&k("archive.max_files"), a.max_files, 1, 10_000_000)?,
                max_bytes: (c.real(&k("archive.max_mb"), a.max_mb, 1.0, 1e8)? * 1e6) as u64,
            })
        }
    };
    Ok(CameraConfig {
        unit_id,
        name: rc.name.clone().unwrap_or_else(|| format!("camera{unit_id}")),
        source,
        trigger,
        online: rc.online,
        jobs,
        start_job,
        word_order,
        robot,
        picking_order: rc.picking_order,
        archive,
    })
}

/// `[camera.source]`: only the keys of its `kind` may be set.
fn source_of(c: &Check<'_>, k: &dyn Fn(&str) -> String, s: &raw::Source, base: &Path, free_run: bool) -> Result<SourceConfig, ConfigError> {
    let only = |allowed: &[&str]| -> Result<(), ConfigError> {
        let given = [
            ("seed", s.seed.is_some()),
            ("width", s.width.is_some()),
            ("height", s.height.is_some()),
            ("noise", s.noise.is_some()),
            ("scenes", s.scenes.is_some()),
            ("interval_ms", s.interval_ms.is_some()),
            ("cell", s.cell.is_some()),
            ("path", s.path.is_some()),
            ("settle_ms", s.settle_ms.is_some()),
            ("timeout_ms", s.timeout_ms.is_some()),
            ("uri", s.uri.is_some()),
            ("device", s.device.is_some()),
            ("exposure_us", s.exposure_us.is_some()),
            ("gain", s.gain.is_some()),
            ("pixel_format", s.pixel_format.is_some()),
            ("hardware_trigger", s.hardware_trigger.is_some()),
            ("packet_size", s.packet_size.is_some()),
        ];
        for (name, set) in given {
            if set && !allowed.contains(&name) {
                return Err(c.err(k(&format!("source.{name}")), "(set)", format!("does not apply to kind = {:?}", s.kind)));
            }
        }
        Ok(())
    };
    Ok(match s.kind.as_str() {
        "sim" => {
            only(&["seed", "width", "height", "noise", "scenes", "interval_ms", "cell"])?;
            SourceConfig::Sim {
                seed: c.int(&k("source.seed"), s.seed.unwrap_or(1), 0, i64::MAX)?,
                width: c.int(&k("source.width"), s.width.unwrap_or(2592), 320, 8192)?,
                height: c.int(&k("source.height"), s.height.unwrap_or(1944), 240, 8192)?,
                noise: s.noise.map(|n| c.real(&k("source.noise"), n, 0.0, 100.0)).transpose()?,
                scenes: c.int(&k("source.scenes"), s.scenes.unwrap_or(8), 1, 256)?,
                interval: Duration::from_millis(c.int(&k("source.interval_ms"), s.interval_ms.unwrap_or(500), 0, 3_600_000)?),
                cell: s.cell.unwrap_or(false),
            }
        }
        "dir" => {
            only(&["path", "settle_ms", "timeout_ms"])?;
            let p = s.path.as_ref().ok_or_else(|| c.err(k("source.path"), "(missing)", "is required for kind = \"dir\""))?;
            SourceConfig::Dir {
                path: base.join(p),
                settle: Duration::from_millis(c.int(&k("source.settle_ms"), s.settle_ms.unwrap_or(200), 0, 60_000)?),
                timeout: Duration::from_millis(c.int(&k("source.timeout_ms"), s.timeout_ms.unwrap_or(5000), 1, 3_600_000)?),
            }
        }
        "video" => {
            only(&["uri", "timeout_ms"])?;
            let uri = s
                .uri
                .clone()
                .filter(|u| !u.trim().is_empty())
                .ok_or_else(|| c.err(k("source.uri"), "(missing)", "is required for kind = \"video\""))?;
            SourceConfig::Video {
                uri,
                timeout: Duration::from_millis(c.int(&k("source.timeout_ms"), s.timeout_ms.unwrap_or(5000), 1, 3_600_000)?),
            }
        }
        "genicam" => {
            only(&["device", "exposure_us", "gain", "pixel_format", "hardware_trigger", "packet_size", "timeout_ms"])?;
            let name = |key: &str, v: &Option<String>| -> Result<Option<String>, ConfigError> {
                match v {
                    Some(t) if t.trim().is_empty() || t.chars().any(char::is_control) => {
                        Err(c.err(k(&format!("source.{key}")), format!("{t:?}"), "is empty or holds control characters"))
                    }
                    other => Ok(other.clone()),
                }
            };
            let hardware_trigger = name("hardware_trigger", &s.hardware_trigger)?;
            if hardware_trigger.is_some() && free_run {
                return Err(c.err(
                    k("trigger"),
                    "\"free-run\"",
                    "does not go with source.hardware_trigger: with a hardware trigger every frame the camera sends is an acquisition; leave trigger unset",
                ));
            }
            SourceConfig::Genicam(GenicamSettings {
                device: name("device", &s.device)?,
                exposure_us: s.exposure_us.map(|v| c.real(&k("source.exposure_us"), v, 1.0, 1e8)).transpose()?,
                gain: s.gain.map(|v| c.real(&k("source.gain"), v, -1000.0, 10000.0)).transpose()?,
                pixel_format: name("pixel_format", &s.pixel_format)?,
                hardware_trigger,
                packet_size: s.packet_size.map(|v| c.int(&k("source.packet_size"), v, 576, 16384)).transpose()?,
                timeout: Duration::from_millis(c.int(&k("source.timeout_ms"), s.timeout_ms.unwrap_or(2000), 1, 3_600_000)?),
                free_run,
            })
        }
        other => return Err(c.err(k("source.kind"), format!("{other:?}"), "is not one of \"sim\", \"dir\", \"video\", \"genicam\"")),
    })
}

/// A camera's own job keys, which its `[[camera.job]]` tables default to.
struct JobDefaults {
    kb: Option<KbSource>,
    accept_threshold: f64,
    roi: Option<[usize; 4]>,
    calibration: CalibrationConfig,
}

/// `[[camera.job]]`, each key defaulting to the camera's own; without job tables, the camera's
/// keys are its one job, job 1.
fn jobs_of(
    c: &Check<'_>,
    k: &dyn Fn(&str) -> String,
    rc: &raw::Camera,
    source: &SourceConfig,
    base: &Path,
    own: JobDefaults,
) -> Result<Vec<JobConfig>, ConfigError> {
    let mut jobs: Vec<JobConfig> = Vec::new();
    for (j, rj) in rc.job.iter().enumerate() {
        let jk = |f: &str| k(&format!("job[{j}].{f}"));
        let id: u16 = c.int(&jk("id"), rj.id, 1, 999)?;
        if jobs.iter().any(|o| o.id == id) {
            return Err(c.err(jk("id"), id, "is used by another job of this camera"));
        }
        let kb = match kb_source(c, &jk, rj.kb.as_deref(), rj.kb_from_simulator, source, base)? {
            Some(kb) => kb,
            None => own
                .kb
                .clone()
                .ok_or_else(|| c.err(jk("kb"), "(missing)", "is required: the camera has no kb for its jobs to start from"))?,
        };
        jobs.push(JobConfig {
            id,
            name: rj.name.clone().unwrap_or_else(|| format!("job {id}")),
            kb,
            expected_type: rj.expected_type.map(|t| c.int(&jk("expected_type"), t, 0, 65535)).transpose()?,
            accept_threshold: rj
                .accept_threshold
                .map(|t| c.real(&jk("accept_threshold"), t, 0.0, 1.0))
                .transpose()?
                .unwrap_or(own.accept_threshold),
            roi: roi_of(c, &jk, rj.roi.as_deref(), source)?.or(own.roi),
            calibration: calibration_of(c, &jk, rj.calibration.as_ref(), rj.mm_per_px, base)?.unwrap_or_else(|| own.calibration.clone()),
        });
    }
    if jobs.is_empty() {
        let kb = own.kb.ok_or_else(|| c.err(k("kb"), "(missing)", "is required (or kb_from_simulator = true with a sim source)"))?;
        let JobDefaults { accept_threshold, roi, calibration, .. } = own;
        jobs.push(JobConfig { id: 1, name: "job 1".into(), kb, expected_type: None, accept_threshold, roi, calibration });
    }
    Ok(jobs)
}

/// `[camera.robot]`, its keys named by `rk`.
fn robot_of(c: &Check<'_>, rk: &dyn Fn(&str) -> String, r: &raw::Robot, word_order: WordOrder) -> Result<RobotConfig, ConfigError> {
    if let Err(problem) = check_host_port(&r.address) {
        return Err(c.err(rk("address"), format!("{:?}", r.address), problem));
    }
    Ok(RobotConfig {
        address: r.address.clone(),
        unit_id: c.int(&rk("unit_id"), r.unit_id, 0, 255)?,
        input_words_at: c.int(&rk("input_words_at"), r.input_words_at, 0, 65535 - 9)?, // words 0..=9
        output_words_at: c.int(&rk("output_words_at"), r.output_words_at, 0, 65535 - 1)?,
        output_function: c.int(&rk("output_function"), r.output_function, 3, 4)?,
        poll: Duration::from_millis(c.int(&rk("poll_ms"), r.poll_ms, 1, 60_000)?),
        ack_timeout: Duration::from_secs_f64(c.real(&rk("ack_timeout_s"), r.ack_timeout_s, 0.05, 86400.0)?),
        send: r.send,
        queue_depth: c.int(&rk("queue_depth"), r.queue_depth, 1, 10_000)?,
        word_order,
    })
}

/// A knowledge base from `kb` (a file, relative to the configuration's folder) or
/// `kb_from_simulator` (a simulated camera's own templates); None when neither is given.
fn kb_source(
    c: &Check<'_>,
    k: &dyn Fn(&str) -> String,
    kb: Option<&str>,
    from_simulator: bool,
    source: &SourceConfig,
    base: &Path,
) -> Result<Option<KbSource>, ConfigError> {
    Ok(match (kb, from_simulator) {
        (Some(_), true) => return Err(c.err(k("kb_from_simulator"), true, "cannot be combined with kb")),
        (Some(p), false) => Some(KbSource::File(base.join(p))),
        (None, true) => {
            if !matches!(source, SourceConfig::Sim { .. }) {
                return Err(c.err(k("kb_from_simulator"), true, "needs source.kind = \"sim\""));
            }
            Some(KbSource::Simulator)
        }
        (None, false) => None,
    })
}

/// A region of interest `[x, y, width, height]`; a simulated camera's must fit its frame.
fn roi_of(c: &Check<'_>, k: &dyn Fn(&str) -> String, v: Option<&[i64]>, source: &SourceConfig) -> Result<Option<[usize; 4]>, ConfigError> {
    let Some(v) = v else { return Ok(None) };
    if v.len() != 4 || v.iter().any(|&x| x < 0) || v[2] < 32 || v[3] < 32 {
        return Err(c.err(k("roi"), format!("{v:?}"), "must be [x, y, width, height] with width and height >= 32"));
    }
    let roi = [v[0] as usize, v[1] as usize, v[2] as usize, v[3] as usize];
    // A simulated camera's frame size is known now; a real one's only at the first frame (a
    // misfit there is a frame error naming the ROI and the frame).
    if let SourceConfig::Sim { width, height, .. } = source
        && (roi[0].saturating_add(roi[2]) > *width || roi[1].saturating_add(roi[3]) > *height)
    {
        return Err(c.err(k("roi"), format!("{v:?}"), format!("reaches past the simulated {width} x {height} frame")));
    }
    Ok(Some(roi))
}

/// `mm_per_px` or a `calibration` table (point pairs, with or without a plate file); None when
/// neither is given.
fn calibration_of(
    c: &Check<'_>,
    k: &dyn Fn(&str) -> String,
    cal: Option<&raw::Calibration>,
    mm_per_px: Option<f64>,
    base: &Path,
) -> Result<Option<CalibrationConfig>, ConfigError> {
    Ok(match (cal, mm_per_px) {
        (Some(_), Some(v)) => return Err(c.err(k("mm_per_px"), v, format!("cannot be combined with [{}]", k("calibration")))),
        (Some(cal), None) => {
            let least = if cal.file.is_some() { 3 } else { 4 };
            if cal.points.len() < least {
                let what = if cal.file.is_some() {
                    "needs at least 3 [x_px, y_px, x_mm, y_mm] pairs touched up with the robot to place the plate calibration in the robot frame"
                } else {
                    "needs at least 4 [x_px, y_px, x_mm, y_mm] pairs"
                };
                return Err(c.err(k("calibration.points"), format!("{} pairs", cal.points.len()), what));
            }
            let mut pts = Vec::new();
            for (j, p) in cal.points.iter().enumerate() {
                if p.len() != 4 || p.iter().any(|v| !v.is_finite()) {
                    return Err(c.err(k(&format!("calibration.points[{j}]")), format!("{p:?}"), "must be [x_px, y_px, x_mm, y_mm]"));
                }
                pts.push([p[0], p[1], p[2], p[3]]);
            }
            match &cal.file {
                None => {
                    if let Some(f) = &cal.fit {
                        return Err(c.err(
                            k("calibration.fit"),
                            format!("{f:?}"),
                            "only applies with calibration.file (a plate calibration)",
                        ));
                    }
                    if let Some(v) = cal.max_point_error_mm {
                        return Err(c.err(
                            k("calibration.max_point_error_mm"),
                            v,
                            "only applies with calibration.file (a plate calibration)",
                        ));
                    }
                    Some(CalibrationConfig::Points(pts))
                }
                Some(file) => {
                    let scaled = match cal.fit.as_deref().unwrap_or("similarity") {
                        "similarity" => true,
                        "rigid" => false,
                        other => return Err(c.err(k("calibration.fit"), format!("{other:?}"), "must be \"similarity\" or \"rigid\"")),
                    };
                    let max_point_error_mm =
                        c.real(&k("calibration.max_point_error_mm"), cal.max_point_error_mm.unwrap_or(0.5), 0.001, 100.0)?;
                    Some(CalibrationConfig::Plate { file: base.join(file), points: pts, scaled, max_point_error_mm })
                }
            }
        }
        (None, Some(s)) => Some(CalibrationConfig::Scale { mm_per_px: c.real(&k("mm_per_px"), s, 1e-6, 1e6)? }),
        (None, None) => None,
    })
}

/// A robot controller's address as the link dials it: `host:port` (a name or an IPv4 address)
/// or `[v6]:port`. Checked at start-up so a missing port is not first noticed as a connection
/// that never comes up (the standard Modbus port is not assumed: FANUC cells often move it).
fn check_host_port(address: &str) -> Result<(), &'static str> {
    if address.trim().is_empty() {
        return Err("is empty");
    }
    let Some((host, port)) = address.rsplit_once(':') else { return Err("has no port: write host:port (Modbus/TCP is usually 502)") };
    if host.is_empty() || host.chars().any(char::is_whitespace) {
        return Err("has no host before the port (host:port)");
    }
    if host.contains(':') && !(host.starts_with('[') && host.ends_with(']')) {
        return Err("is an IPv6 address without brackets or without a port: write [addr]:port");
    }
    match port.parse::<u16>() {
        Ok(p) if p > 0 => Ok(()),
        _ => Err("has a port that is not a number in 1..=65535"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_robot_gets_accepted_parts_and_rejects_only_when_it_asked_for_all() {
        assert!(RobotSend::Accepted.wants(true) && !RobotSend::Accepted.wants(false));
        assert!(RobotSend::All.wants(true) && RobotSend::All.wants(false));
    }

    const MIN: &str = "[[camera]]\nunit_id = 1\nkb_from_simulator = true\n[camera.source]\nkind = \"sim\"\n";

    fn err(text: &str) -> String {
        Config::from_toml(text, Path::new("/etc/lfi/x.toml")).unwrap_err().to_string()
    }

    #[test]
    fn a_plate_calibration_takes_its_file_beside_the_config_and_three_touch_ups() {
        let pts = "points = [[0, 0, 0, 0], [100, 0, 10, 0], [0, 100, 0, 10]]\n";
        let text = format!("{MIN}[camera.calibration]\nfile = \"cal/plate.toml\"\n{pts}fit = \"rigid\"\nmax_point_error_mm = 0.2\n");
        let c = Config::from_toml(&text, Path::new("/etc/lfi/x.toml")).unwrap();
        match &c.cameras[0].jobs[0].calibration {
            CalibrationConfig::Plate { file, points, scaled, max_point_error_mm } => {
                assert_eq!(file, Path::new("/etc/lfi/cal/plate.toml"));
                assert_eq!((points.len(), *scaled, *max_point_error_mm), (3, false, 0.2));
            }
            other => panic!("{other:?}"),
        }
        let e = err(&format!("{MIN}[camera.calibration]\nfile = \"p.toml\"\n{pts}fit = \"affine\"\n"));
        assert!(e.contains("calibration.fit") && e.contains("affine"), "{e}");
        let e = err(&format!("{MIN}[camera.calibration]\nfile = \"p.toml\"\npoints = [[0, 0, 0, 0]]\n"));
        assert!(e.contains("at least 3"), "{e}");
        let e = err(&format!("{MIN}[camera.calibration]\n{pts}fit = \"rigid\"\n"));
        assert!(e.contains("at least 4"), "a homography still needs four: {e}");
        let four = "points = [[0, 0, 0, 0], [100, 0, 10, 0], [0, 100, 0, 10], [100, 100, 10, 10]]\n";
        let e = err(&format!("{MIN}[camera.calibration]\n{four}fit = \"rigid\"\n"));
        assert!(e.contains("only applies with calibration.file"), "{e}");
        let e = err(&format!("{MIN}[camera.calibration]\nfile = \"p.toml\"\n{pts}max_point_error_mm = -1\n"));
        assert!(e.contains("max_point_error_mm"), "{e}");
    }

    #[test]
    fn defaults_fill_a_minimal_file() {
        let c = Config::from_toml(MIN, Path::new("x.toml")).unwrap();
        assert_eq!(c.modbus.bind.to_string(), "127.0.0.1:1502");
        assert_eq!(c.modbus.max_connections, 64);
        assert_eq!(c.queue_depth, 8);
        assert_eq!(c.cameras[0].trigger, Trigger::Modbus);
        assert!(c.cameras[0].online);
        assert_eq!(c.cameras[0].word_order, WordOrder::HighFirst);
    }

    #[test]
    fn the_shipped_configurations_are_valid() {
        for name in ["demo.toml", "production.toml"] {
            let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("config").join(name);
            let c = Config::load(&path).unwrap_or_else(|e| panic!("{name}: {e}"));
            assert!(!c.cameras.is_empty());
        }
        let demo = Config::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("config/demo.toml")).unwrap();
        assert_eq!(demo.modbus.bind.to_string(), "127.0.0.1:1502");
        assert_eq!(demo.cameras[0].start().kb, KbSource::Simulator);
        assert_eq!(demo.cameras[0].trigger, Trigger::Modbus);
        assert_eq!(demo.queue_depth, 8);
    }

    #[test]
    fn opcua_is_off_by_default_and_its_errors_name_the_key() {
        let c = Config::from_toml(MIN, Path::new("/etc/lfi/x.toml")).unwrap();
        assert!(c.opcua.is_none());
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("pw"), "long-enough\nignored\n").unwrap();
        let text = format!("[opcua]\nenabled = true\npki_dir = \"pki\"\n[[opcua.users]]\nname = \"mes\"\npassword_file = \"pw\"\n{MIN}");
        let c = Config::from_toml(&text, &dir.path().join("x.toml")).unwrap();
        let o = c.opcua.expect("enabled");
        assert_eq!(o.bind, "127.0.0.1:4840".parse().unwrap());
        assert_eq!(o.pki_dir, dir.path().join("pki"));
        assert!(o.allow_anonymous_read && o.max_sessions >= 24);
        assert_eq!((o.users[0].name.as_str(), o.users[0].password.as_str()), ("mes", "long-enough"));
        assert!(!format!("{:?}", o.users[0]).contains("long-enough"), "a password in a log line");
        let e = err(&format!("[opcua]\nenabled = true\n[[opcua.users]]\nname = \"mes\"\npassword_file = \"nowhere.pw\"\n{MIN}"));
        assert!(e.contains("opcua.users[0].password_file") && e.contains("/etc/lfi/nowhere.pw"), "{e}");
        let e = err(&format!("[opcua]\nenabled = true\nmax_sessions = 4\n{MIN}"));
        assert!(e.contains("opcua.max_sessions = 4") && e.contains("24..="), "{e}");
        assert_eq!(o.results_kept, 100);
        let e = err(&format!("[opcua]\nenabled = true\nresults_kept = 0\n{MIN}"));
        assert!(e.contains("opcua.results_kept = 0") && e.contains("1..="), "{e}");
        let e = err(&format!("[http]\nbind = \"0.0.0.0:4840\"\n[opcua]\nenabled = true\n{MIN}"));
        assert!(e.contains("opcua.bind") && e.contains("operator view"), "{e}");
    }

    #[test]
    fn errors_name_file_key_and_value() {
        let e = err(&format!("{MIN}bogus = 1\n"));
        assert!(e.contains("/etc/lfi/x.toml") && e.contains("bogus"), "{e}");
        let e = err(&MIN.replace("unit_id = 1", "unit_id = 300"));
        assert!(e.contains("camera[0].unit_id = 300") && e.contains("1..=247"), "{e}");
        let e = err(&format!("[modbus]\nmax_connections = 0\n{MIN}"));
        assert!(e.contains("modbus.max_connections = 0"), "{e}");
        let e = err(&format!("[modbus]\nwrite_allow = [\"10.0.0.300\"]\n{MIN}"));
        assert!(e.contains("modbus.write_allow[0]") && e.contains("10.0.0.300"), "{e}");
        let e = err(&format!("[result]\nqueue_depth = -1\n{MIN}"));
        assert!(e.contains("result.queue_depth = -1"), "{e}");
        let e = err(&MIN.replace("kind = \"sim\"", "kind = \"webcam\""));
        assert!(e.contains("camera[0].source.kind = \"webcam\""), "{e}");
        let e = err(&MIN.replace("kind = \"sim\"", "kind = \"dir\""));
        assert!(e.contains("camera[0].source.path"), "{e}");
        let e = err(&format!("{MIN}path = \"/x\"\n"));
        assert!(e.contains("source.path") && e.contains("does not apply"), "{e}");
        let e = err(&format!("{}\n[[camera]]\nunit_id = 1\nkb = \"k.toml\"\n[camera.source]\nkind = \"sim\"\n", MIN));
        assert!(e.contains("camera[1].unit_id = 1") && e.contains("another camera"), "{e}");
        let e = err("[modbus]\nbind = \"nowhere\"\n");
        assert!(e.contains("modbus.bind"), "{e}");
        let e = err(&format!("{MIN}[camera.calibration]\npoints = [[0, 0, 0, 0]]\n"));
        assert!(e.contains("calibration.points") && e.contains("at least 4"), "{e}");
    }

    #[test]
    fn a_genicam_source_takes_its_keys_and_a_hardware_trigger_makes_frames_the_acquisitions() {
        let cam = |trigger: &str, src: &str| {
            format!("[[camera]]\nunit_id = 1\nkb = \"kb.toml\"\n{trigger}[camera.source]\nkind = \"genicam\"\n{src}")
        };
        let c = Config::from_toml(
            &cam("", "device = \"Basler-123\"\nexposure_us = 8000\ngain = 2.5\npixel_format = \"Mono12\"\npacket_size = 9000\ntimeout_ms = 1500\n"),
            Path::new("x.toml"),
        )
        .unwrap();
        let SourceConfig::Genicam(g) = &c.cameras[0].source else { panic!("genicam") };
        assert_eq!(
            (g.device.as_deref(), g.exposure_us, g.gain, g.pixel_format.as_deref(), g.packet_size, g.timeout, g.free_run),
            (Some("Basler-123"), Some(8000.0), Some(2.5), Some("Mono12"), Some(9000), Duration::from_millis(1500), false)
        );
        assert_eq!(c.cameras[0].trigger, Trigger::Modbus, "software trigger from the PLC's TRIGGER");
        let hw = Config::from_toml(&cam("", "hardware_trigger = \"Line0\"\n"), Path::new("x.toml")).unwrap();
        assert_eq!(hw.cameras[0].trigger, Trigger::FreeRun, "every frame the camera sends is an acquisition");
        let free = Config::from_toml(&cam("trigger = \"free-run\"\n", ""), Path::new("x.toml")).unwrap();
        assert!(matches!(&free.cameras[0].source, SourceConfig::Genicam(g) if g.free_run && g.timeout == Duration::from_millis(2000)));
        for (src, trigger, says) in [
            ("hardware_trigger = \"Line0\"\n", "trigger = \"free-run\"\n", "camera[0].trigger"),
            ("packet_size = 100\n", "", "camera[0].source.packet_size"),
            ("exposure_us = 0\n", "", "camera[0].source.exposure_us"),
            ("device = \"\"\n", "", "camera[0].source.device"),
            ("uri = \"0\"\n", "", "camera[0].source.uri"),
        ] {
            let e = err(&cam(trigger, src));
            assert!(e.contains(says), "{src}: {e}");
        }
    }

    #[test]
    fn a_robot_address_needs_a_port() {
        let with = |addr: &str| format!("{MIN}[camera.robot]\naddress = \"{addr}\"\n");
        for ok in ["10.0.0.5:502", "robot-1.cell:5020", "[fe80::1]:502"] {
            let c = Config::from_toml(&with(ok), Path::new("x.toml")).unwrap();
            assert_eq!(c.cameras[0].robot.as_ref().unwrap().address, ok);
        }
        for (bad, says) in
            [("10.0.0.5", "no port"), ("10.0.0.5:", "port"), (":502", "no host"), ("fe80::1", "IPv6"), ("r:70000", "1..=65535")]
        {
            let e = err(&with(bad));
            assert!(e.contains("camera[0].robot.address") && e.contains(bad) && e.contains(says), "{bad}: {e}");
        }
    }

    #[test]
    fn a_word_that_names_a_choice_is_one_of_its_spellings() {
        let c = Config::from_toml(
            &MIN.replace(
                "unit_id = 1",
                "unit_id = 1\ntrigger = \"free-run\"\nfloat_word_order = \"low-first\"\npicking_order = \"confidence\"",
            ),
            Path::new("x.toml"),
        )
        .unwrap();
        let cam = &c.cameras[0];
        assert_eq!((cam.trigger, cam.word_order, cam.picking_order), (Trigger::FreeRun, WordOrder::LowFirst, PickingOrder::Confidence));
        let c = Config::from_toml(MIN, Path::new("x.toml")).unwrap();
        assert_eq!(
            (c.cameras[0].trigger, c.cameras[0].word_order, c.cameras[0].picking_order),
            (Trigger::Modbus, WordOrder::HighFirst, PickingOrder::XDescending)
        );
        for (key, bad, one_of) in
            [("trigger", "sometimes", "free-run"), ("float_word_order", "middle", "low-first"), ("picking_order", "random", "y-descending")]
        {
            let e = err(&MIN.replace("unit_id = 1", &format!("unit_id = 1\n{key} = \"{bad}\"")));
            assert!(e.contains(bad) && e.contains(one_of) && e.contains("line 3"), "{key}: {e}");
        }
        let e = err(&format!("{MIN}[camera.robot]\naddress = \"r:502\"\nsend = \"some\"\n"));
        assert!(e.contains("some") && e.contains("accepted"), "{e}");
    }

    #[test]
    fn jobs_start_from_the_camera_s_keys_and_change_what_they_name() {
        // Without jobs: job 1, of the camera's own keys.
        let c = Config::from_toml(MIN, Path::new("x.toml")).unwrap();
        let cam = &c.cameras[0];
        assert_eq!((cam.jobs.len(), cam.start_job, cam.start().id, cam.start().kb.clone()), (1, 1, 1, KbSource::Simulator));
        let text = MIN.replace("kb_from_simulator = true", "kb = \"base.toml\"\nmm_per_px = 0.2\nroi = [0, 0, 640, 480]\nstart_job = 7")
            + "[[camera.job]]\nid = 3\n[[camera.job]]\nid = 7\nname = \"big\"\nkb = \"big.toml\"\nexpected_type = 4\naccept_threshold = 0.7\nmm_per_px = 0.4\n";
        let c = Config::from_toml(&text, Path::new("/etc/lfi/x.toml")).unwrap();
        let cam = &c.cameras[0];
        let (j3, j7) = (cam.job(3).unwrap(), cam.job(7).unwrap());
        assert_eq!(cam.start().id, 7);
        assert_eq!(j3.kb, KbSource::File("/etc/lfi/base.toml".into()), "a job starts from the camera's kb");
        assert_eq!((j3.name.as_str(), j3.expected_type, j3.accept_threshold, j3.roi), ("job 3", None, 0.5, Some([0, 0, 640, 480])));
        assert_eq!(j3.calibration, CalibrationConfig::Scale { mm_per_px: 0.2 });
        assert_eq!(j7.kb, KbSource::File("/etc/lfi/big.toml".into()));
        assert_eq!((j7.name.as_str(), j7.expected_type, j7.accept_threshold), ("big", Some(4), 0.7));
        assert_eq!(j7.calibration, CalibrationConfig::Scale { mm_per_px: 0.4 });
        // Without start_job, the lowest id.
        let c = Config::from_toml(&text.replace("start_job = 7", ""), Path::new("x.toml")).unwrap();
        assert_eq!(c.cameras[0].start().id, 3);
        for (bad, says) in [
            (text.replace("id = 3", "id = 1000"), "camera[0].job[0].id = 1000"),
            (text.replace("id = 3", "id = 7"), "camera[0].job[1].id = 7 is used by another job"),
            (text.replace("start_job = 7", "start_job = 8"), "camera[0].start_job = 8 is not a configured job (jobs: 3, 7)"),
            (text.replace("expected_type = 4", "expected_type = -1"), "camera[0].job[1].expected_type = -1"),
            (text.replace("accept_threshold = 0.7", "accept_threshold = 1.5"), "camera[0].job[1].accept_threshold = 1.5"),
            (text.replace("kb = \"base.toml\"\n", ""), "camera[0].job[0].kb = (missing) is required"),
            (text.replace("name = \"big\"", "colour = 1"), "colour"),
        ] {
            let e = err(&bad);
            assert!(e.contains(says), "{says}: {e}");
        }
    }

    #[test]
    fn an_archive_has_a_folder_a_choice_of_frames_and_limits() {
        let with = |body: &str| format!("{MIN}[camera.archive]\n{body}\n");
        let c = Config::from_toml(&with("dir = \"frames\""), Path::new("/etc/lfi/x.toml")).unwrap();
        let a = c.cameras[0].archive.as_ref().unwrap();
        assert_eq!(a.dir, Path::new("/etc/lfi/frames"), "relative to the configuration file");
        assert_eq!((a.save, a.max_files, a.max_bytes), (ArchiveSave::Rejects, 1000, 2_000_000_000));
        let c = Config::from_toml(&with("dir = \"f\"\nsave = \"all\"\nmax_files = 5\nmax_mb = 1.5"), Path::new("x.toml")).unwrap();
        let a = c.cameras[0].archive.as_ref().unwrap();
        assert_eq!((a.save, a.max_files, a.max_bytes), (ArchiveSave::All, 5, 1_500_000));
        let e = err(&with("dir = \"f\"\nsave = \"some\""));
        assert!(e.contains("some") && e.contains("rejects"), "{e}");
        let e = err(&with("dir = \"f\"\nmax_files = 0"));
        assert!(e.contains("camera[0].archive.max_files = 0"), "{e}");
        let e = err(&with("dir = \" \""));
        assert!(e.contains("camera[0].archive.dir"), "{e}");
        assert!(err(&with("save = \"all\"")).contains("dir"), "dir is required");
    }

    #[test]
    fn a_roi_must_fit_a_simulated_frame() {
        let text = MIN.replace("kind = \"sim\"", "kind = \"sim\"\nwidth = 640\nheight = 480");
        let roi = |r: &str| text.replace("kb_from_simulator = true", &format!("kb_from_simulator = true\nroi = {r}"));
        assert!(Config::from_toml(&roi("[0, 0, 640, 480]"), Path::new("x.toml")).is_ok());
        let e = err(&roi("[600, 0, 100, 100]"));
        assert!(e.contains("camera[0].roi") && e.contains("640 x 480"), "{e}");
    }
}
