//! Photometric training loss `L = (1 − λ)·L1 + λ·(1 − SSIM)` and its gradient.

use rayon::prelude::*;

use super::assert_same_size;
use super::ssim::{SsimScratch, ssim_with_grad};
use crate::io::image::Image;

/// Reusable buffers for [`training_loss`]; no allocation at an unchanged image size.
#[derive(Clone, Debug, Default)]
pub struct LossScratch {
    /// SSIM buffers.
    pub ssim: SsimScratch,
    /// Per-row L1 sums (combined in a fixed order so the result is deterministic).
    row_l1: Vec<f64>,
}

impl LossScratch {
    /// Empty scratch space; buffers are allocated on first use.
    pub fn new() -> Self {
        Self {
            ssim: SsimScratch::new(),
            row_l1: Vec::new(),
        }
    }
}

/// Value of the training loss and its components.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LossValue {
    /// `(1 − λ)·l1 + λ·(1 − ssim)`.
    pub total: f32,
    /// Mean absolute error over pixels and channels.
    pub l1: f32,
    /// Mean SSIM of the render against the ground truth.
    pub ssim: f32,
}

/// Computes `L = (1 − λ)·L1 + λ·(1 − SSIM)` of `render` against `gt` and writes dL/d(render)
/// into `d_render`, which is resized to `width·height` (keeping its allocation when the size is
/// unchanged). The L1 term contributes `sign(render − gt)/N` (0 at equality), with `N` the number
/// of pixel-channels.
///
/// Panics if the images differ in size.
pub fn training_loss(
    scratch: &mut LossScratch,
    render: &Image,
    gt: &Image,
    lambda_dssim: f32,
    d_render: &mut Vec<[f32; 3]>,
) -> LossValue {
    assert_same_size(render, gt);
    let (w, h) = (render.width, render.height);
    let n = w * h;
    d_render.resize(n, [0.0; 3]);
    if n == 0 {
        return LossValue {
            total: 0.0,
            l1: 0.0,
            ssim: 1.0,
        };
    }
    // d_render ← dSSIM/d(render), then turned into dL/d(render) in place.
    let ssim = ssim_with_grad(&mut scratch.ssim, render, gt, d_render);

    let lambda = lambda_dssim;
    let l1_scale = (1.0 - lambda) / (3 * n) as f32;
    scratch.row_l1.resize(h, 0.0);
    d_render
        .par_chunks_mut(w)
        .zip(scratch.row_l1.par_iter_mut())
        .zip(render.data.par_chunks(w))
        .zip(gt.data.par_chunks(w))
        .for_each(|(((out, row_sum), xs), ys)| {
            let mut sum = 0.0f64;
            for ((o, x), y) in out.iter_mut().zip(xs).zip(ys) {
                for c in 0..3 {
                    let diff = x[c] - y[c];
                    sum += diff.abs() as f64;
                    let sign = if diff > 0.0 {
                        1.0
                    } else if diff < 0.0 {
                        -1.0
                    } else {
                        0.0
                    };
                    o[c] = l1_scale * sign - lambda * o[c];
                }
            }
            *row_sum = sum;
        });
    let l1 = (scratch.row_l1.iter().sum::<f64>() / (3 * n) as f64) as f32;
    let total = (1.0 - lambda) * l1 + lambda * (1.0 - ssim);
    LossValue { total, l1, ssim }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::ssim::tests::{noisy, reference_ssim, to_f64};

    /// `f64` reference of the total loss (independent L1, direct-loop SSIM).
    fn reference_loss(x: &[[f64; 3]], y: &[[f64; 3]], w: usize, h: usize, lambda: f64) -> f64 {
        let l1 = x
            .iter()
            .zip(y)
            .flat_map(|(p, q)| (0..3).map(|c| (p[c] - q[c]).abs()))
            .sum::<f64>()
            / (3 * w * h) as f64;
        (1.0 - lambda) * l1 + lambda * (1.0 - reference_ssim(x, y, w, h))
    }

    #[test]
    fn identical_images_give_zero_loss() {
        let a = noisy(10, 7, 3);
        let mut scratch = LossScratch::new();
        let mut d = Vec::new();
        let v = training_loss(&mut scratch, &a, &a, 0.2, &mut d);
        assert_eq!(v.l1, 0.0);
        assert!((v.ssim - 1.0).abs() < 1e-5, "{}", v.ssim);
        assert!(v.total.abs() < 1e-5, "{}", v.total);
        assert_eq!(d.len(), 70);
        // At the optimum the SSIM gradient vanishes and sign(0) = 0.
        assert!(d.iter().flatten().all(|g| g.abs() < 1e-6));
    }

    #[test]
    fn values_match_reference() {
        let (w, h) = (15, 11);
        let (a, b) = (noisy(w, h, 4), noisy(w, h, 5));
        let mut d = Vec::new();
        let v = training_loss(&mut LossScratch::new(), &a, &b, 0.2, &mut d);
        let r = reference_loss(&to_f64(&a), &to_f64(&b), w, h, 0.2);
        assert!((v.total as f64 - r).abs() < 1e-5, "{} vs {r}", v.total);
        assert!((v.ssim - crate::metrics::ssim(&a, &b)).abs() < 1e-7);
        assert!((v.total - (0.8 * v.l1 + 0.2 * (1.0 - v.ssim))).abs() < 1e-6);
    }

    /// Central differences of the `f64` reference; pixels are kept ≥ 2e-3 apart from the ground
    /// truth so the ±1e-4 steps never cross the L1 kink. Tolerance reasoning as for the SSIM
    /// gradient test (f32 analytic vs f64 finite differences).
    #[test]
    fn gradient_matches_finite_differences() {
        let (w, h) = (13, 9);
        let gt = noisy(w, h, 21);
        let mut img = noisy(w, h, 22);
        for (p, q) in img.data.iter_mut().zip(&gt.data) {
            for c in 0..3 {
                if (p[c] - q[c]).abs() < 2e-3 {
                    p[c] = q[c] + if q[c] < 0.5 { 5e-3 } else { -5e-3 };
                }
            }
        }
        for lambda in [0.2f32, 0.0, 1.0] {
            let mut d = Vec::new();
            training_loss(&mut LossScratch::new(), &img, &gt, lambda, &mut d);
            let (x0, y) = (to_f64(&img), to_f64(&gt));
            let step = 1e-4;
            let grad_scale = d
                .iter()
                .flatten()
                .fold(0.0f64, |m, v| m.max(v.abs() as f64));
            let (mut num, mut den, mut max_err, mut max_fd) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
            for i in 0..w * h {
                for c in 0..3 {
                    let mut x = x0.clone();
                    x[i][c] = x0[i][c] + step;
                    let plus = reference_loss(&x, &y, w, h, lambda as f64);
                    x[i][c] = x0[i][c] - step;
                    let minus = reference_loss(&x, &y, w, h, lambda as f64);
                    let fd = (plus - minus) / (2.0 * step);
                    let err = (d[i][c] as f64 - fd).abs();
                    // Per entry: relative error, with a floor for entries near zero.
                    assert!(
                        err <= 1e-3 * fd.abs() + 1e-6 * grad_scale,
                        "entry ({i}, {c}): {} vs {fd}",
                        d[i][c]
                    );
                    num += err * err;
                    den += fd * fd;
                    max_err = max_err.max(err);
                    max_fd = max_fd.max(fd.abs());
                }
            }
            let rel = (num / den).sqrt();
            assert!(
                rel <= 1e-3,
                "λ = {lambda}: relative L2 gradient error {rel}"
            );
            assert!(
                max_err <= 1e-3 * max_fd,
                "λ = {lambda}: max error {max_err} vs {max_fd}"
            );
        }
    }

    #[test]
    fn l1_gradient_sign_and_zero() {
        let a = Image::filled(2, 1, [0.5; 3]);
        let mut b = a.clone();
        b.data[0] = [0.4, 0.5, 0.6];
        let mut d = Vec::new();
        let v = training_loss(&mut LossScratch::new(), &a, &b, 0.0, &mut d);
        let n = 6.0;
        assert_eq!(d[0], [1.0 / n, 0.0, -1.0 / n]);
        assert_eq!(d[1], [0.0; 3]);
        assert!((v.l1 - 0.2 / n).abs() < 1e-7);
        assert!((v.total - v.l1).abs() < 1e-7);
    }

    #[test]
    fn gradient_buffer_is_reused() {
        let (a, b) = (noisy(16, 12, 1), noisy(16, 12, 2));
        let mut scratch = LossScratch::new();
        let mut d = Vec::new();
        let first = training_loss(&mut scratch, &a, &b, 0.2, &mut d);
        let (ptr, cap) = (d.as_ptr(), d.capacity());
        let d_first = d.clone();
        let second = training_loss(&mut scratch, &a, &b, 0.2, &mut d);
        assert_eq!(first, second);
        assert_eq!(d, d_first);
        assert_eq!((d.as_ptr(), d.capacity()), (ptr, cap));
        // Stale contents of a larger buffer are overwritten after shrinking to the new size.
        let (c, e) = (noisy(5, 4, 3), noisy(5, 4, 4));
        training_loss(&mut scratch, &c, &e, 0.2, &mut d);
        assert_eq!(d.len(), 20);
    }
}
