//! Mean squared error and peak signal-to-noise ratio for images in [0, 1].

use super::{assert_mask_size, assert_same_size};
use crate::io::image::Image;

/// Squared difference summed over the three channels of one pixel, in `f64`.
#[inline]
fn sq_diff(p: [f32; 3], q: [f32; 3]) -> f64 {
    (0..3).map(|c| (p[c] as f64 - q[c] as f64).powi(2)).sum()
}

/// PSNR (dB) for a peak value of 1 from a mean squared error; infinite when `mse` is 0.
#[inline]
fn psnr_from_mse(mse: f64) -> f32 {
    if mse <= 0.0 {
        f32::INFINITY
    } else {
        (-10.0 * mse.log10()) as f32
    }
}

/// Mean squared error over all pixels and channels (accumulated in `f64`; 0 for empty images).
///
/// Panics if the images differ in size.
pub fn mse(a: &Image, b: &Image) -> f32 {
    assert_same_size(a, b);
    let n = a.data.len() * 3;
    if n == 0 {
        return 0.0;
    }
    let sum: f64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(&p, &q)| sq_diff(p, q))
        .sum();
    (sum / n as f64) as f32
}

/// PSNR in dB, `10·log10(1 / mse)` over all channels; `f32::INFINITY` for identical images.
///
/// Panics if the images differ in size.
pub fn psnr(a: &Image, b: &Image) -> f32 {
    assert_same_size(a, b);
    let n = a.data.len() * 3;
    if n == 0 {
        return f32::INFINITY;
    }
    let sum: f64 = a
        .data
        .iter()
        .zip(&b.data)
        .map(|(&p, &q)| sq_diff(p, q))
        .sum();
    psnr_from_mse(sum / n as f64)
}

/// PSNR in dB over the pixels where `mask` is true (all three channels); `None` when no pixel is
/// selected, `Some(f32::INFINITY)` when the selected pixels are identical.
///
/// Panics if the images differ in size or the mask length is not `width·height`.
pub fn masked_psnr(a: &Image, b: &Image, mask: &[bool]) -> Option<f32> {
    assert_same_size(a, b);
    assert_mask_size(a, mask);
    let (sum, count) = a
        .data
        .iter()
        .zip(&b.data)
        .zip(mask)
        .filter(|&(_, &m)| m)
        .fold((0.0f64, 0usize), |(s, k), ((&p, &q), _)| {
            (s + sq_diff(p, q), k + 1)
        });
    (count > 0).then(|| psnr_from_mse(sum / (3 * count) as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy(w: usize, h: usize, seed: u32) -> Image {
        // Small deterministic LCG, enough for test images.
        let mut s = seed.wrapping_mul(2654435761).wrapping_add(1);
        let mut next = || {
            s = s.wrapping_mul(1664525).wrapping_add(1013904223);
            (s >> 8) as f32 / (1u32 << 24) as f32
        };
        Image {
            width: w,
            height: h,
            data: (0..w * h).map(|_| [next(), next(), next()]).collect(),
        }
    }

    #[test]
    fn identical_images_are_infinite() {
        let a = noisy(7, 5, 1);
        assert_eq!(mse(&a, &a), 0.0);
        assert_eq!(psnr(&a, &a), f32::INFINITY);
        assert_eq!(masked_psnr(&a, &a, &[true; 35]), Some(f32::INFINITY));
    }

    #[test]
    fn known_value() {
        // Uniform error of 0.1 in every channel: mse = 0.01, PSNR = 20 dB.
        let a = Image::filled(4, 3, [0.5, 0.2, 0.9]);
        let b = Image::filled(4, 3, [0.6, 0.1, 0.8]);
        assert!((mse(&a, &b) - 0.01).abs() < 1e-7);
        assert!((psnr(&a, &b) - 20.0).abs() < 1e-4);
        // Error in a single channel only: mse = 0.01 / 3.
        let c = Image::filled(4, 3, [0.6, 0.2, 0.9]);
        assert!((mse(&a, &c) - 0.01 / 3.0).abs() < 1e-7);
    }

    #[test]
    fn masked_full_and_empty() {
        let a = noisy(9, 6, 2);
        let b = noisy(9, 6, 3);
        let full = vec![true; 54];
        let m = masked_psnr(&a, &b, &full).unwrap();
        assert!((m - psnr(&a, &b)).abs() < 1e-5, "{m} vs {}", psnr(&a, &b));
        assert_eq!(masked_psnr(&a, &b, &[false; 54]), None);
    }

    #[test]
    fn masked_selects_pixels() {
        // Only the masked pixel differs by 0.1 -> masked PSNR is 20 dB, unmasked pixels ignored.
        let a = Image::filled(3, 2, [0.5; 3]);
        let mut b = a.clone();
        b.data[4] = [0.6; 3];
        b.data[0] = [1.0; 3];
        let mut mask = vec![false; 6];
        mask[4] = true;
        let m = masked_psnr(&a, &b, &mask).unwrap();
        assert!((m - 20.0).abs() < 1e-4, "{m}");
    }

    #[test]
    #[should_panic(expected = "image sizes differ")]
    fn size_mismatch_panics() {
        psnr(
            &Image::filled(2, 2, [0.0; 3]),
            &Image::filled(3, 2, [0.0; 3]),
        );
    }

    #[test]
    #[should_panic(expected = "mask length")]
    fn mask_mismatch_panics() {
        let a = Image::filled(2, 2, [0.0; 3]);
        masked_psnr(&a, &a, &[true; 3]);
    }
}
