//! The fast line detector (FLD, Lee et al. 2014) on an edge map, following the rules of
//! OpenCV's `ximgproc::FastLineDetector` without its per-position matrix allocations.
//!
//! Why our own: OpenCV's FLD builds and clones small matrices at every chain position it tries
//! and for every line fit. On the bench's four-part frame it took 18.6 M of the frame's 94 M
//! instructions (4.6 M per part), most of it allocation, for a few hundred edge pixels per part.
//! The rules are kept so that the segments are the same (`tests/line_features.rs` holds this
//! detector to OpenCV's on simulated and shared scenes): chains of 8-connected edge pixels
//! walked in a consistent direction; a window of `min_len` chain steps that stays within
//! `max_dist` of the chord through its ends starts a segment; a least-squares line through the
//! segment's pixels grows it while the next pixel stays within `max_dist` (one refit allowed at
//! each miss); the ends are projected on the fitted line. The fit's sums are kept running, so
//! growing a segment costs a few operations per pixel.

/// One segment, `[x1, y1, x2, y2]` in the map's pixels, directed as OpenCV directs it.
pub type Line = [f32; 4];

/// Finds the segments of an edge map (non-zero = edge), `width` x `height`, row-major.
///
/// `min_len` is the least segment length and window (pixels, at least 1); `max_dist` the largest
/// distance of an edge pixel from its segment's line. The map is consumed: traced pixels are
/// cleared (as OpenCV's detector clears its input).
pub fn detect(map: &mut [u8], width: usize, height: usize, min_len: usize, max_dist: f32) -> Vec<Line> {
    let (w, h) = (width, height);
    assert_eq!(map.len(), w * h, "edge map of {} bytes is not {w} x {h}", map.len());
    let min_len = min_len.max(1);
    let mut out = Vec::new();
    if w < 8 || h < 8 {
        return out;
    }
    // OpenCV clears these two corners of its input before tracing.
    for y in 0..6 {
        map[y * w..y * w + 6].fill(0);
    }
    for y in h - 5..h {
        map[y * w + w - 5..(y + 1) * w].fill(0);
    }
    let mut chain: Vec<(i32, i32)> = Vec::new();
    let mut found: Vec<Line> = Vec::new();
    let (wf, hf) = (w as f32, h as f32);
    for r in 0..h {
        for c in 0..w {
            if map[r * w + c] == 0 {
                continue;
            }
            chain.clear();
            let mut pt = (c as i32, r as i32);
            chain.push(pt);
            map[r * w + c] = 0;
            let mut direction = 0.0f32;
            let mut step = 0;
            while let Some(next) = next_in_chain(map, w, h, pt, &mut direction, step) {
                chain.push(next);
                step += 1;
                map[next.1 as usize * w + next.0 as usize] = 0;
                pt = next;
            }
            if chain.len() < min_len + 1 {
                continue;
            }
            found.clear();
            split(&chain, min_len, max_dist as f64, (w, h), &mut found);
            for &s in &found {
                let [x1, y1, x2, y2] = s;
                let len = ((x1 - x2) * (x1 - x2) + (y1 - y2) * (y1 - y2)).sqrt();
                if len < min_len as f32 {
                    continue;
                }
                // Segments along the map's own edge belong to the box, not the picture.
                if (x1 <= 5.0 && x2 <= 5.0)
                    || (y1 <= 5.0 && y2 <= 5.0)
                    || (x1 >= wf - 5.0 && x2 >= wf - 5.0)
                    || (y1 >= hf - 5.0 && y2 >= hf - 5.0)
                {
                    continue;
                }
                out.push(direct(map, w, h, s));
            }
        }
    }
    out
}

/// The next pixel of a chain from `pt`: the first neighbour at the first step, afterwards the
/// neighbour whose direction is closest (within one eighth turn either way) to the chain's mean
/// direction so far, which `direction` keeps. Directions are eighth turns, -3..=4.
fn next_in_chain(map: &[u8], w: usize, h: usize, pt: (i32, i32), direction: &mut f32, step: usize) -> Option<(i32, i32)> {
    // (row, column) offsets in OpenCV's order: the order decides ties.
    const AROUND: [(i32, i32); 8] = [(1, 1), (1, 0), (1, -1), (0, -1), (-1, -1), (-1, 0), (-1, 1), (0, 1)];
    let mut best: Option<((i32, i32), f32)> = None;
    let mut least = 7.0f32;
    for (i, &(dr, dc)) in AROUND.iter().enumerate() {
        let (c, r) = (pt.0 + dc, pt.1 + dr);
        if r < 0 || r as usize >= h || c < 0 || c as usize >= w || map[r as usize * w + c as usize] == 0 {
            continue;
        }
        let dir = if i > 4 { i as f32 - 8.0 } else { i as f32 };
        if step == 0 {
            *direction = dir;
            return Some((c, r));
        }
        let mut diff = (dir - *direction).abs();
        if diff > 4.0 {
            diff = 8.0 - diff;
        }
        if diff <= least {
            least = diff;
            best = Some(((c, r), dir));
        }
    }
    let (next, dir) = best.filter(|_| least < 2.0)?;
    *direction = (*direction * step as f32 + dir) / (step + 1) as f32;
    Some(next)
}

/// A line `a x + b y + c = 0` in homogeneous form.
#[derive(Clone, Copy)]
struct Homog([f64; 3]);

impl Homog {
    fn cross(p: [f64; 3], q: [f64; 3]) -> Homog {
        Homog([p[1] * q[2] - p[2] * q[1], p[2] * q[0] - p[0] * q[2], p[0] * q[1] - p[1] * q[0]])
    }
    /// Scaled so that `a² + b² = 1`.
    fn normalised(self) -> Homog {
        let [a, b, c] = self.0;
        let n = (a * a + b * b).sqrt();
        Homog([a / n, b / n, c / n])
    }
    /// Signed distance of an integer point from a normalised line.
    fn dist(&self, p: (i32, i32)) -> f64 {
        self.0[0] * p.0 as f64 + self.0[1] * p.1 as f64 + self.0[2]
    }
    /// The foot of the perpendicular from `(x, y)`, clamped into a `w` x `h` map.
    fn foot(&self, x: f64, y: f64, (w, h): (usize, usize)) -> (f32, f32) {
        let l = self.0;
        let k = Homog::cross([x, y, 1.0], [l[0], l[1], 0.0]).0;
        let f = Homog::cross(k, l).0;
        let s = 1.0 / f[2];
        let clamp = |v: f32, size: usize| {
            let top = size as f32 - 1.0;
            if v < 0.0 {
                0.0
            } else if v >= top {
                top
            } else {
                v
            }
        };
        (clamp((f[0] * s) as f32, w), clamp((f[1] * s) as f32, h))
    }
}

/// Running sums of a least-squares line fit over integer points.
#[derive(Default)]
struct Moments {
    n: f64,
    x: f64,
    y: f64,
    xx: f64,
    yy: f64,
    xy: f64,
}

impl Moments {
    fn add(&mut self, (x, y): (i32, i32)) {
        let (x, y) = (x as f64, y as f64);
        self.n += 1.0;
        self.x += x;
        self.y += y;
        self.xx += x * x;
        self.yy += y * y;
        self.xy += x * y;
    }
    /// The total-least-squares line through the points so far, in single precision as OpenCV's
    /// `fitLine` reports it (a point and a unit direction).
    fn line(&self) -> Homog {
        let (mx, my) = (self.x / self.n, self.y / self.n);
        let dxx = self.xx / self.n - mx * mx;
        let dyy = self.yy / self.n - my * my;
        let dxy = self.xy / self.n - mx * my;
        let t = ((2.0 * dxy).atan2(dxx - dyy) as f32) / 2.0;
        let (dx, dy) = (t.cos(), t.sin());
        let (px, py) = (mx as f32, my as f32);
        Homog::cross([px as f64, py as f64, 1.0], [(px + dx) as f64, (py + dy) as f64, 1.0])
    }
}

/// Splits one chain into straight segments (see the module's description).
fn split(points: &[(i32, i32)], min_len: usize, max_dist: f64, size: (usize, usize), out: &mut Vec<Line>) {
    let total = points.len();
    let mut i = 0;
    while i + min_len < total {
        let (ps, pe) = (points[i], points[i + min_len]);
        let chord = Homog::cross([ps.0 as f64, ps.1 as f64, 1.0], [pe.0 as f64, pe.1 as f64, 1.0]).normalised();
        if points[i + 1..i + min_len].iter().any(|&p| chord.dist(p).abs() > max_dist) {
            i += 1;
            continue;
        }
        let mut fit = Moments::default();
        for &p in &points[i..=i + min_len] {
            fit.add(p);
        }
        let mut line = fit.line();
        let (sx, sy) = line.foot(ps.0 as f64, ps.1 as f64, size);
        let start = (sx.round_ties_even() as i32, sy.round_ties_even() as i32);
        line = line.normalised();
        let mut end = pe;
        let mut j = min_len + 1;
        while i + j < total {
            let p = points[i + j];
            if line.dist(p).abs() > max_dist {
                line = fit.line().normalised();
                if line.dist(p).abs() > max_dist {
                    j -= 1;
                    break;
                }
            }
            end = p;
            fit.add(p);
            j += 1;
        }
        let line = fit.line();
        let (x1, y1) = line.foot(start.0 as f64, start.1 as f64, size);
        let (x2, y2) = line.foot(end.0 as f64, end.1 as f64, size);
        out.push([x1, y1, x2, y2]);
        i += j + 1;
    }
}

/// The segment directed as OpenCV directs it: the side with fewer (remaining) edge pixels on
/// the left, sampled at ten points one pixel to either side.
fn direct(map: &[u8], w: usize, h: usize, s: Line) -> Line {
    let [x1, y1, x2, y2] = s;
    let ang = ((y2 - y1) as f64).atan2((x2 - x1) as f64) as f32 as f64;
    let (dx, dy) = (x2 - x1, y2 - y1);
    let (ox, oy) = ((std::f64::consts::FRAC_PI_2 + ang).cos(), (std::f64::consts::FRAC_PI_2 + ang).sin());
    // Held five pixels inside the map, as OpenCV holds them (the map is at least 8 wide).
    let inboard = |v: f64, size: usize| {
        let v = v.round_ties_even() as i64;
        let top = size as i64 - 5;
        (if v <= 5 {
            5
        } else if v >= top {
            top
        } else {
            v
        }) as usize
    };
    let (mut right, mut left) = (0u32, 0u32);
    for i in 0..10 {
        let (px, py) = match i {
            0 => (x1, y1),
            9 => (x2, y2),
            _ => (x1 + dx / 9.0 * i as f32, y1 + dy / 9.0 * i as f32),
        };
        let (px, py) = (px as f64, py as f64);
        right += map[inboard(py + oy, h) * w + inboard(px + ox, w)] as u32;
        left += map[inboard(py - oy, h) * w + inboard(px - ox, w)] as u32;
    }
    if right > left { [x2, y2, x1, y1] } else { s }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_l_of_edge_pixels_is_two_segments_meeting_at_the_corner() {
        let (w, h) = (40, 30);
        let mut map = vec![0u8; w * h];
        for x in 8..=30 {
            map[10 * w + x] = 255;
        }
        for y in 10..=24 {
            map[y * w + 30] = 255;
        }
        let found = detect(&mut map, w, h, 5, std::f32::consts::SQRT_2);
        assert_eq!(found.len(), 2, "{found:?}");
        let near = |p: (f32, f32), q: (f32, f32)| (p.0 - q.0).hypot(p.1 - q.1) < 1.01;
        let ends = |s: &Line| [(s[0], s[1]), (s[2], s[3])];
        let has = |a: (f32, f32), b: (f32, f32)| {
            found.iter().any(|s| {
                let [p, q] = ends(s);
                (near(p, a) && near(q, b)) || (near(p, b) && near(q, a))
            })
        };
        assert!(has((8.0, 10.0), (30.0, 10.0)), "{found:?}");
        assert!(has((30.0, 11.0), (30.0, 24.0)), "{found:?}");
        assert!(map.iter().all(|&v| v == 0), "traced pixels are cleared");
    }

    #[test]
    fn short_chains_and_tiny_maps_give_nothing() {
        let mut map = vec![255u8; 7 * 7];
        assert!(detect(&mut map, 7, 7, 3, 1.5).is_empty());
        let (w, h) = (20, 20);
        let mut map = vec![0u8; w * h];
        for x in 8..12 {
            map[10 * w + x] = 255;
        }
        assert!(detect(&mut map, w, h, 5, 1.5).is_empty());
    }
}
