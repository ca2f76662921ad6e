//! Stage 5b: regions the silhouette alone cannot explain: touching and overlapping parts, and a
//! single part whose outline the coarse stage got partly wrong (thin arms closed over, glare).
//!
//! A region's outline is the union of pieces of its parts' outlines. Each template votes for its
//! own poses from those pieces (a generalised Hough transform: a pair of outline points, one on
//! the region and one on the template, with their normals, fixes the rotation and the centroid),
//! so a part is found from the part of its outline that shows, wherever the rest is. Each
//! hypothesis is then refined by the same point-to-line ICP as a separate part and *verified
//! against the image*: every point of the template's outline at that pose must be explained,
//! either by the region's outline or by an edge across the outline's normal inside the region
//! (where a part lies on another, or where the coarse outline bridged a gap). Which of two
//! overlapping parts lies on top follows from the same evidence: the upper part's outline runs on
//! across the lower one, the lower one's outline disappears under the upper.
//!
//! The decisions (accept, `covered`, `touching/overlapping`) are the estimator's; this module
//! only finds and measures.

use opencv::core::{self, Mat, Point, Scalar, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::detect::{Blob, Coarse};
use super::geometry::{Affine, Pt, Similarity, angle_diff_deg, area_centroid, bounds};
use super::register::{self, OutlineIndex, Registration};
use super::shape::{EdgeTest, FINE, MODEL_VOTE_STRIDE, ShapeModel, oriented_points};
use super::template::Library;

/// Least cosine between a template point's normal and the region's outline there (and the
/// offset between them) for a deviation beyond the tolerance to count as the same outline moved.
const PARALLEL_COS: f64 = 0.9;

/// The angles tried around a vote peak's: +-4 steps of 2 degrees, about a bin's width either
/// way, leaving at most a degree (under 8 px at a 450 px radius) to the registration.
const ANGLE_SEARCH: i32 = 4;
const ANGLE_SEARCH_STEP: f64 = 2.0;

/// Rotation bins of the vote accumulator (10 degrees). Each vote rotates by its own pair's angle
/// (to [`FINE`] steps), so the centroid votes of a true pose agree whatever the bin width: the
/// bins only keep parts at different angles apart, and a small accumulator stays in cache.
const ANGLE_BINS: usize = 36;
/// Centroid cell of the vote accumulator, frame pixels.
const CELL: f64 = 12.0;
/// Largest difference of turn (in [`FINE`] steps: 15 degrees) between corresponding points.
const TURN_TOLERANCE: i32 = 30;
/// Poses per template kept from the vote.
const PEAKS_PER_TEMPLATE: usize = 3;
/// Hypotheses refined and verified per region, best votes first.
const MAX_HYPOTHESES: usize = 10;

/// What the region offers as evidence.
pub struct Region<'a> {
    /// The frame's coarse stage (decimated, blurred frame for the edge tests).
    pub coarse: &'a Coarse,
    /// The region.
    pub blob: &'a Blob,
    /// The region's refined outline, frame pixels.
    pub outline: &'a [Pt],
    /// Frame noise, gray levels.
    pub noise: f64,
    /// Part-to-belt contrast along the region's outline, gray levels.
    pub contrast: f64,
}

/// A part found in a region.
#[derive(Debug, Clone)]
pub struct Found {
    /// Index of the template in the library.
    pub entry: usize,
    /// The registration at its pose.
    pub reg: Registration,
    /// The outline tolerance used, template pixels.
    pub tolerance: f64,
    /// Length fraction of the template's outline explained by the image at the pose.
    pub support: f64,
    /// Index (into [`Explained::parts`]) of a part found lying on this one.
    pub under: Option<usize>,
    /// Overlaps another part found here, and the image cannot tell which lies on top.
    pub order_unclear: bool,
    /// Another template explaining the same material nearly as well: (entry, its registration,
    /// support).
    pub rival: Option<(usize, Registration, f64)>,
    /// Verification points.
    points: Vec<Probe>,
}

/// Everything found in a region.
#[derive(Debug, Clone, Default)]
pub struct Explained {
    /// The parts found, best supported first.
    pub parts: Vec<Found>,
    /// Material of the region that no found part explains: (area in frame pixels, centroid).
    pub leftover: Vec<(f64, Pt)>,
    /// Wall time of the vote, milliseconds (the rest of the region's time is verification).
    pub vote_ms: f64,
}

/// Least support for a hypothesis to stand for a physical part at all.
pub const MIN_SUPPORT: f64 = 0.7;

/// Finds and verifies the parts in a region. `tolerance(entry)` is the outline tolerance of that
/// template at this frame's noise, as the single-part path uses it.
pub fn explain(lib: &Library, region: &Region<'_>, tolerance: impl Fn(usize) -> f64, min_leftover: f64) -> Explained {
    let scene = oriented_points(region.outline);
    if scene.len() < 8 {
        return Explained::default();
    }
    let (lo, hi) = bounds(region.outline);
    let mut acc = Accumulator::new(lo, hi);
    let mut vote_ms = 0.0;
    let mut hypotheses = |scene: &[(Pt, usize, i32)], scale: f64, vote_ms: &mut f64| {
        let voting = std::time::Instant::now();
        let mut hyps: Vec<(usize, Similarity, u32)> = Vec::new();
        let rot = Rotations::new(scale);
        for (ei, e) in lib.entries.iter().enumerate() {
            for (pose, votes) in vote(&mut acc, &e.shape, e.template.centroid, scene, &rot) {
                hyps.push((ei, pose, votes));
            }
        }
        // Stronger evidence first: votes as a fraction of the template's voting points.
        hyps.sort_by(|a, b| {
            let fa = a.2 as f64 / lib.entries[a.0].shape.vote.len() as f64;
            let fb = b.2 as f64 / lib.entries[b.0].shape.vote.len() as f64;
            fb.total_cmp(&fa)
        });
        hyps.truncate(MAX_HYPOTHESES);
        *vote_ms += voting.elapsed().as_secs_f64() * 1e3;
        hyps
    };
    let hyps = hypotheses(&scene, 1.0, &mut vote_ms);
    let ext = OutlineIndex::of_frame(region.outline);
    let edge = EdgeTest::new(region.coarse, region.noise, region.contrast);
    let mut found: Vec<Found> = Vec::new();
    let look = |found: &[Found], ei: usize, init: Similarity| -> Option<Found> {
        let e = &lib.entries[ei];
        let tol = tolerance(ei);
        // A mostly round part votes for its centroid from every rotation alike, and only its
        // lobes tell the angle: the peak's angle may be several degrees off, beyond what the
        // registration pulls in. A coarse look at the angles around it first.
        let init = (-ANGLE_SEARCH..=ANGLE_SEARCH)
            .map(|k| {
                let mut pose = init;
                pose.angle_rad += (k as f64 * ANGLE_SEARCH_STEP).to_radians();
                (pose, support(&e.shape, &pose, &ext, &edge, 2.0 * tol, 8))
            })
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(init, |(pose, _)| pose);
        // Cheap looks first: most peaks are another part's outline voting by chance, or the
        // same part again, and end here before any registration.
        let duplicate = found.iter().any(|f| {
            f.entry == ei && (f.reg.pose.to - init.to).norm() < 20.0 && angle_diff_deg(f.reg.pose.angle_deg(), init.angle_deg()).abs() < 4.0
        });
        if duplicate || support(&e.shape, &init, &ext, &edge, 2.0 * tol, 4) < MIN_SUPPORT - 0.2 {
            return None;
        }
        // Registration on the stretch of the region's outline the part can reach: the rest is
        // its neighbours', and costs correspondence searches that find nothing.
        let reach = e.shape.radius * 1.2 + 2.0 * register::MAX_REACH;
        let local: Vec<Pt> = region.outline.iter().copied().filter(|p| (*p - init.to).norm() <= reach).collect();
        if local.len() < 16 {
            return None;
        }
        let rough = register::register(&local, &e.index, init, tol, 4);
        if support(&e.shape, &rough.pose, &ext, &edge, tol, 3) < MIN_SUPPORT - 0.05 {
            return None;
        }
        let reg = register::register(&local, &e.index, rough.pose, tol, 2);
        let (support, points) = verify(&e.shape, &reg.pose, &ext, &edge, tol);
        (support >= MIN_SUPPORT).then_some(Found {
            entry: ei,
            reg,
            tolerance: tol,
            support,
            under: None,
            order_unclear: false,
            rival: None,
            points,
        })
    };
    // Each found part's filled outline at its pose, made once: the second vote's look at what is
    // left and the overlap tests below read the same masks.
    let f = region.coarse.factor;
    let mask = |x: &Found| mask_of(lib, x, region.blob, f).unwrap_or_default();
    let mut masks: Vec<Mat> = Vec::new();
    for (ei, init, _) in hyps {
        if let Some(part) = look(&found, ei, init) {
            masks.push(mask(&part));
            found.push(part);
        }
    }
    // The stretch of the region's outline that no part found so far explains: outside the found
    // parts' material grown by twice the widest tolerance (a region outline point farther out is
    // no part's; a cheaper look than a distance to every placed outline).
    let left = |found: &[Found], masks: &[Mat]| -> Vec<(Pt, usize, i32)> {
        if found.is_empty() {
            return scene.clone();
        }
        if masks.iter().any(|m| m.empty()) {
            return Vec::new();
        }
        let reach = found.iter().map(|x| 2.0 * x.tolerance * x.reg.pose.scale).fold(0.0, f64::max);
        let size = 2 * (reach / f as f64).ceil() as i32 + 1;
        let near = masks
            .iter()
            .try_fold(Mat::default(), |acc, m| -> opencv::Result<Mat> {
                if acc.empty() {
                    return m.try_clone();
                }
                let mut both = Mat::default();
                core::bitwise_or(&acc, m, &mut both, &core::no_array())?;
                Ok(both)
            })
            .and_then(|m| dilate(&m, size));
        match near {
            Ok(near) => scene.iter().copied().filter(|&(p, _, _)| !at_mask(&near, region.blob, p, f)).collect(),
            Err(_) => Vec::new(),
        }
    };
    // Long enough to be most of a part's outline.
    let shortest = lib.entries.iter().map(|e| e.shape.vote.len() * MODEL_VOTE_STRIDE).min().unwrap_or(usize::MAX);
    let enough = |rest: &[(Pt, usize, i32)]| 2 * rest.len() >= shortest;
    // A part whose outline shows less than its neighbour's may not make the first vote's
    // strongest peaks at all: the neighbour's outline votes for that neighbour again from every
    // face and type alike. What is left votes once more on its own. Then, should some still be
    // left, at a scale 5 % either side: the vote at the template's scale smears the centroid's
    // votes of a part more than about 4 % larger or smaller (a 370 px radius moves 15 px, over a
    // cell) and loses its peak, where the registration would pull the scale in.
    for scale in [1.0, 0.95, 1.05] {
        if scale == 1.0 && found.is_empty() {
            continue; // the same vote again
        }
        let rest = left(&found, &masks);
        if !enough(&rest) {
            break;
        }
        for (ei, init, _) in hypotheses(&rest, scale, &mut vote_ms) {
            if let Some(part) = look(&found, ei, init) {
                masks.push(mask(&part));
                found.push(part);
            }
        }
    }
    // One physical part, several explanations (the same template from two peaks, another face or
    // type): the best stays, the runner-up of a different type or face is its rival.
    let mut by_support: Vec<(Found, Mat)> = found.into_iter().zip(masks).collect();
    by_support.sort_by(|a, b| b.0.support.total_cmp(&a.0.support));
    let (mut found, masks): (Vec<Found>, Vec<Mat>) = by_support.into_iter().unzip();
    let areas: Vec<f64> = masks.iter().map(|m| core::count_non_zero(m).unwrap_or(0) as f64).collect();
    let mut keep: Vec<usize> = Vec::new();
    for i in 0..found.len() {
        let same = keep.iter().copied().find(|&k| {
            let inter = overlap(&masks[i], &masks[k]);
            inter > 0.5 * areas[i].min(areas[k]).max(1.0)
        });
        match same {
            None => keep.push(i),
            Some(k) => {
                let (a, b) = (&lib.entries[found[k].entry].template, &lib.entries[found[i].entry].template);
                if found[k].rival.is_none() && (a.type_name != b.type_name || a.face != b.face) {
                    found[k].rival = Some((found[i].entry, found[i].reg, found[i].support));
                }
            }
        }
    }
    // Which of two overlapping parts is on top: the one whose outline shows inside the other
    // (away from the other's own outline: inside its mask eroded by a decimated pixel; they
    // overlap at all where one's outline runs two decimated pixels inside the other, more than
    // the poses of touching parts are off by), where the lower one's outline runs under the
    // upper's surface and shows nothing.
    let deep: Vec<Mat> = masks.iter().map(|m| erode(m, 5).unwrap_or_default()).collect();
    let eroded: Vec<Mat> = masks.iter().map(|m| erode(m, 3).unwrap_or_default()).collect();
    let inside =
        |pts: &[Probe], mask: &Mat| -> Vec<usize> { (0..pts.len()).filter(|&j| at_mask(mask, region.blob, pts[j].at, f)).collect() };
    // Three measures of how an outline shows inside the other part: the fraction of its points
    // with an edge at all (the most telling), the mean step, and the magnitude of the mean
    // signed step (a real outline runs with one polarity, the features of the upper part that a
    // hidden outline crosses come with either). Where they do not point the same way, which
    // part lies on top stays undecided: a reject either way.
    let strength = |pts: &[Probe], idx: &[usize]| -> Steps {
        if idx.is_empty() {
            return Steps::default();
        }
        let n = idx.len() as f64;
        Steps {
            mean: idx.iter().map(|&j| pts[j].across.abs()).sum::<f64>() / n,
            signed: (idx.iter().map(|&j| pts[j].across).sum::<f64>() / n).abs(),
            shown: idx.iter().filter(|&&j| pts[j].across.abs() >= 0.4 * edge.threshold).count() as f64 / n,
        }
    };
    // The features inside a part where the other lies.
    let features = |x: &Found, zone: &Mat| -> Features {
        let t = &lib.entries[x.entry].template;
        let pose = x.reg.pose;
        let (to_frame, turn) = (pose.forward(), Affine::rotation(pose.angle_rad));
        let (mut n, mut seen) = (0usize, 0usize);
        for &(q, nq) in &t.interior {
            let at = to_frame.apply(q);
            if at_mask(zone, region.blob, at, f) {
                n += 1;
                if edge.across(at, turn.apply(nq)) >= edge.threshold {
                    seen += 1;
                }
            }
        }
        Features { count: n, shown: if n > 0 { seen as f64 / n as f64 } else { 0.0 } }
    };
    let mut over: Vec<Vec<usize>> = vec![Vec::new(); found.len()];
    for (a, &i) in keep.iter().enumerate() {
        for &k in &keep[a + 1..] {
            if inside(&found[i].points, &deep[k]).len() < 4 && inside(&found[k].points, &deep[i]).len() < 4 {
                continue; // touching at most
            }
            let (ii, kk) = (inside(&found[i].points, &eroded[k]), inside(&found[k].points, &eroded[i]));
            // The steps across are measured here, where they tell something, not for every point.
            for (x, idx) in [(i, &ii), (k, &kk)] {
                for &j in idx {
                    found[x].points[j].across(&edge);
                }
            }
            let (si, sk) = (strength(&found[i].points, &ii), strength(&found[k].points, &kk));
            let m = edge.margin;
            let enough = ii.len().min(kk.len()) >= 20;
            let (fi, fk) = (features(&found[i], &deep[k]), features(&found[k], &deep[i]));
            let on_top = |a: Steps, b: Steps, fa: Features, fb: Features| lies_on_top(a, b, fa, fb, enough, m);
            if on_top(si, sk, fi, fk) {
                found[k].under.get_or_insert(i);
                over[i].extend(ii);
            } else if on_top(sk, si, fk, fi) {
                found[i].under.get_or_insert(k);
                over[k].extend(kk);
            } else {
                found[i].order_unclear = true;
                found[k].order_unclear = true;
            }
        }
    }
    // An upper part's outline across a lower part shows as well as that part's surface allows:
    // decided on top, those points count as seen.
    for &i in &keep {
        let pts = &mut found[i].points;
        for &j in &over[i] {
            pts[j].seen = true;
        }
        found[i].support = pts.iter().filter(|p| p.seen).count() as f64 / pts.len().max(1) as f64;
    }
    // Material no part explains.
    let leftover = leftover(region, &keep.iter().map(|&i| &masks[i]).collect::<Vec<_>>(), min_leftover).unwrap_or_default();
    let index_of: Vec<Option<usize>> = (0..found.len()).map(|i| keep.iter().position(|&k| k == i)).collect();
    let parts = keep
        .iter()
        .map(|&i| {
            let mut f = found[i].clone();
            f.under = f.under.and_then(|k| index_of[k]);
            f
        })
        .collect();
    Explained { parts, leftover, vote_ms }
}

/// The vote accumulator over a region: rotation bins x centroid cells, reused by every
/// template. Only the cells a template's votes touched are read and cleared again: a pair's
/// region has some 0.2 M cells, of which its votes touch a fraction.
struct Accumulator {
    lo: Pt,
    nx: usize,
    ny: usize,
    /// Per cell: the votes, and the sum of their fine angles relative to their bin's start, in
    /// one 32-bit word (a cell would need thousands of votes to saturate either).
    cells: Vec<[u16; 2]>,
    /// Cells with a vote (to clear).
    touched: Vec<u32>,
    /// Cells that reached the candidate floor.
    tall: Vec<u32>,
}

impl Accumulator {
    /// An empty accumulator for centroids in the box `lo`..`hi` (a part's centroid lies within
    /// its bounding box, which lies within the region's).
    fn new(lo: Pt, hi: Pt) -> Self {
        let nx = (((hi.x - lo.x) / CELL).ceil() as usize + 1).max(1);
        let ny = (((hi.y - lo.y) / CELL).ceil() as usize + 1).max(1);
        let n = ANGLE_BINS * nx * ny;
        Self { lo, nx, ny, cells: vec![[0; 2]; n], touched: Vec::new(), tall: Vec::new() }
    }
}

/// The vote's rotation table, sine and cosine per [`FINE`] step, scaled to accumulator cells and
/// by the part's `scale`, so that the inner loop needs no division. Made once per vote of a
/// region, not per template: with a hundred types its 720 `sin_cos` per template cost 3 % of a
/// touching pair's time.
struct Rotations {
    scale: f64,
    lut: Vec<(f64, f64)>,
}

impl Rotations {
    fn new(scale: f64) -> Self {
        let fine_step = std::f64::consts::TAU / FINE as f64;
        let lut = (0..FINE)
            .map(|b| {
                let (s, c) = (b as f64 * fine_step).sin_cos();
                (s * scale / CELL, c * scale / CELL)
            })
            .collect();
        Self { scale, lut }
    }
}

/// Generalised Hough vote of one template over the region: its best few poses (at the
/// rotations' scale) and their votes (3 x 3 x 3 cells around the peak).
fn vote(acc: &mut Accumulator, model: &ShapeModel, centroid: Pt, scene: &[(Pt, usize, i32)], rot: &Rotations) -> Vec<(Similarity, u32)> {
    let (lo, nx, ny) = (acc.lo, acc.nx, acc.ny);
    let plane = nx * ny;
    let fine_step = std::f64::consts::TAU / FINE as f64;
    let (lut, scale) = (&rot.lut, rot.scale);
    let per_bin = FINE / ANGLE_BINS;
    // Candidate cells: the raw count is at least a twentieth of the model's points.
    let floor = (model.vote.len() / 20).clamp(3, u16::MAX as usize) as u16;
    // Each bin's votes, and the sum of their fine angles relative to the bin's start, so that a
    // peak's angle is the mean of its votes rather than the bin's centre.
    for &(p, beta, turn) in scene {
        // Only points where the outlines bend alike can correspond: a fraction of the pairs.
        let from = model.vote.partition_point(|v| v.2 < turn - TURN_TOLERANCE);
        let to = model.vote.partition_point(|v| v.2 <= turn + TURN_TOLERANCE);
        let (px, py) = ((p.x - lo.x) / CELL, (p.y - lo.y) / CELL);
        let (nxf, nyf) = (nx as f64, ny as f64);
        for &(d, alpha, _) in &model.vote[from..to] {
            let fine = if beta >= alpha { beta - alpha } else { beta + FINE - alpha };
            let b = fine / per_bin;
            let (s, c) = lut[fine];
            // The centroid p + rotate_display(d, theta) with the pair's angle, in cells.
            let ix = px + c * d.x + s * d.y;
            let iy = py - s * d.x + c * d.y;
            // Inside the accumulator (compared as floats: a float-to-integer cast costs a dozen
            // instructions here), truncation is the floor (and needs no libm call).
            if !(ix >= 0.0 && iy >= 0.0 && ix < nxf && iy < nyf) {
                continue;
            }
            let k = b * plane + iy as usize * nx + ix as usize;
            let cell = &mut acc.cells[k];
            cell[0] = cell[0].saturating_add(1);
            cell[1] = cell[1].saturating_add((fine - b * per_bin) as u16);
            let v = cell[0];
            if v == 1 {
                acc.touched.push(k as u32);
            }
            if v == floor {
                acc.tall.push(k as u32);
            }
        }
    }
    let cells = &acc.cells;
    let box_sum = |b: usize, y: usize, x: usize| -> u32 {
        let mut s = 0u32;
        for db in [ANGLE_BINS - 1, 0, 1] {
            let bb = (b + db) % ANGLE_BINS;
            for yy in y.saturating_sub(1)..=(y + 1).min(ny - 1) {
                for xx in x.saturating_sub(1)..=(x + 1).min(nx - 1) {
                    s += cells[bb * plane + yy * nx + xx][0] as u32;
                }
            }
        }
        s
    };
    // In cell order, so that equal sums rank as a scan of the whole accumulator would.
    acc.tall.sort_unstable();
    let mut cands: Vec<(u32, usize, usize, usize)> = acc
        .tall
        .iter()
        .map(|&k| {
            let k = k as usize;
            let (b, y, x) = (k / plane, (k % plane) / nx, k % nx);
            (box_sum(b, y, x), b, y, x)
        })
        .collect();
    cands.sort_by_key(|c| std::cmp::Reverse(c.0));
    let mut peaks: Vec<(u32, usize, usize, usize)> = Vec::new();
    for c in cands {
        let near = peaks.iter().any(|p| {
            let db = (c.1 as isize - p.1 as isize).rem_euclid(ANGLE_BINS as isize);
            let db = db.min(ANGLE_BINS as isize - db);
            db <= 4 && c.2.abs_diff(p.2) <= 4 && c.3.abs_diff(p.3) <= 4
        });
        if !near {
            peaks.push(c);
            if peaks.len() == PEAKS_PER_TEMPLATE {
                break;
            }
        }
    }
    let poses = peaks
        .into_iter()
        .map(|(v, b, y, x)| {
            // The mean of the votes around the peak, for a start within a few pixels and about a
            // degree: centroid from the cells, angle from the votes' own angles.
            let (mut sx, mut sy, mut sa, mut sw) = (0.0, 0.0, 0.0, 0.0);
            for db in [-1isize, 0, 1] {
                let bb = (b as isize + db).rem_euclid(ANGLE_BINS as isize) as usize;
                for yy in y.saturating_sub(1)..=(y + 1).min(ny - 1) {
                    for xx in x.saturating_sub(1)..=(x + 1).min(nx - 1) {
                        let k = bb * plane + yy * nx + xx;
                        let w = cells[k][0] as f64;
                        sx += w * (xx as f64 + 0.5);
                        sy += w * (yy as f64 + 0.5);
                        sa += w * ((b as isize + db) * per_bin as isize) as f64 + cells[k][1] as f64;
                        sw += w;
                    }
                }
            }
            let (cx, cy, a) = if sw > 0.0 { (sx / sw, sy / sw, sa / sw) } else { (x as f64 + 0.5, y as f64 + 0.5, (b * per_bin) as f64) };
            let to = Pt::new(lo.x + cx * CELL, lo.y + cy * CELL);
            (Similarity { from: centroid, to, angle_rad: a * fine_step, scale }, v)
        })
        .collect();
    for &k in &acc.touched {
        acc.cells[k as usize] = [0; 2];
    }
    acc.touched.clear();
    acc.tall.clear();
    poses
}

/// How one part's outline shows where it runs inside another part.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Steps {
    /// Mean magnitude of the gray-level step across it.
    mean: f64,
    /// Magnitude of its mean signed step.
    signed: f64,
    /// Fraction of its points with an edge at all (a step of 0.4 x the edge threshold).
    shown: f64,
}

/// One part's own interior features (holes' rims, pockets, bosses) where another part lies.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct Features {
    /// How many interior edge points lie there.
    count: usize,
    /// The fraction of them showing with the template's polarity.
    shown: f64,
}

/// Whether the part whose outline and features show as `a` and `fa` lies on the one showing
/// `b` and `fb`; `enough`: both outlines have enough points inside the other to tell a faint
/// edge from none; `m`: the edge test's margin (gray levels). Which of two overlapping parts
/// lies on top is seen where they overlap: the upper part's outline runs on across the lower
/// one, the lower one's disappears under the upper's surface.
///
/// The most telling measure is how much of each outline shows as an edge at all; the means of
/// the steps may only not both speak against it. Two parts of one material and shade show the
/// upper one's outline faintly; it still decides where the lower one's shows nothing at all and
/// its mean step is larger by the margin. Where one part's features show almost all over the
/// other and the other's show hardly at all there, an outline that leans the same way, short of
/// deciding alone, is enough: more of it shows as an edge, and its mean step is not smaller by
/// more than the margin (means within the margin are a tie, not a vote against).
///
/// What never decides alone: features (a lower part's show through an upper part's hole),
/// hidden features (an upper part's through-hole shows the part beneath instead of the belt,
/// its rim's step reversed), the polarity of the steps (an upper part's outline over a lower
/// part of several shades changes polarity along its way).
fn lies_on_top(a: Steps, b: Steps, fa: Features, fb: Features, enough: bool, m: f64) -> bool {
    let shows = |x: Features| x.count >= FEATURES_MIN && x.shown >= FEATURES_SHOWN;
    let hidden = |x: Features| x.count < FEATURES_MIN || x.shown <= FEATURES_HIDDEN;
    let not_against = !(b.mean > a.mean + m && b.signed > a.signed + m);
    let clear = a.shown >= 0.4 && a.shown >= b.shown + 0.2 && not_against;
    let faint = enough && a.shown >= 0.15 && b.shown <= 0.05 && a.mean >= b.mean + m;
    let leans = a.shown >= b.shown + 0.1 && a.mean >= b.mean - m && not_against;
    let featured = shows(fa) && hidden(fb) && leans;
    clear || faint || featured
}

/// Interior edge points of a part over another that make its features count at all.
const FEATURES_MIN: usize = 8;
/// Fraction of them showing for the features to show (see [`explain`]).
const FEATURES_SHOWN: f64 = 0.8;
/// Fraction of them at most showing for the features to be hidden.
const FEATURES_HIDDEN: f64 = 0.2;
/// One verification point of a template's outline at a hypothesised pose.
#[derive(Debug, Clone, Copy)]
struct Probe {
    /// Frame position.
    at: Pt,
    /// The outline's outward unit normal there.
    normal: Pt,
    /// Explained: on the region's outline, or a clear edge across the outline there.
    seen: bool,
    /// Gray-level step across the outline there, inside minus outside (see
    /// [`EdgeTest::across`]); measured where the region's outline does not explain the point,
    /// otherwise NaN until [`Probe::across`] measures it (only where another part lies).
    across: f64,
}

impl Probe {
    /// The step across the outline here, measured once.
    fn across(&mut self, edge: &EdgeTest<'_>) -> f64 {
        if self.across.is_nan() {
            self.across = edge.across(self.at, self.normal);
        }
        self.across
    }
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

/// The found part's filled outline at its pose, in the blob's mask coordinates.
fn mask_of(lib: &Library, f: &Found, blob: &Blob, factor: usize) -> opencv::Result<Mat> {
    let t = &lib.entries[f.entry].template;
    let mut mask = Mat::new_rows_cols_with_default(blob.mask.rows(), blob.mask.cols(), core::CV_8UC1, Scalar::all(0.0))?;
    let to_frame = f.reg.pose.forward();
    let poly: Vector<Point> = t
        .outline
        .iter()
        .step_by(2)
        .map(|&q| {
            let p = to_frame.apply(q);
            let (u, v) = to_mask(p, factor, blob);
            Point::new((u * 16.0).round() as i32, (v * 16.0).round() as i32)
        })
        .collect();
    let mut polys: Vector<Vector<Point>> = Vector::new();
    polys.push(poly);
    imgproc::fill_poly(&mut mask, &polys, Scalar::all(255.0), imgproc::LINE_8, 4, Point::new(0, 0))?;
    Ok(mask)
}

fn erode(m: &Mat, size: i32) -> opencv::Result<Mat> {
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, core::Size::new(size, size), Point::new(-1, -1))?;
    let mut out = Mat::default();
    imgproc::erode(m, &mut out, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
    Ok(out)
}

fn dilate(m: &Mat, size: i32) -> opencv::Result<Mat> {
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, core::Size::new(size, size), Point::new(-1, -1))?;
    let mut out = Mat::default();
    imgproc::dilate(m, &mut out, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
    Ok(out)
}

fn to_mask(p: Pt, factor: usize, blob: &Blob) -> (f64, f64) {
    let f = factor as f64;
    ((p.x - (f - 1.0) / 2.0) / f - blob.mask_origin.x as f64, (p.y - (f - 1.0) / 2.0) / f - blob.mask_origin.y as f64)
}

fn at_mask(mask: &Mat, blob: &Blob, p: Pt, factor: usize) -> bool {
    let (u, v) = to_mask(p, factor, blob);
    let (x, y) = (u.round() as i32, v.round() as i32);
    x >= 0 && y >= 0 && x < mask.cols() && y < mask.rows() && mask.at_2d::<u8>(y, x).is_ok_and(|v| *v > 0)
}

fn overlap(a: &Mat, b: &Mat) -> f64 {
    let mut both = Mat::default();
    if core::bitwise_and(a, b, &mut both, &core::no_array()).is_err() {
        return 0.0;
    }
    core::count_non_zero(&both).unwrap_or(0) as f64
}

/// Connected pieces of the region's material that none of `masks` explains, at least
/// `min_area` frame pixels each: (area, centroid).
fn leftover(region: &Region<'_>, masks: &[&Mat], min_area: f64) -> opencv::Result<Vec<(f64, Pt)>> {
    let blob = region.blob;
    let mut explained = Mat::new_rows_cols_with_default(blob.mask.rows(), blob.mask.cols(), core::CV_8UC1, Scalar::all(0.0))?;
    for m in masks {
        let mut t = Mat::default();
        core::bitwise_or(&explained, *m, &mut t, &core::no_array())?;
        explained = t;
    }
    // The coarse region is dilated by the closing and outlines are good to a decimated pixel or
    // two: grow the explained material by that much, and open what is left to drop slivers.
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, core::Size::new(7, 7), Point::new(-1, -1))?;
    let mut grown = Mat::default();
    imgproc::dilate(&explained, &mut grown, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
    let mut rest = Mat::default();
    let mut inv = Mat::default();
    core::bitwise_not(&grown, &mut inv, &core::no_array())?;
    core::bitwise_and(&blob.mask, &inv, &mut rest, &core::no_array())?;
    let mut opened = Mat::default();
    imgproc::morphology_ex(
        &rest,
        &mut opened,
        imgproc::MORPH_OPEN,
        &kernel,
        Point::new(-1, -1),
        1,
        core::BORDER_CONSTANT,
        Scalar::all(0.0),
    )?;
    let mut contours: Vector<Vector<Point>> = Vector::new();
    imgproc::find_contours(&opened, &mut contours, imgproc::RETR_EXTERNAL, imgproc::CHAIN_APPROX_SIMPLE, Point::new(0, 0))?;
    let f = region.coarse.factor as f64;
    let mut out = Vec::new();
    for c in contours.iter() {
        let pts: Vec<Pt> = c
            .iter()
            .map(|q| {
                Pt::new((q.x + blob.mask_origin.x) as f64 * f + (f - 1.0) / 2.0, (q.y + blob.mask_origin.y) as f64 * f + (f - 1.0) / 2.0)
            })
            .collect();
        if pts.len() < 3 {
            continue;
        }
        let (a, c) = area_centroid(&pts);
        if a.abs() >= min_area {
            out.push((a.abs(), c));
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const M: f64 = 3.0;

    fn steps(mean: f64, signed: f64, shown: f64) -> Steps {
        Steps { mean, signed, shown }
    }

    fn features(count: usize, shown: f64) -> Features {
        Features { count, shown }
    }

    /// The upper part's outline shows as an edge over the lower part; the lower one's, under
    /// the upper's surface, hardly at all: decided both ways round, whichever is asked first.
    #[test]
    fn the_outline_that_shows_lies_on_top() {
        let (upper, lower) = (steps(30.0, 28.0, 0.8), steps(6.0, 1.0, 0.1));
        let none = Features::default();
        assert!(lies_on_top(upper, lower, none, none, true, M));
        assert!(!lies_on_top(lower, upper, none, none, true, M));
    }

    /// Features showing all over the other part, the other's hidden, and an outline that leans
    /// the same way decide even where the outlines' mean steps tie within the margin (a
    /// simulated clevis under a bracket: 9.48 against 9.56 gray levels, margin 2.96).
    #[test]
    fn features_and_a_leaning_outline_decide_on_a_tie_of_means() {
        let (upper, lower) = (steps(9.48, 7.34, 0.435), steps(9.56, 8.19, 0.278));
        assert!(lies_on_top(upper, lower, features(10, 1.0), features(0, 0.0), true, 2.96));
        assert!(!lies_on_top(lower, upper, features(0, 0.0), features(10, 1.0), true, 2.96));
        // A mean smaller by more than the margin speaks against it.
        assert!(!lies_on_top(steps(5.0, 4.0, 0.435), lower, features(10, 1.0), features(0, 0.0), true, 2.96));
    }

    /// Features alone never decide: an upper part's through-holes showing the part beneath
    /// (their rims reversed, so that its features look hidden) do not put the lower part on top
    /// (a simulated flange under a bracket: the bracket's outline decides), nor do a lower
    /// part's features seen through an upper part's hole with outlines that lean neither way.
    #[test]
    fn features_alone_never_decide() {
        let (flange, bracket) = (steps(14.5, 14.5, 0.33), steps(16.7, 3.4, 0.66));
        assert!(!lies_on_top(flange, bracket, features(0, 0.0), features(60, 0.0), true, 3.45));
        assert!(lies_on_top(bracket, flange, features(60, 0.0), features(0, 0.0), true, 3.45));
        let tie = steps(10.0, 8.0, 0.3);
        assert!(!lies_on_top(tie, tie, features(20, 1.0), features(20, 0.0), true, M));
    }

    /// Two parts of one shade: the upper outline's faint edge decides only where the lower's
    /// shows none and there are enough points to tell.
    #[test]
    fn a_faint_outline_decides_only_against_none_with_enough_points() {
        let (faint, none) = (steps(12.0, 11.0, 0.2), steps(4.0, 1.0, 0.02));
        let f = Features::default();
        assert!(lies_on_top(faint, none, f, f, true, M));
        assert!(!lies_on_top(faint, none, f, f, false, M));
        assert!(!lies_on_top(faint, steps(4.0, 1.0, 0.1), f, f, true, M));
    }
}
