//! Errors of the dataset readers: each names the file and what was wrong in it.

use std::path::{Path, PathBuf};

use crate::scene::FieldError;

/// A dataset could not be read.
#[derive(Debug, thiserror::Error)]
pub enum DataError {
    /// The file or folder could not be opened or read.
    #[error("cannot read {}: {source}", path.display())]
    Io {
        /// The file or folder that could not be read.
        path: PathBuf,
        /// The underlying I/O error (`NotFound` for a missing image).
        source: std::io::Error,
    },
    /// The file is not valid in its format (JSON syntax, binary layout, ...).
    #[error("{}: {message}", path.display())]
    Format {
        /// The malformed file.
        path: PathBuf,
        /// What is wrong, with the line or byte offset where the reader knows it.
        message: String,
    },
    /// A field is missing or has the wrong type, shape or value.
    #[error("{}: field `{field}`: {message}", path.display())]
    Field {
        /// The file holding the field; the dataset folder when the field is one of the scene
        /// file's source settings (`downscale`, `frame_stride`, ...).
        path: PathBuf,
        /// The field's name as written in the file, with indices where it is inside an array
        /// (e.g. `k[3][7]`).
        field: String,
        /// What is wrong with it (`missing`, wrong shape, out of range, ...).
        message: String,
    },
    /// An image or mask could not be decoded.
    #[error("cannot decode image {}: {message}", path.display())]
    Image {
        /// The image or mask file.
        path: PathBuf,
        /// The decoder's error message.
        message: String,
    },
    /// An image or mask does not have the size its camera says.
    #[error("{}: image is {found_width}×{found_height} px, but its camera is {width}×{height}", path.display())]
    Size {
        /// The image or mask file.
        path: PathBuf,
        /// Expected width in pixels, at full resolution (before any downscale): the camera's, or
        /// for an N3DV frame folder the first frame's.
        width: u32,
        /// Expected height in pixels, at full resolution, like `width`.
        height: u32,
        /// Width of the decoded image in pixels.
        found_width: u32,
        /// Height of the decoded image in pixels.
        found_height: u32,
    },
    /// The dataset as a whole is unusable (no training views, ...).
    #[error("{}: {message}", path.display())]
    Dataset {
        /// The dataset's folder or the file that made it unusable.
        path: PathBuf,
        /// Why the dataset cannot be used.
        message: String,
    },
}

impl DataError {
    /// A [`DataError::Io`] for `path`.
    pub fn io(path: &Path, source: std::io::Error) -> Self {
        Self::Io {
            path: path.to_path_buf(),
            source,
        }
    }

    /// A [`DataError::Format`] for `path`.
    pub fn format(path: &Path, message: impl Into<String>) -> Self {
        Self::Format {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }

    /// A [`DataError::Field`]: `field` of `path` is wrong, as `message` says.
    pub fn field(path: &Path, field: impl Into<String>, message: impl Into<String>) -> Self {
        Self::Field {
            path: path.to_path_buf(),
            field: field.into(),
            message: message.into(),
        }
    }

    /// A [`DataError::Field`] for a data source's setting that its own check refused.
    pub fn setting(path: &Path, error: FieldError) -> Self {
        Self::field(path, error.path, error.message)
    }

    /// A [`DataError::Dataset`] for the dataset at (or the file) `path`.
    pub fn dataset(path: &Path, message: impl Into<String>) -> Self {
        Self::Dataset {
            path: path.to_path_buf(),
            message: message.into(),
        }
    }
}

/// Checks that a dataset's root (`data.path`) is a folder, naming what it is instead.
pub fn require_folder(root: &Path) -> Result<(), DataError> {
    if root.is_dir() {
        return Ok(());
    }
    let what = if root.exists() {
        "a file, but data.path names the dataset's folder"
    } else {
        "no such folder"
    };
    Err(DataError::io(
        root,
        std::io::Error::new(std::io::ErrorKind::NotFound, what),
    ))
}

/// Reads an RGB image (PNG/JPEG; alpha dropped) and checks its size when one is expected.
pub fn read_rgb8(path: &Path, expected: Option<(u32, u32)>) -> Result<image::RgbImage, DataError> {
    let img = open_image(path)?.to_rgb8();
    check_size(path, img.dimensions(), expected)?;
    Ok(img)
}

/// Checks an image file's size from its header, without decoding it (for views read later).
pub fn check_image_size(path: &Path, expected: (u32, u32)) -> Result<(), DataError> {
    check_size(path, image_dimensions(path)?, Some(expected))
}

/// An image file's size from its header, without decoding it.
pub fn image_dimensions(path: &Path) -> Result<(u32, u32), DataError> {
    image::ImageReader::open(path)
        .map_err(|e| DataError::io(path, e))?
        .with_guessed_format()
        .map_err(|e| DataError::io(path, e))?
        .into_dimensions()
        .map_err(|e| DataError::Image {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
}

/// Reads a mask image (any format; a pixel is set where its first channel is non-zero) and
/// checks its size when one is expected.
pub fn read_mask(path: &Path, expected: Option<(u32, u32)>) -> Result<Vec<bool>, DataError> {
    let img = open_image(path)?.to_luma8();
    check_size(path, img.dimensions(), expected)?;
    Ok(img.as_raw().iter().map(|&v| v > 0).collect())
}

/// Opens any image file, with the file named in the error.
pub fn open_image(path: &Path) -> Result<image::DynamicImage, DataError> {
    if !path.is_file() {
        return Err(DataError::Io {
            path: path.to_path_buf(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such file"),
        });
    }
    let bytes = std::fs::read(path).map_err(|e| DataError::io(path, e))?;
    let error = |message: String| DataError::Image {
        path: path.to_path_buf(),
        message,
    };
    if is_truncated_jpeg(&bytes) {
        return Err(error(
            "truncated JPEG (no end-of-image marker at the end of the file)".into(),
        ));
    }
    image::load_from_memory(&bytes).map_err(|e| error(e.to_string()))
}

/// Whether `bytes` are a JPEG that was cut short. The decoder fills a cut-off image with grey
/// without an error, so this checks for the end-of-image marker (FF D9) near the end of the
/// file (some writers pad after it). Inside the compressed data FF is always followed by 00 or
/// a restart marker, so FF D9 there can only be the real end.
pub(crate) fn is_truncated_jpeg(bytes: &[u8]) -> bool {
    const PADDING: usize = 4096;
    if !bytes.starts_with(&[0xFF, 0xD8]) {
        return false;
    }
    let tail = &bytes[bytes.len().saturating_sub(PADDING)..];
    !tail.windows(2).any(|w| w == [0xFF, 0xD9])
}

fn check_size(
    path: &Path,
    found: (u32, u32),
    expected: Option<(u32, u32)>,
) -> Result<(), DataError> {
    match expected {
        Some((width, height)) if (width, height) != found => Err(DataError::Size {
            path: path.to_path_buf(),
            width,
            height,
            found_width: found.0,
            found_height: found.1,
        }),
        _ => Ok(()),
    }
}

/// Reads a whole text file, with the file named in the error.
pub fn read_text(path: &Path) -> Result<String, DataError> {
    std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))
}

/// Checks that an image of `width × height` keeps at least one pixel after an integer
/// `downscale`; a smaller one would give an empty image and a camera without pixels.
pub(crate) fn check_downscale(
    path: &Path,
    (width, height): (u32, u32),
    downscale: u32,
) -> Result<(), DataError> {
    if width < downscale || height < downscale {
        return Err(DataError::dataset(
            path,
            format!("images of {width}×{height} px are too small to downscale by {downscale}"),
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::is_truncated_jpeg;

    fn jpeg() -> Vec<u8> {
        let img =
            image::RgbImage::from_fn(64, 48, |x, y| image::Rgb([x as u8 * 4, y as u8 * 5, 7]));
        let mut bytes = std::io::Cursor::new(Vec::new());
        img.write_to(&mut bytes, image::ImageFormat::Jpeg).unwrap();
        bytes.into_inner()
    }

    /// A complete JPEG (also with padding after its end marker) and a PNG pass; a JPEG cut
    /// anywhere after its header is found.
    #[test]
    fn truncated_jpegs_are_found() {
        let full = jpeg();
        assert!(!is_truncated_jpeg(&full));
        let mut padded = full.clone();
        padded.extend([0u8; 1000]);
        assert!(!is_truncated_jpeg(&padded));
        for cut in [full.len() / 3, full.len() / 2, full.len() - 2] {
            assert!(
                is_truncated_jpeg(&full[..cut]),
                "cut at {cut} of {}",
                full.len()
            );
        }
        assert!(!is_truncated_jpeg(b"\x89PNG\r\n\x1a\n"));
    }
}
