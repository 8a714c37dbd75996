//! Dense optical flow and the dynamic-region masks of the evaluation protocol.
//!
//! The paper reports metrics restricted to *dynamic* pixels: for a test camera, a pixel of
//! frame `t` is dynamic where the optical-flow magnitude between frames `t − 5` and `t`
//! ([`MASK_FRAME_GAP`]) exceeds a threshold ([`DEFAULT_FLOW_THRESHOLD`]); frames `0..5` have no
//! mask.
//!
//! # Algorithm
//!
//! [`dense_flow`] is a classical coarse-to-fine dense Lucas–Kanade estimator on grayscale
//! images (Rec. 601 luma):
//!
//! 1. Both images are lightly smoothed (Gaussian, σ = [`PRESMOOTH_SIGMA`]) and a pyramid is
//!    built by Gaussian filtering with the binomial kernel `[1 4 6 4 1]/16` and subsampling by
//!    2, down to a coarsest side of at least [`MIN_LEVEL_SIZE`] pixels (at most
//!    [`MAX_LEVELS`] levels; 5 for 640×360).
//! 2. At each level, starting from the coarsest with zero flow, the flow is refined by
//!    Gauss–Newton iterations: the second image is warped by the current flow (bilinear
//!    sampling), the temporal residual `r = b(x + u) − a(x)` is formed, and the per-pixel
//!    normal equations `(G + λI) δ = −Σ w g r` are solved, where the window sums `Σ w` are a
//!    Gaussian of σ = [`WINDOW_SIGMA`] (a separable blur of the products, so every pixel has
//!    its own window), `g` is the mean of the gradients of `a` and of the warped `b` (as in
//!    efficient second-order minimisation) and `G = Σ w g gᵀ`. The
//!    Tikhonov term λ ([`REGULARIZATION`]) keeps textureless regions at the flow propagated
//!    from the coarser level instead of amplifying noise.
//! 3. After every iteration the flow is cleaned with a 3×3 median filter (removes
//!    isolated outliers); after the last one of a level it is bilinearly upsampled (and
//!    doubled) to the next finer level.
//!
//! All passes are parallel over rows with rayon. A 640×360 pair takes roughly 0.1–0.25 s in
//! release builds on a 2-core machine (see the `panoptic` test output).

use crate::io::image::Image;
use rayon::prelude::*;

/// Number of frames between the two images compared by the dynamic mask: frame `t` is
/// compared with frame `t − MASK_FRAME_GAP`, and frames `0..MASK_FRAME_GAP` have no mask.
pub const MASK_FRAME_GAP: usize = 5;

/// Default flow-magnitude threshold (pixels at full image resolution) above which a pixel is
/// *dynamic*.
///
/// 1 px over a 5-frame gap: the evaluation cameras are static, so on the background the
/// estimated flow is only estimator noise (JPEG artefacts, sensor noise, flicker), which on the
/// CMU Panoptic videos stays well below 0.5 px, while a person moving even slowly covers
/// several pixels in 5 frames (1/6 s at 30 fps). 1 px sits between the two with a
/// margin on both sides; it is also the smallest displacement that is unambiguous at the
/// image's own resolution. Every function takes the threshold as a parameter.
pub const DEFAULT_FLOW_THRESHOLD: f32 = 1.0;

/// Standard deviation (pixels) of the Gaussian applied to the grayscale images before the
/// pyramid is built (suppresses JPEG and sensor noise).
pub const PRESMOOTH_SIGMA: f32 = 1.0;

/// Standard deviation (pixels of the current level) of the Gaussian Lucas–Kanade window.
pub const WINDOW_SIGMA: f32 = 2.5;

/// Tikhonov regularisation added to the diagonal of the structure tensor (intensity² per
/// pixel², intensities in [0, 1]); far below the tensor of textured regions (~1e-3), so it only
/// matters where the image is essentially flat and the flow is undetermined.
pub const REGULARIZATION: f32 = 1e-6;

/// Maximum number of pyramid levels (including full resolution).
pub const MAX_LEVELS: usize = 5;

/// The coarsest pyramid level keeps at least this many pixels along its shorter side.
pub const MIN_LEVEL_SIZE: usize = 16;

/// Gauss–Newton iterations per pyramid level.
const ITERATIONS: usize = 6;

/// Largest update (pixels of the current level) applied in one iteration; keeps the
/// linearisation from overshooting on poorly conditioned pixels.
const MAX_STEP: f32 = 1.5;

/// A dense displacement field: `data[y * width + x] = [dx, dy]` is the displacement in pixels
/// from pixel (x, y) of the first image to its match in the second image, i.e.
/// `a(x, y) ≈ b(x + dx, y + dy)`.
#[derive(Clone, Debug, PartialEq)]
pub struct Flow {
    /// Width in pixels (that of the images the flow was computed from).
    pub width: usize,
    /// Height in pixels.
    pub height: usize,
    /// Row-major displacements `[dx, dy]` in pixels.
    pub data: Vec<[f32; 2]>,
}

impl Flow {
    /// Euclidean length of the displacement of every pixel, row-major.
    pub fn magnitude(&self) -> Vec<f32> {
        self.data
            .iter()
            .map(|&[dx, dy]| (dx * dx + dy * dy).sqrt())
            .collect()
    }
}

/// Dense optical flow from `a` to `b` (per pixel of `a`, see [`Flow`]).
///
/// # Panics
///
/// When the two images do not have the same size or a buffer length does not match its size.
pub fn dense_flow(a: &Image, b: &Image) -> Flow {
    super::assert_same_size(a, b);
    let (w, h) = (a.width, a.height);
    if w == 0 || h == 0 {
        return Flow {
            width: w,
            height: h,
            data: Vec::new(),
        };
    }
    let pyr_a = pyramid(&to_gray(a));
    let pyr_b = pyramid(&to_gray(b));
    let window = gaussian_kernel(WINDOW_SIGMA);

    let mut flow: Vec<[f32; 2]> = Vec::new();
    for level in (0..pyr_a.len()).rev() {
        let (la, lb) = (&pyr_a[level], &pyr_b[level]);
        flow = if flow.is_empty() {
            vec![[0.0; 2]; la.w * la.h]
        } else {
            let c = &pyr_a[level + 1];
            upsample_flow(&flow, c.w, c.h, la.w, la.h)
        };
        refine_level(la, lb, &mut flow, &window);
    }
    Flow {
        width: w,
        height: h,
        data: flow,
    }
}

/// Dynamic-region mask of `current` (row-major, one entry per pixel, `true` = dynamic).
///
/// A pixel is dynamic when the frames differ around it (local RMS luma difference above
/// [`CHANGE_THRESHOLD`]) and its flow exceeds `threshold` (pixels). Flow is computed in **both** directions, `current → earlier` and `earlier → current`, and either
/// magnitude may exceed the threshold. The evaluation cameras
/// are static, so both flows live on the same pixel grid: the backward flow (`current →
/// earlier`) flags where moving content is *now*, the forward flow (`earlier → current`) flags
/// where it *was* (the region it left, which in `current` shows background that has no match
/// in `earlier` and would otherwise be missed). No dilation is applied: the Lucas–Kanade window
/// already spreads the motion of an object over a few pixels around its outline.
///
/// `earlier` is normally frame `t − MASK_FRAME_GAP` and `current` frame `t`.
///
/// # Panics
///
/// When the two images do not have the same size.
pub fn dynamic_mask(earlier: &Image, current: &Image, threshold: f32) -> Vec<bool> {
    let backward = dense_flow(current, earlier);
    let forward = dense_flow(earlier, current);
    let change = local_change(earlier, current);
    let t2 = threshold * threshold;
    let c2 = CHANGE_THRESHOLD * CHANGE_THRESHOLD;
    backward
        .data
        .par_iter()
        .zip(forward.data.par_iter())
        .zip(change.par_iter())
        .map(|((b, f), &c)| {
            c > c2 && (b[0] * b[0] + b[1] * b[1] > t2 || f[0] * f[0] + f[1] * f[1] > t2)
        })
        .collect()
}

/// Root-mean-square luma difference (intensities in [0, 1]) between the two frames over a
/// Gaussian neighbourhood (σ = [`CHANGE_SIGMA`]) below which [`dynamic_mask`] never flags a
/// pixel, whatever its flow.
///
/// Where nothing changed between the frames the flow is unobservable (a flat floor or wall
/// matches itself under any displacement), and the coarse pyramid levels, whose windows span
/// tens of pixels, leak the motion of nearby people into such regions. On the CMU Panoptic
/// videos the static background differs by about 0.005–0.015 between frames (JPEG and sensor
/// noise) and moving people by more than 0.04, so 0.02 separates them. The gate misses only
/// the interior of large *uniform* moving surfaces, whose appearance does not change either.
pub const CHANGE_THRESHOLD: f32 = 0.02;

/// Standard deviation (pixels) of the neighbourhood of [`CHANGE_THRESHOLD`].
pub const CHANGE_SIGMA: f32 = 3.0;

/// Mean squared luma difference of the two (pre-smoothed) frames over a Gaussian
/// neighbourhood of σ = [`CHANGE_SIGMA`].
fn local_change(a: &Image, b: &Image) -> Vec<f32> {
    let smooth = gaussian_kernel(PRESMOOTH_SIGMA);
    let (ga, gb) = (
        blur_gray(&to_gray(a), &smooth),
        blur_gray(&to_gray(b), &smooth),
    );
    let d2: Vec<[f32; 1]> =
        ga.d.iter()
            .zip(&gb.d)
            .map(|(x, y)| [(x - y) * (x - y)])
            .collect();
    blur(&d2, ga.w, ga.h, &gaussian_kernel(CHANGE_SIGMA))
        .into_iter()
        .map(|[v]| v)
        .collect()
}

/// A black/white image of a mask (white = dynamic), for saving as PNG.
///
/// # Panics
///
/// When `mask.len() != width * height`.
pub fn mask_to_image(mask: &[bool], width: usize, height: usize) -> Image {
    assert_eq!(
        mask.len(),
        width * height,
        "mask_to_image: mask length {} does not match {width}x{height}",
        mask.len()
    );
    Image {
        width,
        height,
        data: mask
            .iter()
            .map(|&m| if m { [1.0; 3] } else { [0.0; 3] })
            .collect(),
    }
}

/// Reads a mask back from an image: a pixel is dynamic where its mean channel value is
/// above 0.5.
pub fn mask_from_image(img: &Image) -> Vec<bool> {
    img.data
        .iter()
        .map(|p| (p[0] + p[1] + p[2]) / 3.0 > 0.5)
        .collect()
}

/// A single-channel float image.
struct Gray {
    w: usize,
    h: usize,
    d: Vec<f32>,
}

impl Gray {
    /// Bilinear sample at (x, y) with coordinates clamped to the image.
    #[inline]
    fn sample(&self, x: f32, y: f32) -> f32 {
        let x = x.clamp(0.0, (self.w - 1) as f32);
        let y = y.clamp(0.0, (self.h - 1) as f32);
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(self.w - 1), (y0 + 1).min(self.h - 1));
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        let r0 = &self.d[y0 * self.w..];
        let r1 = &self.d[y1 * self.w..];
        let top = r0[x0] + fx * (r0[x1] - r0[x0]);
        let bottom = r1[x0] + fx * (r1[x1] - r1[x0]);
        top + fy * (bottom - top)
    }
}

/// Rec. 601 luma of an RGB image.
fn to_gray(img: &Image) -> Gray {
    Gray {
        w: img.width,
        h: img.height,
        d: img
            .data
            .par_iter()
            .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
            .collect(),
    }
}

/// Normalised Gaussian kernel of standard deviation `sigma`, radius `ceil(2.5 σ)`.
fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (2.5 * sigma).ceil() as i32;
    let k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    k.into_iter().map(|v| v / s).collect()
}

/// Separable convolution of an `N`-channel image with a symmetric odd-length kernel,
/// replicating the border pixels.
fn blur<const N: usize>(src: &[[f32; N]], w: usize, h: usize, k: &[f32]) -> Vec<[f32; N]> {
    let r = (k.len() / 2) as isize;
    let (wi, hi) = (w as isize, h as isize);
    let mut tmp = vec![[0.0f32; N]; w * h];
    tmp.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let s = &src[y * w..(y + 1) * w];
        for (x, out) in row.iter_mut().enumerate() {
            let mut acc = [0.0f32; N];
            for (j, &kv) in k.iter().enumerate() {
                let xx = (x as isize + j as isize - r).clamp(0, wi - 1) as usize;
                for c in 0..N {
                    acc[c] += kv * s[xx][c];
                }
            }
            *out = acc;
        }
    });
    let mut out = vec![[0.0f32; N]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        for (j, &kv) in k.iter().enumerate() {
            let yy = (y as isize + j as isize - r).clamp(0, hi - 1) as usize;
            let s = &tmp[yy * w..(yy + 1) * w];
            for (o, v) in row.iter_mut().zip(s) {
                for c in 0..N {
                    o[c] += kv * v[c];
                }
            }
        }
    });
    out
}

/// Blurs a grayscale image.
fn blur_gray(g: &Gray, k: &[f32]) -> Gray {
    let src: Vec<[f32; 1]> = g.d.iter().map(|&v| [v]).collect();
    Gray {
        w: g.w,
        h: g.h,
        d: blur(&src, g.w, g.h, k).into_iter().map(|[v]| v).collect(),
    }
}

/// Gaussian pyramid, finest level first.
fn pyramid(g: &Gray) -> Vec<Gray> {
    let mut levels = vec![blur_gray(g, &gaussian_kernel(PRESMOOTH_SIGMA))];
    let binomial = [1.0 / 16.0, 4.0 / 16.0, 6.0 / 16.0, 4.0 / 16.0, 1.0 / 16.0];
    while levels.len() < MAX_LEVELS {
        let last = levels.last().expect("pyramid is not empty");
        let (nw, nh) = (last.w.div_ceil(2), last.h.div_ceil(2));
        if nw.min(nh) < MIN_LEVEL_SIZE {
            break;
        }
        let smooth = blur_gray(last, &binomial);
        let mut d = vec![0.0f32; nw * nh];
        d.par_chunks_mut(nw).enumerate().for_each(|(y, row)| {
            for (x, v) in row.iter_mut().enumerate() {
                *v = smooth.d[(2 * y) * smooth.w + 2 * x];
            }
        });
        levels.push(Gray { w: nw, h: nh, d });
    }
    levels
}

/// Central-difference gradients of a grayscale image (one-sided at the border).
fn gradients(a: &Gray) -> [Gray; 2] {
    let (w, h) = (a.w, a.h);
    let mut grad = vec![[0.0f32; 2]; w * h];
    grad.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let (ym, yp) = (y.saturating_sub(1), (y + 1).min(h - 1));
        for (x, g) in row.iter_mut().enumerate() {
            let (xm, xp) = (x.saturating_sub(1), (x + 1).min(w - 1));
            let gx = (a.d[y * w + xp] - a.d[y * w + xm]) / (xp - xm).max(1) as f32;
            let gy = (a.d[yp * w + x] - a.d[ym * w + x]) / (yp - ym).max(1) as f32;
            *g = [gx, gy];
        }
    });
    std::array::from_fn(|c| Gray {
        w,
        h,
        d: grad.iter().map(|g| g[c]).collect(),
    })
}

/// Gauss–Newton refinement of `flow` (per pixel of `a`) at one pyramid level.
///
/// Uses the mean of the gradient of `a` and of the warped `b` (efficient second-order
/// minimisation), which converges faster and more precisely than the gradient of `a` alone.
fn refine_level(a: &Gray, b: &Gray, flow: &mut [[f32; 2]], window: &[f32]) {
    let (w, h) = (a.w, a.h);
    let [ax, ay] = gradients(a);
    let [bx, by] = gradients(b);
    let mut terms = vec![[0.0f32; 5]; w * h];
    for _ in 0..ITERATIONS {
        // Per-pixel normal-equation terms; pixels whose match falls outside `b` contribute
        // nothing.
        terms
            .par_chunks_mut(w)
            .zip(flow.par_chunks(w))
            .enumerate()
            .for_each(|(y, (row, frow))| {
                for (x, (out, f)) in row.iter_mut().zip(frow).enumerate() {
                    let (sx, sy) = (x as f32 + f[0], y as f32 + f[1]);
                    let inside =
                        sx >= 0.0 && sy >= 0.0 && sx <= (w - 1) as f32 && sy <= (h - 1) as f32;
                    let i = y * w + x;
                    *out = if inside {
                        let r = b.sample(sx, sy) - a.d[i];
                        let gx = 0.5 * (ax.d[i] + bx.sample(sx, sy));
                        let gy = 0.5 * (ay.d[i] + by.sample(sx, sy));
                        [gx * gx, gx * gy, gy * gy, gx * r, gy * r]
                    } else {
                        [0.0; 5]
                    };
                }
            });
        let summed = blur(&terms, w, h, window);
        flow.par_iter_mut()
            .zip(summed.par_iter())
            .for_each(|(f, s)| {
                let (gxx, gxy, gyy) = (s[0] + REGULARIZATION, s[1], s[2] + REGULARIZATION);
                let det = gxx * gyy - gxy * gxy;
                if det <= 0.0 {
                    return;
                }
                let mut dx = -(gyy * s[3] - gxy * s[4]) / det;
                let mut dy = -(gxx * s[4] - gxy * s[3]) / det;
                let len = (dx * dx + dy * dy).sqrt();
                if len > MAX_STEP {
                    dx *= MAX_STEP / len;
                    dy *= MAX_STEP / len;
                }
                f[0] += dx;
                f[1] += dy;
            });
        // The per-pixel updates are coupled through the windows (each window sums residuals
        // taken at its neighbours' flows); a median after every step suppresses the
        // oscillating outliers this coupling creates.
        let smoothed = median3(flow, w, h);
        flow.copy_from_slice(&smoothed);
    }
}

/// Bilinear upsampling of a flow field from `cw × ch` to `w × h` (about twice the size),
/// scaling the displacements by the size ratio.
fn upsample_flow(flow: &[[f32; 2]], cw: usize, ch: usize, w: usize, h: usize) -> Vec<[f32; 2]> {
    let (sx, sy) = (cw as f32 / w as f32, ch as f32 / h as f32);
    let comps: [Gray; 2] = std::array::from_fn(|c| Gray {
        w: cw,
        h: ch,
        d: flow.iter().map(|f| f[c]).collect(),
    });
    let mut out = vec![[0.0f32; 2]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let cy = (y as f32 + 0.5) * sy - 0.5;
        for (x, o) in row.iter_mut().enumerate() {
            let cx = (x as f32 + 0.5) * sx - 0.5;
            *o = [comps[0].sample(cx, cy) / sx, comps[1].sample(cx, cy) / sy];
        }
    });
    out
}

/// Component-wise 3×3 median filter of a flow field (border pixels use the clamped window).
fn median3(flow: &[[f32; 2]], w: usize, h: usize) -> Vec<[f32; 2]> {
    let mut out = vec![[0.0f32; 2]; w * h];
    out.par_chunks_mut(w).enumerate().for_each(|(y, row)| {
        let ys = [y.saturating_sub(1), y, (y + 1).min(h - 1)];
        for (x, o) in row.iter_mut().enumerate() {
            let xs = [x.saturating_sub(1), x, (x + 1).min(w - 1)];
            for c in 0..2 {
                let mut v = [0.0f32; 9];
                for (k, (&yy, &xx)) in ys
                    .iter()
                    .flat_map(|yy| xs.iter().map(move |xx| (yy, xx)))
                    .enumerate()
                {
                    v[k] = flow[yy * w + xx][c];
                }
                let (_, m, _) = v.select_nth_unstable_by(4, f32::total_cmp);
                o[c] = *m;
            }
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_kernel_is_normalised_and_symmetric() {
        let k = gaussian_kernel(2.5);
        assert_eq!(k.len() % 2, 1);
        assert!((k.iter().sum::<f32>() - 1.0).abs() < 1e-5);
        for i in 0..k.len() {
            assert!((k[i] - k[k.len() - 1 - i]).abs() < 1e-7);
        }
    }

    #[test]
    fn blur_preserves_constant() {
        let src = vec![[0.3f32, 0.7]; 7 * 5];
        let out = blur(&src, 7, 5, &gaussian_kernel(1.5));
        for v in out {
            assert!((v[0] - 0.3).abs() < 1e-5 && (v[1] - 0.7).abs() < 1e-5);
        }
    }

    #[test]
    fn upsample_doubles_constant_flow() {
        let f = vec![[1.0f32, -0.5]; 4 * 3];
        let up = upsample_flow(&f, 4, 3, 8, 6);
        for v in up {
            assert!((v[0] - 2.0).abs() < 1e-5 && (v[1] + 1.0).abs() < 1e-5);
        }
    }

    #[test]
    fn median_removes_outlier() {
        let mut f = vec![[0.0f32, 0.0]; 5 * 5];
        f[12] = [9.0, -9.0];
        let m = median3(&f, 5, 5);
        assert!(m.iter().all(|v| v[0] == 0.0 && v[1] == 0.0));
    }

    #[test]
    fn pyramid_sizes() {
        let g = Gray {
            w: 640,
            h: 360,
            d: vec![0.5; 640 * 360],
        };
        let p = pyramid(&g);
        let sizes: Vec<_> = p.iter().map(|l| (l.w, l.h)).collect();
        assert_eq!(
            sizes,
            vec![(640, 360), (320, 180), (160, 90), (80, 45), (40, 23)]
        );
    }
}
