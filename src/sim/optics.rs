//! A real cell's camera for the simulator: the belt seen through a tilted camera and a lens with
//! barrel distortion, and a robot whose frame is the belt's turned and mirrored.
//!
//! Scenes are rendered flat (the belt at `px_per_mm`, as without optics) and then resampled
//! through the camera, so parts, light and noise stay those of the flat renderer (the noise is
//! interpolated once, which softens it slightly).

use nalgebra::{Matrix3, Rotation3, Vector2};
use opencv::core::{self, Mat, Scalar};
use opencv::imgproc;
use opencv::prelude::*;

use crate::lens::{Lens, Similarity, project};
use crate::plate::Grid;
use crate::vision::{GrayImage, Pt};

/// The camera between the flat belt render and the frame, and where the robot is.
#[derive(Debug, Clone)]
pub struct Optics {
    /// Flat render pixels to ideal (undistorted) frame pixels: the camera's tilt.
    pub tilt: Matrix3<f64>,
    /// The lens, on ideal frame pixels.
    pub lens: Lens,
    /// Belt millimetres per flat render pixel (the inverse of the simulator's scale).
    pub mm_per_px: f64,
    /// Belt millimetres to robot millimetres.
    pub robot: Similarity,
}

impl Optics {
    /// The built-in cell: the camera tilted 2.5 degrees about the frame's x axis and 1.5 about
    /// its y axis (focal length 5000 px), a lens of k1 = -0.008, k2 = -0.0005 (13.8 px inwards
    /// at half the diagonal), small tangential terms, its centre 31 px right of and 19 px above
    /// the frame's; the robot's X along the belt's -y, its Y along the belt's -x (an overhead
    /// camera and a Z-up robot: mirrored), origin 600 mm and -250 mm away.
    pub fn cell(width: usize, height: usize, px_per_mm: f64) -> Self {
        let (w, h) = (width as f64, height as f64);
        let (cx, cy) = ((w - 1.0) / 2.0, (h - 1.0) / 2.0);
        let f = 5000.0 * w / 2592.0;
        let k = Matrix3::new(f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0);
        let rot = Rotation3::from_euler_angles(2.5f64.to_radians(), -1.5f64.to_radians(), 0.0);
        let tilt = k * rot.matrix() * k.try_inverse().expect("a focal length is invertible");
        // Keep the frame centre where it was: tilt about the optical axis's foot on the belt.
        let c = project(&tilt, Vector2::new(cx, cy));
        let tilt = Matrix3::new(1.0, 0.0, cx - c.x, 0.0, 1.0, cy - c.y, 0.0, 0.0, 1.0) * tilt;
        let mut lens = Lens::ideal(width, height);
        lens.centre_px = [cx + 31.0 * w / 2592.0, cy - 19.0 * w / 2592.0];
        (lens.k1, lens.k2, lens.p1, lens.p2) = (-0.008, -0.0005, 2e-4, -1e-4);
        let robot =
            Similarity { angle: -std::f64::consts::FRAC_PI_2, scale: 1.0, shift: Vector2::new(600.0, -250.0), mirrored: true, rms: 0.0 };
        Optics { tilt, lens, mm_per_px: 1.0 / px_per_mm, robot }
    }

    /// Where a flat render pixel shows in the frame.
    pub fn to_frame(&self, flat: Pt) -> Pt {
        let q = project(&self.tilt, Vector2::new(flat.x, flat.y));
        let u = (q - Vector2::from(self.lens.centre_px)) / self.lens.radius_px;
        let p = self.lens.pixel(u);
        Pt::new(p.x, p.y)
    }

    /// The flat render pixel a frame pixel shows (None far outside the frame).
    pub fn to_flat(&self, frame: Pt) -> Option<Pt> {
        let u = self.lens.normalise(Vector2::new(frame.x, frame.y))?;
        let q = Vector2::from(self.lens.centre_px) + u * self.lens.radius_px;
        let f = project(&self.tilt.try_inverse()?, q);
        Some(Pt::new(f.x, f.y))
    }

    /// The robot millimetres of a flat render pixel.
    pub fn to_robot(&self, flat: Pt) -> Vector2<f64> {
        self.robot.apply(Vector2::new(flat.x, flat.y) * self.mm_per_px)
    }

    /// A direction at a flat pixel (degrees, counter-clockwise as displayed) as it shows in the
    /// frame, and as the robot sees it (counter-clockwise from robot +X towards +Y).
    pub fn angles(&self, flat: Pt, angle_deg: f64) -> (f64, f64) {
        let a = angle_deg.to_radians();
        let (dx, dy) = (a.cos() * 0.5, -a.sin() * 0.5);
        let (p0, p1) = (self.to_frame(Pt::new(flat.x - dx, flat.y - dy)), self.to_frame(Pt::new(flat.x + dx, flat.y + dy)));
        let frame = (-(p1.y - p0.y)).atan2(p1.x - p0.x).to_degrees().rem_euclid(360.0);
        let (r0, r1) = (self.to_robot(Pt::new(flat.x - dx, flat.y - dy)), self.to_robot(Pt::new(flat.x + dx, flat.y + dy)));
        let robot = (r1.y - r0.y).atan2(r1.x - r0.x).to_degrees().rem_euclid(360.0);
        (frame, robot)
    }

    /// The frame the camera makes of a flat render (bilinear; outside the render, its edge
    /// mirrored, so the belt's texture continues).
    pub fn image(&self, flat: &GrayImage) -> opencv::Result<GrayImage> {
        let (w, h) = (flat.width, flat.height);
        let mut mx = Mat::new_rows_cols_with_default(h as i32, w as i32, core::CV_32FC1, Scalar::all(0.0))?;
        let mut my = Mat::new_rows_cols_with_default(h as i32, w as i32, core::CV_32FC1, Scalar::all(0.0))?;
        {
            let (xs, ys) = (mx.data_typed_mut::<f32>()?, my.data_typed_mut::<f32>()?);
            for y in 0..h {
                for x in 0..w {
                    let f = self.to_flat(Pt::new(x as f64, y as f64)).unwrap_or(Pt::new(-1e4, -1e4));
                    xs[y * w + x] = f.x as f32;
                    ys[y * w + x] = f.y as f32;
                }
            }
        }
        let src = flat.to_mat().map_err(|e| opencv::Error::new(core::StsError, e.to_string()))?;
        let mut out = Mat::default();
        imgproc::remap(&src, &mut out, &mx, &my, imgproc::INTER_LINEAR, core::BORDER_REFLECT, Scalar::all(0.0))?;
        GrayImage::from_mat(&out).map(|(g, _)| g).map_err(|e| opencv::Error::new(core::StsError, e.to_string()))
    }
}

/// A plate lying on the belt: its pattern, where its first grid point lies (belt mm) and its
/// turn on the belt.
#[derive(Debug, Clone, Copy)]
pub struct Plate {
    /// The pattern.
    pub grid: Grid,
    /// Grid points per row.
    pub cols: usize,
    /// Rows of grid points.
    pub rows: usize,
    /// See [`Grid::points`].
    pub pitch_mm: f64,
    /// Belt mm of the first grid point.
    pub origin_mm: Vector2<f64>,
    /// Counter-clockwise as displayed, degrees.
    pub angle_deg: f64,
}

impl Plate {
    /// The plate the simulator's cell is calibrated with: it covers most of a frame of
    /// `width_mm` x `height_mm` of belt.
    pub fn covering(grid: Grid, width_mm: f64, height_mm: f64) -> Self {
        let pitch = 15.0;
        let (cols, rows, span_x) = match grid {
            Grid::AsymmetricCircles => {
                let cols = ((width_mm * 0.9 / pitch - 1.0) / 2.0).floor() as usize;
                (cols, (height_mm * 0.9 / pitch).floor() as usize, (2 * cols - 1) as f64 * pitch)
            }
            _ => {
                let cols = (width_mm * 0.9 / pitch).floor() as usize;
                (cols, (height_mm * 0.9 / pitch).floor() as usize, (cols - 1) as f64 * pitch)
            }
        };
        let span_y = (rows - 1) as f64 * pitch;
        Plate {
            grid,
            cols,
            rows,
            pitch_mm: pitch,
            origin_mm: Vector2::new((width_mm - span_x) / 2.0 + 1.3, (height_mm - span_y) / 2.0 - 0.7),
            angle_deg: 0.8,
        }
    }

    /// Belt mm of a plate point.
    pub fn to_belt(&self, p: Vector2<f64>) -> Vector2<f64> {
        let (s, c) = (-self.angle_deg.to_radians()).sin_cos();
        Vector2::new(c * p.x - s * p.y, s * p.x + c * p.y) + self.origin_mm
    }

    /// Four grid points one in from the plate's corners: where a robot touches it up.
    pub fn corner_marks(&self) -> [usize; 4] {
        let (c, r) = (self.cols, self.rows);
        [c + 1, 2 * c - 2, (r - 2) * c + 1, (r - 1) * c - 2]
    }

    /// The grid points, plate mm, in the grid finder's order.
    pub fn points(&self) -> Vec<Vector2<f64>> {
        self.grid.points(self.cols, self.rows, self.pitch_mm)
    }

    /// The plate rendered flat: a white plate with black marks on the belt's gray, each pixel
    /// the mean of 8 x 8 samples, blurred by `blur` px. (OpenCV's anti-aliased polygons are
    /// out by up to half a pixel across horizontal edges: fine for a part's silhouette, not for
    /// a plate that must place its corners to hundredths.)
    pub fn render(&self, width: usize, height: usize, px_per_mm: f64, blur: f64) -> opencv::Result<GrayImage> {
        const BELT: f64 = 55.0;
        const WHITE: f64 = 225.0;
        const BLACK: f64 = 30.0;
        const N: usize = 8;
        let pitch = self.pitch_mm;
        let (x_max, y_max) = match self.grid {
            Grid::AsymmetricCircles => ((2 * self.cols - 1) as f64 * pitch, (self.rows - 1) as f64 * pitch),
            _ => ((self.cols - 1) as f64 * pitch, (self.rows - 1) as f64 * pitch),
        };
        let (s, c) = self.angle_deg.to_radians().sin_cos();
        let r = pitch * if self.grid == Grid::Circles { 0.3 } else { 0.25 };
        // The level at a point of the belt (millimetres), and how far the nearest edge is, mm.
        let level = |b: Vector2<f64>| -> (f64, f64) {
            let d = b - self.origin_mm;
            // Belt to plate: the inverse of `to_belt`'s turn.
            let (x, y) = (c * d.x - s * d.y, s * d.x + c * d.y);
            let border = (x + pitch).min(y + pitch).min(x_max + pitch - x).min(y_max + pitch - y);
            if border < 0.0 {
                return (BELT, -border);
            }
            let (dark, edge) = match self.grid {
                Grid::Chessboard => {
                    let (fx, fy) = ((x / pitch).rem_euclid(1.0), (y / pitch).rem_euclid(1.0));
                    let edge = pitch * fx.min(1.0 - fx).min(fy).min(1.0 - fy);
                    (((x / pitch).floor() as i64 + (y / pitch).floor() as i64).rem_euclid(2) == 1, edge)
                }
                Grid::Circles => {
                    let (i, j) =
                        ((x / pitch).round().clamp(0.0, (self.cols - 1) as f64), (y / pitch).round().clamp(0.0, (self.rows - 1) as f64));
                    let d = (x - i * pitch).hypot(y - j * pitch);
                    (d < r, (d - r).abs())
                }
                Grid::AsymmetricCircles => {
                    let j = (y / pitch).round().clamp(0.0, (self.rows - 1) as f64);
                    let odd = (j as usize % 2) as f64;
                    let i = ((x / pitch - odd) / 2.0).round().clamp(0.0, (self.cols - 1) as f64);
                    let d = (x - (2.0 * i + odd) * pitch).hypot(y - j * pitch);
                    (d < r, (d - r).abs())
                }
            };
            (if dark { BLACK } else { WHITE }, edge.min(border))
        };
        // A pixel whose centre is more than its half-diagonal from every edge is one level.
        let clear_mm = 0.75 / px_per_mm;
        let mut out = GrayImage::new(width, height, BELT as u8);
        // Only the plate's bounding box needs sampling.
        let corners = [(-pitch, -pitch), (x_max + pitch, -pitch), (x_max + pitch, y_max + pitch), (-pitch, y_max + pitch)]
            .map(|(x, y)| self.to_belt(Vector2::new(x, y)) * px_per_mm);
        let lo = |f: fn(&Vector2<f64>) -> f64, n: usize| {
            (corners.iter().map(f).fold(f64::INFINITY, f64::min).floor() - 1.0).clamp(0.0, n as f64) as usize
        };
        let hi = |f: fn(&Vector2<f64>) -> f64, n: usize| {
            (corners.iter().map(f).fold(f64::NEG_INFINITY, f64::max).ceil() + 2.0).clamp(0.0, n as f64) as usize
        };
        let (x0, x1, y0, y1) = (lo(|v| v.x, width), hi(|v| v.x, width), lo(|v| v.y, height), hi(|v| v.y, height));
        for y in y0..y1 {
            for x in x0..x1 {
                let (v, edge) = level(Vector2::new(x as f64, y as f64) / px_per_mm);
                if edge > clear_mm {
                    out.data[y * width + x] = v as u8;
                    continue;
                }
                let mut sum = 0.0;
                for sy in 0..N {
                    for sx in 0..N {
                        let px = Vector2::new(x as f64 + (sx as f64 + 0.5) / N as f64 - 0.5, y as f64 + (sy as f64 + 0.5) / N as f64 - 0.5);
                        sum += level(px / px_per_mm).0;
                    }
                }
                out.data[y * width + x] = (sum / (N * N) as f64).round() as u8;
            }
        }
        if blur > 0.0 {
            let mut b = Mat::default();
            let src = out.to_mat().map_err(|e| opencv::Error::new(core::StsError, e.to_string()))?;
            imgproc::gaussian_blur(&src, &mut b, core::Size::new(0, 0), blur, blur, core::BORDER_REPLICATE)?;
            out = GrayImage::from_mat(&b).map(|(g, _)| g).map_err(|e| opencv::Error::new(core::StsError, e.to_string()))?;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_and_flat_pixels_go_back_and_forth() {
        let o = Optics::cell(2592, 1944, 6.5);
        for &(x, y) in &[(0.0, 0.0), (2591.0, 1943.0), (1296.0, 972.0), (300.0, 1700.0)] {
            let f = Pt::new(x, y);
            let back = o.to_flat(o.to_frame(f)).unwrap();
            assert!((back.x - f.x).abs() < 1e-6 && (back.y - f.y).abs() < 1e-6, "{f:?} {back:?}");
        }
        // The tilt magnifies one side by about 1 %, the lens pulls the corners in by 14 px: the
        // flat frame's corners land within 30 px of the frame's, its centre where it was.
        for &(x, y) in &[(0.0, 0.0), (2591.0, 0.0), (0.0, 1943.0), (2591.0, 1943.0)] {
            let c = o.to_frame(Pt::new(x, y));
            assert!((c.x - x).abs() < 30.0 && (c.y - y).abs() < 30.0, "{x},{y} -> {c:?}");
        }
        let c = o.to_frame(Pt::new(1295.5, 971.5));
        assert!((c.x - 1295.5).abs() < 1e-3 && (c.y - 971.5).abs() < 1e-3, "{c:?}");
    }
}
