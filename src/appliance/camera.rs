//! One camera's worker thread: waits for a trigger (or a frame, free-running), estimates, and
//! reports to the handshake. Estimation is CPU-bound and synchronous, so it runs on its own OS
//! thread rather than on the async runtime.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::source::{Source, SourceError};
use crate::calibration::Calibration;
use crate::config::{PickingOrder, Trigger};
use crate::handshake::{Command, Fault, Handshake, Outcome, PartResult};
use crate::vision::{Estimator, FrameEstimate, GrayImage, PartEstimate};

/// The estimator a camera uses; replaced whole when the operator enrolls a template.
pub type SharedEstimator = Arc<std::sync::RwLock<Arc<Estimator>>>;

/// What the operator view shows of a camera: the latest frame and estimate, and counters.
#[derive(Default)]
pub struct Live {
    pub frame: Option<Arc<GrayImage>>,
    pub estimate: Option<FrameEstimate>,
    /// Increments with every frame shown (the page reloads the picture when it changes).
    pub seq: u64,
    pub label: String,
    /// Seconds since the appliance started, when the latest frame was estimated.
    pub at_s: f64,
    pub frames: u64,
    pub frame_errors: u64,
    pub accepted: u64,
    /// Rejected parts by REASON code.
    pub rejected: [u64; crate::vision::Reason::ALL.len()],
    /// Debris pieces seen, all frames, and in the latest frame.
    pub debris_total: u64,
    pub debris_last: u64,
    /// The latest cycle times (trigger to results), ms, newest last.
    pub cycle_ms: std::collections::VecDeque<f64>,
    pub last_error: Option<String>,
}

/// Everything a worker needs.
pub struct Worker {
    pub name: String,
    pub trigger: Trigger,
    pub order: PickingOrder,
    pub roi: Option<[usize; 4]>,
    pub estimator: SharedEstimator,
    pub calibration: Calibration,
    pub source: Box<dyn Source>,
    pub handshake: Arc<Mutex<Handshake>>,
    pub commands: Receiver<Command>,
    pub live: Arc<Mutex<Live>>,
    pub started: Instant,
    pub stop: Arc<AtomicBool>,
    /// Accepted (or all) results for the robot link, if one is configured.
    pub robot: Option<tokio::sync::mpsc::UnboundedSender<(u16, PartResult)>>,
    pub robot_sends_all: bool,
}

impl Worker {
    pub fn run(mut self) {
        tracing::info!(camera = %self.name, "camera worker started ({:?} trigger)", self.trigger);
        while !self.stop.load(Ordering::Relaxed) {
            match self.trigger {
                Trigger::Modbus => match self.commands.recv_timeout(Duration::from_millis(100)) {
                    Ok(Command::Acquire { acq_id }) => {
                        let t = Instant::now();
                        let frame = self.source.grab();
                        self.process(acq_id, frame, t);
                    }
                    Err(RecvTimeoutError::Timeout) => self.update_camera_ok(),
                    Err(RecvTimeoutError::Disconnected) => break,
                },
                Trigger::FreeRun => {
                    // Take a frame only when it can be used: a folder's files wait in the inbox
                    // while the camera is offline or in ERROR instead of being consumed unseen.
                    let can = self.handshake.lock().unwrap_or_else(|p| p.into_inner()).can_acquire();
                    if !can {
                        self.update_camera_ok();
                        std::thread::sleep(Duration::from_millis(50));
                        continue;
                    }
                    let frame = self.source.next(Duration::from_millis(200));
                    if matches!(frame, Err(SourceError::Timeout(_))) {
                        self.update_camera_ok();
                        continue;
                    }
                    let t = Instant::now();
                    let acq = self.handshake.lock().unwrap_or_else(|p| p.into_inner()).free_run(self.started.elapsed());
                    match acq {
                        Some(Command::Acquire { acq_id }) => self.process(acq_id, frame, t),
                        None => tracing::debug!(camera = %self.name, "frame skipped: not ready (offline, busy or in error)"),
                    }
                }
            }
        }
        tracing::info!(camera = %self.name, "camera worker stopped");
    }

    fn update_camera_ok(&self) {
        let ok = self.source.ok();
        let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
        if hs.camera_ok() != ok {
            if ok {
                tracing::info!(camera = %self.name, "camera OK");
            } else {
                tracing::warn!(camera = %self.name, "camera not OK");
            }
            hs.set_camera_ok(ok);
        }
    }

    fn process(&mut self, acq_id: u16, frame: Result<super::source::Frame, SourceError>, t0: Instant) {
        let mut debris = 0;
        let outcome = match frame {
            Err(e) => {
                let fault = if matches!(e, SourceError::Unusable(_)) { Fault::Frame } else { Fault::Camera };
                tracing::warn!(camera = %self.name, acq_id, "acquisition failed: {e}");
                self.note_error(e.to_string());
                Outcome::Failed { fault }
            }
            Ok(f) => match self.estimate(&f.image) {
                Err(e) => {
                    tracing::warn!(camera = %self.name, acq_id, frame = %f.label, "frame error: {e}");
                    self.note_error(format!("{}: {e}", f.label));
                    Outcome::Failed { fault: Fault::Frame }
                }
                Ok(fe) => {
                    let parts = self.results(&fe.parts);
                    for (p, r) in fe.parts.iter().zip(&parts) {
                        if p.accepted {
                            tracing::info!(camera = %self.name, acq_id, "accept {} {} angle {:.2} deg at ({:.1}, {:.1}) mm, confidence {:.3}", p.type_name.as_deref().unwrap_or("?"), p.face.map(|f| f.as_str()).unwrap_or("?"), r.angle_deg, r.x_mm, r.y_mm, p.confidence);
                        } else {
                            tracing::info!(camera = %self.name, acq_id, "reject ({}) at ({:.1}, {:.1}) px", p.reason, p.x, p.y);
                        }
                        tracing::debug!(camera = %self.name, acq_id, "{}", p.detail());
                    }
                    if parts.is_empty() {
                        tracing::info!(camera = %self.name, acq_id, frame = %f.label, "no part");
                    }
                    let processing_ms = fe.timings.total;
                    if fe.debris > 0 {
                        tracing::info!(camera = %self.name, acq_id, "{} piece(s) of debris on the belt", fe.debris);
                    }
                    debris = fe.debris;
                    self.note_frame(f.image, f.label, fe);
                    Outcome::Parts { parts, processing_ms }
                }
            },
        };
        let results = {
            let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
            hs.set_camera_ok(self.source.ok());
            hs.set_debris(debris);
            hs.complete(acq_id, outcome, self.started.elapsed())
        };
        // The robot gets what the PLC gets (the handshake's final results, the expected-type
        // rule applied there), the rejected ones only with `send = "all"`.
        if let Some(tx) = &self.robot {
            for r in results.into_iter().filter(|r| r.is_part() && (r.part.accepted || self.robot_sends_all)) {
                let _ = tx.send((acq_id, r.part));
            }
        }
        let cycle = t0.elapsed().as_secs_f64() * 1e3;
        let mut live = self.live.lock().unwrap_or_else(|p| p.into_inner());
        live.cycle_ms.push_back(cycle);
        while live.cycle_ms.len() > 512 {
            live.cycle_ms.pop_front();
        }
    }

    fn estimate(&self, img: &GrayImage) -> Result<FrameEstimate, crate::vision::FrameError> {
        let estimator = self.estimator.read().unwrap_or_else(|p| p.into_inner()).clone();
        match self.roi {
            None => estimator.estimate(img.view()?),
            Some([x, y, w, h]) => {
                let crop = img.crop(x, y, w, h).ok_or(crate::vision::FrameError::TooSmall { width: img.width, height: img.height })?;
                let mut fe = estimator.estimate(crop.view()?)?;
                for p in &mut fe.parts {
                    p.x += x as f64;
                    p.y += y as f64;
                    for q in &mut p.outline {
                        q.x += x as f64;
                        q.y += y as f64;
                    }
                }
                Ok(fe)
            }
        }
    }

    /// Robot-frame results in picking order: accepted parts first.
    fn results(&self, parts: &[PartEstimate]) -> Vec<PartResult> {
        let mut out: Vec<PartResult> = parts
            .iter()
            .map(|p| {
                let (x, y, a) = self.calibration.apply(p.x, p.y, p.angle_deg);
                PartResult {
                    accepted: p.accepted,
                    reason: p.reason,
                    type_id: p.type_id,
                    face: p.face.map(|f| f.code()).unwrap_or(0),
                    angle_deg: a,
                    x_mm: x,
                    y_mm: y,
                    confidence: p.confidence,
                }
            })
            .collect();
        out.sort_by(|a, b| b.accepted.cmp(&a.accepted).then_with(|| self.order.compare(a, b)));
        out
    }

    fn note_error(&self, msg: String) {
        let mut live = self.live.lock().unwrap_or_else(|p| p.into_inner());
        live.frame_errors += 1;
        live.last_error = Some(msg);
    }

    fn note_frame(&self, image: GrayImage, label: String, fe: FrameEstimate) {
        let mut live = self.live.lock().unwrap_or_else(|p| p.into_inner());
        live.frames += 1;
        for p in &fe.parts {
            if p.accepted {
                live.accepted += 1;
            } else {
                live.rejected[p.reason.code() as usize] += 1;
            }
        }
        live.debris_total += fe.debris as u64;
        live.debris_last = fe.debris as u64;
        live.frame = Some(Arc::new(image));
        live.estimate = Some(fe);
        live.label = label;
        live.seq += 1;
        live.at_s = self.started.elapsed().as_secs_f64();
    }
}
