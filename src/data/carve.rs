//! Initial point clouds from the images themselves: a visual hull carved from foreground
//! masks, background points outside it, and a photo-consistency fallback for unmasked data.
//!
//! Random initial points waste the first thousands of iterations on moving Gaussians to the
//! subject; carving puts them there from the start and gives them the observed colours.
//!
//! All carving works on a regular grid of cubic voxels. A voxel votes with its centre: every
//! view into which the centre projects (in front of the camera, inside the image) looks at the
//! pixels whose centres lie in a square footprint around it. For the visual hull the square
//! bounds the voxel's bounding sphere, so voxels bigger than a pixel do not miss thin parts and
//! the hull stays an over-approximation; photo-consistency uses the inscribed sphere, so as
//! not to mix in colours of neighbouring surfaces.

use std::time::Instant;

use glam::Vec3;
use image::RgbImage;
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::init::{InitPoint, rig_focus};
use super::{Camera, Dataset, View};

/// Points closer to a camera than this (along its axis) are not seen by it.
const MIN_DEPTH: f32 = 1e-3;
/// The fine grid may not exceed this many voxels per side (memory: one byte per voxel).
const MAX_RESOLUTION: u32 = 512;
/// Background candidates are drawn in batches of this size and tested in parallel.
const CANDIDATE_BATCH: usize = 4096;
/// Rejection sampling of background candidates gives up after this many draws per wanted one.
const CANDIDATE_TRIES: usize = 200;
/// Hull points are drawn at most this many times per point before filtering is given up.
const HULL_TRIES: usize = 20;

/// How to carve the initial point cloud of an anchor frame (a `carve: (...)` block in scene
/// files; omitted fields take their defaults).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CarveSettings {
    /// Voxels along the longest side of the grid. The hull is first carved at this resolution
    /// (at most 64) over the whole region the cameras see, then at this one over the bounding
    /// box of what survived: on Panoptic frame 0 (two players, 4 m apart) 96 gives 4.4 cm voxels.
    pub resolution: u32,
    /// Fraction of the views that see a voxel which must see it as foreground for it to be
    /// kept. Below 1 tolerates a few bad masks (a player cut off by a segmentation error).
    pub agreement: f32,
    /// A voxel (or background point) seen by fewer masked views than this is dropped: a region
    /// seen by one or two cameras is a cone, not a shape.
    pub min_views: usize,
    /// Share of the points of [`initial_points`] taken from the hull; the rest are background.
    pub foreground_fraction: f32,
    /// Photo-consistency: the largest standard deviation (RGB in [0, 1], averaged over the
    /// channels) of a voxel's colours across the views that see it for it to be kept.
    pub colour_tolerance: f32,
    /// Share of hull points placed in surface voxels (those with an empty neighbour): Gaussians
    /// only need to model what the cameras see, so the interior gets few.
    pub surface_preference: f32,
    /// Half-size of the search region (a cube around the rig's focus) in units of the mean
    /// camera distance from the focus. Raise it when the subject is near or beyond the cameras.
    pub region_scale: f32,
    /// Colour hull points only from views in which they lie on the hull's visible surface
    /// (tested against a depth map of the hull per view); otherwise the far side of a player
    /// takes the colour of the near side.
    pub occlusion: bool,
    /// Background points are the most photo-consistent of this many candidates per point, which
    /// pulls them towards real surfaces (floor, walls) rather than empty space.
    pub background_oversample: usize,
    /// A background candidate must be seen by at least this fraction of the masked views (and
    /// by `min_views`). Lower it where the background is a wall around the rig (a dome with
    /// the cameras on it), whose points only the cameras opposite can see.
    pub background_view_fraction: f32,
}

impl Default for CarveSettings {
    fn default() -> Self {
        Self {
            resolution: 96,
            agreement: 0.9,
            min_views: 4,
            foreground_fraction: 0.5,
            colour_tolerance: 0.08,
            surface_preference: 0.8,
            region_scale: 1.0,
            occlusion: true,
            background_oversample: 4,
            background_view_fraction: 0.5,
        }
    }
}

impl CarveSettings {
    /// Checks the ranges, so that bad scene files fail with a message instead of odd clouds.
    pub fn validate(&self) -> Result<(), CarveError> {
        let invalid = |message: String| Err(CarveError::InvalidSettings(message));
        if !(2..=MAX_RESOLUTION).contains(&self.resolution) {
            return invalid(format!(
                "resolution {} is outside 2..={MAX_RESOLUTION}",
                self.resolution
            ));
        }
        if !(self.agreement > 0.0 && self.agreement <= 1.0) {
            return invalid(format!("agreement {} is outside (0, 1]", self.agreement));
        }
        if self.min_views == 0 {
            return invalid("min_views must be at least 1".into());
        }
        for (name, value) in [
            ("foreground_fraction", self.foreground_fraction),
            ("surface_preference", self.surface_preference),
            ("background_view_fraction", self.background_view_fraction),
        ] {
            if !(0.0..=1.0).contains(&value) {
                return invalid(format!("{name} {value} is outside [0, 1]"));
            }
        }
        if !(self.colour_tolerance > 0.0 && self.colour_tolerance.is_finite()) {
            return invalid(format!(
                "colour_tolerance {} must be positive",
                self.colour_tolerance
            ));
        }
        if !(self.region_scale > 0.0 && self.region_scale.is_finite()) {
            return invalid(format!(
                "region_scale {} must be positive",
                self.region_scale
            ));
        }
        Ok(())
    }
}

/// Why no point cloud could be carved.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CarveError {
    /// The dataset has no training view at the frame.
    #[error("frame {frame} has no training views")]
    NoViews {
        /// Frame index (not normalised time).
        frame: usize,
    },
    /// No training view at the frame has a usable foreground mask.
    #[error(
        "no training view at frame {frame} has a foreground mask of its camera's size; \
         use photo-consistency carving or random points instead"
    )]
    NoMasks {
        /// Frame index.
        frame: usize,
    },
    /// Too few views to carve anything meaningful (a monocular dataset, or a tiny subset).
    #[error(
        "frame {frame} has {found} usable views, but carving needs at least min_views = {needed}"
    )]
    TooFewViews {
        /// Frame index.
        frame: usize,
        /// Usable views at the frame (with a mask of the camera's size, for mask carving).
        found: usize,
        /// [`CarveSettings::min_views`].
        needed: usize,
    },
    /// Every voxel was carved away.
    #[error(
        "the visual hull at frame {frame} is empty: no voxel of {voxels} was foreground in at \
         least {agreement} of the (at least {min_views}) masked views that see it, among {views} \
         views; the masks disagree with the cameras (wrong poses, masks of another frame or \
         camera) or the search region misses the subject (raise region_scale)"
    )]
    EmptyHull {
        /// Frame index.
        frame: usize,
        /// Masked views used for carving.
        views: usize,
        /// Voxels tested in the grid that came out empty (the coarse grid, or the fine one).
        voxels: usize,
        /// [`CarveSettings::agreement`].
        agreement: f32,
        /// [`CarveSettings::min_views`].
        min_views: usize,
    },
    /// Photo-consistency carving kept nothing.
    #[error(
        "no voxel at frame {frame} is seen by at least {min_views} views with colours within \
         {tolerance} of each other; raise colour_tolerance or lower min_views"
    )]
    NoConsistentVoxels {
        /// Frame index.
        frame: usize,
        /// [`CarveSettings::colour_tolerance`].
        tolerance: f32,
        /// [`CarveSettings::min_views`].
        min_views: usize,
    },
    /// A setting is out of range.
    #[error("invalid carve settings: {0}")]
    InvalidSettings(String),
}

/// A regular grid of cubic voxels with an occupancy flag each (x fastest, then y, then z).
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelGrid {
    /// Minimum corner of the grid in world coordinates.
    pub origin: Vec3,
    /// Edge length of a voxel.
    pub voxel_size: f32,
    /// Voxels along x, y and z.
    pub dims: [usize; 3],
    /// Whether each voxel was kept.
    pub occupied: Vec<bool>,
}

impl VoxelGrid {
    /// An empty grid of cubic voxels covering `min..max`, `resolution` voxels along its longest side.
    fn covering(min: Vec3, max: Vec3, resolution: u32) -> Self {
        let extent = (max - min).max(Vec3::splat(1e-6));
        let voxel_size = extent.max_element() / resolution.max(1) as f32;
        let dims = (extent / voxel_size)
            .ceil()
            .to_array()
            .map(|n| (n as usize).clamp(1, MAX_RESOLUTION as usize));
        Self {
            origin: min,
            voxel_size,
            dims,
            occupied: Vec::new(),
        }
    }

    /// The grid over `min..max` with each voxel kept where `keep(centre)` holds (in parallel).
    fn carve(min: Vec3, max: Vec3, resolution: u32, keep: impl Fn(Vec3) -> bool + Sync) -> Self {
        let mut grid = Self::covering(min, max, resolution);
        let count = grid.dims.iter().product::<usize>();
        let centres = &grid;
        let occupied = (0..count)
            .into_par_iter()
            .map(|i| keep(centres.voxel_center(i)))
            .collect();
        grid.occupied = occupied;
        grid
    }

    /// Number of voxels.
    pub fn len(&self) -> usize {
        self.occupied.len()
    }

    /// Whether the grid has no voxels at all.
    pub fn is_empty(&self) -> bool {
        self.occupied.is_empty()
    }

    /// Number of kept voxels.
    pub fn occupied_count(&self) -> usize {
        self.occupied.iter().filter(|&&o| o).count()
    }

    /// Volume of the kept voxels.
    pub fn volume(&self) -> f32 {
        self.occupied_count() as f32 * self.voxel_size.powi(3)
    }

    /// Integer coordinates of voxel `index`.
    pub fn coords(&self, index: usize) -> [usize; 3] {
        let [nx, ny, _] = self.dims;
        [index % nx, (index / nx) % ny, index / (nx * ny)]
    }

    /// Minimum corner of voxel `index`.
    pub fn voxel_corner(&self, index: usize) -> Vec3 {
        let [x, y, z] = self.coords(index);
        self.origin + Vec3::new(x as f32, y as f32, z as f32) * self.voxel_size
    }

    /// Centre of voxel `index`.
    pub fn voxel_center(&self, index: usize) -> Vec3 {
        self.voxel_corner(index) + Vec3::splat(0.5 * self.voxel_size)
    }

    /// Maximum corner of the grid.
    pub fn max_corner(&self) -> Vec3 {
        self.origin
            + Vec3::new(
                self.dims[0] as f32,
                self.dims[1] as f32,
                self.dims[2] as f32,
            ) * self.voxel_size
    }

    /// The voxel containing `point`, if it lies in the grid.
    pub fn voxel_at(&self, point: Vec3) -> Option<usize> {
        let cell = ((point - self.origin) / self.voxel_size).floor();
        if !cell.is_finite() || cell.min_element() < 0.0 {
            return None;
        }
        let [x, y, z] = cell.to_array().map(|c| c as usize);
        let [nx, ny, nz] = self.dims;
        (x < nx && y < ny && z < nz).then(|| x + nx * (y + ny * z))
    }

    /// Whether `point` lies in a kept voxel.
    pub fn contains(&self, point: Vec3) -> bool {
        self.voxel_at(point)
            .is_some_and(|i| self.occupied.get(i).copied().unwrap_or(false))
    }

    /// Whether voxel `index` is kept and has an empty (or outside) face neighbour.
    pub fn is_surface(&self, index: usize) -> bool {
        if !self.occupied[index] {
            return false;
        }
        let c = self.coords(index);
        let [nx, ny, _] = self.dims;
        let strides = [1, nx, nx * ny];
        (0..3).any(|axis| {
            c[axis] == 0
                || c[axis] + 1 == self.dims[axis]
                || !self.occupied[index - strides[axis]]
                || !self.occupied[index + strides[axis]]
        })
    }

    /// Bounding box (min, max corners) of the kept voxels.
    pub fn occupied_bounds(&self) -> Option<(Vec3, Vec3)> {
        let mut bounds: Option<(Vec3, Vec3)> = None;
        for (i, _) in self.occupied.iter().enumerate().filter(|(_, o)| **o) {
            let lo = self.voxel_corner(i);
            let hi = lo + Vec3::splat(self.voxel_size);
            bounds = Some(match bounds {
                Some((min, max)) => (min.min(lo), max.max(hi)),
                None => (lo, hi),
            });
        }
        bounds
    }

    /// `count` points uniformly jittered in kept voxels, a `surface_preference` share of them in
    /// surface voxels. Empty when no voxel is kept.
    pub fn sample_points(
        &self,
        count: usize,
        surface_preference: f32,
        rng: &mut impl Rng,
    ) -> Vec<Vec3> {
        VoxelPools::new(self).sample(self, count, surface_preference, rng)
    }
}

/// Indices of a grid's kept and surface voxels, listed once for repeated sampling.
struct VoxelPools {
    kept: Vec<usize>,
    surface: Vec<usize>,
}

impl VoxelPools {
    fn new(grid: &VoxelGrid) -> Self {
        let kept: Vec<usize> = (0..grid.len()).filter(|&i| grid.occupied[i]).collect();
        let surface = kept
            .iter()
            .copied()
            .filter(|&i| grid.is_surface(i))
            .collect();
        Self { kept, surface }
    }

    fn sample(
        &self,
        grid: &VoxelGrid,
        count: usize,
        surface_preference: f32,
        rng: &mut impl Rng,
    ) -> Vec<Vec3> {
        if self.kept.is_empty() {
            return Vec::new();
        }
        (0..count)
            .map(|_| {
                let from_surface =
                    !self.surface.is_empty() && rng.random::<f32>() < surface_preference;
                let pool = if from_surface {
                    &self.surface
                } else {
                    &self.kept
                };
                let voxel = pool[rng.random_range(0..pool.len())];
                let jitter = Vec3::new(rng.random(), rng.random(), rng.random());
                grid.voxel_corner(voxel) + jitter * grid.voxel_size
            })
            .collect()
    }
}

/// Prefix sums over an image of `N`-channel counts: any axis-aligned rectangle's sum in O(1).
///
/// Sums wrap around on overflow: a difference of wrapped prefix sums is still exact as long as
/// the rectangle's own sum fits in a `u32`, which holds for any footprint of any real image.
struct SummedArea<const N: usize> {
    stride: usize,
    sums: Vec<[u32; N]>,
}

impl<const N: usize> SummedArea<N> {
    fn new(width: usize, height: usize, value: impl Fn(usize, usize) -> [u32; N]) -> Self {
        let stride = width + 1;
        let mut sums = vec![[0u32; N]; stride * (height + 1)];
        for y in 0..height {
            let mut row = [0u32; N];
            for x in 0..width {
                let v = value(x, y);
                let above = sums[y * stride + x + 1];
                let cell = &mut sums[(y + 1) * stride + x + 1];
                for c in 0..N {
                    row[c] = row[c].wrapping_add(v[c]);
                    cell[c] = above[c].wrapping_add(row[c]);
                }
            }
        }
        Self { stride, sums }
    }

    /// Sum over pixels `x0..=x1`, `y0..=y1` (inclusive, inside the image).
    fn sum(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> [u32; N] {
        let s = |x: usize, y: usize| self.sums[y * self.stride + x];
        let (a, b, c, d) = (s(x1 + 1, y1 + 1), s(x0, y1 + 1), s(x1 + 1, y0), s(x0, y0));
        std::array::from_fn(|i| {
            a[i].wrapping_add(d[i])
                .wrapping_sub(b[i])
                .wrapping_sub(c[i])
        })
    }
}

/// Inclusive pixel rectangle (x0, y0, x1, y1).
type PixelRect = (usize, usize, usize, usize);

/// A training view prepared for carving.
struct CarveView<'a> {
    camera: &'a Camera,
    eye: Vec3,
    image: &'a RgbImage,
    mask: Option<&'a [bool]>,
    /// Foreground pixel counts, for "any foreground under this footprint".
    mask_sums: Option<SummedArea<1>>,
    /// Colour sums, for the mean colour under a footprint (photo-consistency only).
    colour_sums: Option<SummedArea<3>>,
}

impl CarveView<'_> {
    fn width(&self) -> usize {
        self.camera.width as usize
    }

    /// Pixel coordinates of `point` when it lies in front of the camera and inside the image.
    fn project(&self, point: Vec3) -> Option<(f32, f32, f32)> {
        let (u, v, z) = self.camera.project(point);
        // Written so that NaN fails every comparison.
        let inside = z > MIN_DEPTH
            && u >= 0.0
            && v >= 0.0
            && u < self.camera.width as f32
            && v < self.camera.height as f32;
        inside.then_some((u, v, z))
    }

    /// The pixels whose centres lie in the square around (u, v) that bounds a sphere of
    /// `radius` at depth `z`; at least the pixel containing (u, v).
    fn footprint(&self, u: f32, v: f32, z: f32, radius: f32) -> PixelRect {
        let r = radius * self.camera.fx.max(self.camera.fy) / z;
        // Pixel i has its centre at i + 0.5.
        let span = |c: f32, size: u32| {
            let last = size as usize - 1;
            let first = (c - r - 0.5).ceil().max(0.0) as usize;
            let end = ((c + r - 0.5).floor().max(0.0) as usize).min(last);
            if first > end {
                let own = (c as usize).min(last);
                (own, own)
            } else {
                (first, end)
            }
        };
        let (x0, x1) = span(u, self.camera.width);
        let (y0, y1) = span(v, self.camera.height);
        (x0, y0, x1, y1)
    }

    fn pixel_index(&self, u: f32, v: f32) -> usize {
        v as usize * self.width() + u as usize
    }

    fn is_foreground(&self, u: f32, v: f32) -> bool {
        self.mask.is_some_and(|m| m[self.pixel_index(u, v)])
    }

    fn any_foreground(&self, rect: PixelRect) -> bool {
        let (x0, y0, x1, y1) = rect;
        self.mask_sums
            .as_ref()
            .is_some_and(|s| s.sum(x0, y0, x1, y1)[0] > 0)
    }

    fn colour(&self, u: f32, v: f32) -> Vec3 {
        let p = self.image.get_pixel(u as u32, v as u32).0;
        Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / 255.0
    }

    fn mean_colour(&self, rect: PixelRect) -> Vec3 {
        let (x0, y0, x1, y1) = rect;
        let Some(sums) = &self.colour_sums else {
            return Vec3::ZERO;
        };
        let s = sums.sum(x0, y0, x1, y1);
        let area = ((x1 - x0 + 1) * (y1 - y0 + 1)) as f32;
        Vec3::new(s[0] as f32, s[1] as f32, s[2] as f32) / (255.0 * area)
    }
}

/// Training views at `frame` with a foreground mask of their camera's size (others are skipped
/// with a warning).
fn masked_views(dataset: &Dataset, frame: usize) -> Result<Vec<CarveView<'_>>, CarveError> {
    let views = views_at(dataset, frame, |view, camera| {
        let mask = view.foreground.as_deref()?;
        let (w, h) = (camera.width as usize, camera.height as usize);
        if mask.len() != w * h || view.image.dimensions() != (camera.width, camera.height) {
            tracing::warn!(
                camera = view.camera,
                frame,
                "mask or image does not match its camera's size; not carving with it"
            );
            return None;
        }
        let sums = SummedArea::new(w, h, |x, y| [u32::from(mask[y * w + x])]);
        Some(CarveView {
            camera,
            eye: camera.center(),
            image: &view.image,
            mask: Some(mask),
            mask_sums: Some(sums),
            colour_sums: None,
        })
    })?;
    if views.is_empty() {
        return Err(CarveError::NoMasks { frame });
    }
    Ok(views)
}

/// All training views at `frame` with colour prefix sums (for photo-consistency).
fn colour_views(dataset: &Dataset, frame: usize) -> Result<Vec<CarveView<'_>>, CarveError> {
    views_at(dataset, frame, |view, camera| {
        if view.image.dimensions() != (camera.width, camera.height) {
            tracing::warn!(
                camera = view.camera,
                frame,
                "image does not match its camera's size"
            );
            return None;
        }
        let image = &view.image;
        let sums = SummedArea::new(camera.width as usize, camera.height as usize, |x, y| {
            image.get_pixel(x as u32, y as u32).0.map(u32::from)
        });
        Some(CarveView {
            camera,
            eye: camera.center(),
            image,
            mask: None,
            mask_sums: None,
            colour_sums: Some(sums),
        })
    })
}

/// The training views at `frame` (with their cameras) that `make` turns into carving views,
/// built in parallel; `make` returns `None` for a view it cannot use.
fn views_at<'a>(
    dataset: &'a Dataset,
    frame: usize,
    make: impl Fn(&'a View, &'a Camera) -> Option<CarveView<'a>> + Sync,
) -> Result<Vec<CarveView<'a>>, CarveError> {
    let at_frame: Vec<&View> = dataset.train.iter().filter(|v| v.frame == frame).collect();
    if at_frame.is_empty() {
        return Err(CarveError::NoViews { frame });
    }
    Ok(at_frame
        .par_iter()
        .filter_map(|view| make(view, dataset.cameras.get(view.camera)?))
        .collect())
}

/// What the public entry points share: validates `settings`, collects the views of `frame`
/// with `collect` ([`masked_views`] or [`colour_views`]) and checks that at least `min_views`
/// of them are usable.
fn checked_views<'a>(
    dataset: &'a Dataset,
    frame: usize,
    settings: &CarveSettings,
    collect: fn(&'a Dataset, usize) -> Result<Vec<CarveView<'a>>, CarveError>,
) -> Result<Vec<CarveView<'a>>, CarveError> {
    settings.validate()?;
    let views = collect(dataset, frame)?;
    if views.len() < settings.min_views {
        return Err(CarveError::TooFewViews {
            frame,
            found: views.len(),
            needed: settings.min_views,
        });
    }
    Ok(views)
}

/// The cube the cameras look at: around the rig's focus, half-size `region_scale` × the mean
/// camera distance from it.
fn search_region(views: &[CarveView], region_scale: f32) -> (Vec3, Vec3) {
    let cameras: Vec<Camera> = views.iter().map(|v| *v.camera).collect();
    let focus = rig_focus(&cameras);
    let mean_distance =
        views.iter().map(|v| v.eye.distance(focus)).sum::<f32>() / views.len().max(1) as f32;
    let half = Vec3::splat(region_scale * mean_distance.max(1e-3));
    (focus - half, focus + half)
}

/// Whether a voxel of bounding-sphere `radius` at `centre` belongs to the visual hull (with
/// radius 0: whether the point does, judged on the pixels it falls in).
fn in_visual_hull(
    views: &[CarveView],
    centre: Vec3,
    radius: f32,
    settings: &CarveSettings,
) -> bool {
    // Once this many views see background, agreement cannot be reached however many of the
    // rest see the voxel: most of the search region is rejected after a few views.
    let background_limit = (1.0 - settings.agreement) * views.len() as f32 + 1e-4;
    let mut seen = 0usize;
    let mut foreground = 0usize;
    for view in views {
        let Some((u, v, z)) = view.project(centre) else {
            continue;
        };
        seen += 1;
        if view.any_foreground(view.footprint(u, v, z, radius)) {
            foreground += 1;
        } else if (seen - foreground) as f32 > background_limit {
            return false;
        }
    }
    // The small slack keeps "9 of 10 at agreement 0.9" from failing on rounding.
    seen >= settings.min_views && foreground as f32 >= settings.agreement * seen as f32 - 1e-4
}

/// The visual hull at `frame`: voxels seen as foreground by at least `agreement` of the masked
/// training views that see them.
///
/// Carved twice: coarsely over the whole search region (conservative, since a voxel's whole
/// footprint is tested), then at `resolution` over the bounding box of what survived, so the
/// voxels are spent on the subject rather than on empty space.
pub fn visual_hull(
    dataset: &Dataset,
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let views = checked_views(dataset, frame, settings, masked_views)?;
    visual_hull_of(&views, frame, settings)
}

fn visual_hull_of(
    views: &[CarveView],
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let start = Instant::now();
    let (region_min, region_max) = search_region(views, settings.region_scale);
    let carve = |min: Vec3, max: Vec3, resolution: u32| {
        let probe = VoxelGrid::covering(min, max, resolution);
        let radius = 0.5 * 3f32.sqrt() * probe.voxel_size;
        VoxelGrid::carve(min, max, resolution, |c| {
            in_visual_hull(views, c, radius, settings)
        })
    };
    let coarse = carve(region_min, region_max, settings.resolution.min(64));
    let empty_hull = |voxels: usize| CarveError::EmptyHull {
        frame,
        views: views.len(),
        voxels,
        agreement: settings.agreement,
        min_views: settings.min_views,
    };
    let Some((lo, hi)) = coarse.occupied_bounds() else {
        return Err(empty_hull(coarse.len()));
    };
    let margin = Vec3::splat(coarse.voxel_size);
    let fine = carve(
        (lo - margin).max(region_min),
        (hi + margin).min(region_max),
        settings.resolution,
    );
    let kept = fine.occupied_count();
    tracing::info!(
        frame,
        views = views.len(),
        coarse_kept = coarse.occupied_count(),
        kept,
        dims = ?fine.dims,
        voxel_size = fine.voxel_size,
        seconds = start.elapsed().as_secs_f32(),
        "carved visual hull"
    );
    if kept == 0 {
        return Err(empty_hull(fine.len()));
    }
    Ok(fine)
}

/// Per view, the camera depth of the nearest hull surface at each pixel (infinity where the
/// hull is not seen): splats of the surface voxels' footprints, for O(1) occlusion tests.
fn hull_depth_maps(views: &[CarveView], grid: &VoxelGrid) -> Vec<Vec<f32>> {
    let surface: Vec<usize> = (0..grid.len()).filter(|&i| grid.is_surface(i)).collect();
    let radius = 0.5 * 3f32.sqrt() * grid.voxel_size;
    views
        .par_iter()
        .map(|view| {
            let width = view.width();
            let mut depth = vec![f32::INFINITY; width * view.camera.height as usize];
            for &voxel in &surface {
                let Some((u, v, z)) = view.project(grid.voxel_center(voxel)) else {
                    continue;
                };
                let (x0, y0, x1, y1) = view.footprint(u, v, z, radius);
                for y in y0..=y1 {
                    for d in &mut depth[y * width + x0..=y * width + x1] {
                        *d = d.min(z);
                    }
                }
            }
            depth
        })
        .collect()
}

/// Colour of a hull point: its mean pixel colour over the views in which it is foreground and
/// (given depth maps) not hidden behind the hull's nearer surface. Falls back to ignoring
/// occlusion, then to every view that sees it.
fn hull_point_colour(
    views: &[CarveView],
    depth_maps: Option<&[Vec<f32>]>,
    depth_slack: f32,
    point: Vec3,
) -> [f32; 3] {
    let mean_over = |accept: &dyn Fn(usize, f32, f32, f32) -> bool| {
        let mut sum = Vec3::ZERO;
        let mut n = 0u32;
        for (index, view) in views.iter().enumerate() {
            if let Some((u, v, z)) = view.project(point)
                && accept(index, u, v, z)
            {
                sum += view.colour(u, v);
                n += 1;
            }
        }
        (n > 0).then(|| (sum / n as f32).to_array())
    };
    let foreground = |index: usize, u: f32, v: f32| views[index].is_foreground(u, v);
    let visible = |index: usize, u: f32, v: f32, z: f32| {
        depth_maps.is_some_and(|maps| {
            foreground(index, u, v)
                && z <= maps[index][views[index].pixel_index(u, v)] + depth_slack
        })
    };
    depth_maps
        .and_then(|_| mean_over(&visible))
        .or_else(|| mean_over(&|index, u, v, _| foreground(index, u, v)))
        .or_else(|| mean_over(&|_, _, _, _| true))
        .unwrap_or([0.5; 3])
}

/// `count` points in hull voxels that also pass the hull test themselves, pixel-exactly (the
/// voxel test is conservative by up to two voxels, which on a limb is a lot). Gives up
/// filtering after `HULL_TRIES` draws per point and fills up with unfiltered ones.
fn sample_inside_silhouettes(
    views: &[CarveView],
    grid: &VoxelGrid,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Vec<Vec3> {
    let pools = VoxelPools::new(grid);
    let mut positions = Vec::with_capacity(count);
    let mut draws = 0usize;
    while positions.len() < count && draws < count * HULL_TRIES {
        let batch = (count - positions.len()).clamp(256, CANDIDATE_BATCH);
        let candidates = pools.sample(grid, batch, settings.surface_preference, &mut *rng);
        draws += candidates.len();
        let passed: Vec<Vec3> = candidates
            .into_par_iter()
            .filter(|p| in_visual_hull(views, *p, 0.0, settings))
            .collect();
        positions.extend(passed.into_iter().take(count - positions.len()));
    }
    if positions.len() < count {
        tracing::warn!(
            passed = positions.len(),
            count,
            draws,
            "few points in hull voxels pass the pixel-exact silhouette test; filling up unfiltered"
        );
        let missing = count - positions.len();
        positions.extend(pools.sample(grid, missing, settings.surface_preference, rng));
    }
    positions
}

fn sample_hull(
    views: &[CarveView],
    grid: &VoxelGrid,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Vec<InitPoint> {
    if count == 0 {
        return Vec::new();
    }
    let positions = sample_inside_silhouettes(views, grid, count, settings, rng);
    let depth_maps = settings.occlusion.then(|| hull_depth_maps(views, grid));
    // A point may lie anywhere in its surface voxel, behind the splatted centre depth, and
    // neighbouring surface voxels overlap it at grazing angles.
    let depth_slack = 2.0 * grid.voxel_size;
    positions
        .into_par_iter()
        .map(|position| InitPoint {
            position,
            color: hull_point_colour(views, depth_maps.as_deref(), depth_slack, position),
        })
        .collect()
}

/// `count` points in the visual hull at `frame` (see [`visual_hull`]), mostly on its surface,
/// coloured by the views that see them as foreground.
///
/// Points are jittered in hull voxels and kept only where they pass the hull test themselves on
/// the pixels they project to, which undoes the voxel test's conservative margin.
pub fn carve_from_masks(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let views = checked_views(dataset, frame, settings, masked_views)?;
    let grid = visual_hull_of(&views, frame, settings)?;
    Ok(sample_hull(&views, &grid, count, settings, rng))
}

/// A background candidate: position, mean colour over the views that see it as background, and
/// how much those colours disagree.
struct Candidate {
    position: Vec3,
    colour: Vec3,
    spread: f32,
}

/// Mean and standard deviation (averaged over channels) of colours given as sum and sum of
/// squares over `n` samples.
fn mean_and_spread(sum: Vec3, sum_sq: Vec3, n: usize) -> (Vec3, f32) {
    let mean = sum / n as f32;
    let variance = (sum_sq / n as f32 - mean * mean).max(Vec3::ZERO);
    (mean, (variance.element_sum() / 3.0).sqrt())
}

fn background_candidate(
    views: &[CarveView],
    position: Vec3,
    settings: &CarveSettings,
    needed: usize,
) -> Option<Candidate> {
    let (mut seen, mut foreground) = (0usize, 0usize);
    let (mut sum, mut sum_sq) = (Vec3::ZERO, Vec3::ZERO);
    // Most rejected candidates lie outside the common view volume: stop once too many views
    // have missed them.
    let allowed_misses = views.len().saturating_sub(needed);
    for (index, view) in views.iter().enumerate() {
        let Some((u, v, _)) = view.project(position) else {
            if index + 1 - seen > allowed_misses {
                return None;
            }
            continue;
        };
        seen += 1;
        if view.is_foreground(u, v) {
            foreground += 1;
        } else {
            let c = view.colour(u, v);
            sum += c;
            sum_sq += c * c;
        }
    }
    let background = seen - foreground;
    let outside_hull = (foreground as f32) < settings.agreement * seen as f32;
    if seen < needed || !outside_hull || background < settings.min_views.min(seen) {
        return None;
    }
    let (colour, spread) = mean_and_spread(sum, sum_sq, background);
    Some(Candidate {
        position,
        colour,
        spread,
    })
}

/// Bounding box of the part of the search region seen by at least `needed` views (found on a
/// coarse grid, padded by a cell): rejection sampling there wastes far fewer draws.
fn common_view_bounds(
    views: &[CarveView],
    region_scale: f32,
    needed: usize,
) -> Option<(Vec3, Vec3)> {
    let (region_min, region_max) = search_region(views, region_scale);
    let seen_enough = |p: Vec3| views.iter().filter(|v| v.project(p).is_some()).count() >= needed;
    let coarse = VoxelGrid::carve(region_min, region_max, 24, seen_enough);
    let (lo, hi) = coarse.occupied_bounds()?;
    let margin = Vec3::splat(coarse.voxel_size);
    Some(((lo - margin).max(region_min), (hi + margin).min(region_max)))
}

/// `count` points of the static background at `frame`: random points in the region seen by at
/// least half of the masked views (and `min_views`), outside the visual hull (seen as foreground
/// by fewer than `agreement` of them), coloured by the mean of their background projections.
/// Of `background_oversample` candidates per point the most photo-consistent are kept, which
/// favours points near real surfaces. May return fewer points when the region is hard to hit.
pub fn background_points(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let views = checked_views(dataset, frame, settings, masked_views)?;
    Ok(background_points_of(&views, count, settings, rng))
}

fn background_points_of(
    views: &[CarveView],
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Vec<InitPoint> {
    if count == 0 {
        return Vec::new();
    }
    let fraction_needed = (settings.background_view_fraction * views.len() as f32).ceil() as usize;
    let needed = settings.min_views.max(fraction_needed);
    let Some((lo, hi)) = common_view_bounds(views, settings.region_scale, needed) else {
        tracing::warn!(
            needed,
            "no region is seen by enough cameras for background points"
        );
        return Vec::new();
    };
    let wanted = count * settings.background_oversample.max(1);
    let mut candidates: Vec<Candidate> = Vec::with_capacity(wanted);
    let mut draws = 0usize;
    while candidates.len() < wanted && draws < wanted * CANDIDATE_TRIES {
        let batch: Vec<Vec3> = (0..CANDIDATE_BATCH)
            .map(|_| lo + Vec3::new(rng.random(), rng.random(), rng.random()) * (hi - lo))
            .collect();
        draws += batch.len();
        candidates.par_extend(
            batch
                .into_par_iter()
                .filter_map(|p| background_candidate(views, p, settings, needed)),
        );
    }
    candidates.sort_by(|a, b| a.spread.total_cmp(&b.spread));
    candidates.truncate(count);
    if candidates.len() < count {
        tracing::warn!(
            found = candidates.len(),
            count,
            draws,
            "few random points fall in the background seen by most cameras"
        );
    }
    candidates
        .into_iter()
        .map(|c| InitPoint {
            position: c.position,
            color: c.colour.to_array(),
        })
        .collect()
}

/// Whether a voxel at `centre` looks the same from every view that sees it, comparing the mean
/// colours of footprints of `radius`; returns its mean colour if so.
fn consistent_colour(
    views: &[CarveView],
    centre: Vec3,
    radius: f32,
    settings: &CarveSettings,
) -> Option<Vec3> {
    let mut seen = 0usize;
    let (mut sum, mut sum_sq) = (Vec3::ZERO, Vec3::ZERO);
    for view in views {
        let Some((u, v, z)) = view.project(centre) else {
            continue;
        };
        let c = view.mean_colour(view.footprint(u, v, z, radius));
        sum += c;
        sum_sq += c * c;
        seen += 1;
    }
    if seen < settings.min_views {
        return None;
    }
    let (mean, spread) = mean_and_spread(sum, sum_sq, seen);
    (spread <= settings.colour_tolerance).then_some(mean)
}

/// The photo-consistent voxels at `frame`: seen by at least `min_views` training views whose
/// mean colours under the voxel's footprint agree within `colour_tolerance`.
///
/// Approximate: a single pass without visibility reasoning, so a voxel hidden from some views
/// by another surface is judged by the occluder's colour too (carving away parts of concave or
/// occluded surfaces), and empty space that only ever sees uniform colour (a plain wall or sky
/// behind it from every side) survives. Use masks where a dataset has them.
pub fn photo_consistent_hull(
    dataset: &Dataset,
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let views = checked_views(dataset, frame, settings, colour_views)?;
    photo_consistent_hull_of(&views, frame, settings)
}

fn photo_consistent_hull_of(
    views: &[CarveView],
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let start = Instant::now();
    let (min, max) = search_region(views, settings.region_scale);
    let radius = 0.5 * VoxelGrid::covering(min, max, settings.resolution).voxel_size;
    let grid = VoxelGrid::carve(min, max, settings.resolution, |c| {
        consistent_colour(views, c, radius, settings).is_some()
    });
    let kept = grid.occupied_count();
    tracing::info!(
        frame,
        views = views.len(),
        kept,
        dims = ?grid.dims,
        seconds = start.elapsed().as_secs_f32(),
        "carved photo-consistent voxels"
    );
    if kept == 0 {
        return Err(CarveError::NoConsistentVoxels {
            frame,
            tolerance: settings.colour_tolerance,
            min_views: settings.min_views,
        });
    }
    Ok(grid)
}

/// `count` points in photo-consistent voxels at `frame` (see [`photo_consistent_hull`] for what
/// "approximate" means), coloured by the mean over the views that see them. For datasets
/// without masks.
pub fn carve_photo_consistent(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let views = checked_views(dataset, frame, settings, colour_views)?;
    let grid = photo_consistent_hull_of(&views, frame, settings)?;
    let positions = grid.sample_points(count, settings.surface_preference, rng);
    Ok(positions
        .into_par_iter()
        .map(|position| {
            let mut sum = Vec3::ZERO;
            let mut n = 0u32;
            for view in &views {
                if let Some((u, v, _)) = view.project(position) {
                    sum += view.colour(u, v);
                    n += 1;
                }
            }
            let color = if n == 0 {
                [0.5; 3]
            } else {
                (sum / n as f32).to_array()
            };
            InitPoint { position, color }
        })
        .collect())
}

/// Whether any training view at `frame` carries a foreground mask.
pub fn has_masks(dataset: &Dataset, frame: usize) -> bool {
    dataset
        .train
        .iter()
        .any(|v| v.frame == frame && v.foreground.is_some())
}

/// The initial point cloud of anchor `frame`: with masks, `foreground_fraction` of `count` from
/// the visual hull and the rest from the background (topped up from the hull when the
/// background is hard to hit); without masks, all from photo-consistency carving. On an error
/// the caller can fall back to [`super::init::random_points_in_view`].
pub fn initial_points(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let mut carved = carved_points(dataset, frame, count, settings, rng)?;
    carved.foreground.append(&mut carved.background);
    Ok(carved.foreground)
}

/// [`initial_points`] kept apart: the points on the visual hull and the background points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CarvedPoints {
    /// On the visual hull of the masks (the moving foreground), or every point of a
    /// photo-consistency carving (which does not tell foreground from background).
    pub foreground: Vec<InitPoint>,
    /// Photo-consistent points outside the hull: the static background.
    pub background: Vec<InitPoint>,
}

impl CarvedPoints {
    /// Points whose source does not tell foreground from background (random points, a point
    /// cloud, a photo-consistency carving): all counted as foreground.
    pub fn undivided(points: Vec<InitPoint>) -> Self {
        Self {
            foreground: points,
            background: Vec::new(),
        }
    }
}

/// The points of [`initial_points`], the hull's and the background's apart.
pub fn carved_points(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<CarvedPoints, CarveError> {
    settings.validate()?;
    if !has_masks(dataset, frame) {
        tracing::info!(frame, "no foreground masks; carving by photo-consistency");
        let points = carve_photo_consistent(dataset, frame, count, settings, rng)?;
        return Ok(CarvedPoints::undivided(points));
    }
    let views = checked_views(dataset, frame, settings, masked_views)?;
    let grid = visual_hull_of(&views, frame, settings)?;
    let foreground_count =
        ((count as f32 * settings.foreground_fraction).round() as usize).min(count);
    let mut foreground = sample_hull(&views, &grid, foreground_count, settings, &mut *rng);
    let background = background_points_of(&views, count - foreground_count, settings, &mut *rng);
    let shortfall = count - foreground_count - background.len();
    foreground.extend(sample_hull(&views, &grid, shortfall, settings, rng));
    Ok(CarvedPoints {
        foreground,
        background,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::View;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    const RED: [u8; 3] = [220, 30, 30];
    const GREY: [u8; 3] = [128, 128, 128];
    const WIDTH: u32 = 64;
    const HEIGHT: u32 = 48;

    /// A sphere seen by cameras around it: its analytic masks and red-on-grey images.
    struct SphereScene {
        centre: Vec3,
        radius: f32,
        dataset: Dataset,
    }

    /// Whether the ray from `origin` along unit `dir` hits the sphere.
    fn ray_hits_sphere(origin: Vec3, dir: Vec3, centre: Vec3, radius: f32) -> bool {
        let oc = origin - centre;
        let b = oc.dot(dir);
        let c = oc.length_squared() - radius * radius;
        let disc = b * b - c;
        disc >= 0.0 && -b + disc.sqrt() > 0.0
    }

    /// Ten cameras on a ring of radius 4 (alternately 1 above and below its plane) looking at
    /// the origin, and a sphere of radius 0.8 slightly off the origin.
    fn sphere_scene() -> SphereScene {
        let count = 10;
        let elevation = 1.0;
        let centre = Vec3::new(0.15, -0.1, 0.05);
        let radius = 0.8;
        let cameras: Vec<Camera> = (0..count)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / count as f32;
                let height = if i % 2 == 0 { elevation } else { -elevation };
                let eye = Vec3::new(4.0 * a.cos(), height, 4.0 * a.sin());
                Camera::look_at(eye, Vec3::ZERO, Vec3::Y, WIDTH, HEIGHT, 1.0)
            })
            .collect();
        let train = cameras
            .iter()
            .enumerate()
            .map(|(index, cam)| {
                let eye = cam.center();
                let mut mask = vec![false; (WIDTH * HEIGHT) as usize];
                let image = RgbImage::from_fn(WIDTH, HEIGHT, |x, y| {
                    let dir = cam.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
                    let hit = ray_hits_sphere(eye, dir, centre, radius);
                    mask[(y * WIDTH + x) as usize] = hit;
                    image::Rgb(if hit { RED } else { GREY })
                });
                View {
                    camera: index,
                    frame: 0,
                    time: 0.0,
                    image,
                    dynamic_mask: None,
                    foreground: Some(mask),
                }
            })
            .collect();
        SphereScene {
            centre,
            radius,
            dataset: Dataset {
                cameras,
                frame_count: 1,
                train,
                ..Dataset::default()
            },
        }
    }

    fn test_settings() -> CarveSettings {
        CarveSettings {
            resolution: 40,
            ..CarveSettings::default()
        }
    }

    fn rng() -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(7)
    }

    /// Hull points lie within r + 1.5 voxels + 1 pixel (the masks' quantisation) of the sphere's
    /// centre and reach out to the sphere in all six axis directions (the hull neither grows
    /// nor loses a side).
    #[test]
    fn hull_points_hug_the_sphere() {
        let scene = sphere_scene();
        let settings = test_settings();
        let grid = visual_hull(&scene.dataset, 0, &settings).unwrap();
        let points = carve_from_masks(&scene.dataset, 0, 4000, &settings, &mut rng()).unwrap();
        assert_eq!(points.len(), 4000);
        let camera = &scene.dataset.cameras[0];
        let pixel = (camera.center().distance(scene.centre) - scene.radius) / camera.fx;
        let limit = scene.radius + 1.5 * grid.voxel_size + pixel;
        let mut reach_pos = Vec3::splat(f32::MIN);
        let mut reach_neg = Vec3::splat(f32::MIN);
        for p in &points {
            let offset = p.position - scene.centre;
            assert!(
                offset.length() <= limit,
                "{offset} is {} from the centre",
                offset.length()
            );
            reach_pos = reach_pos.max(offset);
            reach_neg = reach_neg.max(-offset);
        }
        for reach in [reach_pos, reach_neg] {
            assert!(reach.min_element() > 0.85 * scene.radius, "reach {reach}");
        }
    }

    /// The visual hull over-approximates: its volume is at least the sphere's and at most twice it.
    #[test]
    fn hull_volume_bounds_the_sphere() {
        let scene = sphere_scene();
        let grid = visual_hull(&scene.dataset, 0, &test_settings()).unwrap();
        let sphere = 4.0 / 3.0 * std::f32::consts::PI * scene.radius.powi(3);
        let volume = grid.volume();
        assert!(
            volume >= sphere && volume <= 2.0 * sphere,
            "hull {volume} vs sphere {sphere}"
        );
        assert!(grid.contains(scene.centre));
        let (lo, hi) = grid.occupied_bounds().unwrap();
        let tolerance = Vec3::splat(scene.radius * 0.15 + grid.voxel_size);
        assert!(
            ((lo - (scene.centre - scene.radius)).abs())
                .cmple(tolerance)
                .all(),
            "{lo}"
        );
        assert!(
            ((hi - (scene.centre + scene.radius)).abs())
                .cmple(tolerance)
                .all(),
            "{hi}"
        );
    }

    /// Hull points take the colour of the sphere (red), not of the background.
    #[test]
    fn hull_points_are_red() {
        let scene = sphere_scene();
        for occlusion in [true, false] {
            let settings = CarveSettings {
                occlusion,
                ..test_settings()
            };
            let points = carve_from_masks(&scene.dataset, 0, 500, &settings, &mut rng()).unwrap();
            for p in points {
                let [r, g, b] = p.color;
                assert!(r > 0.8 && g < 0.2 && b < 0.2, "{:?}", p.color);
            }
        }
    }

    /// Background points avoid the sphere and take the background's grey.
    #[test]
    fn background_points_avoid_the_sphere() {
        let scene = sphere_scene();
        let points =
            background_points(&scene.dataset, 0, 300, &test_settings(), &mut rng()).unwrap();
        assert_eq!(points.len(), 300);
        for p in points {
            assert!(p.position.distance(scene.centre) > scene.radius);
            for c in p.color {
                assert!((c - 128.0 / 255.0).abs() < 0.02, "{:?}", p.color);
            }
        }
    }

    /// `initial_points` splits the count between hull and background by `foreground_fraction`.
    #[test]
    fn initial_points_mix_hull_and_background() {
        let scene = sphere_scene();
        let settings = CarveSettings {
            foreground_fraction: 0.25,
            ..test_settings()
        };
        let points = initial_points(&scene.dataset, 0, 400, &settings, &mut rng()).unwrap();
        assert_eq!(points.len(), 400);
        // Hull points are red, background points grey.
        let red = points.iter().filter(|p| p.color[0] > 0.8).count();
        assert_eq!(red, 100);
    }

    /// `carved_points` keeps the two kinds apart: every hull point is red (on the sphere),
    /// every background point grey (outside it), and together they are `initial_points`.
    #[test]
    fn carved_points_keep_hull_and_background_apart() {
        let scene = sphere_scene();
        let settings = CarveSettings {
            foreground_fraction: 0.25,
            ..test_settings()
        };
        let carved = carved_points(&scene.dataset, 0, 400, &settings, &mut rng()).unwrap();
        assert_eq!(
            (carved.foreground.len(), carved.background.len()),
            (100, 300)
        );
        assert!(carved.foreground.iter().all(|p| p.color[0] > 0.8));
        assert!(carved.background.iter().all(|p| p.color[0] < 0.6));
        for p in &carved.background {
            assert!(p.position.distance(scene.centre) > scene.radius);
        }
        let mut all = initial_points(&scene.dataset, 0, 400, &settings, &mut rng()).unwrap();
        let mut joined = [carved.foreground, carved.background].concat();
        let key = |p: &InitPoint| p.position.to_array().map(f32::to_bits);
        all.sort_by_key(key);
        joined.sort_by_key(key);
        assert_eq!(all, joined);
    }

    /// The same seed gives the same cloud.
    #[test]
    fn carving_is_deterministic() {
        let scene = sphere_scene();
        let a = initial_points(&scene.dataset, 0, 200, &test_settings(), &mut rng()).unwrap();
        let b = initial_points(&scene.dataset, 0, 200, &test_settings(), &mut rng()).unwrap();
        assert_eq!(a, b);
    }

    /// With agreement 0.9, one blank mask out of ten does not carve the sphere away.
    #[test]
    fn one_bad_mask_is_tolerated() {
        let mut scene = sphere_scene();
        scene.dataset.train[3].foreground = Some(vec![false; (WIDTH * HEIGHT) as usize]);
        let grid = visual_hull(&scene.dataset, 0, &test_settings()).unwrap();
        let sphere = 4.0 / 3.0 * std::f32::consts::PI * scene.radius.powi(3);
        assert!(grid.volume() >= sphere);
        let strict = CarveSettings {
            agreement: 1.0,
            ..test_settings()
        };
        assert!(matches!(
            visual_hull(&scene.dataset, 0, &strict),
            Err(CarveError::EmptyHull { .. })
        ));
    }

    /// Photo-consistency carving (no masks) keeps every voxel well inside the sphere, and the
    /// red points it samples are on the sphere.
    #[test]
    fn photo_consistency_keeps_the_sphere() {
        let mut scene = sphere_scene();
        for view in &mut scene.dataset.train {
            view.foreground = None;
        }
        let settings = test_settings();
        let grid = photo_consistent_hull(&scene.dataset, 0, &settings).unwrap();
        let mut inside = 0;
        for i in 0..grid.len() {
            if grid.voxel_center(i).distance(scene.centre) < scene.radius - 1.5 * grid.voxel_size {
                assert!(grid.occupied[i], "voxel at {} carved", grid.voxel_center(i));
                inside += 1;
            }
        }
        assert!(inside > 0);
        let points = initial_points(&scene.dataset, 0, 2000, &settings, &mut rng()).unwrap();
        assert_eq!(points.len(), 2000);
        let red: Vec<_> = points
            .iter()
            .filter(|p| p.color[0] > 0.7 && p.color[1] < 0.3)
            .collect();
        assert!(!red.is_empty());
        for p in red {
            assert!(p.position.distance(scene.centre) < scene.radius + 2.0 * grid.voxel_size);
        }
    }

    /// Without masks, mask carving says so; a frame without views and too few views are errors too.
    #[test]
    fn missing_masks_and_views_are_errors() {
        let mut scene = sphere_scene();
        let settings = test_settings();
        assert_eq!(
            carve_from_masks(&scene.dataset, 5, 10, &settings, &mut rng()),
            Err(CarveError::NoViews { frame: 5 })
        );
        let few = CarveSettings {
            min_views: 11,
            ..test_settings()
        };
        assert!(matches!(
            visual_hull(&scene.dataset, 0, &few),
            Err(CarveError::TooFewViews {
                found: 10,
                needed: 11,
                ..
            })
        ));
        for view in &mut scene.dataset.train {
            view.foreground = None;
        }
        assert_eq!(
            carve_from_masks(&scene.dataset, 0, 10, &settings, &mut rng()),
            Err(CarveError::NoMasks { frame: 0 })
        );
        assert_eq!(
            background_points(&scene.dataset, 0, 10, &settings, &mut rng()),
            Err(CarveError::NoMasks { frame: 0 })
        );
    }

    /// Masks that show nothing empty the hull, and the error says why.
    #[test]
    fn blank_masks_give_an_empty_hull_error() {
        let mut scene = sphere_scene();
        for view in &mut scene.dataset.train {
            view.foreground = Some(vec![false; (WIDTH * HEIGHT) as usize]);
        }
        let err = visual_hull(&scene.dataset, 0, &test_settings()).unwrap_err();
        assert!(matches!(
            err,
            CarveError::EmptyHull {
                frame: 0,
                views: 10,
                ..
            }
        ));
        assert!(err.to_string().contains("masks disagree with the cameras"));
    }

    /// Out-of-range settings are rejected rather than carving nonsense.
    #[test]
    fn bad_settings_are_rejected() {
        let scene = sphere_scene();
        for bad in [
            CarveSettings {
                resolution: 0,
                ..test_settings()
            },
            CarveSettings {
                agreement: 0.0,
                ..test_settings()
            },
            CarveSettings {
                min_views: 0,
                ..test_settings()
            },
            CarveSettings {
                foreground_fraction: 1.5,
                ..test_settings()
            },
            CarveSettings {
                colour_tolerance: f32::NAN,
                ..test_settings()
            },
        ] {
            assert!(matches!(
                initial_points(&scene.dataset, 0, 10, &bad, &mut rng()),
                Err(CarveError::InvalidSettings(_))
            ));
        }
    }

    /// Settings survive a RON round trip, omitted fields default and unknown ones are refused.
    #[test]
    fn settings_read_from_ron() {
        let settings = CarveSettings {
            resolution: 64,
            occlusion: false,
            ..CarveSettings::default()
        };
        let text = ron::to_string(&settings).unwrap();
        assert_eq!(ron::from_str::<CarveSettings>(&text).unwrap(), settings);
        let partial: CarveSettings = ron::from_str("(agreement: 0.8)").unwrap();
        assert_eq!(partial.agreement, 0.8);
        assert_eq!(partial.resolution, CarveSettings::default().resolution);
        assert!(ron::from_str::<CarveSettings>("(resolutoin: 8)").is_err());
    }

    /// Summed-area rectangle sums equal brute-force sums, also where the prefix sums wrap.
    #[test]
    fn summed_area_matches_brute_force() {
        let (width, height) = (13, 7);
        let value = |x: usize, y: usize| [(x * 31 + y * 17) as u32 % 256, u32::MAX / 40];
        let sums = SummedArea::new(width, height, value);
        for (x0, y0, x1, y1) in [(0, 0, 12, 6), (3, 2, 3, 2), (5, 1, 11, 5), (0, 6, 12, 6)] {
            let mut expected = [0u64; 2];
            for y in y0..=y1 {
                for x in x0..=x1 {
                    let v = value(x, y);
                    expected[0] += u64::from(v[0]);
                    expected[1] += u64::from(v[1]);
                }
            }
            let got = sums.sum(x0, y0, x1, y1);
            assert_eq!(u64::from(got[0]), expected[0]);
            // The second channel's full-image sum overflows; small rectangles are still exact.
            if expected[1] <= u64::from(u32::MAX) {
                assert_eq!(u64::from(got[1]), expected[1]);
            }
        }
    }

    /// A voxel grid's geometry: index ↔ coordinates, lookup and surface test agree.
    #[test]
    fn voxel_grid_geometry() {
        let mut grid = VoxelGrid::covering(Vec3::ZERO, Vec3::new(4.0, 2.0, 2.0), 4);
        assert_eq!(grid.dims, [4, 2, 2]);
        assert_eq!(grid.voxel_size, 1.0);
        grid.occupied = vec![true; grid.dims.iter().product()];
        for i in 0..grid.len() {
            assert_eq!(grid.voxel_at(grid.voxel_center(i)), Some(i));
            assert!(grid.is_surface(i)); // every voxel touches the grid's border
        }
        assert_eq!(grid.voxel_at(Vec3::new(-0.1, 0.5, 0.5)), None);
        assert_eq!(grid.voxel_at(Vec3::new(0.5, 0.5, 2.5)), None);
        assert_eq!(grid.volume(), 16.0);
    }

    /// On the Panoptic capture (when present) frame 0 carves to a non-empty hull inside the rig,
    /// and every initial point gets a colour; prints sizes and timings. Ignored: it decodes
    /// 31 JPEGs and 27 masks.
    #[test]
    #[ignore]
    fn panoptic_hull_report() {
        use crate::data::panoptic::{PanopticSource, load};
        let root = std::env::var("TADGS_DATA")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|_| {
                std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
            });
        let path = root.join("panoptic_basketball");
        if !path.exists() {
            println!("skipping: {} not found", path.display());
            return;
        }
        let source = PanopticSource {
            frames: Some(1),
            ..PanopticSource::new(path.to_string_lossy())
        };
        let start = Instant::now();
        let dataset = load(&source).unwrap();
        println!(
            "loaded {} train views in {:.2} s",
            dataset.train.len(),
            start.elapsed().as_secs_f32()
        );
        for resolution in [64, 96, 128] {
            let settings = CarveSettings {
                resolution,
                ..CarveSettings::default()
            };
            let start = Instant::now();
            let grid = visual_hull(&dataset, 0, &settings).unwrap();
            let hull_seconds = start.elapsed().as_secs_f32();
            let (lo, hi) = grid.occupied_bounds().unwrap();
            println!(
                "resolution {resolution}: grid {:?}, voxel {:.4}, kept {} ({:.3} m³), bounds {lo:.2}..{hi:.2}, {hull_seconds:.3} s",
                grid.dims,
                grid.voxel_size,
                grid.occupied_count(),
                grid.volume()
            );
            // Silhouette agreement: how much of each mask the hull's projection covers, and how
            // much of the projection is foreground.
            let views = masked_views(&dataset, 0).unwrap();
            let depth_maps = hull_depth_maps(&views, &grid);
            let (mut recall, mut precision) = (Vec::new(), Vec::new());
            for (view, depth) in views.iter().zip(&depth_maps) {
                let mask = view.mask.unwrap();
                let both = mask
                    .iter()
                    .zip(depth)
                    .filter(|(m, d)| **m && d.is_finite())
                    .count();
                recall.push(both as f32 / mask.iter().filter(|m| **m).count().max(1) as f32);
                precision.push(
                    both as f32 / depth.iter().filter(|d| d.is_finite()).count().max(1) as f32,
                );
            }
            let summary = |v: &[f32]| {
                let mean = v.iter().sum::<f32>() / v.len() as f32;
                (mean, v.iter().copied().fold(1.0, f32::min))
            };
            println!(
                "  mask recall (mean, min) {:.3?}, precision {:.3?}",
                summary(&recall),
                summary(&precision)
            );
            let start = Instant::now();
            let points = initial_points(&dataset, 0, 100_000, &settings, &mut rng()).unwrap();
            println!(
                "  initial_points(100000): {} points in {:.3} s",
                points.len(),
                start.elapsed().as_secs_f32()
            );
            assert_eq!(points.len(), 100_000);
            // Of the hull points (the first half), the share of (point, view) pairs on the mask,
            // and of the background points, the share off it.
            let on_mask = |points: &[InitPoint]| {
                let (mut on, mut pairs) = (0usize, 0usize);
                for p in points {
                    for view in &views {
                        if let Some((u, v, _)) = view.project(p.position) {
                            pairs += 1;
                            on += usize::from(view.is_foreground(u, v));
                        }
                    }
                }
                on as f32 / pairs as f32
            };
            println!(
                "  (point, view) pairs on the mask: hull points {:.3}, background points {:.3}",
                on_mask(&points[..50_000]),
                on_mask(&points[50_000..])
            );
            assert!(
                points
                    .iter()
                    .all(|p| p.position.is_finite()
                        && p.color.iter().all(|c| (0.0..=1.0).contains(c)))
            );
        }
    }
}
