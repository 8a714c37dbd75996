//! LPIPS perceptual distance with the AlexNet backbone (linear heads v0.1).
//!
//! A self-contained CPU implementation: the five AlexNet convolutions are evaluated as
//! packed matrix products (im2col + a register-blocked micro kernel that auto-vectorises,
//! with an AVX2/FMA variant picked at run time), parallelised with rayon.
//!
//! The formula follows `shared/data/lpips/README.md`:
//!
//! 1. RGB8 values `v` map to `x = v / 127.5 − 1`; for our float images `v = c · 255`
//!    (no rounding), so images loaded from 8-bit files reproduce the reference input exactly.
//! 2. ScalingLayer `x' = (x − shift) / scale` per channel.
//! 3. AlexNet `features` up to the fifth ReLU, tapping every ReLU after a convolution.
//! 4. Each tap is unit-normalised across channels (`f / (‖f‖ + 1e-10)`).
//! 5. Squared differences are weighted per channel by `lin_l`, summed over channels and
//!    averaged over pixels; LPIPS is the sum of the five per-tap averages.

use std::path::Path;

use rayon::prelude::*;
use safetensors::{Dtype, SafeTensors};

use crate::io::image::Image;

/// Errors loading the LPIPS weights or evaluating the distance.
#[derive(Debug, thiserror::Error)]
pub enum LpipsError {
    /// The weights file could not be read (missing, unreadable).
    #[error("cannot read LPIPS weights file {path}: {source}")]
    Read {
        /// Path of the weights file.
        path: String,
        /// Underlying I/O error.
        source: std::io::Error,
    },
    /// The weights file is not a valid safetensors file.
    #[error("LPIPS weights file {path} is not a valid safetensors file: {message}")]
    Format {
        /// Path of the weights file.
        path: String,
        /// Parser message.
        message: String,
    },
    /// A tensor the network needs is absent from the weights file.
    #[error("LPIPS weights file {path} has no tensor `{name}` (expected shape {expected:?})")]
    MissingTensor {
        /// Path of the weights file.
        path: String,
        /// Name of the missing tensor.
        name: String,
        /// Shape the tensor should have.
        expected: Vec<usize>,
    },
    /// A tensor has the wrong shape or is not `float32`.
    #[error(
        "LPIPS weights file {path}: tensor `{name}` is {dtype} {found:?}, expected F32 {expected:?}"
    )]
    Shape {
        /// Path of the weights file.
        path: String,
        /// Name of the tensor.
        name: String,
        /// Data type found in the file.
        dtype: String,
        /// Shape found in the file.
        found: Vec<usize>,
        /// Shape expected.
        expected: Vec<usize>,
    },
    /// The two images do not have the same size.
    #[error("LPIPS: image sizes differ ({a_width}x{a_height} vs {b_width}x{b_height})")]
    SizeMismatch {
        /// Width of the first image.
        a_width: usize,
        /// Height of the first image.
        a_height: usize,
        /// Width of the second image.
        b_width: usize,
        /// Height of the second image.
        b_height: usize,
    },
    /// An image's pixel buffer does not hold `width × height` pixels.
    #[error("LPIPS: image buffer has {len} pixels but the image is {width}x{height}")]
    BadBuffer {
        /// Width of the image.
        width: usize,
        /// Height of the image.
        height: usize,
        /// Number of pixels in the buffer.
        len: usize,
    },
    /// The images are too small for the network (a tap would be empty).
    #[error("LPIPS: image {width}x{height} is too small for AlexNet (needs at least {min}x{min})")]
    TooSmall {
        /// Width of the images.
        width: usize,
        /// Height of the images.
        height: usize,
        /// Smallest width and height the network accepts.
        min: usize,
    },
}

/// Smallest image side for which every AlexNet tap is non-empty.
pub const MIN_SIZE: usize = 31;

/// ScalingLayer shift (R, G, B).
const SHIFT: [f32; 3] = [-0.030, -0.088, -0.188];
/// ScalingLayer scale (R, G, B).
const SCALE: [f32; 3] = [0.458, 0.448, 0.450];

/// Output channels processed together by the micro kernel.
const MR: usize = 4;
/// Output pixels processed together by the micro kernel.
const NR: usize = 16;
/// Output-channel rows per parallel task (a multiple of `MR`).
const OC_GROUP: usize = 16;

/// Static description of one convolution: (in ch, out ch, kernel, stride, padding).
const CONVS: [(usize, usize, usize, usize, usize); 5] = [
    (3, 64, 11, 4, 2),
    (64, 192, 5, 1, 2),
    (192, 384, 3, 1, 1),
    (384, 256, 3, 1, 1),
    (256, 256, 3, 1, 1),
];

/// A dense `c × h × w` float tensor, channel-major.
#[derive(Clone, Debug)]
struct Tensor3 {
    c: usize,
    h: usize,
    w: usize,
    data: Vec<f32>,
}

/// One convolution layer with its weights packed for the micro kernel.
#[derive(Clone, Debug)]
struct Conv {
    in_c: usize,
    out_c: usize,
    k: usize,
    stride: usize,
    pad: usize,
    /// Weights as `[out_c / MR][in_c·k·k][MR]`.
    packed: Vec<f32>,
    bias: Vec<f32>,
}

/// LPIPS (AlexNet, lin v0.1) network weights; see the module documentation for the formula.
#[derive(Clone, Debug)]
pub struct Lpips {
    convs: Vec<Conv>,
    lins: Vec<Vec<f32>>,
}

/// Reads one `float32` tensor with the expected shape.
fn read_tensor(
    st: &SafeTensors<'_>,
    path: &str,
    name: &str,
    expected: &[usize],
) -> Result<Vec<f32>, LpipsError> {
    let view = st.tensor(name).map_err(|_| LpipsError::MissingTensor {
        path: path.to_string(),
        name: name.to_string(),
        expected: expected.to_vec(),
    })?;
    if view.dtype() != Dtype::F32 || view.shape() != expected {
        return Err(LpipsError::Shape {
            path: path.to_string(),
            name: name.to_string(),
            dtype: format!("{:?}", view.dtype()),
            found: view.shape().to_vec(),
            expected: expected.to_vec(),
        });
    }
    Ok(view
        .data()
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect())
}

impl Lpips {
    /// Loads the AlexNet backbone and linear heads from a safetensors file laid out as in
    /// `shared/data/lpips/README.md` (`features.conv{0..4}.{weight,bias}`, `lin{0..4}.weight`).
    pub fn load(path: &Path) -> Result<Lpips, LpipsError> {
        let shown = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| LpipsError::Read {
            path: shown.clone(),
            source,
        })?;
        let st = SafeTensors::deserialize(&bytes).map_err(|e| LpipsError::Format {
            path: shown.clone(),
            message: e.to_string(),
        })?;
        let mut convs = Vec::with_capacity(5);
        let mut lins = Vec::with_capacity(5);
        for (i, &(in_c, out_c, k, stride, pad)) in CONVS.iter().enumerate() {
            let weight = read_tensor(
                &st,
                &shown,
                &format!("features.conv{i}.weight"),
                &[out_c, in_c, k, k],
            )?;
            let bias = read_tensor(&st, &shown, &format!("features.conv{i}.bias"), &[out_c])?;
            let lin = read_tensor(&st, &shown, &format!("lin{i}.weight"), &[out_c])?;
            let kk = in_c * k * k;
            let mut packed = vec![0.0f32; out_c * kk];
            for oc in 0..out_c {
                let (blk, r) = (oc / MR, oc % MR);
                for j in 0..kk {
                    packed[blk * kk * MR + j * MR + r] = weight[oc * kk + j];
                }
            }
            convs.push(Conv {
                in_c,
                out_c,
                k,
                stride,
                pad,
                packed,
                bias,
            });
            lins.push(lin);
        }
        Ok(Lpips { convs, lins })
    }

    /// LPIPS distance between two images of the same size (channels in [0, 1]).
    pub fn distance(&self, a: &Image, b: &Image) -> Result<f32, LpipsError> {
        Ok(self.layer_distances(a, b)?.iter().sum())
    }

    /// Per-tap contributions `s_0..s_4` (relu1..relu5); [`Lpips::distance`] is their sum.
    pub fn layer_distances(&self, a: &Image, b: &Image) -> Result<[f32; 5], LpipsError> {
        for img in [a, b] {
            if img.data.len() != img.width * img.height {
                return Err(LpipsError::BadBuffer {
                    width: img.width,
                    height: img.height,
                    len: img.data.len(),
                });
            }
        }
        if (a.width, a.height) != (b.width, b.height) {
            return Err(LpipsError::SizeMismatch {
                a_width: a.width,
                a_height: a.height,
                b_width: b.width,
                b_height: b.height,
            });
        }
        if a.width < MIN_SIZE || a.height < MIN_SIZE {
            return Err(LpipsError::TooSmall {
                width: a.width,
                height: a.height,
                min: MIN_SIZE,
            });
        }
        let (fa, fb) = rayon::join(|| self.features(a), || self.features(b));
        let mut out = [0.0f32; 5];
        for (l, o) in out.iter_mut().enumerate() {
            *o = tap_distance(&fa[l], &fb[l], &self.lins[l]) as f32;
        }
        Ok(out)
    }

    /// The five ReLU taps of AlexNet for one image.
    fn features(&self, img: &Image) -> Vec<Tensor3> {
        let x = scaled_input(img);
        let mut taps = Vec::with_capacity(5);
        let t0 = conv_relu(&x, &self.convs[0]);
        let p0 = maxpool3s2(&t0);
        taps.push(t0);
        let t1 = conv_relu(&p0, &self.convs[1]);
        let p1 = maxpool3s2(&t1);
        taps.push(t1);
        let t2 = conv_relu(&p1, &self.convs[2]);
        let t3 = conv_relu(&t2, &self.convs[3]);
        let t4 = conv_relu(&t3, &self.convs[4]);
        taps.push(t2);
        taps.push(t3);
        taps.push(t4);
        taps
    }
}

/// Converts an image to the network input (RGB8 scale, `[-1, 1]`, then ScalingLayer).
fn scaled_input(img: &Image) -> Tensor3 {
    let (h, w) = (img.height, img.width);
    let mut data = vec![0.0f32; 3 * h * w];
    for (i, p) in img.data.iter().enumerate() {
        for c in 0..3 {
            let v = p[c] * 255.0;
            let x = v / 127.5 - 1.0;
            data[c * h * w + i] = (x - SHIFT[c]) / SCALE[c];
        }
    }
    Tensor3 { c: 3, h, w, data }
}

/// Convolution (cross-correlation, zero padding) followed by ReLU.
fn conv_relu(x: &Tensor3, conv: &Conv) -> Tensor3 {
    assert_eq!(x.c, conv.in_c, "lpips: channel count mismatch");
    assert_eq!(
        conv.out_c % MR,
        0,
        "lpips: output channels must be a multiple of {MR}"
    );
    let (k, s, p) = (conv.k, conv.stride, conv.pad);
    let oh = (x.h + 2 * p - k) / s + 1;
    let ow = (x.w + 2 * p - k) / s + 1;
    let n = oh * ow;
    let kk = conv.in_c * k * k;

    // Zero-padded copy of the input.
    let (hp, wp) = (x.h + 2 * p, x.w + 2 * p);
    let mut xp = vec![0.0f32; x.c * hp * wp];
    for c in 0..x.c {
        for y in 0..x.h {
            let src = &x.data[(c * x.h + y) * x.w..][..x.w];
            xp[(c * hp + y + p) * wp + p..][..x.w].copy_from_slice(src);
        }
    }
    // Offset of each kernel tap (ic, ky, kx) and of each output pixel in the padded input.
    let mut tap_off = Vec::with_capacity(kk);
    for c in 0..x.c {
        for ky in 0..k {
            for kx in 0..k {
                tap_off.push((c * hp + ky) * wp + kx);
            }
        }
    }
    let panels = n.div_ceil(NR);
    let mut pix_off = vec![usize::MAX; panels * NR];
    for oy in 0..oh {
        for ox in 0..ow {
            pix_off[oy * ow + ox] = oy * s * wp + ox * s;
        }
    }
    // im2col, packed as [panel][kk][NR] (missing pixels of the last panel stay zero).
    let mut cols = vec![0.0f32; panels * kk * NR];
    cols.par_chunks_mut(kk * NR)
        .zip(pix_off.par_chunks(NR))
        .for_each(|(panel, offs)| {
            for (row, &t) in panel.chunks_exact_mut(NR).zip(&tap_off) {
                for (v, &o) in row.iter_mut().zip(offs) {
                    if o != usize::MAX {
                        *v = xp[o + t];
                    }
                }
            }
        });

    // Packed GEMM: out[oc][pixel] = bias + W[oc] · col[pixel], then ReLU.
    let mut out = vec![0.0f32; conv.out_c * n];
    let use_fma = has_fma();
    out.par_chunks_mut(OC_GROUP * n)
        .enumerate()
        .for_each(|(g, rows)| {
            let blocks = rows.len() / n / MR;
            for panel in 0..panels {
                let cp = &cols[panel * kk * NR..][..kk * NR];
                let cols_here = NR.min(n - panel * NR);
                for blk in 0..blocks {
                    let oc0 = g * OC_GROUP + blk * MR;
                    let wp = &conv.packed[(oc0 / MR) * kk * MR..][..kk * MR];
                    let acc = micro(use_fma, wp, cp);
                    for (r, acc_r) in acc.iter().enumerate() {
                        let b = conv.bias[oc0 + r];
                        let dst = &mut rows[(blk * MR + r) * n + panel * NR..][..cols_here];
                        for (d, &a) in dst.iter_mut().zip(acc_r) {
                            *d = (a + b).max(0.0);
                        }
                    }
                }
            }
        });
    Tensor3 {
        c: conv.out_c,
        h: oh,
        w: ow,
        data: out,
    }
}

/// Whether the AVX2 + FMA micro kernel can be used.
fn has_fma() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// `MR × NR` block of the product of packed weights `[kk][MR]` and packed columns `[kk][NR]`.
fn micro(use_fma: bool, wp: &[f32], cp: &[f32]) -> [[f32; NR]; MR] {
    #[cfg(target_arch = "x86_64")]
    if use_fma {
        // SAFETY: `use_fma` is only true when AVX2 and FMA were detected at run time.
        return unsafe { micro_fma(wp, cp) };
    }
    let _ = use_fma;
    micro_body::<false>(wp, cp)
}

/// The micro kernel compiled for AVX2 + FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn micro_fma(wp: &[f32], cp: &[f32]) -> [[f32; NR]; MR] {
    micro_body::<true>(wp, cp)
}

/// Register-blocked inner product loop; `FMA` selects fused multiply-adds.
#[inline(always)]
fn micro_body<const FMA: bool>(wp: &[f32], cp: &[f32]) -> [[f32; NR]; MR] {
    let mut acc = [[0.0f32; NR]; MR];
    for (w, c) in wp.chunks_exact(MR).zip(cp.chunks_exact(NR)) {
        let w: &[f32; MR] = w.try_into().unwrap();
        let c: &[f32; NR] = c.try_into().unwrap();
        for r in 0..MR {
            for j in 0..NR {
                acc[r][j] = if FMA {
                    w[r].mul_add(c[j], acc[r][j])
                } else {
                    acc[r][j] + w[r] * c[j]
                };
            }
        }
    }
    acc
}

/// 3×3 max-pool with stride 2 and no padding (floor).
fn maxpool3s2(x: &Tensor3) -> Tensor3 {
    let oh = (x.h - 3) / 2 + 1;
    let ow = (x.w - 3) / 2 + 1;
    let mut data = vec![0.0f32; x.c * oh * ow];
    data.par_chunks_mut(oh * ow)
        .enumerate()
        .for_each(|(c, plane)| {
            let src = &x.data[c * x.h * x.w..][..x.h * x.w];
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut m = f32::NEG_INFINITY;
                    for dy in 0..3 {
                        for dx in 0..3 {
                            m = m.max(src[(2 * oy + dy) * x.w + 2 * ox + dx]);
                        }
                    }
                    plane[oy * ow + ox] = m;
                }
            }
        });
    Tensor3 {
        c: x.c,
        h: oh,
        w: ow,
        data,
    }
}

/// Spatial mean of the lin-weighted squared difference of channel-normalised taps.
fn tap_distance(a: &Tensor3, b: &Tensor3, lin: &[f32]) -> f64 {
    let hw = a.h * a.w;
    let mut total = 0.0f64;
    let mut na = vec![0.0f32; hw];
    let mut nb = vec![0.0f32; hw];
    for c in 0..a.c {
        let (ca, cb) = (&a.data[c * hw..][..hw], &b.data[c * hw..][..hw]);
        for i in 0..hw {
            na[i] += ca[i] * ca[i];
            nb[i] += cb[i] * cb[i];
        }
    }
    let ia: Vec<f32> = na.iter().map(|s| 1.0 / (s.sqrt() + 1e-10)).collect();
    let ib: Vec<f32> = nb.iter().map(|s| 1.0 / (s.sqrt() + 1e-10)).collect();
    let mut d = vec![0.0f32; hw];
    for (c, &l) in lin.iter().enumerate().take(a.c) {
        let (ca, cb) = (&a.data[c * hw..][..hw], &b.data[c * hw..][..hw]);
        for i in 0..hw {
            let e = ca[i] * ia[i] - cb[i] * ib[i];
            d[i] += l * e * e;
        }
    }
    for v in d {
        total += v as f64;
    }
    total / hw as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct (naive) convolution used to check the packed GEMM path.
    fn naive_conv_relu(x: &Tensor3, w: &[f32], bias: &[f32], conv: &Conv) -> Tensor3 {
        let (k, s, p) = (conv.k, conv.stride, conv.pad);
        let oh = (x.h + 2 * p - k) / s + 1;
        let ow = (x.w + 2 * p - k) / s + 1;
        let mut data = vec![0.0f32; conv.out_c * oh * ow];
        for oc in 0..conv.out_c {
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut acc = bias[oc] as f64;
                    for ic in 0..x.c {
                        for ky in 0..k {
                            for kx in 0..k {
                                let iy = (oy * s + ky) as isize - p as isize;
                                let ix = (ox * s + kx) as isize - p as isize;
                                if iy < 0 || ix < 0 || iy >= x.h as isize || ix >= x.w as isize {
                                    continue;
                                }
                                let v = x.data[(ic * x.h + iy as usize) * x.w + ix as usize];
                                let wv = w[((oc * x.c + ic) * k + ky) * k + kx];
                                acc += (v * wv) as f64;
                            }
                        }
                    }
                    data[(oc * oh + oy) * ow + ox] = (acc as f32).max(0.0);
                }
            }
        }
        Tensor3 {
            c: conv.out_c,
            h: oh,
            w: ow,
            data,
        }
    }

    fn pseudo(i: usize) -> f32 {
        let x = (i as u64)
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((x >> 40) as f32 / (1u64 << 24) as f32) - 0.5
    }

    #[test]
    fn packed_conv_matches_naive() {
        for &(in_c, out_c, k, stride, pad, h, w) in &[
            (3usize, 8usize, 11usize, 4usize, 2usize, 37usize, 45usize),
            (5, 12, 5, 1, 2, 9, 13),
            (7, 4, 3, 1, 1, 6, 5),
        ] {
            let kk = in_c * k * k;
            let weight: Vec<f32> = (0..out_c * kk).map(pseudo).collect();
            let bias: Vec<f32> = (0..out_c).map(|i| pseudo(i + 999)).collect();
            let mut packed = vec![0.0f32; out_c * kk];
            for oc in 0..out_c {
                for j in 0..kk {
                    packed[(oc / MR) * kk * MR + j * MR + oc % MR] = weight[oc * kk + j];
                }
            }
            let conv = Conv {
                in_c,
                out_c,
                k,
                stride,
                pad,
                packed,
                bias: bias.clone(),
            };
            let x = Tensor3 {
                c: in_c,
                h,
                w,
                data: (0..in_c * h * w).map(|i| pseudo(i + 7777)).collect(),
            };
            let fast = conv_relu(&x, &conv);
            let slow = naive_conv_relu(&x, &weight, &bias, &conv);
            assert_eq!((fast.c, fast.h, fast.w), (slow.c, slow.h, slow.w));
            for (a, b) in fast.data.iter().zip(&slow.data) {
                assert!((a - b).abs() < 1e-4, "{a} vs {b}");
            }
        }
    }

    #[test]
    fn portable_and_fma_kernels_agree() {
        let kk = 37;
        let wp: Vec<f32> = (0..kk * MR).map(pseudo).collect();
        let cp: Vec<f32> = (0..kk * NR).map(|i| pseudo(i + 31)).collect();
        let portable = micro(false, &wp, &cp);
        let best = micro(has_fma(), &wp, &cp);
        for r in 0..MR {
            for j in 0..NR {
                let exact: f64 = (0..kk)
                    .map(|k| wp[k * MR + r] as f64 * cp[k * NR + j] as f64)
                    .sum();
                assert!((portable[r][j] as f64 - exact).abs() < 1e-5);
                assert!((best[r][j] as f64 - exact).abs() < 1e-5);
            }
        }
    }

    #[test]
    fn maxpool_shapes_and_values() {
        let x = Tensor3 {
            c: 1,
            h: 5,
            w: 7,
            data: (0..35).map(|i| i as f32).collect(),
        };
        let y = maxpool3s2(&x);
        assert_eq!((y.h, y.w), (2, 3));
        assert_eq!(y.data, vec![16.0, 18.0, 20.0, 30.0, 32.0, 34.0]);
    }

    #[test]
    fn min_size_gives_nonempty_taps() {
        // Follow the shape arithmetic of the network for MIN_SIZE and MIN_SIZE - 1.
        let taps = |n: usize| -> Option<usize> {
            let c0 = (n + 4).checked_sub(11)? / 4 + 1;
            let p0 = c0.checked_sub(3)? / 2 + 1;
            let p1 = p0.checked_sub(3)? / 2 + 1;
            Some(p1)
        };
        assert!(taps(MIN_SIZE).is_some_and(|v| v >= 1));
        assert!(taps(MIN_SIZE - 1).is_none());
    }
}
