//! Pixel to robot-frame millimetres: a homography fitted to point pairs, or a plain scale.

use nalgebra::{DMatrix, Matrix3, Vector3};

use crate::config::CalibrationConfig;

/// A fitted mapping from frame pixels to robot millimetres.
#[derive(Debug, Clone, PartialEq)]
pub enum Calibration {
    /// x_mm = x_px * s, y_mm = y_px * s; angles keep the image convention (counter-clockwise as
    /// displayed).
    Scale(f64),
    /// Projective map; the angle is the direction of the part's axis mapped into the robot frame,
    /// counter-clockwise from robot +X towards robot +Y.
    Homography {
        /// Pixels (x, y, 1) to millimetres (x, y, w), up to scale.
        h: Matrix3<f64>,
        /// RMS residual over the touched-up points, mm.
        rms_mm: f64,
        /// Largest residual over the touched-up points, mm.
        max_mm: f64,
    },
}

/// Why a calibration cannot be made from the configured points.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum CalibrationError {
    /// Fewer than four point pairs (the number given).
    #[error("calibration needs at least 4 point pairs, got {0}")]
    TooFew(usize),
    /// No homography fits the points.
    #[error("calibration points are degenerate (three or more on a line, or repeated): no homography fits")]
    Degenerate,
}

impl Calibration {
    /// The calibration the configuration describes (a homography is fitted to its points).
    pub fn from_config(c: &CalibrationConfig) -> Result<Self, CalibrationError> {
        match c {
            CalibrationConfig::Scale { mm_per_px } => Ok(Calibration::Scale(*mm_per_px)),
            CalibrationConfig::Points(p) => fit(p),
        }
    }

    /// Maps a pixel position and an image angle (degrees, counter-clockwise as displayed).
    pub fn apply(&self, x: f64, y: f64, angle_deg: f64) -> (f64, f64, f64) {
        match self {
            Calibration::Scale(s) => (x * s, y * s, angle_deg),
            Calibration::Homography { h, .. } => {
                let (mx, my) = project(h, x, y);
                // Direction of the part's axis in the image (y down), mapped by the local Jacobian.
                let a = angle_deg.to_radians();
                let (dx, dy) = (a.cos(), -a.sin());
                let e = 1e-3;
                let (px, py) = project(h, x + dx * e, y + dy * e);
                (mx, my, (py - my).atan2(px - mx).to_degrees())
            }
        }
    }

    /// One line for the start-up log.
    pub fn describe(&self) -> String {
        match self {
            Calibration::Scale(s) => format!("scale {s} mm/px (no homography: robot frame = image frame scaled)"),
            Calibration::Homography { rms_mm, max_mm, .. } => format!("homography, fit residual RMS {rms_mm:.3} mm, max {max_mm:.3} mm"),
        }
    }
}

fn project(h: &Matrix3<f64>, x: f64, y: f64) -> (f64, f64) {
    let v = h * Vector3::new(x, y, 1.0);
    (v.x / v.z, v.y / v.z)
}

/// Normalisation (Hartley): centre on the mean, scale to mean distance sqrt(2).
fn normaliser(pts: &[(f64, f64)]) -> Matrix3<f64> {
    let n = pts.len() as f64;
    let (mx, my) = pts.iter().fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
    let d = pts.iter().map(|p| (p.0 - mx).hypot(p.1 - my)).sum::<f64>() / n;
    let s = if d > 0.0 { std::f64::consts::SQRT_2 / d } else { 1.0 };
    Matrix3::new(s, 0.0, -s * mx, 0.0, s, -s * my, 0.0, 0.0, 1.0)
}

/// Direct linear transform with normalisation; residuals in millimetres.
pub fn fit(points: &[[f64; 4]]) -> Result<Calibration, CalibrationError> {
    if points.len() < 4 {
        return Err(CalibrationError::TooFew(points.len()));
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
    let (k, &smallest) = eig.eigenvalues.iter().enumerate().min_by(|x, y| x.1.total_cmp(y.1)).ok_or(CalibrationError::Degenerate)?;
    let mut sorted: Vec<f64> = eig.eigenvalues.iter().copied().collect();
    sorted.sort_by(f64::total_cmp);
    // A unique solution needs the second-smallest eigenvalue clearly above the smallest.
    if !(sorted[1] > 1e-9 && smallest <= sorted[1] * 1e-3 + 1e-12) {
        return Err(CalibrationError::Degenerate);
    }
    let hv = eig.eigenvectors.column(k);
    let hn = Matrix3::new(hv[0], hv[1], hv[2], hv[3], hv[4], hv[5], hv[6], hv[7], hv[8]);
    let td_inv = td.try_inverse().ok_or(CalibrationError::Degenerate)?;
    let mut h = td_inv * hn * ts;
    if h[(2, 2)].abs() < 1e-15 {
        return Err(CalibrationError::Degenerate);
    }
    h /= h[(2, 2)];
    let mut sq = 0.0;
    let mut max: f64 = 0.0;
    for p in points {
        let (x, y) = project(&h, p[0], p[1]);
        let e = (x - p[2]).hypot(y - p[3]);
        sq += e * e;
        max = max.max(e);
    }
    if !sq.is_finite() {
        return Err(CalibrationError::Degenerate);
    }
    Ok(Calibration::Homography { h, rms_mm: (sq / n as f64).sqrt(), max_mm: max })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_a_rotated_scaled_flipped_frame_exactly() {
        // Robot frame: 0.2 mm/px, Y up (image y flipped), rotated 30 degrees, offset.
        let (s, th, ox, oy) = (0.2f64, 30f64.to_radians(), 400.0, -120.0);
        let to_robot = |x: f64, y: f64| {
            let (u, v) = (x * s, -y * s);
            (ox + u * th.cos() - v * th.sin(), oy + u * th.sin() + v * th.cos())
        };
        let pts: Vec<[f64; 4]> = [(0.0, 0.0), (2591.0, 0.0), (2591.0, 1943.0), (0.0, 1943.0), (1300.0, 900.0)]
            .iter()
            .map(|&(x, y)| {
                let (u, v) = to_robot(x, y);
                [x, y, u, v]
            })
            .collect();
        let cal = fit(&pts).unwrap();
        let Calibration::Homography { rms_mm, .. } = &cal else { panic!() };
        assert!(*rms_mm < 1e-6);
        let (x, y, a) = cal.apply(1000.0, 500.0, 10.0);
        let (ex, ey) = to_robot(1000.0, 500.0);
        assert!((x - ex).abs() < 1e-6 && (y - ey).abs() < 1e-6);
        // Image CCW-as-displayed 10 deg, seen in a Y-up frame rotated by 30: 40 deg.
        assert!((a - 40.0).abs() < 1e-6, "{a}");
    }

    #[test]
    fn rejects_degenerate_points() {
        let line: Vec<[f64; 4]> = (0..5).map(|i| [i as f64, 0.0, i as f64, 0.0]).collect();
        assert_eq!(fit(&line).unwrap_err(), CalibrationError::Degenerate);
        assert_eq!(fit(&line[..3]).unwrap_err(), CalibrationError::TooFew(3));
    }
}
