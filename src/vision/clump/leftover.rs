//! Material of the region that no found part explains (debris, or a part no template fits).

use opencv::core::{self, Mat, Point, Scalar, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::super::geometry::{Pt, area_centroid};
use super::found::Region;

/// Connected pieces of the region's material that none of `masks` explains, at least
/// `min_area` frame pixels each: (area, centroid).
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
    imgproc::find_contours(&opened, &mut contours, imgproc::RETR_EXTERNAL, imgproc::CHAIN_APPROX_SIMPLE, Point::new(0, 0))?;
    let f = region.coarse.factor as f64;
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
        let (a, c) = area_centroid(&pts);
        if a.abs() >= min_area {
            out.push((a.abs(), c));
        }
    }
    Ok(out)
}
