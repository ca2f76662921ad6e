//! Where two templates placed on one part differ, and what the part's outline does there.
//!
//! A global fit hardly moves when two templates differ by one lug or notch a few millimetres
//! deep: most of their outlines coincide, and the fraction that does not is within any margin a
//! fit can afford. Design revisions of one part differ exactly like that. Placed at the poses
//! the registration found for each, the stretches where one template's outline runs farther
//! than `apart` from the other's are the only places that can tell them apart; there the part's
//! own outline lies on one of them, on neither, or tells nothing (the stretch is hidden, or
//! there is none). [`super::decide::Local::follows`] reads the answer.

use super::decide::{Departure, Local};
use super::geometry::{Pt, Similarity};
use super::register::{MAX_REACH, OutlineIndex};

/// How far apart two outlines must be to differ, and along how much of them, when an outline
/// within `near` of another counts as on it: three times it (a notch or lug shallower than that
/// is the outline's noise), on runs twice that long (shorter ones are the placements' jitter at
/// corners). One rule for telling siblings apart and for a part's departure from its template.
pub fn separation(near: f64) -> (f64, f64) {
    let apart = 3.0 * near;
    (apart, 2.0 * apart)
}

/// A template placed on the part: its outline's index (template pixels), its pose (template to
/// frame pixels) and its centroid (template pixels, for naming where a stretch lies).
#[derive(Clone, Copy)]
pub struct Placed<'a> {
    /// The template's outline.
    pub index: &'a OutlineIndex,
    /// Template pixels to frame pixels.
    pub pose: Similarity,
    /// The template's centroid, template pixels.
    pub centroid: Pt,
}

/// Compares templates `best` and `rival` on a part whose outline is indexed as `part` (frame
/// pixels): points of either template's outline farther than `apart` from the other's, on runs
/// at least `min_run` long (frame pixels; shorter ones are the placements' jitter at corners),
/// and of those the fraction within `near` of the part's outline.
pub fn compare(part: &OutlineIndex, best: Placed<'_>, rival: Placed<'_>, near: f64, apart: f64, min_run: f64) -> Local {
    let b = stretches(part, best, rival, near, apart, min_run);
    let r = stretches(part, rival, best, near, apart, min_run);
    let longest = if b.longest.0 >= r.longest.0 { (b.longest, best) } else { (r.longest, rival) };
    let ((_, mid), on) = longest;
    let at = mid.map(|q| {
        let v = on.pose.inverse().apply(q) - on.centroid;
        v.y.atan2(v.x).to_degrees().rem_euclid(360.0)
    });
    Local {
        best_len: b.len,
        best_follows: if b.len > 0.0 { b.followed / b.len } else { 0.0 },
        rival_len: r.len,
        rival_follows: if r.len > 0.0 { r.followed / r.len } else { 0.0 },
        apart,
        at_deg: at.unwrap_or(0.0),
    }
}

/// One template's stretches apart from the other's.
struct Stretches {
    /// Their total length, frame pixels.
    len: f64,
    /// Of it, the length the part's outline follows.
    followed: f64,
    /// The longest: its length and middle point (frame pixels).
    longest: (f64, Option<Pt>),
}

fn stretches(part: &OutlineIndex, this: Placed<'_>, other: Placed<'_>, near: f64, apart: f64, min_run: f64) -> Stretches {
    let frame: Vec<Pt> = this.index.outline().iter().map(|&q| this.pose.apply(q)).collect();
    let to_other = other.pose.inverse();
    let reach = apart / other.pose.scale;
    let off: Vec<bool> = frame.iter().map(|&q| !other.index.any_within(to_other.apply(q), reach)).collect();
    let mut out = Stretches { len: 0.0, followed: 0.0, longest: (0.0, None) };
    for run in runs(&frame, &off, min_run) {
        out.len += run.len;
        out.followed += run.points.iter().filter(|&&i| part.any_within(frame[i], near)).map(|&i| run.step(&frame, i)).sum::<f64>();
        if run.len > out.longest.0 {
            out.longest = (run.len, Some(frame[run.points[run.points.len() / 2]]));
        }
    }
    out
}

/// A run of consecutive outline points marked off.
struct Run {
    /// Indices of its points, in order along the outline.
    points: Vec<usize>,
    /// Its length along the outline, px.
    len: f64,
}

impl Run {
    /// The length of the outline from point `i` to the next.
    fn step(&self, outline: &[Pt], i: usize) -> f64 {
        (outline[(i + 1) % outline.len()] - outline[i]).norm()
    }
}

/// The runs of consecutive points of the closed `outline` marked `off`, at least `min_run`
/// long; none when every point is off (nothing to be off from).
fn runs(outline: &[Pt], off: &[bool], min_run: f64) -> Vec<Run> {
    let n = outline.len();
    let mut out = Vec::new();
    // Walked from a point that is not off, so that no run wraps.
    let Some(start) = off.iter().position(|&o| !o) else { return out };
    let mut run = Run { points: Vec::new(), len: 0.0 };
    for k in 1..=n {
        let i = (start + k) % n;
        if off[i] {
            run.len += run.step(outline, i);
            run.points.push(i);
        } else if !run.points.is_empty() {
            let done = std::mem::replace(&mut run, Run { points: Vec::new(), len: 0.0 });
            if done.len >= min_run {
                out.push(done);
            }
        }
    }
    out
}

/// Where a part departs from its best template (placed on it) by more than `apart`: the longest
/// run of the template's outline with none of the part's near it (material the part lacks) or of
/// the part's outline with none of the template's near it (material the template lacks), at
/// least `min_run` long; None when there is none.
pub fn departure(part: &OutlineIndex, tpl: Placed<'_>, apart: f64, min_run: f64) -> Option<Departure> {
    let to_tpl = tpl.pose.inverse();
    let reach = apart / tpl.pose.scale;
    let placed: Vec<Pt> = tpl.index.outline().iter().map(|&q| tpl.pose.apply(q)).collect();
    let missing: Vec<bool> = placed.iter().map(|&q| !part.any_within(q, apart)).collect();
    let own = part.outline();
    let extra: Vec<bool> = own.iter().map(|&q| !tpl.index.any_within(to_tpl.apply(q), reach)).collect();
    let depth_missing = |q: Pt| part.nearest(q, MAX_REACH).map_or(MAX_REACH, |(_, d, _)| d);
    let depth_extra = |q: Pt| tpl.index.nearest(to_tpl.apply(q), MAX_REACH).map_or(MAX_REACH, |(_, d, _)| d * tpl.pose.scale);
    let longest = |outline: &[Pt], off: &[bool]| runs(outline, off, min_run).into_iter().max_by(|a, b| a.len.total_cmp(&b.len));
    let m = longest(&placed, &missing).map(|r| (r, true));
    let e = longest(own, &extra).map(|r| (r, false));
    let (run, lacks) = match (m, e) {
        (Some(m), Some(e)) => {
            if m.0.len >= e.0.len {
                m
            } else {
                e
            }
        }
        (m, e) => m.or(e)?,
    };
    let (outline, depth): (&[Pt], &dyn Fn(Pt) -> f64) = if lacks { (&placed, &depth_missing) } else { (own, &depth_extra) };
    let mid = outline[run.points[run.points.len() / 2]];
    let v = to_tpl.apply(mid) - tpl.centroid;
    Some(Departure {
        len: run.len,
        depth: run.points.iter().map(|&i| depth(outline[i])).fold(0.0, f64::max),
        at_deg: v.y.atan2(v.x).to_degrees().rem_euclid(360.0),
        part_lacks: lacks,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::decide::Follows;

    /// A 200 x 100 plate (template pixels, corners at 0,0 and 200,100), with a lug `lug` px
    /// proud on its top edge between x 80 and 120 (a notch when `lug` < 0), sampled every 2 px.
    fn plate(lug: f64) -> Vec<Pt> {
        let mut corners = vec![Pt::new(0.0, 0.0)];
        if lug != 0.0 {
            corners.extend([Pt::new(80.0, 0.0), Pt::new(80.0, -lug), Pt::new(120.0, -lug), Pt::new(120.0, 0.0)]);
        }
        corners.extend([Pt::new(200.0, 0.0), Pt::new(200.0, 100.0), Pt::new(0.0, 100.0)]);
        crate::vision::geometry::resample_closed(&corners, 2.0)
    }

    fn placed(index: &OutlineIndex, pose: Similarity) -> Placed<'_> {
        Placed { index, pose, centroid: Pt::new(100.0, 50.0) }
    }

    fn pose(x: f64, y: f64, deg: f64) -> Similarity {
        Similarity { from: Pt::new(100.0, 50.0), to: Pt::new(x, y), angle_rad: deg.to_radians(), scale: 1.0 }
    }

    /// The part with the lug follows the template with it; the part without follows the other;
    /// a part with a notch where one has the lug follows neither; two templates the same are
    /// unclear.
    #[test]
    fn the_part_follows_the_template_it_is_where_they_differ() {
        let (with, without) = (OutlineIndex::new(&plate(25.0)), OutlineIndex::new(&plate(0.0)));
        let at = pose(600.0, 400.0, 37.0);
        let frame = |t: &[Pt]| OutlineIndex::of_frame(&t.iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        let cmp = |part: &OutlineIndex, a: &OutlineIndex, b: &OutlineIndex| compare(part, placed(a, at), placed(b, at), 2.0, 6.0, 12.0);

        let l = cmp(&frame(&plate(25.0)), &with, &without);
        assert_eq!(l.follows(), Follows::Best, "{l:?}");
        assert!(l.best_len > 60.0 && l.rival_len > 20.0, "{l:?}");
        assert!((l.at_deg - 270.0).abs() < 20.0, "the lug is on the top edge (template y up is -y): {l:?}");
        let l = cmp(&frame(&plate(0.0)), &with, &without);
        assert_eq!(l.follows(), Follows::Rival, "{l:?}");
        let l = cmp(&frame(&plate(-20.0)), &with, &without);
        assert_eq!(l.follows(), Follows::Neither, "{l:?}");
        let l = cmp(&frame(&plate(25.0)), &with, &with);
        assert_eq!((l.best_len, l.rival_len, l.follows()), (0.0, 0.0, Follows::Unclear), "{l:?}");
    }

    /// A part like its template except a lug (or a notch) departs from it there, by the lug's
    /// depth and about its outline's length; the part itself does not depart.
    #[test]
    fn a_lug_or_notch_the_template_lacks_is_a_departure_where_it_is() {
        let without = OutlineIndex::new(&plate(0.0));
        let at = pose(600.0, 400.0, -52.0);
        let frame = |t: &[Pt]| OutlineIndex::of_frame(&t.iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        assert_eq!(departure(&frame(&plate(0.0)), placed(&without, at), 6.0, 12.0), None);
        for lug in [20.0, -20.0] {
            let d = departure(&frame(&plate(lug)), placed(&without, at), 6.0, 12.0).expect("a departure");
            assert!((d.depth - 20.0).abs() < 1.5, "{lug}: {d:?}");
            assert!(d.len > 25.0 && d.len < 70.0, "{lug}: {d:?}");
            assert!((d.at_deg - 270.0).abs() < 20.0, "{lug}: {d:?}");
        }
        // Shallower than the separation that counts as apart: none.
        assert_eq!(departure(&frame(&plate(4.0)), placed(&without, at), 6.0, 12.0), None);
    }
}
