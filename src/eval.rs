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

use crate::truth::{Catalog, EstimatePart, TruthPart, TruthRecord, UNCOVERED};
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
    /// How the parts of never-enrolled types ended, by REASON (`accepted` and `not found` too):
    /// an *unknown type* tells the operator to enrol it, *touching* or *ambiguous* does not.
    pub unknown_by_reason: BTreeMap<String, usize>,
    /// Every part named as another type than its own, by pair, accepted or not.
    pub taken_for: Vec<TakenFor>,
    /// With a catalogue: each member of a revision family, how often it was picked and how often
    /// taken for a sibling.
    pub families: Vec<FamilyMember>,
}

/// Parts of one type named as another.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TakenFor {
    /// The type the parts are.
    pub truth: String,
    /// The type they were named as.
    pub named: String,
    /// Both in one revision family (from the catalogue).
    pub siblings: bool,
    /// Of those, accepted (each a false accept).
    pub accepted: usize,
    /// Of those, rejected.
    pub rejected: usize,
}

/// One member of a revision family and how its parts ended.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct FamilyMember {
    /// The family.
    pub family: String,
    /// The type.
    pub type_name: String,
    /// The type it is a revision of.
    pub parent: Option<String>,
    /// Enrolled.
    pub known: bool,
    /// Its parts in the scenes.
    pub parts: usize,
    /// Accepted with the right type, face and pose.
    pub picked: usize,
    /// Accepted as a sibling (false accepts).
    pub sibling_accepted: usize,
    /// Rejected while named as a sibling.
    pub sibling_rejected: usize,
    /// Rejected, by REASON (`not found` when no estimate was near).
    pub rejected_by_reason: BTreeMap<String, usize>,
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

/// One true part with its estimate and what every table asks of them, judged once.
struct Judged<'a> {
    truth: &'a TruthPart,
    pred: Option<&'a EstimatePart>,
    /// Its type is enrolled.
    known: bool,
    accepted: bool,
    type_ok: bool,
    /// Type and face right.
    face_ok: bool,
    angle_err: f64,
    centroid_err: f64,
}

impl Judged<'_> {
    /// Type and face right and the angle within [`POSE_TOLERANCE_DEG`].
    fn pose_ok(&self) -> bool {
        self.face_ok && self.angle_err <= POSE_TOLERANCE_DEG
    }
    /// Accepted, and unknown, wrong or turned beyond [`FALSE_ACCEPT_DEG`].
    fn false_accept(&self) -> bool {
        self.accepted && (!self.known || !self.face_ok || self.angle_err > FALSE_ACCEPT_DEG)
    }
}

/// An observation's true parts judged against their estimates, paired closest first,
/// one-to-one, within [`MATCH_RADIUS`]; and which estimates are some part's.
fn judge<'a>(o: &'a Observation, enrolled: &[String]) -> (Vec<Judged<'a>>, Vec<bool>) {
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
    let judged = o
        .truth
        .parts
        .iter()
        .zip(t_match)
        .map(|(t, m)| {
            let pred = m.map(|pi| &o.parts[pi]);
            let type_ok = pred.is_some_and(|p| p.type_name.as_deref() == Some(t.type_name.as_str()));
            Judged {
                truth: t,
                pred,
                known: enrolled.iter().any(|n| n == &t.type_name),
                accepted: pred.is_some_and(|p| p.accepted),
                type_ok,
                face_ok: type_ok && pred.is_some_and(|p| p.face.as_deref() == Some(t.face.as_str())),
                angle_err: pred.map(|p| angle_diff_deg(p.angle_deg, t.angle_deg).abs()).unwrap_or(f64::INFINITY),
                centroid_err: pred.map(|p| (p.x_px - t.x_px).hypot(p.y_px - t.y_px)).unwrap_or(f64::INFINITY),
            }
        })
        .collect();
    (judged, p_used)
}

/// Scores observations; `enrolled` are the type names in the knowledge base.
pub fn evaluate(obs: &[Observation], enrolled: &[String]) -> Report {
    evaluate_catalogue(obs, enrolled, None)
}

/// [`evaluate`], and with a catalogue the story of its revision families.
pub fn evaluate_catalogue(obs: &[Observation], enrolled: &[String], catalog: Option<&Catalog>) -> Report {
    let judged: Vec<_> = obs.iter().map(|o| judge(o, enrolled)).collect();
    let mut report = evaluate_frames(obs, &judged);
    let family_of = |name: &str| catalog.and_then(|c| c.types.iter().find(|t| t.name == name)).and_then(|t| t.family.clone());
    let mut taken: BTreeMap<(String, String), (usize, usize)> = BTreeMap::new();
    let mut members: Vec<FamilyMember> = catalog
        .map(|c| {
            c.types
                .iter()
                .filter_map(|t| {
                    Some(FamilyMember {
                        family: t.family.clone()?,
                        type_name: t.name.clone(),
                        parent: t.parent.clone(),
                        known: t.known,
                        parts: 0,
                        picked: 0,
                        sibling_accepted: 0,
                        sibling_rejected: 0,
                        rejected_by_reason: BTreeMap::new(),
                    })
                })
                .collect()
        })
        .unwrap_or_default();
    members.sort_by(|a, b| (&a.family, &a.type_name).cmp(&(&b.family, &b.type_name)));
    for j in judged.iter().flat_map(|(parts, _)| parts) {
        let t = j.truth;
        let named = j.pred.and_then(|p| p.type_name.clone()).filter(|n| *n != t.type_name);
        if let Some(n) = &named {
            let e = taken.entry((t.type_name.clone(), n.clone())).or_default();
            if j.accepted { e.0 += 1 } else { e.1 += 1 }
        }
        let reason = || j.pred.map_or("not found".to_string(), |p| p.reason.clone());
        if !j.known {
            *report.unknown_by_reason.entry(if j.accepted { "accepted".to_string() } else { reason() }).or_default() += 1;
        }
        if let Some(m) = members.iter_mut().find(|m| m.type_name == t.type_name) {
            m.parts += 1;
            let sibling = named.as_deref().is_some_and(|n| family_of(n).as_deref() == Some(m.family.as_str()));
            match (j.accepted, sibling) {
                (true, true) => m.sibling_accepted += 1,
                (true, false) if j.known && j.pose_ok() => m.picked += 1,
                (true, false) => *m.rejected_by_reason.entry("accepted wrong".into()).or_default() += 1,
                (false, true) => m.sibling_rejected += 1,
                (false, false) => *m.rejected_by_reason.entry(reason()).or_default() += 1,
            }
        }
    }
    report.taken_for = taken
        .into_iter()
        .map(|((truth, named), (accepted, rejected))| {
            let siblings = family_of(&truth).is_some_and(|f| family_of(&named).as_deref() == Some(f.as_str()));
            TakenFor { truth, named, siblings, accepted, rejected }
        })
        .collect();
    report.families = members;
    report
}

/// The per-frame tables and false accepts.
fn evaluate_frames(obs: &[Observation], judged: &[(Vec<Judged<'_>>, Vec<bool>)]) -> Report {
    let mut overall = Acc::default();
    let mut by_cond: BTreeMap<String, Acc> = BTreeMap::new();
    let mut by_type: BTreeMap<String, Acc> = BTreeMap::new();
    let mut by_noise: BTreeMap<i64, Acc> = BTreeMap::new();
    let mut details = Vec::new();

    for (o, (parts, p_used)) in obs.iter().zip(judged) {
        let cond = o.truth.condition.clone();
        let noise_bucket = ((o.truth.noise_sigma / 10.0).round() * 10.0) as i64;
        for acc in [&mut overall, by_cond.entry(cond.clone()).or_default(), by_noise.entry(noise_bucket).or_default()] {
            acc.frames += 1;
            acc.latency.push(o.elapsed_ms);
        }
        for j in parts {
            let t = j.truth;
            let (known, accepted, false_accept) = (j.known, j.accepted, j.false_accept());
            if false_accept {
                let p = j.pred.expect("accepted implies matched");
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
                acc.type_ok += j.type_ok as usize;
                acc.face_ok += j.face_ok as usize;
                let pose_ok = j.pose_ok();
                let uncovered = t.visible_fraction >= UNCOVERED;
                acc.pose_ok += pose_ok as usize;
                acc.accepted += accepted as usize;
                acc.picked += (accepted && pose_ok) as usize;
                acc.uncovered += uncovered as usize;
                acc.uncovered_picked += (uncovered && accepted && pose_ok) as usize;
                acc.covered_accepts += (!uncovered && accepted) as usize;
                if j.face_ok {
                    acc.angle_err.push(j.angle_err);
                    acc.centroid_err.push(j.centroid_err);
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
        unknown_by_reason: BTreeMap::new(),
        taken_for: Vec::new(),
        families: Vec::new(),
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
    let counts = |m: &BTreeMap<String, usize>| m.iter().map(|(k, v)| format!("{k} {v}")).collect::<Vec<_>>().join(", ");
    if !r.unknown_by_reason.is_empty() {
        s.push_str(&format!("unknown parts (types not enrolled), how they ended: {}\n", counts(&r.unknown_by_reason)));
    }
    if !r.taken_for.is_empty() {
        s.push_str("parts named as another type (accepted / rejected):\n");
        for t in &r.taken_for {
            let sib = if t.siblings { " (siblings)" } else { "" };
            s.push_str(&format!("  {} as {}{sib}: {} / {}\n", t.truth, t.named, t.accepted, t.rejected));
        }
    }
    if !r.families.is_empty() {
        s.push_str("\nrevision families (catalog.json)\n");
        s.push_str(&format!(
            "{:<8} {:<10} {:<10} {:>5} {:>5} {:>6} {:>9} {:>9}  {}\n",
            "family", "type", "parent", "known", "parts", "picked", "sib.acc", "sib.rej", "otherwise, by reason"
        ));
        for m in &r.families {
            s.push_str(&format!(
                "{:<8} {:<10} {:<10} {:>5} {:>5} {:>6} {:>9} {:>9}  {}\n",
                m.family,
                m.type_name,
                m.parent.as_deref().unwrap_or("-"),
                if m.known { "yes" } else { "no" },
                m.parts,
                m.picked,
                m.sibling_accepted,
                m.sibling_rejected,
                counts(&m.rejected_by_reason)
            ));
        }
        s.push_str("(sib.acc = accepted as a sibling of its family: a false accept; sib.rej = rejected while named as a sibling; otherwise: rejected by REASON, not found, or accepted wrong)\n");
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

    fn named(t: &str, accepted: bool, reason: &str, x: f64) -> EstimatePart {
        EstimatePart { reason: reason.into(), ..part(t, "up", 0.0, x, 100.0, accepted) }
    }

    /// A family P (parent) and R (revision), an unseen revision N of R and an unknown X: each
    /// sibling taken for another is counted per member, the unknowns by how they ended.
    #[test]
    fn tells_the_catalogues_story() {
        use crate::truth::{CatalogType, parse_catalog};
        let ty = |name: &str, known: bool, family: Option<&str>, parent: Option<&str>| CatalogType {
            name: name.into(),
            known,
            family: family.map(Into::into),
            revision: None,
            parent: parent.map(Into::into),
            change: None,
        };
        let catalog = Catalog {
            types: vec![
                ty("P", true, Some("F1"), None),
                ty("R", true, Some("F1"), Some("P")),
                ty("N", false, Some("F1"), Some("R")),
                ty("X", false, None, None),
            ],
        };
        let enrolled = vec!["P".to_string(), "R".to_string()];
        let scene =
            |parts: Vec<TruthPart>, est: Vec<EstimatePart>| Observation { truth: truth("multi", parts), parts: est, elapsed_ms: 1.0 };
        let obs = vec![
            // P picked, R taken for P (accepted), R named P but rejected as ambiguous.
            scene(
                vec![tp("P", "up", 0.0, 100.0, 100.0), tp("R", "up", 0.0, 400.0, 100.0), tp("R", "up", 0.0, 700.0, 100.0)],
                vec![named("P", true, "ok", 100.0), named("P", true, "ok", 400.0), named("P", false, "ambiguous", 700.0)],
            ),
            // N accepted as R; X rejected as an unknown type; R not found at all.
            scene(
                vec![tp("N", "up", 0.0, 100.0, 100.0), tp("X", "up", 0.0, 400.0, 100.0), tp("R", "up", 0.0, 900.0, 100.0)],
                vec![
                    named("R", true, "ok", 100.0),
                    EstimatePart { type_name: None, face: None, ..named("P", false, "unknown type", 400.0) },
                ],
            ),
        ];
        let r = evaluate_catalogue(&obs, &enrolled, Some(&catalog));
        assert_eq!(r.unknown_by_reason, BTreeMap::from([("accepted".to_string(), 1), ("unknown type".to_string(), 1)]));
        let pairs: Vec<_> = r.taken_for.iter().map(|t| (t.truth.as_str(), t.named.as_str(), t.siblings, t.accepted, t.rejected)).collect();
        assert_eq!(pairs, [("N", "R", true, 1, 0), ("R", "P", true, 1, 1)]);
        let row = |name: &str| r.families.iter().find(|m| m.type_name == name).unwrap();
        assert_eq!((row("P").parts, row("P").picked, row("P").sibling_accepted), (1, 1, 0));
        assert_eq!((row("R").parts, row("R").picked, row("R").sibling_accepted, row("R").sibling_rejected), (3, 0, 1, 1));
        assert_eq!(row("R").rejected_by_reason, BTreeMap::from([("not found".to_string(), 1)]));
        assert_eq!((row("N").known, row("N").sibling_accepted), (false, 1));
        assert!(r.families.iter().all(|m| m.type_name != "X"), "a type of no family has no row");
        let text = render_text(&r);
        assert!(text.contains("revision families") && text.contains("R as P (siblings): 1 / 1"), "{text}");
        // The catalogue format of ../shared/samples-catalog.
        let c = parse_catalog(
            r#"{"types": [{"name": "T005", "known": true, "family": "F01", "revision": 1, "parent": "T003", "change": {"kind": "add_notch", "what": "extra notch 3.2 mm deep", "delta_mm": 3.23, "hausdorff_mm": 4.63}, "size_mm": [93.2, 86.5, 37.2]}]}"#,
            "catalog.json",
        )
        .unwrap();
        assert_eq!(c.types[0].change.as_ref().map(|c| c.delta_mm), Some(3.23));
        assert!(parse_catalog("{}", "catalog.json").unwrap_err().starts_with("catalog.json:"));
    }
}
