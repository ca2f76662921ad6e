//! Frames as the estimator sees them: 8-bit, single channel, borrowed.
//!
//! Cameras and files deliver colour, 16-bit and odd sizes; [`GrayImage::from_mat`] is the one
//! place that turns those into what the estimator accepts, and says what it changed so the edge
//! can log it. Anything it cannot make sense of is a [`FrameError`] naming the offending property.

use opencv::core::{self, Mat};
use opencv::prelude::*;

/// Smallest frame side the estimator works on (smaller cannot hold a part worth grasping).
pub const MIN_SIDE: usize = 32;

/// Why a frame cannot be estimated.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum FrameError {
    /// No pixels.
    #[error("empty frame (0 x 0 pixels)")]
    Empty,
    /// Smaller than the estimator can work with.
    #[error("frame is {width} x {height} pixels; at least {MIN_SIDE} x {MIN_SIDE} is needed")]
    TooSmall {
        /// Its width, pixels.
        width: usize,
        /// Its height, pixels.
        height: usize,
    },
    /// A pixel layout other than gray, BGR or BGRA.
    #[error("frame has {channels} channels; expected 1 (gray), 3 (BGR) or 4 (BGRA)")]
    Channels {
        /// Channels per pixel.
        channels: i32,
    },
    /// A sample type other than 8 or 16 bits unsigned.
    #[error("frame pixel depth {depth} is not supported; expected 8-bit or 16-bit unsigned")]
    Depth {
        /// OpenCV's name of it.
        depth: String,
    },
    /// Fewer bytes than width x height.
    #[error("frame buffer holds {len} bytes; {width} x {height} needs {needed}")]
    BufferSize {
        /// Bytes given.
        len: usize,
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
        /// Bytes needed.
        needed: usize,
    },
    /// The configured region of interest does not fit the frame the camera delivered.
    #[error(
        "region of interest [x, y, w, h] = {roi:?} does not fit the {width} x {height} frame (it needs x + w <= {width}, y + h <= {height} and w, h >= {MIN_SIDE})"
    )]
    Roi {
        /// The configured `[x, y, width, height]`.
        roi: [usize; 4],
        /// The frame's width.
        width: usize,
        /// The frame's height.
        height: usize,
    },
    /// OpenCV refused the frame (its message).
    #[error("OpenCV failed on the frame: {0}")]
    OpenCv(String),
}

impl From<opencv::Error> for FrameError {
    fn from(e: opencv::Error) -> Self {
        FrameError::OpenCv(e.to_string())
    }
}

/// A borrowed 8-bit gray frame (row-major, no padding).
#[derive(Clone, Copy)]
pub struct GrayView<'a> {
    data: &'a [u8],
    width: usize,
    height: usize,
}

impl std::fmt::Debug for GrayView<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GrayView({} x {})", self.width, self.height)
    }
}

impl<'a> GrayView<'a> {
    /// Wraps a buffer, checking its size and the minimum frame size.
    pub fn new(data: &'a [u8], width: usize, height: usize) -> Result<Self, FrameError> {
        if width == 0 || height == 0 {
            return Err(FrameError::Empty);
        }
        let needed = width.saturating_mul(height);
        if data.len() != needed {
            return Err(FrameError::BufferSize { len: data.len(), width, height, needed });
        }
        if width < MIN_SIDE || height < MIN_SIDE {
            return Err(FrameError::TooSmall { width, height });
        }
        Ok(Self { data, width, height })
    }
    /// Width, pixels.
    pub fn width(&self) -> usize {
        self.width
    }
    /// Height, pixels.
    pub fn height(&self) -> usize {
        self.height
    }
    /// Row-major pixels, `width` per row, no padding.
    pub fn data(&self) -> &'a [u8] {
        self.data
    }
    /// Pixel at integer coordinates (caller keeps them in range).
    #[inline]
    pub fn at(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }
    /// Bilinear sample with edge clamping; coordinates with pixel centres on integers.
    #[inline]
    pub fn bilinear(&self, x: f64, y: f64) -> f64 {
        let xm = (self.width - 1) as f64;
        let ym = (self.height - 1) as f64;
        let x = x.clamp(0.0, xm);
        let y = y.clamp(0.0, ym);
        // Clamped to be non-negative: truncation is the floor (and needs no libm call).
        let x0 = x as usize;
        let y0 = y as usize;
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let fx = x - x0 as f64;
        let fy = y - y0 as f64;
        let a = self.at(x0, y0) as f64;
        let b = self.at(x1, y0) as f64;
        let c = self.at(x0, y1) as f64;
        let d = self.at(x1, y1) as f64;
        let top = a + (b - a) * fx;
        let bot = c + (d - c) * fx;
        top + (bot - top) * fy
    }
    /// A zero-copy OpenCV header over this view, for calling OpenCV algorithms.
    pub fn as_mat(&self) -> Result<opencv::boxed_ref::BoxedRef<'a, Mat>, FrameError> {
        Ok(Mat::new_rows_cols_with_data(self.height as i32, self.width as i32, self.data)?)
    }
}

/// An owned 8-bit gray frame.
#[derive(Clone, PartialEq)]
pub struct GrayImage {
    /// Row-major pixels, `width` per row, no padding.
    pub data: Vec<u8>,
    /// Width, pixels.
    pub width: usize,
    /// Height, pixels.
    pub height: usize,
}

impl std::fmt::Debug for GrayImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GrayImage({} x {})", self.width, self.height)
    }
}

impl GrayImage {
    /// An image of one gray level.
    pub fn new(width: usize, height: usize, fill: u8) -> Self {
        Self { data: vec![fill; width * height], width, height }
    }
    /// A borrowed view, after checking the buffer holds width x height bytes.
    pub fn view(&self) -> Result<GrayView<'_>, FrameError> {
        GrayView::new(&self.data, self.width, self.height)
    }

    /// The `w` x `h` rectangle at (`x`, `y`), copied; None unless it lies inside the image.
    pub fn crop(&self, x: usize, y: usize, w: usize, h: usize) -> Option<GrayImage> {
        if x.checked_add(w)? > self.width || y.checked_add(h)? > self.height {
            return None;
        }
        let mut out = GrayImage::new(w, h, 0);
        for r in 0..h {
            let at = (y + r) * self.width + x;
            out.data[r * w..(r + 1) * w].copy_from_slice(&self.data[at..at + w]);
        }
        Some(out)
    }

    /// Converts any frame a camera or file may deliver into 8-bit gray, returning a note for each
    /// conversion made (colour to gray, 16 to 8 bits) so the caller can log it.
    pub fn from_mat(mat: &Mat) -> Result<(Self, Vec<String>), FrameError> {
        let mut notes = Vec::new();
        if mat.empty() || mat.rows() <= 0 || mat.cols() <= 0 {
            return Err(FrameError::Empty);
        }
        let (w, h) = (mat.cols() as usize, mat.rows() as usize);
        if w < MIN_SIDE || h < MIN_SIDE {
            return Err(FrameError::TooSmall { width: w, height: h });
        }
        let channels = mat.channels();
        let depth = mat.depth();
        let mut cur = mat.clone();
        match depth {
            core::CV_8U => {}
            core::CV_16U => {
                let mut out = Mat::default();
                // The full 16-bit range maps to 0..255: cameras deliver 10/12-bit data left-aligned
                // or right-aligned; scale by the actual maximum so both keep their contrast.
                let mut maxv = 0.0;
                core::min_max_loc(&cur.reshape(1, 0)?, None, Some(&mut maxv), None, None, &core::no_array())?;
                let scale = if maxv > 0.0 { 255.0 / maxv } else { 1.0 };
                cur.convert_to(&mut out, core::CV_8U, scale, 0.0)?;
                notes.push(format!("16-bit frame scaled to 8 bits (x{scale:.5}, max {maxv})"));
                cur = out;
            }
            d => {
                let name = match d {
                    core::CV_8S => "8-bit signed",
                    core::CV_16S => "16-bit signed",
                    core::CV_32S => "32-bit integer",
                    core::CV_32F => "32-bit float",
                    core::CV_64F => "64-bit float",
                    _ => "unknown",
                };
                return Err(FrameError::Depth { depth: name.to_string() });
            }
        }
        match channels {
            1 => {}
            3 | 4 => {
                let mut out = Mat::default();
                let code = if channels == 3 { opencv::imgproc::COLOR_BGR2GRAY } else { opencv::imgproc::COLOR_BGRA2GRAY };
                opencv::imgproc::cvt_color(&cur, &mut out, code, 0)?;
                notes.push(format!("{channels}-channel frame converted to gray"));
                cur = out;
            }
            c => return Err(FrameError::Channels { channels: c }),
        }
        let cur = if cur.is_continuous() { cur } else { cur.try_clone()? };
        let data = cur.data_bytes()?.to_vec();
        Ok((Self { data, width: w, height: h }, notes))
    }

    /// An OpenCV copy of this image (for drawing and encoding at the edges).
    pub fn to_mat(&self) -> Result<Mat, FrameError> {
        let m = Mat::new_rows_cols_with_data(self.height as i32, self.width as i32, &self.data)?;
        Ok(m.try_clone()?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rejects_bad_buffers_with_the_numbers() {
        assert_eq!(GrayView::new(&[], 0, 0).unwrap_err(), FrameError::Empty);
        let e = GrayView::new(&[0; 10], 5, 5).unwrap_err();
        assert!(e.to_string().contains("10 bytes"), "{e}");
        let one = [7u8];
        assert!(matches!(GrayView::new(&one, 1, 1), Err(FrameError::TooSmall { .. })));
    }

    #[test]
    fn converts_colour_and_16_bit() {
        let bgr = Mat::new_rows_cols_with_default(40, 50, core::CV_8UC3, core::Scalar::new(10.0, 20.0, 30.0, 0.0)).unwrap();
        let (g, notes) = GrayImage::from_mat(&bgr).unwrap();
        assert_eq!((g.width, g.height), (50, 40));
        assert_eq!(notes.len(), 1);
        let deep = Mat::new_rows_cols_with_default(40, 40, core::CV_16UC1, core::Scalar::all(4000.0)).unwrap();
        let (g, notes) = GrayImage::from_mat(&deep).unwrap();
        assert_eq!(g.data[0], 255);
        assert!(notes[0].contains("16-bit"));
        let float = Mat::new_rows_cols_with_default(40, 40, core::CV_32FC1, core::Scalar::all(1.0)).unwrap();
        assert!(matches!(GrayImage::from_mat(&float), Err(FrameError::Depth { .. })));
    }

    #[test]
    fn bilinear_interpolates_between_pixels() {
        let mut img = GrayImage::new(32, 32, 0);
        img.data[32 + 1] = 100;
        let v = img.view().unwrap();
        assert_eq!(v.bilinear(1.0, 1.0), 100.0);
        assert_eq!(v.bilinear(1.5, 1.0), 50.0);
        assert_eq!(v.bilinear(-5.0, -5.0), 0.0);
    }
}
