//! Finding a calibration plate's grid in a frame: OpenCV's grid finders (`findCirclesGrid`,
//! `findChessboardCornersSB`), dot centres refined to hundredths of a pixel, and, when the grid
//! is not found, why (blurred, partly outside, not there).
//!
//! Pure: a frame in, points out.

use nalgebra::Vector2;
use opencv::core::{self, KeyPoint, Mat, Point2f, Size, Vector};
use opencv::prelude::*;
use opencv::{calib3d, features2d, imgproc};

use crate::vision::GrayImage;

/// A calibration plate's pattern.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Grid {
    /// Dark dots in rows and columns.
    Circles,
    /// Dark dots, every other row shifted by half a pitch (OpenCV's asymmetric grid).
    AsymmetricCircles,
    /// Black and white squares; the points are the inner corners.
    Chessboard,
}

impl std::str::FromStr for Grid {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "circles" => Ok(Grid::Circles),
            "asymmetric-circles" => Ok(Grid::AsymmetricCircles),
            "chessboard" => Ok(Grid::Chessboard),
            _ => Err(format!("grid {s:?}: expected circles, asymmetric-circles or chessboard")),
        }
    }
}

impl Grid {
    /// The name on the command line and in a calibration file.
    pub fn as_str(self) -> &'static str {
        match self {
            Grid::Circles => "circles",
            Grid::AsymmetricCircles => "asymmetric-circles",
            Grid::Chessboard => "chessboard",
        }
    }

    /// Plate millimetres of the grid points in the order OpenCV's grid finders report them
    /// (row by row). `pitch`: between neighbouring dots or corners; for the asymmetric grid
    /// OpenCV's square size: dots in a row are two pitches apart, rows one pitch.
    pub fn points(self, cols: usize, rows: usize, pitch: f64) -> Vec<Vector2<f64>> {
        let mut out = Vec::with_capacity(cols * rows);
        for i in 0..rows {
            for j in 0..cols {
                out.push(match self {
                    Grid::AsymmetricCircles => Vector2::new((2 * j + i % 2) as f64 * pitch, i as f64 * pitch),
                    _ => Vector2::new(j as f64 * pitch, i as f64 * pitch),
                });
            }
        }
        out
    }
}

/// A plate's pattern and size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSpec {
    /// The pattern.
    pub grid: Grid,
    /// Points per row (dots, or inner corners of a chessboard).
    pub cols: usize,
    /// Rows of points.
    pub rows: usize,
    /// See [`Grid::points`].
    pub pitch_mm: f64,
}

impl GridSpec {
    /// The grid's points on the plate, millimetres, in the order they are found.
    pub fn plate_points(&self) -> Vec<Vector2<f64>> {
        self.grid.points(self.cols, self.rows, self.pitch_mm)
    }
}

/// Why a frame's grid was not found.
#[derive(Debug, thiserror::Error)]
pub enum GridError {
    /// The edges are too soft for the finder.
    #[error("too blurred: edges spread over {sigma_px:.1} px (sigma); focus the lens or stop down")]
    TooBlurred {
        /// Estimated blur of the frame's sharpest edges, pixels.
        sigma_px: f64,
    },
    /// Part of the grid lies outside the frame.
    #[error("partly outside the frame: {seen} of {expected} dots found, some at the frame's edge")]
    PartlyOutside {
        /// Dots found.
        seen: usize,
        /// Dots the grid has.
        expected: usize,
    },
    /// No grid of this size is there.
    #[error("not found: {0}")]
    NotFound(String),
    /// The grid's size does not make sense.
    #[error("{0}")]
    Spec(String),
    /// OpenCV failed.
    #[error("OpenCV: {0}")]
    Cv(#[from] opencv::Error),
}

/// The grid's points in `frame`, pixels (pixel centres at integer coordinates), in the order of
/// [`GridSpec::plate_points`].
pub fn find_grid(frame: &GrayImage, spec: &GridSpec) -> Result<Vec<Vector2<f64>>, GridError> {
    if spec.cols < 2 || spec.rows < 2 || spec.cols * spec.rows < 9 {
        return Err(GridError::Spec(format!("a grid of {} x {} points is too small (at least 3 x 3)", spec.cols, spec.rows)));
    }
    if !(spec.pitch_mm.is_finite() && spec.pitch_mm > 0.0) {
        return Err(GridError::Spec(format!("pitch {} mm must be a positive number", spec.pitch_mm)));
    }
    let mat = frame.to_mat().map_err(|e| GridError::Spec(format!("the frame: {e}")))?;
    let size = Size::new(spec.cols as i32, spec.rows as i32);
    let expected = spec.cols * spec.rows;
    let found = match spec.grid {
        Grid::Circles | Grid::AsymmetricCircles => {
            let detector = blob_detector(frame, expected)?;
            let shape = if spec.grid == Grid::Circles { calib3d::CALIB_CB_SYMMETRIC_GRID } else { calib3d::CALIB_CB_ASYMMETRIC_GRID };
            let mut centres = Vector::<Point2f>::new();
            let mut ok = false;
            // Plain first; clustering copes with strong perspective where the plain search fails.
            for flags in [shape, shape | calib3d::CALIB_CB_CLUSTERING] {
                centres.clear();
                if calib3d::find_circles_grid(&mat, size, &mut centres, flags, Some(&detector))? && centres.len() == expected {
                    ok = true;
                    break;
                }
            }
            if ok {
                let pts: Vec<Vector2<f64>> = centres.iter().map(|p| Vector2::new(p.x as f64, p.y as f64)).collect();
                Some(refine_dots(frame, &pts))
            } else {
                None
            }
        }
        Grid::Chessboard => {
            let mut corners = Mat::default();
            let mut ok = false;
            // The exhaustive search is five times slower: only when the quick one fails.
            for extra in [0, calib3d::CALIB_CB_EXHAUSTIVE] {
                let flags = calib3d::CALIB_CB_ACCURACY | calib3d::CALIB_CB_NORMALIZE_IMAGE | extra;
                if calib3d::find_chessboard_corners_sb(&mat, size, &mut corners, flags)? && corners.total() == expected {
                    ok = true;
                    break;
                }
            }
            if ok {
                // The finder's corners are good to a few tenths of a pixel; the saddle point of
                // the gray levels around each (cornerSubPix) to hundredths. Its window stays
                // inside the four squares around the corner.
                let mut pts = Vector::<Point2f>::new();
                for p in corners.data_typed::<Point2f>()? {
                    pts.push(*p);
                }
                let mut steps: Vec<f32> = (1..pts.len())
                    .filter(|i| i % spec.cols != 0)
                    .map(|i| {
                        let (a, b) = (pts.get(i - 1).unwrap_or_default(), pts.get(i).unwrap_or_default());
                        (a.x - b.x).hypot(a.y - b.y)
                    })
                    .collect();
                steps.sort_by(f32::total_cmp);
                let half = (0.3 * steps.get(steps.len() / 2).copied().unwrap_or(10.0) as f64).clamp(3.0, 15.0).round() as i32;
                let criteria = core::TermCriteria::new(core::TermCriteria_COUNT + core::TermCriteria_EPS, 50, 1e-4)?;
                imgproc::corner_sub_pix(&mat, &mut pts, Size::new(half, half), Size::new(-1, -1), criteria)?;
                Some(pts.iter().map(|p| Vector2::new(p.x as f64, p.y as f64)).collect())
            } else {
                None
            }
        }
    };
    match found {
        Some(p) => Ok(p),
        None => Err(diagnose(frame, &mat, spec, expected)?),
    }
}

/// Dark, roundish blobs no larger than a grid cell could hold.
fn blob_detector(frame: &GrayImage, expected: usize) -> opencv::Result<core::Ptr<features2d::Feature2D>> {
    let mut p = features2d::SimpleBlobDetector_Params::default()?;
    p.filter_by_color = true;
    p.blob_color = 0;
    p.filter_by_area = true;
    p.min_area = 12.0;
    p.max_area = (frame.width * frame.height / expected.max(1)) as f32 * 0.6;
    p.filter_by_circularity = true;
    p.min_circularity = 0.6;
    p.filter_by_inertia = true;
    p.min_inertia_ratio = 0.3;
    p.filter_by_convexity = true;
    p.min_convexity = 0.85;
    p.min_dist_between_blobs = 4.0;
    Ok(features2d::SimpleBlobDetector::create(p)?.into())
}

/// Each dot's centre as the darkness-weighted centroid of its disc. The blob finder's centres
/// are the mean of thresholded blobs, good to a tenth of a pixel; a lens fit to a hundredth of
/// a pixel needs better. The window is 0.45 of the distance to the nearest dot, so it never
/// reaches a neighbour; two passes re-centre it.
fn refine_dots(frame: &GrayImage, pts: &[Vector2<f64>]) -> Vec<Vector2<f64>> {
    let (w, h) = (frame.width as i64, frame.height as i64);
    pts.iter()
        .map(|&c0| {
            let near = pts.iter().filter(|q| (*q - c0).norm() > 1e-6).map(|q| (q - c0).norm()).fold(f64::INFINITY, f64::min);
            let r = (0.45 * near).clamp(2.0, 200.0);
            let mut c = c0;
            for _ in 0..2 {
                let (x0, x1) = (((c.x - r).floor() as i64).max(0), ((c.x + r).ceil() as i64).min(w - 1));
                let (y0, y1) = (((c.y - r).floor() as i64).max(0), ((c.y + r).ceil() as i64).min(h - 1));
                // The window's pixels: the plate's white is their brightest twentieth, the dot's
                // black their darkest.
                let mut window: Vec<(f64, f64, f64)> = Vec::new();
                for y in y0..=y1 {
                    for x in x0..=x1 {
                        let (fx, fy) = (x as f64, y as f64);
                        if (fx - c.x).powi(2) + (fy - c.y).powi(2) <= r * r {
                            window.push((fx, fy, frame.data[(y * w + x) as usize] as f64));
                        }
                    }
                }
                if window.len() < 9 {
                    return c0;
                }
                let mut vals: Vec<f64> = window.iter().map(|p| p.2).collect();
                vals.sort_unstable_by(f64::total_cmp);
                let (dark, white) = (vals[vals.len() / 20], vals[vals.len() * 19 / 20]);
                if white - dark < 10.0 {
                    return c0;
                }
                let (mut sw, mut sx, mut sy) = (0.0, 0.0, 0.0);
                for &(x, y, v) in &window {
                    let wgt = ((white - v) / (white - dark)).clamp(0.0, 1.0);
                    sw += wgt;
                    sx += wgt * x;
                    sy += wgt * y;
                }
                if sw <= 0.0 {
                    return c0;
                }
                c = Vector2::new(sx / sw, sy / sw);
            }
            c
        })
        .collect()
}

/// Why the finder failed: soft edges first (nothing else can be judged on them), then dots at
/// the frame's edge, else not there.
fn diagnose(frame: &GrayImage, mat: &Mat, spec: &GridSpec, expected: usize) -> Result<GridError, GridError> {
    let sigma_px = edge_sigma(mat)?;
    if sigma_px > 3.0 {
        return Ok(GridError::TooBlurred { sigma_px });
    }
    if spec.grid != Grid::Chessboard {
        let mut detector = blob_detector(frame, expected)?;
        let mut kps = Vector::<KeyPoint>::new();
        detector.detect(mat, &mut kps, &core::no_array())?;
        let seen = kps.len();
        let edge = |k: &KeyPoint| {
            let (p, m) = (k.pt(), k.size() as f64);
            (p.x as f64) < m || (p.y as f64) < m || p.x as f64 > frame.width as f64 - 1.0 - m || p.y as f64 > frame.height as f64 - 1.0 - m
        };
        if seen * 2 >= expected && seen < expected + expected / 4 && kps.iter().any(|k| edge(&k)) {
            return Ok(GridError::PartlyOutside { seen, expected });
        }
        return Ok(GridError::NotFound(format!(
            "{seen} dark dots seen, the grid has {expected} ({} x {}): check --cols, --rows and --grid",
            spec.cols, spec.rows
        )));
    }
    Ok(GridError::NotFound(format!(
        "no chessboard of {} x {} inner corners (corners between four squares, not squares): check --cols, --rows, and that the whole board is in the frame",
        spec.cols, spec.rows
    )))
}

/// The blur of the frame's sharpest edges, as a Gaussian's sigma in pixels: a step of contrast
/// C blurred by sigma has a largest slope of C / (sigma sqrt(2 pi)).
fn edge_sigma(mat: &Mat) -> opencv::Result<f64> {
    let (mut gx, mut gy) = (Mat::default(), Mat::default());
    imgproc::sobel(mat, &mut gx, core::CV_32F, 1, 0, 3, 0.125, 0.0, core::BORDER_REPLICATE)?;
    imgproc::sobel(mat, &mut gy, core::CV_32F, 0, 1, 3, 0.125, 0.0, core::BORDER_REPLICATE)?;
    let (gx, gy) = (gx.data_typed::<f32>()?, gy.data_typed::<f32>()?);
    let mut mags: Vec<f32> = gx.iter().zip(gy).map(|(a, b)| a.hypot(*b)).collect();
    let data = mat.data_bytes()?;
    let mut hist = [0usize; 256];
    data.iter().for_each(|&v| hist[v as usize] += 1);
    let pct = |q: f64| {
        let target = (q * data.len() as f64) as usize;
        let mut acc = 0;
        for (v, &n) in hist.iter().enumerate() {
            acc += n;
            if acc > target {
                return v as f64;
            }
        }
        255.0
    };
    let contrast = pct(0.98) - pct(0.02);
    let k = mags.len() - 1 - mags.len() / 2000;
    let (_, top, _) = mags.select_nth_unstable_by(k, f32::total_cmp);
    let slope = *top as f64;
    if slope <= 0.0 || contrast <= 0.0 {
        return Ok(f64::INFINITY);
    }
    Ok(contrast / (slope * (2.0 * std::f64::consts::PI).sqrt()))
}
