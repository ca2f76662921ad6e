//! A hypothesis looked at: a coarse angle search, cheap support looks, the registration on the
//! reachable outline, then every point of the template's outline verified against the region's
//! outline or an edge in the image.

use super::super::geometry::{Affine, Pt, Similarity, angle_diff_deg};
use super::super::register::{self, OutlineIndex};
use super::super::shape::{EdgeTest, ShapeModel};
use super::super::template::Library;
use super::found::{Found, MIN_SUPPORT, Probe, Region};

/// Least cosine between a template point's normal and the region's outline there (and the
/// offset between them) for a deviation beyond the tolerance to count as the same outline moved.
const PARALLEL_COS: f64 = 0.9;

/// Least cheap support at a hypothesis's aimed pose that a look goes on from: below it, the
/// outline is mostly not there.
pub(super) const LOOK_FROM: f64 = MIN_SUPPORT - 0.2;

/// The angles tried around a vote peak's: +-4 steps of 2 degrees, about a bin's width either
/// way, leaving at most a degree (under 8 px at a 450 px radius) to the registration.
const ANGLE_SEARCH: i32 = 4;
const ANGLE_SEARCH_STEP: f64 = 2.0;

/// What a hypothesis is looked at against: the region's outline, indexed, and the image's edges.
pub(super) struct Look<'a> {
    pub(super) lib: &'a Library,
    outline: &'a [Pt],
    tolerance: &'a (dyn Fn(usize) -> f64 + Sync),
    ext: OutlineIndex,
    pub(super) edge: EdgeTest<'a>,
}

impl<'a> Look<'a> {
    pub(super) fn new(lib: &'a Library, region: &Region<'a>, tolerance: &'a (dyn Fn(usize) -> f64 + Sync)) -> Self {
        Self {
            lib,
            outline: region.outline,
            tolerance,
            ext: OutlineIndex::of_frame(region.outline),
            edge: EdgeTest::new(region.coarse, region.noise, region.contrast),
        }
    }

    /// The start of the look at template `ei` near a vote peak's `init`: the peak's pose at the
    /// best of a few angles around it, and the cheap support there (which ranks the hypotheses
    /// looked at).
    pub(super) fn aim(&self, ei: usize, init: Similarity) -> (Similarity, f64) {
        let (ext, edge) = (&self.ext, &self.edge);
        let e = &self.lib.entries[ei];
        let tol = (self.tolerance)(ei);
        // A mostly round part votes for its centroid from every rotation alike, and only its
        // lobes tell the angle: the peak's angle may be several degrees off, beyond what the
        // registration pulls in. A coarse look at the angles around it first.
        (-ANGLE_SEARCH..=ANGLE_SEARCH)
            .map(|k| {
                let mut pose = init;
                pose.angle_rad += (k as f64 * ANGLE_SEARCH_STEP).to_radians();
                (pose, support(&e.shape, &pose, ext, edge, 2.0 * tol, 8))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((init, 0.0))
    }

    /// The part template `ei` explains from `init` (its [`Look::aim`]), if any; whether it is
    /// one already found is [`already_found`]'s to say.
    pub(super) fn at(&self, ei: usize, init: Similarity) -> Option<Found> {
        let (ext, edge) = (&self.ext, &self.edge);
        let e = &self.lib.entries[ei];
        let tol = (self.tolerance)(ei);
        // Cheap looks first: most peaks are another part's outline voting by chance, or the
        // same part again (see `already_found`), and end here before any registration.
        if support(&e.shape, &init, ext, edge, 2.0 * tol, 4) < LOOK_FROM {
            return None;
        }
        // Registration on the stretch of the region's outline the part can reach: the rest is
        // its neighbours', and costs correspondence searches that find nothing.
        let reach = e.shape.radius * 1.2 + 2.0 * register::MAX_REACH;
        let local: Vec<Pt> = self.outline.iter().copied().filter(|p| (*p - init.to).norm() <= reach).collect();
        if local.len() < 16 {
            return None;
        }
        let rough = register::register(&local, &e.index, init, tol, 4);
        if support(&e.shape, &rough.pose, ext, edge, tol, 3) < MIN_SUPPORT - 0.05 {
            return None;
        }
        let reg = register::register(&local, &e.index, rough.pose, tol, 2);
        let (support, points) = verify(&e.shape, &reg.pose, ext, edge, tol);
        (support >= MIN_SUPPORT).then_some(Found {
            entry: ei,
            reg,
            tolerance: tol,
            support,
            under: None,
            order_unclear: false,
            rivals: Vec::new(),
            points,
        })
    }
}

/// Whether template `ei` aimed at `init` is a part already `found`: the same template within
/// 20 px and 4 degrees.
pub(super) fn already_found(found: &[Found], ei: usize, init: &Similarity) -> bool {
    found.iter().any(|f| {
        f.entry == ei && (f.reg.pose.to - init.to).norm() < 20.0 && angle_diff_deg(f.reg.pose.angle_deg(), init.angle_deg()).abs() < 4.0
    })
}

/// The fraction of the template's outline at `pose` (every `stride`-th point) that the region's
/// outline (within `tol`) or an edge in the image explains: the cheap look that most hypotheses
/// end at, before any registration.
fn support(model: &ShapeModel, pose: &Similarity, ext: &OutlineIndex, edge: &EdgeTest<'_>, tol: f64, stride: usize) -> f64 {
    let to_frame = pose.forward();
    let turn = Affine::rotation(pose.angle_rad);
    let (mut n, mut seen) = (0usize, 0usize);
    for &(m, nm) in model.verify.iter().step_by(stride) {
        let at = to_frame.apply(m);
        n += 1;
        if ext.any_within(at, tol * pose.scale) || edge.shows(at, turn.apply(nm)) {
            seen += 1;
        }
    }
    seen as f64 / n.max(1) as f64
}

/// The template's outline at `pose`, point by point: explained by the region's outline, or by an
/// edge in the image. Returns the explained fraction and the points.
fn verify(model: &ShapeModel, pose: &Similarity, ext: &OutlineIndex, edge: &EdgeTest<'_>, tol: f64) -> (f64, Vec<Probe>) {
    let mut pts = Vec::with_capacity(model.verify.len());
    let to_frame = pose.forward();
    let turn = Affine::rotation(pose.angle_rad);
    for &(m, n) in &model.verify {
        let at = to_frame.apply(m);
        let nn = turn.apply(n);
        // Within the tolerance anywhere, or within twice it where the region's outline runs
        // parallel to the template's, offset straight along the normal: a rounded part's
        // silhouette moves with the light, and a cast part's arm is a few pixels thinner or
        // bent by the part's tolerance and the lens, while the outline of whatever else lies
        // there (a part across it, debris) runs its own way. (The nearest within twice the
        // tolerance is the nearest within the tolerance whenever that one exists.)
        let on_region = ext.nearest(at, 2.0 * tol * pose.scale).is_some_and(|(i, d, q)| {
            d <= tol * pose.scale || ext.normal(i).dot(nn) >= PARALLEL_COS && (q - at).dot(nn).abs() >= PARALLEL_COS * d
        });
        let mut probe = Probe { at, normal: nn, seen: on_region, across: f64::NAN };
        if !on_region {
            probe.seen = probe.across(edge).abs() >= edge.threshold;
        }
        pts.push(probe);
    }
    (pts.iter().filter(|p| p.seen).count() as f64 / pts.len().max(1) as f64, pts)
}
