//! Stage 1b: sub-pixel outline on the full-resolution frame.
//!
//! The coarse outline is good to a few pixels; the pose and the centroid need a tenth of one. For
//! every point of the outline the frame is sampled along the outward normal, the profile is
//! smoothed (along the normal by a Gaussian, across by averaging neighbouring profiles), and the
//! edge is where the profile, scanned inwards from the belt, first rises clearly above the belt's
//! level: first because a part's own features (rims, grooves, ribs) make strong edges just inside
//! its silhouette, and a level close to the belt's rather than a gradient peak because rounded and
//! dark-rimmed parts shade gradually towards their silhouette, where a peak wanders with texture
//! and lighting.

use super::frame::GrayView;
use super::geometry::{Pt, area_centroid, outward_normals, resample_closed, smooth_closed};

/// Parameters of the refinement.
#[derive(Debug, Clone)]
pub struct RefineParams {
    /// Spacing of the refined outline's points, frame pixels.
    pub spacing: f64,
    /// Half-length of the search along the normal, frame pixels.
    pub search: f64,
    /// Gaussian smoothing of each profile, frame pixels.
    pub profile_sigma: f64,
    /// Neighbouring profiles averaged on each side.
    pub across: usize,
    /// Least rise above the belt's level, as a fraction of the part's contrast, at which the
    /// edge is placed (the frame's noise may push it higher).
    pub level: f64,
}

/// Sample spacing along the normal, frame pixels (the profile is smoothed over more than this).
const STEP: f64 = 1.0;

/// A refined outline.
#[derive(Debug, Clone)]
pub struct Refined {
    /// The outline on the full frame, sub-pixel, frame pixels.
    pub outline: Vec<Pt>,
    /// Typical gray-level step across the outline (median over its points).
    pub contrast: f64,
    /// The part is brighter than the belt.
    pub brighter: bool,
}

/// Refines a closed coarse outline to sub-pixel edge positions.
pub fn refine(frame: GrayView<'_>, coarse: &[Pt], noise: f64, p: &RefineParams) -> Refined {
    let pts = resample_closed(coarse, p.spacing);
    let n = pts.len();
    if n < 8 {
        return Refined { outline: pts, contrast: 0.0, brighter: true };
    }
    // Normals from a smoothed copy: the decimated outline is a staircase.
    let smooth = smooth_closed(&pts, 3);
    let normals = outward_normals(&smooth, 3);
    let half = (p.search / STEP).round() as isize;
    let k = (2 * half + 1) as usize;
    let ts: Vec<f64> = (-half..=half).map(|i| i as f64 * STEP).collect();

    // Raw profiles: the frame sampled bilinearly along each normal (edges replicated).
    let mut raw = Vec::with_capacity(n * k);
    for (b, nn) in smooth.iter().zip(&normals) {
        profile(frame, *b, *nn, &ts, &mut raw);
    }
    // Gaussian kernel along the profile.
    let sig = (p.profile_sigma / STEP).max(0.5);
    let kr = (3.0 * sig).ceil() as isize;
    let kernel: Vec<f64> = (-kr..=kr).map(|i| (-(i as f64).powi(2) / (2.0 * sig * sig)).exp()).collect();
    let ksum: f64 = kernel.iter().sum();

    // Smoothed profiles: averaged across neighbours (a running sum around the closed outline),
    // then Gaussian along the normal.
    let m = p.across.min(n / 4);
    let norm = 1.0 / (ksum * (2 * m + 1) as f64);
    let mut acc = vec![0.0f64; k];
    for d in 0..=2 * m {
        let ii = (n + d - m) % n;
        for j in 0..k {
            acc[j] += raw[ii * k + j];
        }
    }
    let mut sm = vec![0.0f64; n * k];
    // The averaged profile with its end values repeated kernel-radius times on either side, so
    // that the convolution needs no index clamping.
    let r = kr as usize;
    let mut padded = vec![0.0f64; k + 2 * r];
    for i in 0..n {
        padded[..r].fill(acc[0]);
        padded[r..r + k].copy_from_slice(&acc);
        padded[r + k..].fill(acc[k - 1]);
        // Tap by tap over the whole profile: each output still sums its taps in order, but the
        // outputs are independent, so the additions run side by side instead of one after another.
        let row = &mut sm[i * k..(i + 1) * k];
        row.fill(0.0);
        for (q, w) in kernel.iter().enumerate() {
            for (out, v) in row.iter_mut().zip(&padded[q..q + k]) {
                *out += w * v;
            }
        }
        for out in row.iter_mut() {
            *out *= norm;
        }
        // Slide the window: drop profile i - m, add profile i + m + 1.
        let out = (i + n - m) % n;
        let inn = (i + m + 1) % n;
        for j in 0..k {
            acc[j] += raw[inn * k + j] - raw[out * k + j];
        }
    }
    // The belt's level: the median at the outer ends of the profiles. The part's: the median of
    // each profile's extreme on its inner half (a part's margin can be a thin bright rim beside a
    // dark groove, so the inner ends alone may read as dark as the belt). Extreme = brightest for
    // parts brighter than the belt, darkest otherwise.
    let ends = (2.0 / STEP) as usize + 1;
    let mut outer: Vec<f64> = Vec::with_capacity(n * ends);
    for i in 0..n {
        outer.extend_from_slice(&sm[(i + 1) * k - ends..(i + 1) * k]);
    }
    let l_belt = median(&mut outer);
    let mut hi: Vec<f64> = (0..n).map(|i| sm[i * k..i * k + half as usize].iter().cloned().fold(f64::MIN, f64::max)).collect();
    let mut lo: Vec<f64> = (0..n).map(|i| sm[i * k..i * k + half as usize].iter().cloned().fold(f64::MAX, f64::min)).collect();
    let (bright, dark) = (median(&mut hi), median(&mut lo));
    let l_part = if bright - l_belt >= l_belt - dark { bright } else { dark };
    let brighter = l_part >= l_belt;
    let sign = if brighter { 1.0 } else { -1.0 };
    // Smoothing divides white noise by sqrt(profiles averaged) and by sqrt(2 sqrt(pi) sigma) along
    // the profile; the level keeps four of those sigmas clear of the belt so noise rarely
    // crosses it, and at least `level` of the part's contrast.
    let profile_noise = noise / ((2 * m + 1) as f64).sqrt() / (2.0 * std::f64::consts::PI.sqrt() * sig).sqrt();
    let rise = (p.level * (l_part - l_belt).abs()).max(4.0 * profile_noise);
    // Each profile measures its own belt (clouds, shading, the part's own shadow), held within
    // a few spreads of the typical belt so that a neighbour or a speck cannot drag it.
    let mut dev: Vec<f64> = outer.iter().map(|v| (v - l_belt).abs()).collect();
    let spread = 1.4826 * median(&mut dev) + 1.0;
    // The edge is the outermost crossing: stable on the soft shading ramps of rounded parts,
    // where a gradient peak wanders, and at the true edge of a sharp step.
    let contrast = (l_part - l_belt).abs();
    let mut offsets = vec![f64::NAN; n];
    // Whether the material inside each point rises to half the part's contrast (see
    // `drop_faint_spurs`).
    let mut solid = vec![true; n];
    for i in 0..n {
        let prof = &sm[i * k..(i + 1) * k];
        let belt = (prof[k - ends..].iter().sum::<f64>() / ends as f64).clamp(l_belt - 3.0 * spread, l_belt + 3.0 * spread);
        solid[i] = prof[..half as usize].iter().any(|&v| sign * (v - belt) >= 0.5 * contrast);
        let level = belt + sign * rise;
        let is_part = |v: f64| if brighter { v >= level } else { v <= level };
        if let Some(j) = (0..k - 1).rev().find(|&j| is_part(prof[j]))
            && !is_part(prof[j + 1])
        {
            let (a, b) = (prof[j], prof[j + 1]);
            let frac = if (b - a).abs() > 1e-9 { ((level - a) / (b - a)).clamp(0.0, 1.0) } else { 0.5 };
            offsets[i] = ts[j] + frac * STEP;
        }
    }
    clean_offsets(&mut offsets);
    let kept: Vec<usize> = (0..n).filter(|&i| offsets[i].is_finite()).collect();
    if kept.len() < n / 2 {
        // Mostly no edge: keep the coarse outline rather than a few scattered points.
        return Refined { outline: smooth, contrast, brighter };
    }
    let outline: Vec<Pt> = kept.iter().map(|&i| smooth[i] + normals[i].scale(offsets[i])).collect();
    let solid: Vec<bool> = kept.iter().map(|&i| solid[i]).collect();
    Refined { outline: drop_faint_spurs(outline, &solid, 2.0 * p.search), contrast, brighter }
}

/// Faint points in a row, at least this many, make a spur worth looking for.
const FAINT_RUN: usize = 3;

/// How many points either side of a faint run the spur's neck is looked for.
const NECK_REACH: usize = 24;

/// Least reach of a spur beyond its neck, px: less is the outline's own wobble along a faint
/// flank, and cutting it gains nothing.
const SPUR_DEPTH: f64 = 5.0;

/// How far the points of an open polyline reach from the chord joining its ends.
fn depth(pts: &[Pt]) -> f64 {
    let (Some(&a), Some(&b)) = (pts.first(), pts.last()) else { return 0.0 };
    let d = b - a;
    let len = d.norm();
    pts.iter().map(|&p| if len > 1e-9 { (d.x * (p.y - a.y) - d.y * (p.x - a.x)).abs() / len } else { (p - a).norm() }).fold(0.0, f64::max)
}

/// Cuts from a closed outline every spur of faint material joined to the part by a narrow neck:
/// a stain or speck of the belt that lay within the coarse closing's reach of the part, whose
/// edge the refinement then followed (a stain is material to the level test, and the profiles
/// along its far side never see the part). A spur is a run of points whose material never rises
/// to half the part's contrast (`solid` false), leaving the outline through a neck narrower than
/// `neck` px (the points just before and after it come that close) and adding area outside the
/// rest of the outline by more than [`SPUR_DEPTH`]; the outline then goes straight across the neck.
/// The neck may be as wide as the closing's reach, which joined the stain to the part: `neck` is
/// twice the refinement's search. Faint material that widens the part along its side (a dark
/// rim, a shaded flank) has no neck and stays, as does a spur of the part's own bright material.
fn drop_faint_spurs(outline: Vec<Pt>, solid: &[bool], neck: f64) -> Vec<Pt> {
    let n = outline.len();
    if n < 4 * NECK_REACH || solid.iter().all(|&s| s) {
        return outline;
    }
    // Start the walk at a solid point so that no faint run wraps past the end.
    let Some(start) = solid.iter().position(|&s| s) else { return outline };
    let at = |i: usize| (start + i) % n;
    let (total, _) = area_centroid(&outline);
    let mut drop = vec![false; n];
    let mut i = 0;
    while i < n {
        if solid[at(i)] {
            i += 1;
            continue;
        }
        let a = i;
        while i < n && !solid[at(i)] {
            i += 1;
        }
        let b = i - 1;
        if b + 1 - a < FAINT_RUN {
            continue;
        }
        // The neck: the closest pair of points before and after the run.
        let mut best: Option<(f64, usize, usize)> = None;
        for u in a.saturating_sub(NECK_REACH)..a {
            for v in b + 1..(b + 1 + NECK_REACH).min(n + u) {
                let d = (outline[at(u)] - outline[at(v)]).norm();
                if best.is_none_or(|(bd, _, _)| d < bd) {
                    best = Some((d, u, v));
                }
            }
        }
        let Some((d, u, v)) = best else { continue };
        if d > neck {
            continue;
        }
        // The spur adds area: its loop turns the same way as the whole outline.
        let spur: Vec<Pt> = (u..=v).map(|j| outline[at(j)]).collect();
        let (area, _) = area_centroid(&spur);
        if area * total <= 0.0 || area.abs() > 0.1 * total.abs() || depth(&spur) < SPUR_DEPTH {
            continue;
        }
        for j in u + 1..v {
            drop[at(j)] = true;
        }
    }
    if !drop.iter().any(|&d| d) {
        return outline;
    }
    outline.into_iter().zip(drop).filter(|(_, d)| !d).map(|(p, _)| p).collect()
}

/// Appends the frame's bilinear samples at `b + n t` for every t (evenly spaced, ascending): as
/// [`GrayView::bilinear`] gives them, without its clamping where the whole profile lies inside
/// the frame (nearly every profile; this is the refinement's innermost loop).
fn profile(frame: GrayView<'_>, b: Pt, n: Pt, ts: &[f64], out: &mut Vec<f64>) {
    let (w, h) = (frame.width(), frame.height());
    let (Some(&t0), Some(&t1)) = (ts.first(), ts.last()) else { return };
    let (xa, xb, ya, yb) = (b.x + n.x * t0, b.x + n.x * t1, b.y + n.y * t0, b.y + n.y * t1);
    // A thousandth of a pixel to spare: the stepped positions below may drift by a millionth.
    let inside = |lo: f64, hi: f64, size: usize| lo.min(hi) >= 1e-3 && lo.max(hi) <= size as f64 - 2.001;
    if !(inside(xa, xb, w) && inside(ya, yb, h)) {
        out.extend(ts.iter().map(|t| frame.bilinear(b.x + n.x * t, b.y + n.y * t)));
        return;
    }
    let data = frame.data();
    // Positions in 2^-24 pixel, stepped by adding the normal's step and the weights in integers:
    // no float-to-index round trip per sample. A position moves by under 1e-6 pixel over a
    // profile, a value by under 0.001 gray level.
    const BITS: u32 = 24;
    const ONE: f64 = (1u64 << BITS) as f64;
    const FRAC: i64 = (1 << BITS) - 1;
    let (mut x, mut y) = ((xa * ONE) as i64, (ya * ONE) as i64);
    let step = if ts.len() > 1 { (t1 - t0) / (ts.len() - 1) as f64 } else { 0.0 };
    let (dx, dy) = ((n.x * step * ONE).round() as i64, (n.y * step * ONE).round() as i64);
    out.extend(ts.iter().map(|_| {
        let (fx, fy) = (x & FRAC, y & FRAC);
        let i = (y >> BITS) as usize * w + (x >> BITS) as usize;
        let (p, q) = (&data[i..i + 2], &data[i + w..i + w + 2]);
        let top = ((p[0] as i64) << BITS) + (p[1] as i64 - p[0] as i64) * fx;
        let bot = ((q[0] as i64) << BITS) + (q[1] as i64 - q[0] as i64) * fx;
        (x, y) = (x + dx, y + dy);
        ((top << BITS) + (bot - top) * fy) as f64 * (1.0 / (ONE * ONE))
    }));
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    let mid = v.len() / 2;
    *v.select_nth_unstable_by(mid, f64::total_cmp).1
}

/// Replaces missing and isolated outlying offsets by the local median: a speck of dirt next to
/// the part or a noise spike must not bend the outline.
///
/// A stretch where no neighbour found an edge either stays missing (NaN): the coarse region ran
/// around something that is not the part (a speck of dirt closed onto it), and the refined outline
/// bridges the gap with a chord instead of following it.
fn clean_offsets(off: &mut [f64]) {
    let n = off.len();
    let src = off.to_vec();
    let mut win = Vec::with_capacity(7);
    for i in 0..n {
        win.clear();
        for d in 0..7 {
            let v = src[(i + n + d - 3) % n];
            if v.is_finite() {
                win.push(v);
            }
        }
        if win.is_empty() {
            off[i] = f64::NAN;
            continue;
        }
        win.sort_by(f64::total_cmp);
        let med = win[win.len() / 2];
        if !src[i].is_finite() || (src[i] - med).abs() > 2.0 {
            off[i] = med;
        }
    }
}

/// Robust standard deviation of the frame's pixel noise, from horizontal differences of every
/// sixteenth row away from the given regions (if any). The belt's texture is smooth at one pixel,
/// so what remains is sensor noise.
pub fn noise_sigma(frame: GrayView<'_>, exclude: &[(Pt, Pt)]) -> f64 {
    // Four interleaved tables: neighbouring differences mostly fall in the same few bins, and
    // one table's increments would wait on each other.
    let mut hists = [[0u32; 256]; 4];
    let w = frame.width();
    let mut spans: Vec<(usize, usize)> = Vec::new();
    for y in (0..frame.height()).step_by(16) {
        let row = &frame.data()[y * w..(y + 1) * w];
        let yf = y as f64;
        // The row's stretches between excluded boxes.
        spans.clear();
        spans.extend(
            exclude
                .iter()
                .filter(|(lo, hi)| yf >= lo.y && yf <= hi.y)
                .map(|(lo, hi)| (lo.x.max(0.0) as usize, (hi.x.max(0.0) as usize + 1).min(w))),
        );
        spans.sort_unstable();
        let mut x = 0;
        for &(a, b) in spans.iter().chain(std::iter::once(&(w, w))) {
            if a > x {
                let mut octets = row[x..a].chunks_exact(8);
                for o in &mut octets {
                    for (k, hist) in hists.iter_mut().enumerate() {
                        hist[o[2 * k + 1].abs_diff(o[2 * k]) as usize] += 1;
                    }
                }
                for pair in octets.remainder().chunks_exact(2) {
                    hists[0][pair[1].abs_diff(pair[0]) as usize] += 1;
                }
            }
            x = x.max(b);
        }
    }
    let mut hist = hists[0];
    for h in &hists[1..] {
        for (a, b) in hist.iter_mut().zip(h) {
            *a += b;
        }
    }
    let count: u32 = hist.iter().sum();
    if count == 0 {
        return 0.0;
    }
    // Median absolute difference -> sigma of a Gaussian; a difference has sqrt(2) x the noise.
    let mut acc = 0u32;
    let mut med = 0.0;
    for (v, c) in hist.iter().enumerate() {
        acc += c;
        if acc * 2 >= count {
            // Interpolate within the bin so small noise levels are not stuck at integers.
            let before = acc - c;
            let frac = if *c > 0 { (count as f64 / 2.0 - before as f64) / *c as f64 } else { 0.5 };
            med = v as f64 - 0.5 + frac;
            break;
        }
    }
    med.max(0.0) * 1.4826 / std::f64::consts::SQRT_2
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::frame::GrayImage;
    use crate::vision::geometry::area_centroid;

    /// A bright disc of radius `r` at (cx, cy), anti-aliased by 8 x 8 supersampling.
    fn disc(w: usize, h: usize, cx: f64, cy: f64, r: f64) -> GrayImage {
        let mut img = GrayImage::new(w, h, 40);
        for y in 0..h {
            for x in 0..w {
                let mut inside = 0;
                for sy in 0..8 {
                    for sx in 0..8 {
                        let px = x as f64 - 0.5 + (sx as f64 + 0.5) / 8.0;
                        let py = y as f64 - 0.5 + (sy as f64 + 0.5) / 8.0;
                        if (px - cx).hypot(py - cy) <= r {
                            inside += 1;
                        }
                    }
                }
                img.data[y * w + x] = (40.0 + 160.0 * inside as f64 / 64.0).round() as u8;
            }
        }
        img
    }

    #[test]
    fn refines_a_rough_circle_to_sub_pixel() {
        let img = disc(200, 200, 97.3, 101.8, 60.0);
        // A coarse outline 3 px too large and slightly off centre.
        let coarse: Vec<Pt> = (0..64)
            .map(|i| {
                let a = i as f64 / 64.0 * std::f64::consts::TAU;
                Pt::new(98.0 + 63.0 * a.cos(), 101.0 + 63.0 * a.sin())
            })
            .collect();
        let p = RefineParams { spacing: 2.0, search: 8.0, profile_sigma: 1.0, across: 2, level: 0.5 };
        let out = refine(img.view().unwrap(), &coarse, 0.0, &p);
        assert!((out.contrast - 160.0).abs() < 40.0, "contrast {}", out.contrast);
        let (area, c) = area_centroid(&out.outline);
        assert!((c.x - 97.3).abs() < 0.05 && (c.y - 101.8).abs() < 0.05, "centroid {c:?}");
        let r = (area.abs() / std::f64::consts::PI).sqrt();
        assert!((r - 60.0).abs() < 0.2, "radius {r}");
    }

    #[test]
    fn profiles_inside_the_frame_sample_as_bilinear_does() {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(3);
        let (w, h) = (64, 48);
        let mut img = GrayImage::new(w, h, 0);
        for v in img.data.iter_mut() {
            *v = rng.random_range(0..=255);
        }
        let frame = img.view().unwrap();
        let ts: Vec<f64> = (-8..=8).map(|i| i as f64 * STEP).collect();
        let mut fast_path = 0;
        for _ in 0..500 {
            let b = Pt::new(rng.random_range(-5.0..70.0), rng.random_range(-5.0..53.0));
            let a: f64 = rng.random_range(0.0..std::f64::consts::TAU);
            let n = Pt::new(a.cos(), a.sin());
            let mut got = Vec::new();
            profile(frame, b, n, &ts, &mut got);
            assert_eq!(got.len(), ts.len());
            fast_path += usize::from(b.x.min(b.y) > 9.0 && b.x < 53.0 && b.y < 37.0);
            for (t, v) in ts.iter().zip(&got) {
                let want = frame.bilinear(b.x + n.x * t, b.y + n.y * t);
                assert!((v - want).abs() < 1e-3, "at {b:?} + {n:?} x {t}: {v} against {want}");
            }
        }
        assert!(fast_path > 100, "only {fast_path} profiles wholly inside");
    }

    #[test]
    fn noise_estimate_tracks_added_noise() {
        use rand::SeedableRng;
        use rand_distr::{Distribution, Normal};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for sigma in [5.0f64, 20.0] {
            let nd = Normal::new(0.0, sigma).unwrap();
            let mut img = GrayImage::new(400, 300, 0);
            for v in img.data.iter_mut() {
                *v = (100.0 + nd.sample(&mut rng)).round().clamp(0.0, 255.0) as u8;
            }
            let est = noise_sigma(img.view().unwrap(), &[]);
            assert!((est - sigma).abs() < 0.1 * sigma, "sigma {sigma} estimated {est}");
        }
    }
}
