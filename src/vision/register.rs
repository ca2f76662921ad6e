//! Stage 4b: fine registration of a part's outline onto a template's.
//!
//! The correlation's angle is good to a fraction of a bin and its centroid to a pixel or so. The
//! grasp needs better, and the accept decision needs a measure of fit that a human can read:
//! point-to-line ICP of the refined outline against the template's outline, solving for a
//! similarity transform (angle, scale, translation), with Tukey weights so that a neighbour's edge
//! or a chipped corner does not pull the pose. Its by-products are the numbers the decision uses:
//! which fraction of the part's outline lies on the template's (`inliers`), which fraction of the
//! template's outline is seen in the part (`coverage`), and the RMS distance of the inliers.

use super::geometry::{Pt, Similarity, point_segment};
use nalgebra::{Matrix4, Vector4};
use std::sync::OnceLock;

/// Correspondences farther than this (template pixels) are never looked for.
pub const MAX_REACH: f64 = 24.0;
/// Reach of the fine grid used once the pose is close.
const NEAR_REACH: f64 = 8.0;
/// Reach of the middle grid: the second ICP iteration and the fit measures (whose gross
/// distance is usually its lower bound, 12 px) look this far, and a cell list that reaches no
/// farther holds half the segments of the coarse one.
const MID_REACH: f64 = 12.0;

/// Segments near each cell of a uniform grid, stored compactly (one list for all cells, an offset
/// per cell): a region's outline is indexed once per frame, and a list per cell made that cost
/// more allocations than the queries it served.
#[derive(Debug, Clone)]
struct Grid {
    cell: f64,
    origin: Pt,
    cols: usize,
    rows: usize,
    /// Cell `k`'s segments are `items[starts[k]..starts[k + 1]]`.
    starts: Vec<u32>,
    items: Vec<u32>,
}

impl Grid {
    /// Every segment within `reach` of a cell, in cells of `cell` pixels. `prune` keeps in each
    /// cell only the segments that can be the nearest for some point of it (within the reach),
    /// which makes queries several times cheaper and the build several times dearer: right for
    /// a template, indexed once and queried for every frame.
    fn new(outline: &[Pt], reach: f64, cell: f64, prune: bool) -> Self {
        let n = outline.len();
        let (lo, hi) = super::geometry::bounds(outline);
        let origin = Pt::new(lo.x - reach - cell, lo.y - reach - cell);
        let cols = (((hi.x - origin.x) + reach + cell) / cell).ceil() as usize + 1;
        let rows = (((hi.y - origin.y) + reach + cell) / cell).ceil() as usize + 1;
        // The cells each segment's box (grown by the reach) covers.
        let span = |i: usize| {
            let a = outline[i];
            let b = outline[(i + 1) % n];
            let x0 = ((a.x.min(b.x) - reach - origin.x) / cell).floor().max(0.0) as usize;
            let x1 = (((a.x.max(b.x) + reach - origin.x) / cell).floor() as usize).min(cols - 1);
            let y0 = ((a.y.min(b.y) - reach - origin.y) / cell).floor().max(0.0) as usize;
            let y1 = (((a.y.max(b.y) + reach - origin.y) / cell).floor() as usize).min(rows - 1);
            (x0, x1, y0, y1)
        };
        // Counting sort: sizes, offsets, then the items in segment order within each cell.
        let mut starts = vec![0u32; cols * rows + 1];
        for i in 0..n {
            let (x0, x1, y0, y1) = span(i);
            for y in y0..=y1 {
                for c in &mut starts[y * cols + x0 + 1..=y * cols + x1 + 1] {
                    *c += 1;
                }
            }
        }
        for k in 1..starts.len() {
            starts[k] += starts[k - 1];
        }
        let mut next = starts.clone();
        let mut items = vec![0u32; starts[cols * rows] as usize];
        for i in 0..n {
            let (x0, x1, y0, y1) = span(i);
            for y in y0..=y1 {
                for k in y * cols + x0..=y * cols + x1 {
                    items[next[k] as usize] = i as u32;
                    next[k] += 1;
                }
            }
        }
        if prune {
            // For a point p of a cell with centre c and half-diagonal h, and any segment s,
            // d(c, s) - h <= d(p, s) <= d(c, s) + h: the nearest segment to p lies within
            // min_s d(c, s) + 2h of c. Segments farther than that from c, or farther than the
            // reach plus h, can never be the answer from this cell.
            let h = cell * std::f64::consts::SQRT_2 / 2.0;
            let mut kept = 0usize;
            let mut dist: Vec<f64> = Vec::new();
            for k in 0..cols * rows {
                let c = Pt::new(origin.x + ((k % cols) as f64 + 0.5) * cell, origin.y + ((k / cols) as f64 + 0.5) * cell);
                let (from, to) = (starts[k] as usize, starts[k + 1] as usize);
                dist.clear();
                dist.extend(items[from..to].iter().map(|&i| point_segment(c, outline[i as usize], outline[(i as usize + 1) % n]).0));
                let least = dist.iter().copied().fold(f64::INFINITY, f64::min);
                let bound = (least + 2.0 * h).min(reach + h);
                starts[k] = kept as u32;
                for (j, d) in (from..to).zip(&dist) {
                    if *d <= bound {
                        items[kept] = items[j];
                        kept += 1;
                    }
                }
            }
            starts[cols * rows] = kept as u32;
            items.truncate(kept);
            items.shrink_to_fit();
        }
        Self { cell, origin, cols, rows, starts, items }
    }

    fn candidates(&self, q: Pt) -> &[u32] {
        let cx = (q.x - self.origin.x) / self.cell;
        let cy = (q.y - self.origin.y) / self.cell;
        // Truncation is the floor once negatives are out (and needs no libm call: this is the
        // innermost query of the registration and the verification). NaN fails the tests too.
        if !(cx >= 0.0 && cy >= 0.0) || cx as usize >= self.cols || cy as usize >= self.rows {
            return &[];
        }
        let k = cy as usize * self.cols + cx as usize;
        &self.items[self.starts[k] as usize..self.starts[k + 1] as usize]
    }
}

/// An outline with spatial indexes for nearest-segment queries.
#[derive(Debug, Clone)]
pub struct OutlineIndex {
    pts: Vec<Pt>,
    /// Segment i (pts[i] -> pts[i+1]) ready for the distance of a point: the innermost loop of
    /// registration and verification, spared a division, a modulo and a square root per segment.
    segs: Vec<Seg>,
    /// Outward unit normal of segment i (pts[i] -> pts[i+1]).
    normals: Vec<Pt>,
    lens: Vec<f64>,
    /// By increasing reach; a query uses the first that reaches as far. Built when first asked
    /// for: a region's outline is indexed for every frame, and most frames' queries never look
    /// as far as the coarse grid reaches (it cost a tenth of a touching pair's instructions).
    grids: Vec<LazyGrid>,
}

/// A grid's shape, and the grid once some query needed it.
#[derive(Debug, Clone)]
struct LazyGrid {
    reach: f64,
    cell: f64,
    prune: bool,
    grid: OnceLock<Grid>,
}

impl LazyGrid {
    fn new(reach: f64, cell: f64, prune: bool) -> Self {
        Self { reach, cell, prune, grid: OnceLock::new() }
    }

    fn get(&self, outline: &[Pt]) -> &Grid {
        self.grid.get_or_init(|| Grid::new(outline, self.reach, self.cell, self.prune))
    }
}

impl OutlineIndex {
    /// An index of a template's closed outline (template pixels), built once and queried for
    /// every part of every frame: one grid pruned to the segments that can be nearest.
    pub fn new(outline: &[Pt]) -> Self {
        let index = Self::with_grids(outline, vec![LazyGrid::new(MAX_REACH, 4.0, true)]);
        // Built now, once, not in the first frame's time.
        index.grids[0].get(&index.pts);
        index
    }

    /// An index of an outline found in a frame, queried a few thousand times: cheap to build
    /// (unpruned grids, a coarse one reaching far and finer ones for short reaches).
    pub fn of_frame(outline: &[Pt]) -> Self {
        Self::with_grids(
            outline,
            vec![LazyGrid::new(NEAR_REACH, 4.0, false), LazyGrid::new(MID_REACH, 4.0, false), LazyGrid::new(MAX_REACH, 8.0, false)],
        )
    }

    fn with_grids(outline: &[Pt], grids: Vec<LazyGrid>) -> Self {
        let n = outline.len();
        let (area, _) = super::geometry::area_centroid(outline);
        let sign = if area > 0.0 { 1.0 } else { -1.0 };
        let mut normals = Vec::with_capacity(n);
        let mut lens = Vec::with_capacity(n);
        let mut segs = Vec::with_capacity(n);
        for i in 0..n {
            let e = outline[(i + 1) % n] - outline[i];
            let l = e.norm().max(1e-12);
            normals.push(Pt::new(e.y / l * sign, -e.x / l * sign));
            lens.push(l);
            let l2 = e.dot(e);
            segs.push(Seg { a: outline[i], ab: e, inv_l2: if l2 > 0.0 { 1.0 / l2 } else { 0.0 } });
        }
        Self { pts: outline.to_vec(), segs, normals, lens, grids }
    }

    /// The outline indexed.
    pub fn outline(&self) -> &[Pt] {
        &self.pts
    }

    /// Outward unit normal of segment `i` (as returned by [`OutlineIndex::nearest`]).
    pub fn normal(&self, i: usize) -> Pt {
        self.normals[i]
    }

    /// The first grid that reaches as far as `reach`: each holds every segment that can be the
    /// nearest within its reach of a cell, so the answer is the same from any of them, only
    /// found sooner.
    fn grid(&self, reach: f64) -> Option<&Grid> {
        let lazy = self.grids.iter().find(|g| reach <= g.reach).or(self.grids.last())?;
        Some(lazy.get(&self.pts))
    }

    /// Nearest segment to `q` within `reach` (at most [`MAX_REACH`]): (segment, distance, foot).
    pub fn nearest(&self, q: Pt, reach: f64) -> Option<(usize, f64, Pt)> {
        let grid = self.grid(reach)?;
        // Squared distances throughout; the one square root is the answer's.
        let (mut best, mut best_d2, mut foot) = (usize::MAX, reach * reach, Pt::new(0.0, 0.0));
        for &i in grid.candidates(q) {
            let s = &self.segs[i as usize];
            let aq = q - s.a;
            let t = (aq.dot(s.ab) * s.inv_l2).clamp(0.0, 1.0);
            let f = s.a + s.ab.scale(t);
            let (dx, dy) = (f.x - q.x, f.y - q.y);
            let d2 = dx * dx + dy * dy;
            if d2 < best_d2 || d2 == best_d2 && best == usize::MAX {
                (best, best_d2, foot) = (i as usize, d2, f);
            }
        }
        (best != usize::MAX).then(|| (best, best_d2.sqrt(), foot))
    }
}

impl OutlineIndex {
    /// Whether any segment lies within `reach` of `q` (at most [`MAX_REACH`]): the verification's
    /// question, answered at the first segment that is near enough.
    pub fn any_within(&self, q: Pt, reach: f64) -> bool {
        let Some(grid) = self.grid(reach) else { return false };
        let r2 = reach * reach;
        grid.candidates(q).iter().any(|&i| {
            let s = &self.segs[i as usize];
            let t = ((q - s.a).dot(s.ab) * s.inv_l2).clamp(0.0, 1.0);
            let f = s.a + s.ab.scale(t);
            let (dx, dy) = (f.x - q.x, f.y - q.y);
            dx * dx + dy * dy <= r2
        })
    }
}

/// A segment of an indexed outline: its start, its vector and the inverse of its squared length
/// (0 for a degenerate one, whose nearest point is its start).
#[derive(Debug, Clone, Copy)]
struct Seg {
    a: Pt,
    ab: Pt,
    inv_l2: f64,
}

/// Outcome of a registration.
#[derive(Debug, Clone, Copy)]
pub struct Registration {
    /// Template pixels -> frame pixels.
    pub pose: Similarity,
    /// Fraction of the part's outline within the tolerance of the template's.
    pub inliers: f64,
    /// Length fraction of the template's outline with part outline within the tolerance.
    pub coverage: f64,
    /// RMS distance of the inliers, template pixels.
    pub rms: f64,
    /// Fraction of the part's outline far (beyond [`gross_distance`]) from the template's:
    /// material that is not this part (a neighbour, an overlapping part, debris).
    pub extra: f64,
    /// Length fraction of the template's outline with no part outline near it: this part's
    /// material that is not seen (hidden under another part, broken off).
    pub missing: f64,
}

/// The tolerance at which a rival template is held against the best: four times the best fit's
/// own residual, within the fit tolerance (`floor`) and the generous one (`generous`) it was
/// named at. Noise widens the tolerance for naming a type, but must not blur a small face
/// difference into a tie. One rule for the separate-part path and the region search.
pub fn tight_tolerance(best_rms: f64, floor: f64, generous: f64) -> f64 {
    (4.0 * best_rms).max(floor).min(generous)
}

/// A part's outline with the uniform offset from its template taken out ([`even_out`]).
#[derive(Debug, Clone)]
pub struct Evened {
    /// The outline, frame pixels: each point within the tolerance of the template moved back
    /// along the template's normal by `offset`, the others as they were.
    pub outline: Vec<Pt>,
    /// The median signed distance of the outline from the template's along its normal,
    /// template pixels.
    pub offset: f64,
    /// How far the outline scatters about the template once the offset is out: the median
    /// distance scaled (x 1.4826) to equal the rms of Gaussian scatter, template pixels.
    pub scatter: f64,
}

/// Takes out of `part` (frame pixels) its uniform offset from the template `tmpl` placed by
/// `pose`, measured on the points within `tolerance` of it. Glare blooms a silhouette outward
/// and dim light shrinks it, by about the same distance all round: no similarity takes that up,
/// and left in it counts against every template alike and widens the tight tolerance until
/// revision siblings tie. The median is not moved by a lug or notch (a few per cent of the
/// outline), which stays where it is to be compared.
pub fn even_out(part: &[Pt], tmpl: &OutlineIndex, pose: Similarity, tolerance: f64) -> Evened {
    let to_template = pose.inverse();
    // Per point: where it is in the template's frame, the template's normal there, and its
    // signed distance along that normal.
    let near: Vec<Option<(Pt, Pt, f64)>> = part
        .iter()
        .map(|&p| {
            let q = to_template.apply(p);
            tmpl.nearest(q, tolerance).map(|(i, _, foot)| (q, tmpl.normal(i), (q - foot).dot(tmpl.normal(i))))
        })
        .collect();
    let mut d: Vec<f64> = near.iter().flatten().map(|&(_, _, s)| s).collect();
    if d.is_empty() {
        return Evened { outline: part.to_vec(), offset: 0.0, scatter: f64::INFINITY };
    }
    let median = |v: &mut [f64]| {
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let offset = median(&mut d);
    let mut dev: Vec<f64> = d.iter().map(|x| (x - offset).abs()).collect();
    let scatter = 1.4826 * median(&mut dev);
    let outline = part.iter().zip(&near).map(|(&p, x)| x.map_or(p, |(q, n, _)| pose.apply(q - n.scale(offset)))).collect();
    Evened { outline, offset, scatter }
}

/// Beyond this distance (template pixels) an outline point is not a local segmentation
/// difference but something else: three tolerances, within 12..=24 px.
pub fn gross_distance(tolerance: f64) -> f64 {
    (3.0 * tolerance).clamp(12.0, MAX_REACH)
}

impl Registration {
    /// One number for "how well does this template explain this outline": the worse of the two
    /// directions, so that both extra material (a neighbour) and missing material (occlusion)
    /// lower it.
    pub fn fit(&self) -> f64 {
        self.inliers.min(self.coverage)
    }
}

/// Registers `part` (frame pixels) onto the template outline, starting from `init`.
/// `tolerance` (template pixels) separates inliers from outliers in the final statistics;
/// `stride` > 1 uses every stride-th point only (a cheaper, slightly noisier answer, enough to
/// tell a rival template from the right one).
pub fn register(part: &[Pt], tmpl: &OutlineIndex, init: Similarity, tolerance: f64, stride: usize) -> Registration {
    let (pose, _) = icp(part, tmpl, init, stride, 0.0);
    measure(part, tmpl, pose, tolerance, stride)
}

/// [`register`], giving up once the pose is within `GIVE_UP_REACH` of its answer if fewer
/// than `least` of the part's points lie that close to the template: an outline that is mostly
/// something else (a region of several parts) will not fit, and the rest of the iterations on
/// every point would only measure how badly. Err holds the pose so far, measured on every
/// fourth point.
pub fn register_unless(
    part: &[Pt],
    tmpl: &OutlineIndex,
    init: Similarity,
    tolerance: f64,
    least: f64,
) -> Result<Registration, Registration> {
    match icp(part, tmpl, init, 1, least) {
        (pose, false) => Ok(measure(part, tmpl, pose, tolerance, 1)),
        (pose, true) => Err(measure(part, tmpl, pose, tolerance, 4)),
    }
}

/// The correspondence reach at which [`register_unless`] judges: the third iteration's.
const GIVE_UP_REACH: f64 = 8.0;

/// Point-to-line ICP from `init`: the pose, and whether it gave up (see [`register_unless`]).
fn icp(part: &[Pt], tmpl: &OutlineIndex, init: Similarity, stride: usize, least: f64) -> (Similarity, bool) {
    // Parameterise the frame -> template map as q = c_t + tau + M (p - c_p), M = [[a, -b], [b, a]].
    let cp = init.to;
    let ct = init.from;
    let inv_s = 1.0 / init.scale;
    let (mut a, mut b) = (init.angle_rad.cos() * inv_s, init.angle_rad.sin() * inv_s);
    let (mut tx, mut ty) = (0.0, 0.0);
    let map = |a: f64, b: f64, tx: f64, ty: f64, p: Pt| -> Pt {
        let d = p - cp;
        Pt::new(ct.x + tx + a * d.x - b * d.y, ct.y + ty + b * d.x + a * d.y)
    };
    let stride = stride.max(1);
    let pose_of = |a: f64, b: f64, tx: f64, ty: f64| Similarity {
        from: Pt::new(ct.x + tx, ct.y + ty),
        to: cp,
        angle_rad: b.atan2(a),
        scale: 1.0 / a.hypot(b),
    };
    // Tukey cut-off shrinks from the correspondence reach to a few pixels; early iterations use a
    // quarter of the points, which is plenty while the pose is still moving by pixels.
    let schedule: [(f64, usize); 8] = [(MAX_REACH, 4), (12.0, 4), (8.0, 4), (6.0, 2), (5.0, 1), (4.0, 1), (4.0, 1), (4.0, 1)];
    for (iter, &(c, sub)) in schedule.iter().enumerate() {
        let step = stride.max(sub);
        let mut h = Matrix4::<f64>::zeros();
        let mut g = Vector4::<f64>::zeros();
        let (mut used, mut looked) = (0usize, 0usize);
        for &p in part.iter().step_by(step) {
            looked += 1;
            let q = map(a, b, tx, ty, p);
            let Some((i, dist, foot)) = tmpl.nearest(q, c) else {
                continue;
            };
            if dist >= c {
                continue;
            }
            let w = {
                let u = dist / c;
                (1.0 - u * u).powi(2)
            };
            let n = tmpl.normals[i];
            let d = p - cp;
            let j = Vector4::new(n.x * d.x + n.y * d.y, -n.x * d.y + n.y * d.x, n.x, n.y);
            let r = n.dot(q - foot);
            h += j * j.transpose() * w;
            g += j * (w * r);
            used += 1;
        }
        if used < 8 {
            break;
        }
        if c == GIVE_UP_REACH && (used as f64) < least * looked as f64 {
            return (pose_of(a, b, tx, ty), true);
        }
        // Levenberg damping keeps a degenerate first step (a circle's rotation) finite.
        let damp = Matrix4::from_diagonal(&Vector4::new(1e-9, 1e-9, 1e-9, 1e-9)) * h.trace().max(1.0);
        let Some(delta) = (h + damp).lu().solve(&(-g)) else {
            break;
        };
        a += delta[0];
        b += delta[1];
        tx += delta[2];
        ty += delta[3];
        // Converged on all points: the last step moved the outline by under a hundredth of a pixel.
        let moved = (delta[0].hypot(delta[1]) * 300.0).max(delta[2].hypot(delta[3]));
        if iter >= 5 && moved < 0.01 {
            break;
        }
    }
    (pose_of(a, b, tx, ty), false)
}

/// How well `tmpl` placed by `pose` explains `part`, at a given tolerance (template pixels).
pub fn measure(part: &[Pt], tmpl: &OutlineIndex, pose: Similarity, tolerance: f64, stride: usize) -> Registration {
    let stride = stride.max(1);
    let n_t = tmpl.pts.len();
    let mut covered = vec![false; n_t];
    let mut near = vec![false; n_t];
    let gross = gross_distance(tolerance);
    let (mut inl, mut far, mut total, mut ss) = (0usize, 0usize, 0usize, 0.0);
    // A part point vouches for its segment and enough neighbours to span the sampling gap.
    let spread = stride as isize;
    let to_template = pose.inverse();
    for &p in part.iter().step_by(stride) {
        total += 1;
        let q = to_template.apply(p);
        match tmpl.nearest(q, gross) {
            Some((i, dist, _)) => {
                for d in -spread..=spread {
                    let j = (i as isize + d).rem_euclid(n_t as isize) as usize;
                    near[j] = true;
                    if dist <= tolerance {
                        covered[j] = true;
                    }
                }
                if dist <= tolerance {
                    inl += 1;
                    ss += dist * dist;
                }
            }
            None => far += 1,
        }
    }
    let total_len: f64 = tmpl.lens.iter().sum();
    let frac = |flags: &[bool]| {
        if total_len > 0.0 { tmpl.lens.iter().zip(flags).filter(|(_, c)| **c).map(|(l, _)| l).sum::<f64>() / total_len } else { 0.0 }
    };
    let tot = total.max(1) as f64;
    Registration {
        pose,
        inliers: inl as f64 / tot,
        coverage: frac(&covered),
        rms: if inl > 0 { (ss / inl as f64).sqrt() } else { f64::INFINITY },
        extra: far as f64 / tot,
        missing: 1.0 - frac(&near),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::geometry::resample_closed;

    fn blob() -> Vec<Pt> {
        let raw: Vec<Pt> = (0..400)
            .map(|i| {
                let a = i as f64 / 400.0 * std::f64::consts::TAU;
                let r = 80.0 + 15.0 * (3.0 * a).sin() + 9.0 * (2.0 * a + 0.4).cos();
                Pt::new(200.0 + r * a.cos(), 150.0 + r * a.sin())
            })
            .collect();
        resample_closed(&raw, 2.0)
    }

    /// A silhouette bloomed all round by 1.5 px (glare) is evened back onto its template, with
    /// little scatter left; a lug 20 px proud on a tenth of it moves neither the offset nor
    /// itself.
    #[test]
    fn evening_out_takes_out_a_uniform_bloom_and_keeps_a_lug() {
        let t = blob();
        let idx = OutlineIndex::new(&t);
        let at = Similarity { from: Pt::new(200.0, 150.0), to: Pt::new(900.0, 500.0), angle_rad: 0.8, scale: 1.0 };
        let n = t.len();
        let bloomed: Vec<Pt> = t
            .iter()
            .enumerate()
            .map(|(i, &q)| {
                let lug = if i < n / 10 { 20.0 } else { 0.0 };
                at.apply(q + idx.normal(i).scale(1.5 + lug))
            })
            .collect();
        let e = even_out(&bloomed, &idx, at, 6.0);
        assert!((e.offset.abs() - 1.5).abs() < 0.05, "offset {}", e.offset);
        assert!(e.scatter < 0.2, "scatter {}", e.scatter);
        let to_t = at.inverse();
        for (i, &p) in e.outline.iter().enumerate() {
            let d = idx.nearest(to_t.apply(p), MAX_REACH).map_or(MAX_REACH, |(_, d, _)| d);
            if i < n / 10 - 2 {
                assert!(d > 15.0, "the lug stays: point {i} at {d:.2} px");
            } else if i >= n / 10 + 2 && i < n - 2 {
                assert!(d < 0.3, "point {i} at {d:.2} px after evening out");
            }
        }
    }

    #[test]
    fn recovers_a_similarity_from_a_rough_start() {
        let t = blob();
        let idx = OutlineIndex::new(&t);
        let truth = Similarity { from: Pt::new(200.0, 150.0), to: Pt::new(812.3, 433.7), angle_rad: 0.6, scale: 1.04 };
        let part: Vec<Pt> = resample_closed(&t, 1.7).iter().map(|&q| truth.apply(q)).collect();
        let init = Similarity { from: Pt::new(201.5, 149.0), to: Pt::new(812.3, 433.7), angle_rad: 0.6 + 0.01, scale: 1.0 };
        let r = register(&part, &idx, init, 2.0, 1);
        let err = truth.apply(Pt::new(230.0, 170.0)) - r.pose.apply(Pt::new(230.0, 170.0));
        assert!(err.norm() < 0.02, "point error {err:?}");
        assert!((r.pose.angle_rad - 0.6).abs() < 1e-4);
        assert!((r.pose.scale - 1.04).abs() < 1e-4);
        assert!(r.inliers > 0.99 && r.coverage > 0.99);
    }

    #[test]
    fn a_different_shape_fits_badly() {
        let t = blob();
        let idx = OutlineIndex::new(&t);
        let other: Vec<Pt> = (0..400)
            .map(|i| {
                let a = i as f64 / 400.0 * std::f64::consts::TAU;
                Pt::new(200.0 + 85.0 * a.cos(), 150.0 + 85.0 * a.sin())
            })
            .collect();
        let init = Similarity { from: Pt::new(200.0, 150.0), to: Pt::new(200.0, 150.0), angle_rad: 0.0, scale: 1.0 };
        let r = register(&other, &idx, init, 2.0, 1);
        assert!(r.fit() < 0.5, "fit {}", r.fit());
    }

    #[test]
    fn the_nearest_segment_is_the_same_whichever_grid_answers() {
        let t = blob();
        for idx in [OutlineIndex::new(&t), OutlineIndex::of_frame(&t)] {
            nearest_is_brute_force(&t, &idx);
        }
    }

    /// Pruned (a template's) or not (a frame's): the grids must answer as brute force does, the
    /// nearest segment and whether any lies within reach.
    fn nearest_is_brute_force(t: &[Pt], idx: &OutlineIndex) {
        let n = t.len();
        let mut seed = 12345u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..2000 {
            let q = Pt::new(90.0 + 220.0 * next(), 40.0 + 220.0 * next());
            for reach in [3.0, 8.0, 10.0, 12.0, 17.0, MAX_REACH] {
                let brute = (0..n)
                    .map(|i| (i, point_segment(q, t[i], t[(i + 1) % n]).0))
                    .filter(|&(_, d)| d <= reach)
                    .min_by(|a, b| a.1.total_cmp(&b.1));
                let got = idx.nearest(q, reach).map(|(i, d, _)| (i, d));
                assert_eq!(idx.any_within(q, reach), brute.is_some(), "{q:?} reach {reach}: any_within");
                match (brute, got) {
                    (None, None) => {}
                    (Some((_, bd)), Some((_, gd))) => assert!((bd - gd).abs() < 1e-9, "{q:?} reach {reach}: {bd} vs {gd}"),
                    other => panic!("{q:?} reach {reach}: brute force and grid disagree: {other:?}"),
                }
            }
        }
    }
}
