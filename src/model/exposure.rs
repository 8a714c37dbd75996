//! Per-camera exposure compensation: an affine colour per channel, `gain·render + offset` with
//! `gain = exp(log_gain)`, applied to the render of a training camera before the loss, and its
//! gradient.
//!
//! Multi-camera rigs (Panoptic's dome) record each camera with its own exposure and white
//! balance. Without a correction the Gaussians average the cameras' disagreement into blur and
//! view-dependent colour; with one, each training camera explains its own brightness. Held-out
//! cameras have no training pixels, so they are rendered without a correction.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::io::image::Image;

/// The affine colour of one camera: `exp(log_gain)·c + offset` per channel. The default is the
/// identity.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Exposure {
    /// Natural log of the gain per channel (0: gain 1).
    pub log_gain: [f32; 3],
    /// Added after the gain, per channel.
    pub offset: [f32; 3],
}

impl Exposure {
    /// The six values, log-gains first (the layout Adam works on).
    pub fn values(&self) -> [f32; 6] {
        let (g, o) = (self.log_gain, self.offset);
        [g[0], g[1], g[2], o[0], o[1], o[2]]
    }

    /// The exposure with these six values, log-gains first.
    pub fn from_values(v: [f32; 6]) -> Self {
        Self {
            log_gain: [v[0], v[1], v[2]],
            offset: [v[3], v[4], v[5]],
        }
    }

    /// The gain per channel.
    pub fn gain(&self) -> [f32; 3] {
        self.log_gain.map(f32::exp)
    }

    /// Writes `gain·render + offset` into `out` (resized to the render's size, keeping its
    /// allocation).
    pub fn apply(&self, render: &Image, out: &mut Image) {
        let (gain, offset) = (self.gain(), self.offset);
        out.width = render.width;
        out.height = render.height;
        render
            .data
            .par_iter()
            .map(|c| std::array::from_fn(|k| gain[k] * c[k] + offset[k]))
            .collect_into_vec(&mut out.data);
    }

    /// Chains a loss gradient through [`Exposure::apply`]: `d_color` holds dL/d(corrected) on
    /// entry and dL/d(render) on return; the result is dL/d(log_gain, offset).
    pub fn backward(&self, render: &Image, d_color: &mut [[f32; 3]]) -> Exposure {
        let gain = self.gain();
        let (d_gain, d_offset) = d_color
            .par_iter_mut()
            .zip(&render.data)
            .map(|(d, c)| {
                let mut sums = ([0.0f64; 3], [0.0f64; 3]);
                for k in 0..3 {
                    sums.0[k] = (d[k] * c[k]) as f64;
                    sums.1[k] = d[k] as f64;
                    d[k] *= gain[k];
                }
                sums
            })
            .reduce(
                || ([0.0; 3], [0.0; 3]),
                |a, b| {
                    (
                        std::array::from_fn(|k| a.0[k] + b.0[k]),
                        std::array::from_fn(|k| a.1[k] + b.1[k]),
                    )
                },
            );
        Exposure {
            // d/d(log g) = d/dg · g.
            log_gain: std::array::from_fn(|k| d_gain[k] as f32 * gain[k]),
            offset: d_offset.map(|v| v as f32),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::metrics::loss::{LossScratch, training_loss};
    use crate::model::fd::{assert_grad, central};

    fn image(width: usize, height: usize, seed: u32) -> Image {
        let data = (0..width * height)
            .map(|i| {
                let x = (i as u32).wrapping_mul(2_654_435_761).wrapping_add(seed);
                std::array::from_fn(|k| ((x >> (8 * k)) & 0xff) as f32 / 255.0)
            })
            .collect();
        Image {
            width,
            height,
            data,
        }
    }

    /// The training loss of the corrected render, and its gradients with respect to the render
    /// and the exposure.
    fn loss_and_grads(
        exposure: Exposure,
        render: &Image,
        gt: &Image,
        lambda: f32,
    ) -> (f32, Vec<[f32; 3]>, Exposure) {
        let mut corrected = Image::filled(0, 0, [0.0; 3]);
        exposure.apply(render, &mut corrected);
        let mut d = Vec::new();
        let value = training_loss(&mut LossScratch::default(), &corrected, gt, lambda, &mut d);
        let d_exposure = exposure.backward(render, &mut d);
        (value.total, d, d_exposure)
    }

    #[test]
    fn identity_changes_nothing() {
        let render = image(7, 5, 1);
        let mut out = Image::filled(0, 0, [0.0; 3]);
        Exposure::default().apply(&render, &mut out);
        assert_eq!(out.data, render.data);
    }

    /// The exposure gradient (and the render gradient through it) matches fourth-order finite
    /// differences of the training loss to 1e-3 relative. D-SSIM only (λ = 1): the L1 term's
    /// kinks would make finite differences meaningless.
    #[test]
    fn gradient_matches_finite_differences() {
        let (render, gt) = (image(16, 12, 3), image(16, 12, 99));
        let exposure = Exposure {
            log_gain: [0.1, -0.2, 0.05],
            offset: [0.02, -0.03, 0.01],
        };
        let (_, d_render, d_exposure) = loss_and_grads(exposure, &render, &gt, 1.0);
        let analytic = d_exposure.values();
        for i in 0..6 {
            let fd = central(
                |x| {
                    let mut v = exposure.values();
                    v[i] = x;
                    loss_and_grads(Exposure::from_values(v), &render, &gt, 1.0).0
                },
                exposure.values()[i],
                1e-2,
            );
            assert_grad(&format!("exposure value {i}"), analytic[i], fd);
        }
        for (pixel, k) in [(0, 0), (37, 1), (150, 2)] {
            let fd = central(
                |x| {
                    let mut r = render.clone();
                    r.data[pixel][k] = x;
                    loss_and_grads(exposure, &r, &gt, 1.0).0
                },
                render.data[pixel][k],
                1e-2,
            );
            assert_grad(
                &format!("render pixel {pixel} channel {k}"),
                d_render[pixel][k],
                fd,
            );
        }
    }
}
