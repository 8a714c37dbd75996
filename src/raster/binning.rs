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
    /// The other buffer of the radix sort of `sorted_keys`.
    sort_scratch: Vec<u64>,
    /// What the scatter needs of each splat of `sorted_keys`, in the same (depth) order.
    by_depth: Vec<DepthOrdered>,
    /// Position in the sorted order of each unsorted entry (splat-major order), filled on
    /// demand by [`TileBins::sorted_position`]: the CPU rasterizer does not need it.
    sorted_position: Vec<u32>,
    /// Whether `sorted_position` belongs to the current bins.
    positions_filled: bool,
    /// Tile t owns sorted entries `tile_offsets[t]..tile_offsets[t+1]`.
    pub tile_offsets: Vec<u32>,
    tile_fill: Vec<u32>,
    /// The 2-D difference array of the tile rectangles, (tiles_y + 1) × (tiles_x + 1).
    rect_corners: Vec<i32>,
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
            + self.tile_fill.capacity()
            + self.rect_corners.capacity())
            + 8 * (self.sorted_keys.capacity() + self.sort_scratch.capacity())
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
        self.positions_filled = false;

        splats
            .par_iter()
            .map(|s| tile_rect(s, tiles_x, tiles_y))
            .collect_into_vec(&mut self.rects);

        // Entries per splat (splat-major order), and per tile from a 2-D difference array of
        // the rectangles: +1 at the corners (x0, y0) and (x1, y1), −1 at (x1, y0) and (x0, y1),
        // then prefix sums along rows and columns. That costs a few additions per splat instead
        // of one per entry.
        let stride = self.tiles_x + 1;
        self.rect_corners.clear();
        self.rect_corners.resize(stride * (self.tiles_y + 1), 0);
        self.splat_offsets.clear();
        self.splat_offsets.reserve(splats.len() + 1);
        self.splat_offsets.push(0);
        let mut total = 0u32;
        for r in &self.rects {
            total += (r[2] - r[0]) * (r[3] - r[1]);
            self.splat_offsets.push(total);
            let [x0, y0, x1, y1] = r.map(|v| v as usize);
            self.rect_corners[y0 * stride + x0] += 1;
            self.rect_corners[y0 * stride + x1] -= 1;
            self.rect_corners[y1 * stride + x0] -= 1;
            self.rect_corners[y1 * stride + x1] += 1;
        }
        // Invisible splats have empty rectangles at the origin: their four updates cancel.
        self.tile_fill.clear();
        self.tile_fill.resize(tile_count + 1, 0);
        let counts = &mut self.tile_fill[1..];
        for ty in 0..self.tiles_y {
            let mut row_sum = 0i32;
            for tx in 0..self.tiles_x {
                let tile = ty * self.tiles_x + tx;
                row_sum += self.rect_corners[ty * stride + tx];
                let above = if ty > 0 {
                    counts[tile - self.tiles_x]
                } else {
                    0
                };
                counts[tile] = above.wrapping_add_signed(row_sum);
            }
        }
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
        radix_sort_by_high_half(&mut self.sorted_keys, &mut self.sort_scratch);

        // Each band scans every splat in depth order: gather what it reads of them once, so
        // that the bands read one array front to back instead of jumping around two.
        let rects = &self.rects;
        self.sorted_keys
            .par_iter()
            .map(|&key| {
                let s = key as u32;
                DepthOrdered {
                    splat: s,
                    rect: rects[s as usize],
                }
            })
            .collect_into_vec(&mut self.by_depth);

        // Scatter in depth order, band by band in parallel.
        self.sorted_splats.resize(total as usize, 0);
        let sorted_splats = Disjoint(self.sorted_splats.as_mut_ptr());
        self.scatter(|d, _, k| {
            // SAFETY: k is an entry of one of this band's tiles, which no other band writes,
            // and below the total, the buffer's length.
            unsafe { sorted_splats.write(k, d.splat) };
        });
    }

    /// Position in the depth-sorted order of each entry in splat-major order (entry e of
    /// splat s is `splat_range(s).start + e`, its tiles row by row), computed on first use
    /// after each [`TileBins::build`]: the CPU rasterizer does not need it; the GPU's
    /// per-splat reduction does.
    pub fn sorted_position(&mut self) -> &[u32] {
        if !self.positions_filled {
            self.sorted_position.resize(self.sorted_splats.len(), 0);
            let sorted_position = Disjoint(self.sorted_position.as_mut_ptr());
            let splat_offsets = &self.splat_offsets;
            let tiles_x = self.tiles_x;
            let mut fill = std::mem::take(&mut self.tile_fill);
            fill.copy_from_slice(&self.tile_offsets);
            scatter_bands(
                &self.by_depth,
                &mut fill,
                tiles_x,
                self.tiles_y,
                |d, tile, k| {
                    let [x0, y0, x1, _] = d.rect;
                    let (tx, ty) = ((tile % tiles_x) as u32, (tile / tiles_x) as u32);
                    let entry = splat_offsets[d.splat as usize] + (ty - y0) * (x1 - x0) + (tx - x0);
                    // SAFETY: every (splat, tile) pair has its own entry, below the total, and
                    // only the band of the tile writes it.
                    unsafe { sorted_position.write(entry as usize, k as u32) };
                },
            );
            self.tile_fill = fill;
            self.positions_filled = true;
        }
        &self.sorted_position
    }

    /// Calls `place(splat, tile, k)` for every entry of the bins, k its sorted position, in
    /// depth order within each tile, tiles in bands in parallel.
    fn scatter(&mut self, place: impl Fn(&DepthOrdered, usize, usize) + Sync) {
        self.tile_fill.copy_from_slice(&self.tile_offsets);
        scatter_bands(
            &self.by_depth,
            &mut self.tile_fill,
            self.tiles_x,
            self.tiles_y,
            place,
        );
    }
}

/// The scatter of [`TileBins::scatter`]: `fill` holds each tile's next free position (one more
/// than tiles; the last is unused), bands of tile rows run in parallel, each scanning the splats
/// in depth order.
fn scatter_bands(
    by_depth: &[DepthOrdered],
    fill: &mut [u32],
    tiles_x: usize,
    tiles_y: usize,
    place: impl Fn(&DepthOrdered, usize, usize) + Sync,
) {
    let tile_count = tiles_x * tiles_y;
    // At least 1: an image without tiles (zero width or height) has no chunks anyway.
    let tiles_per_band = (tiles_x * tiles_y.div_ceil(band_count())).max(1);
    fill[..tile_count]
        .par_chunks_mut(tiles_per_band)
        .enumerate()
        .for_each(|(band, fill)| {
            let rows = band_rows(band, tiles_per_band, fill.len(), tiles_x);
            let first_tile = rows.start as usize * tiles_x;
            for d in by_depth {
                let r = d.rect;
                for ty in r[1].max(rows.start)..r[3].min(rows.end) {
                    let row = (ty - rows.start) as usize * tiles_x;
                    for tx in r[0]..r[2] {
                        let local = row + tx as usize;
                        let k = fill[local] as usize;
                        fill[local] += 1;
                        place(d, first_tile + local, k);
                    }
                }
            }
        });
}

/// Sorts keys by their high 32 bits, stably (keys with equal high halves keep their order), by
/// least-significant-digit radix sort in bytes; a byte that is the same in every key (the
/// exponent of depths of one scale, say) costs one counting pass and no move.
fn radix_sort_by_high_half(keys: &mut Vec<u64>, scratch: &mut Vec<u64>) {
    scratch.clear();
    scratch.resize(keys.len(), 0);
    for shift in [32, 40, 48, 56] {
        let digit = |k: u64| ((k >> shift) & 0xff) as usize;
        let mut starts = [0usize; 256];
        for &k in keys.iter() {
            starts[digit(k)] += 1;
        }
        if keys.first().is_none_or(|&k| starts[digit(k)] == keys.len()) {
            continue;
        }
        let mut sum = 0;
        for start in starts.iter_mut() {
            (*start, sum) = (sum, sum + *start);
        }
        for &k in keys.iter() {
            let slot = &mut starts[digit(k)];
            scratch[*slot] = k;
            *slot += 1;
        }
        std::mem::swap(keys, scratch);
    }
}

/// A splat that covers a tile, as the scatter reads it.
#[derive(Clone, Copy, Debug, Default)]
struct DepthOrdered {
    splat: u32,
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
