//! The regular grid of cubic voxels all carving works on, and summed-area tables for the
//! O(1) footprint sums of a view.

use glam::Vec3;
use rand::Rng;
use rayon::prelude::*;

use super::MAX_RESOLUTION;

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
    pub(super) fn covering(min: Vec3, max: Vec3, resolution: u32) -> Self {
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
    pub(super) fn carve(
        min: Vec3,
        max: Vec3,
        resolution: u32,
        keep: impl Fn(Vec3) -> bool + Sync,
    ) -> Self {
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
pub(super) struct VoxelPools {
    kept: Vec<usize>,
    surface: Vec<usize>,
}

impl VoxelPools {
    pub(super) fn new(grid: &VoxelGrid) -> Self {
        let kept: Vec<usize> = (0..grid.len()).filter(|&i| grid.occupied[i]).collect();
        let surface = kept
            .iter()
            .copied()
            .filter(|&i| grid.is_surface(i))
            .collect();
        Self { kept, surface }
    }

    pub(super) fn sample(
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
pub(super) struct SummedArea<const N: usize> {
    stride: usize,
    sums: Vec<[u32; N]>,
}

impl<const N: usize> SummedArea<N> {
    pub(super) fn new(
        width: usize,
        height: usize,
        value: impl Fn(usize, usize) -> [u32; N],
    ) -> Self {
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
    pub(super) fn sum(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> [u32; N] {
        let s = |x: usize, y: usize| self.sums[y * self.stride + x];
        let (a, b, c, d) = (s(x1 + 1, y1 + 1), s(x0, y1 + 1), s(x1 + 1, y0), s(x0, y0));
        std::array::from_fn(|i| {
            a[i].wrapping_add(d[i])
                .wrapping_sub(b[i])
                .wrapping_sub(c[i])
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
}
