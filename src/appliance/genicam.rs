//! GigE Vision and USB3 Vision cameras through Aravis: the camera as a first-class source, its
//! frames handed to the estimator without an encode or decode.
//!
//! The source owns the camera and its stream. It applies the configured features at every
//! connection (a power-cycled camera forgets them), names a feature the camera lacks or a value
//! it refuses together with what it allows, and reconnects with back-off when the camera is lost
//! (Aravis reports the control channel lost, or a prober thread gets no answer). Which pixels become which gray level is [`to_gray`], a pure function.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use aravis::glib::prelude::*;
use aravis::prelude::*;
use aravis::{Camera, PixelFormat, Stream};

use super::source::{Frame, Source, SourceError};
use crate::config::GenicamSettings;
use crate::vision::GrayImage;

/// Buffers queued in the stream: enough to ride out an estimate at a hardware trigger's pace.
const BUFFERS: usize = 8;
/// First wait before reconnecting a lost camera; doubled after each failure up to [`BACKOFF_MAX`].
const BACKOFF_MIN: Duration = Duration::from_millis(500);
/// Longest wait between reconnection attempts.
const BACKOFF_MAX: Duration = Duration::from_secs(5);
/// How often a prober thread asks the camera a register. Aravis's own heartbeat reports a lost
/// GigE camera only after several seconds and a failing read blocks for GVCP's retries (2.5 s);
/// the PLC must know within `timeout_ms` + 1 s.
const PROBE_EVERY: Duration = Duration::from_millis(200);
/// A camera that has not answered a probe for this long is lost.
const ANSWER_WITHIN: Duration = Duration::from_millis(1000);

/// What is known of the camera, for the log, the page and `/metrics`.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct CameraInfo {
    /// Model name.
    pub model: String,
    /// Serial number.
    pub serial: String,
    /// Pixel format in use.
    pub pixel_format: String,
    /// Frame width, pixels.
    pub width: i32,
    /// Frame height, pixels.
    pub height: i32,
    /// Exposure read back from the camera, microseconds (None: it has no exposure feature).
    pub exposure_us: Option<f64>,
    /// The frame trigger read back from the camera: "Off" (free-running) or "On, <source>".
    pub trigger: String,
}

/// Counters of one camera, shared with the operator view and `/metrics`.
#[derive(Debug, Default)]
pub struct GenicamStats {
    /// Complete frames received.
    pub received: AtomicU64,
    /// Complete frames dropped in free-run because a newer one was there.
    pub dropped: AtomicU64,
    /// Incomplete or corrupt buffers (missing packets, wrong size, unsupported payload).
    pub incomplete: AtomicU64,
    /// Successful reconnections after a loss.
    pub reconnects: AtomicU64,
    /// The last software trigger's time to its frame in memory (converted), microseconds.
    pub last_grab_us: AtomicU64,
    /// The camera as last connected (None: never connected).
    pub info: Mutex<Option<CameraInfo>>,
}

struct Connection {
    camera: Camera,
    stream: Stream,
    /// Set by Aravis's `control-lost` signal (cable pulled, power cycle).
    lost: Arc<AtomicBool>,
    /// When the camera last answered a probe (milliseconds since `since`).
    answered_ms: Arc<AtomicU64>,
    since: Instant,
    /// Tells the prober thread to end.
    stop_probe: Arc<AtomicBool>,
}

impl Connection {
    /// Why the camera counts as lost: by Aravis's word, or silent beyond [`ANSWER_WITHIN`].
    fn loss(&self) -> Option<String> {
        let silent = self.since.elapsed().saturating_sub(Duration::from_millis(self.answered_ms.load(Ordering::SeqCst)));
        if self.lost.load(Ordering::SeqCst) {
            Some("control channel lost".into())
        } else if silent >= ANSWER_WITHIN {
            Some(format!("no answer for {} ms", ANSWER_WITHIN.as_millis()))
        } else {
            None
        }
    }
}

/// How frames are started, from the settings (the configuration refuses a hardware trigger
/// with free-run).
#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode<'a> {
    /// One software trigger per PLC trigger.
    Software,
    /// Streaming; the newest frame is taken.
    FreeRun,
    /// Fired on this line; every frame is taken.
    Hardware(&'a str),
}

impl GenicamSettings {
    fn mode(&self) -> Mode<'_> {
        match (&self.hardware_trigger, self.free_run) {
            (Some(line), _) => Mode::Hardware(line),
            (None, true) => Mode::FreeRun,
            (None, false) => Mode::Software,
        }
    }
}

/// Reads a register of `camera` every [`PROBE_EVERY`] and stamps each answer, until `stop`.
fn probe(camera: Camera, answered_ms: Arc<AtomicU64>, since: Instant, stop: Arc<AtomicBool>) {
    while !stop.load(Ordering::SeqCst) {
        if camera.integer("Width").is_ok() {
            answered_ms.store(since.elapsed().as_millis() as u64, Ordering::SeqCst);
        }
        std::thread::sleep(PROBE_EVERY);
    }
}

/// Why [`GenicamSource::pop`] returned no frame.
enum Popped {
    /// The one frame awaited came incomplete.
    Incomplete,
    /// Timeout, a lost camera, an unusable frame.
    Failed(SourceError),
}

/// A GenICam camera through Aravis.
pub struct GenicamSource {
    name: String,
    settings: GenicamSettings,
    conn: Option<Connection>,
    retry_at: Instant,
    backoff: Duration,
    ever_connected: bool,
    stats: Arc<GenicamStats>,
}

/// Aravis's device list (which opening a camera updates too) is global state: one caller at a
/// time.
static DEVICE_LIST: Mutex<()> = Mutex::new(());

/// The Aravis device ids of the cameras found now.
pub fn cameras_found() -> Vec<String> {
    let _guard = DEVICE_LIST.lock().unwrap_or_else(|p| p.into_inner());
    // SAFETY: the device list is only read under DEVICE_LIST, here.
    let list = unsafe { aravis::get_device_list() };
    list.iter().map(|d| d.id.to_string_lossy().into_owned()).collect()
}

impl GenicamSource {
    /// A source for camera `name` (for the log). It connects now if it can; a camera not
    /// found starts the appliance anyway with CAMERA_OK = 0 and is looked for again.
    pub fn new(name: &str, settings: GenicamSettings) -> Self {
        let mut s = Self {
            name: name.to_string(),
            settings,
            conn: None,
            retry_at: Instant::now(),
            backoff: BACKOFF_MIN,
            ever_connected: false,
            stats: Arc::new(GenicamStats::default()),
        };
        s.maintain();
        s
    }

    /// The counters, shared.
    pub fn stats(&self) -> Arc<GenicamStats> {
        self.stats.clone()
    }

    fn connect(&mut self) -> Result<Connection, String> {
        let s = &self.settings;
        let opened = {
            let _guard = DEVICE_LIST.lock().unwrap_or_else(|p| p.into_inner());
            Camera::new(s.device.as_deref())
        };
        let camera = opened.map_err(|e| {
            let found = cameras_found();
            let wanted = s.device.as_deref().unwrap_or("(the only camera)");
            format!("camera {wanted} not found ({e}); cameras found: {}", if found.is_empty() { "none".into() } else { found.join(", ") })
        })?;
        let warn = |what: &str, e: &dyn std::fmt::Display| tracing::warn!(camera = %self.name, "{what}: {e}");
        if let Some(fmt) = &s.pixel_format
            && let Err(e) = camera.set_pixel_format_from_string(fmt)
        {
            let allowed = camera.dup_available_pixel_formats_as_strings().map(|v| v.join(", ")).unwrap_or_default();
            warn(&format!("pixel_format = {fmt:?} refused (the camera offers {allowed})"), &e);
        }
        if let Some(us) = s.exposure_us {
            match camera.is_exposure_time_available() {
                Ok(true) => {
                    if let Err(e) = camera.set_exposure_time(us) {
                        let b = camera.exposure_time_bounds().map(|(lo, hi)| format!("{lo}..{hi} us")).unwrap_or_default();
                        warn(&format!("exposure_us = {us} refused (the camera allows {b})"), &e);
                    }
                }
                _ => warn(&format!("exposure_us = {us} not applied"), &"the camera has neither ExposureTime nor ExposureTimeAbs"),
            }
        }
        if let Some(g) = s.gain {
            match camera.is_gain_available() {
                Ok(true) => {
                    if let Err(e) = camera.set_gain(g) {
                        let b = camera.gain_bounds().map(|(lo, hi)| format!("{lo}..{hi}")).unwrap_or_default();
                        warn(&format!("gain = {g} refused (the camera allows {b})"), &e);
                    }
                }
                _ => warn(&format!("gain = {g} not applied"), &"the camera has neither Gain nor GainRaw"),
            }
        }
        if let Some(size) = s.packet_size
            && camera.is_gv_device()
            && let Err(e) = camera.gv_set_packet_size(size as i32)
        {
            warn(&format!("packet_size = {size} refused"), &e);
        }
        let trigger = match s.mode() {
            Mode::Hardware(line) => camera.set_trigger(line).map_err(|e| {
                let lines = camera.dup_available_trigger_sources().map(|v| v.join(", ")).unwrap_or_default();
                format!("hardware_trigger = {line:?} refused (trigger sources: {lines}): {e}")
            }),
            Mode::FreeRun => camera
                .clear_triggers()
                .and_then(|_| camera.set_acquisition_mode(aravis::AcquisitionMode::Continuous))
                .map_err(|e| format!("free-run: {e}")),
            Mode::Software => camera.set_trigger("Software").map_err(|e| format!("software trigger refused: {e}")),
        };
        trigger?;
        let payload = camera.payload().map_err(|e| format!("payload size: {e}"))? as usize;
        if camera.is_gv_device() && self.on_loopback(&camera) {
            // Aravis's packet socket (the fast path on a real NIC) receives nothing on loopback.
            camera.gv_set_stream_options(aravis::GvStreamOption::PACKET_SOCKET_DISABLED);
        }
        let stream = camera.create_stream().map_err(|e| format!("cannot open the stream: {e}"))?;
        if let Some(gv) = stream.downcast_ref::<aravis::GvStream>() {
            // The kernel's default receive buffer holds a fraction of a 5-MP frame: size it to one.
            gv.set_socket_buffer(aravis::GvStreamSocketBuffer::Auto);
        }
        for _ in 0..BUFFERS {
            stream.push_buffer(aravis::Buffer::new_allocate(payload));
        }
        let lost = Arc::new(AtomicBool::new(false));
        if let Some(device) = camera.device() {
            let flag = lost.clone();
            device.connect_control_lost(move |_| flag.store(true, Ordering::SeqCst));
        }
        camera.start_acquisition().map_err(|e| format!("cannot start the acquisition: {e}"))?;
        let (_, _, width, height) = camera.region().unwrap_or_default();
        let info = CameraInfo {
            model: camera.model_name().map(|m| m.to_string()).unwrap_or_default(),
            serial: camera.device_serial_number().map(|m| m.to_string()).unwrap_or_default(),
            pixel_format: camera.pixel_format_as_string().map(|m| m.to_string()).unwrap_or_default(),
            width,
            height,
            exposure_us: camera.exposure_time().ok(),
            trigger: read_trigger(&camera),
        };
        tracing::info!(
            camera = %self.name,
            "GenICam camera {} serial {} connected: {} {} x {}, exposure {}, trigger {} ({})",
            info.model,
            info.serial,
            info.pixel_format,
            info.width,
            info.height,
            info.exposure_us.map_or("n/a".into(), |e| format!("{e} us")),
            info.trigger,
            match s.mode() {
                Mode::Hardware(l) => format!("hardware trigger on {l}"),
                Mode::FreeRun => "free-running".into(),
                Mode::Software => "software trigger".into(),
            }
        );
        *self.stats.info.lock().unwrap_or_else(|p| p.into_inner()) = Some(info);
        let (since, answered_ms, stop_probe) = (Instant::now(), Arc::new(AtomicU64::new(0)), Arc::new(AtomicBool::new(false)));
        let (cam, ans, stop) = (camera.clone(), answered_ms.clone(), stop_probe.clone());
        std::thread::Builder::new()
            .name("genicam-probe".into())
            .spawn(move || probe(cam, ans, since, stop))
            .map_err(|e| format!("cannot start the camera's prober: {e}"))?;
        Ok(Connection { camera, stream, lost, answered_ms, since, stop_probe })
    }

    /// Whether the camera answers on a loopback address (Aravis's fake camera in the tests).
    /// Read off the open device: updating Aravis's device list while a stream runs stops it.
    fn on_loopback(&self, camera: &Camera) -> bool {
        use gio::prelude::*;
        camera
            .device()
            .and_then(|d| d.downcast::<aravis::GvDevice>().ok())
            .and_then(|gv| gv.device_address())
            .and_then(|a| a.downcast::<gio::InetSocketAddress>().ok())
            .is_some_and(|a| a.address().is_loopback())
    }

    fn disconnect(&mut self, why: &str) {
        if let Some(c) = self.conn.take() {
            tracing::warn!(camera = %self.name, "GenICam camera lost: {why}; reconnecting");
            c.stop_probe.store(true, Ordering::SeqCst);
            // A dead camera makes each command wait out GVCP's retries (2.5 s): stopping it and
            // letting go of it happen aside, not in the worker.
            let _ = std::thread::Builder::new().name("genicam-release".into()).spawn(move || {
                let _ = c.camera.stop_acquisition();
                drop(c);
            });
        }
        self.retry_at = Instant::now() + self.backoff;
    }

    /// The next buffer within `wait`: the oldest, or the newest with older ones dropped
    /// (`newest`). Incomplete buffers are counted and given back; with `one_frame` (a
    /// software trigger's frame) one ends the wait with [`Popped::Incomplete`].
    fn pop(&mut self, wait: Duration, newest: bool, one_frame: bool) -> Result<Frame, Popped> {
        let Some(c) = &self.conn else { return Err(Popped::Failed(SourceError::Camera(format!("{} is not connected", self.label())))) };
        let until = Instant::now() + wait;
        loop {
            if let Some(why) = c.loss() {
                let label = self.label();
                self.disconnect(&why);
                return Err(Popped::Failed(SourceError::Camera(format!("{label}: camera lost: {why}"))));
            }
            let left = until.saturating_duration_since(Instant::now());
            // Wait in slices, so that a lost camera is seen within one.
            let slice = left.min(Duration::from_millis(100)).as_micros() as u64;
            let Some(mut buffer) = c.stream.timeout_pop_buffer(slice) else {
                if left.is_zero() {
                    return Err(Popped::Failed(SourceError::Timeout(wait.as_millis())));
                }
                continue;
            };
            if newest {
                while let Some(next) = c.stream.try_pop_buffer() {
                    if next.status() == aravis::BufferStatus::Success {
                        self.stats.dropped.fetch_add(1, Ordering::Relaxed);
                        c.stream.push_buffer(std::mem::replace(&mut buffer, next));
                    } else {
                        self.stats.incomplete.fetch_add(1, Ordering::Relaxed);
                        c.stream.push_buffer(next);
                    }
                }
            }
            if buffer.status() != aravis::BufferStatus::Success || buffer.payload_type() != aravis::BufferPayloadType::Image {
                self.stats.incomplete.fetch_add(1, Ordering::Relaxed);
                tracing::debug!(camera = %self.name, "buffer dropped: {:?}", buffer.status());
                c.stream.push_buffer(buffer);
                if one_frame {
                    return Err(Popped::Incomplete);
                }
                continue;
            }
            let (ptr, len) = buffer.data();
            // SAFETY: Aravis owns `len` bytes at `ptr` until the buffer is pushed back below.
            let data = if ptr.is_null() { &[][..] } else { unsafe { std::slice::from_raw_parts(ptr as *const u8, len) } };
            let converted = to_gray(buffer.image_pixel_format(), buffer.image_width(), buffer.image_height(), data);
            let frame_id = buffer.frame_id();
            c.stream.push_buffer(buffer);
            self.stats.received.fetch_add(1, Ordering::Relaxed);
            return match converted {
                Ok(image) => Ok(Frame { image, label: format!("{} frame {frame_id}", self.label()) }),
                Err(e) => Err(Popped::Failed(SourceError::Unusable(format!("{}: {e}", self.label())))),
            };
        }
    }

    fn label(&self) -> String {
        self.settings.device.clone().unwrap_or_else(|| "GenICam camera".into())
    }
}

impl Source for GenicamSource {
    fn grab(&mut self) -> Result<Frame, SourceError> {
        if self.settings.mode() != Mode::Software {
            return self.next(self.settings.timeout);
        }
        // One frame per trigger: a frame that arrives incomplete (packets lost on the wire) is
        // dropped, counted and taken again within the same timeout.
        let started = Instant::now();
        let until = started + self.settings.timeout;
        loop {
            let Some(c) = &self.conn else { return Err(SourceError::Camera(format!("{} is not connected", self.label()))) };
            // Frames left from before this trigger are not its frame.
            while let Some(old) = c.stream.try_pop_buffer() {
                c.stream.push_buffer(old);
            }
            if let Err(e) = c.camera.software_trigger() {
                let label = self.label();
                self.disconnect(&format!("software trigger failed: {e}"));
                return Err(SourceError::Camera(format!("{label}: software trigger failed: {e}")));
            }
            let left = until.saturating_duration_since(Instant::now());
            match self.pop(left, false, true) {
                Ok(frame) => {
                    self.stats.last_grab_us.store(started.elapsed().as_micros() as u64, Ordering::Relaxed);
                    return Ok(frame);
                }
                Err(Popped::Failed(SourceError::Timeout(_))) => return Err(SourceError::Timeout(self.settings.timeout.as_millis())),
                Err(Popped::Failed(e)) => return Err(e),
                Err(Popped::Incomplete) if Instant::now() < until => continue,
                Err(Popped::Incomplete) => return Err(SourceError::Timeout(self.settings.timeout.as_millis())),
            }
        }
    }

    fn next(&mut self, wait: Duration) -> Result<Frame, SourceError> {
        let newest = self.settings.mode() == Mode::FreeRun;
        self.pop(wait, newest, false).map_err(|p| match p {
            Popped::Failed(e) => e,
            Popped::Incomplete => SourceError::Timeout(wait.as_millis()),
        })
    }

    fn ok(&self) -> bool {
        self.conn.as_ref().is_some_and(|c| c.loss().is_none())
    }

    fn maintain(&mut self) {
        if let Some(why) = self.conn.as_ref().and_then(Connection::loss) {
            self.disconnect(&why);
        }
        if self.conn.is_some() || Instant::now() < self.retry_at {
            return;
        }
        match self.connect() {
            Ok(c) => {
                if self.ever_connected {
                    self.stats.reconnects.fetch_add(1, Ordering::Relaxed);
                }
                self.ever_connected = true;
                self.backoff = BACKOFF_MIN;
                self.conn = Some(c);
            }
            Err(e) => {
                tracing::warn!(camera = %self.name, "{e}; trying again in {:.1} s", self.backoff.as_secs_f64());
                self.retry_at = Instant::now() + self.backoff;
                self.backoff = (self.backoff * 2).min(BACKOFF_MAX);
            }
        }
    }
}

impl Drop for GenicamSource {
    fn drop(&mut self) {
        if let Some(c) = &self.conn {
            c.stop_probe.store(true, Ordering::SeqCst);
            let _ = c.camera.stop_acquisition();
        }
    }
}

/// The frame-start trigger as the camera reports it (what the settings made of it, whatever the
/// camera accepted): "Off", or "On, " and the source.
fn read_trigger(camera: &aravis::Camera) -> String {
    // Aravis's set_trigger leaves the selector on FrameStart; clear_triggers turns every one off.
    match (camera.string("TriggerMode"), camera.string("TriggerSource")) {
        (Ok(m), Ok(src)) if m.as_str() == "On" => format!("On, {src}"),
        (Ok(m), _) => m.to_string(),
        (Err(e), _) => format!("unknown ({e})"),
    }
}

/// The gray frame of a buffer's pixels: Mono8 as it is, Mono10/12/16 (16-bit little-endian
/// words) scaled to 8 bits, Bayer and RGB/BGR converted to gray. Rows may carry padding: the
/// payload is `height` rows of `len / height` bytes.
pub fn to_gray(format: PixelFormat, width: i32, height: i32, data: &[u8]) -> Result<GrayImage, String> {
    use opencv::core::{Mat, Mat_AUTO_STEP};
    use opencv::imgproc;
    use opencv::prelude::*;
    let (w, h) = (width.max(0) as usize, height.max(0) as usize);
    if w == 0 || h == 0 {
        return Err(format!("empty frame ({width} x {height})"));
    }
    let bpp = aravis::bits_per_pixel(format) as usize;
    let row = w * bpp.div_ceil(8);
    if !bpp.is_multiple_of(8) {
        return Err(format!(
            "packed pixel format {format:?} ({bpp} bits) is not supported: configure Mono8, Mono10/12/16, Bayer 8 or RGB8"
        ));
    }
    if data.len() < row * h {
        return Err(format!("buffer holds {} bytes; {w} x {h} at {bpp} bits needs {}", data.len(), row * h));
    }
    let stride = data.len() / h;
    let bayer = [
        (PixelFormat::BAYER_RG_8, imgproc::COLOR_BayerBG2GRAY),
        (PixelFormat::BAYER_GB_8, imgproc::COLOR_BayerGR2GRAY),
        (PixelFormat::BAYER_GR_8, imgproc::COLOR_BayerGB2GRAY),
        (PixelFormat::BAYER_BG_8, imgproc::COLOR_BayerRG2GRAY),
    ];
    let rgb = [(PixelFormat::RGB_8_PACKED, imgproc::COLOR_RGB2GRAY), (PixelFormat::BGR_8_PACKED, imgproc::COLOR_BGR2GRAY)];
    let mut out = Vec::with_capacity(w * h);
    if format == PixelFormat::MONO_8 {
        for y in 0..h {
            out.extend_from_slice(&data[y * stride..y * stride + w]);
        }
    } else if let Some(shift) = [(PixelFormat::MONO_10, 2), (PixelFormat::MONO_12, 4), (PixelFormat::MONO_16, 8)]
        .iter()
        .find(|(f, _)| *f == format)
        .map(|(_, s)| *s)
    {
        for y in 0..h {
            let r = &data[y * stride..y * stride + 2 * w];
            out.extend(r.chunks_exact(2).map(|p| (u16::from_le_bytes([p[0], p[1]]) >> shift).min(255) as u8));
        }
    } else if let Some(&(_, code)) = bayer.iter().chain(rgb.iter()).find(|(f, _)| *f == format) {
        let channels = bpp / 8;
        let typ = if channels == 3 { opencv::core::CV_8UC3 } else { opencv::core::CV_8UC1 };
        // SAFETY: `data` outlives `src`, which only reads `h` rows of `stride` bytes from it.
        let src = unsafe {
            Mat::new_rows_cols_with_data_unsafe(
                h as i32,
                w as i32,
                typ,
                data.as_ptr() as *mut std::ffi::c_void,
                if stride == row { Mat_AUTO_STEP } else { stride },
            )
        }
        .map_err(|e| e.to_string())?;
        let mut gray = Mat::default();
        imgproc::cvt_color(&src, &mut gray, code, 0).map_err(|e| e.to_string())?;
        out.extend_from_slice(gray.data_bytes().map_err(|e| e.to_string())?);
    } else {
        return Err(format!("pixel format {format:?} is not supported: configure Mono8, Mono10/12/16, Bayer 8 or RGB8"));
    }
    Ok(GrayImage { data: out, width: w, height: h })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mono8_is_taken_as_it_is_and_padding_dropped() {
        let data: Vec<u8> = vec![1, 2, 3, 0, 4, 5, 6, 0];
        let g = to_gray(PixelFormat::MONO_8, 3, 2, &data).unwrap();
        assert_eq!((g.width, g.height, g.data), (3, 2, vec![1, 2, 3, 4, 5, 6]));
    }

    #[test]
    fn mono12_and_mono16_are_scaled_to_eight_bits() {
        let words = |v: &[u16]| v.iter().flat_map(|x| x.to_le_bytes()).collect::<Vec<u8>>();
        assert_eq!(to_gray(PixelFormat::MONO_12, 2, 1, &words(&[4095, 1024])).unwrap().data, vec![255, 64]);
        assert_eq!(to_gray(PixelFormat::MONO_16, 2, 1, &words(&[65535, 256])).unwrap().data, vec![255, 1]);
    }

    #[test]
    fn colour_becomes_gray_and_unsupported_formats_are_named() {
        let g = to_gray(PixelFormat::RGB_8_PACKED, 2, 1, &[255, 255, 255, 0, 0, 0]).unwrap();
        assert_eq!(g.data, vec![255, 0]);
        let b = to_gray(PixelFormat::BAYER_RG_8, 4, 4, &[128; 16]).unwrap();
        assert!(b.data.iter().all(|&v| (127..=129).contains(&v)), "{:?}", b.data);
        let e = to_gray(PixelFormat::MONO_10_PACKED, 4, 1, &[0; 5]).unwrap_err();
        assert!(e.contains("packed"), "{e}");
        let short = to_gray(PixelFormat::MONO_8, 4, 4, &[0; 10]).unwrap_err();
        assert!(short.contains("needs 16"), "{short}");
    }
}
