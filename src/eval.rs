//! Scoring estimates against ground truth (pure: records in, report out).
//!
//! Predicted parts are matched to true parts one-to-one by nearest centroid (closest pairs
//! first, within [`MATCH_RADIUS`]). A true part counts as *pose-correct* when its match names the
//! right type and face and the angle is within 2 degrees, accepted or not; *pass-through* is the
//! fraction accepted. A *false accept* is an accepted estimate that is wrong (type, face, or angle
//! off by more than 5 degrees), that sits on a part of a type not enrolled, or that matches no
//! true part at all (an empty belt, a merged blob).

use std::collections::BTreeMap;

use serde::Serialize;

use crate::truth::{EstimatePart, TruthRecord, UNCOVERED};
use crate::vision::geometry::angle_diff_deg;

/// Farthest a prediction may be from a true part's centroid to be its estimate, pixels.
pub const MATCH_RADIUS: f64 = 60.0;
/// A pose is right when its angle is within this of the truth (and its position within 5 px).
pub const POSE_TOLERANCE_DEG: f64 = 2.0;
/// An accept whose type, face or angle (beyond this) is wrong is a false accept.
pub const FALSE_ACCEPT_DEG: f64 = 5.0;

/// One image's estimate as the evaluator needs it.
#[derive(Debug, Clone)]
pub struct Observation {
    /// What the frame holds.
    pub truth: TruthRecord,
    /// What the estimator said.
    pub parts: Vec<EstimatePart>,
    /// Estimate time, ms.
    pub elapsed_ms: f64,
}

/// Counters and samples of one group.
#[derive(Debug, Clone, Default)]
struct Acc {
    frames: usize,
    parts: usize,
    unknown_parts: usize,
    unknown_rejected: usize,
    type_ok: usize,
    face_ok: usize,
    pose_ok: usize,
    accepted: usize,
    /// Accepted with the right pose (pick), and the same over the parts nothing covers (top).
    picked: usize,
    uncovered: usize,
    uncovered_picked: usize,
    /// Accepted parts that another part partly covers: a robot would drag the one on top.
    covered_accepts: usize,
    false_accepts: usize,
    angle_err: Vec<f64>,
    centroid_err: Vec<f64>,
    latency: Vec<f64>,
}

/// Summary of one group, as printed.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct GroupReport {
    /// The group's name ("overall", a condition, a type, a noise band).
    pub group: String,
    /// Frames in the group.
    pub frames: usize,
    /// True parts of enrolled types.
    pub parts: usize,
    /// Parts whose type was named right.
    pub type_accuracy: f64,
    /// Parts whose type and face were named right.
    pub face_accuracy: f64,
    /// Parts with type, face and pose right (accepted or not).
    pub pose_accuracy: f64,
    /// Angle error of the right-type parts, degrees.
    pub angle_err_mean: f64,
    /// See `angle_err_mean`.
    pub angle_err_median: f64,
    /// See `angle_err_mean`.
    pub angle_err_p95: f64,
    /// Position error of the right-type parts, pixels.
    pub centroid_err_median: f64,
    /// See `centroid_err_median`.
    pub centroid_err_p95: f64,
    /// Accepted over parts of enrolled types (whatever the pose).
    pub pass_through: f64,
    /// Accepted and pose right, over every part of an enrolled type.
    pub pick: f64,
    /// Accepted and pose right, over the parts nothing covers (visible fraction >= 0.98).
    pub top: f64,
    /// Parts nothing covers, the denominator of `top`.
    pub uncovered_parts: usize,
    /// Accepted parts with a visible fraction below 0.98 (must be 0).
    pub covered_accepts: usize,
    /// Accepts with a wrong type, face or pose.
    pub false_accepts: usize,
    /// Parts of types not enrolled, and how many of them were rejected.
    pub unknown_parts: usize,
    /// See `unknown_parts`.
    pub unknown_rejected: usize,
    /// Estimate time per frame, ms.
    pub latency_median_ms: f64,
    /// See `latency_median_ms`.
    pub latency_p95_ms: f64,
}

/// The evaluation of a truth file's frames, overall and by group.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Report {
    /// Every frame.
    pub overall: GroupReport,
    /// By scene condition.
    pub by_condition: Vec<GroupReport>,
    /// By part type.
    pub by_type: Vec<GroupReport>,
    /// By noise band.
    pub by_noise: Vec<GroupReport>,
    /// Every false accept, described (image, what was accepted, what was there).
    pub false_accept_details: Vec<String>,
}

/// The `q` quantile of `v` (0..=1), interpolated between the nearest ranks; NaN when `v` is
/// empty. The one percentile of the crate: the evaluation's tables and the operator view's
/// cycle times and metrics alike.
pub fn percentile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let pos = q * (s.len() - 1) as f64;
    let i = pos.floor() as usize;
    let j = (i + 1).min(s.len() - 1);
    s[i] + (s[j] - s[i]) * (pos - i as f64)
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 { f64::NAN } else { a as f64 / b as f64 }
}

impl Acc {
    fn report(&self, group: String) -> GroupReport {
        GroupReport {
            group,
            frames: self.frames,
            parts: self.parts,
            type_accuracy: ratio(self.type_ok, self.parts),
            face_accuracy: ratio(self.face_ok, self.parts),
            pose_accuracy: ratio(self.pose_ok, self.parts),
            angle_err_mean: if self.angle_err.is_empty() {
                f64::NAN
            } else {
                self.angle_err.iter().sum::<f64>() / self.angle_err.len() as f64
            },
            angle_err_median: percentile(&self.angle_err, 0.5),
            angle_err_p95: percentile(&self.angle_err, 0.95),
            centroid_err_median: percentile(&self.centroid_err, 0.5),
            centroid_err_p95: percentile(&self.centroid_err, 0.95),
            pass_through: ratio(self.accepted, self.parts),
            pick: ratio(self.picked, self.parts),
            top: ratio(self.uncovered_picked, self.uncovered),
            uncovered_parts: self.uncovered,
            covered_accepts: self.covered_accepts,
            false_accepts: self.false_accepts,
            unknown_parts: self.unknown_parts,
            unknown_rejected: self.unknown_rejected,
            latency_median_ms: percentile(&self.latency, 0.5),
            latency_p95_ms: percentile(&self.latency, 0.95),
        }
    }
}

/// Scores observations; `enrolled` are the type names in the knowledge base.
pub fn evaluate(obs: &[Observation], enrolled: &[String]) -> Report {
    let mut overall = Acc::default();
    let mut by_cond: BTreeMap<String, Acc> = BTreeMap::new();
    let mut by_type: BTreeMap<String, Acc> = BTreeMap::new();
    let mut by_noise: BTreeMap<i64, Acc> = BTreeMap::new();
    let mut details = Vec::new();

    for o in obs {
        let cond = o.truth.condition.clone();
        let noise_bucket = ((o.truth.noise_sigma / 10.0).round() * 10.0) as i64;
        for acc in [&mut overall, by_cond.entry(cond.clone()).or_default(), by_noise.entry(noise_bucket).or_default()] {
            acc.frames += 1;
            acc.latency.push(o.elapsed_ms);
        }
        // Closest pairs first, one-to-one.
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (ti, t) in o.truth.parts.iter().enumerate() {
            for (pi, p) in o.parts.iter().enumerate() {
                let d = (t.x_px - p.x_px).hypot(t.y_px - p.y_px);
                if d <= MATCH_RADIUS {
                    pairs.push((d, ti, pi));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut t_match = vec![None; o.truth.parts.len()];
        let mut p_used = vec![false; o.parts.len()];
        for (_, ti, pi) in pairs {
            if t_match[ti].is_none() && !p_used[pi] {
                t_match[ti] = Some(pi);
                p_used[pi] = true;
            }
        }
        for (ti, t) in o.truth.parts.iter().enumerate() {
            let known = enrolled.iter().any(|n| n == &t.type_name);
            let pred = t_match[ti].map(|pi| &o.parts[pi]);
            let type_ok = pred.is_some_and(|p| p.type_name.as_deref() == Some(t.type_name.as_str()));
            let face_ok = type_ok && pred.is_some_and(|p| p.face.as_deref() == Some(t.face.as_str()));
            let aerr = pred.map(|p| angle_diff_deg(p.angle_deg, t.angle_deg).abs()).unwrap_or(f64::INFINITY);
            let cerr = pred.map(|p| (p.x_px - t.x_px).hypot(p.y_px - t.y_px)).unwrap_or(f64::INFINITY);
            let accepted = pred.is_some_and(|p| p.accepted);
            let false_accept = accepted && (!known || !face_ok || aerr > FALSE_ACCEPT_DEG);
            if false_accept {
                let p = pred.expect("accepted implies matched");
                details.push(format!(
                    "{}: accepted {} {} {:.2} deg at ({:.1}, {:.1}) on a {} {} {:.2} deg at ({:.1}, {:.1})",
                    o.truth.image,
                    p.type_name.as_deref().unwrap_or("?"),
                    p.face.as_deref().unwrap_or("?"),
                    p.angle_deg,
                    p.x_px,
                    p.y_px,
                    t.type_name,
                    t.face,
                    t.angle_deg,
                    t.x_px,
                    t.y_px
                ));
            }
            for acc in [
                &mut overall,
                by_cond.entry(cond.clone()).or_default(),
                by_type.entry(t.type_name.clone()).or_default(),
                by_noise.entry(noise_bucket).or_default(),
            ] {
                if false_accept {
                    acc.false_accepts += 1;
                }
                if !known {
                    acc.unknown_parts += 1;
                    if !accepted {
                        acc.unknown_rejected += 1;
                    }
                    continue;
                }
                acc.parts += 1;
                acc.type_ok += type_ok as usize;
                acc.face_ok += face_ok as usize;
                let pose_ok = face_ok && aerr <= POSE_TOLERANCE_DEG;
                let uncovered = t.visible_fraction >= UNCOVERED;
                acc.pose_ok += pose_ok as usize;
                acc.accepted += accepted as usize;
                acc.picked += (accepted && pose_ok) as usize;
                acc.uncovered += uncovered as usize;
                acc.uncovered_picked += (uncovered && accepted && pose_ok) as usize;
                acc.covered_accepts += (!uncovered && accepted) as usize;
                if face_ok {
                    acc.angle_err.push(aerr);
                    acc.centroid_err.push(cerr);
                }
            }
        }
        for (pi, p) in o.parts.iter().enumerate() {
            if !p_used[pi] && p.accepted {
                details.push(format!(
                    "{}: accepted {} {} at ({:.1}, {:.1}) where no part is",
                    o.truth.image,
                    p.type_name.as_deref().unwrap_or("?"),
                    p.face.as_deref().unwrap_or("?"),
                    p.x_px,
                    p.y_px
                ));
                for acc in [&mut overall, by_cond.entry(cond.clone()).or_default(), by_noise.entry(noise_bucket).or_default()] {
                    acc.false_accepts += 1;
                }
            }
        }
    }
    Report {
        overall: overall.report("all".into()),
        by_condition: by_cond.into_iter().map(|(k, v)| v.report(k)).collect(),
        by_type: by_type.into_iter().map(|(k, v)| v.report(k)).collect(),
        by_noise: by_noise.into_iter().map(|(k, v)| v.report(format!("sigma~{k}"))).collect(),
        false_accept_details: details,
    }
}

fn pct(v: f64) -> String {
    if v.is_nan() { "-".into() } else { format!("{:.1}%", 100.0 * v) }
}
fn num(v: f64, prec: usize) -> String {
    if v.is_nan() { "-".into() } else { format!("{v:.prec$}") }
}

/// The report as fixed-width text tables.
pub fn render_text(r: &Report) -> String {
    let mut s = String::new();
    let header = format!(
        "{:<14} {:>6} {:>6} {:>7} {:>7} {:>7} {:>7} {:>7} {:>5} {:>8} {:>8} {:>8} {:>8} {:>8} {:>7} {:>5} {:>7} {:>8} {:>8}\n",
        "group",
        "frames",
        "parts",
        "pick",
        "top",
        "cov.A",
        "type",
        "face",
        "pose",
        "ang.mean",
        "ang.med",
        "ang.p95",
        "xy.med",
        "xy.p95",
        "pass",
        "FA",
        "unk.rej",
        "lat.med",
        "lat.p95"
    );
    let row = |g: &GroupReport| {
        format!(
            "{:<14} {:>6} {:>6} {:>7} {:>7} {:>7} {:>7} {:>7} {:>5} {:>8} {:>8} {:>8} {:>8} {:>8} {:>7} {:>5} {:>7} {:>8} {:>8}\n",
            g.group,
            g.frames,
            g.parts,
            pct(g.pick),
            pct(g.top),
            g.covered_accepts,
            pct(g.type_accuracy),
            pct(g.face_accuracy),
            pct(g.pose_accuracy),
            num(g.angle_err_mean, 3),
            num(g.angle_err_median, 3),
            num(g.angle_err_p95, 3),
            num(g.centroid_err_median, 2),
            num(g.centroid_err_p95, 2),
            pct(g.pass_through),
            g.false_accepts,
            format!("{}/{}", g.unknown_rejected, g.unknown_parts),
            num(g.latency_median_ms, 1),
            num(g.latency_p95_ms, 1),
        )
    };
    for (title, groups) in [("by condition", &r.by_condition), ("by type", &r.by_type), ("by noise sigma", &r.by_noise)] {
        s.push_str(&format!("\n{title}\n"));
        s.push_str(&header);
        for g in groups.iter() {
            s.push_str(&row(g));
        }
    }
    s.push_str("\noverall\n");
    s.push_str(&header);
    s.push_str(&row(&r.overall));
    s.push_str("\n(angles in degrees, xy in pixels, latency in ms per frame; pose = type and face right and angle within 2 deg; pick = accepted and pose right; top = pick over the parts nothing covers (visible fraction >= 0.98); cov.A = accepted parts that something covers; FA = false accepts)\n");
    if r.false_accept_details.is_empty() {
        s.push_str("no false accepts\n");
    } else {
        s.push_str("false accepts:\n");
        for d in &r.false_accept_details {
            s.push_str(&format!("  {d}\n"));
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::truth::TruthPart;

    fn part(t: &str, face: &str, a: f64, x: f64, y: f64, accepted: bool) -> EstimatePart {
        EstimatePart {
            type_name: Some(t.into()),
            type_id: 1,
            face: Some(face.into()),
            angle_deg: a,
            x_px: x,
            y_px: y,
            confidence: 0.9,
            accepted,
            reason: if accepted { "ok".into() } else { "low confidence".into() },
        }
    }
    fn truth(cond: &str, parts: Vec<TruthPart>) -> TruthRecord {
        TruthRecord { image: "images/x.png".into(), condition: cond.into(), noise_sigma: 1.0, parts }
    }
    fn tp(t: &str, face: &str, a: f64, x: f64, y: f64) -> TruthPart {
        TruthPart {
            type_name: t.into(),
            face: face.into(),
            angle_deg: a,
            x_px: x,
            y_px: y,
            visible_fraction: 1.0,
            x_mm: None,
            y_mm: None,
            robot_angle_deg: None,
        }
    }

    #[test]
    fn counts_pose_wrap_around_and_false_accepts() {
        let enrolled = vec!["A".to_string()];
        let obs = vec![
            // Right within 2 degrees across the 0/360 wrap.
            Observation {
                truth: truth("clean", vec![tp("A", "up", 359.5, 100.0, 100.0)]),
                parts: vec![part("A", "up", 0.7, 100.5, 100.0, true)],
                elapsed_ms: 5.0,
            },
            // Wrong face, accepted: a false accept.
            Observation {
                truth: truth("clean", vec![tp("A", "up", 10.0, 100.0, 100.0)]),
                parts: vec![part("A", "down", 10.0, 100.0, 100.0, true)],
                elapsed_ms: 7.0,
            },
            // Accepted on an empty belt.
            Observation { truth: truth("empty", vec![]), parts: vec![part("A", "up", 0.0, 500.0, 500.0, true)], elapsed_ms: 3.0 },
            // Unknown type, rejected: fine.
            Observation {
                truth: truth("unknown", vec![tp("D", "up", 0.0, 50.0, 50.0)]),
                parts: vec![part("A", "up", 0.0, 50.0, 50.0, false)],
                elapsed_ms: 4.0,
            },
        ];
        let r = evaluate(&obs, &enrolled);
        assert_eq!(r.overall.parts, 2);
        assert_eq!(r.overall.pose_accuracy, 0.5);
        assert_eq!(r.overall.false_accepts, 2);
        assert_eq!((r.overall.unknown_parts, r.overall.unknown_rejected), (1, 1));
        assert!((r.overall.angle_err_median - 1.2).abs() < 1e-9, "{}", r.overall.angle_err_median);
        assert_eq!(r.false_accept_details.len(), 2);
        let text = render_text(&r);
        assert!(text.contains("empty") && text.contains("false accepts:"));
    }
}
