//! The line features' detector (`vision::fld`) finds the segments OpenCV's fast line detector
//! finds, on the edge maps of simulated and shared scenes: it replaced OpenCV's for speed, and
//! the confidence and the enrolled templates were measured with OpenCV's segments.

mod common;

use lfi_bridge::vision::{GrayImage, fld};
use opencv::core::{self, Mat, Rect, Size, Vec4f, Vector};
use opencv::imgproc;
use opencv::prelude::*;
use opencv::ximgproc::FastLineDetectorTrait;

/// The decimated (by 4), blurred Canny edge map of a frame, as the coarse stage makes one.
fn edge_map(img: &GrayImage) -> Mat {
    let v = img.view().unwrap();
    let full = Mat::new_rows_cols_with_data(v.height() as i32, v.width() as i32, v.data()).unwrap();
    let mut small = Mat::default();
    imgproc::resize(&full, &mut small, Size::new(v.width() as i32 / 4, v.height() as i32 / 4), 0.0, 0.0, imgproc::INTER_AREA).unwrap();
    let mut blurred = Mat::default();
    imgproc::gaussian_blur(&small, &mut blurred, Size::new(0, 0), 1.5, 1.5, core::BORDER_REPLICATE).unwrap();
    let mut edges = Mat::default();
    imgproc::canny(&blurred, &mut edges, 20.0, 50.0, 3, false).unwrap();
    edges
}

fn opencv_fld(roi: &impl MatTraitConst, min_len: i32) -> Vec<[f32; 4]> {
    let mut copy = Mat::default();
    roi.copy_to(&mut copy).unwrap();
    let mut fld = opencv::ximgproc::create_fast_line_detector(min_len, std::f32::consts::SQRT_2, 50.0, 50.0, 0, false).unwrap();
    let mut lines: Vector<Vec4f> = Vector::new();
    fld.detect(&copy, &mut lines).unwrap();
    lines.iter().map(|l| [l[0], l[1], l[2], l[3]]).collect()
}

fn ours(roi: &impl MatTraitConst, min_len: i32) -> Vec<[f32; 4]> {
    let mut copy = Mat::default();
    roi.copy_to(&mut copy).unwrap();
    let (w, h) = (copy.cols() as usize, copy.rows() as usize);
    let mut data = copy.data_bytes().unwrap().to_vec();
    fld::detect(&mut data, w, h, min_len as usize, std::f32::consts::SQRT_2)
}

/// Compares both detectors on `roi`; returns (segments, segments that differ).
fn compare(roi: &impl MatTraitConst, min_len: i32, what: &str) -> (usize, usize) {
    let (a, b) = (opencv_fld(roi, min_len), ours(roi, min_len));
    assert_eq!(a.len(), b.len(), "{what}, min_len {min_len}: OpenCV found {} segments, ours {}", a.len(), b.len());
    let close = |p: &[f32; 4], q: &[f32; 4]| p.iter().zip(q).all(|(x, y)| (x - y).abs() <= 1e-3);
    let mut differ = 0;
    for (p, q) in a.iter().zip(&b) {
        let reversed = [q[2], q[3], q[0], q[1]];
        assert!(close(p, q) || close(p, &reversed), "{what}, min_len {min_len}: OpenCV {p:?}, ours {q:?}");
        differ += usize::from(!close(p, q));
    }
    (a.len(), differ)
}

fn compare_frame(img: &GrayImage, what: &str) -> (usize, usize) {
    let edges = edge_map(img);
    let (mut n, mut differ) = (0, 0);
    for min_len in [3, 6, 11] {
        let (k, d) = compare(&edges, min_len, what);
        n += k;
        differ += d;
        // Boxes at odd places, as parts' boxes are.
        for (i, j) in [(0, 0), (37, 11), (101, 203), (250, 90)] {
            let r = Rect::new(i, j, (edges.cols() - i).min(231), (edges.rows() - j).min(177));
            let (k, d) = compare(&Mat::roi(&edges, r).unwrap(), min_len, what);
            n += k;
            differ += d;
        }
    }
    (n, differ)
}

#[test]
fn finds_the_segments_opencvs_fast_line_detector_finds() {
    let sim = common::simulator(5, None);
    let (mut n, mut differ) = (0, 0);
    for (i, cond) in [(0, "clean"), (1, "noise"), (2, "glare"), (4, "multi"), (5, "touching"), (6, "overlapping")] {
        let scene = sim.scene_with(i, cond).unwrap();
        let (k, d) = compare_frame(&scene.image, &format!("simulated {cond} scene {i}"));
        n += k;
        differ += d;
    }
    for set in ["samples", "samples-hard"] {
        let (dir, _) = common::shared_set(set);
        let mut names: Vec<_> = std::fs::read_dir(dir.join("images")).unwrap().map(|e| e.unwrap().path()).collect();
        names.sort();
        for path in names.iter().step_by(5) {
            let (img, _) = lfi_bridge::imageio::read_gray(path).unwrap();
            let (k, d) = compare_frame(&img, &path.display().to_string());
            n += k;
            differ += d;
        }
    }
    assert!(n > 1000, "only {n} segments compared");
    assert_eq!(differ, 0, "{differ} of {n} segments directed the other way");
    eprintln!("{n} segments compared, {differ} reversed");
}
