//! Found parts as filled masks on the region's decimated grid: what the vote's second round
//! leaves out, which explanations are one physical part, where one part lies over another.

use opencv::core::{self, Mat, Point, Scalar, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::super::detect::Blob;
use super::super::geometry::Pt;
use super::super::template::Library;
use super::found::{Found, Region};

/// The stretch of the region's outline (`scene`) that no part `found` so far explains: outside
/// the found parts' material (`masks`) grown by twice the widest tolerance (a region outline
/// point farther out is no part's; a cheaper look than a distance to every placed outline).
pub(super) fn unexplained(scene: &[(Pt, usize, i32)], found: &[Found], masks: &[Mat], region: &Region<'_>) -> Vec<(Pt, usize, i32)> {
    let f = region.coarse.factor;
    if found.is_empty() {
        return scene.to_vec();
    }
    if masks.iter().any(|m| m.empty()) {
        return Vec::new();
    }
    let reach = found.iter().map(|x| 2.0 * x.tolerance * x.reg.pose.scale).fold(0.0, f64::max);
    let size = 2 * (reach / f as f64).ceil() as i32 + 1;
    let near = masks
        .iter()
        .try_fold(Mat::default(), |acc, m| -> opencv::Result<Mat> {
            if acc.empty() {
                return m.try_clone();
            }
            let mut both = Mat::default();
            core::bitwise_or(&acc, m, &mut both, &core::no_array())?;
            Ok(both)
        })
        .and_then(|m| dilate(&m, size));
    match near {
        Ok(near) => scene.iter().copied().filter(|&(p, _, _)| !at_mask(&near, region.blob, p, f)).collect(),
        Err(_) => Vec::new(),
    }
}

/// The found part's filled outline at its pose, in the blob's mask coordinates.
pub(super) fn mask_of(lib: &Library, f: &Found, blob: &Blob, factor: usize) -> opencv::Result<Mat> {
    let t = &lib.entries[f.entry].template;
    let mut mask = Mat::new_rows_cols_with_default(blob.mask.rows(), blob.mask.cols(), core::CV_8UC1, Scalar::all(0.0))?;
    let to_frame = f.reg.pose.forward();
    let poly: Vector<Point> = t
        .outline
        .iter()
        .step_by(2)
        .map(|&q| {
            let p = to_frame.apply(q);
            let (u, v) = to_mask(p, factor, blob);
            Point::new((u * 16.0).round() as i32, (v * 16.0).round() as i32)
        })
        .collect();
    let mut polys: Vector<Vector<Point>> = Vector::new();
    polys.push(poly);
    imgproc::fill_poly(&mut mask, &polys, Scalar::all(255.0), imgproc::LINE_8, 4, Point::new(0, 0))?;
    Ok(mask)
}

pub(super) fn erode(m: &Mat, size: i32) -> opencv::Result<Mat> {
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, core::Size::new(size, size), Point::new(-1, -1))?;
    let mut out = Mat::default();
    imgproc::erode(m, &mut out, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
    Ok(out)
}

pub(super) fn dilate(m: &Mat, size: i32) -> opencv::Result<Mat> {
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, core::Size::new(size, size), Point::new(-1, -1))?;
    let mut out = Mat::default();
    imgproc::dilate(m, &mut out, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, Scalar::all(0.0))?;
    Ok(out)
}

pub(super) fn to_mask(p: Pt, factor: usize, blob: &Blob) -> (f64, f64) {
    let f = factor as f64;
    ((p.x - (f - 1.0) / 2.0) / f - blob.mask_origin.x as f64, (p.y - (f - 1.0) / 2.0) / f - blob.mask_origin.y as f64)
}

pub(super) fn at_mask(mask: &Mat, blob: &Blob, p: Pt, factor: usize) -> bool {
    let (u, v) = to_mask(p, factor, blob);
    let (x, y) = (u.round() as i32, v.round() as i32);
    x >= 0 && y >= 0 && x < mask.cols() && y < mask.rows() && mask.at_2d::<u8>(y, x).is_ok_and(|v| *v > 0)
}

pub(super) fn overlap(a: &Mat, b: &Mat) -> f64 {
    let mut both = Mat::default();
    if core::bitwise_and(a, b, &mut both, &core::no_array()).is_err() {
        return 0.0;
    }
    core::count_non_zero(&both).unwrap_or(0) as f64
}
