//! Rendering parts on a textured belt.
//!
//! Geometry is drawn with OpenCV's anti-aliased polygon filling at 1/16-pixel precision, so the
//! silhouette in the image and the pose in the ground truth agree to hundredths of a pixel.

use opencv::core::{self, Mat, Point, Scalar, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;
use rand::{Rng, RngExt};
use rand_distr::{Distribution, Normal};

use super::models::{Look, Model, Shape};
use crate::vision::{Face, GrayImage, Pt};

const SHIFT: i32 = 4;
const SUB: f64 = 16.0;

/// A model with its derived geometry.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// The model.
    pub model: Model,
    /// Material centroid of the face-up view, mm.
    pub centroid: (f64, f64),
    /// Largest distance of any material point from the centroid, mm.
    pub radius: f64,
}

/// Where and how a part lies in a scene.
#[derive(Debug, Clone, Copy)]
pub struct Placement {
    /// Which face lies up.
    pub face: Face,
    /// Counter-clockwise as displayed, degrees.
    pub angle_deg: f64,
    /// Where the material centroid lands, frame pixels.
    pub x: f64,
    /// See `x`.
    pub y: f64,
    /// Scale of the scene.
    pub px_per_mm: f64,
    /// Gray level of the bare material.
    pub gray: f64,
}

/// Scene-wide lighting and sensor.
#[derive(Debug, Clone)]
pub struct Lighting {
    /// Factor on the part's and belt's light (1: nominal).
    pub exposure: f64,
    /// Relative brightness change across the frame (linear ramp), e.g. 0.1.
    pub gradient: f64,
    /// Direction of the ramp, degrees.
    pub gradient_dir_deg: f64,
    /// Specular highlight: centre, radius (px), amplitude (gray levels); on parts only.
    pub glare: Option<(Pt, f64, f64)>,
    /// Optical blur, pixels.
    pub blur_sigma: f64,
    /// Gaussian sensor noise, gray levels.
    pub noise_sigma: f64,
    /// Gray level of the bare belt.
    pub belt_gray: f64,
}

fn poly_mm_to_px(pts: &[(f64, f64)], prep: &Prepared, pl: &Placement, off: (i32, i32)) -> Vector<Point> {
    pts.iter()
        .map(|&q| {
            let p = map_point(prep, pl, q);
            Point::new(((p.x - off.0 as f64) * SUB).round() as i32, ((p.y - off.1 as f64) * SUB).round() as i32)
        })
        .collect()
}

/// Model millimetres -> frame pixels for a placement.
pub fn map_point(prep: &Prepared, pl: &Placement, q: (f64, f64)) -> Pt {
    let (qx, mut qy) = q;
    let (cx, mut cy) = prep.centroid;
    if pl.face == Face::Down {
        qy = -qy;
        cy = -cy;
    }
    let d = Pt::new((qx - cx) * pl.px_per_mm, (qy - cy) * pl.px_per_mm);
    Pt::new(pl.x, pl.y) + crate::vision::geometry::rotate_display(d, pl.angle_deg.to_radians())
}

fn fill(img: &mut Mat, shape: &Shape, prep: &Prepared, pl: &Placement, off: (i32, i32), value: f64) -> opencv::Result<()> {
    let mut polys: Vector<Vector<Point>> = Vector::new();
    for c in shape.contours() {
        polys.push(poly_mm_to_px(&c, prep, pl, off));
    }
    imgproc::fill_poly(img, &polys, Scalar::all(value), imgproc::LINE_AA, SHIFT, Point::new(0, 0))
}

fn outline(
    img: &mut Mat,
    shape: &Shape,
    prep: &Prepared,
    pl: &Placement,
    off: (i32, i32),
    value: f64,
    thickness: i32,
) -> opencv::Result<()> {
    let mut polys: Vector<Vector<Point>> = Vector::new();
    for c in shape.contours() {
        polys.push(poly_mm_to_px(&c, prep, pl, off));
    }
    imgproc::polylines(img, &polys, true, Scalar::all(value), thickness, imgproc::LINE_AA, SHIFT)
}

impl Prepared {
    /// The model with its centroid and radius computed.
    pub fn new(model: Model) -> Self {
        let (_, cx, cy) = material_moments(&model);
        let pts: Vec<(f64, f64)> = model.material.iter().flat_map(|s| s.contours()).flatten().collect();
        let radius = pts.iter().map(|p| (p.0 - cx).hypot(p.1 - cy)).fold(0.0, f64::max);
        Prepared { model, centroid: (cx, cy), radius }
    }

    /// Material outline polygons in frame pixels for a placement (for spacing parts apart).
    pub fn material_polys(&self, pl: &Placement) -> Vec<Vec<Pt>> {
        self.model.material.iter().flat_map(|s| s.contours()).map(|c| c.iter().map(|&q| map_point(self, pl, q)).collect()).collect()
    }
}

/// x-intervals where a horizontal line at `y` is inside a shape given as its contours
/// (`Shape::contours`, even-odd).
fn spans(contours: &[Vec<(f64, f64)>], y: f64) -> Spans {
    let mut xs = Vec::new();
    for c in contours {
        let n = c.len();
        for i in 0..n {
            let (a, b) = (c[i], c[(i + 1) % n]);
            if (a.1 > y) != (b.1 > y) {
                xs.push(a.0 + (y - a.1) / (b.1 - a.1) * (b.0 - a.0));
            }
        }
    }
    xs.sort_by(f64::total_cmp);
    xs.chunks_exact(2).map(|p| (p[0], p[1])).collect()
}

/// Union of interval lists, sorted and merged.
fn union(mut v: Spans) -> Spans {
    v.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut out: Vec<(f64, f64)> = Vec::with_capacity(v.len());
    for (a, b) in v {
        match out.last_mut() {
            Some(last) if a <= last.1 => last.1 = last.1.max(b),
            _ => out.push((a, b)),
        }
    }
    out
}

/// x-intervals of a horizontal line, sorted.
type Spans = Vec<(f64, f64)>;

/// A model's shapes as polygons (`Shape::contours`), made once for many scanline questions.
pub struct Polygons {
    material: Vec<Vec<Vec<(f64, f64)>>>,
    holes: Vec<Vec<Vec<(f64, f64)>>>,
}

impl Polygons {
    /// The polygons of `model`'s material and holes.
    pub fn new(model: &Model) -> Self {
        Self { material: model.material.iter().map(Shape::contours).collect(), holes: model.holes.iter().map(Shape::contours).collect() }
    }

    /// The line at `y`: the union of the material's spans and the union of the holes'.
    fn spans(&self, y: f64) -> (Spans, Spans) {
        let line = |shapes: &[Vec<Vec<(f64, f64)>>]| union(shapes.iter().flat_map(|c| spans(c, y)).collect());
        (line(&self.material), line(&self.holes))
    }

    /// Whether (x, y) mm is material: inside a material shape and in no hole.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let (material, holes) = self.spans(y);
        let within = |v: &[(f64, f64)]| v.iter().any(|&(a, b)| a <= x && x < b);
        within(&material) && !within(&holes)
    }

    /// The largest distance of a material polygon's vertex from `c`, mm.
    pub fn reach(&self, c: (f64, f64)) -> f64 {
        self.material.iter().flatten().flatten().map(|p| (p.0 - c.0).hypot(p.1 - c.1)).fold(0.0, f64::max)
    }
}

/// Area and centroid (mm) of a model's material (union of `material` minus union of `holes`),
/// integrated exactly along scanlines 0.01 mm apart: independent of any rasteriser's edge rule.
pub fn material_moments(model: &Model) -> (f64, f64, f64) {
    let pts: Vec<(f64, f64)> = model.material.iter().flat_map(|s| s.contours()).flatten().collect();
    let (y0, y1) = pts.iter().fold((f64::MAX, f64::MIN), |a, p| (a.0.min(p.1), a.1.max(p.1)));
    let h = 0.01;
    // Each shape's polygons once, not once per scanline.
    let polygons = Polygons::new(model);
    let (mut area, mut mx, mut my) = (0.0, 0.0, 0.0);
    let mut y = y0 + h / 2.0;
    while y < y1 {
        let (mat, holes) = polygons.spans(y);
        for &(a, b) in &mat {
            // Subtract the holes from [a, b].
            let mut cur = a;
            for &(ha, hb) in holes.iter().filter(|(ha, hb)| *hb > a && *ha < b) {
                if ha > cur {
                    area += (ha - cur) * h;
                    mx += (ha * ha - cur * cur) / 2.0 * h;
                    my += (ha - cur) * y * h;
                }
                cur = cur.max(hb);
            }
            if b > cur {
                area += (b - cur) * h;
                mx += (b * b - cur * cur) / 2.0 * h;
                my += (b - cur) * y * h;
            }
        }
        y += h;
    }
    (area, mx / area, my / area)
}

/// Low-frequency random field (zero mean, unit-ish amplitude) with features about `scale` px.
fn low_freq(w: i32, h: i32, scale: f64, rng: &mut impl Rng) -> opencv::Result<Mat> {
    let sw = ((w as f64 / scale).ceil() as i32 + 2).max(2);
    let sh = ((h as f64 / scale).ceil() as i32 + 2).max(2);
    let n = Normal::new(0.0f32, 1.0).expect("unit normal");
    let vals: Vec<f32> = (0..sw * sh).map(|_| n.sample(rng)).collect();
    let small = Mat::new_rows_cols_with_data(sh, sw, &vals)?.try_clone()?;
    let mut out = Mat::default();
    imgproc::resize(&small, &mut out, Size::new(w, h), 0.0, 0.0, imgproc::INTER_CUBIC)?;
    Ok(out)
}

/// Renders a frame with the given parts (drawn in order: later parts lie on top).
pub fn render(
    width: usize,
    height: usize,
    parts: &[(&Prepared, Placement)],
    light: &Lighting,
    rng: &mut impl Rng,
) -> opencv::Result<GrayImage> {
    let scene = belt(width, height, light, rng)?;
    let grain = low_freq(width as i32, height as i32, 25.0, rng)?.data_typed::<f32>()?.to_vec();
    let mut canvas = Canvas { width, height, scene, coverage: vec![0f32; width * height], grain };
    for (prep, pl) in parts {
        canvas.lay(prep, pl)?;
    }
    canvas.light(light);
    canvas.finish(light, rng)
}

/// The empty belt: base gray, cloudy texture, the weave's faint rows, dirt.
fn belt(width: usize, height: usize, light: &Lighting, rng: &mut impl Rng) -> opencv::Result<Vec<f32>> {
    let (w, h) = (width as i32, height as i32);
    let cloud = low_freq(w, h, 90.0, rng)?;
    let row_n = Normal::new(0.0f32, 1.0).expect("unit normal");
    let rows: Vec<f32> = (0..h).map(|_| row_n.sample(rng)).collect();
    let mut scene = vec![0f32; width * height];
    {
        let c = cloud.data_typed::<f32>()?;
        for (y, row) in rows.iter().enumerate() {
            for x in 0..width {
                let i = y * width + x;
                scene[i] = light.belt_gray as f32 + 3.5 * c[i] + 1.3 * row;
            }
        }
    }
    let mut dirt = Mat::new_rows_cols_with_default(h, w, core::CV_8UC1, Scalar::all(0.0))?;
    let spots = (width * height / 120_000).max(3);
    for _ in 0..spots {
        let c = Point::new(rng.random_range(0..w), rng.random_range(0..h));
        let ax = Size::new(rng.random_range(2..9), rng.random_range(1..5));
        imgproc::ellipse(
            &mut dirt,
            c,
            ax,
            rng.random_range(0.0..180.0),
            0.0,
            360.0,
            Scalar::all(rng.random_range(60.0..200.0)),
            -1,
            imgproc::LINE_AA,
            0,
        )?;
    }
    {
        let d = dirt.data_bytes()?;
        for (s, &v) in scene.iter_mut().zip(d) {
            *s -= v as f32 * 0.12;
        }
    }
    Ok(scene)
}

/// A frame being rendered: gray levels as floats, how much part material covers each pixel
/// (glare shines on parts only), and the parts' surface grain.
struct Canvas {
    width: usize,
    height: usize,
    scene: Vec<f32>,
    coverage: Vec<f32>,
    grain: Vec<f32>,
}

impl Canvas {
    /// Lays one part on what is there: its material with the visible face's features, bevel
    /// and rounded edge, and its soft shadow on whatever lies below.
    fn lay(&mut self, prep: &Prepared, pl: &Placement) -> opencv::Result<()> {
        let (width, w, h) = (self.width, self.width as i32, self.height as i32);
        let (scene, coverage, grain) = (&mut self.scene, &mut self.coverage, &self.grain);
        let polys = prep.material_polys(pl);
        let all: Vec<Pt> = polys.iter().flatten().copied().collect();
        let (lo, hi) = crate::vision::geometry::bounds(&all);
        let margin = 24.0;
        let x0 = ((lo.x - margin).floor() as i32).clamp(0, w - 1);
        let y0 = ((lo.y - margin).floor() as i32).clamp(0, h - 1);
        let x1 = ((hi.x + margin).ceil() as i32).clamp(x0 + 1, w);
        let y1 = ((hi.y + margin).ceil() as i32).clamp(y0 + 1, h);
        let (rw, rh) = (x1 - x0, y1 - y0);
        let off = (x0, y0);

        let mut mask = Mat::new_rows_cols_with_default(rh, rw, core::CV_8UC1, Scalar::all(0.0))?;
        for s in &prep.model.material {
            fill(&mut mask, s, prep, pl, off, 255.0)?;
        }
        for s in &prep.model.holes {
            fill(&mut mask, s, prep, pl, off, 0.0)?;
        }
        // Appearance of the visible face.
        let g = pl.gray;
        let mut app = Mat::new_rows_cols_with_default(rh, rw, core::CV_8UC1, Scalar::all(g))?;
        let feats = if pl.face == Face::Up { &prep.model.top } else { &prep.model.bottom };
        let line = ((0.25 * pl.px_per_mm).round() as i32).max(1);
        for f in feats {
            match f.look {
                Look::Raised => {
                    fill(&mut app, &f.shape, prep, pl, off, (g + 35.0).min(250.0))?;
                    outline(&mut app, &f.shape, prep, pl, off, (g - 60.0).max(20.0), line)?;
                }
                Look::Recessed => {
                    fill(&mut app, &f.shape, prep, pl, off, (g - 55.0).max(25.0))?;
                    outline(&mut app, &f.shape, prep, pl, off, (g - 85.0).max(15.0), line)?;
                }
                Look::Blind => fill(&mut app, &f.shape, prep, pl, off, 30.0)?,
            }
        }
        // A bevel: the outer band of the material reads darker, as a cast edge does.
        let mut eroded = Mat::default();
        let k = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, Size::new(2 * line + 1, 2 * line + 1), Point::new(-1, -1))?;
        imgproc::erode(&mask, &mut eroded, &k, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
        // A rounded (forged) edge darkens towards the silhouette: Lambert shading of a quarter
        // round whose radius is the model's `rounded` width.
        let round_px = prep.model.rounded * pl.px_per_mm;
        let dist = if round_px > 0.5 {
            let mut bin = Mat::default();
            imgproc::threshold(&mask, &mut bin, 127.0, 255.0, imgproc::THRESH_BINARY)?;
            let mut d = Mat::default();
            imgproc::distance_transform(&bin, &mut d, imgproc::DIST_L2, imgproc::DIST_MASK_PRECISE, core::CV_32F)?;
            Some(d)
        } else {
            None
        };
        let dist = match &dist {
            Some(d) => Some(d.data_typed::<f32>()?),
            None => None,
        };
        // A soft drop shadow on whatever lies below, offset down and right.
        let mut shadow = Mat::default();
        let sig = 0.6 * pl.px_per_mm;
        imgproc::gaussian_blur(&mask, &mut shadow, Size::new(0, 0), sig, sig, core::BORDER_CONSTANT)?;
        let (sdx, sdy) = ((0.5 * pl.px_per_mm).round() as i32, (0.7 * pl.px_per_mm).round() as i32);
        let m = mask.data_bytes()?;
        let e = eroded.data_bytes()?;
        let a = app.data_bytes()?;
        let sh = shadow.data_bytes()?;
        for yy in 0..rh {
            for xx in 0..rw {
                let li = (yy * rw + xx) as usize;
                let gi = (y0 + yy) as usize * width + (x0 + xx) as usize;
                let sy = yy - sdy;
                let sx = xx - sdx;
                if sy >= 0 && sx >= 0 {
                    let s = sh[(sy * rw + sx) as usize] as f32 / 255.0;
                    scene[gi] *= 1.0 - 0.35 * s;
                }
                let cov = m[li] as f32 / 255.0;
                if cov > 0.0 {
                    let bevel = (m[li] as f32 - e[li] as f32).max(0.0) / 255.0;
                    let shade = match dist {
                        Some(d) => {
                            let u = (d[li] / round_px as f32).min(1.0);
                            // Surface normal of a quarter round at u: cos of its tilt.
                            0.3 + 0.7 * (1.0 - (1.0 - u) * (1.0 - u)).sqrt()
                        }
                        None => 1.0,
                    };
                    let val = (a[li] as f32 * shade - 40.0 * bevel) * (1.0 + 0.05 * grain[gi]);
                    scene[gi] = scene[gi] * (1.0 - cov) + val * cov;
                    coverage[gi] = coverage[gi].max(cov);
                }
            }
        }
        Ok(())
    }

    /// The light: exposure, a gradient across the frame, and glare on the parts.
    fn light(&mut self, light: &Lighting) {
        let (width, height, scene, coverage) = (self.width, self.height, &mut self.scene, &self.coverage);
        let dir = light.gradient_dir_deg.to_radians();
        let (dx, dy) = (dir.cos() as f32, dir.sin() as f32);
        let half = (width.max(height) as f32) / 2.0;
        for y in 0..height {
            for x in 0..width {
                let i = y * width + x;
                let ramp = ((x as f32 - width as f32 / 2.0) * dx + (y as f32 - height as f32 / 2.0) * dy) / half;
                let mut v = scene[i] * light.exposure as f32 * (1.0 + light.gradient as f32 * ramp);
                if let Some((c, r, amp)) = light.glare {
                    let d2 = (x as f64 - c.x).powi(2) + (y as f64 - c.y).powi(2);
                    if d2 < 9.0 * r * r {
                        v += (amp * (-d2 / (2.0 * r * r)).exp()) as f32 * coverage[i];
                    }
                }
                scene[i] = v;
            }
        }
    }

    /// The camera's blur and noise, to 8 bits.
    fn finish(self, light: &Lighting, rng: &mut impl Rng) -> opencv::Result<GrayImage> {
        let (width, height, scene) = (self.width, self.height, self.scene);
        let (w, h) = (width as i32, height as i32);
        let mut mat = Mat::new_rows_cols_with_data(h, w, &scene)?.try_clone()?;
        if light.blur_sigma > 0.05 {
            let mut b = Mat::default();
            imgproc::gaussian_blur(&mat, &mut b, Size::new(0, 0), light.blur_sigma, light.blur_sigma, core::BORDER_REPLICATE)?;
            mat = b;
        }
        let noise = Normal::new(0.0f32, light.noise_sigma.max(0.0) as f32).expect("noise sigma is finite");
        let data = mat.data_typed::<f32>()?;
        let out: Vec<u8> = data.iter().map(|&v| (v + noise.sample(rng)).round().clamp(0.0, 255.0) as u8).collect();
        Ok(GrayImage { data: out, width, height })
    }
}

/// Fraction of each part's material that no later-drawn part lies on (parts are drawn in order,
/// each over the ones before it): the truth's `visible_fraction`.
pub fn visible_fractions(width: usize, height: usize, parts: &[(&Prepared, Placement)]) -> opencv::Result<Vec<f64>> {
    let masks: Vec<Mat> = parts
        .iter()
        .map(|(prep, pl)| {
            let mut mask = Mat::new_rows_cols_with_default(height as i32, width as i32, core::CV_8UC1, Scalar::all(0.0))?;
            for s in &prep.model.material {
                fill(&mut mask, s, prep, pl, (0, 0), 255.0)?;
            }
            for s in &prep.model.holes {
                fill(&mut mask, s, prep, pl, (0, 0), 0.0)?;
            }
            Ok(mask)
        })
        .collect::<opencv::Result<_>>()?;
    let mut out = Vec::with_capacity(masks.len());
    for (i, m) in masks.iter().enumerate() {
        let own = m.data_bytes()?;
        let above: Vec<&[u8]> = masks[i + 1..].iter().map(|o| o.data_bytes()).collect::<opencv::Result<_>>()?;
        let (mut total, mut seen) = (0.0f64, 0.0f64);
        for (k, &v) in own.iter().enumerate() {
            if v == 0 {
                continue;
            }
            let mut f = v as f64 / 255.0;
            total += f;
            for a in &above {
                f *= 1.0 - a[k] as f64 / 255.0;
            }
            seen += f;
        }
        out.push(if total > 0.0 { seen / total } else { 1.0 });
    }
    Ok(out)
}
