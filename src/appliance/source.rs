//! Where frames come from: the simulated camera, a folder a camera writes into, or OpenCV video.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use opencv::prelude::*;
use opencv::videoio;

use crate::imageio;
use crate::sim::{SimConfig, Simulator};
use crate::vision::GrayImage;

/// A frame and where it came from (for logs).
#[derive(Debug, Clone)]
pub struct Frame {
    /// The frame, gray.
    pub image: GrayImage,
    /// Where it came from, for the log and the page.
    pub label: String,
}

/// Why there is no usable frame.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SourceError {
    /// Nothing arrived in time (a camera fault in trigger mode, a quiet spell in free-run).
    #[error("no frame within {0} ms")]
    Timeout(u128),
    /// The camera failed (device gone, stream broken).
    #[error("camera failed: {0}")]
    Camera(String),
    /// A frame arrived but cannot be used (corrupt file, unsupported format).
    #[error("unusable frame: {0}")]
    Unusable(String),
}

impl SourceError {
    /// The ERROR the acquisition raises: a frame that came but cannot be used is the frame's
    /// fault, anything else the camera's.
    pub fn fault(&self) -> crate::handshake::Fault {
        match self {
            SourceError::Unusable(_) => crate::handshake::Fault::Frame,
            SourceError::Timeout(_) | SourceError::Camera(_) => crate::handshake::Fault::Camera,
        }
    }
}

/// A camera.
pub trait Source: Send {
    /// The frame for a trigger, waiting at most the source's timeout.
    fn grab(&mut self) -> Result<Frame, SourceError>;
    /// The next new frame in free-run, waiting at most `wait`.
    fn next(&mut self, wait: Duration) -> Result<Frame, SourceError>;
    /// Whether the camera is currently usable (CAMERA_OK).
    fn ok(&self) -> bool;
    /// Housekeeping between frames (reconnecting a lost camera); called while the worker idles.
    fn maintain(&mut self) {}
}

/// The built-in simulated camera: scenes rendered once at start-up, served in turn.
pub struct SimSource {
    frames: Vec<(GrayImage, String)>,
    next: usize,
    interval: Duration,
    last: Option<Instant>,
}

impl SimSource {
    /// Renders `scenes` scenes of `sim` now (a camera that starts slowly, then serves at once).
    pub fn new(sim: &Simulator, scenes: usize, interval: Duration) -> Result<Self, SourceError> {
        let mut frames = Vec::with_capacity(scenes);
        for i in 0..scenes as u64 {
            let s = sim.scene(i).map_err(|e| SourceError::Camera(e.to_string()))?;
            frames.push((s.image, format!("sim scene {} ({})", i, s.truth.condition)));
        }
        Ok(Self { frames, next: 0, interval, last: None })
    }
    /// The simulator settings a `[camera.source] kind = "sim"` stands for.
    pub fn config(seed: u64, width: usize, height: usize, noise: Option<f64>) -> SimConfig {
        SimConfig { width, height, seed, noise }
    }
}

impl Source for SimSource {
    fn grab(&mut self) -> Result<Frame, SourceError> {
        let (image, label) = self.frames[self.next % self.frames.len()].clone();
        self.next += 1;
        Ok(Frame { image, label })
    }
    fn next(&mut self, wait: Duration) -> Result<Frame, SourceError> {
        if let Some(last) = self.last {
            let due = last + self.interval;
            let now = Instant::now();
            if due > now {
                if due - now > wait {
                    std::thread::sleep(wait);
                    return Err(SourceError::Timeout(wait.as_millis()));
                }
                std::thread::sleep(due - now);
            }
        }
        self.last = Some(Instant::now());
        self.grab()
    }
    fn ok(&self) -> bool {
        true
    }
}

const IMAGE_EXTENSIONS: [&str; 9] = ["png", "bmp", "tif", "tiff", "jpg", "jpeg", "pgm", "ppm", "pnm"];

/// How many settle times a file must stay empty before it is refused as an empty frame.
const EMPTY_SETTLE_FACTOR: u32 = 5;

/// Last (size, mtime) seen of a file, and since when it has been unchanged.
type Seen = (u64, Option<SystemTime>, Instant);

/// A folder the camera's software drops image files into. A file is complete when its size and
/// modification time have not changed for `settle`; each complete file is one frame, then moved
/// to `done/` (or `failed/` when it cannot be decoded), so it is never processed twice.
pub struct DirSource {
    inbox: PathBuf,
    settle: Duration,
    timeout: Duration,
    /// Last (size, mtime) seen per file and since when it has been unchanged.
    watch: HashMap<PathBuf, Seen>,
}

impl DirSource {
    /// A source on the folder `inbox` (`done/` and `failed/` are made inside it as needed).
    pub fn new(inbox: &Path, settle: Duration, timeout: Duration) -> Self {
        Self { inbox: inbox.to_path_buf(), settle, timeout, watch: HashMap::new() }
    }

    /// The oldest complete file, if any, with the reason it can never be a frame when that is
    /// so: a symlink (it may point anywhere, and could change under us), a directory or other
    /// non-file with an image name, or a file that stayed empty (0 bytes for
    /// [`EMPTY_SETTLE_FACTOR`] times the settle time, or at least 1 s, so one the camera has
    /// only created is not taken too early). Those are moved to `failed/` and named as the frame
    /// they stand for, never skipped silently.
    fn scan(&mut self) -> Option<(PathBuf, Option<&'static str>)> {
        let now = Instant::now();
        let Ok(entries) = std::fs::read_dir(&self.inbox) else { return None };
        let mut present = Vec::new();
        let mut refused = None;
        for e in entries.flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().into_owned();
            let ext_ok =
                p.extension().map(|x| x.to_string_lossy().to_ascii_lowercase()).is_some_and(|x| IMAGE_EXTENSIONS.contains(&x.as_str()));
            if name.starts_with('.') || !ext_ok {
                continue;
            }
            // `DirEntry::file_type` does not follow symlinks: a link is seen as a link.
            let Ok(kind) = e.file_type() else { continue };
            if kind.is_symlink() {
                refused.get_or_insert((p, "a symbolic link, not a file the camera wrote"));
                continue;
            }
            if !kind.is_file() {
                refused.get_or_insert((p, if kind.is_dir() { "a directory, not an image file" } else { "not a regular file" }));
                continue;
            }
            let Ok(md) = e.metadata() else { continue };
            let key = (md.len(), md.modified().ok());
            let entry = self.watch.entry(p.clone()).or_insert((key.0, key.1, now));
            if (entry.0, entry.1) != key {
                *entry = (key.0, key.1, now);
            }
            present.push(p);
        }
        self.watch.retain(|p, _| present.contains(p));
        if let Some((p, why)) = refused {
            self.watch.remove(&p);
            return Some((p, Some(why)));
        }
        let empty_settle = (self.settle * EMPTY_SETTLE_FACTOR).max(Duration::from_secs(1));
        let mut complete: Vec<(&PathBuf, &Seen)> = self
            .watch
            .iter()
            .filter(|(_, (size, _, since))| now.duration_since(*since) >= if *size > 0 { self.settle } else { empty_settle })
            .collect();
        complete.sort_by(|a, b| a.1.1.cmp(&b.1.1).then(a.0.cmp(b.0)));
        complete.first().map(|(p, (size, _, _))| ((*p).clone(), (*size == 0).then_some("an empty file (0 bytes)")))
    }

    fn move_to(&self, file: &Path, sub: &str) -> Result<PathBuf, String> {
        let dir = self.inbox.join(sub);
        std::fs::create_dir_all(&dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
        let name = file.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let mut target = dir.join(&name);
        let mut n = 1;
        while target.exists() {
            target = dir.join(format!("{name}.{n}"));
            n += 1;
        }
        std::fs::rename(file, &target).map_err(|e| format!("cannot move {} to {}: {e}", file.display(), target.display()))?;
        Ok(target)
    }

    fn take(&mut self, file: PathBuf, refused: Option<&'static str>) -> Result<Frame, SourceError> {
        self.watch.remove(&file);
        let decoded = match refused {
            Some(why) => Err(format!("{} is {why}", file.display())),
            None => imageio::read_gray(&file).map_err(|e| format!("{e:#}")),
        };
        let (sub, result) = match decoded {
            Ok((image, notes)) => {
                for n in notes {
                    tracing::warn!(file = %file.display(), "{n}");
                }
                ("done", Ok(image))
            }
            Err(e) => ("failed", Err(e)),
        };
        // Moving out of the inbox is what makes "exactly once": a file that cannot be moved
        // would be seen again, so that is a camera fault, not a frame.
        let moved = self.move_to(&file, sub).map_err(SourceError::Camera)?;
        match result {
            Ok(image) => Ok(Frame { image, label: moved.display().to_string() }),
            Err(e) => Err(SourceError::Unusable(format!("{} (moved to {})", e, moved.display()))),
        }
    }

    fn wait_for_file(&mut self, wait: Duration) -> Result<Frame, SourceError> {
        let until = Instant::now() + wait;
        loop {
            if let Some((f, refused)) = self.scan() {
                return self.take(f, refused);
            }
            if !self.inbox.is_dir() {
                return Err(SourceError::Camera(format!("folder {} is missing", self.inbox.display())));
            }
            let now = Instant::now();
            if now >= until {
                return Err(SourceError::Timeout(wait.as_millis()));
            }
            std::thread::sleep((until - now).min(Duration::from_millis(25)));
        }
    }
}

impl Source for DirSource {
    fn grab(&mut self) -> Result<Frame, SourceError> {
        self.wait_for_file(self.timeout)
    }
    fn next(&mut self, wait: Duration) -> Result<Frame, SourceError> {
        self.wait_for_file(wait)
    }
    fn ok(&self) -> bool {
        self.inbox.is_dir()
    }
}

/// OpenCV VideoCapture: "0" (a device index), a file, an RTSP URL or a GStreamer pipeline.
pub struct VideoSource {
    uri: String,
    cap: Option<videoio::VideoCapture>,
    retry_at: Instant,
    timeout: Duration,
    /// Wait before reopening after a failed read (twice this after a failed open).
    retry: Duration,
}

/// How long a video source waits before reopening a stream that failed.
pub const VIDEO_RETRY: Duration = Duration::from_secs(1);

impl VideoSource {
    /// A source on `uri`, opened at the first grab (and reopened after a failure).
    pub fn new(uri: &str, timeout: Duration) -> Self {
        Self::with_retry(uri, timeout, VIDEO_RETRY)
    }

    /// As [`VideoSource::new`], reopening `retry` after a failed read.
    pub fn with_retry(uri: &str, timeout: Duration, retry: Duration) -> Self {
        let mut s = Self { uri: uri.to_string(), cap: None, retry_at: Instant::now(), timeout, retry };
        s.open();
        s
    }

    fn open(&mut self) {
        let opened = match self.uri.trim().parse::<i32>() {
            Ok(index) => videoio::VideoCapture::new(index, videoio::CAP_ANY),
            Err(_) => videoio::VideoCapture::from_file(&self.uri, videoio::CAP_ANY),
        };
        match opened {
            Ok(cap) if cap.is_opened().unwrap_or(false) => {
                tracing::info!(uri = %self.uri, "video source opened");
                self.cap = Some(cap);
            }
            Ok(_) | Err(_) => {
                tracing::warn!(uri = %self.uri, "video source cannot be opened; retrying in {:.1} s", (2 * self.retry).as_secs_f64());
                self.cap = None;
                self.retry_at = Instant::now() + 2 * self.retry;
            }
        }
    }

    fn read(&mut self) -> Result<Frame, SourceError> {
        if self.cap.is_none() && Instant::now() >= self.retry_at {
            self.open();
        }
        let Some(cap) = self.cap.as_mut() else { return Err(SourceError::Camera(format!("{} is not open", self.uri))) };
        let mut m = opencv::core::Mat::default();
        let started = Instant::now();
        let ok = cap.read(&mut m).unwrap_or(false);
        if !ok || m.empty() {
            self.cap = None;
            self.retry_at = Instant::now() + self.retry;
            if started.elapsed() > self.timeout {
                return Err(SourceError::Timeout(self.timeout.as_millis()));
            }
            return Err(SourceError::Camera(format!("{} delivered no frame (end of stream or device error)", self.uri)));
        }
        let (image, _) = GrayImage::from_mat(&m).map_err(|e| SourceError::Unusable(e.to_string()))?;
        Ok(Frame { image, label: self.uri.clone() })
    }
}

impl Source for VideoSource {
    fn grab(&mut self) -> Result<Frame, SourceError> {
        self.read()
    }
    fn next(&mut self, _wait: Duration) -> Result<Frame, SourceError> {
        self.read()
    }
    fn ok(&self) -> bool {
        self.cap.is_some()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_unusable_frame_is_the_frames_fault_and_anything_else_the_cameras() {
        use crate::handshake::Fault;
        assert_eq!(SourceError::Unusable("corrupt".into()).fault(), Fault::Frame);
        assert_eq!(SourceError::Timeout(500).fault(), Fault::Camera);
        assert_eq!(SourceError::Camera("gone".into()).fault(), Fault::Camera);
    }

    #[test]
    fn dir_source_takes_each_complete_file_once_and_files_bad_ones() {
        let dir = tempfile::tempdir().unwrap();
        let mut src = DirSource::new(dir.path(), Duration::from_millis(30), Duration::from_millis(300));
        assert!(matches!(src.grab(), Err(SourceError::Timeout(_))));
        imageio::write_png(&dir.path().join("a.png"), &GrayImage::new(64, 48, 9)).unwrap();
        std::fs::write(dir.path().join("b.png"), b"not a png").unwrap();
        std::fs::write(dir.path().join("notes.txt"), b"ignored").unwrap();
        let mut got = Vec::new();
        for _ in 0..2 {
            got.push(src.grab());
        }
        assert!(matches!(src.grab(), Err(SourceError::Timeout(_))), "nothing is taken twice");
        assert!(got.iter().any(|r| r.as_ref().is_ok_and(|f| f.label.contains("done"))));
        assert!(got.iter().any(|r| matches!(r, Err(SourceError::Unusable(m)) if m.contains("failed"))));
        assert!(dir.path().join("done/a.png").exists() && dir.path().join("failed/b.png").exists());
        assert!(dir.path().join("notes.txt").exists());
    }

    /// An empty file, a symlink and a directory with image names are each one unusable frame
    /// that names the file, moved to `failed/`, never left in the inbox unmentioned.
    #[test]
    fn files_that_can_never_be_frames_are_named_and_moved_aside() {
        let dir = tempfile::tempdir().unwrap();
        let outside = tempfile::tempdir().unwrap();
        let target = outside.path().join("real.png");
        imageio::write_png(&target, &GrayImage::new(64, 48, 9)).unwrap();
        std::os::unix::fs::symlink(&target, dir.path().join("link.png")).unwrap();
        std::fs::create_dir(dir.path().join("d.png")).unwrap();
        std::fs::write(dir.path().join("empty.png"), b"").unwrap();
        let mut src = DirSource::new(dir.path(), Duration::from_millis(20), Duration::from_millis(1500));
        let mut why = Vec::new();
        for _ in 0..3 {
            match src.grab() {
                Err(SourceError::Unusable(m)) => why.push(m),
                other => panic!("expected an unusable frame, got {other:?}"),
            }
        }
        assert!(matches!(src.grab(), Err(SourceError::Timeout(_))), "nothing is taken twice: {why:?}");
        for (name, what) in [("link.png", "symbolic link"), ("d.png", "directory"), ("empty.png", "empty file")] {
            assert!(why.iter().any(|m| m.contains(name) && m.contains(what) && m.contains("failed")), "{name}: {why:?}");
            assert!(dir.path().join("failed").join(name).symlink_metadata().is_ok(), "{name} moved to failed/");
            assert!(dir.path().join(name).symlink_metadata().is_err(), "{name} left the inbox");
        }
        assert!(target.exists(), "a link's target is never touched");
    }

    /// A recorded file stands in for a camera: OpenCV's built-in MJPEG writer needs no codec
    /// package, so this runs wherever libopencv-dev does.
    #[test]
    fn video_source_reads_a_recorded_file_then_reports_its_end() {
        use opencv::{core, prelude::*, videoio};
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("belt.avi");
        let fourcc = videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').unwrap();
        let size = core::Size::new(160, 120);
        let mean_gray = |f: &Frame| f.image.data.iter().map(|&v| v as f64).sum::<f64>() / f.image.data.len() as f64;
        let mut writer =
            videoio::VideoWriter::new_with_backend(file.to_str().unwrap(), videoio::CAP_OPENCV_MJPEG, fourcc, 10.0, size, true).unwrap();
        assert!(writer.is_opened().unwrap(), "OpenCV's MJPEG writer is available");
        let levels = [40.0, 120.0, 200.0];
        for level in levels {
            let frame = core::Mat::new_rows_cols_with_default(size.height, size.width, core::CV_8UC3, core::Scalar::all(level)).unwrap();
            writer.write(&frame).unwrap();
        }
        writer.release().unwrap();

        let retry = Duration::from_millis(200);
        let mut src = VideoSource::with_retry(file.to_str().unwrap(), Duration::from_millis(500), retry);
        assert!(src.ok());
        for level in levels {
            let frame = src.grab().expect("a recorded frame");
            assert_eq!((frame.image.width, frame.image.height), (160, 120), "colour frames arrive as gray at full size");
            let mean = mean_gray(&frame);
            assert!((mean - level).abs() < 4.0, "frame gray {mean:.1} is the recorded {level}");
        }
        let end = src.grab().unwrap_err();
        assert!(matches!(&end, SourceError::Camera(m) if m.contains("belt.avi")), "{end}");
        assert!(!src.ok(), "after the end of the stream the camera is not OK");
        assert!(src.grab().is_err(), "not reopened before the retry delay");
        std::thread::sleep(retry + Duration::from_millis(20));
        let again = src.grab().expect("after the retry delay the file is reopened");
        let mean = mean_gray(&again);
        assert!((mean - levels[0]).abs() < 4.0, "a file replays from its first frame ({mean:.1})");
    }

    #[test]
    fn video_source_that_cannot_open_names_the_uri() {
        let mut src = VideoSource::new("/nonexistent/camera.avi", Duration::from_millis(100));
        assert!(!src.ok());
        let e = src.grab().unwrap_err();
        assert!(e.to_string().contains("/nonexistent/camera.avi"), "{e}");
    }
}
