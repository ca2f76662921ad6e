//! Drawing estimates over a frame: what the operator and the debug output see.

use opencv::core::{self, Mat, Point, Scalar};
use opencv::imgproc;
use opencv::prelude::*;

use crate::vision::{Estimator, FrameEstimate, GrayView, Pt};

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

/// A colour picture of the frame, scaled by `scale`, with each part's outline (green accepted,
/// red rejected), the matched template's outline in blue, line features in yellow, the
/// orientation axis thick, and a label.
pub fn draw(frame: GrayView<'_>, est: &FrameEstimate, estimator: &Estimator, scale: f64) -> opencv::Result<Mat> {
    let src = frame.as_mat().map_err(|e| opencv::Error::new(core::StsError, e.to_string()))?;
    let mut small = Mat::default();
    let size = core::Size::new(
        ((frame.width() as f64) * scale).round().max(1.0) as i32,
        ((frame.height() as f64) * scale).round().max(1.0) as i32,
    );
    imgproc::resize(&src, &mut small, size, 0.0, 0.0, imgproc::INTER_AREA)?;
    let mut img = Mat::default();
    imgproc::cvt_color(&small, &mut img, imgproc::COLOR_GRAY2BGR, 0)?;
    let templates: Vec<_> = estimator.templates().collect();
    let thick = ((2.0 * scale).round() as i32).max(1);
    for p in &est.parts {
        let color = bgr(if p.accepted { GREEN } else { RED });
        if let Some((i, pose)) = p.matched
            && let Some(t) = templates.get(i)
        {
            let to_frame = pose.forward();
            let mapped: Vec<Pt> = t.outline.iter().map(|&q| to_frame.apply(q)).collect();
            poly(&mut img, &mapped, scale, bgr(BLUE), 1)?;
        }
        poly(&mut img, &p.outline, scale, color, thick)?;
        for s in &p.segments {
            line(&mut img, s.a, s.b, scale, bgr(YELLOW), 1)?;
        }
        if let Some(ax) = p.axis {
            line(&mut img, ax.a, ax.b, scale, bgr(YELLOW), 3 * thick)?;
        }
        let label = if p.accepted {
            format!(
                "{} {} {:.1} deg c={:.2}",
                p.type_name.as_deref().unwrap_or("?"),
                p.face.map(|f| f.as_str()).unwrap_or("?"),
                p.angle_deg,
                p.confidence
            )
        } else {
            format!("REJECT {}{}", p.reason, p.type_name.as_deref().map(|t| format!(" ({t})")).unwrap_or_default())
        };
        // Above the part's box, kept inside the picture.
        let (lo, _) = crate::vision::geometry::bounds(&p.outline);
        let fs = (img.cols() as f64 / 1600.0).clamp(0.35, 1.0);
        let at = Point::new(((lo.x * scale) as i32).clamp(2, (img.cols() - 200).max(2)), ((lo.y * scale) as i32 - 6).max(14));
        imgproc::put_text(
            &mut img,
            &label,
            at,
            imgproc::FONT_HERSHEY_SIMPLEX,
            fs,
            Scalar::new(0.0, 0.0, 0.0, 0.0),
            3 * thick,
            imgproc::LINE_AA,
            false,
        )?;
        imgproc::put_text(&mut img, &label, at, imgproc::FONT_HERSHEY_SIMPLEX, fs, color, thick, imgproc::LINE_AA, false)?;
    }
    Ok(img)
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
