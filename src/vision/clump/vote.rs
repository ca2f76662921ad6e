//! The generalised Hough vote: each template votes for its own poses from the region's outline
//! pieces, into one accumulator reused by every template.

use super::super::geometry::{Pt, Similarity, bounds};
use super::super::shape::{FINE, ShapeModel};
use super::super::template::Library;

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
/// Candidate cells of a template's vote sorted at first in search of its peaks (the rest are
/// sorted only when these do not hold them all).
const CANDIDATES_SORTED: usize = 48;
/// Hypotheses refined and verified per vote of a region: the strongest by share of votes, but
/// those the image rules out at their aimed pose give their places (see [`CANDIDATES`]).
pub(super) const MAX_HYPOTHESES: usize = 10;
/// Poses of the strongest votes (by share) aimed, of which [`MAX_HYPOTHESES`] are looked at:
/// the first of them, but each one whose cheap support at its aimed pose is below what a look
/// goes on from (`verify::LOOK_FROM`, where `Look::at` would end at once) gives its place to
/// the best supported of the rest. A share of votes favours a round template: any arc of its
/// radius votes for it from each of its rotations alike, so a peak's box of three angle bins
/// holds its votes three times over. With the three built-in types and 97 of a generated
/// catalogue enrolled, the rings' peaks in a clevis's C took every place looked at, and of the
/// simulator's touching pairs 37.5 % were found (85 % now; 92.5 % when all ten are the best
/// supported of the thirty, which changed a decision of the tests' glance check and lost a
/// pick on seed 83, where this form changes none on any `eval` set). 20 found fewer.
pub(super) const CANDIDATES: usize = 30;
/// A catalogue of more templates than this votes twice: every template at a glance (one region
/// point in [`GLANCE_THIN`]), then those the glance ranks best ([`GLANCE_KEEP`]) in full. Below
/// it, everyone votes in full (a three-type cell's six templates: today's decisions exactly).
pub const GLANCE_FROM: usize = 24;
/// Region points one glance vote uses: one in this many.
const GLANCE_THIN: usize = 4;
/// Templates a glance keeps for the full vote by their share of votes over the whole region.
/// The full vote keeps [`CANDIDATES`] poses of at most [`PEAKS_PER_TEMPLATE`] each, of which
/// [`MAX_HYPOTHESES`] are looked at. Beside a larger part, whose outline every shape like it
/// votes for, the smaller part's own template ranks low overall (29th of 80 on the unseen
/// catalogue of seed 97) but high where it lies, so each of the [`GLANCE_PLACES`] places the
/// strongest glance peaks point to (a part's centroid; peaks within the smallest template's rms
/// radius share one) also keeps its [`GLANCE_PLACE`] strongest templates (not peaks: one
/// template's peaks a little turned or shifted took the places of others, and on the unseen
/// catalogue of seed 181 a flange touching another went unfound, its place filled by five
/// peaks of two look-alikes). Measured on the simulator's
/// 40-type catalogue and five unseen ones (seeds 29, 41, 53, 77, 97; touching and overlapping
/// pairs at noise 0-40, debris, unknown parts), every `eval` decision is the same as with the
/// 24 best overall kept before (about 19 templates kept instead of 24); 4 overall and 4 per
/// place lost picks and gave a false accept; 6 and 8 changed one decision that the tests'
/// glance check (`tests/shortlist.rs`) holds against the full vote. The look-alikes of each part
/// found are looked at anyway (`look_alikes`), so a sibling a glance passes over still stands
/// as a rival.
const GLANCE_KEEP: usize = 8;
/// Templates kept per place the glance's peaks point to (see [`GLANCE_KEEP`]).
const GLANCE_PLACE: usize = 8;
/// Places the glance's peaks point to that keep templates of their own, strongest first.
const GLANCE_PLACES: usize = 3;

/// The region's vote: one accumulator per worker for every template and every round, and its
/// wall time.
pub(super) struct Vote<'a> {
    lib: &'a Library,
    /// Glance first with a catalogue (more than [`GLANCE_FROM`] templates); false: every
    /// template votes in full (what tests hold the glance's decisions against).
    glance: bool,
    /// The templates the first round's glance kept: the later rounds vote with them (what is
    /// left of the region is part of what the glance saw).
    kept: Option<Vec<usize>>,
    accs: Vec<Accumulator>,
    /// Wall time spent voting so far, milliseconds.
    pub(super) ms: f64,
}

impl<'a> Vote<'a> {
    /// A vote over the bounding box of the region's `outline`.
    pub(super) fn new(lib: &'a Library, outline: &[Pt], glance: bool) -> Self {
        let (lo, hi) = bounds(outline);
        Self { lib, glance, kept: None, accs: vec![Accumulator::new(lo, hi)], ms: 0.0 }
    }

    /// Every template's best poses from `scene` (oriented outline points) at `scale`: (entry,
    /// pose, votes), the [`CANDIDATES`] with the most votes as a fraction of the template's
    /// voting points.
    /// With a `pool`, its workers vote at once, each template on one of them, dealt in turn.
    pub(super) fn hypotheses(
        &mut self,
        scene: &[(Pt, usize, i32)],
        scale: f64,
        pool: Option<&rayon::ThreadPool>,
    ) -> Vec<(usize, Similarity, u32)> {
        let voting = std::time::Instant::now();
        let lib = self.lib;
        let rot = Rotations::new(scale);
        let workers = pool.map_or(1, |p| p.current_num_threads()).min(lib.entries.len()).max(1);
        while self.accs.len() < workers {
            let more = self.accs[0].empty_like();
            self.accs.push(more);
        }
        let all: Vec<usize> = (0..lib.entries.len()).collect();
        let voters = if let Some(kept) = &self.kept {
            kept.clone()
        } else if self.glance && lib.entries.len() > GLANCE_FROM {
            // The glance: each template's best share of votes from a thinned region.
            let thin: Vec<(Pt, usize, i32)> = scene.iter().step_by(GLANCE_THIN).copied().collect();
            let mut shares: Vec<(usize, f64, Pt)> = self
                .deal(&all, pool, workers, &thin, &rot, GLANCE_THIN)
                .into_iter()
                .map(|(ei, pose, votes)| (ei, votes as f64 / lib.entries[ei].shape.vote.len() as f64, pose.to))
                .collect();
            shares.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
            let mut keep: Vec<usize> = Vec::new();
            for &(ei, _, _) in &shares {
                if !keep.contains(&ei) {
                    keep.push(ei);
                    if keep.len() == GLANCE_KEEP {
                        break;
                    }
                }
            }
            // Per place: beside a larger part, whose outline every shape like it votes for,
            // the smaller part's own template ranks low overall but high where it lies.
            // A place keeps templates, not peaks: one template's further peaks there (the same
            // shape a little turned or shifted) take no other template's place.
            let mut places: Vec<(Pt, Vec<usize>)> = Vec::new();
            let mut extra: Vec<usize> = Vec::new();
            for &(ei, _, at) in &shares {
                let admitted = match places.iter().position(|(c, _)| (at - *c).norm() <= lib.smallest_radius) {
                    Some(k) if places[k].1.contains(&ei) => true,
                    Some(k) if places[k].1.len() < GLANCE_PLACE => {
                        places[k].1.push(ei);
                        true
                    }
                    None if places.len() < GLANCE_PLACES => {
                        places.push((at, vec![ei]));
                        true
                    }
                    _ => false,
                };
                if admitted && !keep.contains(&ei) && !extra.contains(&ei) {
                    extra.push(ei);
                }
            }
            keep.extend(extra);
            keep.sort_unstable();
            self.kept = Some(keep.clone());
            keep
        } else {
            all
        };
        let hyps = strongest(lib, self.deal(&voters, pool, workers, scene, &rot, 1));
        self.ms += voting.elapsed().as_secs_f64() * 1e3;
        hyps
    }

    /// The poses of each of the templates `entries` from `scene`, dealt to `workers` in turn, one
    /// accumulator each; `thin` is the scene's thinning (the floor of a candidate cell with it).
    fn deal(
        &mut self,
        entries: &[usize],
        pool: Option<&rayon::ThreadPool>,
        workers: usize,
        scene: &[(Pt, usize, i32)],
        rot: &Rotations,
        thin: usize,
    ) -> Vec<(usize, Similarity, u32)> {
        let lib = self.lib;
        let deal = |(k, acc): (usize, &mut Accumulator)| {
            let mut hyps = Vec::new();
            for &ei in entries.iter().skip(k).step_by(workers) {
                let e = &lib.entries[ei];
                for (pose, votes) in vote(acc, &e.shape, e.template.centroid, scene, rot, thin) {
                    hyps.push((ei, pose, votes));
                }
            }
            hyps
        };
        match pool {
            Some(pool) if workers > 1 => {
                use rayon::prelude::*;
                pool.install(|| self.accs[..workers].par_iter_mut().enumerate().map(deal).collect::<Vec<_>>()).concat()
            }
            _ => deal((0, &mut self.accs[0])),
        }
    }
}

/// The [`CANDIDATES`] poses with the strongest evidence: in template order (each
/// template's peaks in their own order), as one worker finds them; then votes as a fraction
/// of the template's voting points (both sorts stable, so equal fractions keep that order).
fn strongest(lib: &Library, mut hyps: Vec<(usize, Similarity, u32)>) -> Vec<(usize, Similarity, u32)> {
    hyps.sort_by_key(|h| h.0);
    hyps.sort_by(|a, b| {
        let fa = a.2 as f64 / lib.entries[a.0].shape.vote.len() as f64;
        let fb = b.2 as f64 / lib.entries[b.0].shape.vote.len() as f64;
        fb.total_cmp(&fa)
    });
    hyps.truncate(CANDIDATES);
    hyps
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
    /// Room for the cells with a vote (to clear), kept between templates ([`vote`] fills it).
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

    /// Another empty accumulator over the same box, for another worker.
    fn empty_like(&self) -> Self {
        Self { lo: self.lo, nx: self.nx, ny: self.ny, cells: vec![[0; 2]; self.cells.len()], touched: Vec::new(), tall: Vec::new() }
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
/// rotations' scale) and their votes (3 x 3 x 3 cells around the peak), from a `scene` thinned to
/// one point in `thin`.
fn vote(
    acc: &mut Accumulator,
    model: &ShapeModel,
    centroid: Pt,
    scene: &[(Pt, usize, i32)],
    rot: &Rotations,
    thin: usize,
) -> Vec<(Similarity, u32)> {
    let (lo, nx, ny) = (acc.lo, acc.nx, acc.ny);
    let plane = nx * ny;
    let fine_step = std::f64::consts::TAU / FINE as f64;
    let (lut, scale) = (&rot.lut, rot.scale);
    let per_bin = FINE / ANGLE_BINS;
    // Candidate cells: the raw count is at least a twentieth of the model's points.
    let floor = (model.vote.len() / 20 / thin).clamp(3, u16::MAX as usize) as u16;
    // Each bin's votes, and the sum of their fine angles relative to the bin's start, so that a
    // peak's angle is the mean of its votes rather than the bin's centre.
    // Each vote's cell is written to `touched`, the count moving only when it is the cell's
    // first vote: half the votes are, and a branch on it would be mispredicted as often (the
    // glance's voting 4.4-5.8 -> 2.5-3.8 ms on a touching pair of the 40-type catalogue).
    // Room for every vote of a point is made before its loop.
    let mut touched = std::mem::take(&mut acc.touched);
    let mut n_touched = 0usize;
    for &(p, beta, turn) in scene {
        // Only points where the outlines bend alike can correspond: a fraction of the pairs.
        let from = model.vote.partition_point(|v| v.2 < turn - TURN_TOLERANCE);
        let to = model.vote.partition_point(|v| v.2 <= turn + TURN_TOLERANCE);
        if touched.len() < n_touched + (to - from) {
            touched.resize(n_touched + (to - from), 0);
        }
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
            touched[n_touched] = k as u32;
            n_touched += usize::from(v == 1);
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
    let mut cands: Vec<(u32, usize, usize, usize)> = acc
        .tall
        .iter()
        .map(|&k| {
            let k = k as usize;
            let (b, y, x) = (k / plane, (k % plane) / nx, k % nx);
            (box_sum(b, y, x), b, y, x)
        })
        .collect();
    // The largest sums first, equal sums in cell order, as a scan of the whole accumulator
    // would rank them. The peaks are nearly always among the first few dozen: those are
    // picked out and sorted, the rest only when they are not.
    let order = |a: &(u32, usize, usize, usize), c: &(u32, usize, usize, usize)| c.0.cmp(&a.0).then((a.1, a.2, a.3).cmp(&(c.1, c.2, c.3)));
    let mut sorted = CANDIDATES_SORTED.min(cands.len());
    if sorted < cands.len() {
        cands.select_nth_unstable_by(sorted, order);
    }
    cands[..sorted].sort_unstable_by(order);
    let mut peaks: Vec<(u32, usize, usize, usize)> = Vec::new();
    let mut i = 0;
    while i < cands.len() && peaks.len() < PEAKS_PER_TEMPLATE {
        if i == sorted {
            cands[sorted..].sort_unstable_by(order);
            sorted = cands.len();
        }
        let c = cands[i];
        i += 1;
        let near = peaks.iter().any(|p| {
            let db = (c.1 as isize - p.1 as isize).rem_euclid(ANGLE_BINS as isize);
            let db = db.min(ANGLE_BINS as isize - db);
            db <= 4 && c.2.abs_diff(p.2) <= 4 && c.3.abs_diff(p.3) <= 4
        });
        if !near {
            peaks.push(c);
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
    for &k in &touched[..n_touched] {
        acc.cells[k as usize] = [0; 2];
    }
    acc.touched = touched;
    acc.tall.clear();
    poses
}
