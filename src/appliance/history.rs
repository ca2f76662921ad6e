//! The operator view's history: the last N acquisitions of a camera with their final results,
//! each frame kept downscaled in memory, so a reject of a minute ago can still be looked at.
//!
//! The camera worker only offers an acquisition (the frame is shared, not copied); a background
//! thread downscales it and files it, so the PLC's cycle never waits for the history. An
//! acquisition that finds the thread busy with the last few is dropped and counted.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::mpsc::{Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex};

use crate::handshake::Queued;
use crate::vision::{FrameEstimate, GrayImage};

/// Width of a kept frame at most, pixels: a 5-MP frame downscaled 4x (about 300 kB).
pub const PICTURE_WIDTH: usize = 648;

/// Acquisitions waiting to be filed at most.
const QUEUE_DEPTH: usize = 4;

/// One acquisition as the page shows it later.
#[derive(Debug)]
pub struct Entry {
    /// Increments with every entry of this camera (the page's key).
    pub id: u64,
    /// ACQ_ID of the acquisition.
    pub acq_id: u16,
    /// Seconds since the appliance started, when its results were made.
    pub at_s: f64,
    /// The same instant, RFC 3339 UTC.
    pub time: String,
    /// Where the frame came from.
    pub label: String,
    /// The final results as queued for the PLC, in picking order.
    pub results: Vec<Queued>,
    /// The estimate, its parts in the results' order; None when no usable frame came.
    pub estimate: Option<FrameEstimate>,
    /// The frame downscaled by `scale`; None when no frame came.
    pub picture: Option<GrayImage>,
    /// Picture pixels per frame pixel.
    pub scale: f64,
    /// The camera or frame fault, for an acquisition that failed.
    pub error: Option<String>,
    /// Trigger to results, ms.
    pub cycle_ms: f64,
}

/// An acquisition offered by the camera worker.
pub struct Offer {
    /// ACQ_ID.
    pub acq_id: u16,
    /// Seconds since start.
    pub at_s: f64,
    /// Where the frame came from.
    pub label: String,
    /// The final results.
    pub results: Vec<Queued>,
    /// The estimate in final order.
    pub estimate: Option<FrameEstimate>,
    /// The frame (shared with the live view).
    pub frame: Option<Arc<GrayImage>>,
    /// The fault, if the acquisition failed.
    pub error: Option<String>,
    /// Trigger to results, ms.
    pub cycle_ms: f64,
}

/// The kept entries, newest last, shared with the operator view.
#[derive(Debug, Clone, Default)]
pub struct Shelf {
    entries: Arc<Mutex<VecDeque<Arc<Entry>>>>,
    /// Acquisitions not kept because the thread was still filing earlier ones.
    pub dropped: Arc<AtomicU64>,
}

impl Shelf {
    /// Every kept entry, oldest first.
    pub fn entries(&self) -> Vec<Arc<Entry>> {
        self.entries.lock().unwrap_or_else(|p| p.into_inner()).iter().cloned().collect()
    }
    /// The entry with this id, if still kept.
    pub fn get(&self, id: u64) -> Option<Arc<Entry>> {
        self.entries.lock().unwrap_or_else(|p| p.into_inner()).iter().find(|e| e.id == id).cloned()
    }
}

/// The worker's end: offers acquisitions without waiting.
pub struct Recorder {
    tx: SyncSender<Offer>,
    dropped: Arc<AtomicU64>,
}

impl Recorder {
    /// Starts the filing thread for a camera keeping `keep` entries (at least 1), calling
    /// `changed` after each entry is filed; returns the recorder and the shelf.
    pub fn start(camera: &str, keep: usize, changed: impl Fn() + Send + 'static) -> (Recorder, Shelf) {
        let (tx, rx) = std::sync::mpsc::sync_channel(QUEUE_DEPTH);
        let shelf = Shelf::default();
        let entries = shelf.entries.clone();
        let name = camera.to_string();
        std::thread::Builder::new()
            .name(format!("history-{camera}"))
            .spawn(move || {
                // Work for people, not for the PLC: the camera worker goes first.
                super::priority::lower_priority("history");
                file(rx, entries, keep.max(1), &name, changed)
            })
            .expect("spawn history thread");
        (Recorder { tx, dropped: shelf.dropped.clone() }, shelf)
    }

    /// Offers an acquisition; a full queue drops it (counted).
    pub fn offer(&self, offer: Offer) {
        if let Err(TrySendError::Full(_)) = self.tx.try_send(offer) {
            self.dropped.fetch_add(1, Relaxed);
        }
    }
}

fn file(rx: Receiver<Offer>, entries: Arc<Mutex<VecDeque<Arc<Entry>>>>, keep: usize, camera: &str, changed: impl Fn()) {
    let mut next_id = 1u64;
    while let Ok(o) = rx.recv() {
        let (picture, scale) = match o.frame.as_deref().map(downscale) {
            Some(Ok((p, s))) => (Some(p), s),
            Some(Err(e)) => {
                tracing::warn!(camera, acq_id = o.acq_id, "history: frame not kept: {e}");
                (None, 1.0)
            }
            None => (None, 1.0),
        };
        let entry = Entry {
            id: next_id,
            acq_id: o.acq_id,
            at_s: o.at_s,
            time: humantime::format_rfc3339_millis(std::time::SystemTime::now()).to_string(),
            label: o.label,
            results: o.results,
            estimate: o.estimate,
            picture,
            scale,
            error: o.error,
            cycle_ms: o.cycle_ms,
        };
        next_id += 1;
        {
            let mut e = entries.lock().unwrap_or_else(|p| p.into_inner());
            e.push_back(Arc::new(entry));
            while e.len() > keep {
                e.pop_front();
            }
        }
        changed();
    }
}

/// The frame at most [`PICTURE_WIDTH`] wide, by an integer factor, and its scale: each picture
/// pixel the mean of the two middle pixels of the middle row of its block. It reads one row in
/// `factor` of the frame (0.3 ms for a 5-MP frame), leaving the memory bandwidth of a 2-core
/// appliance to the camera's next estimate; a picture for people needs no area average.
pub fn downscale(img: &GrayImage) -> Result<(GrayImage, f64), String> {
    let f = img.width.div_ceil(PICTURE_WIDTH).max(1);
    let (w, h) = (img.width / f, img.height / f);
    if w == 0 || h == 0 {
        return Err(format!("frame {} x {} is too small to keep", img.width, img.height));
    }
    if f == 1 {
        return Ok((img.clone(), 1.0));
    }
    let mid = (f - 1) / 2;
    let mut data = Vec::with_capacity(w * h);
    for y in 0..h {
        let row = &img.data[(f * y + mid) * img.width..][..img.width];
        data.extend(row.chunks_exact(f).take(w).map(|b| (b[mid] as u16 + b[(mid + 1).min(f - 1)] as u16).div_ceil(2) as u8));
    }
    Ok((GrayImage { data, width: w, height: h }, 1.0 / f as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_newest_entries_downscaled_and_says_when_it_filed_one() {
        let filed = Arc::new(AtomicU64::new(0));
        let seen = filed.clone();
        let (rec, shelf) = Recorder::start("test", 3, move || {
            seen.fetch_add(1, Relaxed);
        });
        let frame = Arc::new(GrayImage::new(2592, 1944, 90));
        for acq_id in 1..=5u16 {
            rec.offer(Offer {
                acq_id,
                at_s: acq_id as f64,
                label: format!("frame {acq_id}"),
                results: Vec::new(),
                estimate: None,
                frame: (acq_id != 4).then(|| frame.clone()),
                error: (acq_id == 4).then(|| "no frame within 2000 ms".to_string()),
                cycle_ms: 5.0,
            });
            // One at a time, so that none is dropped for a full queue.
            while filed.load(Relaxed) < acq_id as u64 {
                std::thread::sleep(std::time::Duration::from_millis(2));
            }
        }
        let kept = shelf.entries();
        assert_eq!(kept.iter().map(|e| e.acq_id).collect::<Vec<_>>(), vec![3, 4, 5]);
        let p = kept[0].picture.as_ref().expect("a frame came");
        assert_eq!((p.width, p.height), (648, 486));
        assert!((kept[0].scale - 0.25).abs() < 1e-9);
        assert!(kept[1].picture.is_none() && kept[1].error.as_deref() == Some("no frame within 2000 ms"));
        assert_eq!(shelf.get(kept[2].id).unwrap().acq_id, 5);
        assert!(shelf.get(1).is_none(), "the oldest entries are gone");
    }
}
