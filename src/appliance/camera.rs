//! One camera's worker thread: waits for a trigger (or a frame, free-running), estimates, and
//! reports to the handshake. Estimation is CPU-bound and synchronous, so it runs on its own OS
//! thread rather than on the async runtime.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use super::enrol::{EnrolError, EnrolRequest, Enrolled, Shown};
use super::job::InForce;
use super::source::{Source, SourceError};
use crate::config::Trigger;
use crate::handshake::{Command, Fault, Handshake, JobOutcome, Outcome, PartResult, Queued};
use crate::vision::{FrameEstimate, GrayImage, PartEstimate};

/// The job in force as everyone but the worker sees it: read, never written (the camera worker
/// puts a new job in force whole).
pub type SharedJob = Arc<std::sync::RwLock<Arc<InForce>>>;

/// What the worker is asked to do besides the PLC's commands, with where the answer goes.
pub enum Order {
    /// Enrol a part of the current frame (the operator view).
    Enrol(EnrolRequest, tokio::sync::oneshot::Sender<Result<Enrolled, EnrolError>>),
}

/// What the operator view shows of a camera: the latest frame and estimate, and counters.
///
/// Everything here comes from the handshake's final results (after EXPECTED_TYPE, in picking
/// order), the same the PLC, the robot link and the log get.
#[derive(Default)]
pub struct Live {
    /// The latest frame (shared, never copied for the page).
    pub frame: Option<Arc<GrayImage>>,
    /// The latest frame's estimate, its parts in picking order (`parts[i]` has PART_INDEX
    /// `i + 1`) with the final verdict.
    pub estimate: Option<FrameEstimate>,
    /// The latest acquisition's final results, as queued for the PLC (a no-part or frame-error
    /// result included).
    pub results: Vec<Queued>,
    /// Increments with every frame shown (the page reloads the picture when it changes).
    pub seq: u64,
    /// Where the frame came from (a file name, "sim scene 3 (clean)").
    pub label: String,
    /// Seconds since the appliance started, when the latest frame was estimated.
    pub at_s: f64,
    /// Frames estimated.
    pub frames: u64,
    /// Acquisitions without a usable frame.
    pub frame_errors: u64,
    /// Parts accepted.
    pub accepted: u64,
    /// Rejected parts by REASON code.
    pub rejected: [u64; crate::vision::Reason::ALL.len()],
    /// Debris pieces seen, all frames, and in the latest frame.
    pub debris_total: u64,
    /// See `debris_total`.
    pub debris_last: u64,
    /// The latest cycle times (trigger to results), ms, newest last.
    pub cycle_ms: std::collections::VecDeque<f64>,
    /// The latest camera or frame fault, as the log wrote it (kept after the fault is cleared:
    /// `last_error_at_s` says when, the page compares it with the frame's time).
    pub last_error: Option<String>,
    /// Seconds since start when `last_error` happened.
    pub last_error_at_s: f64,
    /// ACQ_ID of `results`.
    pub acq_id: u16,
    /// ACQ_ID of `frame` and `estimate` (older than `acq_id` after a failed acquisition).
    pub frame_acq_id: u16,
}

/// An acquisition's final results as published beyond the PLC (OPC UA's ResultReady): the
/// parts the PLC reads, in its order, with its values.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Acquisition {
    /// ACQ_ID.
    pub acq_id: u16,
    /// The job in force when the frame was estimated.
    pub job_id: u16,
    /// USER_DATA as latched when the frame was taken.
    pub user_data: u32,
    /// When the results were final.
    #[serde(skip)]
    pub at: std::time::SystemTime,
    /// PROCESSING_TIME, ms.
    pub processing_ms: f64,
    /// Every part, in picking order (empty: no part, or no usable frame).
    pub parts: Vec<ResultPart>,
    /// Why there was no usable frame, if there was none.
    pub error: Option<String>,
}

/// One part of an [`Acquisition`], with the values of the PLC's registers.
#[derive(Debug, Clone, serde::Serialize)]
pub struct ResultPart {
    /// ACQ_ID.
    pub acq_id: u16,
    /// PART_INDEX (1-based, picking order).
    pub part_index: u16,
    /// PART_COUNT.
    pub part_count: u16,
    /// TYPE_ID (0 unknown).
    pub type_id: u16,
    /// The type's name, if one was named.
    pub type_name: Option<String>,
    /// "up" or "down", if a type was named.
    pub face: Option<&'static str>,
    /// ANGLE_F32.
    pub angle_deg: f32,
    /// X_F32, mm in the robot frame.
    pub x_mm: f32,
    /// Y_F32.
    pub y_mm: f32,
    /// Pick point in the frame, pixels.
    pub x_px: f64,
    /// See `x_px`.
    pub y_px: f64,
    /// "accept" or "reject".
    pub decision: &'static str,
    /// REASON as text.
    pub reason: &'static str,
    /// REASON's code.
    pub reason_code: u16,
    /// CONFIDENCE (as the register: thousandths).
    pub confidence: f64,
}

impl Acquisition {
    /// The record of a completed acquisition: `results` as the handshake queued them, `fe` the
    /// estimate with its parts in the same order (None: no usable frame).
    pub fn of(acq_id: u16, job_id: u16, results: &[Queued], fe: Option<&FrameEstimate>, error: Option<String>) -> Self {
        let estimates = fe.map(|fe| fe.parts.as_slice()).unwrap_or(&[]);
        let parts = results
            .iter()
            .filter(|r| r.is_part())
            .enumerate()
            .map(|(i, r)| {
                let p = estimates.get(i);
                ResultPart {
                    acq_id: r.acq_id,
                    part_index: r.index,
                    part_count: r.count,
                    type_id: r.part.type_id,
                    type_name: p.and_then(|p| p.type_name.clone()),
                    face: crate::registers::face_of_code(r.part.face).map(|f| f.as_str()),
                    angle_deg: crate::registers::angle_f32(r.part.angle_deg),
                    x_mm: r.part.x_mm as f32,
                    y_mm: r.part.y_mm as f32,
                    x_px: p.map_or(f64::NAN, |p| p.x),
                    y_px: p.map_or(f64::NAN, |p| p.y),
                    decision: if r.part.accepted { "accept" } else { "reject" },
                    reason: r.part.reason.as_str(),
                    reason_code: crate::registers::reason_code(r.part.reason),
                    confidence: crate::registers::confidence_of_word(crate::registers::confidence_word(r.part.confidence)),
                }
            })
            .collect();
        let first = results.first();
        Acquisition {
            acq_id,
            job_id,
            user_data: first.map_or(0, |r| r.user_data),
            at: std::time::SystemTime::now(),
            processing_ms: first.map_or(0.0, |r| r.processing_ms),
            parts,
            error,
        }
    }
}

/// How many acquisitions a listener of [`Published`] may fall behind before it misses some.
pub const PUBLISHED: usize = 256;

/// Where a camera's acquisitions are published (OPC UA subscribes; nobody need listen).
pub type Published = tokio::sync::broadcast::Sender<std::sync::Arc<Acquisition>>;

/// Everything a worker needs. It is the only owner of the job in force: a job change (a PLC
/// command) and an enrolment (an [`Order`]) are done here, between frames, and each puts a new
/// job in force whole; the rest of the appliance reads `shared`.
pub(crate) struct Worker {
    pub name: String,
    pub trigger: Trigger,
    /// The job in force.
    pub job: Arc<InForce>,
    /// Where the job in force is shown to the rest of the appliance.
    pub shared: SharedJob,
    pub source: Box<dyn Source>,
    pub handshake: Arc<Mutex<Handshake>>,
    pub commands: Receiver<Command>,
    pub orders: Receiver<Order>,
    pub live: Arc<Mutex<Live>>,
    pub started: Instant,
    pub stop: Arc<AtomicBool>,
    /// Accepted (or all) results for the robot link, if one is configured.
    pub robot: Option<tokio::sync::mpsc::UnboundedSender<Queued>>,
    pub robot_send: crate::config::RobotSend,
    /// The image archive, if configured (dropped with the worker: it writes what was queued).
    pub archive: Option<super::archive::Archive>,
    /// The operator view's history, if kept.
    pub history: Option<super::history::Recorder>,
    /// Told of every frame and fault.
    pub changes: super::changes::Changes,
    /// The jobs the PLC may switch between, and what loading one needs.
    pub jobs: super::job::Jobs,
    /// Every completed acquisition, for OPC UA.
    pub published: Published,
}

impl Worker {
    pub(crate) fn run(mut self) {
        tracing::info!(camera = %self.name, "camera worker started ({:?} trigger)", self.trigger);
        while !self.stop.load(Ordering::Relaxed) {
            while let Ok(order) = self.orders.try_recv() {
                match order {
                    Order::Enrol(req, reply) => {
                        let _ = reply.send(self.enrol(&req));
                    }
                }
            }
            match self.trigger {
                Trigger::Modbus => match self.commands.recv_timeout(Duration::from_millis(100)) {
                    Ok(Command::Acquire { acq_id }) => {
                        let t = Instant::now();
                        let frame = self.source.grab();
                        self.process(acq_id, frame, t);
                    }
                    Ok(Command::ChangeJob { id }) => self.change_job(id),
                    Err(RecvTimeoutError::Timeout) => self.update_camera_ok(),
                    Err(RecvTimeoutError::Disconnected) => break,
                },
                Trigger::FreeRun => {
                    // A free-running camera gets no acquisitions through the channel, only
                    // job changes.
                    while let Ok(cmd) = self.commands.try_recv() {
                        if let Command::ChangeJob { id } = cmd {
                            self.change_job(id);
                        }
                    }
                    // Take a frame only when it can be used: a folder's files wait in the inbox
                    // while the camera is offline or in ERROR instead of being consumed unseen.
                    let can = self.handshake.lock().unwrap_or_else(|p| p.into_inner()).ready();
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
                        _ => tracing::debug!(camera = %self.name, "frame skipped: not ready (offline, busy or in error)"),
                    }
                }
            }
        }
        tracing::info!(camera = %self.name, "camera worker stopped");
    }

    /// Loads job `id` whole (knowledge base, estimator, calibration) and only then puts it in
    /// force; a job that is not configured or does not load leaves the job in force as it was.
    /// Either way the handshake learns the outcome (JOB_STATUS) and the log says why.
    fn change_job(&mut self, id: u16) {
        let t = Instant::now();
        let loaded = self.jobs.load(id);
        match loaded {
            Ok(l) => {
                let (job, kb_desc) = (l.job, l.kb_desc);
                let expected_type = job.expected_type;
                tracing::info!(
                    camera = %self.name,
                    "job {id} ({}) in force after {:.0} ms: knowledge base {kb_desc}; calibration {}{}",
                    job.name,
                    t.elapsed().as_secs_f64() * 1e3,
                    job.calibration.describe(),
                    expected_type.map(|e| format!("; EXPECTED_TYPE {e}")).unwrap_or_default()
                );
                let mut hs = self.put_in_force(job);
                hs.job_changed(id, JobOutcome::InForce { expected_type });
            }
            Err(reason) => {
                self.handshake.lock().unwrap_or_else(|p| p.into_inner()).job_changed(id, JobOutcome::Failed);
                let message = format!("job change failed, job {} stays in force: {reason}", self.job.id);
                tracing::warn!(camera = %self.name, "{message}");
                self.note_error(message);
            }
        }
    }

    /// Puts `job` in force: for the next frame, for everyone who reads it, and as the
    /// handshake's TYPES_ENROLLED. Returns the handshake, still locked, for what else it must
    /// learn in the same step (a job change's JOB_STATUS).
    fn put_in_force(&mut self, job: InForce) -> std::sync::MutexGuard<'_, Handshake> {
        let job = Arc::new(job);
        let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
        hs.set_types_enrolled(job.types_enrolled());
        *self.shared.write().unwrap_or_else(|p| p.into_inner()) = job.clone();
        self.job = job;
        super::changes::bump(&self.changes);
        hs
    }

    /// An operator's enrolment (see [`super::enrol`]): the job with the new template goes in
    /// force between two frames.
    fn enrol(&mut self, req: &EnrolRequest) -> Result<Enrolled, EnrolError> {
        let shown = {
            let live = self.live.lock().unwrap_or_else(|p| p.into_inner());
            Shown { frame: live.frame.clone(), estimate: live.estimate.clone(), label: live.label.clone(), acq_id: live.frame_acq_id }
        };
        let (job, done) = super::enrol::enrol(&self.job, shown, req)?;
        drop(self.put_in_force(job));
        tracing::info!(
            camera = %self.name,
            "{} template {} {} (id {}) from part {} of {}, asked by {}; {}",
            if done.replaced { "replaced" } else { "enrolled" },
            req.type_name,
            req.face,
            req.id,
            req.part,
            done.from,
            req.by,
            done.saved
        );
        Ok(done)
    }

    fn update_camera_ok(&mut self) {
        self.source.maintain();
        let ok = self.source.ok();
        let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
        let changed = hs.camera_ok() != ok;
        // Every look, not only changes: the handshake tells a lost camera from one never seen.
        hs.set_camera_ok(ok);
        drop(hs);
        if changed {
            if ok {
                tracing::info!(camera = %self.name, "camera OK");
                super::changes::bump(&self.changes);
            } else {
                tracing::warn!(camera = %self.name, "camera not OK");
                self.note_fault("camera not OK: it stopped answering or is not connected".into());
            }
        }
    }

    fn process(&mut self, acq_id: u16, frame: Result<super::source::Frame, SourceError>, t0: Instant) {
        let job = self.job.clone();
        let mut debris = 0;
        let mut estimated = None;
        // A frame that came but could not be estimated is still worth archiving.
        let mut unusable: Option<(Arc<GrayImage>, String, String)> = None;
        let outcome = match frame {
            Err(e) => {
                let fault = e.fault();
                tracing::warn!(camera = %self.name, acq_id, "acquisition failed: {e}");
                self.note_error(e.to_string());
                Outcome::Failed { fault }
            }
            Ok(f) => {
                let fits = job.calibration.fits(f.image.width, f.image.height).map_err(|e| e.to_string());
                match fits.and_then(|()| job.estimator.estimate_in(&f.image, job.roi).map_err(|e| e.to_string())) {
                    Err(e) => {
                        tracing::warn!(camera = %self.name, acq_id, frame = %f.label, "frame error: {e}");
                        self.note_error(format!("{}: {e}", f.label));
                        unusable = Some((Arc::new(f.image), f.label, e.to_string()));
                        Outcome::Failed { fault: Fault::Frame }
                    }
                    Ok(fe) => {
                        let parts = fe.parts.iter().map(|p| result(p, &job)).collect();
                        let processing_ms = fe.timings.total;
                        debris = fe.debris;
                        estimated = Some((Arc::new(f.image), f.label, fe));
                        Outcome::Parts { parts, processing_ms }
                    }
                }
            }
        };
        let results = {
            let mut hs = self.handshake.lock().unwrap_or_else(|p| p.into_inner());
            hs.set_camera_ok(self.source.ok());
            hs.set_debris(debris);
            hs.complete(acq_id, outcome, self.started.elapsed())
        };
        // From here on every consumer takes the handshake's final results: the robot gets what
        // the PLC gets (the rejected ones only with `send = "all"`), the log, the page and the
        // counters the same parts in the same order.
        if let Some(tx) = &self.robot {
            for r in results.iter().filter(|r| r.is_part() && self.robot_send.wants(r.part.accepted)) {
                let _ = tx.send(r.clone());
            }
        }
        let estimated = estimated.map(|(image, label, fe)| (image, label, in_final_order(fe, &results)));
        if let Some((_, label, fe)) = &estimated {
            self.log(acq_id, label, fe, &results);
        }
        if let Some(archive) = &self.archive
            && archive.wants(&results)
        {
            let frame = match (&estimated, &unusable) {
                (Some((image, label, fe)), _) => Some((image.clone(), label.as_str(), Some(fe), None)),
                (None, Some((image, label, error))) => Some((image.clone(), label.as_str(), None, Some(error.as_str()))),
                (None, None) => None, // no frame came: nothing to keep
            };
            if let Some((image, label, fe, error)) = frame {
                archive.offer(archive_item(&self.name, archive.unit_id(), acq_id, job.id, &results, image, label, fe, error));
            }
        }
        // Why there was no usable frame, for OPC UA's results and the page's history.
        let error = if estimated.is_some() { None } else { self.live.lock().unwrap_or_else(|p| p.into_inner()).last_error.clone() };
        if !results.is_empty() && self.published.receiver_count() > 0 {
            let fe = estimated.as_ref().map(|(_, _, fe)| fe);
            // A receiver too slow to keep up loses the oldest; it says so when it reads.
            let _ = self.published.send(Arc::new(Acquisition::of(acq_id, job.id, &results, fe, error.clone())));
        }
        let cycle = t0.elapsed().as_secs_f64() * 1e3;
        if let Some(history) = &self.history
            && !results.is_empty()
        {
            let (frame, label, estimate) = match (&estimated, &unusable) {
                (Some((image, label, fe)), _) => (Some(image.clone()), label.clone(), Some(fe.clone())),
                (None, Some((image, label, _))) => (Some(image.clone()), label.clone(), None),
                (None, None) => (None, String::new(), None),
            };
            history.offer(super::history::Offer {
                acq_id,
                at_s: self.started.elapsed().as_secs_f64(),
                label,
                results: results.clone(),
                estimate,
                frame,
                error,
                cycle_ms: cycle,
            });
        }
        self.note_results(acq_id, results, estimated, cycle);
        super::changes::bump(&self.changes);
    }

    /// One line per final result, with the estimate's numbers at debug level.
    fn log(&self, acq_id: u16, label: &str, fe: &FrameEstimate, results: &[Queued]) {
        for (r, p) in results.iter().filter(|r| r.is_part()).zip(&fe.parts) {
            let (index, count) = (r.index, r.count);
            let name = p.type_name.as_deref().unwrap_or("?");
            if r.part.accepted {
                let face = p.face.map(|f| f.as_str()).unwrap_or("?");
                let (a, x, y, c) = (r.part.angle_deg, r.part.x_mm, r.part.y_mm, r.part.confidence);
                tracing::info!(camera = %self.name, acq_id, part = index, of = count, "accept {name} {face} angle {a:.2} deg at ({x:.1}, {y:.1}) mm, confidence {c:.3}");
            } else {
                let (x, y) = (r.part.x_mm, r.part.y_mm);
                tracing::info!(camera = %self.name, acq_id, part = index, of = count, "reject ({}) {name} at ({x:.1}, {y:.1}) mm, ({:.1}, {:.1}) px", r.part.reason, p.x, p.y);
            }
            tracing::debug!(camera = %self.name, acq_id, part = index, "{}", p.detail());
        }
        if fe.parts.is_empty() {
            tracing::info!(camera = %self.name, acq_id, frame = %label, "no part");
        }
        if fe.debris > 0 {
            tracing::info!(camera = %self.name, acq_id, "{} piece(s) of debris on the belt", fe.debris);
        }
    }

    /// An acquisition without a usable frame: counted, and the latest fault.
    fn note_error(&self, msg: String) {
        self.live.lock().unwrap_or_else(|p| p.into_inner()).frame_errors += 1;
        self.note_fault(msg);
    }

    /// The latest fault, with when it happened, for the page's banner.
    fn note_fault(&self, msg: String) {
        let mut live = self.live.lock().unwrap_or_else(|p| p.into_inner());
        live.last_error = Some(msg);
        live.last_error_at_s = self.started.elapsed().as_secs_f64();
        drop(live);
        super::changes::bump(&self.changes);
    }

    /// The operator view's copy of an acquisition: counters from the final results (a no-part
    /// or frame-error result counts as a reject with its reason, as the PLC got it).
    fn note_results(&self, acq_id: u16, results: Vec<Queued>, estimated: Option<(Arc<GrayImage>, String, FrameEstimate)>, cycle_ms: f64) {
        let mut live = self.live.lock().unwrap_or_else(|p| p.into_inner());
        for r in &results {
            if r.part.accepted {
                live.accepted += 1;
            } else {
                live.rejected[r.part.reason.index()] += 1;
            }
        }
        live.cycle_ms.push_back(cycle_ms);
        while live.cycle_ms.len() > 512 {
            live.cycle_ms.pop_front();
        }
        if results.is_empty() {
            return; // not the acquisition running: the handshake ignored it
        }
        live.acq_id = acq_id;
        live.results = results;
        let Some((image, label, fe)) = estimated else { return };
        live.frames += 1;
        live.debris_total += fe.debris as u64;
        live.debris_last = fe.debris as u64;
        live.frame = Some(image);
        live.frame_acq_id = acq_id;
        live.estimate = Some(fe);
        live.label = label;
        live.seq += 1;
        live.at_s = self.started.elapsed().as_secs_f64();
    }
}

/// A frame's sidecar in the archive: the `estimate --json` record of its final results (in
/// picking order: `parts[i]` has PART_INDEX `i + 1`) with what ties it to the PLC's view.
#[derive(serde::Serialize)]
struct ArchiveRecord<'a> {
    image: String,
    camera: &'a str,
    unit_id: u8,
    acq_id: u16,
    /// The job in force when the frame was estimated (a camera without `[[camera.job]]` tables
    /// is job 1).
    job_id: u16,
    user_data: u32,
    /// UTC, RFC 3339, when the frame was estimated.
    time: String,
    unix_ms: u64,
    /// Where the frame came from (file name, scene).
    frame: &'a str,
    elapsed_ms: f64,
    parts: Vec<crate::truth::EstimatePart>,
    #[serde(skip_serializing_if = "Option::is_none")]
    error: Option<&'a str>,
}

#[allow(clippy::too_many_arguments)]
fn archive_item(
    camera: &str,
    unit_id: u8,
    acq_id: u16,
    job_id: u16,
    results: &[Queued],
    image: Arc<GrayImage>,
    label: &str,
    fe: Option<&FrameEstimate>,
    error: Option<&str>,
) -> super::archive::Item {
    let now = std::time::SystemTime::now();
    let unix_ms = now.duration_since(std::time::UNIX_EPOCH).map(|d| d.as_millis() as u64).unwrap_or(0);
    let stem = super::archive::stem(unix_ms, unit_id, acq_id);
    let record = ArchiveRecord {
        image: format!("{stem}.png"),
        camera,
        unit_id,
        acq_id,
        job_id,
        user_data: results.first().map_or(0, |r| r.user_data),
        time: humantime::format_rfc3339_millis(now).to_string(),
        unix_ms,
        frame: label,
        elapsed_ms: fe.map_or(0.0, |fe| (fe.timings.total * 1000.0).round() / 1000.0),
        parts: fe.map(|fe| fe.parts.iter().map(crate::truth::EstimatePart::from_estimate).collect()).unwrap_or_default(),
        error,
    };
    let sidecar = serde_json::to_string(&record).expect("an archive record always serialises");
    super::archive::Item { stem, image, sidecar }
}

/// A part's result in the robot frame, as the estimate left it (the handshake makes the
/// final one).
fn result(p: &PartEstimate, job: &InForce) -> PartResult {
    let (x, y, a) = job.calibration.apply_part(p, &job.estimator);
    PartResult {
        accepted: p.accepted,
        reason: p.reason,
        type_id: p.type_id,
        face: crate::registers::face_code(p.face),
        angle_deg: a,
        x_mm: x,
        y_mm: y,
        confidence: p.confidence,
    }
}

/// The estimate's parts in the final results' order (picking order), each with its final
/// verdict: `parts[i]` is the part with PART_INDEX `i + 1`.
fn in_final_order(mut fe: FrameEstimate, results: &[Queued]) -> FrameEstimate {
    let mut detected: Vec<Option<PartEstimate>> = std::mem::take(&mut fe.parts).into_iter().map(Some).collect();
    for r in results {
        if let Some(mut p) = r.detection.and_then(|d| detected.get_mut(d)).and_then(Option::take) {
            p.overrule(r.part.accepted, r.part.reason);
            fe.parts.push(p);
        }
    }
    fe
}
