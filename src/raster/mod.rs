//! CPU tile rasterizer, forward and backward: the reference backend.
//!
//! Splats (projected 2D Gaussians) are binned into 16×16 tiles, sorted by depth per tile and
//! alpha-blended front to back with the 3DGS constants (SPEC §4). The backward pass walks each
//! pixel's contributors back to front and writes one gradient per (tile, splat) pair; those
//! partial sums are then reduced per splat, so no atomics are needed and the result is
//! deterministic.

mod backward;
mod binning;
mod forward;

use glam::Vec2;

use crate::io::image::Image;

pub use binning::TileBins;

/// Tile side in pixels.
pub const TILE: usize = 16;
/// Pixels per tile.
pub const TILE_PIXELS: usize = TILE * TILE;
/// Contributions below this alpha are skipped.
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Alpha is clamped to this value.
pub const ALPHA_MAX: f32 = 0.99;
/// A pixel stops once its transmittance would fall below this.
pub const TRANSMITTANCE_MIN: f32 = 1e-4;

/// A projected Gaussian ready to be blended.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Splat {
    /// Centre in pixel coordinates (pixel (x, y) has its centre at (x + 0.5, y + 0.5)).
    pub mean2d: Vec2,
    /// (a, b, c) of the inverse 2D covariance: power = −½(a·dx² + c·dy²) − b·dx·dy.
    pub conic: [f32; 3],
    pub depth: f32,
    pub opacity: f32,
    pub color: [f32; 3],
    /// Half-size in pixels of the screen box it covers.
    pub extent: Vec2,
    /// False for splats culled by projection: they cover no tile.
    pub visible: bool,
}

/// Gradient of the loss with respect to a splat's blended quantities.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SplatGrad {
    pub mean2d: Vec2,
    pub conic: [f32; 3],
    pub opacity: f32,
    pub color: [f32; 3],
}

impl SplatGrad {
    fn add(&mut self, other: &SplatGrad) {
        self.mean2d += other.mean2d;
        for i in 0..3 {
            self.conic[i] += other.conic[i];
            self.color[i] += other.color[i];
        }
        self.opacity += other.opacity;
    }
}

/// Rasterizer state reused across iterations: tile bins and the per-pixel forward results
/// the backward pass needs.
#[derive(Default)]
pub struct Rasterizer {
    bins: TileBins,
    /// Final transmittance per pixel, tile-major.
    final_transmittance: Vec<f32>,
    /// Per pixel (tile-major): number of tile entries up to and including the last one blended.
    contributors: Vec<u32>,
    /// Tile-major colour buffer of the last forward pass.
    tile_color: Vec<[f32; 3]>,
    /// Per-entry gradient partial sums (in tile-sorted entry order).
    entry_grads: Vec<SplatGrad>,
    background: [f32; 3],
}

/// Rendered image and coverage (alpha = 1 − final transmittance), row-major.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    pub image: Image,
    pub alpha: Vec<f32>,
}

impl Default for RenderOutput {
    fn default() -> Self {
        Self {
            image: Image::filled(0, 0, [0.0; 3]),
            alpha: Vec::new(),
        }
    }
}

impl Rasterizer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Number of (tile, splat) pairs in the last forward pass.
    pub fn intersections(&self) -> usize {
        self.bins.entry_count()
    }

    /// Heap bytes held by the rasterizer's reusable buffers.
    pub fn heap_bytes(&self) -> usize {
        fn bytes<T>(v: &Vec<T>) -> usize {
            v.capacity() * std::mem::size_of::<T>()
        }
        self.bins.heap_bytes()
            + bytes(&self.final_transmittance)
            + bytes(&self.contributors)
            + bytes(&self.tile_color)
            + bytes(&self.entry_grads)
    }

    fn tiles_x(&self) -> usize {
        self.bins.tiles_x
    }
}

/// e^x for x ≤ 0 (the Gaussian falloff), relative error below 2e-6 (1e-7 from the polynomial, the rest
/// from rounding x·log2 e in f32): a power-of-two split and
/// a degree-6 polynomial, branch-free so the per-pixel loops vectorise (libm's `expf` is a call).
#[inline(always)]
pub fn exp_falloff(x: f32) -> f32 {
    let t = (x * std::f32::consts::LOG2_E).max(-126.0);
    // Round to nearest by adding and removing 1.5·2^23 (no libm call, vectorises).
    const ROUND: f32 = 12_582_912.0;
    let n = (t + ROUND) - ROUND;
    let f = t - n; // in [−½, ½]
    // 2^f = e^(f ln 2) by its Taylor series to degree 6 (truncation error < 1.2e-7 on [−½, ½]).
    let p = 1.0
        + f * (std::f32::consts::LN_2
            + f * (0.240_226_5
                + f * (0.055_504_11
                    + f * (0.009_618_129 + f * (0.001_333_355_8 + f * 0.000_154_035_3)))));
    f32::from_bits(((n as i32 + 127) as u32) << 23) * p
}

/// Tile-local pixel indices inside a splat's screen box: outside it the splat's alpha is below
/// 1/255 (see [`Splat::extent`]), so those pixels are skipped.
#[inline]
fn box_pixels(splat: &Splat, origin: (usize, usize)) -> impl Iterator<Item = usize> {
    let local = |centre: f32, extent: f32, start: usize| {
        let lo = (centre - extent - 0.5 - start as f32).floor().max(0.0) as usize;
        let hi =
            ((centre + extent - 0.5 - start as f32).ceil() + 1.0).clamp(0.0, TILE as f32) as usize;
        (lo.min(TILE), hi)
    };
    let (x0, x1) = local(splat.mean2d.x, splat.extent.x, origin.0);
    let (y0, y1) = local(splat.mean2d.y, splat.extent.y, origin.1);
    (y0..y1).flat_map(move |y| (x0..x1).map(move |x| y * TILE + x))
}

/// The exponent below which a splat's alpha is under 1/255 (with a little slack for rounding;
/// the alpha test itself follows).
#[inline]
fn min_power(splat: &Splat) -> f32 {
    (ALPHA_MIN / splat.opacity).ln() - 1e-4
}

/// Offset (dx, dy) of tile pixel `p` from the splat centre and the Gaussian falloff G there,
/// or None where the splat is not drawn (alpha < 1/255). Forward and backward share it so they
/// agree on every pixel.
#[inline(always)]
fn falloff_at(
    splat: &Splat,
    origin: (usize, usize),
    p: usize,
    min_power: f32,
) -> Option<(f32, f32, f32)> {
    let dx = (origin.0 + p % TILE) as f32 + 0.5 - splat.mean2d.x;
    let dy = (origin.1 + p / TILE) as f32 + 0.5 - splat.mean2d.y;
    let pw = forward::power(&splat.conic, dx, dy);
    // Below `min_power` alpha < 1/255; a positive exponent is numerical noise.
    if pw > 0.0 || pw < min_power {
        return None;
    }
    let gauss = exp_falloff(pw);
    (splat.opacity * gauss >= ALPHA_MIN).then_some((dx, dy, gauss))
}

/// Reorders a tile-major buffer into a row-major image of `width × height`.
fn untile<T: Copy + Send + Sync>(
    tiled: &[T],
    tiles_x: usize,
    width: usize,
    height: usize,
    out: &mut Vec<T>,
    fill: T,
) {
    use rayon::prelude::*;
    out.clear();
    out.resize(width * height, fill);
    out.par_chunks_mut(width).enumerate().for_each(|(y, row)| {
        let ty = y / TILE;
        let ly = y % TILE;
        for (x, value) in row.iter_mut().enumerate() {
            let tile = ty * tiles_x + x / TILE;
            *value = tiled[tile * TILE_PIXELS + ly * TILE + x % TILE];
        }
    });
}

#[cfg(test)]
mod tests;

/// The instruction set the pixel loops run with on this CPU (chosen at run time).
pub fn simd_level() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
        return "x86-64 AVX2 + FMA";
    }
    "baseline"
}
