//! Stage 2: line features (method step 2) and the LFI descriptor (step 3).
//!
//! Segments are found on the decimated frame inside the part's box only: they are needed for the
//! orientation axis, the descriptor and the confidence, none of which improves with more pixels
//! than the outline refinement already used.
//!
//! Two detectors are available ([`LineDetector`]). LSD is the method's. The fast line detector
//! (FLD, [`super::fld`]) fed the Canny edge map that detection already computed is the default:
//! on a flange-sized box (207 x 169 decimated pixels) OpenCV's FLD took 1.4 ms where LSD took
//! 2.3-3.5 ms (one thread, release build); ours finds the same segments with an eighth of the
//! instructions (18.6 M -> 2.3 M on the bench's four-part frame, whose lines stage fell from 2.7
//! to 0.6 ms). FLD reports no region width, so its support area is its length times one
//! decimated pixel: the axis becomes the longest segment.

use opencv::core::{self, Mat, Rect, Vec4f, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::detect::Blob;
use super::fld;
use super::frame::FrameError;
use super::geometry::{Pt, line_angle_between};

/// A line segment in frame pixels, with the width of the LSD support region.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    /// One end.
    pub a: Pt,
    /// The other end.
    pub b: Pt,
    /// Width of the detector's support region, pixels.
    pub width: f64,
}

impl Segment {
    /// Length, pixels.
    pub fn len(&self) -> f64 {
        (self.b - self.a).norm()
    }
    /// Whether both ends coincide.
    pub fn is_empty(&self) -> bool {
        self.len() == 0.0
    }
    /// The midpoint.
    pub fn mid(&self) -> Pt {
        (self.a + self.b).scale(0.5)
    }
    /// Direction as displayed, radians.
    pub fn direction(&self) -> f64 {
        (self.b - self.a).display_angle()
    }
    /// LSD's support area: the method's measure of how much evidence backs the segment.
    pub fn support(&self) -> f64 {
        self.len() * self.width
    }
}

/// One entry of the LFI descriptor: a segment seen from the part's log-polar frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineFeature {
    /// log of the midpoint's distance from the centroid.
    pub r: f64,
    /// Midpoint angle from the orientation axis, radians in [0, 2 pi).
    pub phi: f64,
    /// Segment length, frame pixels.
    pub len: f64,
}

/// Which line segment detector runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineDetector {
    /// Fast line detector on the detection stage's Canny edges.
    Fld,
    /// Line segment detector on the decimated frame.
    Lsd,
}

/// Segments of a part, mapped to the frame, keeping those at least `min_len` long whose
/// midpoint the part's region covers. `small` is the decimated frame, `edges` its Canny map.
pub fn part_segments(
    detector: LineDetector,
    small: &Mat,
    edges: &Mat,
    factor: usize,
    blob: &Blob,
    min_len: f64,
) -> Result<Vec<Segment>, FrameError> {
    let rect = blob.coarse_rect;
    let pad = 3;
    let x0 = (rect.x - pad).max(0);
    let y0 = (rect.y - pad).max(0);
    let x1 = (rect.x + rect.width + pad).min(small.cols());
    let y1 = (rect.y + rect.height + pad).min(small.rows());
    if x1 - x0 < 8 || y1 - y0 < 8 {
        return Ok(Vec::new());
    }
    let r = Rect::new(x0, y0, x1 - x0, y1 - y0);
    let f = factor as f64;
    let (lines, widths): (Vec<fld::Line>, Vec<f64>) = match detector {
        LineDetector::Lsd => {
            let roi = Mat::roi(small, r)?;
            let mut lsd = imgproc::create_line_segment_detector_def()?;
            let mut lines: Vector<Vec4f> = Vector::new();
            let mut widths = Mat::default();
            lsd.detect(&roi, &mut lines, &mut widths, &mut core::no_array(), &mut core::no_array())?;
            let widths = if widths.empty() {
                vec![1.0; lines.len()]
            } else {
                let mut w64 = Mat::default();
                widths.convert_to(&mut w64, core::CV_64F, 1.0, 0.0)?;
                w64.data_typed::<f64>()?.to_vec()
            };
            (lines.iter().map(|l| [l[0], l[1], l[2], l[3]]).collect(), widths)
        }
        LineDetector::Fld => {
            // The detector clears the edge pixels it traces: it gets a copy of the box, the map
            // is shared by parts. No merging of collinear pieces: it triples the cost and the
            // confidence tolerates fragments.
            let mut roi = Mat::roi(edges, r)?.try_clone()?.data_bytes()?.to_vec();
            let min_coarse = (min_len / f).max(3.0) as usize;
            let lines = fld::detect(&mut roi, r.width as usize, r.height as usize, min_coarse, std::f32::consts::SQRT_2);
            let widths = vec![1.0; lines.len()];
            (lines, widths)
        }
    };
    let off = (f - 1.0) / 2.0;
    let map = |x: f32, y: f32, ox: i32, oy: i32| Pt::new((x as f64 + ox as f64) * f + off, (y as f64 + oy as f64) * f + off);
    let mut out = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let s = Segment { a: map(l[0], l[1], x0, y0), b: map(l[2], l[3], x0, y0), width: widths.get(i).copied().unwrap_or(1.0) * f };
        if s.len() < min_len {
            continue;
        }
        if blob.covers(s.mid(), factor) {
            out.push(s);
        }
    }
    Ok(out)
}

/// The orientation axis: the segment with the largest support area (length x width).
pub fn orientation_axis(segments: &[Segment]) -> Option<Segment> {
    segments.iter().copied().max_by(|a, b| a.support().total_cmp(&b.support()))
}

/// The LFI descriptor: segment midpoints in the log-polar frame at `center` aligned to the axis
/// direction `theta`, sorted by (r, phi).
pub fn descriptor(segments: &[Segment], center: Pt, theta: f64) -> Vec<LineFeature> {
    let mut d: Vec<LineFeature> = segments
        .iter()
        .map(|s| {
            let v = s.mid() - center;
            LineFeature { r: v.norm().max(1e-9).ln(), phi: (v.display_angle() - theta).rem_euclid(std::f64::consts::TAU), len: s.len() }
        })
        .collect();
    d.sort_by(|a, b| a.r.total_cmp(&b.r).then(a.phi.total_cmp(&b.phi)));
    d
}

/// Error of one expected segment against the segments found: mean distance of its endpoints from
/// the best overlapping found segment's line, relative to `size`; 1 when nothing overlaps or the
/// directions differ by more than 20 degrees.
pub fn segment_error(expected: &Segment, found: &[Segment], size: f64) -> f64 {
    let mut best = 1.0f64;
    let dir = expected.direction();
    let mid = expected.mid();
    for s in found {
        if line_angle_between(dir, s.direction()) > 20f64.to_radians() {
            continue;
        }
        let l = s.len();
        if l <= 0.0 {
            continue;
        }
        let u = (s.b - s.a).scale(1.0 / l);
        let t = (mid - s.a).dot(u);
        if t < -0.25 * l || t > 1.25 * l {
            continue;
        }
        let nrm = Pt::new(-u.y, u.x);
        let d = ((expected.a - s.a).dot(nrm).abs() + (expected.b - s.a).dot(nrm).abs()) / 2.0;
        best = best.min(d / size);
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_is_the_segment_with_most_support() {
        let s = |x: f64, w: f64| Segment { a: Pt::new(0.0, 0.0), b: Pt::new(x, 0.0), width: w };
        let segs = [s(10.0, 3.0), s(20.0, 1.0), s(12.0, 2.0)];
        assert_eq!(orientation_axis(&segs).unwrap(), segs[0]);
    }

    #[test]
    fn descriptor_is_sorted_and_rotation_relative() {
        let c = Pt::new(100.0, 100.0);
        let segs = [
            Segment { a: Pt::new(140.0, 90.0), b: Pt::new(140.0, 110.0), width: 2.0 },
            Segment { a: Pt::new(100.0, 80.0), b: Pt::new(110.0, 80.0), width: 2.0 },
        ];
        let d = descriptor(&segs, c, 0.0);
        assert!(d[0].r < d[1].r);
        // The nearer segment's midpoint (105, 80) is above the centre: about 76 degrees.
        assert!((d[0].phi.to_degrees() - 75.96).abs() < 0.1);
        let turned = descriptor(&segs, c, 0.5);
        assert!(((d[0].phi - turned[0].phi).rem_euclid(std::f64::consts::TAU) - 0.5).abs() < 1e-9);
    }

    #[test]
    fn segment_error_measures_offset_and_rejects_crossing_lines() {
        let found = [Segment { a: Pt::new(0.0, 0.0), b: Pt::new(100.0, 0.0), width: 2.0 }];
        let near = Segment { a: Pt::new(10.0, 2.0), b: Pt::new(60.0, 2.0), width: 2.0 };
        assert!((segment_error(&near, &found, 100.0) - 0.02).abs() < 1e-12);
        let across = Segment { a: Pt::new(50.0, -20.0), b: Pt::new(50.0, 20.0), width: 2.0 };
        assert_eq!(segment_error(&across, &found, 100.0), 1.0);
    }
}
