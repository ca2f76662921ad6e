//! Reading and writing image files: the only place that touches image codecs.

use std::path::{Path, PathBuf};

use opencv::core::{Mat, Vector};
use opencv::imgcodecs;
use opencv::prelude::*;

use crate::vision::{FrameError, GrayImage};

#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("cannot read image {path}")]
    Read { path: PathBuf, source: std::io::Error },
    #[error("image {path} is empty (0 bytes)")]
    EmptyFile { path: PathBuf },
    #[error("image {path} cannot be decoded (truncated, corrupt or not an image format OpenCV reads)")]
    Decode { path: PathBuf },
    #[error("image {path}")]
    Frame { path: PathBuf, source: FrameError },
    #[error("cannot write image {path}: {message}")]
    Write { path: PathBuf, message: String },
}

/// Decodes an encoded image (PNG, BMP, TIFF, JPEG...) into 8-bit gray; `notes` say what was
/// converted (colour, 16-bit) so the caller can log it.
pub fn decode_gray(bytes: &[u8], path: &Path) -> Result<(GrayImage, Vec<String>), ImageError> {
    if bytes.is_empty() {
        return Err(ImageError::EmptyFile { path: path.to_path_buf() });
    }
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
        std::fs::write(&junk, b"\x89PNG\r\n\x1a\nthis is not the rest of a png").unwrap();
        assert!(matches!(read_gray(&junk), Err(ImageError::Decode { .. })));
        let mut img = GrayImage::new(64, 48, 9);
        img.data[100] = 200;
        let good = dir.path().join("good.png");
        write_png(&good, &img).unwrap();
        let bytes = std::fs::read(&good).unwrap();
        let truncated = dir.path().join("truncated.png");
        std::fs::write(&truncated, &bytes[..bytes.len() / 2]).unwrap();
        assert!(read_gray(&truncated).is_err());
        let (back, notes) = read_gray(&good).unwrap();
        assert_eq!(back, img);
        assert!(notes.is_empty());
    }
}
