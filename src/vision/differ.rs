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
use super::frame::GrayView;
use super::geometry::{Pt, Similarity};
use super::register::{MAX_REACH, OutlineIndex};
use super::template::{ALIKE_CORR, Library, placed};

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

impl Placed<'_> {
    /// Where frame point `q` lies around the template's centroid, degrees in the template's own
    /// frame (the same for every pose): how a stretch is named to the operator.
    pub fn angle_at(&self, q: Pt) -> f64 {
        let v = self.pose.inverse().apply(q) - self.centroid;
        v.y.atan2(v.x).to_degrees().rem_euclid(360.0)
    }
}

/// Compares templates `best` and `rival` on a part whose outline is indexed as `part` (frame
/// pixels): points of either template's outline farther than `apart` from the other's, on runs
/// at least `min_run` long (both from `near` by [`separation`]; frame pixels; shorter runs are
/// the placements' jitter at corners), and of those the fraction within `near` of the part's
/// outline. Points where `excused` holds
/// (frame pixels: against or under a neighbouring part, where the part's own outline is not
/// seen) tell nothing from the outline: a stretch with any such point is left out, counted as
/// hidden, unless the part's edge is seen along most of it ([`MOST_SHOWN`]): the part's outline
/// on it, or `light` showing a step from part (inside) to belt (outside) across it.
///
/// Why the light: a notch that opens against a touching neighbour is a pocket of belt inside
/// the region, so the region's outer outline never runs into it, yet the frame shows its walls
/// plainly. Only what is shown counts: where a neighbour lies against or over the stretch the
/// frame shows no step whichever template is right, so a stretch not shown stays hidden and
/// [`Local::follows`] asks the other template's stretch to be seen and not followed.
///
/// Where the part lies on top of another (`over`, frame pixels: inside a part found beneath
/// it), its edge runs across that part's surface, which is itself part-coloured, shaded by
/// its own faces: the step from the upper part's material to it is as plain to the eye as to
/// the belt but smaller, so it counts from the step that shows an outline there at all
/// ([`Light::shows_over`]). Without the upper part's material there, both sides of a line are
/// the lower part's surface and show no step, so a lug lying over a lower part, or its
/// absence, is seen as the layering sees which part is on top.
#[allow(clippy::too_many_arguments)]
pub fn compare(
    part: &OutlineIndex,
    best: Placed<'_>,
    rival: Placed<'_>,
    excused: &dyn Fn(Pt) -> bool,
    over: &dyn Fn(Pt) -> bool,
    light: Option<&Light<'_>>,
    near: f64,
) -> Local {
    let (apart, min_run) = separation(near);
    let b = stretches(part, best, rival, excused, over, light, near, apart, min_run);
    let r = stretches(part, rival, best, excused, over, light, near, apart, min_run);
    let ((_, mid), on) = if b.longest.0 >= r.longest.0 { (b.longest, best) } else { (r.longest, rival) };
    let at = mid.map(|q| on.angle_at(q));
    Local {
        best_len: b.len,
        best_follows: if b.len > 0.0 { b.followed / b.len } else { 0.0 },
        rival_len: r.len,
        rival_follows: if r.len > 0.0 { r.followed / r.len } else { 0.0 },
        hidden_len: b.hidden + r.hidden,
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
    /// Length of the stretches not counted because the part's outline is not seen along all
    /// of them.
    hidden: f64,
    /// The longest: its length and middle point (frame pixels).
    longest: (f64, Option<Pt>),
}

/// A stretch partly hidden by a neighbour counts when the frame shows the part's edge along at
/// least this share of it ([`compare`]): the share a part's outline must follow for
/// [`Local::follows`] to name its template.
const MOST_SHOWN: f64 = 0.7;

/// The step, as a fraction of the part-to-belt contrast, that shows an upper part's edge over a
/// lower part ([`Light::shows_over`]).
const OVER: f64 = 0.1;

#[allow(clippy::too_many_arguments)]
fn stretches(
    part: &OutlineIndex,
    this: Placed<'_>,
    other: Placed<'_>,
    excused: &dyn Fn(Pt) -> bool,
    over: &dyn Fn(Pt) -> bool,
    light: Option<&Light<'_>>,
    near: f64,
    apart: f64,
    min_run: f64,
) -> Stretches {
    let frame: Vec<Pt> = this.index.outline().iter().map(|&q| this.pose.apply(q)).collect();
    let to_other = other.pose.inverse();
    let reach = apart / other.pose.scale;
    let off: Vec<bool> = frame.iter().map(|&q| !other.index.any_within(to_other.apply(q), reach)).collect();
    let mut out = Stretches { len: 0.0, followed: 0.0, hidden: 0.0, longest: (0.0, None) };
    for run in runs(&frame, &off, min_run) {
        let against = run.points.iter().any(|&i| excused(frame[i]));
        // Where parts touch, the region's outline runs around both, not into a pocket of belt
        // between them: the frame's step across the template's outline there is as good a sign
        // of the part's edge as the outline. Only there: elsewhere the outline is the part's
        // own, and a step inside a part (a shaded rim, a boss) is no edge.
        let lit = |i: usize| {
            against
                && light.is_some_and(|l| {
                    let (at, n, r) = (frame[i], outward(this, i), 0.5 * apart);
                    if over(at) { l.shows_over(at, n, r) } else { l.shows(at, n, r) }
                })
        };
        let seen = run.points.iter().filter(|&&i| part.any_within(frame[i], near) || lit(i)).map(|&i| run.step(&frame, i)).sum::<f64>();
        if against && (light.is_none() || seen < MOST_SHOWN * run.len) {
            out.hidden += run.len;
            continue;
        }
        out.len += run.len;
        out.followed += seen;
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

/// The frame's word on whether a line separates the part from the belt: the mean gray level a
/// little inside against a little outside, with the part's polarity.
#[derive(Clone, Copy)]
pub struct Light<'a> {
    frame: GrayView<'a>,
    sign: f64,
    least: f64,
    least_over: f64,
}

impl<'a> Light<'a> {
    /// The light of a frame whose parts are `brighter` than the belt by `contrast`, with pixel
    /// noise `noise` (gray levels): a step counts from 30 % of the contrast, and from four times
    /// the noise of the difference of two means of 15 samples; over a lower part, from 10 % of
    /// the contrast ([`Light::shows_over`]).
    pub fn new(frame: GrayView<'a>, brighter: bool, contrast: f64, noise: f64) -> Self {
        let floor = 4.0 * noise * (2.0f64 / 15.0).sqrt();
        let least = (0.3 * contrast).max(floor);
        let least_over = (OVER * contrast).max(floor);
        Self { frame, sign: if brighter { 1.0 } else { -1.0 }, least, least_over }
    }

    fn mean(&self, c: Pt, n: Pt) -> f64 {
        let t = Pt::new(-n.y, n.x);
        let mut s = 0.0;
        for i in -2..=2 {
            for j in -1..=1 {
                let q = c + t.scale(2.0 * i as f64) + n.scale(j as f64);
                s += self.frame.bilinear(q.x, q.y);
            }
        }
        s / 15.0
    }

    /// The frame's gray level at `q`.
    fn at(&self, q: Pt) -> f64 {
        self.frame.bilinear(q.x, q.y)
    }

    /// The belt's and the part's gray level around an outline (`outline`, frame pixels, with
    /// outward unit normals `normal(i)`): the medians `reach` outside and inside it.
    fn levels(&self, outline: &[Pt], normal: impl Fn(usize) -> Pt, reach: f64) -> Option<(f64, f64)> {
        let (mut belt, mut body): (Vec<f64>, Vec<f64>) = (0..outline.len())
            .step_by(4)
            .map(|i| {
                let n = normal(i);
                (self.at(outline[i] + n.scale(reach)), self.at(outline[i] - n.scale(reach)))
            })
            .unzip();
        if belt.is_empty() {
            return None;
        }
        let mid = belt.len() / 2;
        Some((*belt.select_nth_unstable_by(mid, f64::total_cmp).1, *body.select_nth_unstable_by(mid, f64::total_cmp).1))
    }

    /// Whether the frame steps from part (inside) to belt (outside) across the line through
    /// `at` with outward unit normal `n`, within `r` of it either way.
    pub fn shows(&self, at: Pt, n: Pt, r: f64) -> bool {
        self.step(at, n, r) >= self.least
    }

    /// Whether the frame steps between part (inside) and the surface of a part beneath
    /// (outside) across that line, of either sign: the lower part's surface is shaded by its
    /// own faces, a little darker or brighter than the upper part's. The step counts from what
    /// shows an outline at all where one part lies on another, the layering's (a tenth of the
    /// contrast, 0.4 x its edge threshold of a quarter).
    pub fn shows_over(&self, at: Pt, n: Pt, r: f64) -> bool {
        self.step(at, n, r).abs() >= self.least_over
    }

    /// The step in gray level across that line, positive with the part's polarity.
    fn step(&self, at: Pt, n: Pt, r: f64) -> f64 {
        self.sign * (self.mean(at - n.scale(r), n) - self.mean(at + n.scale(r), n))
    }
}

/// Where a part departs from its best template (placed on it) by more than `apart`: every run
/// of the template's outline with none of the part's near it (material the part lacks) or of
/// the part's outline with none of the template's near it (material the template lacks), at
/// least `min_run` long, that the judgement below keeps; [`super::decide::telling`] says which
/// one tells (a long shallow run of a loose placement must not hide a deep lug beside it).
///
/// Judged by `light` where the frame can tell: a place where the part's outline strays from the
/// template's while the frame still shows the part's edge along the template's outline (a dark
/// ring of a boss, a shadow in a rounded margin that the outline followed inward) is the
/// outline gone wrong there, not a departure. Points where `excused` holds (frame pixels: against
/// or under a neighbouring part, where the part's own outline is not seen) are not judged, nor,
/// unless `beyond`, the part's outline outside the template's (a region's outline runs around
/// whatever else lies in it; material the template lacks shows anyway as the template's outline
/// running where the frame shows no edge). Nor is a run whose enclosed strip (midway between
/// the two outlines) looks, by its median gray level against the belt's and the part's around
/// the outline, unlike what it claims: belt where the part has less material, the part's own
/// where it has more (a stain against a shaded edge is neither), unless the part's edge shows
/// along nearly all of the part's own outline there (a boss whose dark bore the strip crosses).
pub fn departures(
    part: &OutlineIndex,
    tpl: Placed<'_>,
    light: Option<&Light<'_>>,
    excused: &dyn Fn(Pt) -> bool,
    beyond: bool,
    apart: f64,
    min_run: f64,
) -> Vec<Departure> {
    let to_tpl = tpl.pose.inverse();
    let reach = apart / tpl.pose.scale;
    let tpl_pts = tpl.index.outline();
    let placed: Vec<Pt> = tpl_pts.iter().map(|&q| tpl.pose.apply(q)).collect();
    // The template's outline at its point or segment `i`, in the frame: whether the frame shows
    // the part's edge there.
    let edge_at = |at: Pt, i: usize| light.is_some_and(|l| l.shows(at, outward(tpl, i), 0.5 * apart));
    let missing: Vec<bool> = placed.iter().enumerate().map(|(i, &q)| !part.any_within(q, apart) && !edge_at(q, i) && !excused(q)).collect();
    let own = part.outline();
    let extra: Vec<bool> = own
        .iter()
        .map(|&q| {
            let qt = to_tpl.apply(q);
            !tpl.index.any_within(qt, reach)
                && !excused(q)
                && (beyond || super::geometry::contains(tpl_pts, qt))
                && !tpl.index.nearest(qt, MAX_REACH).is_some_and(|(i, _, foot)| edge_at(tpl.pose.apply(foot), i))
        })
        .collect();
    let depth_missing = |q: Pt| part.nearest(q, MAX_REACH).map_or(MAX_REACH, |(_, d, _)| d);
    let depth_extra = |q: Pt| tpl.index.nearest(to_tpl.apply(q), MAX_REACH).map_or(MAX_REACH, |(_, d, _)| d * tpl.pose.scale);
    // Where the other outline is nearest a point of a run: the part's for the template's
    // outline, the template's for the part's.
    let other_missing = |q: Pt| part.nearest(q, MAX_REACH).map(|(_, _, foot)| foot);
    let other_extra = |q: Pt| tpl.index.nearest(to_tpl.apply(q), MAX_REACH).map(|(_, _, foot)| tpl.pose.apply(foot));
    let levels = light.and_then(|l| l.levels(&placed, |i| outward(tpl, i), apart));
    let tpl_outline = tpl.index.outline();
    let judged = |run: Run, lacks: bool| -> Option<Departure> {
        let outline: &[Pt] = if lacks { &placed } else { own };
        let depth = |q: Pt| if lacks { depth_missing(q) } else { depth_extra(q) };
        let other = |q: Pt| if lacks { other_missing(q) } else { other_extra(q) };
        // The other outline's nearest point: beyond the index's reach, searched for point by
        // point (few points, and only for departures deeper than the reach).
        let far = |q: Pt| {
            let pts: Box<dyn Iterator<Item = Pt>> =
                if lacks { Box::new(own.iter().copied()) } else { Box::new(tpl_pts.iter().map(|&t| tpl.pose.apply(t))) };
            pts.min_by(|a, b| (*a - q).norm().total_cmp(&(*b - q).norm()))
        };
        let nearest_other = |q: Pt| other(q).or_else(|| far(q));
        // Less material than the template there: the part's outline runs inside the template's,
        // or the template's runs outside the part's.
        let less = run
            .points
            .iter()
            .filter(|&&i| {
                if lacks {
                    !super::geometry::contains(own, outline[i])
                } else {
                    super::geometry::contains(tpl_outline, to_tpl.apply(outline[i]))
                }
            })
            .count();
        let less_material = 2 * less > run.points.len();
        // Where the part has more material, how much of its own outline there the frame shows
        // as the part's edge: shown along and checked of its points (counted once, read twice
        // below).
        let edges = (!less_material).then_some(light).flatten().map(|l| {
            let shown: Vec<bool> = run
                .points
                .iter()
                .filter_map(|&i| {
                    let k = if lacks { part.nearest(outline[i], MAX_REACH).map(|(k, _, _)| k)? } else { i };
                    Some(l.shows(own[k], part.normal(k), 0.5 * apart))
                })
                .collect();
            (shown.iter().filter(|&&e| e).count(), shown.len())
        });
        // What lies between the two outlines must look like what the departure says: the belt
        // where the part has less material (a notch), the part where it has more (a lug). A
        // stain against the part or a crevice the outline ran into looks like neither claims.
        if let (Some(l), Some((belt, body))) = (light, levels) {
            let mut between: Vec<f64> =
                run.points.iter().filter_map(|&i| nearest_other(outline[i]).map(|o| l.at((outline[i] + o).scale(0.5)))).collect();
            if !between.is_empty() {
                let mid = between.len() / 2;
                let m = *between.select_nth_unstable_by(mid, f64::total_cmp).1;
                let belt_like = (m - belt).abs() < (m - body).abs();
                // More material whose own outline shows the part's edge along nearly all of it
                // is the part's, whatever its middle shows (a boss with a dark bore).
                let edged = !lacks && edges.is_some_and(|(shown, of)| 10 * shown >= 9 * of);
                if belt_like != less_material && !edged {
                    return None;
                }
            }
        }
        let depth_max = run.points.iter().map(|&i| depth(outline[i])).fold(0.0, f64::max);
        // Wide as well as deep: the area between the two outlines over its depth. A run into a
        // slit the outline entered further than the template's is long and deep but narrow.
        // Beyond the index's reach the other outline's nearest point is the one searched for
        // (see `far`).
        // The run closed by the chord across its ends as well: where the other outline's
        // nearest points fold back on themselves (a notch cut beside a boss, whose walls lie
        // nearest the boss's outline), the first polygon crosses itself and its halves cancel.
        let mut poly: Vec<Pt> = run.points.iter().map(|&i| outline[i]).collect();
        let closed = super::geometry::area_centroid(&poly).0.abs();
        poly.extend(run.points.iter().rev().filter_map(|&i| nearest_other(outline[i])));
        let width = super::geometry::area_centroid(&poly).0.abs().max(closed) / depth_max.max(1e-9);
        // The template's own outline where it faces itself across a narrow gap of belt (a
        // crevice between a boss and an arm): how deep an outline runs into it is the light's
        // doing, not the part's shape.
        let crevice = run
            .points
            .iter()
            .filter(|&&i| {
                let j = if lacks { Some(i) } else { tpl.index.nearest(to_tpl.apply(outline[i]), MAX_REACH).map(|(j, _, _)| j) };
                j.is_some_and(|j| faces_itself(tpl.index, j, NARROW * apart / tpl.pose.scale))
            })
            .count();
        if (crevice as f64) > CREVICE_SHARE * run.points.len() as f64 {
            return None;
        }
        // Where the part lacks material, the template's outline runs across the notch's mouth,
        // apart from the part's: looked for where the departure is deep (at least half its
        // depth), away from the notch's ends. Where the template's outline is on the part's all
        // along (the run's nearest template points all lie on the part's edge), the part lacks
        // nothing the template has: its outline entered the body (a dark pocket it followed in
        // and out), no notch.
        let mouth: Vec<(usize, Pt)> = if less_material {
            run.points
                .iter()
                .filter(|&&i| depth(outline[i]) >= 0.5 * depth_max)
                .filter_map(|&i| {
                    let (j, foot) = if lacks {
                        (i, tpl_outline[i])
                    } else {
                        let q = to_tpl.apply(outline[i]);
                        tpl.index.nearest(q, MAX_REACH).map(|(j, _, f)| (j, f)).or_else(|| {
                            let j = (0..tpl_pts.len()).min_by(|&a, &b| (tpl_pts[a] - q).norm().total_cmp(&(tpl_pts[b] - q).norm()))?;
                            Some((j, tpl_pts[j]))
                        })?
                    };
                    let at = tpl.pose.apply(foot);
                    (!part.any_within(at, apart)).then_some((j, at))
                })
                .collect()
        } else {
            Vec::new()
        };
        if less_material && mouth.is_empty() {
            return None;
        }
        // The belt shows on both sides of the template's outline across a notch's mouth: a
        // step there (the shaded rim of a part lit from above, which the outline stopped short
        // of, following the lit face) is the part's edge seen otherwise. Measured across the
        // mouth only, where the window across the template's outline holds no wall of the part
        // (the walls of a round notch lie nearest its mouth's corners, where the template runs
        // on the part's own edge and shows its step).
        if let (Some(l), Some((belt, body))) = (light, levels) {
            let mut steps: Vec<f64> = mouth.iter().map(|&(j, at)| l.step(at, outward(tpl, j), 0.5 * apart)).collect();
            if !steps.is_empty() {
                let mid = steps.len() / 2;
                let step = *steps.select_nth_unstable_by(mid, f64::total_cmp).1;
                if step.abs() > STEP_SHARE * (body - belt).abs() {
                    return None;
                }
            }
        }
        // Where the part has more material, its own outline there is an edge of the part: the
        // frame shows the step from part to belt along most of it. An outline that ran around a
        // faint stain or a patch of noise on the belt beside the part shows no such step.
        if edges.is_some_and(|(shown, of)| 2 * shown < of) {
            return None;
        }
        let mid = outline[run.points[run.points.len() / 2]];
        Some(Departure {
            width,
            less_material,
            len: run.len,
            depth: depth_max,
            reach: MAX_REACH,
            apart,
            at_deg: tpl.angle_at(mid),
            part_lacks: lacks,
        })
    };
    let all =
        runs(&placed, &missing, min_run).into_iter().map(|r| (r, true)).chain(runs(own, &extra, min_run).into_iter().map(|r| (r, false)));
    all.filter_map(|(r, lacks)| judged(r, lacks)).collect()
}

/// The template's outward unit normal at its point `i`, in the frame.
fn outward(tpl: Placed<'_>, i: usize) -> Pt {
    let pts = tpl.index.outline();
    let n = tpl.pose.apply(pts[i] + tpl.index.normal(i)) - tpl.pose.apply(pts[i]);
    n.scale(1.0 / n.norm().max(1e-9))
}

/// A gap of belt narrower than this many times the separation, between two stretches of one
/// outline, is a crevice ([`faces_itself`]).
const NARROW: f64 = 4.0;
/// A run more than this share of which lies along a crevice of the template is not judged.
const CREVICE_SHARE: f64 = 0.1;
/// Where the part lacks material, a step across the template's outline larger than this share
/// of the part's contrast says the part's edge is there after all.
const STEP_SHARE: f64 = 0.1;

/// Whether the outline `index` meets itself again within `gap` (its own pixels) straight out
/// from its segment `j`: the segment is a wall of a crevice.
fn faces_itself(index: &OutlineIndex, j: usize, gap: f64) -> bool {
    let (p, n) = (index.outline()[j], index.normal(j));
    // From 2 px out (clear of the segment itself and its neighbours on a smooth outline), in
    // 1 px steps.
    let mut t = 2.0;
    while t <= gap {
        if index.any_within(p + n.scale(t), 1.0) {
            return true;
        }
        t += 1.0;
    }
    false
}

/// Two enrolled templates whose outlines are alike overall (revisions of one part, two faces of
/// a symmetric one), as enrolment reports them: where, if anywhere, a frame can tell them apart.
#[derive(Debug, Clone, PartialEq)]
pub struct Alike {
    /// The two templates (indices into the list compared).
    pub a: usize,
    /// See `a`.
    pub b: usize,
    /// `b`'s outline registered onto `a`'s: the worse of inliers and coverage.
    pub fit: f64,
    /// Length of `a`'s outline apart from `b`'s, and of `b`'s from `a`'s, px (runs long enough
    /// to tell them apart in a clean frame).
    pub a_len: f64,
    /// See `a_len`.
    pub b_len: f64,
    /// The largest distance of either outline from the other, px (at most the registration's
    /// reach).
    pub largest: f64,
    /// Where the longest stretch lies, degrees around `a`'s centroid in its own frame.
    pub at_deg: f64,
}

impl Alike {
    /// Whether some stretch of outline tells them apart in a clean frame.
    pub fn told_apart(&self) -> bool {
        self.a_len + self.b_len > 0.0
    }
}

/// The pairs of templates (of another type or face) whose outlines fit each other at least
/// `min_fit` at tolerance `near` (px, a clean outline's), and where they differ: by three times
/// `near` over runs twice that ([`separation`]), the separation the estimator tells siblings
/// apart by in the cleanest frame. Pairs whose log-polar signals differ by more than
/// [`ALIKE_CORR`] are not registered: their outlines differ everywhere.
pub fn alike(lib: &Library, near: f64, min_fit: f64) -> Vec<Alike> {
    let (apart, min_run) = separation(near);
    let corr = &lib.correlator;
    let mut out = Vec::new();
    for (i, a) in lib.entries.iter().enumerate() {
        for (j, b) in lib.entries.iter().enumerate().skip(i + 1) {
            if a.template.type_name == b.template.type_name && a.template.face == b.template.face {
                continue;
            }
            let al = corr.align(&b.spectrum, &a.spectrum);
            if al.rms > ALIKE_CORR {
                continue;
            }
            let init = placed(corr, &al, a.template.centroid, b.template.centroid);
            let reg = super::register::register(&b.template.outline, &a.index, init, near, 1);
            if reg.fit() < min_fit {
                continue;
            }
            let here = Similarity { from: Pt::new(0.0, 0.0), to: Pt::new(0.0, 0.0), angle_rad: 0.0, scale: 1.0 };
            let pa = Placed { index: &a.index, pose: reg.pose, centroid: a.template.centroid };
            let pb = Placed { index: &b.index, pose: here, centroid: b.template.centroid };
            let (ra, rb) = (apart_of(pa, pb, apart, min_run), apart_of(pb, pa, apart, min_run));
            // Both placed in `b`'s frame: the longest stretch's middle carried back into `a`'s.
            let (_, mid) = if ra.1.0 >= rb.1.0 { ra.1 } else { rb.1 };
            let at_deg = mid.map_or(0.0, |q| pa.angle_at(q));
            out.push(Alike { a: i, b: j, fit: reg.fit(), a_len: ra.0, b_len: rb.0, largest: ra.2.max(rb.2), at_deg });
        }
    }
    out
}

/// One outline against another, both placed: the length of its runs apart, the longest run's
/// length and middle, and its largest distance from the other (px, capped at [`MAX_REACH`]).
fn apart_of(this: Placed<'_>, other: Placed<'_>, apart: f64, min_run: f64) -> (f64, (f64, Option<Pt>), f64) {
    let frame: Vec<Pt> = this.index.outline().iter().map(|&q| this.pose.apply(q)).collect();
    let to_other = other.pose.inverse();
    let dist = |q: Pt| other.index.nearest(to_other.apply(q), MAX_REACH).map_or(MAX_REACH, |(_, d, _)| d * other.pose.scale);
    let d: Vec<f64> = frame.iter().map(|&q| dist(q)).collect();
    let off: Vec<bool> = d.iter().map(|&x| x > apart).collect();
    let mut len = 0.0;
    let mut longest = (0.0, None);
    for run in runs(&frame, &off, min_run) {
        len += run.len;
        if run.len > longest.0 {
            longest = (run.len, Some(frame[run.points[run.points.len() / 2]]));
        }
    }
    (len, longest, d.iter().copied().fold(0.0, f64::max))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::decide::Follows;

    /// The longest departure [`departures`] finds (these plates have one place that departs).
    fn longest(
        part: &OutlineIndex,
        tpl: Placed<'_>,
        light: Option<&Light<'_>>,
        excused: &dyn Fn(Pt) -> bool,
        beyond: bool,
        apart: f64,
        min_run: f64,
    ) -> Option<Departure> {
        departures(part, tpl, light, excused, beyond, apart, min_run).into_iter().max_by(|a, b| a.len.total_cmp(&b.len))
    }

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
        let cmp = |part: &OutlineIndex, a: &OutlineIndex, b: &OutlineIndex| {
            compare(part, placed(a, at), placed(b, at), &|_| false, &|_| false, None, 2.0)
        };

        let l = cmp(&frame(&plate(25.0)), &with, &without);
        assert_eq!(l.follows(), Follows::Best, "{l:?}");
        assert!(l.best_len > 60.0 && l.rival_len > 20.0, "{l:?}");
        assert!((l.at_deg - 270.0).abs() < 20.0, "the lug is on the top edge (template y up is -y): {l:?}");
        let l = cmp(&frame(&plate(0.0)), &with, &without);
        assert_eq!(l.follows(), Follows::Rival, "{l:?}");
        let l = cmp(&frame(&plate(-20.0)), &with, &without);
        assert_eq!(l.follows(), Follows::Neither, "{l:?}");
        // A neighbour against the lug hides a stretch: nothing tells.
        let lug_top = at.apply(Pt::new(100.0, -25.0));
        let hidden = compare(
            &frame(&plate(25.0)),
            placed(&with, at),
            placed(&without, at),
            &|q: Pt| (q - lug_top).norm() < 10.0,
            &|_| false,
            None,
            2.0,
        );
        assert!(hidden.hidden_len > 0.0 && hidden.follows() == Follows::Unclear, "{hidden:?}");
        // A neighbour against the other's straight edge hides that stretch, but the lug is seen
        // and followed: that tells. Not lying where the hidden edge would be tells nothing.
        let edge = at.apply(Pt::new(100.0, 0.0));
        let by_edge = |q: Pt| (q - edge).norm() < 10.0;
        let l = compare(&frame(&plate(25.0)), placed(&with, at), placed(&without, at), &by_edge, &|_| false, None, 2.0);
        assert!(l.hidden_len > 0.0 && l.follows() == Follows::Best, "{l:?}");
        let l = compare(&frame(&plate(0.0)), placed(&with, at), placed(&without, at), &by_edge, &|_| false, None, 2.0);
        assert!(l.hidden_len > 0.0 && l.follows() == Follows::Unclear, "{l:?}");
        let l = cmp(&frame(&plate(25.0)), &with, &with);
        assert_eq!((l.best_len, l.rival_len, l.follows()), (0.0, 0.0, Follows::Unclear), "{l:?}");
    }

    /// A notch that opens against a touching neighbour: the region's outline runs around both
    /// parts, not into the pocket of belt the notch leaves between them, so the outline alone
    /// tells nothing there; the frame shows the notch's walls. Where the frame shows no notch
    /// (the plain part against its neighbour) nothing tells, whichever template is placed first.
    #[test]
    fn a_notch_against_a_neighbour_is_seen_by_the_light() {
        use crate::vision::frame::GrayImage;
        let at = pose(200.0, 150.0, 0.0);
        let (w, h) = (400, 300);
        // The plate spans frame x 100..300, y 100..200; its neighbour lies against its top
        // edge, y 60..100; a notch (template lug -10) is belt at x 180..220, y 100..110, all
        // of it within the reach of the neighbour's outline (12 px) where the outline is not
        // the part's own.
        let image = |notch: bool| {
            let mut img = GrayImage::new(w, h, 50);
            for y in 60..200 {
                for x in 100..300 {
                    if !(notch && (180..220).contains(&x) && (100..110).contains(&y)) {
                        img.data[y * w + x] = 180;
                    }
                }
            }
            img
        };
        let corners = [Pt::new(100.0, 60.0), Pt::new(300.0, 60.0), Pt::new(300.0, 200.0), Pt::new(100.0, 200.0)];
        let region = OutlineIndex::of_frame(&crate::vision::geometry::resample_closed(&corners, 2.0));
        let against = |q: Pt| q.y < 112.0;
        let (notched, plain) = (OutlineIndex::new(&plate(-10.0)), OutlineIndex::new(&plate(0.0)));
        for (notch, first_notched, expect) in
            [(true, true, Follows::Best), (true, false, Follows::Rival), (false, true, Follows::Unclear), (false, false, Follows::Unclear)]
        {
            let img = image(notch);
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let (a, b) = if first_notched { (&notched, &plain) } else { (&plain, &notched) };
            let l = compare(&region, placed(a, at), placed(b, at), &against, &|_| false, Some(&light), 2.0);
            assert_eq!(l.follows(), expect, "notch in the image {notch}, notched template first {first_notched}: {l:?}");
            // Without the frame's word, the stretch against the neighbour is hidden.
            let l = compare(&region, placed(a, at), placed(b, at), &against, &|_| false, None, 2.0);
            assert!(l.hidden_len > 0.0 && l.follows() == Follows::Unclear, "{l:?}");
        }
    }

    /// A lug that lies over a lower part: the region's outline runs around both parts, and the
    /// lower part's surface, a shade darker or brighter than the upper part's, lies on both
    /// sides of any line across it. The frame shows the upper part's edge there by a step
    /// smaller than the part-to-belt contrast, of either sign; without the upper part's material
    /// no step shows. Where the two parts are one shade, nothing tells.
    #[test]
    fn a_lug_over_a_lower_part_is_seen_by_its_step_either_way() {
        use crate::vision::frame::GrayImage;
        let at = pose(200.0, 150.0, 0.0);
        let (w, h) = (400, 300);
        // The lower part spans frame x 60..340, y 40..130; the plate on it x 100..300, y
        // 100..200, with a lug (template lug 10) at x 180..220, y 90..100.
        let image = |lug: bool, lower: u8| {
            let mut img = GrayImage::new(w, h, 50);
            for y in 40..130 {
                for x in 60..340 {
                    img.data[y * w + x] = lower;
                }
            }
            for y in 90..200 {
                for x in 100..300 {
                    if y >= 100 || (lug && (180..220).contains(&x)) {
                        img.data[y * w + x] = 180;
                    }
                }
            }
            img
        };
        let corners = [
            Pt::new(60.0, 40.0),
            Pt::new(340.0, 40.0),
            Pt::new(340.0, 130.0),
            Pt::new(300.0, 130.0),
            Pt::new(300.0, 200.0),
            Pt::new(100.0, 200.0),
            Pt::new(100.0, 130.0),
            Pt::new(60.0, 130.0),
        ];
        let region = OutlineIndex::of_frame(&crate::vision::geometry::resample_closed(&corners, 2.0));
        let lower = |q: Pt| (54.0..346.0).contains(&q.x) && (34.0..136.0).contains(&q.y);
        let (with, without) = (OutlineIndex::new(&plate(10.0)), OutlineIndex::new(&plate(0.0)));
        for shade in [155u8, 205] {
            for (lug, first_with, expect) in
                [(true, true, Follows::Best), (true, false, Follows::Rival), (false, true, Follows::Rival), (false, false, Follows::Best)]
            {
                let img = image(lug, shade);
                let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
                let (a, b) = if first_with { (&with, &without) } else { (&without, &with) };
                let l = compare(&region, placed(a, at), placed(b, at), &lower, &lower, Some(&light), 2.0);
                assert_eq!(l.follows(), expect, "lower part {shade}, lug in the image {lug}, lug template first {first_with}: {l:?}");
                // Not known to lie over it, the step is too small for an edge against the belt.
                let l = compare(&region, placed(a, at), placed(b, at), &lower, &|_| false, Some(&light), 2.0);
                assert_eq!(l.follows(), Follows::Unclear, "{l:?}");
            }
        }
        // One shade: no step either way.
        for lug in [true, false] {
            let img = image(lug, 180);
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let l = compare(&region, placed(&with, at), placed(&without, at), &lower, &lower, Some(&light), 2.0);
            assert_eq!(l.follows(), Follows::Unclear, "lug {lug}: {l:?}");
        }
    }

    /// A part like its template except a lug (or a notch) departs from it there, by the lug's
    /// depth and about its outline's length; the part itself does not depart.
    #[test]
    fn a_lug_or_notch_the_template_lacks_is_a_departure_where_it_is() {
        let without = OutlineIndex::new(&plate(0.0));
        let at = pose(600.0, 400.0, -52.0);
        let frame = |t: &[Pt]| OutlineIndex::of_frame(&t.iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        assert_eq!(longest(&frame(&plate(0.0)), placed(&without, at), None, &|_| false, true, 6.0, 12.0), None);
        for lug in [20.0, -20.0] {
            let d = longest(&frame(&plate(lug)), placed(&without, at), None, &|_| false, true, 6.0, 12.0).expect("a departure");
            assert!((d.depth - 20.0).abs() < 1.5, "{lug}: {d:?}");
            assert!(d.len > 25.0 && d.len < 70.0, "{lug}: {d:?}");
            assert!((d.at_deg - 270.0).abs() < 20.0, "{lug}: {d:?}");
        }
        // Shallower than the separation that counts as apart: none.
        assert_eq!(longest(&frame(&plate(4.0)), placed(&without, at), None, &|_| false, true, 6.0, 12.0), None);
    }

    /// Enrolment's report: a plate and its revision with a lug are alike and told apart at the
    /// lug; the same plate enrolled twice (another name, a pixel's difference) cannot be.
    #[test]
    fn templates_alike_are_reported_with_where_they_differ() {
        use crate::vision::frame::GrayImage;
        use crate::vision::{Face, Library, Params, Template};
        let image = |lug: usize| {
            let (w, h) = (600, 400);
            let mut img = GrayImage::new(w, h, 50);
            for y in 100..300 {
                for x in 100..500 {
                    let plate = (130..280).contains(&y) && (150..450).contains(&x);
                    let on_lug = (130 - lug..130).contains(&y) && (280..320).contains(&x);
                    if plate || on_lug {
                        img.data[y * w + x] = 180;
                    }
                }
            }
            img
        };
        let params = Params::default();
        let t = |name: &str, lug: usize| Template::from_image(image(lug).view().unwrap(), name, 1, Face::Up, None, &params).unwrap();
        let lib = Library::new(&[t("plain", 0), t("lugged", 20), t("twin", 1)], params.signal_bins);
        let found = alike(&lib, params.fit_tolerance, params.min_fit);
        let pair = |a: usize, b: usize| found.iter().find(|x| (x.a, x.b) == (a, b)).unwrap_or_else(|| panic!("{a}, {b}: {found:?}"));
        let (lug, twin) = (pair(0, 1), pair(0, 2));
        assert!(lug.told_apart() && lug.largest > 20.0, "{lug:?}");
        // The plate is symmetric under a half turn: the lug is on its top or bottom edge.
        assert!((lug.at_deg - 270.0).abs() < 25.0 || (lug.at_deg - 90.0).abs() < 25.0, "the lug is on a long edge: {lug:?}");
        assert!(!twin.told_apart() && twin.largest < 6.0, "{twin:?}");
    }

    /// Judged by the frame: a notch the image shows (belt inside the template's outline) is a
    /// departure; the same outline where the image shows the whole plate (the outline went
    /// wrong there) is not.
    #[test]
    fn the_frame_decides_whether_an_outline_that_strays_departs() {
        use crate::vision::frame::GrayImage;
        let at = pose(200.0, 150.0, 0.0);
        let (w, h) = (400, 300);
        let image = |notch: bool| {
            let mut img = GrayImage::new(w, h, 50);
            for y in 100..200 {
                for x in 100..300 {
                    let in_notch = notch && (180..220).contains(&x) && y < 120;
                    if !in_notch {
                        img.data[y * w + x] = 180;
                    }
                }
            }
            img
        };
        let without = OutlineIndex::new(&plate(0.0));
        let part = OutlineIndex::of_frame(&plate(-20.0).iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        for (notch, departs) in [(true, true), (false, false)] {
            let img = image(notch);
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let d = longest(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
            assert_eq!(d.is_some(), departs, "notch in the image {notch}: {d:?}");
            if let Some(d) = d {
                assert!(d.less_material, "{d:?}");
            }
        }
    }

    /// The outline runs out around something against the plate's shaded edge, where the edge
    /// itself shows too weakly to tell: a lug of the part's own material departs; a stain on the
    /// belt (gray between the belt and the part, nearer the belt) is not material the part has.
    #[test]
    fn what_lies_between_the_outlines_must_look_like_what_the_departure_says() {
        use crate::vision::frame::GrayImage;
        let at = pose(200.0, 150.0, 0.0);
        let (w, h) = (400, 300);
        let image = |lug: u8| {
            let mut img = GrayImage::new(w, h, 50);
            for y in 75..200 {
                for x in 100..300 {
                    let on_lug = (180..220).contains(&x) && y < 100;
                    let v = if y >= 100 {
                        // The plate's top edge shaded, as a rounded edge is.
                        if y < 106 { 80 } else { 180 }
                    } else if on_lug {
                        lug
                    } else {
                        50
                    };
                    img.data[y * w + x] = v;
                }
            }
            img
        };
        let without = OutlineIndex::new(&plate(0.0));
        let part = OutlineIndex::of_frame(&plate(25.0).iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        for (lug, departs) in [(180, true), (70, false)] {
            let img = image(lug);
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let d = longest(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
            assert_eq!(d.is_some(), departs, "lug at gray {lug}: {d:?}");
            if let Some(d) = d {
                assert!(!d.less_material && !d.part_lacks, "{d:?}");
            }
        }
    }

    /// A boss proud of the plate with a dark bore: the strip midway between the outlines runs
    /// through the bore and looks like belt, but the part's edge shows along the boss's own
    /// outline nearly all the way: material the template lacks. The same outline around a stain
    /// (no edge along it) is not.
    #[test]
    fn a_boss_with_a_dark_bore_is_material_the_template_lacks() {
        use crate::vision::frame::GrayImage;
        let at = pose(200.0, 150.0, 0.0);
        let (w, h) = (400, 300);
        let image = |boss: u8| {
            let mut img = GrayImage::new(w, h, 50);
            for y in 60..200 {
                for x in 100..300 {
                    let r2 = (x as f64 - 200.0).powi(2) + (y as f64 - 100.0).powi(2);
                    let v = if y >= 100 {
                        180
                    } else if r2 < 289.0 && y < 94 {
                        50
                    } else if r2 < 484.0 {
                        boss
                    } else {
                        50
                    };
                    img.data[y * w + x] = v;
                }
            }
            img
        };
        let mut corners = vec![Pt::new(0.0, 0.0)];
        corners.extend((0..=24).map(|k| {
            let t = std::f64::consts::PI * k as f64 / 24.0;
            Pt::new(100.0 - 22.0 * t.cos(), -22.0 * t.sin())
        }));
        corners.extend([Pt::new(200.0, 0.0), Pt::new(200.0, 100.0), Pt::new(0.0, 100.0)]);
        let bossed = crate::vision::geometry::resample_closed(&corners, 2.0);
        let without = OutlineIndex::new(&plate(0.0));
        let part = OutlineIndex::of_frame(&bossed.iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        for (boss, departs) in [(180, true), (70, false)] {
            let img = image(boss);
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let d = longest(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
            assert_eq!(d.is_some(), departs, "boss at gray {boss}: {d:?}");
            if let Some(d) = d {
                assert!(!d.less_material && !d.part_lacks && d.depth > 20.0, "{d:?}");
            }
        }
    }

    /// A notch's mouth shows belt on both sides of the template's outline; the part's edge seen
    /// there after all (a shaded rim, darker than the lit face the outline followed but
    /// brighter than the belt, too faint for the edge test) is not material the part lacks.
    #[test]
    fn a_notch_shows_belt_across_its_mouth() {
        use crate::vision::frame::GrayImage;
        let at = pose(200.0, 150.0, 0.0);
        let (w, h) = (400, 300);
        let image = |band: u8| {
            let mut img = GrayImage::new(w, h, 50);
            for y in 100..200 {
                for x in 100..300 {
                    let in_notch = (180..220).contains(&x) && y < 125;
                    img.data[y * w + x] = if in_notch { band } else { 180 };
                }
            }
            img
        };
        let without = OutlineIndex::new(&plate(0.0));
        let part = OutlineIndex::of_frame(&plate(-25.0).iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        for (band, departs) in [(50, true), (75, false)] {
            let img = image(band);
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let d = longest(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
            assert_eq!(d.is_some(), departs, "notch at gray {band}: {d:?}");
            if let Some(d) = d {
                assert!(d.less_material && d.width > 30.0, "{d:?}");
            }
        }
    }

    /// An outline that runs further into a crevice of the template (a slit between a boss and
    /// an arm) than the template's does departs deep and long, but along walls that face each
    /// other across a little belt: not judged. Against a template without the crevice, the
    /// slit's mouth is narrower than twice the separation: the template's outline across it
    /// lies on the part's all along, and the part lacks nothing there at this separation.
    #[test]
    fn an_outline_deeper_in_a_crevice_of_the_template_is_not_a_departure() {
        let slit = |depth: f64| {
            let corners = [
                Pt::new(0.0, 0.0),
                Pt::new(96.0, 0.0),
                Pt::new(96.0, depth),
                Pt::new(104.0, depth),
                Pt::new(104.0, 0.0),
                Pt::new(200.0, 0.0),
                Pt::new(200.0, 100.0),
                Pt::new(0.0, 100.0),
            ];
            crate::vision::geometry::resample_closed(&corners, 2.0)
        };
        let at = pose(600.0, 400.0, 21.0);
        let part = OutlineIndex::of_frame(&slit(40.0).iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        let with = OutlineIndex::new(&slit(8.0));
        assert_eq!(longest(&part, placed(&with, at), None, &|_| false, true, 6.0, 12.0), None);
        let without = OutlineIndex::new(&plate(0.0));
        assert_eq!(longest(&part, placed(&without, at), None, &|_| false, true, 6.0, 12.0), None);
    }

    /// The plate's outline (template pixels) with `cut` spliced into its top edge between x 80
    /// and 120 (the points of `cut` run from the first corner to the second), sampled every 2 px.
    fn plate_with(cut: &[Pt]) -> Vec<Pt> {
        let mut corners = vec![Pt::new(0.0, 0.0), Pt::new(80.0, 0.0)];
        corners.extend_from_slice(cut);
        corners.extend([Pt::new(120.0, 0.0), Pt::new(200.0, 0.0), Pt::new(200.0, 100.0), Pt::new(0.0, 100.0)]);
        crate::vision::geometry::resample_closed(&corners, 2.0)
    }

    /// The plate at `pose(200, 150, 0)` (frame x 100..300, y 100..200) drawn at 180 on a belt
    /// of 50, each pixel then as `paint` says (given x, y and the plate's own gray).
    fn drawn(paint: impl Fn(usize, usize, u8) -> u8) -> crate::vision::frame::GrayImage {
        let (w, h) = (400, 300);
        let mut img = crate::vision::frame::GrayImage::new(w, h, 50);
        for y in 0..h {
            for x in 0..w {
                let plate = (100..200).contains(&y) && (100..300).contains(&x);
                img.data[y * w + x] = paint(x, y, if plate { 180 } else { 50 });
            }
        }
        img
    }

    /// A round notch cut deeper than its radius (its mouth narrower than its width): the walls
    /// below the mouth lie nearest the mouth's corners, where the template runs on the part's
    /// own edge and the frame steps from part to belt. Across the mouth itself the belt lies on
    /// both sides of the template's outline: the notch is the part's, a departure.
    #[test]
    fn a_round_notch_is_judged_across_its_mouth() {
        let at = pose(200.0, 150.0, 0.0);
        // A circle of radius 20 about (100, 12): the mouth spans x 84..116 on the top edge.
        let (c, r) = (Pt::new(100.0, 12.0), 20.0f64);
        // From the mouth's left corner round through the bottom (y deepest at angle 90 deg)
        // to its right corner.
        let (from, to) = (std::f64::consts::PI + (12.0 / r).asin(), -(12.0 / r).asin());
        let arc: Vec<Pt> = (0..=40)
            .map(|k| {
                let a = from + (to - from) * k as f64 / 40.0;
                c + Pt::new(a.cos(), a.sin()).scale(r)
            })
            .collect();
        let mut cut = vec![Pt::new(84.0, 0.0)];
        cut.extend(arc.iter().copied().filter(|q| q.y > 0.0));
        cut.push(Pt::new(116.0, 0.0));
        let notched = plate_with(&cut);
        let inside = |q: Pt| crate::vision::geometry::contains(&notched, q);
        let img = drawn(|x, y, g| if inside(at.inverse().apply(Pt::new(x as f64 + 0.5, y as f64 + 0.5))) { 180 } else { g.min(50) });
        let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
        let part = OutlineIndex::of_frame(&notched.iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        let without = OutlineIndex::new(&plate(0.0));
        let found = departures(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
        let d = found.iter().max_by(|a, b| a.depth.total_cmp(&b.depth)).expect("a departure");
        assert!(d.less_material && d.depth >= d.reach && d.width >= 18.0, "{found:?}");
    }

    /// An outline that follows a dark pocket into the part's body and out again, while along
    /// the template's outline above it the part's own outline runs too: the part lacks nothing
    /// the template has (its nearest template outline lies on the part's edge all along), so
    /// however dark the pocket, it is no notch.
    #[test]
    fn an_outline_into_a_dark_pocket_lacks_nothing() {
        let at = pose(200.0, 150.0, 0.0);
        // In from the top edge at x 80..84 down to y 30, along to x 160, back at y 36 to x 84
        // (template pixels): a channel the outline ran, the top edge around it intact.
        let channel = [Pt::new(80.0, 30.0), Pt::new(160.0, 30.0), Pt::new(160.0, 36.0), Pt::new(84.0, 36.0), Pt::new(84.0, 0.0)];
        let mut corners = vec![Pt::new(0.0, 0.0), Pt::new(80.0, 0.0)];
        corners.extend(channel);
        corners.extend([Pt::new(200.0, 0.0), Pt::new(200.0, 100.0), Pt::new(0.0, 100.0)]);
        let outline = crate::vision::geometry::resample_closed(&corners, 2.0);
        let part = OutlineIndex::of_frame(&outline.iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        // The pocket: dark from 4 px under the top edge to the channel's floor.
        let img = drawn(|x, y, g| if (180..262).contains(&x) && (104..137).contains(&y) { 50 } else { g });
        let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
        let without = OutlineIndex::new(&plate(0.0));
        let found = departures(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
        assert!(found.iter().all(|d| d.depth < 12.0), "{found:?}");
    }

    /// Material the template lacks is the part's: its own outline there is an edge the frame
    /// shows. An outline run out around a stain that brightens toward the part (its middle as
    /// bright as the part, its rim a faint step from the belt) is not; a lug is.
    #[test]
    fn more_material_shows_the_parts_edge() {
        let at = pose(200.0, 150.0, 0.0);
        let part = OutlineIndex::of_frame(&plate(20.0).iter().map(|&q| at.apply(q)).collect::<Vec<_>>());
        let without = OutlineIndex::new(&plate(0.0));
        for (stain, departs) in [(false, true), (true, false)] {
            // Frame x 180..220, y 80..100: the lug, or a stain ramping from the belt's gray at
            // y 80 to the part's by y 92.
            let img = drawn(|x, y, g| {
                if (180..220).contains(&x) && (80..100).contains(&y) {
                    if stain { (50.0 + 10.8 * (y as f64 - 80.0)).min(180.0) as u8 } else { 180 }
                } else {
                    g
                }
            });
            let light = Light::new(img.view().unwrap(), true, 130.0, 2.0);
            let found = departures(&part, placed(&without, at), Some(&light), &|_| false, true, 6.0, 12.0);
            // Deep and wide as the ladder's limits (2 and 3 times the separation) want.
            let counts = found.iter().any(|d| d.depth >= 12.0 && d.width >= 18.0);
            assert_eq!(counts, departs, "a stain {stain}: {found:?}");
        }
    }
}
