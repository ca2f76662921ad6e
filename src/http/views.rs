//! What the page's JSON holds: the registers decoded for people, each result as the PLC got it
//! beside the image's pixels and the measures behind its decision, a camera's state, and the
//! history. Built from the same snapshot the Modbus server serves; nothing here decides.

use serde::Serialize;

use crate::appliance::CameraHandle;
use crate::appliance::history::Entry;
use crate::handshake::{Queued, WordOrder};
use crate::registers::{self as map, MAP, code_word};
use crate::vision::decide::Measure;
use crate::vision::{FrameEstimate, Reason};

/// One register as the page shows it.
#[derive(Serialize)]
pub struct RegisterView {
    addr: u16,
    plc: u32,
    name: &'static str,
    access: &'static str,
    raw: Vec<u16>,
    /// Scaled, signed, joined: what the number means.
    value: String,
    /// A code's word, a bit register's set bits by name, a type's name.
    word: Option<String>,
    unit: &'static str,
}

/// A status bit.
#[derive(Serialize)]
pub struct Lamp {
    name: &'static str,
    on: bool,
}

/// One final result as the PLC got it, beside what the image showed and why it was decided so.
#[derive(Serialize)]
pub struct PartView {
    acq_id: u16,
    /// PART_INDEX: 1.. in picking order; 0 for a no-part or frame-error result.
    index: u16,
    accepted: bool,
    /// DECISION's word.
    decision: &'static str,
    reason: &'static str,
    reason_code: u16,
    type_id: u16,
    type_name: Option<String>,
    face: Option<&'static str>,
    /// As the PLC reads them: robot frame, ANGLE -180..180 deg (0.01 deg), X/Y the float copies.
    angle_deg: f64,
    x_mm: f64,
    y_mm: f64,
    confidence: f64,
    /// In the image: the pick point in frame pixels and the angle against the template.
    x_px: f64,
    y_px: f64,
    angle_px_deg: f64,
    /// The verdict in words, the full decision as the log writes it, every measure with its
    /// limit, and the runner-up.
    verdict: String,
    detail: String,
    measures: Vec<Measure>,
    runner_up: Option<String>,
}

/// A camera on the page.
#[derive(Serialize)]
pub struct CameraView {
    unit_id: u8,
    name: String,
    frame_seq: u64,
    frame_label: String,
    /// ACQ_ID and time (seconds since start) of the frame shown.
    frame_acq_id: u16,
    frame_at_s: f64,
    /// The frame's size, pixels (0 before the first).
    frame_width: usize,
    frame_height: usize,
    registers: Vec<RegisterView>,
    status: Vec<Lamp>,
    robot: Option<Vec<Lamp>>,
    frames: u64,
    frame_errors: u64,
    accepted: u64,
    rejected: Vec<(String, u64)>,
    cycle_median_ms: f64,
    cycle_p95_ms: f64,
    /// Cycle-time histogram: counts in bins of `histogram_bin_ms` from 0 (the last bin is open).
    histogram: Vec<u32>,
    histogram_bin_ms: f64,
    parts: Vec<PartView>,
    /// The latest fault and when (seconds since start); `error` says whether ERROR is set now.
    last_error: Option<String>,
    last_error_at_s: f64,
    error: bool,
    /// Median time between the latest frames, s (0 until there are two).
    frame_interval_s: f64,
    job: JobView,
    /// A GenICam camera: what it is and what it delivered.
    genicam: Option<GenicamView>,
    /// Changes whenever the knowledge base does (other pages reload the thumbnails).
    templates_key: String,
    /// Acquisitions kept in the history, and not kept (the history thread was busy).
    history_kept: usize,
    history_dropped: u64,
    /// An image archive is configured: older frames are on disk.
    archive: bool,
}

/// A GenICam camera on the page.
#[derive(Serialize)]
struct GenicamView {
    /// None until the camera was first connected.
    camera: Option<crate::appliance::genicam::CameraInfo>,
    received: u64,
    dropped: u64,
    incomplete: u64,
    reconnects: u64,
}

/// The job in force and the last change, from the same snapshot as the registers.
#[derive(Serialize)]
struct JobView {
    id: u16,
    name: String,
    /// JOB_STATUS's word.
    status: &'static str,
    /// The last JOB_REQUEST (0: none yet).
    request: u16,
    /// Every configured job: (id, name).
    jobs: Vec<(u16, String)>,
    /// The job's calibration.
    calibration: CalibrationView,
}

/// The calibration in force: what it is and how well it fits.
#[derive(Serialize)]
struct CalibrationView {
    /// "scale", "homography" or "plate".
    kind: &'static str,
    /// The start-up log's line for it.
    summary: String,
    /// A plate calibration's figures.
    plate: Option<PlateView>,
}

#[derive(Serialize)]
struct PlateView {
    file: String,
    grid: String,
    rms_px: f64,
    residual_mm_max: f64,
    k1: f64,
    k2: f64,
    /// How far the lens moves the frame's farthest corner, pixels.
    corner_shift_px: f64,
    mirrored: bool,
    scale: f64,
    /// Each touched-up point's residual, mm, in the configured order.
    points_mm: Vec<f64>,
}

fn calibration_view(c: &crate::calibration::Calibration) -> CalibrationView {
    use crate::calibration::Calibration;
    let (kind, plate) = match c {
        Calibration::Scale(_) => ("scale", None),
        Calibration::Homography { .. } => ("homography", None),
        Calibration::Plate(p) => (
            "plate",
            Some(PlateView {
                file: p.file.display().to_string(),
                grid: format!("{} {} x {}, pitch {} mm", p.plate.grid.kind, p.plate.grid.cols, p.plate.grid.rows, p.plate.grid.pitch_mm),
                rms_px: p.plate.fit.rms_px,
                residual_mm_max: p.plate.fit.residual_mm_max,
                k1: p.plate.lens.k1,
                k2: p.plate.lens.k2,
                corner_shift_px: p.plate.lens.corner_shift_px(p.plate.width, p.plate.height),
                mirrored: p.robot.mirrored,
                scale: p.robot.scale,
                points_mm: p.residuals_mm.clone(),
            }),
        ),
    };
    CalibrationView { kind, summary: c.describe(), plate }
}

/// What names a knowledge base's templates: changes whenever one is enrolled or replaced.
pub(super) fn templates_key(kb: &crate::kb::KnowledgeBase) -> String {
    kb.entries
        .iter()
        .map(|e| format!("{}:{}:{}:{}", e.template.type_id, e.template.type_name, e.template.face, e.source))
        .collect::<Vec<_>>()
        .join(",")
}

/// The whole page's state.
#[derive(Serialize)]
pub struct StateView {
    pub(super) uptime_s: f64,
    pub(super) modbus_clients: usize,
    pub(super) modbus_requests: usize,
    pub(super) modbus_exceptions: usize,
    /// The OPC UA server, when it runs.
    pub(super) opcua: Option<OpcuaView>,
    pub(super) can_change: bool,
    pub(super) cameras: Vec<CameraView>,
}

/// The OPC UA server as the page shows it.
#[derive(Serialize)]
pub struct OpcuaView {
    pub(super) endpoint: String,
    pub(super) sessions: u64,
    pub(super) subscriptions: u64,
}

/// One acquisition of the history.
#[derive(Serialize)]
pub struct HistoryView {
    id: u64,
    acq_id: u16,
    at_s: f64,
    time: String,
    label: String,
    accepted: usize,
    rejected: usize,
    error: Option<String>,
    cycle_ms: f64,
    /// Whether a picture was kept (a frame came).
    picture: bool,
    parts: Vec<PartView>,
}

/// Register contents decoded for people: scaled values, signed words, floats, bits by name,
/// codes by word (from the map's own lists) and TYPE_ID by the enrolled type's name.
pub fn decode(words: &[u16], order: WordOrder, type_name: impl Fn(u16) -> Option<String>) -> Vec<RegisterView> {
    MAP.iter()
        .map(|r| {
            let a = r.addr as usize;
            let raw: Vec<u16> = words[a..a + r.kind.words() as usize].to_vec();
            let w = raw[0];
            let value = map::value_text(r, [w, raw.get(1).copied().unwrap_or(0)], order);
            let word = match r.addr {
                map::addr::STATUS => Some(set_bits(w, &map::status::NAMES)),
                map::addr::ROBOT_STATUS => Some(set_bits(w, &map::robot_status::NAMES)),
                map::addr::TYPE_ID | map::addr::EXPECTED_TYPE if w > 0 => type_name(w),
                _ => code_word(r, w).map(str::to_string),
            };
            RegisterView {
                addr: r.addr,
                plc: 400_001 + r.addr as u32,
                name: r.name,
                access: if r.access == map::Access::ReadWrite { "R/W" } else { "R" },
                raw,
                value,
                word,
                unit: r.unit,
            }
        })
        .collect()
}

fn set_bits(word: u16, names: &[&str]) -> String {
    let on: Vec<&str> = names.iter().enumerate().filter(|(i, _)| word & (1 << i) != 0).map(|(_, n)| *n).collect();
    if on.is_empty() { "none".into() } else { on.join(" ") }
}

/// No measurements yet reads 0.
pub fn nan_to_zero(v: f64) -> f64 {
    if v.is_nan() { 0.0 } else { v }
}

/// A camera's state from one snapshot of its registers.
pub fn camera_view(c: &CameraHandle) -> CameraView {
    // The same snapshot the Modbus server serves: one lock, one read of the whole map.
    let (words, order) = {
        let hs = c.handshake.lock().unwrap_or_else(|p| p.into_inner());
        (hs.read(0, map::SIZE), hs.settings().word_order)
    };
    let in_force = c.job();
    let job = {
        let (name, calibration) = (in_force.name.clone(), calibration_view(&in_force.calibration));
        let status = map::lookup(map::addr::JOB_STATUS).and_then(|r| code_word(r, words[map::addr::JOB_STATUS as usize])).unwrap_or("?");
        JobView {
            id: words[map::addr::JOB_ID as usize],
            name,
            status,
            request: words[map::addr::JOB_REQUEST as usize],
            jobs: c.jobs.clone(),
            calibration,
        }
    };
    let (templates_key, names): (String, Vec<(u16, String)>) = {
        let kb = &in_force.templates;
        (templates_key(kb), kb.entries.iter().map(|e| (e.template.type_id, e.template.type_name.clone())).collect())
    };
    let type_name = |id: u16| names.iter().find(|(i, _)| *i == id).map(|(_, n)| n.clone());
    let (history_kept, history_dropped, frame_interval_s) = match &c.history {
        Some(h) => {
            let e = h.entries();
            let mut gaps: Vec<f64> = e.windows(2).rev().take(10).map(|w| w[1].at_s - w[0].at_s).collect();
            gaps.sort_by(f64::total_cmp);
            (e.len(), h.dropped.load(std::sync::atomic::Ordering::Relaxed), gaps.get(gaps.len() / 2).copied().unwrap_or(0.0))
        }
        None => (0, 0, 0.0),
    };
    let live = c.live.lock().unwrap_or_else(|p| p.into_inner());
    let cycles: Vec<f64> = live.cycle_ms.iter().copied().collect();
    let p95 = nan_to_zero(crate::eval::percentile(&cycles, 0.95));
    let bin = ((p95.max(1.0) * 1.25) / 12.0).max(0.5);
    let mut histogram = vec![0u32; 12];
    for v in &cycles {
        histogram[((v / bin) as usize).min(11)] += 1;
    }
    let lamps = |word: u16, names: &[&'static str]| {
        names.iter().enumerate().map(|(i, n)| Lamp { name: n, on: word & (1 << i) != 0 }).collect::<Vec<_>>()
    };
    let status_word = words[map::addr::STATUS as usize];
    let estimate = live.estimate.as_ref().filter(|_| live.frame_acq_id == live.acq_id);
    CameraView {
        unit_id: c.unit_id,
        name: c.name.clone(),
        frame_seq: live.seq,
        frame_label: live.label.clone(),
        frame_acq_id: live.frame_acq_id,
        frame_at_s: live.at_s,
        frame_width: live.frame.as_ref().map_or(0, |f| f.width),
        frame_height: live.frame.as_ref().map_or(0, |f| f.height),
        registers: decode(&words, order, type_name),
        status: lamps(status_word, &map::status::NAMES),
        robot: c.robot.as_ref().map(|_| lamps(words[map::addr::ROBOT_STATUS as usize], &map::robot_status::NAMES)),
        frames: live.frames,
        frame_errors: live.frame_errors,
        accepted: live.accepted,
        rejected: Reason::ALL.iter().skip(1).map(|r| (r.as_str().to_string(), live.rejected[r.index()])).collect(),
        cycle_median_ms: nan_to_zero(crate::eval::percentile(&cycles, 0.5)),
        cycle_p95_ms: p95,
        histogram,
        histogram_bin_ms: bin,
        parts: part_views(&live.results, estimate),
        last_error: live.last_error.clone(),
        last_error_at_s: live.last_error_at_s,
        error: status_word & map::status::ERROR != 0,
        frame_interval_s,
        job,
        genicam: c.genicam.as_ref().map(|g| {
            use std::sync::atomic::Ordering::Relaxed;
            let info = g.info.lock().unwrap_or_else(|p| p.into_inner()).clone();
            GenicamView {
                camera: info,
                received: g.received.load(Relaxed),
                dropped: g.dropped.load(Relaxed),
                incomplete: g.incomplete.load(Relaxed),
                reconnects: g.reconnects.load(Relaxed),
            }
        }),
        templates_key,
        history_kept,
        history_dropped,
        archive: c.archive.is_some(),
    }
}

/// An acquisition's final results, each with its estimate when the frame was estimated (its
/// parts in the results' order: part `i` has PART_INDEX `i + 1`).
pub fn part_views(results: &[Queued], estimate: Option<&FrameEstimate>) -> Vec<PartView> {
    let decision = map::lookup(map::addr::DECISION).expect("DECISION is in the map");
    results
        .iter()
        .map(|r| {
            let p = estimate.and_then(|fe| fe.parts.get((r.index as usize).wrapping_sub(1))).filter(|_| r.is_part());
            PartView {
                acq_id: r.acq_id,
                index: r.index,
                accepted: r.part.accepted,
                decision: code_word(decision, if r.part.accepted { 1 } else { 2 }).unwrap_or("?"),
                reason: r.part.reason.as_str(),
                reason_code: crate::registers::reason_code(r.part.reason),
                type_id: r.part.type_id,
                type_name: p.and_then(|p| p.type_name.clone()),
                face: p.and_then(|p| p.face.map(|f| f.as_str())),
                angle_deg: map::angle_of_word(map::angle_word(r.part.angle_deg)),
                x_mm: r.part.x_mm as f32 as f64,
                y_mm: r.part.y_mm as f32 as f64,
                confidence: r.part.confidence,
                x_px: p.map(|p| p.x).unwrap_or(0.0),
                y_px: p.map(|p| p.y).unwrap_or(0.0),
                angle_px_deg: p.map(|p| p.angle_deg).unwrap_or(0.0),
                verdict: p.map(|p| p.decision.verdict.to_string()).unwrap_or_else(|| r.part.reason.as_str().to_string()),
                detail: p.map(|p| p.detail()).unwrap_or_else(|| r.part.reason.as_str().to_string()),
                measures: p.map(|p| p.decision.measures()).unwrap_or_default(),
                runner_up: p.and_then(|p| p.decision.runner_up()),
            }
        })
        .collect()
}

/// A history entry for the page.
pub fn history_view(e: &Entry) -> HistoryView {
    let parts = part_views(&e.results, e.estimate.as_ref());
    HistoryView {
        id: e.id,
        acq_id: e.acq_id,
        at_s: e.at_s,
        time: e.time.clone(),
        label: e.label.clone(),
        accepted: parts.iter().filter(|p| p.accepted).count(),
        rejected: parts.iter().filter(|p| !p.accepted).count(),
        error: e.error.clone(),
        cycle_ms: e.cycle_ms,
        picture: e.picture.is_some(),
        parts,
    }
}
