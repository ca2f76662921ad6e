//! The camera model behind a plate calibration: a lens (radial k1, k2 and tangential p1, p2
//! about a distortion centre) in front of a plane (a homography to plate millimetres), fitted to
//! grid points by Levenberg-Marquardt.
//!
//! Why not `cv::calibrateCamera`: it fits a focal length and a pose per view, which one view of
//! a flat plate does not determine (the focal length and the plate's distance trade off), so it
//! needs the focal length fixed or several tilted views. A fixed camera over a flat belt needs
//! neither: the pixels only ever have to reach the belt plane, and a homography in place of the
//! pinhole and pose describes that plane exactly. The lens terms are those OpenCV uses (Brown-
//! Conrady), but on coordinates normalised by half the image diagonal about the distortion
//! centre, so that k1 reads the same whatever the lens's focal length: k1 = -0.008 moves the
//! image corners 0.008 x half-diagonal pixels inwards.
//!
//! Pure: no I/O, no OpenCV.

use nalgebra::{DMatrix, DVector, Matrix2, Matrix3, Vector2, Vector3};

/// Lens distortion about a centre; coordinates normalised by `radius_px`.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Lens {
    /// Distortion centre, pixels (OpenCV's convention: pixel centres at integer coordinates).
    pub centre_px: [f64; 2],
    /// The normalising radius, pixels: half the image diagonal.
    pub radius_px: f64,
    /// Radial terms.
    pub k1: f64,
    /// See `k1`.
    pub k2: f64,
    /// Tangential terms (decentring of the lens elements).
    pub p1: f64,
    /// See `p1`.
    pub p2: f64,
}

impl Lens {
    /// No distortion, centred in a `width` x `height` frame.
    pub fn ideal(width: usize, height: usize) -> Self {
        let (w, h) = (width as f64, height as f64);
        Lens { centre_px: [(w - 1.0) / 2.0, (h - 1.0) / 2.0], radius_px: 0.5 * w.hypot(h), k1: 0.0, k2: 0.0, p1: 0.0, p2: 0.0 }
    }

    /// Undistorted normalised coordinates to distorted ones.
    pub fn distort(&self, u: Vector2<f64>) -> Vector2<f64> {
        let (x, y) = (u.x, u.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        Vector2::new(
            x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x),
            y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y,
        )
    }

    fn distort_jacobian(&self, u: Vector2<f64>) -> Matrix2<f64> {
        let (x, y) = (u.x, u.y);
        let r2 = x * x + y * y;
        let radial = 1.0 + self.k1 * r2 + self.k2 * r2 * r2;
        let dr = self.k1 + 2.0 * self.k2 * r2; // d radial / d r2
        Matrix2::new(
            radial + 2.0 * x * x * dr + 2.0 * self.p1 * y + 6.0 * self.p2 * x,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            2.0 * x * y * dr + 2.0 * self.p1 * x + 2.0 * self.p2 * y,
            radial + 2.0 * y * y * dr + 6.0 * self.p1 * y + 2.0 * self.p2 * x,
        )
    }

    /// Distorted normalised coordinates to undistorted ones (Newton's method; None where the
    /// model folds over, far outside any frame it was fitted on).
    pub fn undistort(&self, d: Vector2<f64>) -> Option<Vector2<f64>> {
        let mut u = d;
        for _ in 0..30 {
            let e = self.distort(u) - d;
            if e.norm() < 1e-13 {
                return Some(u);
            }
            let step = self.distort_jacobian(u).try_inverse()? * e;
            u -= step;
            if !u.x.is_finite() || !u.y.is_finite() {
                return None;
            }
        }
        ((self.distort(u) - d).norm() < 1e-9).then_some(u)
    }

    /// A pixel to undistorted normalised coordinates.
    pub fn normalise(&self, px: Vector2<f64>) -> Option<Vector2<f64>> {
        self.undistort((px - Vector2::from(self.centre_px)) / self.radius_px)
    }

    /// Undistorted normalised coordinates to a pixel.
    pub fn pixel(&self, u: Vector2<f64>) -> Vector2<f64> {
        Vector2::from(self.centre_px) + self.distort(u) * self.radius_px
    }

    /// How far the lens moves a pixel at the frame corner farthest from its centre, pixels.
    pub fn corner_shift_px(&self, width: usize, height: usize) -> f64 {
        let corners = [(0.0, 0.0), (width as f64 - 1.0, 0.0), (0.0, height as f64 - 1.0), (width as f64 - 1.0, height as f64 - 1.0)];
        corners
            .iter()
            .filter_map(|&(x, y)| {
                let p = Vector2::new(x, y);
                self.normalise(p).map(|u| (p - (Vector2::from(self.centre_px) + u * self.radius_px)).norm())
            })
            .fold(0.0, f64::max)
    }
}

/// The homography carrying each point's first two coordinates onto its last two (a direct linear
/// transform on Hartley-normalised points), scaled so that its last entry is 1; None when the
/// points do not determine one (fewer than four, on a line, repeated).
pub fn homography(points: &[[f64; 4]]) -> Option<Matrix3<f64>> {
    if points.len() < 4 {
        return None;
    }
    let src: Vec<(f64, f64)> = points.iter().map(|p| (p[0], p[1])).collect();
    let dst: Vec<(f64, f64)> = points.iter().map(|p| (p[2], p[3])).collect();
    let (ts, td) = (normaliser(&src), normaliser(&dst));
    let n = points.len();
    let mut a = DMatrix::<f64>::zeros(2 * n, 9);
    for i in 0..n {
        let s = ts * Vector3::new(src[i].0, src[i].1, 1.0);
        let d = td * Vector3::new(dst[i].0, dst[i].1, 1.0);
        let (x, y, u, v) = (s.x / s.z, s.y / s.z, d.x / d.z, d.y / d.z);
        let r1 = [-x, -y, -1.0, 0.0, 0.0, 0.0, u * x, u * y, u];
        let r2 = [0.0, 0.0, 0.0, -x, -y, -1.0, v * x, v * y, v];
        for j in 0..9 {
            a[(2 * i, j)] = r1[j];
            a[(2 * i + 1, j)] = r2[j];
        }
    }
    // The null vector of A: the right singular vector of the smallest singular value.
    let ata = a.transpose() * &a;
    let eig = ata.symmetric_eigen();
    let (k, &smallest) = eig.eigenvalues.iter().enumerate().min_by(|x, y| x.1.total_cmp(y.1))?;
    let mut sorted: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    sorted.sort_by(f64::total_cmp);
    // A unique solution needs the second-smallest eigenvalue clearly above the smallest.
    if !(sorted[1] > 1e-9 && smallest <= sorted[1] * 1e-3 + 1e-12) {
        return None;
    }
    let hv = eig.eigenvectors.column(k);
    let hn = Matrix3::new(hv[0], hv[1], hv[2], hv[3], hv[4], hv[5], hv[6], hv[7], hv[8]);
    let mut h = td.try_inverse()? * hn * ts;
    if h[(2, 2)].abs() < 1e-15 {
        return None;
    }
    h /= h[(2, 2)];
    Some(h)
}

/// Normalisation (Hartley): centre on the mean, scale to mean distance sqrt(2).
fn normaliser(pts: &[(f64, f64)]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
    let d = pts.iter().map(|p| (p.0 - mx).hypot(p.1 - my)).sum::<f64>() / n;
    let s = if d > 0.0 { std::f64::consts::SQRT_2 / d } else { 1.0 };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// Applies a homography to a point.
pub fn project(h: &Matrix3<f64>, p: Vector2<f64>) -> Vector2<f64> {
    let v = h * Vector3::new(p.x, p.y, 1.0);
    Vector2::new(v.x / v.z, v.y / v.z)
}

/// A fixed camera over a plane: pixels to plane millimetres and back.
#[derive(Debug, Clone, PartialEq)]
pub struct PlaneCamera {
    /// The lens.
    pub lens: Lens,
    /// Plate millimetres to undistorted normalised coordinates.
    pub plane: Matrix3<f64>,
    /// Its inverse (undistorted normalised coordinates to plate millimetres).
    pub plane_inv: Matrix3<f64>,
}

impl PlaneCamera {
    /// The camera of a lens and a plane map (None when the map is singular).
    pub fn new(lens: Lens, plane: Matrix3<f64>) -> Option<Self> {
        let plane_inv = plane.try_inverse()?;
        Some(PlaneCamera { lens, plane, plane_inv })
    }

    /// A pixel to plate millimetres.
    pub fn to_plane(&self, px: Vector2<f64>) -> Option<Vector2<f64>> {
        self.lens.normalise(px).map(|u| project(&self.plane_inv, u))
    }

    /// Plate millimetres to a pixel.
    pub fn to_pixel(&self, mm: Vector2<f64>) -> Vector2<f64> {
        self.lens.pixel(project(&self.plane, mm))
    }
}

/// The grid points one image shows: pixel and plate millimetres, in the same order.
#[derive(Debug, Clone)]
pub struct View {
    /// Where each point was found, pixels.
    pub pixels: Vec<Vector2<f64>>,
    /// Where it lies on the plate, millimetres.
    pub plate: Vec<Vector2<f64>>,
}

/// A fitted camera and how well it fits.
#[derive(Debug, Clone)]
pub struct PlateFit {
    /// The camera; its plane is the first view's plate.
    pub camera: PlaneCamera,
    /// Root mean square distance between found and modelled grid points, pixels.
    pub rms_px: f64,
    /// Largest distance between a found point mapped to the plate and its true place, mm.
    pub residual_mm_max: f64,
    /// Median of the same, mm.
    pub residual_mm_median: f64,
    /// Grid points used.
    pub points: usize,
    /// Per later view: how its plate lies in the first view's plate frame (rotation, degrees;
    /// shift, mm; mirrored when the grid finder numbered it the other way round).
    pub placements: Vec<(f64, Vector2<f64>, bool)>,
}

/// Why no camera fits.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum FitError {
    /// Too few points for the model.
    #[error("{0} grid points are too few for a lens and a plane (at least 20, spread over the field)")]
    TooFew(usize),
    /// The points are degenerate (on a line, repeated).
    #[error("the grid points of view {0} do not determine a plane (on a line or repeated)")]
    Degenerate(usize),
    /// The fit did not settle.
    #[error("the lens fit did not converge (RMS {0:.3} px): are the grid's columns, rows and pitch right?")]
    Diverged(f64),
}

/// The parameter vector: lens (centre x, y in pixels / radius; k1, k2, p1, p2), the first view's
/// plane (8 entries, h33 = 1, on normalised plate coordinates), then per later view an in-plane
/// rotation and shift (normalised plate units).
struct Layout {
    views: usize,
}

impl Layout {
    fn len(&self) -> usize {
        6 + 8 + 3 * (self.views - 1)
    }
}

/// Fits a lens and a plane to the grid points of one or more views of a plate lying on the same
/// plane (moved between views, never tilted): one view that covers most of the frame is enough.
pub fn fit_plate(views: &[View], width: usize, height: usize) -> Result<PlateFit, FitError> {
    let points: usize = views.iter().map(|v| v.pixels.len()).sum();
    if points < 20 || views.is_empty() {
        return Err(FitError::TooFew(points));
    }
    let ideal = Lens::ideal(width, height);
    let r = ideal.radius_px;
    // Plate coordinates normalised (centred on the first view's points, unit spread) so the
    // plane's entries are of one order of magnitude.
    let first = &views[0].plate;
    let n0 = first.len() as f64;
    let mean = first.iter().fold(Vector2::zeros(), |a, p| a + p) / n0;
    let spread = (first.iter().map(|p| (p - mean).norm_squared()).sum::<f64>() / n0).sqrt().max(1e-9);
    let norm = Matrix3::new(1.0 / spread, 0.0, -mean.x / spread, 0.0, 1.0 / spread, -mean.y / spread, 0.0, 0.0, 1.0);
    let plate_n: Vec<Vec<Vector2<f64>>> = views.iter().map(|v| v.plate.iter().map(|p| project(&norm, *p)).collect()).collect();
    // Start: no distortion, each view's own homography; later views placed by Procrustes.
    let dlt = |i: usize| -> Result<Matrix3<f64>, FitError> {
        let pairs: Vec<[f64; 4]> = plate_n[i]
            .iter()
            .zip(&views[i].pixels)
            .map(|(p, q)| {
                let u = ideal.normalise(*q).unwrap_or_default();
                [p.x, p.y, u.x, u.y]
            })
            .collect();
        homography(&pairs).ok_or(FitError::Degenerate(i))
    };
    let h0 = dlt(0)?;
    let h0_inv = h0.try_inverse().ok_or(FitError::Degenerate(0))?;
    let layout = Layout { views: views.len() };
    let mut x = DVector::<f64>::zeros(layout.len());
    x[0] = ideal.centre_px[0] / r;
    x[1] = ideal.centre_px[1] / r;
    for k in 0..8 {
        x[6 + k] = h0[(k / 3, k % 3)];
    }
    let mut mirrored = vec![false; views.len()];
    for i in 1..views.len() {
        let hi = dlt(i)?;
        // Where view i's points lie in view 0's plate frame, from the two homographies.
        let placed: Vec<Vector2<f64>> = plate_n[i].iter().map(|p| project(&h0_inv, project(&hi, *p))).collect();
        let (angle, shift, mirror) = procrustes(&plate_n[i], &placed);
        mirrored[i] = mirror;
        let o = 14 + 3 * (i - 1);
        x[o] = angle;
        x[o + 1] = shift.x;
        x[o + 2] = shift.y;
    }
    let model = |x: &DVector<f64>| -> (Lens, Matrix3<f64>) {
        let lens = Lens { centre_px: [x[0] * r, x[1] * r], radius_px: r, k1: x[2], k2: x[3], p1: x[4], p2: x[5] };
        let h = Matrix3::new(x[6], x[7], x[8], x[9], x[10], x[11], x[12], x[13], 1.0);
        (lens, h)
    };
    let place = |x: &DVector<f64>, i: usize, p: Vector2<f64>| -> Vector2<f64> {
        if i == 0 {
            return p;
        }
        let o = 14 + 3 * (i - 1);
        let q = if mirrored[i] { Vector2::new(p.x, -p.y) } else { p };
        let (s, c) = x[o].sin_cos();
        Vector2::new(c * q.x - s * q.y + x[o + 1], s * q.x + c * q.y + x[o + 2])
    };
    let residuals = |x: &DVector<f64>| -> DVector<f64> {
        let (lens, h) = model(x);
        let mut out = DVector::zeros(2 * points);
        let mut k = 0;
        for (i, v) in views.iter().enumerate() {
            for (p, q) in plate_n[i].iter().zip(&v.pixels) {
                let m = lens.pixel(project(&h, place(x, i, *p)));
                let e = (m - q) / r;
                out[k] = e.x;
                out[k + 1] = e.y;
                k += 2;
            }
        }
        out
    };
    let x = levenberg_marquardt(x, &residuals);
    let res = residuals(&x);
    let rms_px = (res.norm_squared() / points as f64).sqrt() * r;
    if !rms_px.is_finite() || rms_px > 5.0 {
        return Err(FitError::Diverged(rms_px));
    }
    let (lens, hn) = model(&x);
    let plane = hn * norm;
    let camera = PlaneCamera::new(lens, plane).ok_or(FitError::Degenerate(0))?;
    // Residuals on the plate, in millimetres: each found point taken through the fitted camera.
    let norm_inv = norm.try_inverse().ok_or(FitError::Degenerate(0))?;
    let mut mm: Vec<f64> = Vec::with_capacity(points);
    let mut placements = Vec::new();
    for (i, v) in views.iter().enumerate() {
        if i > 0 {
            let o = 14 + 3 * (i - 1);
            let shift = project(&norm_inv, Vector2::new(x[o + 1], x[o + 2])) - project(&norm_inv, Vector2::zeros());
            placements.push((x[o].to_degrees(), shift, mirrored[i]));
        }
        for (p, q) in v.plate.iter().zip(&v.pixels) {
            let truth = project(&norm_inv, place(&x, i, project(&norm, *p)));
            mm.push(camera.to_plane(*q).map(|m| (m - truth).norm()).unwrap_or(f64::INFINITY));
        }
    }
    mm.sort_by(f64::total_cmp);
    let residual_mm_max = mm.last().copied().unwrap_or(0.0);
    let residual_mm_median = mm[mm.len() / 2];
    Ok(PlateFit { camera, rms_px, residual_mm_max, residual_mm_median, points, placements })
}

/// Least squares by Levenberg-Marquardt with a forward-difference Jacobian (the parameters are
/// few and the residuals cheap; an analytic Jacobian would be code to get wrong for no gain).
fn levenberg_marquardt(mut x: DVector<f64>, f: &dyn Fn(&DVector<f64>) -> DVector<f64>) -> DVector<f64> {
    let mut r = f(&x);
    let mut cost = r.norm_squared();
    let mut mu = 1e-3;
    for _ in 0..200 {
        let n = x.len();
        let mut j = DMatrix::<f64>::zeros(r.len(), n);
        for k in 0..n {
            let h = 1e-7 * x[k].abs().max(1e-3);
            let mut xk = x.clone();
            xk[k] += h;
            let col = (f(&xk) - &r) / h;
            j.set_column(k, &col);
        }
        let jtj = j.transpose() * &j;
        let g = j.transpose() * &r;
        let mut improved = false;
        for _ in 0..12 {
            let mut a = jtj.clone();
            for k in 0..n {
                a[(k, k)] += mu * jtj[(k, k)].max(1e-12);
            }
            let Some(step) = a.cholesky().map(|c| c.solve(&g)) else {
                mu *= 10.0;
                continue;
            };
            let xn = &x - &step;
            let rn = f(&xn);
            let cn = rn.norm_squared();
            if cn.is_finite() && cn < cost {
                let rel = (cost - cn) / cost.max(1e-300);
                x = xn;
                r = rn;
                cost = cn;
                mu = (mu / 3.0).max(1e-12);
                improved = true;
                if rel < 1e-12 {
                    return x;
                }
                break;
            }
            mu *= 10.0;
        }
        if !improved {
            break;
        }
    }
    x
}

/// The rotation (radians), shift and mirror that best carry points `a` onto `b` (least squares,
/// unit scale): Kabsch in the plane, both handednesses tried.
pub fn procrustes(a: &[Vector2<f64>], b: &[Vector2<f64>]) -> (f64, Vector2<f64>, bool) {
    let pick = either_hand(a, b, false);
    (pick.angle, pick.shift, pick.mirrored)
}

/// [`similarity`] with the hand (mirrored or not) that fits better.
pub fn either_hand(a: &[Vector2<f64>], b: &[Vector2<f64>], scaled: bool) -> Similarity {
    let plain = similarity(a, b, scaled, false);
    let mirrored = similarity(a, b, scaled, true);
    if mirrored.rms < plain.rms { mirrored } else { plain }
}

/// A plane-to-plane similarity: optional mirror (y negated first), rotation, scale, shift.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Similarity {
    /// Counter-clockwise rotation, radians.
    pub angle: f64,
    /// Scale (1 for a rigid fit).
    pub scale: f64,
    /// Applied last.
    pub shift: Vector2<f64>,
    /// y negated before rotating.
    pub mirrored: bool,
    /// RMS residual over the points fitted, in `b`'s units.
    pub rms: f64,
}

impl Similarity {
    /// Maps a point.
    pub fn apply(&self, p: Vector2<f64>) -> Vector2<f64> {
        let q = if self.mirrored { Vector2::new(p.x, -p.y) } else { p };
        let (s, c) = self.angle.sin_cos();
        Vector2::new(c * q.x - s * q.y, s * q.x + c * q.y) * self.scale + self.shift
    }

    /// The point that maps to `p`.
    pub fn invert(&self, p: Vector2<f64>) -> Vector2<f64> {
        let q = (p - self.shift) / self.scale;
        let (s, c) = self.angle.sin_cos();
        let r = Vector2::new(c * q.x + s * q.y, -s * q.x + c * q.y);
        if self.mirrored { Vector2::new(r.x, -r.y) } else { r }
    }
}

/// Least-squares similarity (or rigid, `scaled` false) of `a` onto `b`, with or without a mirror.
pub fn similarity(a: &[Vector2<f64>], b: &[Vector2<f64>], scaled: bool, mirrored: bool) -> Similarity {
    let n = a.len().max(1) as f64;
    let a: Vec<Vector2<f64>> = a.iter().map(|p| if mirrored { Vector2::new(p.x, -p.y) } else { *p }).collect();
    let ma = a.iter().fold(Vector2::zeros(), |s, p| s + p) / n;
    let mb = b.iter().fold(Vector2::zeros(), |s, p| s + p) / n;
    let (mut dot, mut cross, mut aa) = (0.0, 0.0, 0.0);
    for (p, q) in a.iter().zip(b) {
        let (p, q) = (p - ma, q - mb);
        dot += p.dot(&q);
        cross += p.x * q.y - p.y * q.x;
        aa += p.norm_squared();
    }
    let angle = cross.atan2(dot);
    let scale = if scaled && aa > 0.0 { dot.hypot(cross) / aa } else { 1.0 };
    let (s, c) = angle.sin_cos();
    let rot = |p: Vector2<f64>| Vector2::new(c * p.x - s * p.y, s * p.x + c * p.y) * scale;
    let shift = mb - rot(ma);
    let sq: f64 = a.iter().zip(b).map(|(p, q)| (rot(*p) + shift - q).norm_squared()).sum();
    Similarity { angle, scale, shift, mirrored, rms: (sq / n).sqrt() }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell_lens() -> Lens {
        Lens { centre_px: [1326.5, 950.0], radius_px: 0.5 * 2592f64.hypot(1944.0), k1: -0.008, k2: -0.0005, p1: 2e-4, p2: -1e-4 }
    }

    #[test]
    fn undistort_inverts_distort_over_the_frame() {
        let lens = cell_lens();
        for &(x, y) in &[(0.0, 0.0), (2591.0, 1943.0), (100.0, 1800.0), (1296.0, 972.0)] {
            let p = Vector2::new(x, y);
            let back = lens.pixel(lens.normalise(p).unwrap());
            assert!((back - p).norm() < 1e-8, "{p:?} -> {back:?}");
        }
        // 13.8 px at the half-diagonal; the farthest corner of an off-centre lens moves more.
        let shift = lens.corner_shift_px(2592, 1944);
        assert!((13.8..16.0).contains(&shift), "{shift}");
    }

    #[test]
    fn one_plate_view_recovers_the_lens_and_maps_the_plane_to_hundredths() {
        let lens = cell_lens();
        // A slightly tilted plane: plate mm -> normalised coordinates.
        let plane = Matrix3::new(0.0040, 0.0001, -0.78, -0.0001, 0.0040, -0.58, 1e-6, -2e-6, 1.0);
        let truth = PlaneCamera::new(lens, plane).unwrap();
        let mut view = View { pixels: vec![], plate: vec![] };
        for j in 0..18 {
            for i in 0..24 {
                let p = Vector2::new(i as f64 * 15.0 + 20.0, j as f64 * 15.0 + 15.0);
                view.plate.push(p);
                view.pixels.push(truth.to_pixel(p));
            }
        }
        let fit = fit_plate(std::slice::from_ref(&view), 2592, 1944).unwrap();
        assert!(fit.rms_px < 1e-4, "{}", fit.rms_px);
        assert!((fit.camera.lens.k1 / lens.k1 - 1.0).abs() < 0.05, "k1 {}", fit.camera.lens.k1);
        assert!(fit.residual_mm_max < 1e-3, "{}", fit.residual_mm_max);
        // Anywhere in the frame, not just at the grid points.
        for &(x, y) in &[(5.0, 5.0), (2580.0, 1930.0), (1000.0, 700.0)] {
            let p = Vector2::new(x, y);
            let d = (fit.camera.to_plane(p).unwrap() - truth.to_plane(p).unwrap()).norm();
            assert!(d < 0.01, "{p:?}: {d} mm");
        }
    }

    #[test]
    fn a_second_view_moved_on_the_plane_joins_the_fit() {
        let lens = cell_lens();
        let plane = Matrix3::new(0.0040, 0.0, -0.7, 0.0, 0.0040, -0.5, 0.0, 0.0, 1.0);
        let truth = PlaneCamera::new(lens, plane).unwrap();
        let moved = |p: Vector2<f64>| {
            let (s, c) = 0.1f64.sin_cos();
            Vector2::new(c * p.x - s * p.y + 30.0, s * p.x + c * p.y - 12.0)
        };
        let mut views = vec![View { pixels: vec![], plate: vec![] }, View { pixels: vec![], plate: vec![] }];
        for j in 0..10 {
            for i in 0..14 {
                let p = Vector2::new(i as f64 * 15.0, j as f64 * 15.0);
                views[0].plate.push(p);
                views[0].pixels.push(truth.to_pixel(p + Vector2::new(10.0, 8.0)));
                views[1].plate.push(p);
                views[1].pixels.push(truth.to_pixel(moved(p) + Vector2::new(150.0, 120.0)));
            }
        }
        let fit = fit_plate(&views, 2592, 1944).unwrap();
        assert!(fit.rms_px < 1e-4, "{}", fit.rms_px);
        assert!((fit.camera.lens.k1 / lens.k1 - 1.0).abs() < 0.05, "k1 {}", fit.camera.lens.k1);
        let (deg, _, mirrored) = fit.placements[0];
        assert!((deg - 0.1f64.to_degrees()).abs() < 1e-3 && !mirrored, "{deg}");
    }

    #[test]
    fn a_mirrored_similarity_is_found_and_measured() {
        let a: Vec<Vector2<f64>> = [(0.0, 0.0), (100.0, 0.0), (0.0, 80.0), (60.0, 50.0)].iter().map(|&(x, y)| Vector2::new(x, y)).collect();
        let truth = Similarity { angle: 0.7, scale: 1.003, shift: Vector2::new(500.0, -20.0), mirrored: true, rms: 0.0 };
        let b: Vec<Vector2<f64>> = a.iter().map(|p| truth.apply(*p)).collect();
        let fit = similarity(&a, &b, true, true);
        assert!((fit.invert(b[3]) - a[3]).norm() < 1e-9, "invert undoes apply");
        assert!(fit.rms < 1e-9 && (fit.angle - 0.7).abs() < 1e-9 && (fit.scale - 1.003).abs() < 1e-9);
        assert!(similarity(&a, &b, true, false).rms > 1.0, "the wrong hand does not fit");
        let rigid = similarity(&a, &b, false, true);
        assert!(rigid.rms > 0.05 && rigid.scale == 1.0, "{}", rigid.rms);
    }
}
