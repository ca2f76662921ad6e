//! Stage 1: find the parts in a frame (method step 1).
//!
//! Blur, Canny with automatic hysteresis and external contours run on a decimated copy of the
//! frame: a part is hundreds of pixels across, so its silhouette is found as reliably at a quarter
//! of the resolution for a sixteenth of the cost. Precision comes back in [`super::boundary`],
//! which refines every outline on the full-resolution frame.

use opencv::core::{self, Mat, Point, Rect, Size, Vector};
use opencv::imgproc;
use opencv::prelude::*;

use super::frame::{FrameError, GrayView};
use super::geometry::{Pt, area_centroid};

/// A separated region of the frame that may be a part.
#[derive(Debug, Clone)]
pub struct Blob {
    /// Closed outline in full-frame pixels, accurate to about one decimated pixel.
    pub outline: Vec<Pt>,
    /// Area enclosed by the outline, full-frame pixels.
    pub area: f64,
    /// The region comes within a decimated pixel of the frame border: the part may be cut off.
    pub touches_border: bool,
    /// Bounding box in decimated pixels (for the line detector's region of interest).
    pub coarse_rect: Rect,
    /// The region, filled and dilated by the closing radius, in decimated pixels from
    /// (`mask_origin`): tells which line segments belong to this part.
    pub mask: Mat,
    /// Where the mask's (0, 0) lies in the decimated frame.
    pub mask_origin: Point,
}

impl Blob {
    /// Whether a frame point lies in (or within the closing radius of) the region.
    pub fn covers(&self, p: Pt, factor: usize) -> bool {
        let f = factor as f64;
        let x = ((p.x - (f - 1.0) / 2.0) / f).round() as i32 - self.mask_origin.x;
        let y = ((p.y - (f - 1.0) / 2.0) / f).round() as i32 - self.mask_origin.y;
        if x < 0 || y < 0 || x >= self.mask.cols() || y >= self.mask.rows() {
            return false;
        }
        self.mask.at_2d::<u8>(y, x).is_ok_and(|v| *v > 0)
    }
}

/// A `rows` x `cols` mask with `contour` (moved by `offset`) filled.
fn filled(rows: i32, cols: i32, contour: &Vector<Point>, offset: Point) -> opencv::Result<Mat> {
    let mut mask = Mat::new_rows_cols_with_default(rows, cols, core::CV_8UC1, core::Scalar::all(0.0))?;
    let mut one: Vector<Vector<Point>> = Vector::new();
    one.push(contour.clone());
    imgproc::draw_contours(
        &mut mask,
        &one,
        0,
        core::Scalar::all(255.0),
        imgproc::FILLED,
        imgproc::LINE_8,
        &core::no_array(),
        i32::MAX,
        offset,
    )?;
    Ok(mask)
}

/// One piece of a closed region: the piece filled, dilated as the whole region was, and within
/// the region's own mask.
fn piece_mask(region: &Mat, piece: &Vector<Point>, kernel: &Mat, offset: Point) -> opencv::Result<Mat> {
    let filled = filled(region.rows(), region.cols(), piece, offset)?;
    let mut dilated = Mat::default();
    imgproc::dilate(&filled, &mut dilated, kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, core::Scalar::all(0.0))?;
    let mut own = Mat::default();
    core::bitwise_and(&dilated, region, &mut own, &core::no_array())?;
    Ok(own)
}

/// What the coarse stage hands on.
pub struct Coarse {
    /// Decimation factor (frame pixels per decimated pixel).
    pub factor: usize,
    /// The decimated frame, unblurred (input of LSD).
    pub small: Mat,
    /// The decimated frame blurred (sigma 1.5): edge evidence for verifying part hypotheses.
    pub blurred: Mat,
    /// Canny edges of the decimated frame (input of the fast line detector).
    pub edges: Mat,
    /// Part-sized regions.
    pub blobs: Vec<Blob>,
    /// Separate pieces of material too small to be any part (bolts, washers, chips): at least
    /// [`DetectParams::min_debris_area`], below `min_area`.
    pub debris: usize,
}

/// Parameters of the coarse stage.
#[derive(Debug, Clone)]
pub struct DetectParams {
    /// Decimation factor (reduced for small frames, see [`effective_factor`]).
    pub factor: usize,
    /// Gaussian blur on the decimated frame, decimated pixels.
    pub blur_sigma: f64,
    /// Canny's low threshold as a fraction of the automatic high one.
    pub canny_low_ratio: f64,
    /// Diameter of the closing element in decimated pixels (bridges gaps in the outer edge).
    pub closing: i32,
    /// Regions enclosing less than this many frame pixels are fragments, not parts.
    pub min_area: f64,
    /// Fragments enclosing at least this many frame pixels count as debris.
    pub min_debris_area: f64,
    /// Edges of small material touching the image's edge (a stain or speck of the belt cut by
    /// it) are dropped before the closing: for a template image, where the closing made for
    /// scenes would join such material to the part and cut the part by the border. Off in scenes,
    /// where a part cut by the frame's edge is itself such an edge and is judged at the border.
    pub drop_border_specks: bool,
}

/// Edge chains touching the image's edge whose bounding box is smaller than this fraction of the
/// image's short side are a speck at the border, not a part.
const BORDER_SPECK: f64 = 0.25;

/// The longest side of a chain's bounding box below which a chain at the border is a speck.
fn speck_limit(edges: &Mat) -> i32 {
    (BORDER_SPECK * edges.cols().min(edges.rows()) as f64) as i32
}

/// How near the image's edge a chain makes its closed region touch the border: the blob's
/// border test allows 1 px and the closing's dilation adds its radius.
fn border_reach(closing: i32) -> i32 {
    1 + closing / 2
}

/// The 8-connected chains of `edges` (8-bit, 0 or 255) that come within `reach` pixels of the
/// image's edge (where their closed region would touch the border): each chain's label in
/// `labels` and the longer side of its bounding box.
fn chains_at_border(edges: &Mat, reach: i32, labels: &mut Mat) -> Result<Vec<(i32, i32)>, FrameError> {
    let (w, h) = (edges.cols(), edges.rows());
    let (mut stats, mut centroids) = (Mat::default(), Mat::default());
    let n = imgproc::connected_components_with_stats(edges, labels, &mut stats, &mut centroids, 8, core::CV_32S)?;
    let mut out = Vec::new();
    for k in 1..n {
        let at = |c: i32| stats.at_2d::<i32>(k, c).copied();
        let (x, y, bw, bh) =
            (at(imgproc::CC_STAT_LEFT)?, at(imgproc::CC_STAT_TOP)?, at(imgproc::CC_STAT_WIDTH)?, at(imgproc::CC_STAT_HEIGHT)?);
        if x <= reach || y <= reach || x + bw >= w - reach || y + bh >= h - reach {
            out.push((k, bw.max(bh)));
        }
    }
    Ok(out)
}

/// Clears from `edges` every chain at the border (within the reach of a `closing`, see
/// [`chains_at_border`]) that fits in a box of [`BORDER_SPECK`] of the image's short side.
fn drop_border_specks(edges: &mut Mat, closing: i32) -> Result<(), FrameError> {
    let limit = speck_limit(edges);
    let mut labels = Mat::default();
    let specks: Vec<i32> =
        chains_at_border(edges, border_reach(closing), &mut labels)?.into_iter().filter(|c| c.1 < limit).map(|c| c.0).collect();
    if specks.is_empty() {
        return Ok(());
    }
    for (e, l) in edges.data_bytes_mut()?.iter_mut().zip(labels.data_typed::<i32>()?) {
        if specks.contains(l) {
            *e = 0;
        }
    }
    Ok(())
}

/// Whether an edge chain larger than a speck (`BORDER_SPECK`) comes within the closing's
/// reach of the image's edge: in a template image, a part the edge cuts. Its region may not
/// touch the border at all: the cut outline is an open chain that encloses nothing, and the
/// largest region found is then something inside the part.
pub fn cut_by_border(coarse: &Coarse, closing: i32) -> Result<bool, FrameError> {
    let limit = speck_limit(&coarse.edges);
    Ok(chains_at_border(&coarse.edges, border_reach(closing), &mut Mat::default())?.iter().any(|c| c.1 >= limit))
}

/// The factor actually used: the requested one, reduced for small frames so that the decimated
/// frame keeps at least 120 pixels on its short side.
pub fn effective_factor(requested: usize, width: usize, height: usize) -> usize {
    let by_size = (width.min(height) / 120).max(1);
    requested.clamp(1, 8).min(by_size)
}

/// Maps a decimated pixel coordinate to the frame (INTER_AREA averages an f x f block).
fn to_frame(v: i32, f: usize) -> f64 {
    v as f64 * f as f64 + (f as f64 - 1.0) / 2.0
}

/// Writes the frame decimated by `f` (cropped to a multiple of f) into `out`, row-major: decimated pixel i is
/// centred on frame pixel f i + (f-1)/2, sampled bilinearly there, which for an even factor is
/// the mean of the middle 2 x 2 of each f x f block and for an odd one its middle pixel. Half
/// the cost of a full block average or of OpenCV's bilinear resize on a 5-MP frame (it reads only
/// the two middle rows of each block), and the blur that follows removes the aliasing.
fn decimate(frame: GrayView<'_>, f: usize, out: &mut [u8]) {
    let (w, sw) = (frame.width(), frame.width() / f);
    let data = frame.data();
    let mid = (f - 1) / 2;
    for (y, row) in out.chunks_exact_mut(sw.max(1)).enumerate() {
        let r0 = &data[(f * y + mid) * w..][..w];
        if f % 2 == 1 {
            for (o, a) in row.iter_mut().zip(r0.chunks_exact(f)) {
                *o = a[mid];
            }
        } else if f == 4 {
            // The usual factor: two blocks per 8-byte word of each row, their middle bytes 1, 2
            // and 5, 6 summed in 16-bit lanes.
            let r1 = &data[(f * y + mid + 1) * w..][..w];
            let mut outs = row.chunks_exact_mut(2);
            for ((o, a), b) in (&mut outs).zip(r0.chunks_exact(8)).zip(r1.chunks_exact(8)) {
                let (a, b) = (u64::from_le_bytes(a.try_into().unwrap_or([0; 8])), u64::from_le_bytes(b.try_into().unwrap_or([0; 8])));
                const MID: u64 = 0x00ff_00ff_00ff_00ff;
                // The four 16-bit lanes hold bytes 0, 2, 4, 6 (even) and 1, 3, 5, 7 (odd) of
                // both rows summed; block 0's middle is bytes 1 and 2 (odd lane 0, even lane 1),
                // block 1's bytes 5 and 6 (odd lane 2, even lane 3).
                let odd = ((a >> 8) & MID) + ((b >> 8) & MID);
                let even = (a & MID) + (b & MID);
                let m0 = (odd & 0xffff) + ((even >> 16) & 0xffff);
                let m1 = ((odd >> 32) & 0xffff) + ((even >> 48) & 0xffff);
                o[0] = ((m0 + 2) >> 2) as u8;
                o[1] = ((m1 + 2) >> 2) as u8;
            }
            let done = 2 * (sw / 2);
            for (x, o) in outs.into_remainder().iter_mut().enumerate() {
                let i = f * (done + x) + mid;
                let s = r0[i] as u16 + r0[i + 1] as u16 + r1[i] as u16 + r1[i + 1] as u16;
                *o = ((s + 2) >> 2) as u8;
            }
        } else {
            let r1 = &data[(f * y + mid + 1) * w..][..w];
            for ((o, a), b) in row.iter_mut().zip(r0.chunks_exact(f)).zip(r1.chunks_exact(f)) {
                let sum = a[mid] as u16 + a[mid + 1] as u16 + b[mid] as u16 + b[mid + 1] as u16;
                *o = ((sum + 2) >> 2) as u8;
            }
        }
    }
}

/// The histogram of 8-bit values, counted in four interleaved tables: consecutive pixels of one
/// gray level would otherwise wait on each other's increment (a quarter of the coarse stage's
/// time went to this loop).
pub(crate) fn histogram(pixels: &[u8]) -> [u32; 256] {
    let mut part = [[0u32; 256]; 4];
    let mut quads = pixels.chunks_exact(4);
    for q in &mut quads {
        part[0][q[0] as usize] += 1;
        part[1][q[1] as usize] += 1;
        part[2][q[2] as usize] += 1;
        part[3][q[3] as usize] += 1;
    }
    for &v in quads.remainder() {
        part[0][v as usize] += 1;
    }
    let mut hist = part[0];
    for p in &part[1..] {
        for (h, c) in hist.iter_mut().zip(p) {
            *h += c;
        }
    }
    hist
}

/// Otsu's level of an 8-bit image: the gray level that best splits its histogram into two
/// classes (the largest between-class variance; the first of equals), as OpenCV's
/// `THRESH_OTSU` finds it, without writing the thresholded image it has no use for here.
fn otsu_level(pixels: &[u8]) -> f64 {
    let hist = histogram(pixels);
    let n = pixels.len().max(1) as f64;
    let mu: f64 = hist.iter().enumerate().map(|(i, &c)| i as f64 * c as f64).sum::<f64>() / n;
    let (mut q1, mut mu1, mut best, mut level) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for (i, &c) in hist.iter().enumerate() {
        let p = c as f64 / n;
        let q1_before = q1;
        q1 += p;
        let q2 = 1.0 - q1;
        if q1.min(q2) < f32::EPSILON as f64 || q1.max(q2) > 1.0 - f32::EPSILON as f64 {
            continue;
        }
        mu1 = (mu1 * q1_before + i as f64 * p) / q1;
        let mu2 = (mu - q1 * mu1) / q2;
        let between = q1 * q2 * (mu1 - mu2) * (mu1 - mu2);
        if between > best {
            best = between;
            level = i as f64;
        }
    }
    level
}

/// Median Sobel (L1) gradient magnitude of an 8-bit image, from central differences on every
/// fourth row and second column: the typical gradient of the belt's texture and noise, which
/// covers most of a frame.
fn median_gradient(img: &Mat) -> Result<f64, FrameError> {
    let (w, h) = (img.cols() as usize, img.rows() as usize);
    if w < 3 || h < 3 {
        return Ok(0.0);
    }
    let d = img.data_bytes()?;
    let mut hist = vec![0u32; 2048];
    let mut count = 0u32;
    for y in (1..h - 1).step_by(4) {
        for x in (1..w - 1).step_by(2) {
            let gx = (d[y * w + x + 1] as i32 - d[y * w + x - 1] as i32).unsigned_abs();
            let gy = (d[(y + 1) * w + x] as i32 - d[(y - 1) * w + x] as i32).unsigned_abs();
            // Sobel's kernels weigh a central difference about four times.
            hist[(4 * (gx + gy)).min(2047) as usize] += 1;
            count += 1;
        }
    }
    let mut acc = 0;
    for (v, c) in hist.iter().enumerate() {
        acc += c;
        if 2 * acc >= count {
            return Ok(v as f64);
        }
    }
    Ok(0.0)
}

/// Finds the part regions.
///
/// The automatic Canny threshold is the smaller of Otsu's level on the blurred decimated frame
/// (the classic choice: edges as strong as the part/belt contrast) and six times the frame's
/// median gradient (at least 24): a part's dark rim, or a frame washed out by glare, can leave
/// the outer edge far below Otsu's level while still standing well clear of the belt's texture.
pub fn detect(frame: GrayView<'_>, p: &DetectParams) -> Result<Coarse, FrameError> {
    let f = effective_factor(p.factor, frame.width(), frame.height());
    let (sw, sh) = (frame.width() / f, frame.height() / f);
    let full = frame.as_mat()?;
    let small = if f == 1 {
        full.try_clone()?
    } else {
        let mut small = Mat::new_rows_cols_with_default(sh as i32, sw as i32, core::CV_8UC1, core::Scalar::all(0.0))?;
        decimate(frame, f, small.data_bytes_mut()?);
        small
    };
    let mut blurred = Mat::default();
    // Kernel to +-2.5 sigma (OpenCV's default for 8-bit goes to +-3 sigma at twice the cost for
    // weights below 2 %).
    let ks = 2 * (2.5 * p.blur_sigma).ceil() as i32 + 1;
    imgproc::gaussian_blur(&small, &mut blurred, Size::new(ks, ks), p.blur_sigma, p.blur_sigma, core::BORDER_REPLICATE)?;
    let otsu = otsu_level(blurred.data_bytes()?);
    let auto = otsu.min((6.0 * median_gradient(&blurred)?).max(24.0));
    let mut edges = Mat::default();
    imgproc::canny(&blurred, &mut edges, p.canny_low_ratio * auto, auto, 3, false)?;
    if p.drop_border_specks {
        drop_border_specks(&mut edges, p.closing)?;
    }
    let kernel = imgproc::get_structuring_element(imgproc::MORPH_ELLIPSE, Size::new(p.closing, p.closing), Point::new(-1, -1))?;
    let mut dilated = Mat::default();
    imgproc::dilate(&edges, &mut dilated, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, core::Scalar::all(0.0))?;
    let mut contours: Vector<Vector<Point>> = Vector::new();
    imgproc::find_contours(&dilated, &mut contours, imgproc::RETR_EXTERNAL, imgproc::CHAIN_APPROX_NONE, Point::new(0, 0))?;

    let touches = |r: Rect| r.x <= 1 || r.y <= 1 || r.x + r.width >= sw as i32 - 1 || r.y + r.height >= sh as i32 - 1;
    let min_coarse_area = p.min_area / (f * f) as f64;
    let min_coarse_debris = p.min_debris_area / (f * f) as f64;
    let mut blobs = Vec::new();
    let mut debris = 0;
    for c in contours.iter() {
        let area = imgproc::contour_area(&c, false)?;
        if area < min_coarse_area {
            debris += (area >= min_coarse_debris) as usize;
            continue;
        }
        let r = imgproc::bounding_rect(&c)?;
        let touches_border = touches(r);
        // Fill the dilated region and erode it back: the closing of the part's edge map.
        let m = 2 + p.closing;
        let mask = filled(r.height + 2 * m, r.width + 2 * m, &c, Point::new(m - r.x, m - r.y))?;
        let mut closed = Mat::default();
        imgproc::erode(&mask, &mut closed, &kernel, Point::new(-1, -1), 1, core::BORDER_CONSTANT, core::Scalar::all(0.0))?;
        let mut inner: Vector<Vector<Point>> = Vector::new();
        imgproc::find_contours(&closed, &mut inner, imgproc::RETR_EXTERNAL, imgproc::CHAIN_APPROX_NONE, Point::new(r.x - m, r.y - m))?;
        // Parts that lie within the closing's reach of each other share one dilated region
        // and come apart again in the erosion: each piece is a region of its own (keeping only
        // the largest lost the others without a word), with its own share of the mask.
        let pieces: Vec<(Vector<Point>, f64)> = inner
            .iter()
            .filter(|c| c.len() >= 8)
            .map(|c| {
                let a = imgproc::contour_area(&c, false).unwrap_or(0.0);
                (c, a)
            })
            .collect();
        let sizeable = pieces.iter().filter(|(_, a)| *a >= min_coarse_area).count();
        for (c, a) in pieces {
            if a < min_coarse_area {
                // A fragment the closing cut off a part's region: debris only when it is one.
                debris += (sizeable > 1 && a >= min_coarse_debris) as usize;
                continue;
            }
            let outline: Vec<Pt> = c.iter().map(|q| Pt::new(to_frame(q.x, f), to_frame(q.y, f))).collect();
            let (area, _) = area_centroid(&outline);
            if area.abs() < p.min_area {
                continue;
            }
            let own = if sizeable > 1 { piece_mask(&mask, &c, &kernel, Point::new(m - r.x, m - r.y))? } else { mask.try_clone()? };
            let (own_rect, at_border) = if sizeable > 1 {
                let b = imgproc::bounding_rect(&c)?;
                let (x0, y0) = ((b.x - p.closing).max(r.x), (b.y - p.closing).max(r.y));
                let (x1, y1) = ((b.x + b.width + p.closing).min(r.x + r.width), (b.y + b.height + p.closing).min(r.y + r.height));
                let own = Rect::new(x0, y0, x1 - x0, y1 - y0);
                (own, touches(own))
            } else {
                (r, touches_border)
            };
            blobs.push(Blob {
                outline,
                area: area.abs(),
                touches_border: at_border,
                coarse_rect: own_rect,
                mask: own,
                mask_origin: Point::new(r.x - m, r.y - m),
            });
        }
    }
    Ok(Coarse { factor: f, small, blurred, edges, blobs, debris })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vision::frame::GrayImage;

    /// The level is OpenCV's: on a two-class image with noise, on a flat one, and on a ramp.
    #[test]
    fn otsu_level_is_opencv_s() {
        let mut seed = 7u64;
        let mut next = || {
            seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (seed >> 33) as u32
        };
        let images: Vec<Vec<u8>> = vec![
            (0..40_000).map(|i| if i % 3 == 0 { 180 + (next() % 40) as u8 } else { 40 + (next() % 50) as u8 }).collect(),
            vec![77; 1000],
            (0..=255).cycle().take(5000).map(|v| v as u8).collect(),
        ];
        for img in images {
            let m = Mat::new_rows_cols_with_data(1, img.len() as i32, &img).unwrap();
            let mut out = Mat::default();
            let cv = imgproc::threshold(&m, &mut out, 0.0, 255.0, imgproc::THRESH_BINARY | imgproc::THRESH_OTSU).unwrap();
            assert_eq!(otsu_level(&img), cv, "first pixels {:?}", &img[..4]);
        }
    }

    /// The word-wise path of the usual factor 4 gives what the plain block loop gives, at even
    /// and odd decimated widths; the histogram's four tables add up to the plain count.
    #[test]
    fn decimation_by_four_and_the_histogram_are_the_plain_loops() {
        let mut seed = 11u64;
        for (w, h) in [(64usize, 32usize), (70, 33), (2592, 36)] {
            let img = GrayImage {
                width: w,
                height: h,
                data: (0..w * h)
                    .map(|_| {
                        seed = seed.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                        (seed >> 56) as u8
                    })
                    .collect(),
            };
            let mut fast = vec![0u8; (w / 4) * (h / 4)];
            decimate(img.view().unwrap(), 4, &mut fast);
            let plain: Vec<u8> = (0..h / 4)
                .flat_map(|y| {
                    let img = &img;
                    (0..w / 4).map(move |x| {
                        let at = |r: usize, c: usize| img.data[(4 * y + r) * w + 4 * x + c] as u16;
                        ((at(1, 1) + at(1, 2) + at(2, 1) + at(2, 2) + 2) >> 2) as u8
                    })
                })
                .collect();
            assert_eq!(fast, plain, "{w} x {h}");
            let mut count = [0u32; 256];
            img.data.iter().for_each(|&v| count[v as usize] += 1);
            assert_eq!(histogram(&img.data), count, "{w} x {h}");
        }
    }

    /// Two plates whose corners come within the closing's reach: the closing joins them over a
    /// narrow neck and its erosion parts them again. Each is a region with its own mask;
    /// neither is dropped (keeping only the larger lost the other without a word).
    #[test]
    fn pieces_the_closing_parts_again_are_each_a_region() {
        let (w, h) = (1200, 1100);
        let mut img = GrayImage::new(w, h, 50);
        let mut fill = |x0: usize, x1: usize, y0: usize, y1: usize| {
            for y in y0..y1 {
                for x in x0..x1 {
                    img.data[y * w + x] = 180;
                }
            }
        };
        fill(150, 500, 200, 600);
        fill(510, 900, 610, 950);
        let p = DetectParams {
            factor: 4,
            blur_sigma: 1.5,
            canny_low_ratio: 0.4,
            closing: 5,
            min_area: 20_000.0,
            min_debris_area: 500.0,
            drop_border_specks: false,
        };
        let c = detect(img.view().unwrap(), &p).unwrap();
        let mut areas: Vec<f64> = c.blobs.iter().map(|b| b.area).collect();
        areas.sort_by(f64::total_cmp);
        assert_eq!(areas.len(), 2, "regions {areas:?}");
        assert!((areas[0] - 390.0 * 340.0).abs() < 0.1 * 390.0 * 340.0, "the smaller plate: {areas:?}");
        assert!((areas[1] - 350.0 * 400.0).abs() < 0.1 * 350.0 * 400.0, "the larger plate: {areas:?}");
        // Each mask holds its own plate and not the other's.
        let (small, large) = if c.blobs[0].area < c.blobs[1].area { (&c.blobs[0], &c.blobs[1]) } else { (&c.blobs[1], &c.blobs[0]) };
        let (in_small, in_large) = (Pt::new(705.0, 780.0), Pt::new(325.0, 400.0));
        assert!(small.covers(in_small, c.factor) && !small.covers(in_large, c.factor));
        assert!(large.covers(in_large, c.factor) && !large.covers(in_small, c.factor));
    }
}
