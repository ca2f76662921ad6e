//! Reading and writing image files: the only place that touches image codecs.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;

use crate::vision::{FrameError, GrayImage};

/// Why an image cannot be read or written; each names the file.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file cannot be read.
    #[error("cannot read image {path}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why the system refused it.
        source: std::io::Error,
    },
    /// 0 bytes.
    #[error("image {path} is empty (0 bytes)")]
    EmptyFile {
        /// The file.
        path: PathBuf,
    },
    /// No decoder makes an image of it.
    #[error("image {path} cannot be decoded (truncated, corrupt or not an image format OpenCV reads)")]
    Decode {
        /// The file.
        path: PathBuf,
    },
    /// The file stops before its format's end marker: a half-written or cut-off frame, which a
    /// decoder would otherwise fill with gray and report as an empty belt.
    #[error("image {path} is incomplete: {format} without its end marker ({len} bytes; half-written or cut off)")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its format (from its first bytes).
        format: &'static str,
        /// Its length.
        len: usize,
    },
    /// More pixels than a frame may have: refused from the header, before decoding.
    #[error("image {path} is {width} x {height} pixels, more than the {max} a frame may have")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Width its header declares.
        width: u64,
        /// Height its header declares.
        height: u64,
        /// Most pixels allowed.
        max: u64,
    },
    /// Decoded, but not a usable frame.
    #[error("image {path}")]
    Frame {
        /// The file.
        path: PathBuf,
        /// What is wrong with the frame.
        source: FrameError,
    },
    /// The file cannot be written.
    #[error("cannot write image {path}: {message}")]
    Write {
        /// The file.
        path: PathBuf,
        /// Why not.
        message: String,
    },
}

/// Most pixels a frame file may declare (a 64-MP frame; the largest machine-vision sensors have
/// about 150 MP, this product's cameras 5). Checked in the header, before anything is allocated.
pub const MAX_PIXELS: u64 = 64 << 20;

/// A PNG's first eight bytes.
const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// A PNG's last chunk: IEND, zero length, fixed CRC.
const PNG_END: [u8; 12] = [0, 0, 0, 0, b'I', b'E', b'N', b'D', 0xAE, 0x42, 0x60, 0x82];

/// The size a PNG or JPEG header declares, if it is one of those and the header is readable.
fn declared_size(bytes: &[u8]) -> Option<(u64, u64)> {
    if bytes.starts_with(PNG_SIGNATURE) && bytes.len() >= 24 && &bytes[12..16] == b"IHDR" {
        let be = |i: usize| u32::from_be_bytes([bytes[i], bytes[i + 1], bytes[i + 2], bytes[i + 3]]) as u64;
        return Some((be(16), be(20)));
    }
    if bytes.starts_with(&[0xFF, 0xD8]) {
        // Walk the marker segments to the first start-of-frame (SOF0..SOF15 but DHT, JPG, DAC).
        let mut i = 2;
        while i + 9 < bytes.len() && bytes[i] == 0xFF {
            let marker = bytes[i + 1];
            let len = u16::from_be_bytes([bytes[i + 2], bytes[i + 3]]) as usize;
            if (0xC0..=0xCF).contains(&marker) && ![0xC4, 0xC8, 0xCC].contains(&marker) {
                let h = u16::from_be_bytes([bytes[i + 5], bytes[i + 6]]) as u64;
                let w = u16::from_be_bytes([bytes[i + 7], bytes[i + 8]]) as u64;
                return Some((w, h));
            }
            i += 2 + len;
        }
    }
    None
}

/// Refuses a PNG or JPEG that stops before its end marker, and any frame whose header declares
/// more than [`MAX_PIXELS`].
fn check_complete(bytes: &[u8], path: &Path) -> Result<(), ImageError> {
    let truncated = |format| ImageError::Truncated { path: path.to_path_buf(), format, len: bytes.len() };
    if bytes.starts_with(PNG_SIGNATURE) && !bytes.ends_with(&PNG_END) {
        return Err(truncated("PNG"));
    }
    if bytes.starts_with(&[0xFF, 0xD8]) {
        // Some cameras pad a JPEG with zero bytes after its end-of-image marker.
        let end = bytes.iter().rposition(|b| *b != 0).map_or(0, |i| i + 1);
        if !bytes[..end].ends_with(&[0xFF, 0xD9]) {
            return Err(truncated("JPEG"));
        }
    }
    if let Some((width, height)) = declared_size(bytes)
        && width * height > MAX_PIXELS
    {
        return Err(ImageError::TooLarge { path: path.to_path_buf(), width, height, max: MAX_PIXELS });
    }
    Ok(())
}

/// Decodes an encoded image (PNG, BMP, TIFF, JPEG...) into 8-bit gray; `notes` say what was
/// converted (colour, 16-bit) so the caller can log it. A PNG or JPEG cut off before its end
/// is an error, never a frame (decoders fill the missing rows with gray: an empty belt).
pub fn decode_gray(bytes: &[u8], path: &Path) -> Result<(GrayImage, Vec<String>), ImageError> {
    if bytes.is_empty() {
        return Err(ImageError::EmptyFile { path: path.to_path_buf() });
    }
    check_complete(bytes, path)?;
    let buf = Vector::<u8>::from_slice(bytes);
    let mat = imgcodecs::imdecode(&buf, imgcodecs::IMREAD_UNCHANGED).map_err(|_| ImageError::Decode { path: path.to_path_buf() })?;
    if mat.empty() {
        return Err(ImageError::Decode { path: path.to_path_buf() });
    }
    GrayImage::from_mat(&mat).map_err(|source| ImageError::Frame { path: path.to_path_buf(), source })
}

/// Reads an image file into 8-bit gray.
pub fn read_gray(path: &Path) -> Result<(GrayImage, Vec<String>), ImageError> {
    let bytes = std::fs::read(path).map_err(|source| ImageError::Read { path: path.to_path_buf(), source })?;
    decode_gray(&bytes, path)
}

/// Encodes to PNG bytes.
pub fn encode_png(img: &GrayImage) -> Result<Vec<u8>, String> {
    let mat = img.to_mat().map_err(|e| e.to_string())?;
    encode_mat(&mat, ".png")
}

/// Encodes an image into a file format by extension (".png", ".jpg").
pub fn encode_mat(mat: &Mat, ext: &str) -> Result<Vec<u8>, String> {
    let mut buf = Vector::<u8>::new();
    let ok = imgcodecs::imencode(ext, mat, &mut buf, &Vector::new()).map_err(|e| e.to_string())?;
    if !ok {
        return Err(format!("OpenCV could not encode {ext}"));
    }
    Ok(buf.to_vec())
}

/// Writes a PNG file (via a temporary file and a rename, so readers never see half a file).
pub fn write_png(path: &Path, img: &GrayImage) -> Result<(), ImageError> {
    let bytes = encode_png(img).map_err(|message| ImageError::Write { path: path.to_path_buf(), message })?;
    write_atomic(path, &bytes).map_err(|e| ImageError::Write { path: path.to_path_buf(), message: e.to_string() })
}

/// Writes a file through a temporary sibling and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let tmp = path.with_file_name(format!(".{name}.tmp{}", std::process::id()));
    std::fs::write(&tmp, bytes)?;
    std::fs::rename(&tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_files_are_named_errors() {
        let dir = tempfile::tempdir().unwrap();
        let missing = dir.path().join("nope.png");
        let e = read_gray(&missing).unwrap_err();
        assert!(e.to_string().contains("nope.png"), "{e}");
        let empty = dir.path().join("empty.png");
        std::fs::write(&empty, b"").unwrap();
        assert!(matches!(read_gray(&empty), Err(ImageError::EmptyFile { .. })));
        let junk = dir.path().join("junk.png");
        std::fs::write(&junk, [&b"\x89PNG\r\n\x1a\nthis is not the rest of a png"[..], &PNG_END].concat()).unwrap();
        assert!(matches!(read_gray(&junk), Err(ImageError::Decode { .. })));
        let mut img = GrayImage::new(64, 48, 9);
        img.data[100] = 200;
        let good = dir.path().join("good.png");
        write_png(&good, &img).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let truncated = dir.path().join("truncated.png");
        std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
        assert!(matches!(read_gray(&truncated), Err(ImageError::Truncated { format: "PNG", .. })));
        let (back, notes) = read_gray(&good).unwrap();
        assert_eq!(back, img);
        assert!(notes.is_empty());
    }

    /// A frame cut off anywhere after its header (a camera still writing, a network copy
    /// interrupted) is refused by name: it must never read as an empty belt.
    #[test]
    fn a_cut_off_jpeg_or_png_is_an_error_wherever_it_stops() {
        let mut img = GrayImage::new(320, 240, 40);
        for (i, v) in img.data.iter_mut().enumerate() {
            *v = ((i * 7) % 200) as u8;
        }
        let mat = img.to_mat().unwrap();
        let path = Path::new("frame");
        for (ext, format) in [(".jpg", "JPEG"), (".png", "PNG")] {
            let bytes = encode_mat(&mat, ext).unwrap();
            assert!(decode_gray(&bytes, path).is_ok(), "{format} whole");
            for cut in [bytes.len() - 1, bytes.len() - 2, bytes.len() * 3 / 4, bytes.len() / 2, 700] {
                let e = decode_gray(&bytes[..cut], path).unwrap_err();
                assert!(matches!(e, ImageError::Truncated { format: f, .. } if f == format), "{format} cut at {cut}: {e}");
            }
        }
        let mut padded = encode_mat(&mat, ".jpg").unwrap();
        padded.extend([0u8; 64]);
        assert!(decode_gray(&padded, path).is_ok(), "a JPEG with zero padding after its end is whole");
    }

    #[test]
    fn a_frame_declaring_too_many_pixels_is_refused_before_decoding() {
        // A valid PNG header and end, no pixel data: refused from the header.
        let png = |w: u32, h: u32| {
            let mut png = [PNG_SIGNATURE, b"\x00\x00\x00\x0dIHDR"].concat();
            png.extend(w.to_be_bytes());
            png.extend(h.to_be_bytes());
            png.extend([8, 0, 0, 0, 0, 0, 0, 0, 0]);
            png.extend(PNG_END);
            png
        };
        let e = decode_gray(&png(20000, 20000), Path::new("huge.png")).unwrap_err();
        assert!(matches!(e, ImageError::TooLarge { width: 20000, height: 20000, .. }), "{e}");
        assert!(e.to_string().contains("huge.png"), "{e}");
        // The largest sizes a PNG header can declare (their product still fits in 64 bits).
        let e = decode_gray(&png(u32::MAX, u32::MAX), Path::new("max.png")).unwrap_err();
        assert!(matches!(e, ImageError::TooLarge { .. }), "{e}");
        let jpeg = encode_mat(&GrayImage::new(640, 480, 9).to_mat().unwrap(), ".jpg").unwrap();
        assert_eq!(declared_size(&jpeg), Some((640, 480)));
    }
}
