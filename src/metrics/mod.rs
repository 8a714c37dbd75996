//! Image quality metrics and the photometric training loss.
//!
//! * [`psnr`](mod@psnr): mean squared error and PSNR (optionally restricted to a pixel mask).
//! * [`ssim`](mod@ssim): structural similarity exactly as in the 3DGS / mip-NeRF evaluation code
//!   (11×11 Gaussian window, σ = 1.5, zero padding), with its analytic gradient.
//! * [`eval`]: the evaluation protocol (PSNR, SSIM, LPIPS, M-PSNR, M-SSIM) and dynamic masks.
//! * [`loss`]: the training loss `(1 − λ)·L1 + λ·(1 − SSIM)` and its gradient w.r.t. the render.
//!
//! All functions take [`Image`]s with channels in [0, 1] and panic with a clear message when
//! the two images (or a mask) do not have the same size; callers are expected to check sizes.

use crate::io::image::Image;

pub mod eval;
pub mod flow;
pub mod loss;
pub mod lpips;
pub mod psnr;
pub mod ssim;

pub use loss::{LossScratch, LossValue, training_loss};
pub use psnr::{masked_psnr, mse, psnr};
pub use ssim::{SsimScratch, masked_ssim, ssim, ssim_map, ssim_with_grad, ssim_with_scratch};

/// Asserts that `a` and `b` have the same dimensions and consistent pixel buffers.
pub(crate) fn assert_same_size(a: &Image, b: &Image) {
    assert_eq!(
        (a.width, a.height),
        (b.width, b.height),
        "metrics: image sizes differ ({}x{} vs {}x{})",
        a.width,
        a.height,
        b.width,
        b.height
    );
    assert_eq!(
        a.data.len(),
        a.width * a.height,
        "metrics: image buffer length does not match its {}x{} size",
        a.width,
        a.height
    );
    assert_eq!(
        b.data.len(),
        b.width * b.height,
        "metrics: image buffer length does not match its {}x{} size",
        b.width,
        b.height
    );
}

/// Asserts that a pixel mask has one entry per pixel of `img`.
pub(crate) fn assert_mask_size(img: &Image, mask: &[bool]) {
    assert_eq!(
        mask.len(),
        img.width * img.height,
        "metrics: mask length does not match the {}x{} image",
        img.width,
        img.height
    );
}
