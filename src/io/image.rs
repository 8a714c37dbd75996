//! RGB float images (8-bit values scaled to [0, 1], no sRGB decoding) and PNG/JPEG
//! input/output.

use std::path::Path;

/// An RGB image with `f32` channels in [0, 1], row-major, pixel (x, y) at `data[y * width + x]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// `width × height` RGB pixels, row-major.
    pub data: Vec<[f32; 3]>,
}

/// Errors reading or writing image files.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The file could not be opened or decoded ([`Image::load`]).
    #[error("cannot read image {path}: {source}")]
    Read {
        /// The file, as displayed.
        path: String,
        /// The decoder's (or the file system's) error.
        source: image::ImageError,
    },
    /// The encoded PNG could not be written to the file ([`Image::save_png`]).
    #[error("cannot write image {path}: {source}")]
    Write {
        /// The destination file, as displayed.
        path: String,
        /// The I/O error of the temporary file or the rename.
        source: std::io::Error,
    },
    /// The image could not be encoded as PNG ([`Image::save_png`]).
    #[error("cannot encode image {path}: {source}")]
    Encode {
        /// The destination file, as displayed.
        path: String,
        /// The encoder's error.
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
        self.data
            .extend(rgb.pixels().map(|p| p.0.map(|c| c as f32 * (1.0 / 255.0))));
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
        let mut png = std::io::Cursor::new(Vec::new());
        self.to_rgb8()
            .write_to(&mut png, image::ImageFormat::Png)
            .map_err(|source| ImageError::Encode {
                path: shown.clone(),
                source,
            })?;
        super::write_atomic(path, png.get_ref()).map_err(|source| ImageError::Write {
            path: shown,
            source,
        })
    }
}

/// Shrinks an 8-bit image by an integer `factor`, averaging `factor × factor` blocks with
/// rounding (edge remainders are cropped), so every output pixel sees the same footprint of
/// the original. A factor of 0 or 1 returns a copy.
pub fn box_downscale<P>(
    image: &image::ImageBuffer<P, Vec<u8>>,
    factor: u32,
) -> image::ImageBuffer<P, Vec<u8>>
where
    P: image::Pixel<Subpixel = u8>,
{
    if factor <= 1 {
        return image.clone();
    }
    let area = factor * factor;
    box_filter(image, factor, |sums, out| {
        for (dst, &sum) in out.iter_mut().zip(sums) {
            *dst = ((sum + area / 2) / area) as u8;
        }
    })
}

/// [`box_downscale`] taking the image: returned as it is (no copy) for a factor of 0 or 1.
pub fn box_downscale_owned<P>(
    image: image::ImageBuffer<P, Vec<u8>>,
    factor: u32,
) -> image::ImageBuffer<P, Vec<u8>>
where
    P: image::Pixel<Subpixel = u8>,
{
    if factor <= 1 {
        image
    } else {
        box_downscale(&image, factor)
    }
}

/// The block sums behind [`box_downscale`]: for each `factor × factor` block of `image`
/// (edge remainders cropped), in row-major order, calls `write(sums, out)` with the
/// per-channel sums of the block (`P::CHANNEL_COUNT` of them) and the output pixel's
/// `Q::CHANNEL_COUNT` bytes to fill. `factor` must be at least 1; an image smaller than one
/// block gives an empty image.
pub fn box_filter<P, Q>(
    image: &image::ImageBuffer<P, Vec<u8>>,
    factor: u32,
    mut write: impl FnMut(&[u32], &mut [u8]),
) -> image::ImageBuffer<Q, Vec<u8>>
where
    P: image::Pixel<Subpixel = u8>,
    Q: image::Pixel<Subpixel = u8>,
{
    assert!(factor >= 1, "box filter factor must be at least 1");
    let (width, height) = (image.width() / factor, image.height() / factor);
    let (k, w) = (factor as usize, width as usize);
    let (cin, cout) = (usize::from(P::CHANNEL_COUNT), usize::from(Q::CHANNEL_COUNT));
    let src: &[u8] = image.as_raw();
    let src_stride = image.width() as usize * cin;
    let mut out = image::ImageBuffer::<Q, Vec<u8>>::new(width, height);
    if width == 0 || height == 0 {
        return out; // smaller than one block: nothing to average (and no zero-size chunks)
    }
    let mut sums = vec![0u32; w * cin];
    for (y, out_row) in out.chunks_exact_mut(w * cout).enumerate() {
        sums.fill(0);
        for sy in y * k..(y + 1) * k {
            let row = &src[sy * src_stride..sy * src_stride + w * k * cin];
            for (block, sum) in row.chunks_exact(k * cin).zip(sums.chunks_exact_mut(cin)) {
                for px in block.chunks_exact(cin) {
                    for (s, &v) in sum.iter_mut().zip(px) {
                        *s += u32::from(v);
                    }
                }
            }
        }
        for (dst, sum) in out_row.chunks_exact_mut(cout).zip(sums.chunks_exact(cin)) {
            write(sum, dst);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_downscale_averages_blocks_with_rounding_and_crops_the_remainder() {
        let mut img = image::RgbImage::new(5, 4);
        for (x, y, px) in img.enumerate_pixels_mut() {
            *px = image::Rgb([(x * 10 + y) as u8, 100, 200]);
        }
        let small = box_downscale(&img, 2);
        assert_eq!(small.dimensions(), (2, 2));
        // Block (0,0): values 0,10,1,11 → mean 5.5 → rounds to 6.
        assert_eq!(small.get_pixel(0, 0).0, [6, 100, 200]);
        // Block (1,1): 22, 32, 23, 33 → 27.5 → 28.
        assert_eq!(small.get_pixel(1, 1).0, [28, 100, 200]);
        assert_eq!(box_downscale(&img, 1), img);
    }

    #[test]
    fn box_downscale_keeps_the_channel_count() {
        let rgba = image::RgbaImage::from_fn(4, 3, |x, _| image::Rgba([x as u8 * 10, 0, 255, 7]));
        let small = box_downscale(&rgba, 2);
        assert_eq!(small.dimensions(), (2, 1));
        assert_eq!(small.get_pixel(0, 0).0, [5, 0, 255, 7]);
        assert_eq!(small.get_pixel(1, 0).0, [25, 0, 255, 7]);
    }

    #[test]
    fn box_filter_hands_over_block_sums() {
        let rgba =
            image::RgbaImage::from_fn(2, 2, |x, y| image::Rgba([1, 2, 3, (x + 2 * y) as u8]));
        let out: image::GrayImage = box_filter(&rgba, 2, |sums, out| {
            assert_eq!(&sums[..3], &[4, 8, 12]);
            out[0] = sums[3] as u8;
        });
        assert_eq!(out.get_pixel(0, 0).0, [6]);
    }
}
