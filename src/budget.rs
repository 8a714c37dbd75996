//! Memory a training run needs, estimated before it starts, and checked against the memory
//! the machine has available, so that a run too big for the machine stops with an error
//! that says what to lower instead of being killed by the out-of-memory killer mid-run.
//!
//! The estimate has three parts:
//! - the dataset's images and masks (already loaded when the estimate is made);
//! - per-pixel buffers for the largest camera: rasterizer state, the render, the loss
//!   target and gradient and the SSIM scratch ([`BYTES_PER_PIXEL`]);
//! - per-Gaussian state: every component of a Gaussian (parameters, gradients, Adam
//!   moments, statistics, deformed values), the splatting stage's per-Gaussian arrays and
//!   its per-(tile, Gaussian) entries for [`TILES_PER_GAUSSIAN`] tiles each
//!   ([`bytes_per_gaussian`]), times [`HEADROOM`] for growable arrays and the allocator.
//!
//! The images are already resident when the check runs, so the rest is what must fit in the
//! available memory. The initial Gaussians at the requested resolution must fit, or
//! [`MemoryEstimate::check`] is an error; the population cap `densify.max_gaussians` is
//! lowered (with a warning) to the count that fits, since densification would otherwise
//! grow the population until the process is killed.

use std::mem::size_of;

use crate::components::gaussian_bytes;
use crate::data::Dataset;
use crate::raster::{PACKED_SPLAT_BYTES, Splat, SplatGrad};
use crate::resources::DeformedGrad;
use crate::scene::SceneConfig;

/// Bytes of per-pixel buffers: rasterizer (transmittance, contributor count, tile colour:
/// 20), render (colour and alpha: 16), loss (target and gradient: 24), SSIM scratch (two
/// 15-moment and two 9-gradient buffers and the map: 196).
pub const BYTES_PER_PIXEL: usize = 20 + 16 + 24 + 196;

/// Tiles a Gaussian's screen box overlaps on average: a splat of a few pixels straddles up
/// to four 16×16 tiles.
pub const TILES_PER_GAUSSIAN: usize = 4;

/// Allowance for growable arrays (doubling capacity), ECS tables and the allocator.
pub const HEADROOM: f64 = 1.25;

/// Bytes one Gaussian of a model of SH degree `sh_degree` costs while training, with or
/// without its gradient components (`train.fused_adam` does without them).
pub fn bytes_per_gaussian(sh_degree: u32, gradients: bool) -> usize {
    // ECS storage: the components plus the entity id in its table and its location record.
    let ecs = gaussian_bytes(sh_degree, gradients) + 8 + 16;
    // Splatting arrays indexed by slot: splat, packed splat, gradients and the backward's
    // second half-sum of them, NDC gradient norm, tile rectangle, entry offset, depth key and
    // its radix-sort buffer, and depth-ordered binning record.
    let slots = size_of::<Splat>()
        + PACKED_SPLAT_BYTES
        + 2 * size_of::<SplatGrad>()
        + size_of::<DeformedGrad>()
        + 4
        + 16
        + 4
        + 2 * 8
        + 20;
    // Per (tile, Gaussian) entry: sorted index, position and gradient partial sum (an upper
    // bound: only the entries the backward walks get one).
    let entries = TILES_PER_GAUSSIAN * (4 + 4 + size_of::<SplatGrad>());
    ecs + slots + entries
}

/// The memory a run needs, in bytes, by part.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MemoryEstimate {
    /// Decoded images and masks the dataset holds in memory.
    pub images: u64,
    /// The cache that streamed images are read through (`data.cache_mb`): empty when the
    /// estimate is made, full soon after.
    pub image_cache: u64,
    /// Per-pixel buffers for the largest camera.
    pub pixel_buffers: u64,
    /// Bytes per Gaussian, headroom included.
    pub per_gaussian: u64,
    /// Gaussians at the start: points per anchor × anchor frames (a point-cloud file is
    /// counted as `points_per_anchor` points; its real size is known only once read).
    pub initial_gaussians: u64,
    /// The population cap, `densify.max_gaussians`.
    pub max_gaussians: u64,
}

/// A run that cannot fit in memory.
#[derive(Debug, thiserror::Error)]
#[error(
    "not enough memory: {gaussians} initial Gaussians at {width}×{height} px need {:.2} GB \
     more, but only {:.2} GB is available; lower init.points_per_anchor (at most about \
     {fits} Gaussians fit) or the resolution (data downscale)",
    *.needed as f64 / 1e9,
    *.available as f64 / 1e9
)]
pub struct BudgetError {
    /// Initial Gaussians requested ([`MemoryEstimate::initial_gaussians`]).
    pub gaussians: u64,
    /// Width in pixels of the largest camera, which sizes the per-pixel buffers.
    pub width: u32,
    /// Height in pixels of the largest camera.
    pub height: u32,
    /// Bytes the initial Gaussians and the per-pixel buffers need, beyond the loaded images.
    pub needed: u64,
    /// Bytes available after loading the images (`MemAvailable`).
    pub available: u64,
    /// The largest number of Gaussians that would fit in `available` bytes.
    pub fits: u64,
}

impl MemoryEstimate {
    /// The estimate for training `scene` on `dataset`.
    pub fn new(scene: &SceneConfig, dataset: &Dataset) -> Self {
        let (width, height) = largest_camera(dataset);
        let anchors = dataset.anchor_frames(scene.init.anchor_spacing).len();
        // Coarse-to-fine keeps a downscaled copy of the views (at most this much).
        let factor = u64::from(scene.train.coarse_downscale.max(1));
        let images = dataset.memory_bytes() as u64;
        Self {
            image_cache: dataset.cache().map_or(0, |cache| cache.capacity() as u64),
            images: images
                + if factor > 1 {
                    images / (factor * factor)
                } else {
                    0
                },
            pixel_buffers: (width as u64) * (height as u64) * BYTES_PER_PIXEL as u64,
            per_gaussian: (bytes_per_gaussian(scene.model.sh_degree, !scene.train.fuses_adam())
                as f64
                * HEADROOM)
                .ceil() as u64,
            initial_gaussians: (anchors * scene.init.points_per_anchor) as u64,
            max_gaussians: scene.densify.max_gaussians as u64,
        }
    }

    /// Bytes needed beyond the images with `gaussians` Gaussians alive.
    pub fn working_bytes(&self, gaussians: u64) -> u64 {
        self.pixel_buffers
            .saturating_add(self.per_gaussian.saturating_mul(gaussians))
    }

    /// The largest population whose working set fits in `available` bytes.
    pub fn gaussians_that_fit(&self, available: u64) -> u64 {
        available.saturating_sub(self.pixel_buffers) / self.per_gaussian.max(1)
    }

    /// Checks the run against `available` bytes (free memory after loading the images):
    /// an error when the initial Gaussians do not fit; otherwise the population cap to use,
    /// lower than `max_gaussians` when the cap itself would not fit.
    pub fn check(&self, available: u64, camera: (u32, u32)) -> Result<u64, BudgetError> {
        let available = available.saturating_sub(self.image_cache);
        let fits = self.gaussians_that_fit(available);
        if self.working_bytes(self.initial_gaussians) > available {
            return Err(BudgetError {
                gaussians: self.initial_gaussians,
                width: camera.0,
                height: camera.1,
                needed: self.working_bytes(self.initial_gaussians),
                available,
                fits,
            });
        }
        Ok(self.max_gaussians.min(fits))
    }
}

impl std::fmt::Display for MemoryEstimate {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let gb = |bytes: u64| bytes as f64 / 1e9;
        write!(
            f,
            "memory estimate: images {:.2} GB + per-pixel buffers {:.3} GB + {} B per Gaussian \
             × {} initial Gaussians = {:.2} GB at the start, {:.2} GB at the cap of {} Gaussians",
            gb(self.images + self.image_cache),
            gb(self.pixel_buffers),
            self.per_gaussian,
            self.initial_gaussians,
            gb(self.images + self.image_cache + self.working_bytes(self.initial_gaussians)),
            gb(self.images + self.image_cache + self.working_bytes(self.max_gaussians)),
            self.max_gaussians
        )
    }
}

/// Width and height of the camera with the most pixels (the per-pixel buffers follow it).
pub fn largest_camera(dataset: &Dataset) -> (u32, u32) {
    dataset
        .cameras
        .iter()
        .map(|c| (c.width, c.height))
        .max_by_key(|&(w, h)| w as u64 * h as u64)
        .unwrap_or((0, 0))
}

/// The memory available to a new allocation now (`MemAvailable` of `/proc/meminfo`), or
/// None where that file does not exist (not Linux) or lacks the field.
pub fn available_memory() -> Option<u64> {
    parse_mem_available(&std::fs::read_to_string("/proc/meminfo").ok()?)
}

/// `MemAvailable` of a `/proc/meminfo` text, in bytes.
pub fn parse_mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo
        .lines()
        .find_map(|l| l.strip_prefix("MemAvailable:"))?;
    let mut parts = line.split_whitespace();
    let value: u64 = parts.next()?.parse().ok()?;
    match parts.next() {
        Some("kB") => Some(value * 1024),
        None => Some(value),
        Some(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn estimate() -> MemoryEstimate {
        MemoryEstimate {
            images: 1_000,
            image_cache: 0,
            pixel_buffers: 10_000,
            per_gaussian: 2_000,
            initial_gaussians: 100,
            max_gaussians: 1_000,
        }
    }

    /// MemAvailable is read in kB and converted to bytes; a text without it gives None.
    #[test]
    fn reads_mem_available() {
        let text =
            "MemTotal:       24683656 kB\nMemFree:  10851188 kB\nMemAvailable:   23388112 kB\n";
        assert_eq!(parse_mem_available(text), Some(23_388_112 * 1024));
        assert_eq!(parse_mem_available("MemTotal: 5 kB\n"), None);
        assert_eq!(parse_mem_available("MemAvailable: lots kB\n"), None);
    }

    /// With room for the cap, the cap is kept.
    #[test]
    fn cap_is_kept_when_it_fits() {
        let e = estimate();
        assert_eq!(e.check(10_000 + 2_000 * 1_000, (64, 48)).unwrap(), 1_000);
    }

    /// With room for the initial Gaussians but not for the cap, the cap becomes the
    /// number that fits.
    #[test]
    fn cap_is_lowered_to_what_fits() {
        let e = estimate();
        assert_eq!(
            e.check(10_000 + 2_000 * 400 + 1_999, (64, 48)).unwrap(),
            400
        );
    }

    /// Without room for the initial Gaussians the check fails, and the error says what is
    /// needed, what is available, and what to lower.
    #[test]
    fn initial_gaussians_that_do_not_fit_are_an_error() {
        let e = estimate();
        let error = e.check(10_000 + 2_000 * 99, (640, 360)).unwrap_err();
        assert_eq!((error.needed, error.fits), (210_000, 99));
        let message = error.to_string();
        for part in [
            "100 initial Gaussians",
            "640×360",
            "init.points_per_anchor",
            "downscale",
        ] {
            assert!(message.contains(part), "{message}");
        }
    }

    /// The per-Gaussian cost counts at least the parameters, gradients (4 bytes per value
    /// each) and both Adam moments (2 bytes per value each, bfloat16) of every parameter
    /// component: 12 bytes for each of 97 values with every SH band, of 52 at SH degree 0 (the
    /// higher bands are not stored); without gradient components 4 bytes per value less.
    #[test]
    fn per_gaussian_bytes_cover_the_optimiser_state() {
        for (gradients, per_value) in [(true, 4 + 4 + 2 + 2), (false, 4 + 2 + 2)] {
            let optimised = |values: usize| values * per_value;
            let bytes = |sh_degree| bytes_per_gaussian(sh_degree, gradients);
            assert!(bytes(3) >= optimised(97), "{}", bytes(3));
            assert!(bytes(0) >= optimised(52), "{}", bytes(0));
            assert_eq!(
                bytes(3) - bytes(0),
                optimised(45),
                "the higher bands: 45 values, each with its two moments (and gradient: \
                 {gradients})"
            );
            assert_eq!(
                bytes_per_gaussian(3, true) - bytes_per_gaussian(3, false),
                4 * 97,
                "a gradient per value"
            );
        }
    }
}
