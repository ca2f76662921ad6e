//! The image archive (`[camera.archive]`): frames kept on disk for whoever asks later why a part
//! was rejected, each an image and a JSON sidecar of the same stem with the frame's final
//! results. A background thread writes them through a bounded queue, so the camera loop never
//! waits for the disk: a frame that finds the queue full is dropped and counted, never waited
//! for. Past `max_files` frames or `max_mb`, the oldest frames are deleted.
//!
//! File names are `<unix ms, 13 digits>-u<unit id>-a<ACQ_ID>.png` and `.json`, so they sort by
//! time and each camera manages only its own files (several may share a folder, and nothing
//! else in it is ever touched).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};

use crate::config::{ArchiveConfig, ArchiveSave};
use crate::handshake::Queued;
use crate::vision::GrayImage;

/// Frames waiting for the disk at most: a few seconds of a fast line, a few hundred MB of
/// 5-MP frames at worst.
pub const QUEUE_DEPTH: usize = 8;

/// What the archive did, for `/metrics` and the page.
#[derive(Debug, Default)]
pub struct Counters {
    /// Frames written (image and sidecar).
    pub saved: AtomicU64,
    /// Frames not archived because the queue was full (the disk is slower than the line).
    pub dropped: AtomicU64,
    /// Frames that could not be written (disk full, folder gone); each is logged.
    pub failed: AtomicU64,
    /// Frames deleted to keep within `max_files` and `max_mb`.
    pub deleted: AtomicU64,
}

/// One frame to keep.
pub struct Item {
    /// The file stem (see [`stem`]).
    pub stem: String,
    /// The frame as estimated.
    pub image: Arc<GrayImage>,
    /// The sidecar's JSON text.
    pub sidecar: String,
}

/// Where a camera's archive is, for reading it back (the operator view's history).
#[derive(Debug, Clone)]
pub struct Shelf {
    /// The archive folder.
    pub dir: PathBuf,
    /// The camera's Modbus unit id (in every file name).
    pub unit_id: u8,
    /// The counters the metrics read.
    pub counters: Arc<Counters>,
}

impl Shelf {
    /// The newest `limit` sidecars, newest first, as the JSON they hold (a sidecar that cannot
    /// be read or parsed is skipped: it may be being deleted).
    pub fn recent(&self, limit: usize) -> std::io::Result<Vec<serde_json::Value>> {
        let mut stems: Vec<String> = std::fs::read_dir(&self.dir)?
            .filter_map(|e| e.ok())
            .filter_map(|e| {
                let name = e.file_name().to_string_lossy().into_owned();
                ours(&name, self.unit_id).filter(|(_, ext)| *ext == "json").map(|(stem, _)| stem.to_string())
            })
            .collect();
        stems.sort_unstable_by(|a, b| b.cmp(a));
        Ok(stems
            .iter()
            .take(limit)
            .filter_map(|s| std::fs::read(self.dir.join(format!("{s}.json"))).ok())
            .filter_map(|b| serde_json::from_slice(&b).ok())
            .collect())
    }

    /// One archived file by name: only files this camera's archive wrote (anything else,
    /// a path included, is None).
    pub fn file(&self, name: &str) -> Option<Vec<u8>> {
        ours(name, self.unit_id)?;
        std::fs::read(self.dir.join(name)).ok()
    }
}

/// A camera's archive: the queue into its writer thread.
pub struct Archive {
    save: ArchiveSave,
    tx: Option<SyncSender<Item>>,
    /// Saved, dropped, failed and deleted frames, shared with the metrics.
    pub counters: Arc<Counters>,
    camera: String,
    unit_id: u8,
    dir: PathBuf,
    thread: Option<std::thread::JoinHandle<()>>,
}

/// The file stem of a frame: sortable by time, and naming the camera and the acquisition.
pub fn stem(unix_ms: u64, unit_id: u8, acq_id: u16) -> String {
    format!("{unix_ms:013}-u{unit_id}-a{acq_id:05}")
}

/// Whether `name` is a file this camera's archive wrote: its stem and extension.
fn ours(name: &str, unit_id: u8) -> Option<(&str, &str)> {
    let (stem, ext) = name.rsplit_once('.')?;
    if ext != "png" && ext != "json" {
        return None;
    }
    let mut it = stem.splitn(3, '-');
    let (ms, unit, acq) = (it.next()?, it.next()?, it.next()?);
    let digits = |s: &str, n: usize| s.len() == n && s.bytes().all(|b| b.is_ascii_digit());
    (digits(ms, 13) && unit == format!("u{unit_id}") && acq.strip_prefix('a').is_some_and(|a| digits(a, 5))).then_some((stem, ext))
}

impl Archive {
    /// Opens the folder (created if missing), counts what this camera kept there before, and
    /// starts the writer. `save = "none"` gives no archive.
    pub fn start(cfg: &ArchiveConfig, camera: &str, unit_id: u8) -> std::io::Result<Option<Self>> {
        if cfg.save == ArchiveSave::None {
            return Ok(None);
        }
        let store = Store::open(&cfg.dir, unit_id, cfg.max_files, cfg.max_bytes)?;
        tracing::info!(
            camera,
            "image archive in {} ({:?}; {} frames, {:.1} MB kept already; limits {} frames, {:.0} MB)",
            cfg.dir.display(),
            cfg.save,
            store.kept.len(),
            store.total as f64 / 1e6,
            cfg.max_files,
            cfg.max_bytes as f64 / 1e6
        );
        let (tx, rx) = std::sync::mpsc::sync_channel(QUEUE_DEPTH);
        let counters = Arc::new(Counters::default());
        let (c, name) = (counters.clone(), camera.to_string());
        let thread = std::thread::Builder::new().name(format!("archive-{unit_id}")).spawn(move || write_all(store, rx, &c, &name))?;
        Ok(Some(Self {
            save: cfg.save,
            tx: Some(tx),
            counters,
            camera: camera.to_string(),
            unit_id,
            dir: cfg.dir.clone(),
            thread: Some(thread),
        }))
    }

    /// Whether a frame with these final results is to be kept: `all` every frame, `rejects`
    /// those with at least one rejected result (a no-part or frame-error result is one).
    pub fn wants(&self, results: &[Queued]) -> bool {
        wants(self.save, results)
    }

    /// The camera's Modbus unit id.
    pub fn unit_id(&self) -> u8 {
        self.unit_id
    }

    /// What the operator view needs to read the archive back.
    pub fn shelf(&self) -> Shelf {
        Shelf { dir: self.dir.clone(), unit_id: self.unit_id, counters: self.counters.clone() }
    }

    /// Hands a frame to the writer without waiting: when the queue is full it is dropped and
    /// counted.
    pub fn offer(&self, item: Item) {
        let Some(tx) = &self.tx else { return };
        match tx.try_send(item) {
            Ok(()) => {}
            Err(TrySendError::Full(item)) | Err(TrySendError::Disconnected(item)) => {
                self.counters.dropped.fetch_add(1, Relaxed);
                tracing::warn!(camera = %self.camera, file = %item.stem, "archive queue full: frame not archived (the disk is slower than the line)");
            }
        }
    }
}

/// Waits for the writer to store what was queued: nothing offered is lost at shutdown.
impl Drop for Archive {
    fn drop(&mut self) {
        self.tx = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// Whether `save` keeps a frame with these results.
pub fn wants(save: ArchiveSave, results: &[Queued]) -> bool {
    match save {
        ArchiveSave::All => true,
        ArchiveSave::Rejects => results.iter().any(|r| !r.part.accepted),
        ArchiveSave::None => false,
    }
}

fn write_all(mut store: Store, rx: Receiver<Item>, counters: &Counters, camera: &str) {
    for item in rx {
        match store.put(&item) {
            Ok(deleted) => {
                counters.saved.fetch_add(1, Relaxed);
                counters.deleted.fetch_add(deleted, Relaxed);
            }
            Err(e) => {
                counters.failed.fetch_add(1, Relaxed);
                tracing::warn!(camera, file = %item.stem, "cannot archive frame: {e}");
            }
        }
    }
}

/// The frames of one camera in the folder, oldest first, and their sizes.
struct Store {
    dir: PathBuf,
    max_files: usize,
    max_bytes: u64,
    kept: VecDeque<(String, u64)>,
    total: u64,
}

impl Store {
    fn open(dir: &Path, unit_id: u8, max_files: usize, max_bytes: u64) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let mut sizes: std::collections::BTreeMap<String, u64> = Default::default();
        for e in std::fs::read_dir(dir)? {
            let e = e?;
            let name = e.file_name().to_string_lossy().into_owned();
            if let Some((stem, _)) = ours(&name, unit_id) {
                let len = e.metadata().map(|m| m.len()).unwrap_or(0);
                *sizes.entry(stem.to_string()).or_default() += len;
            }
        }
        let total = sizes.values().sum();
        let mut s = Self { dir: dir.to_path_buf(), max_files, max_bytes, kept: sizes.into_iter().collect(), total };
        s.prune();
        Ok(s)
    }

    /// Writes a frame (the image first, so a sidecar always has its image) and deletes the
    /// oldest past the limits; returns how many frames were deleted.
    fn put(&mut self, item: &Item) -> Result<u64, String> {
        let png = self.dir.join(format!("{}.png", item.stem));
        let json = self.dir.join(format!("{}.json", item.stem));
        let bytes = crate::imageio::encode_png(&item.image)?;
        crate::imageio::write_atomic(&png, &bytes).map_err(|e| format!("{}: {e}", png.display()))?;
        if let Err(e) = crate::imageio::write_atomic(&json, item.sidecar.as_bytes()) {
            let _ = std::fs::remove_file(&png);
            return Err(format!("{}: {e}", json.display()));
        }
        let size = bytes.len() as u64 + item.sidecar.len() as u64;
        self.kept.push_back((item.stem.clone(), size));
        self.total += size;
        Ok(self.prune())
    }

    fn prune(&mut self) -> u64 {
        let mut deleted = 0;
        while self.kept.len() > self.max_files || (self.total > self.max_bytes && !self.kept.is_empty()) {
            let Some((stem, size)) = self.kept.pop_front() else { break };
            for ext in ["json", "png"] {
                let p = self.dir.join(format!("{stem}.{ext}"));
                if let Err(e) = std::fs::remove_file(&p)
                    && e.kind() != std::io::ErrorKind::NotFound
                {
                    tracing::warn!(file = %p.display(), "cannot delete archived frame: {e}");
                }
            }
            self.total = self.total.saturating_sub(size);
            deleted += 1;
        }
        deleted
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::handshake::PartResult;
    use crate::vision::Reason;

    fn item(ms: u64, acq: u16) -> Item {
        let mut img = GrayImage::new(64, 48, 40);
        img.data[acq as usize % 3000] = 200;
        Item { stem: stem(ms, 2, acq), image: Arc::new(img), sidecar: format!("{{\"acq_id\":{acq}}}") }
    }

    fn files(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
        v.sort();
        v
    }

    #[test]
    fn names_sort_by_time_and_name_their_camera() {
        assert_eq!(stem(1_764_680_000_123, 2, 42), "1764680000123-u2-a00042");
        assert_eq!(ours("1764680000123-u2-a00042.png", 2), Some(("1764680000123-u2-a00042", "png")));
        assert_eq!(ours("1764680000123-u2-a00042.json", 3), None, "another camera's");
        for foreign in ["notes.txt", "1764680000123-u2-a00042.jpg", "123-u2-a00042.png", "1764680000123-u2-a42.png"] {
            assert_eq!(ours(foreign, 2), None, "{foreign}");
        }
    }

    #[test]
    fn keeps_to_max_files_oldest_deleted_first_and_leaves_other_files_alone() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
        std::fs::write(dir.path().join(format!("{}.png", stem(5, 3, 1))), "another camera's").unwrap();
        let mut s = Store::open(dir.path(), 2, 3, u64::MAX).unwrap();
        for k in 0..5u16 {
            s.put(&item(1_000 + k as u64, k + 1)).unwrap();
        }
        let names = files(dir.path());
        let ours: Vec<&String> = names.iter().filter(|n| n.contains("-u2-")).collect();
        assert_eq!(ours.len(), 6, "three frames of two files each: {names:?}");
        for k in 3..=5 {
            assert!(names.iter().any(|n| n.ends_with(&format!("a{k:05}.png"))), "frame {k} kept: {names:?}");
            assert!(names.iter().any(|n| n.ends_with(&format!("a{k:05}.json"))), "frame {k}'s sidecar kept: {names:?}");
        }
        assert!(names.contains(&"notes.txt".to_string()) && names.iter().any(|n| n.contains("-u3-")), "{names:?}");
        // A restart counts what is there: two more frames still keep three.
        let mut s = Store::open(dir.path(), 2, 3, u64::MAX).unwrap();
        assert_eq!(s.kept.len(), 3);
        s.put(&item(2_000, 6)).unwrap();
        assert_eq!(files(dir.path()).iter().filter(|n| n.contains("-u2-")).count(), 6);
        assert!(!files(dir.path()).iter().any(|n| n.contains("a00003")), "the oldest went first");
    }

    #[test]
    fn the_shelf_reads_back_the_newest_and_only_the_archive_s_own_files() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("secret.txt"), "not yours").unwrap();
        let mut s = Store::open(dir.path(), 2, 10, u64::MAX).unwrap();
        for k in 1..=4u16 {
            s.put(&item(1_000 + k as u64, k)).unwrap();
        }
        let shelf = Shelf { dir: dir.path().to_path_buf(), unit_id: 2, counters: Arc::default() };
        let acq: Vec<u64> = shelf.recent(3).unwrap().iter().map(|v| v["acq_id"].as_u64().unwrap()).collect();
        assert_eq!(acq, [4, 3, 2], "newest first");
        let png = shelf.file(&format!("{}.png", stem(1_004, 2, 4))).unwrap();
        assert_eq!(&png[1..4], b"PNG");
        for bad in ["secret.txt", "../secret.txt", "/etc/passwd", &format!("{}.png", stem(1_004, 3, 4))] {
            assert!(shelf.file(bad).is_none(), "{bad}");
        }
    }

    #[test]
    fn keeps_to_max_bytes() {
        let dir = tempfile::tempdir().unwrap();
        let mut s = Store::open(dir.path(), 2, 1000, u64::MAX).unwrap();
        s.put(&item(1, 1)).unwrap();
        let one = s.total;
        s.max_bytes = 2 * one + one / 2;
        for k in 2..=6u16 {
            s.put(&item(k as u64, k)).unwrap();
        }
        assert_eq!(s.kept.len(), 2, "{:?}", s.kept);
        assert!(s.total <= s.max_bytes);
        let on_disk: u64 = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().metadata().unwrap().len()).sum();
        assert_eq!(on_disk, s.total);
    }

    #[test]
    fn a_full_queue_drops_and_counts_without_waiting() {
        let (tx, rx) = std::sync::mpsc::sync_channel(2);
        let a = Archive {
            save: ArchiveSave::All,
            tx: Some(tx),
            counters: Arc::default(),
            camera: "cam".into(),
            unit_id: 2,
            dir: PathBuf::from("unused"),
            thread: None,
        };
        let t = std::time::Instant::now();
        for k in 0..5 {
            a.offer(item(k, k as u16));
        }
        assert!(t.elapsed() < std::time::Duration::from_secs(1));
        assert_eq!(a.counters.dropped.load(Relaxed), 3);
        assert_eq!(rx.try_iter().count(), 2);
    }

    #[test]
    fn rejects_means_any_rejected_result_no_part_included() {
        let r = |accepted: bool, reason: Reason| Queued {
            seq: 1,
            acq_id: 1,
            part: PartResult { accepted, reason, type_id: 1, face: 1, angle_deg: 0.0, x_mm: 0.0, y_mm: 0.0, confidence: 0.9 },
            index: 1,
            count: 1,
            processing_ms: 1.0,
            user_data: 0,
            detection: None,
        };
        let ok = [r(true, Reason::Ok), r(true, Reason::Ok)];
        let one_bad = [r(true, Reason::Ok), r(false, Reason::Covered)];
        let no_part = [r(false, Reason::NoPart)];
        assert!(!wants(ArchiveSave::Rejects, &ok));
        assert!(wants(ArchiveSave::Rejects, &one_bad) && wants(ArchiveSave::Rejects, &no_part));
        assert!(wants(ArchiveSave::All, &ok) && !wants(ArchiveSave::None, &one_bad));
    }
}
