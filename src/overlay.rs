//! Drawing estimates over a frame: what the operator and the debug output see.

use opencv::core::{self, Mat, Point, Scalar};
use opencv::imgproc;
use opencv::prelude::*;

use crate::vision::{Estimator, FrameEstimate, GrayView, Pt, Template};

const GREEN: (f64, f64, f64) = (60.0, 220.0, 60.0);
const RED: (f64, f64, f64) = (40.0, 40.0, 235.0);
const BLUE: (f64, f64, f64) = (255.0, 160.0, 40.0);
const YELLOW: (f64, f64, f64) = (0.0, 220.0, 255.0);

fn bgr(c: (f64, f64, f64)) -> Scalar {
    Scalar::new(c.0, c.1, c.2, 0.0)
}

fn poly(img: &mut Mat, pts: &[Pt], scale: f64, color: Scalar, thickness: i32) -> opencv::Result<()> {
    let v: core::Vector<Point> =
        pts.iter().map(|p| Point::new((p.x * scale * 16.0).round() as i32, (p.y * scale * 16.0).round() as i32)).collect();
    let mut all = core::Vector::<core::Vector<Point>>::new();
    all.push(v);
    imgproc::polylines(img, &all, true, color, thickness, imgproc::LINE_AA, 4)
}

fn line(img: &mut Mat, a: Pt, b: Pt, scale: f64, color: Scalar, thickness: i32) -> opencv::Result<()> {
    let p = |q: Pt| Point::new((q.x * scale * 16.0).round() as i32, (q.y * scale * 16.0).round() as i32);
    imgproc::line(img, p(a), p(b), color, thickness, imgproc::LINE_AA, 4)
}

/// A colour picture of the frame, scaled by `scale`, with every part drawn (see [`annotate`]).
pub fn draw(frame: GrayView<'_>, est: &FrameEstimate, estimator: &Estimator, scale: f64) -> opencv::Result<Mat> {
    let src = frame.as_mat().map_err(|e| opencv::Error::new(core::StsError, e.to_string()))?;
    let mut small = Mat::default();
    let size = core::Size::new(
        ((frame.width() as f64) * scale).round().max(1.0) as i32,
        ((frame.height() as f64) * scale).round().max(1.0) as i32,
    );
    imgproc::resize(&src, &mut small, size, 0.0, 0.0, imgproc::INTER_AREA)?;
    let templates: Vec<&Template> = estimator.templates().collect();
    annotate_gray(&small, est, &templates, scale, None)
}

/// [`annotate`] on a gray picture already scaled by `scale` (a history entry's).
pub fn annotate_gray(
    picture: &impl core::ToInputArray,
    est: &FrameEstimate,
    templates: &[&Template],
    scale: f64,
    highlight: Option<usize>,
) -> opencv::Result<Mat> {
    let mut img = Mat::default();
    imgproc::cvt_color(picture, &mut img, imgproc::COLOR_GRAY2BGR, 0)?;
    annotate(&mut img, est, templates, scale, highlight)?;
    Ok(img)
}

/// Draws the parts of `est` (frame pixels times `scale`) over a colour picture, numbered 1..
/// in the estimate's order (the PLC's PART_INDEX for a frame's final results): a tint over each
/// part (green accepted, red rejected), its line features thin, its outline last and thick, a
/// cross at the pick point and an arrow along its angle where it has a type, and a label on a
/// dark background. `highlight` (a part number) also draws that part's best-fit template
/// outline, labelled, in blue.
pub fn annotate(img: &mut Mat, est: &FrameEstimate, templates: &[&Template], scale: f64, highlight: Option<usize>) -> opencv::Result<()> {
    let thick = ((3.0 * scale).round() as i32).clamp(2, 4);
    // The tints first, blended once, so that everything drawn after stays crisp.
    let mut tinted = img.try_clone()?;
    for p in &est.parts {
        fill(&mut tinted, &p.outline, scale, bgr(if p.accepted { GREEN } else { RED }))?;
    }
    let mut blended = Mat::default();
    core::add_weighted(&tinted, 0.22, &*img, 0.78, 0.0, &mut blended, -1)?;
    *img = blended;
    let fs = (img.cols() as f64 / 1100.0).clamp(0.4, 0.9);
    for (i, p) in est.parts.iter().enumerate() {
        let n = i + 1;
        let color = bgr(if p.accepted { GREEN } else { RED });
        for s in &p.segments {
            line(img, s.a, s.b, scale, bgr(YELLOW), 1)?;
        }
        if highlight == Some(n)
            && let Some((ti, pose)) = p.matched
            && let Some(t) = templates.get(ti)
        {
            let to_frame = pose.forward();
            let mapped: Vec<Pt> = t.outline.iter().map(|&q| to_frame.apply(q)).collect();
            poly(img, &mapped, scale, bgr(BLUE), 2)?;
            let (lo, hi) = crate::vision::geometry::bounds(&mapped);
            label(img, &format!("best fit: {} {}", t.type_name, t.face), Pt::new(lo.x * scale, hi.y * scale + 18.0 * fs), fs, bgr(BLUE))?;
        }
        poly(img, &p.outline, scale, color, thick)?;
        let at = Pt::new(p.x, p.y);
        if p.type_name.is_some() {
            let arm = 10.0 / scale;
            line(img, at - Pt::new(arm, 0.0), at + Pt::new(arm, 0.0), scale, color, thick)?;
            line(img, at - Pt::new(0.0, arm), at + Pt::new(0.0, arm), scale, color, thick)?;
            let a = p.angle_deg.to_radians();
            let tip = at + Pt::new(a.cos(), -a.sin()).scale(45.0 / scale);
            let (s0, s1) = (to_px(at, scale), to_px(tip, scale));
            imgproc::arrowed_line(img, s0, s1, color, thick, imgproc::LINE_AA, 4, 0.25)?;
        }
        let text = if p.accepted {
            format!(
                "#{n} {} {} {:.1} deg",
                p.type_name.as_deref().unwrap_or("?"),
                p.face.map(|f| f.as_str()).unwrap_or("?"),
                crate::vision::geometry::angle_diff_deg(p.angle_deg, 0.0)
            )
        } else {
            format!("#{n} REJECT {}{}", p.reason, p.type_name.as_deref().map(|t| format!(" ({t})")).unwrap_or_default())
        };
        let (lo, _) = crate::vision::geometry::bounds(&p.outline);
        label(img, &text, Pt::new(lo.x * scale, lo.y * scale - 8.0), fs, color)?;
    }
    Ok(())
}

/// Text on a dark box at `at` (picture pixels, the text's bottom-left), kept inside the picture.
fn label(img: &mut Mat, text: &str, at: Pt, fs: f64, color: Scalar) -> opencv::Result<()> {
    let mut base = 0;
    let size = imgproc::get_text_size(text, imgproc::FONT_HERSHEY_SIMPLEX, fs, 1, &mut base)?;
    let x = (at.x as i32).clamp(2, (img.cols() - size.width - 4).max(2));
    let y = (at.y as i32).clamp(size.height + 4, (img.rows() - base - 2).max(size.height + 4));
    let bg = core::Rect::new(x - 3, y - size.height - 3, size.width + 6, size.height + base + 6);
    imgproc::rectangle(img, bg, Scalar::new(20.0, 20.0, 20.0, 0.0), imgproc::FILLED, imgproc::LINE_8, 0)?;
    imgproc::put_text(img, text, Point::new(x, y), imgproc::FONT_HERSHEY_SIMPLEX, fs, color, 1, imgproc::LINE_AA, false)
}

fn to_px(q: Pt, scale: f64) -> Point {
    Point::new((q.x * scale * 16.0).round() as i32, (q.y * scale * 16.0).round() as i32)
}

fn fill(img: &mut Mat, pts: &[Pt], scale: f64, color: Scalar) -> opencv::Result<()> {
    if pts.len() < 3 {
        return Ok(());
    }
    let mut all = core::Vector::<core::Vector<Point>>::new();
    all.push(pts.iter().map(|&p| to_px(p, scale)).collect());
    imgproc::fill_poly(img, &all, color, imgproc::LINE_AA, 4, Point::new(0, 0))
}

/// A thumbnail of a template, `size` pixels square: its outline filled and its line features
/// drawn (the knowledge base keeps features, not pictures).
pub fn thumbnail(t: &crate::vision::Template, size: i32) -> opencv::Result<Mat> {
    let (lo, hi) = crate::vision::geometry::bounds(&t.outline);
    let s = (size as f64 - 16.0) / (hi.x - lo.x).max(hi.y - lo.y).max(1.0);
    let at = |x: f64, y: f64| Point::new(((x - lo.x) * s + 8.0) as i32, ((y - lo.y) * s + 8.0) as i32);
    let mut img = Mat::new_rows_cols_with_default(size, size, core::CV_8UC3, Scalar::new(40.0, 40.0, 40.0, 0.0))?;
    let mut poly = core::Vector::<core::Vector<Point>>::new();
    poly.push(t.outline.iter().map(|p| at(p.x, p.y)).collect());
    imgproc::fill_poly(&mut img, &poly, Scalar::new(150.0, 150.0, 150.0, 0.0), imgproc::LINE_AA, 0, Point::new(0, 0))?;
    for sg in &t.segments {
        imgproc::line(&mut img, at(sg.a.x, sg.a.y), at(sg.b.x, sg.b.y), Scalar::new(0.0, 200.0, 255.0, 0.0), 1, imgproc::LINE_AA, 0)?;
    }
    Ok(img)
}

/// Lines of constant robot X and Y over a picture of the frame (frame pixels times `scale`),
/// each labelled with its millimetres: what a commissioning engineer compares with the robot's
/// touch-up. The spacing is the round number (1, 2 or 5 times a power of ten) that gives about
/// eight lines across the field; each line is drawn through the calibration point by point, so
/// a lens's curvature shows.
pub fn draw_grid(img: &mut Mat, cal: &crate::calibration::Calibration, width: usize, height: usize, scale: f64) -> opencv::Result<()> {
    let (w, h) = (width as f64 - 1.0, height as f64 - 1.0);
    // The field's extent in robot millimetres, from points around its edge.
    let mut edge = Vec::new();
    for i in 0..=20 {
        let t = i as f64 / 20.0;
        edge.extend([(t * w, 0.0), (t * w, h), (0.0, t * h), (w, t * h)]);
    }
    let mm: Vec<(f64, f64)> = edge.iter().filter_map(|&(x, y)| cal.to_robot(x, y)).collect();
    if mm.len() < 4 {
        return Ok(());
    }
    let lo = |f: fn(&(f64, f64)) -> f64| mm.iter().map(f).fold(f64::INFINITY, f64::min);
    let hi = |f: fn(&(f64, f64)) -> f64| mm.iter().map(f).fold(f64::NEG_INFINITY, f64::max);
    let (x0, x1, y0, y1) = (lo(|p| p.0), hi(|p| p.0), lo(|p| p.1), hi(|p| p.1));
    let span = (x1 - x0).max(y1 - y0);
    if !(span.is_finite() && span > 0.0) {
        return Ok(());
    }
    let raw = span / 8.0;
    let mag = 10f64.powf(raw.log10().floor());
    let step = [1.0, 2.0, 5.0, 10.0].iter().map(|m| m * mag).find(|s| *s >= raw).unwrap_or(10.0 * mag);
    let color = bgr(YELLOW);
    let inside = |p: (f64, f64)| p.0 >= 0.0 && p.1 >= 0.0 && p.0 <= w && p.1 <= h;
    // One family of lines: `fixed` runs over multiples of the step, `along` over the field.
    let mut family = |fixed: (f64, f64), along: (f64, f64), x_is_fixed: bool| -> opencv::Result<()> {
        let mut v = (fixed.0 / step).ceil() * step;
        while v <= fixed.1 {
            let n = 200;
            let mut run: Vec<Pt> = Vec::new();
            let mut first: Option<Pt> = None;
            for i in 0..=n {
                let u = along.0 + (along.1 - along.0) * i as f64 / n as f64;
                let (x, y) = if x_is_fixed { (v, u) } else { (u, v) };
                match cal.to_pixel(x, y).filter(|p| inside(*p)) {
                    Some((px, py)) => {
                        first.get_or_insert(Pt::new(px, py));
                        run.push(Pt::new(px, py));
                    }
                    None => {
                        for s in run.windows(2) {
                            line(img, s[0], s[1], scale, color, 1)?;
                        }
                        run.clear();
                    }
                }
            }
            for s in run.windows(2) {
                line(img, s[0], s[1], scale, color, 1)?;
            }
            if let Some(p) = first {
                let text = format!("{}={v:.0}", if x_is_fixed { "X" } else { "Y" });
                label(img, &text, Pt::new(p.x * scale + 4.0, p.y * scale + 14.0), 0.4, color)?;
            }
            v += step;
        }
        Ok(())
    };
    family((x0, x1), (y0, y1), true)?;
    family((y0, y1), (x0, x1), false)
}
