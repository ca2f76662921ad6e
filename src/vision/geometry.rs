//! Plane geometry on sub-pixel outlines.
//!
//! Coordinates are image pixels with pixel centres on integers, x to the right and y down. Angles
//! follow the product's convention: positive is counter-clockwise *as displayed*, which in y-down
//! coordinates is the matrix `[[cos, sin], [-sin, cos]]` (OpenCV's `getRotationMatrix2D`).

use std::f64::consts::PI;

/// A point or vector in pixel coordinates.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Pt {
    /// Horizontal, to the right.
    pub x: f64,
    /// Vertical, downwards (image rows).
    pub y: f64,
}

impl Pt {
    /// A point from its coordinates.
    pub const fn new(x: f64, y: f64) -> Self {
        Self { x, y }
    }
    /// Euclidean length.
    pub fn norm(self) -> f64 {
        (self.x * self.x + self.y * self.y).sqrt()
    }
    /// Dot product.
    pub fn dot(self, o: Pt) -> f64 {
        self.x * o.x + self.y * o.y
    }
    /// z of the cross product (positive: `o` lies clockwise as displayed, counter-clockwise in y-down).
    pub fn cross(self, o: Pt) -> f64 {
        self.x * o.y - self.y * o.x
    }
    /// The vector times `k`.
    pub fn scale(self, k: f64) -> Pt {
        Pt::new(self.x * k, self.y * k)
    }
    /// Direction of the vector as displayed: 0 along +x, counter-clockwise positive.
    pub fn display_angle(self) -> f64 {
        (-self.y).atan2(self.x)
    }
}

impl std::ops::Add for Pt {
    type Output = Pt;
    fn add(self, o: Pt) -> Pt {
        Pt::new(self.x + o.x, self.y + o.y)
    }
}

impl std::ops::Sub for Pt {
    type Output = Pt;
    fn sub(self, o: Pt) -> Pt {
        Pt::new(self.x - o.x, self.y - o.y)
    }
}

/// Rotates a vector counter-clockwise as displayed.
pub fn rotate_display(v: Pt, angle_rad: f64) -> Pt {
    let (s, c) = angle_rad.sin_cos();
    Pt::new(c * v.x + s * v.y, -s * v.x + c * v.y)
}

/// Wraps degrees into [0, 360).
pub fn wrap_deg(a: f64) -> f64 {
    let w = a.rem_euclid(360.0);
    if w >= 360.0 { 0.0 } else { w }
}

/// Signed smallest difference a - b in degrees, in (-180, 180].
pub fn angle_diff_deg(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(360.0);
    if d > 180.0 { d - 360.0 } else { d }
}

/// A similarity transform from template pixels to frame pixels:
/// `p = to + scale * R(angle) * (q - from)`, R counter-clockwise as displayed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// The template point `from` maps to.
    pub from: Pt,
    /// Where it lands in the frame.
    pub to: Pt,
    /// Rotation, counter-clockwise as displayed.
    pub angle_rad: f64,
    /// Frame pixels per template pixel.
    pub scale: f64,
}

impl Similarity {
    /// Template pixels to frame pixels.
    pub fn apply(&self, q: Pt) -> Pt {
        self.to + rotate_display(q - self.from, self.angle_rad).scale(self.scale)
    }
    /// Frame pixels to template pixels.
    pub fn invert(&self, p: Pt) -> Pt {
        self.from + rotate_display(p - self.to, -self.angle_rad).scale(1.0 / self.scale)
    }
    /// The rotation in degrees, wrapped into [0, 360).
    pub fn angle_deg(&self) -> f64 {
        wrap_deg(self.angle_rad.to_degrees())
    }
    /// [`Similarity::apply`] as a matrix, for mapping many points: one sine and cosine per pose,
    /// not one per point (they were an eighth of a frame's time).
    pub fn forward(&self) -> Affine {
        let (s, c) = self.angle_rad.sin_cos();
        Affine::new([c * self.scale, s * self.scale, -s * self.scale, c * self.scale], self.from, self.to)
    }
    /// [`Similarity::invert`] as a matrix.
    pub fn inverse(&self) -> Affine {
        let (s, c) = self.angle_rad.sin_cos();
        let k = 1.0 / self.scale;
        Affine::new([c * k, -s * k, s * k, c * k], self.to, self.from)
    }
}

/// `p = m * q + t`, a [`Similarity`] (or its inverse) with its rotation evaluated once.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Affine {
    m: [f64; 4],
    t: Pt,
}

impl Affine {
    /// [`rotate_display`] by `angle_rad` as a matrix (for normals: no scale, no offset).
    pub fn rotation(angle_rad: f64) -> Self {
        let (s, c) = angle_rad.sin_cos();
        Self { m: [c, s, -s, c], t: Pt::new(0.0, 0.0) }
    }
    /// The map `q -> to + m * (q - from)`.
    fn new(m: [f64; 4], from: Pt, to: Pt) -> Self {
        let t = Pt::new(to.x - (m[0] * from.x + m[1] * from.y), to.y - (m[2] * from.x + m[3] * from.y));
        Self { m, t }
    }
    /// Maps a point.
    pub fn apply(&self, q: Pt) -> Pt {
        Pt::new(self.m[0] * q.x + self.m[1] * q.y + self.t.x, self.m[2] * q.x + self.m[3] * q.y + self.t.y)
    }
}

/// Signed area (positive when the vertices run counter-clockwise in y-down coordinates, i.e.
/// clockwise as displayed) and area centroid of a closed polygon.
pub fn area_centroid(poly: &[Pt]) -> (f64, Pt) {
    let n = poly.len();
    if n < 3 {
        return (0.0, centroid_of_points(poly));
    }
    // Shift to the first vertex to keep the cross products well conditioned.
    let o = poly[0];
    let (mut a2, mut cx, mut cy) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let p = poly[i] - o;
        let q = poly[(i + 1) % n] - o;
        let c = p.cross(q);
        a2 += c;
        cx += (p.x + q.x) * c;
        cy += (p.y + q.y) * c;
    }
    if a2.abs() < 1e-12 {
        return (0.0, centroid_of_points(poly));
    }
    (a2 / 2.0, Pt::new(o.x + cx / (3.0 * a2), o.y + cy / (3.0 * a2)))
}

fn centroid_of_points(pts: &[Pt]) -> Pt {
    if pts.is_empty() {
        return Pt::default();
    }
    let n = pts.len() as f64;
    let s = pts.iter().fold(Pt::default(), |a, &p| a + p);
    s.scale(1.0 / n)
}

/// Perimeter of a closed polygon.
pub fn perimeter(poly: &[Pt]) -> f64 {
    let n = poly.len();
    (0..n).map(|i| (poly[(i + 1) % n] - poly[i]).norm()).sum()
}

/// Resamples a closed polygon at (nearly) uniform arc-length spacing.
pub fn resample_closed(poly: &[Pt], spacing: f64) -> Vec<Pt> {
    let n = poly.len();
    if n < 2 || spacing <= 0.0 {
        return poly.to_vec();
    }
    let total = perimeter(poly);
    let count = ((total / spacing).round() as usize).max(3);
    let step = total / count as f64;
    let mut out = Vec::with_capacity(count);
    let mut seg = 0usize;
    let mut seg_start = 0.0;
    let mut seg_len = (poly[1 % n] - poly[0]).norm();
    for k in 0..count {
        let s = k as f64 * step;
        while s > seg_start + seg_len && seg < n - 1 {
            seg_start += seg_len;
            seg += 1;
            seg_len = (poly[(seg + 1) % n] - poly[seg]).norm();
        }
        let a = poly[seg];
        let b = poly[(seg + 1) % n];
        let t = if seg_len > 0.0 { ((s - seg_start) / seg_len).clamp(0.0, 1.0) } else { 0.0 };
        out.push(a + (b - a).scale(t));
    }
    out
}

/// Circular moving average of a closed polyline (`half` samples each side).
pub fn smooth_closed(poly: &[Pt], half: usize) -> Vec<Pt> {
    let n = poly.len();
    if n == 0 || half == 0 {
        return poly.to_vec();
    }
    let w = (2 * half + 1) as f64;
    (0..n)
        .map(|i| {
            let mut s = Pt::default();
            for k in 0..=2 * half {
                s = s + poly[(i + n + k - half % n) % n];
            }
            s.scale(1.0 / w)
        })
        .collect()
}

/// Unit outward normals of a closed polygon (outward for either winding).
pub fn outward_normals(poly: &[Pt], half: usize) -> Vec<Pt> {
    let n = poly.len();
    let (area, _) = area_centroid(poly);
    // For positive signed area (clockwise as displayed) the outward side of tangent t is (t.y, -t.x)
    // rotated; pick the sign so that normals point away from the interior.
    let sign = if area > 0.0 { 1.0 } else { -1.0 };
    (0..n)
        .map(|i| {
            let a = poly[(i + n - half % n) % n];
            let b = poly[(i + half) % n];
            let t = b - a;
            let len = t.norm().max(1e-12);
            Pt::new(t.y / len * sign, -t.x / len * sign)
        })
        .collect()
}

/// Distance from `p` to segment `a`-`b`, and the parameter of the closest point.
pub fn point_segment(p: Pt, a: Pt, b: Pt) -> (f64, f64) {
    let ab = b - a;
    let l2 = ab.dot(ab);
    let t = if l2 > 0.0 { ((p - a).dot(ab) / l2).clamp(0.0, 1.0) } else { 0.0 };
    ((a + ab.scale(t) - p).norm(), t)
}

/// Even-odd point-in-polygon test.
pub fn contains(poly: &[Pt], p: Pt) -> bool {
    let n = poly.len();
    let mut inside = false;
    let mut j = n.wrapping_sub(1);
    for i in 0..n {
        let (a, b) = (poly[i], poly[j]);
        if (a.y > p.y) != (b.y > p.y) {
            let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
            if p.x < x {
                inside = !inside;
            }
        }
        j = i;
    }
    inside
}

/// The even-odd test of [`contains`] for one polygon asked many times: its edges kept by the
/// rows of whole pixels their span meets, so that a point is tested against the few edges of
/// its own row rather than all of them. The answer is [`contains`]'s exactly (the same edges
/// cross the point's row, tested by the same formula); a template's verification points probe
/// its outline a few thousand times at loading, and a part's departure tests every point of
/// one outline against the other.
#[derive(Debug, Clone)]
pub struct Inside {
    /// The first row's top, a whole pixel at or above the polygon's top.
    top: f64,
    /// Per row, where its edges start in `edges` (one more than the rows).
    starts: Vec<u32>,
    /// Each row's edges as (a, b), in the polygon's order (a = point i, b = point i - 1).
    edges: Vec<(Pt, Pt)>,
}

impl Inside {
    /// The test for `poly` (closed, any orientation).
    pub fn new(poly: &[Pt]) -> Self {
        let n = poly.len();
        let (lo, hi) = bounds(poly);
        if n == 0 || !lo.y.is_finite() || !hi.y.is_finite() {
            return Self { top: 0.0, starts: vec![0], edges: Vec::new() };
        }
        let top = lo.y.floor();
        let rows = (hi.y.floor() - top) as usize + 1;
        let row = |y: f64| ((y.floor() - top) as usize).min(rows - 1);
        let span = |i: usize| {
            let (a, b) = (poly[i], poly[(i + n - 1) % n]);
            (a, b, row(a.y.min(b.y)), row(a.y.max(b.y)))
        };
        let mut counts = vec![0u32; rows + 1];
        for i in 0..n {
            let (_, _, r0, r1) = span(i);
            for c in &mut counts[r0 + 1..=r1 + 1] {
                *c += 1;
            }
        }
        for r in 0..rows {
            counts[r + 1] += counts[r];
        }
        let mut fill = counts.clone();
        let mut edges = vec![(Pt::new(0.0, 0.0), Pt::new(0.0, 0.0)); counts[rows] as usize];
        for i in 0..n {
            let (a, b, r0, r1) = span(i);
            for f in &mut fill[r0..=r1] {
                edges[*f as usize] = (a, b);
                *f += 1;
            }
        }
        Self { top, starts: counts, edges }
    }

    /// Whether `p` lies inside, as [`contains`] says.
    pub fn contains(&self, p: Pt) -> bool {
        let r = (p.y.floor() - self.top) as isize;
        if !(r >= 0 && (r as usize) + 1 < self.starts.len()) {
            return false;
        }
        let r = r as usize;
        let mut inside = false;
        for &(a, b) in &self.edges[self.starts[r] as usize..self.starts[r + 1] as usize] {
            if (a.y > p.y) != (b.y > p.y) {
                let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
                if p.x < x {
                    inside = !inside;
                }
            }
        }
        inside
    }
}

/// Axis-aligned bounding box (min, max).
pub fn bounds(poly: &[Pt]) -> (Pt, Pt) {
    let mut lo = Pt::new(f64::INFINITY, f64::INFINITY);
    let mut hi = Pt::new(f64::NEG_INFINITY, f64::NEG_INFINITY);
    for p in poly {
        lo.x = lo.x.min(p.x);
        lo.y = lo.y.min(p.y);
        hi.x = hi.x.max(p.x);
        hi.y = hi.y.max(p.y);
    }
    (lo, hi)
}

/// Undirected angle between two line directions, in [0, pi/2].
pub fn line_angle_between(a: f64, b: f64) -> f64 {
    let d = (a - b).rem_euclid(PI);
    d.min(PI - d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(side: f64) -> Vec<Pt> {
        vec![Pt::new(0.0, 0.0), Pt::new(side, 0.0), Pt::new(side, side), Pt::new(0.0, side)]
    }

    #[test]
    fn area_and_centroid_of_a_square() {
        let (a, c) = area_centroid(&square(4.0));
        assert!((a.abs() - 16.0).abs() < 1e-12);
        assert!((c.x - 2.0).abs() < 1e-12 && (c.y - 2.0).abs() < 1e-12);
    }

    #[test]
    fn normals_point_outward_for_both_windings() {
        let sq = square(10.0);
        let mut rev = sq.clone();
        rev.reverse();
        for poly in [resample_closed(&sq, 1.0), resample_closed(&rev, 1.0)] {
            let (_, c) = area_centroid(&poly);
            let ns = outward_normals(&poly, 1);
            for (p, n) in poly.iter().zip(&ns) {
                // Skip the corners, where the normal is diagonal by construction.
                let probe = *p + n.scale(0.5);
                let inward = *p - n.scale(0.5);
                if (p.x - 5.0).abs() < 4.0 || (p.y - 5.0).abs() < 4.0 {
                    assert!((probe - c).norm() > (inward - c).norm());
                }
            }
        }
    }

    #[test]
    fn similarity_round_trips_and_rotates_counter_clockwise_as_displayed() {
        let t = Similarity { from: Pt::new(1.0, 2.0), to: Pt::new(10.0, 20.0), angle_rad: 0.5, scale: 1.3 };
        let q = Pt::new(4.0, -3.0);
        let back = t.invert(t.apply(q));
        assert!((back - q).norm() < 1e-9);
        // +x rotated by 90 degrees CCW as displayed points up the screen, i.e. -y.
        let v = rotate_display(Pt::new(1.0, 0.0), std::f64::consts::FRAC_PI_2);
        assert!((v - Pt::new(0.0, -1.0)).norm() < 1e-12);
    }

    #[test]
    fn the_matrix_forms_map_as_the_similarity_does() {
        let t = Similarity { from: Pt::new(-7.0, 3.5), to: Pt::new(812.0, 433.0), angle_rad: -2.3, scale: 0.97 };
        let (fwd, inv) = (t.forward(), t.inverse());
        for q in [Pt::new(0.0, 0.0), Pt::new(4.0, -3.0), Pt::new(-120.5, 77.25)] {
            assert!((fwd.apply(q) - t.apply(q)).norm() < 1e-9);
            assert!((inv.apply(q) - t.invert(q)).norm() < 1e-9);
            assert!((Affine::rotation(t.angle_rad).apply(q) - rotate_display(q, t.angle_rad)).norm() < 1e-9);
        }
    }

    /// The row-bucketed test answers as the plain one, on star-shaped polygons with vertices
    /// on and between whole rows and points on rows, on vertices and outside.
    #[test]
    fn inside_answers_as_contains() {
        let mut seed = 12345u64;
        let mut next = move || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        for k in 0..40 {
            let n = 3 + (next() * 60.0) as usize;
            let poly: Vec<Pt> = (0..n)
                .map(|i| {
                    let a = std::f64::consts::TAU * i as f64 / n as f64;
                    let r = 5.0 + 40.0 * next();
                    let p = Pt::new(50.0 + r * a.cos(), 50.0 + r * a.sin());
                    if k % 2 == 0 { Pt::new(p.x.round(), p.y.round()) } else { p }
                })
                .collect();
            let inside = Inside::new(&poly);
            let mut probes: Vec<Pt> = poly.clone();
            probes.extend((0..400).map(|_| Pt::new(-5.0 + 110.0 * next(), -5.0 + 110.0 * next())));
            probes.extend((0..100).map(|_| Pt::new(-5.0 + 110.0 * next(), (-5.0 + 110.0 * next()).round())));
            for p in probes {
                assert_eq!(inside.contains(p), contains(&poly, p), "polygon {k} at {p:?}");
            }
        }
        assert!(!Inside::new(&[]).contains(Pt::new(0.0, 0.0)));
    }

    #[test]
    fn resampling_keeps_the_perimeter() {
        let sq = square(10.0);
        let r = resample_closed(&sq, 0.7);
        assert!((perimeter(&r) - 40.0).abs() < 0.5);
        assert!(contains(&sq, Pt::new(5.0, 5.0)) && !contains(&sq, Pt::new(11.0, 5.0)));
    }

    #[test]
    fn angle_helpers_wrap() {
        assert_eq!(wrap_deg(-10.0), 350.0);
        assert!((angle_diff_deg(1.0, 359.0) - 2.0).abs() < 1e-12);
        assert!((angle_diff_deg(359.0, 1.0) + 2.0).abs() < 1e-12);
    }
}
