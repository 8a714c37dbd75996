//! Tile binning: which splats touch which 16×16 tile, depth-sorted per tile.

use rayon::prelude::*;

use super::{Splat, TILE};

/// Per-tile, depth-sorted lists of splats, reused across frames.
#[derive(Default)]
pub struct TileBins {
    /// Number of tile columns: ⌈width / 16⌉.
    pub tiles_x: usize,
    /// Number of tile rows: ⌈height / 16⌉.
    pub tiles_y: usize,
    /// Tile rectangle [x0, y0, x1, y1) per splat (empty for invisible splats).
    pub(super) rects: Vec<[u32; 4]>,
    /// Prefix sums of entries per splat: splat s owns entries `splat_offsets[s]..splat_offsets[s+1]`.
    splat_offsets: Vec<u32>,
    /// Entries sorted by tile then depth: the splat index of each.
    pub sorted_splats: Vec<u32>,
    /// Splats that cover a tile, sorted by key: depth bits (high) and splat index (low).
    sorted_keys: Vec<u64>,
    /// What the scatter needs of each splat of `sorted_keys`, in the same (depth) order.
    by_depth: Vec<DepthOrdered>,
    /// Position in the sorted order of each unsorted entry (splat-major order).
    pub sorted_position: Vec<u32>,
    /// Tile t owns sorted entries `tile_offsets[t]..tile_offsets[t+1]`.
    pub tile_offsets: Vec<u32>,
    tile_fill: Vec<u32>,
}

impl TileBins {
    /// Total number of (tile, splat) pairs.
    pub fn entry_count(&self) -> usize {
        self.sorted_splats.len()
    }

    /// Heap bytes held by the bins.
    pub fn heap_bytes(&self) -> usize {
        4 * (self.rects.capacity() * 4
            + self.splat_offsets.capacity()
            + self.sorted_splats.capacity()
            + self.sorted_position.capacity()
            + self.tile_offsets.capacity()
            + self.tile_fill.capacity())
            + 8 * self.sorted_keys.capacity()
            + std::mem::size_of::<DepthOrdered>() * self.by_depth.capacity()
    }

    /// Sorted entries of tile `t`.
    pub fn tile_range(&self, t: usize) -> std::ops::Range<usize> {
        self.tile_offsets[t] as usize..self.tile_offsets[t + 1] as usize
    }

    /// Prefix sums of entries per splat (splat-major entry order), one more than splats.
    pub fn splat_offsets(&self) -> &[u32] {
        &self.splat_offsets
    }

    /// Entries (unsorted, splat-major) owned by splat `s`.
    pub fn splat_range(&self, s: usize) -> std::ops::Range<usize> {
        self.splat_offsets[s] as usize..self.splat_offsets[s + 1] as usize
    }

    /// Bins `splats` for an image of `width × height` pixels.
    ///
    /// Cost is linear in the (tile, splat) pairs plus one sort of the visible splats by depth:
    /// entries are scattered into their tiles in depth order (a stable counting sort by tile),
    /// so every tile's list comes out depth-sorted without sorting each tile.
    pub fn build(&mut self, splats: &[Splat], width: usize, height: usize) {
        self.tiles_x = width.div_ceil(TILE);
        self.tiles_y = height.div_ceil(TILE);
        let tile_count = self.tiles_x * self.tiles_y;
        let (tiles_x, tiles_y) = (self.tiles_x as f32, self.tiles_y as f32);

        splats
            .par_iter()
            .map(|s| tile_rect(s, tiles_x, tiles_y))
            .collect_into_vec(&mut self.rects);

        // Entries per splat (splat-major order).
        self.splat_offsets.clear();
        self.splat_offsets.reserve(splats.len() + 1);
        self.splat_offsets.push(0);
        let mut total = 0u32;
        for r in &self.rects {
            total += (r[2] - r[0]) * (r[3] - r[1]);
            self.splat_offsets.push(total);
        }

        // Entries per tile. Tile rows are split into bands, one task each; a band counts and
        // later fills only its own tiles, so the bands never write the same place.
        // At least 1: an image without tiles (zero width or height) has no chunks anyway.
        let tiles_per_band = (self.tiles_x * self.tiles_y.div_ceil(band_count())).max(1);
        let (tiles_x, rects) = (self.tiles_x, &self.rects);
        self.tile_fill.clear();
        self.tile_fill.resize(tile_count + 1, 0);
        self.tile_fill[1..]
            .par_chunks_mut(tiles_per_band)
            .enumerate()
            .for_each(|(band, counts)| {
                let rows = band_rows(band, tiles_per_band, counts.len(), tiles_x);
                for r in rects {
                    for ty in r[1].max(rows.start)..r[3].min(rows.end) {
                        let row = (ty - rows.start) as usize * tiles_x;
                        for tx in r[0]..r[2] {
                            counts[row + tx as usize] += 1;
                        }
                    }
                }
            });
        for t in 0..tile_count {
            self.tile_fill[t + 1] += self.tile_fill[t];
        }
        self.tile_offsets.clear();
        self.tile_offsets.extend_from_slice(&self.tile_fill);

        // Splats that cover a tile, by depth; the splat index breaks ties. Depths are positive
        // (beyond the near plane), so their bits order like the values.
        self.sorted_keys.clear();
        self.sorted_keys.extend(
            self.rects
                .iter()
                .enumerate()
                .filter(|(_, r)| r[2] > r[0])
                .map(|(s, _)| ((splats[s].depth.to_bits() as u64) << 32) | s as u64),
        );
        self.sorted_keys.par_sort_unstable();

        // Each band scans every splat in depth order: gather what it reads of them once, so
        // that the bands read one array front to back instead of jumping around two.
        let (rects, splat_offsets) = (&self.rects, &self.splat_offsets);
        self.sorted_keys
            .par_iter()
            .map(|&key| {
                let s = key as u32;
                DepthOrdered {
                    splat: s,
                    first_entry: splat_offsets[s as usize],
                    rect: rects[s as usize],
                }
            })
            .collect_into_vec(&mut self.by_depth);

        // Scatter in depth order, band by band in parallel.
        let total = total as usize;
        self.sorted_splats.resize(total, 0);
        self.sorted_position.resize(total, 0);
        let sorted_splats = Disjoint(self.sorted_splats.as_mut_ptr());
        let sorted_position = Disjoint(self.sorted_position.as_mut_ptr());
        let by_depth = &self.by_depth;
        self.tile_fill[..tile_count]
            .par_chunks_mut(tiles_per_band)
            .enumerate()
            .for_each(|(band, fill)| {
                let rows = band_rows(band, tiles_per_band, fill.len(), tiles_x);
                for d in by_depth {
                    let r = d.rect;
                    let rect_width = (r[2] - r[0]) as usize;
                    for ty in r[1].max(rows.start)..r[3].min(rows.end) {
                        let mut entry = d.first_entry as usize + (ty - r[1]) as usize * rect_width;
                        let row = (ty - rows.start) as usize * tiles_x;
                        for tx in r[0]..r[2] {
                            let slot = &mut fill[row + tx as usize];
                            let k = *slot as usize;
                            *slot += 1;
                            // SAFETY: k is an entry of one of this band's tiles and `entry` the
                            // (splat, tile) pair of one of them; no other band writes either,
                            // and both are below `total`, the length of the two buffers.
                            unsafe {
                                sorted_splats.write(k, d.splat);
                                sorted_position.write(entry, k as u32);
                            }
                            entry += 1;
                        }
                    }
                }
            });
    }
}

/// A splat that covers a tile, as the scatter reads it.
#[derive(Clone, Copy, Debug, Default)]
struct DepthOrdered {
    splat: u32,
    /// Its first entry in splat-major order.
    first_entry: u32,
    /// Its tile rectangle [x0, y0, x1, y1).
    rect: [u32; 4],
}

/// Bands of tile rows binned in parallel: a few per thread, so an uneven band does not hold
/// the others up; one on a single thread, where every extra band rescans all splats for
/// nothing.
fn band_count() -> usize {
    match rayon::current_num_threads() {
        1 => 1,
        threads => 2 * threads,
    }
}

/// Tile rows of band `band` whose chunk of per-tile values has `len` tiles.
fn band_rows(
    band: usize,
    tiles_per_band: usize,
    len: usize,
    tiles_x: usize,
) -> std::ops::Range<u32> {
    let first = band * tiles_per_band / tiles_x;
    first as u32..(first + len / tiles_x) as u32
}

/// A buffer that parallel tasks write at indices no two of them share.
#[derive(Clone, Copy)]
struct Disjoint<T>(*mut T);

// SAFETY: the tasks holding copies write disjoint elements (see the call sites).
unsafe impl<T: Send> Send for Disjoint<T> {}
unsafe impl<T: Send> Sync for Disjoint<T> {}

impl<T> Disjoint<T> {
    /// # Safety
    /// `index` is in bounds and no other task reads or writes it meanwhile.
    #[inline(always)]
    unsafe fn write(self, index: usize, value: T) {
        unsafe { *self.0.add(index) = value }
    }
}

/// The tiles a splat's screen box overlaps, as [x0, y0, x1, y1) in tile units.
fn tile_rect(s: &Splat, tiles_x: f32, tiles_y: f32) -> [u32; 4] {
    if !s.visible {
        return [0; 4];
    }
    let t = TILE as f32;
    let x0 = ((s.mean2d.x - s.extent.x) / t).floor().clamp(0.0, tiles_x);
    let y0 = ((s.mean2d.y - s.extent.y) / t).floor().clamp(0.0, tiles_y);
    let x1 = (((s.mean2d.x + s.extent.x) / t).floor() + 1.0).clamp(0.0, tiles_x);
    let y1 = (((s.mean2d.y + s.extent.y) / t).floor() + 1.0).clamp(0.0, tiles_y);
    if x1 <= x0 || y1 <= y0 {
        return [0; 4];
    }
    [x0 as u32, y0 as u32, x1 as u32, y1 as u32]
}

/// Calls `f(tile, piece)` in parallel for every tile, where `piece` is the tile's part of
/// `data` (tile t owns `offsets[t]..offsets[t + 1]`, offsets starting at 0). Splits the range in
/// halves with `rayon::join`, so nothing is allocated and idle threads steal the larger halves.
pub(super) fn for_each_tile_mut<T: Send>(
    data: &mut [T],
    offsets: &[u32],
    tiles: std::ops::Range<usize>,
    f: &(impl Fn(usize, &mut [T]) + Sync),
) {
    if tiles.len() == 1 {
        f(tiles.start, data);
        return;
    }
    if tiles.is_empty() {
        return;
    }
    let mid = tiles.start + tiles.len() / 2;
    let split = (offsets[mid] - offsets[tiles.start]) as usize;
    let (left, right) = data.split_at_mut(split);
    rayon::join(
        || for_each_tile_mut(left, offsets, tiles.start..mid, f),
        || for_each_tile_mut(right, offsets, mid..tiles.end, f),
    );
}
