//! Pixel to robot-frame millimetres: a plate calibration (lens and plane, from `calibrate`)
//! placed in the robot frame by touched-up points, a homography fitted to point pairs, or a
//! plain scale.

use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector2};

use crate::config::CalibrationConfig;
use crate::lens::{self, Lens, PlaneCamera, Similarity};
use crate::vision::Pt;

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
    /// A plate calibration's lens and plane, then the plate-to-robot similarity fitted to
    /// touched-up points.
    Plate(Box<PlateCalibration>),
}

/// A plate calibration in force: [`PlateFile`]'s camera placed in the robot frame.
#[derive(Debug, Clone, PartialEq)]
pub struct PlateCalibration {
    /// Where it came from.
    pub file: PathBuf,
    /// The plate file as read.
    pub plate: PlateFile,
    /// Pixels to plate millimetres.
    pub camera: PlaneCamera,
    /// Plate millimetres to robot millimetres.
    pub robot: Similarity,
    /// The robot frame was fitted with a free scale (`fit = "similarity"`), not rigidly: as
    /// configured, not read back from a scale that happened to come out 1.
    pub scaled: bool,
    /// Each touched-up point's distance from where the fit puts it, mm, in the configured order.
    pub residuals_mm: Vec<f64>,
}

/// The file `lfi-bridge calibrate` writes: a camera model of the belt plane, versioned like the
/// knowledge base. Human-readable so a commissioning engineer can see k1 and the residuals.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateFile {
    /// Always "lfi-bridge plate calibration".
    pub format: String,
    /// [`PLATE_FILE_VERSION`].
    pub version: u32,
    /// Frame width the calibration was made on, pixels; frames of another size are refused.
    pub width: usize,
    /// Frame height, pixels.
    pub height: usize,
    /// The lens (coordinates normalised by `radius_px` about `centre_px`).
    pub lens: Lens,
    /// Plate millimetres to undistorted normalised coordinates, row-major.
    pub plane: [[f64; 3]; 3],
    /// The plate.
    pub grid: PlateGrid,
    /// How well the model fits the plate.
    pub fit: PlateFitRecord,
}

/// The plate a calibration was made with.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateGrid {
    /// circles, asymmetric-circles or chessboard.
    pub kind: String,
    /// Points per row.
    pub cols: usize,
    /// Rows.
    pub rows: usize,
    /// Pitch, mm.
    pub pitch_mm: f64,
}

/// The fit's figures, as `calibrate` printed them.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateFitRecord {
    /// The images given, in order.
    pub images: Vec<String>,
    /// How many had the grid found.
    pub images_used: usize,
    /// Grid points fitted.
    pub points: usize,
    /// Reprojection RMS, pixels.
    pub rms_px: f64,
    /// Median distance of a found point, mapped to the plate, from its true place, mm.
    pub residual_mm_median: f64,
    /// Largest such distance, mm.
    pub residual_mm_max: f64,
}

/// The plate file format this build writes and reads.
pub const PLATE_FILE_VERSION: u32 = 1;
const PLATE_FILE_FORMAT: &str = "lfi-bridge plate calibration";

impl PlateFile {
    /// The camera it describes.
    pub fn camera(&self) -> Option<PlaneCamera> {
        let p = self.plane;
        PlaneCamera::new(self.lens, Matrix3::new(p[0][0], p[0][1], p[0][2], p[1][0], p[1][1], p[1][2], p[2][0], p[2][1], p[2][2]))
    }

    /// Reads and checks a plate file.
    pub fn load(path: &Path) -> Result<Self, CalibrationError> {
        let bad = |message: String| CalibrationError::File { path: path.to_path_buf(), message };
        let text = std::fs::read_to_string(path).map_err(|e| bad(e.to_string()))?;
        let f: PlateFile = toml::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if f.format != PLATE_FILE_FORMAT {
            return Err(bad(format!("format {:?} is not {PLATE_FILE_FORMAT:?}", f.format)));
        }
        if f.version != PLATE_FILE_VERSION {
            return Err(bad(format!("version {} is not supported (this build reads version {PLATE_FILE_VERSION})", f.version)));
        }
        let l = f.lens;
        let numbers = [l.centre_px[0], l.centre_px[1], l.radius_px, l.k1, l.k2, l.p1, l.p2];
        if numbers.iter().chain(f.plane.iter().flatten()).any(|v| !v.is_finite()) || l.radius_px <= 0.0 {
            return Err(bad("the lens or plane holds a number that is not finite (or a radius <= 0)".into()));
        }
        if f.width < 32 || f.height < 32 {
            return Err(bad(format!("frame size {} x {} is too small", f.width, f.height)));
        }
        if f.camera().is_none() {
            return Err(bad("the plane map is singular".into()));
        }
        Ok(f)
    }

    /// Writes it as TOML, with a header saying what it is.
    pub fn to_toml(&self) -> Result<String, toml::ser::Error> {
        Ok(format!(
            "# Written by `lfi-bridge calibrate`: the camera's lens and the belt plane, from a grid plate.\n# Pixels: OpenCV's convention (pixel centres at integer coordinates).\n{}",
            toml::to_string(self)?
        ))
    }

    /// A plate file for a fitted camera.
    pub fn new(camera: &PlaneCamera, width: usize, height: usize, grid: PlateGrid, fit: PlateFitRecord) -> Self {
        let h = camera.plane;
        PlateFile {
            format: PLATE_FILE_FORMAT.into(),
            version: PLATE_FILE_VERSION,
            width,
            height,
            lens: camera.lens,
            plane: [[h[(0, 0)], h[(0, 1)], h[(0, 2)]], [h[(1, 0)], h[(1, 1)], h[(1, 2)]], [h[(2, 0)], h[(2, 1)], h[(2, 2)]]],
            grid,
            fit,
        }
    }
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
    /// The plate file cannot be used.
    #[error("calibration file {}: {message}", path.display())]
    File {
        /// The file.
        path: PathBuf,
        /// Why.
        message: String,
    },
    /// Fewer than three touched-up points for a plate calibration.
    #[error("a plate calibration needs at least 3 touched-up points (calibration.points), got {0}")]
    TooFewTouchUps(usize),
    /// The touched-up points lie on a line (or on top of each other).
    #[error("calibration.points lie on a line or on top of each other: they do not fix the robot frame (spread them over the field)")]
    Collinear,
    /// A touched-up point lies outside the lens model's reach.
    #[error("calibration.points[{index}] at ({x_px}, {y_px}) px is outside the frame the plate calibration covers")]
    OutsideModel {
        /// Its index in `calibration.points`.
        index: usize,
        /// Its pixel x.
        x_px: f64,
        /// Its pixel y.
        y_px: f64,
    },
    /// One touched-up point disagrees with the others.
    #[error(
        "calibration.points[{index}] ({x_px}, {y_px}) px -> ({x_mm}, {y_mm}) mm is {off_mm:.3} mm from where the other points put it (limit max_point_error_mm = {limit_mm}): touch it up again or remove it"
    )]
    PointDisagrees {
        /// Its index in `calibration.points`.
        index: usize,
        /// Its pixel x.
        x_px: f64,
        /// Its pixel y.
        y_px: f64,
        /// Its robot x.
        x_mm: f64,
        /// Its robot y.
        y_mm: f64,
        /// How far off it is, mm.
        off_mm: f64,
        /// The configured limit, mm.
        limit_mm: f64,
    },
}

/// A frame of another size than the plate calibration was made on.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "frame is {width} x {height} pixels but the plate calibration was made on {} x {} frames: no positions in millimetres from it (calibrate again, or restore the camera's size)",
    made_on.0,
    made_on.1
)]
pub struct WrongFrameSize {
    /// The frame's width.
    pub width: usize,
    /// The frame's height.
    pub height: usize,
    /// The size the calibration was made on.
    pub made_on: (usize, usize),
}

impl Calibration {
    /// The calibration the configuration describes (a homography is fitted to its points).
    pub fn from_config(c: &CalibrationConfig) -> Result<Self, CalibrationError> {
        match c {
            CalibrationConfig::Scale { mm_per_px } => Ok(Calibration::Scale(*mm_per_px)),
            CalibrationConfig::Points(p) => fit(p),
            CalibrationConfig::Plate { file, points, scaled, max_point_error_mm } => {
                let plate = PlateFile::load(file)?;
                let camera = plate
                    .camera()
                    .ok_or_else(|| CalibrationError::File { path: file.clone(), message: "the plane map is singular".into() })?;
                let (robot, residuals_mm) = place_in_robot_frame(&camera, points, *scaled, *max_point_error_mm)?;
                Ok(Calibration::Plate(Box::new(PlateCalibration {
                    file: file.clone(),
                    plate,
                    camera,
                    robot,
                    scaled: *scaled,
                    residuals_mm,
                })))
            }
        }
    }

    /// The frame size this calibration holds for (a plate calibration's; None: any).
    pub fn frame_size(&self) -> Option<(usize, usize)> {
        match self {
            Calibration::Plate(p) => Some((p.plate.width, p.plate.height)),
            _ => None,
        }
    }

    /// Whether frames of `width` x `height` may be mapped: a plate calibration holds only for
    /// frames of the size it was made on; another size (a binning or ROI changed on the camera)
    /// would put every part in the wrong place.
    pub fn fits(&self, width: usize, height: usize) -> Result<(), WrongFrameSize> {
        match self.frame_size() {
            Some(made_on) if made_on != (width, height) => Err(WrongFrameSize { width, height, made_on }),
            _ => Ok(()),
        }
    }

    /// Pixels to robot millimetres (None outside the lens model's reach).
    pub fn to_robot(&self, x: f64, y: f64) -> Option<(f64, f64)> {
        match self {
            Calibration::Scale(s) => Some((x * s, y * s)),
            Calibration::Homography { h, .. } => {
                let m = lens::project(h, Vector2::new(x, y));
                Some((m.x, m.y))
            }
            Calibration::Plate(p) => p.camera.to_plane(Vector2::new(x, y)).map(|m| {
                let r = p.robot.apply(m);
                (r.x, r.y)
            }),
        }
    }

    /// Maps a pixel position and an image angle (degrees, counter-clockwise as displayed).
    pub fn apply(&self, x: f64, y: f64, angle_deg: f64) -> (f64, f64, f64) {
        match self {
            Calibration::Scale(s) => (x * s, y * s, angle_deg),
            Calibration::Homography { .. } | Calibration::Plate(_) => {
                let Some((mx, my)) = self.to_robot(x, y) else { return (f64::NAN, f64::NAN, f64::NAN) };
                // Direction of the part's axis in the image (y down), mapped by the local
                // Jacobian (central differences half a pixel either side).
                let a = angle_deg.to_radians();
                let (dx, dy) = (a.cos() * 0.5, -a.sin() * 0.5);
                match (self.to_robot(x - dx, y - dy), self.to_robot(x + dx, y + dy)) {
                    (Some(p0), Some(p1)) => (mx, my, (p1.1 - p0.1).atan2(p1.0 - p0.0).to_degrees()),
                    _ => (mx, my, f64::NAN),
                }
            }
        }
    }

    /// Robot millimetres to a pixel (None where the mapping cannot be inverted there): what the
    /// operator view's grid of robot coordinates is drawn with.
    pub fn to_pixel(&self, x_mm: f64, y_mm: f64) -> Option<(f64, f64)> {
        match self {
            Calibration::Scale(s) => Some((x_mm / s, y_mm / s)),
            Calibration::Homography { h, .. } => {
                let p = lens::project(&h.try_inverse()?, Vector2::new(x_mm, y_mm));
                (p.x.is_finite() && p.y.is_finite()).then_some((p.x, p.y))
            }
            Calibration::Plate(p) => {
                let plate = p.robot.invert(Vector2::new(x_mm, y_mm));
                let px = p.camera.to_pixel(plate);
                (px.x.is_finite() && px.y.is_finite()).then_some((px.x, px.y))
            }
        }
    }

    /// Maps a part's pose to the robot frame. Where the mapping is not a plain scale (a lens, a
    /// tilt), a part's image is not its template moved rigidly: it is stretched by up to a few
    /// percent, differently along and across the radius and more on one side than the other,
    /// and the estimator's rigid fit misplaces the template's origin by that stretch times the
    /// origin's offset from the outline's middle (up to 2 px at the simulated cell's corners,
    /// 0.3 mm). So the part's outline (frame pixels: the measured one for a separate part) is
    /// taken through the calibration into the plane and back to pixels by one similarity fitted
    /// to it (a frame without the stretch), the matched template is registered there again from
    /// the estimate's pose, and that pose's origin and direction go to the robot frame through
    /// the similarity. Without a matched template, the similarity alone maps the position
    /// (the stretch cancelled to first order).
    pub fn apply_part(&self, p: &crate::vision::PartEstimate, estimator: &crate::vision::Estimator) -> (f64, f64, f64) {
        if matches!(self, Calibration::Scale(_)) || p.outline.len() < 8 {
            return self.apply(p.x, p.y, p.angle_deg);
        }
        let mapped: Vec<(Vector2<f64>, Vector2<f64>)> =
            p.outline.iter().filter_map(|q| self.to_robot(q.x, q.y).map(|(u, v)| (Vector2::new(q.x, q.y), Vector2::new(u, v)))).collect();
        if mapped.len() < 8 {
            return self.apply(p.x, p.y, p.angle_deg);
        }
        let step = mapped.len().div_ceil(256);
        let (px, mm): (Vec<Vector2<f64>>, Vec<Vector2<f64>>) = mapped.iter().step_by(step).copied().unzip();
        let f = crate::lens::either_hand(&px, &mm, true);
        let (at, angle_deg) = match p.matched {
            Some((entry, pose)) => {
                let straight: Vec<Pt> = mapped
                    .iter()
                    .map(|(_, m)| {
                        let r = f.invert(*m);
                        Pt::new(r.x, r.y)
                    })
                    .collect();
                let origin = estimator.templates().nth(entry).map(|t| t.origin);
                match (origin, estimator.reregister(entry, &straight, pose)) {
                    (Some(o), Some(again)) => {
                        let at = again.apply(o);
                        (Vector2::new(at.x, at.y), again.angle_deg())
                    }
                    _ => (Vector2::new(p.x, p.y), p.angle_deg),
                }
            }
            None => (Vector2::new(p.x, p.y), p.angle_deg),
        };
        let a = angle_deg.to_radians();
        let (m, ahead) = (f.apply(at), f.apply(at + Vector2::new(a.cos(), -a.sin())));
        (m.x, m.y, (ahead.y - m.y).atan2(ahead.x - m.x).to_degrees())
    }

    /// One line for the start-up log.
    pub fn describe(&self) -> String {
        match self {
            Calibration::Scale(s) => format!("scale {s} mm/px (no homography: robot frame = image frame scaled)"),
            Calibration::Homography { rms_mm, max_mm, .. } => format!("homography, fit residual RMS {rms_mm:.3} mm, max {max_mm:.3} mm"),
            Calibration::Plate(p) => {
                let f = &p.plate.fit;
                let r = &p.robot;
                let per_point: Vec<String> = p.residuals_mm.iter().enumerate().map(|(i, e)| format!("[{i}] {e:.3}")).collect();
                format!(
                    "plate {} ({} {}x{}, pitch {} mm; k1 {:.5}, k2 {:.5}; reprojection RMS {:.3} px, plate residual max {:.3} mm); robot frame: {} fitted to {} points ({}), {}, turned {:.2} deg, RMS {:.3} mm; residual mm per point: {}",
                    p.file.display(),
                    p.plate.grid.kind,
                    p.plate.grid.cols,
                    p.plate.grid.rows,
                    p.plate.grid.pitch_mm,
                    p.plate.lens.k1,
                    p.plate.lens.k2,
                    f.rms_px,
                    f.residual_mm_max,
                    if p.scaled { "similarity" } else { "rigid" },
                    p.residuals_mm.len(),
                    if p.scaled { format!("scale {:.5}", r.scale) } else { "scale fixed at 1".to_string() },
                    if r.mirrored {
                        "mirrored (the robot sees the belt from the other side: its hand differs from the image's)"
                    } else {
                        "not mirrored"
                    },
                    r.angle.to_degrees(),
                    r.rms,
                    per_point.join(", ")
                )
            }
        }
    }
}

/// The similarity (or rigid map) from plate millimetres to robot millimetres that best fits the
/// touched-up points, with the hand (mirrored or not) that fits them better: an overhead camera
/// and a Z-up robot see the belt mirrored, a camera looking up at a robot does not, and the
/// points tell which without a setting to get wrong. Scaled by default: a plate a few mm thick
/// lies closer to the camera than the belt, so its millimetres look a fraction of a percent
/// larger (3 mm at 1 m: 0.3 %, 0.6 mm across 200 mm), which the scale takes up.
pub fn place_in_robot_frame(
    camera: &PlaneCamera,
    points: &[[f64; 4]],
    scaled: bool,
    limit_mm: f64,
) -> Result<(Similarity, Vec<f64>), CalibrationError> {
    if points.len() < 3 {
        return Err(CalibrationError::TooFewTouchUps(points.len()));
    }
    let mut plate = Vec::with_capacity(points.len());
    for (index, p) in points.iter().enumerate() {
        let m = camera.to_plane(Vector2::new(p[0], p[1])).ok_or(CalibrationError::OutsideModel { index, x_px: p[0], y_px: p[1] })?;
        plate.push(m);
    }
    let robot: Vec<Vector2<f64>> = points.iter().map(|p| Vector2::new(p[2], p[3])).collect();
    // Points on a line fix neither the hand nor the turn: the smaller spread must be real.
    let spread = |v: &[Vector2<f64>]| {
        let n = v.len() as f64;
        let m = v.iter().fold(Vector2::zeros(), |a, p| a + p) / n;
        let (mut sxx, mut syy, mut sxy) = (0.0, 0.0, 0.0);
        for p in v {
            let d = p - m;
            sxx += d.x * d.x / n;
            syy += d.y * d.y / n;
            sxy += d.x * d.y / n;
        }
        let t = 0.5 * (sxx + syy);
        let q = (0.25 * (sxx - syy).powi(2) + sxy * sxy).sqrt();
        ((t - q).max(0.0).sqrt(), (t + q).sqrt())
    };
    let (minor, major) = spread(&plate);
    if !(major > 1.0 && minor > 0.05 * major) {
        return Err(CalibrationError::Collinear);
    }
    let fit = |a: &[Vector2<f64>], b: &[Vector2<f64>]| crate::lens::either_hand(a, b, scaled);
    let best = fit(&plate, &robot);
    let residuals: Vec<f64> = plate.iter().zip(&robot).map(|(p, r)| (best.apply(*p) - r).norm()).collect();
    if residuals.iter().any(|&e| e > limit_mm) {
        // Name the point the others disagree with most: each left out in turn and predicted by
        // the rest (with three points a bad one drags the fit towards itself, so the fit's own
        // residual would blame a good neighbour as often).
        let held_out = |i: usize| {
            let (a, b): (Vec<_>, Vec<_>) =
                plate.iter().zip(&robot).enumerate().filter(|(j, _)| *j != i).map(|(_, (p, r))| (*p, *r)).unzip();
            (fit(&a, &b).apply(plate[i]) - robot[i]).norm()
        };
        let (index, off_mm) = if points.len() >= 4 {
            (0..points.len()).map(|i| (i, held_out(i))).max_by(|a, b| a.1.total_cmp(&b.1)).unwrap_or((0, 0.0))
        } else {
            residuals.iter().copied().enumerate().max_by(|a, b| a.1.total_cmp(&b.1)).unwrap_or((0, 0.0))
        };
        let p = points[index];
        return Err(CalibrationError::PointDisagrees { index, x_px: p[0], y_px: p[1], x_mm: p[2], y_mm: p[3], off_mm, limit_mm });
    }
    Ok((best, residuals))
}

/// Direct linear transform with normalisation; residuals in millimetres.
pub fn fit(points: &[[f64; 4]]) -> Result<Calibration, CalibrationError> {
    if points.len() < 4 {
        return Err(CalibrationError::TooFew(points.len()));
    }
    let h = lens::homography(points).ok_or(CalibrationError::Degenerate)?;
    let mut sq = 0.0;
    let mut max: f64 = 0.0;
    for p in points {
        let e = (lens::project(&h, Vector2::new(p[0], p[1])) - Vector2::new(p[2], p[3])).norm();
        sq += e * e;
        max = max.max(e);
    }
    if !sq.is_finite() {
        return Err(CalibrationError::Degenerate);
    }
    Ok(Calibration::Homography { h, rms_mm: (sq / points.len() as f64).sqrt(), max_mm: max })
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
