//! A template's outline as the region search uses it: the voting points (each with its normal's
//! angle and the outline's turn there) and the verification points, the edge test that reads
//! the coarse frame across an outline, and a part's interior edges. Below both `template`, which
//! builds them once per template, and `clump`, which votes and verifies with them.

use opencv::prelude::*;

use super::decide::OwnFeatures;
use super::detect::Coarse;
use super::geometry::{Affine, Inside, Pt, Similarity, outward_normals, resample_closed, smooth_closed};
use super::register::OutlineIndex;

/// Width below which a gap between two lobes of a template's outline is not verified, template
/// pixels: about the reach of the outline's refinement (3 decimated pixels and 4 more at the
/// usual decimation 4), within which the refined outline may as well bridge the gap as enter it.
const NARROW_GAP: f64 = 16.0;

/// Spacing of the voting points on the region's outline, frame pixels (and of the points the
/// turn is measured over on both outlines): fine enough that a part's visible stretch casts
/// dozens of votes, coarse enough that a pair of parts costs well under 0.1 M votes per template
/// once the turns are matched.
const VOTE_SPACING: f64 = 10.0;
/// A template votes from every this many of its outline's voting points: a region point still
/// finds a template point within a cell of its true partner, so a true pose's votes land in the
/// peak's 3 x 3 cells as before, at half the votes (the same parts found on all three sets and on
/// unseen simulator seeds, in half the voting time).
pub(super) const MODEL_VOTE_STRIDE: usize = 2;
/// Angle steps of the normals and of the rotation table (half a degree).
pub(super) const FINE: usize = 720;
/// Points either side over which the outline's turn is measured (about 24 px).
const TURN_SPAN: usize = 3;
/// Spacing of the verification points on a template's outline, frame pixels.
const VERIFY_SPACING: f64 = 4.0;

/// A template's outline prepared for voting and verification.
#[derive(Debug, Clone)]
pub struct ShapeModel {
    /// Voting points: offset from the point to the centroid, the outward normal's angle in
    /// [`FINE`] steps, and the outline's turn there; sorted by turn.
    pub(super) vote: Vec<(Pt, usize, i32)>,
    /// Verification points on the outline and their outward unit normals (template pixels).
    pub(super) verify: Vec<(Pt, Pt)>,
    /// Largest distance of the outline from the centroid, template pixels.
    pub(super) radius: f64,
}

impl ShapeModel {
    /// The model of a template's outline with this centroid (template pixels).
    pub fn new(outline: &[Pt], centroid: Pt) -> Self {
        let mut vote: Vec<(Pt, usize, i32)> =
            oriented_points(outline).into_iter().step_by(MODEL_VOTE_STRIDE).map(|(p, a, t)| (centroid - p, a, t)).collect();
        vote.sort_by_key(|v| v.2);
        let fp = resample_closed(outline, VERIFY_SPACING);
        let fs = smooth_closed(&fp, 2);
        let fnm = outward_normals(&fs, 2);
        // Where the outline runs into a narrow gap between two lobes of the part (a crevice, a
        // slit beside a boss), the same part may show the gap or bridge it, depending on blur,
        // light, tilt and the decimated closing: neither seeing nor missing it there says
        // anything, so those points are not verified.
        let coarse_poly = Inside::new(&resample_closed(outline, 4.0));
        let in_gap = |p: Pt, n: Pt| (1..=(NARROW_GAP / 2.0) as usize).any(|k| coarse_poly.contains(p + n.scale(2.0 * k as f64)));
        let verify = fp.iter().copied().zip(fnm).filter(|&(p, n)| !in_gap(p, n)).collect();
        let radius = outline.iter().map(|p| (*p - centroid).norm()).fold(0.0, f64::max);
        Self { vote, verify, radius }
    }
}

/// A direction's display angle in [`FINE`] steps.
fn fine_angle(n: Pt) -> usize {
    ((n.display_angle() / std::f64::consts::TAU * FINE as f64).round() as i64).rem_euclid(FINE as i64) as usize
}

/// Outline points for voting: position, outward normal angle and turn (the normal's change over
/// [`TURN_SPAN`] points either side), both in [`FINE`] steps.
pub(super) fn oriented_points(outline: &[Pt]) -> Vec<(Pt, usize, i32)> {
    let p = resample_closed(outline, VOTE_SPACING);
    let n = p.len();
    if n < 2 * TURN_SPAN + 2 {
        return Vec::new();
    }
    let s = smooth_closed(&p, 1);
    let a: Vec<usize> = outward_normals(&s, 1).into_iter().map(fine_angle).collect();
    (0..n)
        .map(|i| {
            let (before, after) = (a[(i + n - TURN_SPAN) % n] as i32, a[(i + TURN_SPAN) % n] as i32);
            let half = FINE as i32 / 2;
            let turn = (after - before + FINE as i32 + half).rem_euclid(FINE as i32) - half;
            (s[i], a[i], turn)
        })
        .collect()
}

/// Edge evidence across a line, from the blurred decimated frame: the gray-level step across the
/// normal, taken at the best of a few offsets along it (the pose is good to a pixel or two).
pub(super) struct EdgeTest<'a> {
    img: &'a [u8],
    width: usize,
    height: usize,
    factor: usize,
    /// Least step (gray levels) that counts as an edge.
    pub(super) threshold: f64,
    /// Least difference of mean steps that tells which of two outlines shows more.
    pub(super) margin: f64,
}

impl<'a> EdgeTest<'a> {
    pub(super) fn new(coarse: &'a Coarse, noise: f64, contrast: f64) -> Self {
        let f = coarse.factor as f64;
        // Decimation averages about f/2 x f/2 pixels (bilinear of the middle 2 x 2 at f = 4) and the
        // blur divides white noise by 2 sqrt(pi) sigma; a difference of two samples has sqrt 2 x.
        let sigma_b = noise / (f / 2.0).max(1.0) / (2.0 * std::f64::consts::PI.sqrt() * 1.5);
        let threshold = (0.25 * contrast).max(4.0 * std::f64::consts::SQRT_2 * sigma_b).max(4.0);
        let m = &coarse.blurred;
        let img = m.data_bytes().unwrap_or(&[]);
        let (width, height) = if img.is_empty() { (0, 0) } else { (m.cols() as usize, m.rows() as usize) };
        // Mean steps over dozens of points: a few noise sigmas of one step suffice.
        let margin = (2.0 * std::f64::consts::SQRT_2 * sigma_b).max(0.03 * contrast).max(2.0);
        Self { img, width, height, factor: coarse.factor, threshold, margin }
    }

    /// Gray-level gradient of the blurred decimated frame at `p` (frame pixels, per decimated
    /// pixel), by central differences.
    pub(super) fn gradient(&self, p: Pt) -> Option<Pt> {
        let f = self.factor as f64;
        let (dx, dy) = (Pt::new(f, 0.0), Pt::new(0.0, f));
        Some(Pt::new((self.sample(p + dx)? - self.sample(p - dx)?) / 2.0, (self.sample(p + dy)? - self.sample(p - dy)?) / 2.0))
    }

    fn sample(&self, p: Pt) -> Option<f64> {
        let f = self.factor as f64;
        let u = (p.x - (f - 1.0) / 2.0) / f;
        let v = (p.y - (f - 1.0) / 2.0) / f;
        let (w, h) = (self.width, self.height);
        if u < 0.0 || v < 0.0 || u >= w.saturating_sub(1) as f64 || v >= h.saturating_sub(1) as f64 {
            return None;
        }
        let (x0, y0) = (u as usize, v as usize);
        let (fx, fy) = (u - x0 as f64, v - y0 as f64);
        let i = y0 * w + x0;
        let g = |k: usize| self.img[k] as f64;
        let top = g(i) * (1.0 - fx) + g(i + 1) * fx;
        let bot = g(i + w) * (1.0 - fx) + g(i + w + 1) * fx;
        Some(top * (1.0 - fy) + bot * fy)
    }

    /// Whether [`EdgeTest::across`] reaches the threshold, looking from the middle outwards and
    /// stopping at the first offset that does.
    pub(super) fn shows(&self, p: Pt, n: Pt) -> bool {
        let f = self.factor as f64;
        let t = Pt::new(-n.y, n.x);
        [0, -1, 1, -2, 2, -3, 3].into_iter().any(|k| {
            let c = p + n.scale(k as f64 * 0.5 * f);
            let (Some(a), Some(b)) = (self.sample(c - n.scale(f)), self.sample(c + n.scale(f))) else {
                return false;
            };
            let across = (a - b).abs();
            // The step along the outline is sampled only for a step across it that is tall
            // enough (most points of a wrong hypothesis lie on flat belt or part).
            if across < self.threshold {
                return false;
            }
            let (Some(l), Some(r)) = (self.sample(c - t.scale(f)), self.sample(c + t.scale(f))) else {
                return false;
            };
            across >= 2.0 * (l - r).abs()
        })
    }

    /// The gray-level step across the normal `n` near `p` (frame pixels), inside minus outside:
    /// the largest, within
    /// a decimated pixel and a half along the normal, of the steps that run mostly across it
    /// (gradient within about 27 degrees of the normal), so that the texture and features of a
    /// neighbour's surface rarely count. 0 where none does.
    pub(super) fn across(&self, p: Pt, n: Pt) -> f64 {
        let f = self.factor as f64;
        let t = Pt::new(-n.y, n.x);
        let mut best = 0.0f64;
        let mut signed = 0.0f64;
        for k in -3..=3 {
            let c = p + n.scale(k as f64 * 0.5 * f);
            let (Some(a), Some(b), Some(l), Some(r)) =
                (self.sample(c - n.scale(f)), self.sample(c + n.scale(f)), self.sample(c - t.scale(f)), self.sample(c + t.scale(f)))
            else {
                continue;
            };
            let across = (a - b).abs();
            if across >= 2.0 * (l - r).abs() && across > best {
                best = across;
                signed = a - b;
            }
        }
        signed
    }
}

/// [`OwnFeatures`] of templates `a` and `b` (their interior features, see [`interior_edges`], and
/// poses): a feature shows where the step across it, from the brighter side to the darker,
/// reaches the edge threshold. Points where `excused` holds (near or under another part found
/// beside it) are not looked at: what shows there may be the other part's.
pub(super) fn own_features(
    edge: &EdgeTest<'_>,
    a: (&[(Pt, Pt)], &Similarity),
    b: (&[(Pt, Pt)], &Similarity),
    excused: &dyn Fn(Pt) -> bool,
) -> OwnFeatures {
    let placed = |(interior, pose): (&[(Pt, Pt)], &Similarity)| -> Vec<(Pt, Pt)> {
        let (to_frame, turn) = (pose.forward(), Affine::rotation(pose.angle_rad));
        interior
            .iter()
            .map(|&(q, n)| (to_frame.apply(q), turn.apply(n)))
            .filter(|&(at, _)| edge.sample(at).is_some() && !excused(at))
            .collect()
    };
    let (pa, pb) = (placed(a), placed(b));
    let near = 2.0 * edge.factor as f64;
    let own = |this: &[(Pt, Pt)], other: &[(Pt, Pt)]| -> (usize, f64) {
        let mine: Vec<&(Pt, Pt)> = this.iter().filter(|(p, _)| !other.iter().any(|(q, _)| (*p - *q).norm() <= near)).collect();
        let shown = mine.iter().filter(|(p, n)| edge.across(*p, *n) >= edge.threshold).count();
        (mine.len(), if mine.is_empty() { 0.0 } else { shown as f64 / mine.len() as f64 })
    };
    let ((a_count, a_shown), (b_count, b_shown)) = (own(&pa, &pb), own(&pb, &pa));
    OwnFeatures { a_count, a_shown, b_count, b_shown }
}

/// Least distance of an interior edge from the part's outline, frame pixels: three decimated
/// pixels, beyond the reach of [`EdgeTest::across`] (two and a half), so that the outline's own
/// step never counts as a feature inside.
const INTERIOR_MARGIN: f64 = 12.0;
/// Most interior edge points kept per template.
const INTERIOR_MAX: usize = 1500;

/// The edges inside a part (holes, pockets, bosses, ribs) as the coarse stage sees them: points
/// of the decimated Canny edges at least `INTERIOR_MARGIN` (12 px) inside `outline`, each with the
/// unit normal pointing from the brighter side to the darker, kept where the step across is at
/// least a third of the part's contrast against the belt (the features any frame of this part
/// shows, not its surface's texture). Which of two overlapping parts lies on top is seen most
/// surely where they overlap: the upper part's features show there, the lower part's are
/// hidden under the upper's surface.
pub fn interior_edges(coarse: &Coarse, outline: &[Pt], noise: f64, contrast: f64) -> Vec<(Pt, Pt)> {
    let edges = &coarse.edges;
    let Ok(data) = edges.data_bytes() else {
        return Vec::new();
    };
    let (w, h) = (edges.cols().max(0) as usize, edges.rows().max(0) as usize);
    if data.len() < w * h || outline.len() < 3 {
        return Vec::new();
    }
    let test = EdgeTest::new(coarse, noise, contrast);
    let index = OutlineIndex::of_frame(outline);
    let poly = Inside::new(&resample_closed(outline, 4.0));
    let f = coarse.factor as f64;
    let least = (contrast / 3.0).max(test.threshold);
    let mut out = Vec::new();
    for v in 0..h {
        for u in 0..w {
            if data[v * w + u] == 0 {
                continue;
            }
            let p = Pt::new(u as f64 * f + (f - 1.0) / 2.0, v as f64 * f + (f - 1.0) / 2.0);
            if !poly.contains(p) || index.any_within(p, INTERIOR_MARGIN) {
                continue;
            }
            let Some(g) = test.gradient(p) else { continue };
            let len = g.norm();
            if len <= 0.0 {
                continue;
            }
            let n = Pt::new(-g.x / len, -g.y / len);
            if test.across(p, n) >= least {
                out.push((p, n));
            }
        }
    }
    let stride = out.len().div_ceil(INTERIOR_MAX).max(1);
    out.into_iter().step_by(stride).collect()
}
