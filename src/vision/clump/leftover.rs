//! Material of the region that no found part explains (debris, or a part no template fits).
//!
//! The region is filled to its outer outline, so belt that parts found here close in (between a
//! fork's arms where another part lies across their ends) is inside it too: a piece whose grey
//! is the belt's, not the parts', and that the parts close in all round, is such a gap, not
//! material.

use opencv::core::{self, Mat, Point, Scalar, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::super::geometry::{Pt, area_centroid};
use super::found::Region;

/// Connected pieces of the region's material that none of `masks` explains, at least
/// `min_area` frame pixels each, belt closed in by the parts left out: (area, centroid).
pub(super) fn pieces(region: &Region<'_>, masks: &[&Mat], min_area: f64) -> opencv::Result<Vec<(f64, Pt)>> {
    let blob = region.blob;
    let mut explained = Mat::new_rows_cols_with_default(blob.mask.rows(), blob.mask.cols(), core::CV_8UC1, Scalar::all(0.0))?;
    for m in masks {
        let mut t = Mat::default();
        core::bitwise_or(&explained, *m, &mut t, &core::no_array())?;
        explained = t;
    }
    // The coarse region is dilated by the closing and outlines are good to a decimated pixel or
    // two: grow the explained material by that much, and open what is left to drop slivers.
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, core::Size::new(7, 7), Point::new(-1, -1))?;
    let mut grown = Mat::default();
    imgproc::dilate(&explained, &mut grown, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
    let mut rest = Mat::default();
    let mut inv = Mat::default();
    core::bitwise_not(&grown, &mut inv, &core::no_array())?;
    core::bitwise_and(&blob.mask, &inv, &mut rest, &core::no_array())?;
    let mut opened = Mat::default();
    imgproc::morphology_ex(
        &rest,
        &mut opened,
        imgproc::MORPH_OPEN,
        &kernel,
        Point::new(-1, -1),
        1,
        core::BORDER_CONSTANT,
        Scalar::all(0.0),
    )?;
    let mut contours: Vector<Vector<Point>> = Vector::new();
    imgproc::find_contours(&opened, &mut contours, imgproc::RETR_EXTERNAL, imgproc::CHAIN_APPROX_NONE, Point::new(0, 0))?;
    let f = region.coarse.factor as f64;
    let grey = &region.coarse.blurred;
    let outside = |x: i32, y: i32| blob.mask.at_2d::<u8>(y, x).map_or(true, |v| *v == 0);
    // The belt's grey: the decimated frame beside the region (outside its dilated mask), the
    // median, so that another part reaching into the box moves it little. Measured once, and
    // only for a piece that may be belt (most regions leave none).
    let mut belt: Option<Option<f64>> = None;
    let mut out = Vec::new();
    for c in contours.iter() {
        let pts: Vec<Pt> = c
            .iter()
            .map(|q| {
                Pt::new((q.x + blob.mask_origin.x) as f64 * f + (f - 1.0) / 2.0, (q.y + blob.mask_origin.y) as f64 * f + (f - 1.0) / 2.0)
            })
            .collect();
        if pts.len() < 3 {
            continue;
        }
        let (a, centroid) = area_centroid(&pts);
        if a.abs() < min_area {
            continue;
        }
        // Closed in: its outline runs along the region's outer outline hardly anywhere (a
        // quarter at most: a chink the closing bridged), where a part beside the others makes
        // much of it (a dark face of a part not enrolled must not pass for belt).
        let reaches = |q: Point| (-2..=2).any(|dy| (-2..=2).any(|dx| outside(q.x + dx, q.y + dy)));
        let closed_in = 4 * c.iter().filter(|&q| reaches(q)).count() <= c.len();
        // And the belt's grey within a tenth of the step from belt to part along the region's
        // outline: belt the parts close in. (Measured on the eighteen sets: belt so closed in
        // within 0.04 of the step, a belt's seam of dashes 0.17, unknown parts 0.33 and more.)
        if closed_in
            && let Some(belt) = *belt.get_or_insert_with(|| median(grey, blob.mask_origin, blob.mask.cols(), blob.mask.rows(), outside))
            && let Some(own) = own_grey(grey, &opened, &c, blob.mask_origin)?
            && (own - belt).abs() < 0.1 * region.contrast
        {
            continue;
        }
        out.push((a.abs(), centroid));
    }
    Ok(out)
}

/// The median grey of `image` over the piece of `opened` (its mask, at `origin` in the image)
/// that the external contour `c` bounds.
fn own_grey(image: &Mat, opened: &Mat, c: &Vector<Point>, origin: Point) -> opencv::Result<Option<f64>> {
    let mut piece = Mat::new_rows_cols_with_default(opened.rows(), opened.cols(), core::CV_8UC1, Scalar::all(0.0))?;
    let mut one: Vector<Vector<Point>> = Vector::new();
    one.push(c.clone());
    imgproc::draw_contours(
        &mut piece,
        &one,
        0,
        Scalar::all(255.0),
        imgproc::FILLED,
        imgproc::LINE_8,
        &core::no_array(),
        0,
        Point::new(0, 0),
    )?;
    let inside = |x: i32, y: i32| piece.at_2d::<u8>(y, x).is_ok_and(|v| *v > 0) && opened.at_2d::<u8>(y, x).is_ok_and(|v| *v > 0);
    Ok(median(image, origin, opened.cols(), opened.rows(), inside))
}

/// The median grey of `image` over the `cols` x `rows` box at `origin` where `take(x, y)` holds
/// (box coordinates), the box clipped to the image; None where it holds nowhere.
fn median(image: &Mat, origin: Point, cols: i32, rows: i32, take: impl Fn(i32, i32) -> bool) -> Option<f64> {
    let mut histogram = [0usize; 256];
    let mut n = 0usize;
    for y in 0..rows {
        for x in 0..cols {
            let (u, v) = (x + origin.x, y + origin.y);
            if u < 0 || v < 0 || u >= image.cols() || v >= image.rows() || !take(x, y) {
                continue;
            }
            if let Ok(g) = image.at_2d::<u8>(v, u) {
                histogram[*g as usize] += 1;
                n += 1;
            }
        }
    }
    let mut below = 0;
    histogram
        .iter()
        .position(|&h| {
            below += h;
            n > 0 && 2 * below > n
        })
        .map(|g| g as f64)
}
