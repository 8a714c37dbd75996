//! Structural similarity (SSIM) and its analytic gradient.
//!
//! The definition follows the 3DGS / mip-NeRF evaluation code: an 11×11 normalised Gaussian
//! window with σ = 1.5 applied per channel with zero padding (torch `conv2d(padding = 5)`),
//! `C1 = 0.01²`, `C2 = 0.03²`,
//!
//! ```text
//! map = ((2μxμy + C1)(2σxy + C2)) / ((μx² + μy² + C1)(σx² + σy² + C2))
//! ```
//!
//! with `μx = G∗x`, `σx² = G∗x² − μx²`, `σxy = G∗(xy) − μxμy`, and SSIM the mean of the map
//! over all pixels and channels. The 2-D window is the outer product of a 1-D Gaussian, so it is
//! applied as two 1-D passes (rows, then columns). The image is cut into bands of rows, one
//! rayon task each, and a band streams its rows: each input row is blurred horizontally into a
//! ring of the window's last eleven rows, and each output row is the vertical blur of the ring.
//! The blurred statistics never exist as a whole image, so the working set stays in the cache
//! instead of passing several image-sized buffers through memory.
//!
//! # Gradient
//!
//! With `N` the number of pixel-channels, `A = 2μxμy + C1`, `B = 2σxy + C2`,
//! `C = μx² + μy² + C1`, `D = σx² + σy² + C2` and `m = AB/(CD)`, the partial derivatives of one
//! map value w.r.t. the local statistics are
//!
//! ```text
//! ∂m/∂μx  = 2μy·B/(CD) − 2μx·m/C      (σ's held fixed)
//! ∂m/∂σx² = −m/D
//! ∂m/∂σxy = 2A/(CD)
//! ```
//!
//! Rewriting in terms of the blurred moments `μx`, `Exx = G∗x²`, `Exy = G∗(xy)` (`σx² = Exx − μx²`,
//! `σxy = Exy − μxμy`) gives per pixel
//!
//! ```text
//! gμ = ∂m/∂μx − 2μx·∂m/∂σx² − μy·∂m/∂σxy,   gxx = ∂m/∂σx²,   gxy = ∂m/∂σxy
//! ```
//!
//! (all divided by `N`). The blur with zero padding is the linear map
//! `(Gf)(p) = Σ_q g(p − q) f(q)` over in-image `q`; its adjoint is `Σ_p g(p − q) f(p)` over
//! in-image `p`, which is the same zero-padded blur because `g` is symmetric. Hence
//!
//! ```text
//! dSSIM/dx(q) = (G gμ)(q) + 2·x(q)·(G gxx)(q) + y(q)·(G gxy)(q).
//! ```

use rayon::prelude::*;

use super::{assert_mask_size, assert_same_size};
use crate::io::image::Image;

/// Side of the Gaussian window.
const WIN: usize = 11;
/// Half-width of the window (the zero padding).
const RADIUS: usize = WIN / 2;
/// Standard deviation of the Gaussian window.
const SIGMA: f64 = 1.5;
/// Stabilising constant of the luminance term, `(0.01·L)²` with `L = 1`.
const C1: f32 = 0.01 * 0.01;
/// Stabilising constant of the contrast/structure term, `(0.03·L)²` with `L = 1`.
const C2: f32 = 0.03 * 0.03;

/// Number of blurred statistics per pixel: μx, μy, E[x²], E[y²], E[xy] for 3 channels.
const NSTAT: usize = 15;
/// Number of gradient maps per pixel: gμ, gxx, gxy for 3 channels.
const NGRAD: usize = 9;

/// Normalised 1-D Gaussian window (computed in `f64`, stored as `f32`).
fn gaussian_window() -> [f32; WIN] {
    let raw: [f64; WIN] = std::array::from_fn(|i| {
        let d = i as f64 - RADIUS as f64;
        (-(d * d) / (2.0 * SIGMA * SIGMA)).exp()
    });
    let sum: f64 = raw.iter().sum();
    raw.map(|v| (v / sum) as f32)
}

/// Reusable buffers for SSIM evaluation; repeated calls at the same image size allocate nothing
/// (buffers are resized only when the image size changes).
#[derive(Clone, Debug)]
pub struct SsimScratch {
    /// 1-D Gaussian window.
    window: [f32; WIN],
    /// Per-pixel gradient w.r.t. the blurred statistics (the input of the second blur).
    grad: Vec<[f32; NGRAD]>,
    /// Per-band streaming buffers.
    bands: Vec<BandScratch>,
    /// SSIM map per pixel, averaged over channels.
    map: Vec<f32>,
    /// Per-row sums of the map over pixels and channels (summed in a fixed order afterwards so
    /// the result does not depend on thread scheduling).
    row_sums: Vec<f64>,
}

/// One band's streaming buffers: for the statistics and for the gradient maps, a row of input,
/// the ring of horizontally blurred rows and the blurred output row.
#[derive(Clone, Debug, Default)]
struct BandScratch {
    stats: RowStream<NSTAT>,
    grad: RowStream<NGRAD>,
}

/// Rows of a field of `K`-vectors on their way through the separable blur.
#[derive(Clone, Debug, Default)]
struct RowStream<const K: usize> {
    /// The row being blurred horizontally.
    input: Vec<[f32; K]>,
    /// Horizontally blurred rows: row q in slot q mod [`WIN`].
    ring: Vec<[f32; K]>,
    /// The blurred row handed to the consumer.
    output: Vec<[f32; K]>,
}

impl Default for SsimScratch {
    fn default() -> Self {
        Self::new()
    }
}

impl SsimScratch {
    /// Empty scratch space; buffers are allocated on first use.
    pub fn new() -> Self {
        Self {
            window: gaussian_window(),
            grad: Vec::new(),
            bands: Vec::new(),
            map: Vec::new(),
            row_sums: Vec::new(),
        }
    }

    /// Per-pixel SSIM map (averaged over channels) of the last evaluation.
    pub fn map(&self) -> &[f32] {
        &self.map
    }
}

/// Rows per band: a few bands per thread so an uneven one does not hold the others up, each
/// long enough that the window's overlap (the ten rows around a band that it blurs again)
/// stays small.
fn band_rows(h: usize) -> usize {
    h.div_ceil(2 * rayon::current_num_threads()).max(2 * WIN)
}

/// Zero-padded horizontal blur of one row: out(x) = Σ_d g[d + R] row(x + d) over in-image x + d.
/// Every output value sums its taps in the same order from 0, so the interior and the border
/// paths give the same bits as one pass per tap would.
#[inline(always)]
fn blur_row<const K: usize>(row: &[[f32; K]], out: &mut [[f32; K]], g: &[f32; WIN]) {
    let w = row.len();
    let (out, row) = (out.as_flattened_mut(), row.as_flattened());
    // Columns whose window lies inside the row: in the flattened K-vectors, tap t of output
    // value i is input value i − R·K + t·K.
    let interior = if w > 2 * RADIUS {
        RADIUS..w - RADIUS
    } else {
        0..0
    };
    let n = interior.len() * K;
    if n > 0 {
        let taps = std::array::from_fn(|t| &row[t * K..t * K + n]);
        sum_of_taps(
            &mut out[interior.start * K..interior.start * K + n],
            &taps,
            g,
        );
    }
    // The border columns, whose windows reach past the row's ends.
    for x in (0..interior.start).chain(interior.end..w) {
        for j in 0..K {
            let mut acc = 0.0;
            for (t, &wgt) in g.iter().enumerate() {
                if let Some(src) = (x + t).checked_sub(RADIUS).filter(|&src| src < w) {
                    acc += wgt * row[src * K + j];
                }
            }
            out[x * K + j] = acc;
        }
    }
}

/// out[i] = Σ_t g[t]·taps[t][i], the taps summed in order in a register (each slice at least
/// as long as `out`); consecutive outputs vectorise.
#[inline(always)]
fn sum_of_taps(out: &mut [f32], taps: &[&[f32]; WIN], g: &[f32; WIN]) {
    for (i, o) in out.iter_mut().enumerate() {
        let mut acc = 0.0;
        for t in 0..WIN {
            acc += g[t] * taps[t][i];
        }
        *o = acc;
    }
}

impl<const K: usize> RowStream<K> {
    /// Separable zero-padded Gaussian blur of a `w × h` field, streamed: for every output row y
    /// of `rows`, in order, `consume(y, blurred row)`. `fill(q, row)` writes input row q; each
    /// is asked for once, in order, from the window's first row above `rows` to its last below.
    #[inline(always)]
    fn blur_rows(
        &mut self,
        (w, h): (usize, usize),
        rows: std::ops::Range<usize>,
        g: &[f32; WIN],
        mut fill: impl FnMut(usize, &mut [[f32; K]]),
        mut consume: impl FnMut(usize, &[[f32; K]]),
    ) {
        self.input.resize(w, [0.0; K]);
        self.ring.resize(WIN * w, [0.0; K]);
        self.output.resize(w, [0.0; K]);
        let mut next = rows.start.saturating_sub(RADIUS);
        for y in rows {
            // Vertical pass: out(x, y) = Σ_q g[q − y + R] blurred(x, q) over in-image rows q.
            let (lo, hi) = (y.saturating_sub(RADIUS), (y + RADIUS).min(h - 1));
            while next <= hi {
                fill(next, &mut self.input);
                let slot = next % WIN * w;
                blur_row(&self.input, &mut self.ring[slot..slot + w], g);
                next += 1;
            }
            let out = self.output.as_flattened_mut();
            let ring_row = |q: usize| self.ring[q % WIN * w..(q % WIN + 1) * w].as_flattened();
            if hi - lo + 1 == WIN {
                // A full window: each output sums its eleven rows in a register.
                let rows = std::array::from_fn(|t| ring_row(lo + t));
                sum_of_taps(out, &rows, g);
            } else {
                // Near the top or bottom: one pass per in-image row, in the same order.
                out.fill(0.0);
                for q in lo..=hi {
                    let wgt = g[q + RADIUS - y];
                    for (o, v) in out.iter_mut().zip(ring_row(q)) {
                        *o += wgt * v;
                    }
                }
            }
            consume(y, &self.output);
        }
    }
}

/// SSIM map values of one row of blurred statistics, summed over the row (f64); with
/// `grad_row`, also the per-pixel gradient w.r.t. the blurred statistics, scaled by
/// `inv_count`.
#[inline(always)]
fn map_row(
    st: &[[f32; NSTAT]],
    map: &mut [f32],
    mut grad_row: Option<&mut [[f32; NGRAD]]>,
    inv_count: f32,
) -> f64 {
    let mut sum = 0.0f64;
    for (i, s) in st.iter().enumerate() {
        let mut pix = 0.0f32;
        for c in 0..3 {
            let (mx, my) = (s[c], s[3 + c]);
            let sxx = s[6 + c] - mx * mx;
            let syy = s[9 + c] - my * my;
            let sxy = s[12 + c] - mx * my;
            let a = 2.0 * mx * my + C1;
            let b = 2.0 * sxy + C2;
            let cc = mx * mx + my * my + C1;
            let d = sxx + syy + C2;
            let inv_cd = 1.0 / (cc * d);
            let m = a * b * inv_cd;
            pix += m;
            if let Some(gr) = grad_row.as_deref_mut() {
                let dm_dmx = 2.0 * my * b * inv_cd - 2.0 * mx * m / cc;
                let dm_dsxx = -m / d;
                let dm_dsxy = 2.0 * a * inv_cd;
                gr[i][c] = (dm_dmx - 2.0 * mx * dm_dsxx - my * dm_dsxy) * inv_count;
                gr[i][3 + c] = dm_dsxx * inv_count;
                gr[i][6 + c] = dm_dsxy * inv_count;
            }
        }
        sum += pix as f64;
        map[i] = pix / 3.0;
    }
    sum
}

crate::raster::simd_kernel! {
    /// The map, its row sums and (with `grad`) the gradient w.r.t. the blurred moments for the
    /// band of rows starting at `first` (as many as `row_sums` holds).
    fn map_band(
        images: (&Image, &Image),
        g: &[f32; WIN],
        first: usize,
        scratch: &mut BandScratch,
        map: &mut [f32],
        row_sums: &mut [f64],
        grad: Option<&mut [[f32; NGRAD]]>,
        inv_count: f32,
    ) {
        let (img, gt) = images;
        let (w, h) = (img.width, img.height);
        let mut grad = grad;
        let moments = |q: usize, row: &mut [[f32; NSTAT]]| {
            let (xs, ys) = (&img.data[q * w..(q + 1) * w], &gt.data[q * w..(q + 1) * w]);
            for ((s, x), y) in row.iter_mut().zip(xs).zip(ys) {
                for c in 0..3 {
                    s[c] = x[c];
                    s[3 + c] = y[c];
                    s[6 + c] = x[c] * x[c];
                    s[9 + c] = y[c] * y[c];
                    s[12 + c] = x[c] * y[c];
                }
            }
        };
        let rows = first..first + row_sums.len();
        scratch.stats.blur_rows((w, h), rows, g, moments, |y, st| {
            let local = (y - first) * w..(y - first + 1) * w;
            let grad_row = grad.as_deref_mut().map(|gr| &mut gr[local.clone()]);
            row_sums[y - first] = map_row(st, &mut map[local], grad_row, inv_count);
        });
    }
}

crate::raster::simd_kernel! {
    /// dSSIM/d(img) for the band of rows starting at `first` (as many as `d_band` holds): the
    /// blur of the gradient maps `grad`, combined with the image values.
    fn gradient_band(
        images: (&Image, &Image),
        g: &[f32; WIN],
        first: usize,
        grad: &[[f32; NGRAD]],
        scratch: &mut BandScratch,
        d_band: &mut [[f32; 3]],
    ) {
        let (img, gt) = images;
        let (w, h) = (img.width, img.height);
        let rows = first..first + d_band.len() / w;
        scratch.grad.blur_rows(
            (w, h),
            rows,
            g,
            |q, row| row.copy_from_slice(&grad[q * w..(q + 1) * w]),
            |y, gb| {
                let out = &mut d_band[(y - first) * w..(y - first + 1) * w];
                let (xs, ys) = (&img.data[y * w..(y + 1) * w], &gt.data[y * w..(y + 1) * w]);
                for (((o, gb), x), yv) in out.iter_mut().zip(gb).zip(xs).zip(ys) {
                    for c in 0..3 {
                        o[c] = gb[c] + 2.0 * x[c] * gb[3 + c] + yv[c] * gb[6 + c];
                    }
                }
            },
        );
    }
}

/// What the first pass hands each band: its index, buffers, map rows and row sums.
type BandChunks<'a> = (usize, ((&'a mut BandScratch, &'a mut [f32]), &'a mut [f64]));

/// Core evaluation: fills `scratch.map`, returns the mean SSIM, and, when `d_img` is given,
/// writes dSSIM/d(img) into it.
fn evaluate(
    scratch: &mut SsimScratch,
    img: &Image,
    gt: &Image,
    d_img: Option<&mut [[f32; 3]]>,
) -> f32 {
    assert_same_size(img, gt);
    let (w, h) = (img.width, img.height);
    let n = w * h;
    if let Some(d) = d_img.as_deref() {
        assert_eq!(
            d.len(),
            n,
            "ssim_with_grad: gradient buffer length does not match the image"
        );
    }
    scratch.map.resize(n, 0.0);
    if n == 0 {
        return 1.0;
    }
    let SsimScratch {
        window,
        grad,
        bands,
        map,
        row_sums,
    } = scratch;
    let g = &*window;
    let rows_per_band = band_rows(h);
    bands.resize_with(h.div_ceil(rows_per_band), BandScratch::default);
    row_sums.resize(h, 0.0);
    let want_grad = d_img.is_some();
    if want_grad {
        grad.resize(n, [0.0; NGRAD]);
    }
    // Scale of the mean: every map value contributes 1/(3n).
    let inv_count = 1.0 / (3 * n) as f32;
    let band_pixels = rows_per_band * w;

    // Per band: the moments, blurred, then the map and its gradient w.r.t. the blurred moments.
    let images = (img, gt);
    let bands_iter = bands
        .par_iter_mut()
        .zip(map.par_chunks_mut(band_pixels))
        .zip(row_sums.par_chunks_mut(rows_per_band))
        .enumerate();
    let band = |(band, ((scratch, map), sums)): BandChunks<'_>,
                grad: Option<&mut [[f32; NGRAD]]>| {
        let first = band * rows_per_band;
        map_band(images, g, first, scratch, map, sums, grad, inv_count)
    };
    if want_grad {
        bands_iter
            .zip(grad.par_chunks_mut(band_pixels))
            .for_each(|(b, gr)| band(b, Some(gr)));
    } else {
        bands_iter.for_each(|b| band(b, None));
    }
    let mean = (row_sums.iter().sum::<f64>() / (3 * n) as f64) as f32;

    // dSSIM/dx(q) = (G gμ)(q) + 2·x(q)·(G gxx)(q) + y(q)·(G gxy)(q), band by band.
    if let Some(d_img) = d_img {
        let grad: &[[f32; NGRAD]] = grad;
        bands
            .par_iter_mut()
            .zip(d_img.par_chunks_mut(band_pixels))
            .enumerate()
            .for_each(|(band, (scratch, d_band))| {
                gradient_band(images, g, band * rows_per_band, grad, scratch, d_band)
            });
    }
    mean
}

/// Mean SSIM of `a` against `b` (convenience wrapper that allocates its own scratch space).
///
/// Panics if the images differ in size. Empty images give 1.
pub fn ssim(a: &Image, b: &Image) -> f32 {
    evaluate(&mut SsimScratch::new(), a, b, None)
}

/// Mean SSIM of `a` against `b` using reusable buffers (no allocation at an unchanged size);
/// the per-pixel map is available afterwards through [`SsimScratch::map`].
pub fn ssim_with_scratch(scratch: &mut SsimScratch, a: &Image, b: &Image) -> f32 {
    evaluate(scratch, a, b, None)
}

/// Per-pixel SSIM map (row-major, averaged over the three channels).
pub fn ssim_map(a: &Image, b: &Image) -> Vec<f32> {
    let mut scratch = SsimScratch::new();
    evaluate(&mut scratch, a, b, None);
    scratch.map
}

/// Mean of the SSIM map over the pixels where `mask` is true; `None` when no pixel is selected.
///
/// Note that the map values near masked pixels still see their unmasked neighbours through the
/// window. Panics if the images differ in size or the mask length is not `width·height`.
pub fn masked_ssim(a: &Image, b: &Image, mask: &[bool]) -> Option<f32> {
    assert_mask_size(a, mask);
    let map = ssim_map(a, b);
    let (sum, count) = map
        .iter()
        .zip(mask)
        .filter(|&(_, &m)| m)
        .fold((0.0f64, 0usize), |(s, k), (&v, _)| (s + v as f64, k + 1));
    (count > 0).then(|| (sum / count as f64) as f32)
}

/// Mean SSIM of `img` against the constant `gt`, writing dSSIM/d(img) (gradient of the mean over
/// all pixels and channels) into `d_img`, which must have `width·height` entries.
///
/// Panics if the images differ in size or `d_img` has the wrong length.
pub fn ssim_with_grad(
    scratch: &mut SsimScratch,
    img: &Image,
    gt: &Image,
    d_img: &mut [[f32; 3]],
) -> f32 {
    evaluate(scratch, img, gt, Some(d_img))
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Deterministic pseudo-random image with channels in [0, 1).
    pub(crate) fn noisy(w: usize, h: usize, seed: u32) -> Image {
        let mut s = seed.wrapping_mul(2654435761).wrapping_add(12345);
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

    /// Direct (non-separable) double-loop SSIM map in `f64`, per pixel and channel, written
    /// independently of the implementation above: explicit 2-D window, explicit zero padding.
    pub(crate) fn reference_map(
        x: &[[f64; 3]],
        y: &[[f64; 3]],
        w: usize,
        h: usize,
    ) -> Vec<[f64; 3]> {
        let g1: Vec<f64> = (0..11)
            .map(|i| (-((i as f64 - 5.0).powi(2)) / 4.5).exp())
            .collect();
        let s: f64 = g1.iter().sum();
        let g1: Vec<f64> = g1.iter().map(|v| v / s).collect();
        let (c1, c2) = (0.01f64.powi(2), 0.03f64.powi(2));
        let mut out = vec![[0.0; 3]; w * h];
        for py in 0..h as isize {
            for px in 0..w as isize {
                for c in 0..3 {
                    let (mut mx, mut my, mut exx, mut eyy, mut exy) = (0.0, 0.0, 0.0, 0.0, 0.0);
                    for dy in -5isize..=5 {
                        for dx in -5isize..=5 {
                            let (qx, qy) = (px + dx, py + dy);
                            if qx < 0 || qy < 0 || qx >= w as isize || qy >= h as isize {
                                continue; // zero padding
                            }
                            let wgt = g1[(dx + 5) as usize] * g1[(dy + 5) as usize];
                            let i = qy as usize * w + qx as usize;
                            let (a, b) = (x[i][c], y[i][c]);
                            mx += wgt * a;
                            my += wgt * b;
                            exx += wgt * a * a;
                            eyy += wgt * b * b;
                            exy += wgt * a * b;
                        }
                    }
                    let (sxx, syy, sxy) = (exx - mx * mx, eyy - my * my, exy - mx * my);
                    out[py as usize * w + px as usize][c] = ((2.0 * mx * my + c1)
                        * (2.0 * sxy + c2))
                        / ((mx * mx + my * my + c1) * (sxx + syy + c2));
                }
            }
        }
        out
    }

    /// Mean of [`reference_map`].
    pub(crate) fn reference_ssim(x: &[[f64; 3]], y: &[[f64; 3]], w: usize, h: usize) -> f64 {
        let m = reference_map(x, y, w, h);
        m.iter().flatten().sum::<f64>() / (3 * w * h) as f64
    }

    pub(crate) fn to_f64(img: &Image) -> Vec<[f64; 3]> {
        img.data.iter().map(|p| p.map(|v| v as f64)).collect()
    }

    #[test]
    fn window_is_normalised_and_symmetric() {
        let g = gaussian_window();
        assert!((g.iter().sum::<f32>() - 1.0).abs() < 1e-6);
        for i in 0..WIN {
            assert_eq!(g[i], g[WIN - 1 - i]);
        }
        assert!(g[RADIUS] > g[RADIUS - 1]);
    }

    #[test]
    fn self_similarity_is_one() {
        for (w, h) in [(13, 9), (32, 20), (3, 2), (1, 1)] {
            let a = noisy(w, h, 7);
            let s = ssim(&a, &a);
            assert!((s - 1.0).abs() < 1e-5, "{w}x{h}: {s}");
            assert!(ssim_map(&a, &a).iter().all(|v| (v - 1.0).abs() < 1e-4));
        }
    }

    #[test]
    fn constant_images_interior_value() {
        // Constant images: away from the borders (≥ 5 px) the window lies fully inside, so
        // σ's vanish and the map is the luminance term (2·c1·c2 + C1)/(c1² + c2² + C1).
        let (w, h) = (25, 23);
        let (a, b) = (0.3f32, 0.7f32);
        let map = ssim_map(&Image::filled(w, h, [a; 3]), &Image::filled(w, h, [b; 3]));
        let expected = (2.0 * a * b + C1) / (a * a + b * b + C1);
        for y in RADIUS..h - RADIUS {
            for x in RADIUS..w - RADIUS {
                let v = map[y * w + x];
                assert!((v - expected).abs() < 2e-4, "({x},{y}): {v} vs {expected}");
            }
        }
        // At a corner the zero padding makes the local statistics differ.
        assert!((map[0] - expected).abs() > 1e-3);
    }

    #[test]
    fn matches_direct_reference() {
        for (w, h, seed) in [(13, 9, 1), (30, 17, 2), (4, 3, 3), (11, 1, 4)] {
            let a = noisy(w, h, seed);
            // A correlated second image, so SSIM is away from 0.
            let mut b = noisy(w, h, seed + 100);
            for (q, p) in b.data.iter_mut().zip(&a.data) {
                for c in 0..3 {
                    q[c] = 0.7 * p[c] + 0.3 * q[c];
                }
            }
            let reference = reference_map(&to_f64(&a), &to_f64(&b), w, h);
            let map = ssim_map(&a, &b);
            for (i, (m, r)) in map.iter().zip(&reference).enumerate() {
                let r = (r[0] + r[1] + r[2]) / 3.0;
                assert!(
                    (*m as f64 - r).abs() < 2e-4,
                    "{w}x{h} pixel {i}: {m} vs {r}"
                );
            }
            let s = ssim(&a, &b) as f64;
            let r = reference_ssim(&to_f64(&a), &to_f64(&b), w, h);
            assert!((s - r).abs() < 2e-5, "{w}x{h}: {s} vs {r}");
        }
    }

    #[test]
    fn masked_ssim_full_and_empty() {
        let (a, b) = (noisy(12, 8, 5), noisy(12, 8, 6));
        let full = masked_ssim(&a, &b, &[true; 96]).unwrap();
        assert!((full - ssim(&a, &b)).abs() < 1e-6);
        assert_eq!(masked_ssim(&a, &b, &[false; 96]), None);
        let mut mask = vec![false; 96];
        mask[50] = true;
        assert!((masked_ssim(&a, &b, &mask).unwrap() - ssim_map(&a, &b)[50]).abs() < 1e-7);
    }

    /// Gradient against central differences of the `f64` reference (the `f32` forward would
    /// drown an `h = 1e-3` step in rounding noise). The analytic gradient is computed in `f32`,
    /// whose error relative to the largest gradient entry is ~1e-6·(condition ≈ 1/D ≲ 10²), and
    /// the central-difference truncation error is O(h²) ≈ 1e-8 relative, so 1e-3 has a wide
    /// margin while still catching any wrong term (dropping the −2μx correction, for instance,
    /// gives a relative error of ~0.4). Checked both in L2 norm and per entry (relative, with a
    /// floor of 1e-6 × the largest gradient entry for entries that are nearly zero); measured
    /// errors are ~2e-7.
    fn check_grad(w: usize, h: usize, seed: u32) {
        let img = noisy(w, h, seed);
        let gt = noisy(w, h, seed + 50);
        let mut scratch = SsimScratch::new();
        let mut d = vec![[0.0f32; 3]; w * h];
        let s = ssim_with_grad(&mut scratch, &img, &gt, &mut d);
        assert!((s - ssim(&img, &gt)).abs() < 1e-7);

        let (x0, y) = (to_f64(&img), to_f64(&gt));
        let step = 1e-4;
        let grad_scale = d
            .iter()
            .flatten()
            .fold(0.0f64, |m, v| m.max(v.abs() as f64));
        let mut max_fd = 0.0f64;
        let mut max_err = 0.0f64;
        let (mut num, mut den) = (0.0f64, 0.0f64);
        for i in 0..w * h {
            for c in 0..3 {
                let mut x = x0.clone();
                x[i][c] = x0[i][c] + step;
                let plus = reference_ssim(&x, &y, w, h);
                x[i][c] = x0[i][c] - step;
                let minus = reference_ssim(&x, &y, w, h);
                let fd = (plus - minus) / (2.0 * step);
                let err = (d[i][c] as f64 - fd).abs();
                // Per entry: relative error, with a floor for entries near zero.
                assert!(
                    err <= 1e-3 * fd.abs() + 1e-6 * grad_scale,
                    "entry ({i}, {c}): {} vs {fd}",
                    d[i][c]
                );
                max_fd = max_fd.max(fd.abs());
                max_err = max_err.max(err);
                num += err * err;
                den += fd * fd;
            }
        }
        let rel = (num / den).sqrt();
        assert!(rel <= 1e-3, "{w}x{h}: relative L2 gradient error {rel}");
        assert!(
            max_err <= 1e-3 * max_fd,
            "{w}x{h}: max error {max_err} (max |fd| {max_fd})"
        );
    }

    #[test]
    fn gradient_matches_finite_differences() {
        check_grad(13, 9, 11);
    }

    #[test]
    fn gradient_matches_finite_differences_small_image() {
        // Smaller than the window in both directions: every pixel is a border pixel.
        check_grad(4, 3, 12);
    }

    #[test]
    fn scratch_reuse_does_not_reallocate() {
        let (a, b) = (noisy(20, 14, 8), noisy(20, 14, 9));
        let mut scratch = SsimScratch::new();
        let mut d = vec![[0.0f32; 3]; 20 * 14];
        let first = ssim_with_grad(&mut scratch, &a, &b, &mut d);
        let ptrs = (
            scratch.bands[0].stats.ring.as_ptr(),
            scratch.bands[0].grad.ring.as_ptr(),
            scratch.grad.as_ptr(),
            scratch.map.as_ptr(),
            scratch.row_sums.as_ptr(),
        );
        let d_first = d.clone();
        let second = ssim_with_grad(&mut scratch, &a, &b, &mut d);
        assert_eq!(first, second, "evaluation must be deterministic");
        assert_eq!(d, d_first);
        assert_eq!(ssim_with_scratch(&mut scratch, &a, &b), first);
        let ptrs_after = (
            scratch.bands[0].stats.ring.as_ptr(),
            scratch.bands[0].grad.ring.as_ptr(),
            scratch.grad.as_ptr(),
            scratch.map.as_ptr(),
            scratch.row_sums.as_ptr(),
        );
        assert_eq!(ptrs, ptrs_after);
        // A size change still works with the same scratch.
        let (c, e) = (noisy(7, 5, 1), noisy(7, 5, 2));
        let mut d2 = vec![[0.0f32; 3]; 35];
        let s = ssim_with_grad(&mut scratch, &c, &e, &mut d2);
        assert!((s - ssim(&c, &e)).abs() < 1e-7);
    }

    #[test]
    #[should_panic(expected = "gradient buffer length")]
    fn grad_length_mismatch_panics() {
        let a = noisy(3, 3, 1);
        ssim_with_grad(&mut SsimScratch::new(), &a, &a, &mut [[0.0; 3]; 8]);
    }
}
