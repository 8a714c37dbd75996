//! Linear RGB float images and PNG/JPEG input/output.

use std::path::Path;

/// An RGB image with `f32` channels in [0, 1], row-major, pixel (x, y) at `data[y * width + x]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub data: Vec<[f32; 3]>,
}

/// Errors reading or writing image files.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    #[error("cannot read image {path}: {source}")]
    Read {
        path: String,
        source: image::ImageError,
    },
    #[error("cannot write image {path}: {source}")]
    Write {
        path: String,
        source: std::io::Error,
    },
    #[error("cannot encode image {path}: {source}")]
    Encode {
        path: String,
        source: image::ImageError,
    },
}

impl Image {
    /// A `width × height` image filled with `color`.
    pub fn filled(width: usize, height: usize, color: [f32; 3]) -> Self {
        Self {
            width,
            height,
            data: vec![color; width * height],
        }
    }

    /// Converts an 8-bit RGB image to `f32` in [0, 1].
    pub fn from_rgb8(rgb: &image::RgbImage) -> Self {
        let mut out = Self::filled(0, 0, [0.0; 3]);
        out.copy_from_rgb8(rgb);
        out
    }

    /// Overwrites `self` with an 8-bit RGB image, reusing the allocation.
    pub fn copy_from_rgb8(&mut self, rgb: &image::RgbImage) {
        self.width = rgb.width() as usize;
        self.height = rgb.height() as usize;
        self.data.clear();
        self.data.extend(
            rgb.pixels()
                .map(|p| p.0.map(|c| c as f32 * (1.0 / 255.0))),
        );
    }

    /// Pixel at (x, y).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> [f32; 3] {
        self.data[y * self.width + x]
    }

    /// Reads a PNG or JPEG file as RGB (alpha, if any, is dropped).
    pub fn load(path: &Path) -> Result<Self, ImageError> {
        let img = image::open(path)
            .map_err(|source| ImageError::Read {
                path: path.display().to_string(),
                source,
            })?
            .to_rgb32f();
        let (width, height) = (img.width() as usize, img.height() as usize);
        let data = img.pixels().map(|p| p.0).collect();
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// 8-bit sRGB-coded bytes (values are clamped to [0, 1] and rounded).
    pub fn to_rgb8(&self) -> image::RgbImage {
        let bytes = self
            .data
            .iter()
            .flat_map(|p| p.map(|c| (c.clamp(0.0, 1.0) * 255.0 + 0.5) as u8))
            .collect();
        image::RgbImage::from_raw(self.width as u32, self.height as u32, bytes)
            .expect("buffer size matches the image size")
    }

    /// Writes a PNG atomically (temporary file, then rename) so a crash never leaves half a file.
    pub fn save_png(&self, path: &Path) -> Result<(), ImageError> {
        let shown = path.display().to_string();
        let tmp = path.with_extension("png.tmp");
        self.to_rgb8()
            .save_with_format(&tmp, image::ImageFormat::Png)
            .map_err(|source| ImageError::Encode {
                path: shown.clone(),
                source,
            })?;
        std::fs::rename(&tmp, path).map_err(|source| ImageError::Write {
            path: shown,
            source,
        })
    }
}
