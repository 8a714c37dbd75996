//! Tile binning: which splats touch which 16×16 tile, depth-sorted per tile.

use rayon::prelude::*;

use super::{Splat, TILE, prefetch, simd_kernel};

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
    /// Per chunk of `by_depth`, per tile: the sorted position of the chunk's first entry in
    /// the tile (chunk-major, tiles within).
    chunk_starts: Vec<u32>,
    /// `chunk_starts` as the scatter advances it.
    chunk_fill: Vec<u32>,
    /// Per chunk of `by_depth`, the 2-D difference array of its tile rectangles,
    /// (tiles_y + 1) × (tiles_x + 1).
    chunk_corners: Vec<i32>,
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
            + self.chunk_starts.capacity()
            + self.chunk_fill.capacity()
            + self.chunk_corners.capacity())
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
    /// so every tile's list comes out depth-sorted without sorting each tile. The splats are
    /// cut into chunks of consecutive depths that count and scatter in parallel, each chunk
    /// from its own starting position in every tile.
    pub fn build(&mut self, splats: &[Splat], width: usize, height: usize) {
        self.build_with(splats, width, height, &mut Vec::<()>::new(), |_, _| ());
    }

    /// [`TileBins::build`], and `per_chunk(chunk, out_chunk)` for consecutive chunks of the
    /// splats and of `out` (resized to the splats), in parallel beside the depth sort, which
    /// takes one thread only.
    pub(super) fn build_with<T: Send + Clone + Default>(
        &mut self,
        splats: &[Splat],
        width: usize,
        height: usize,
        out: &mut Vec<T>,
        per_chunk: impl Fn(&[Splat], &mut [T]) + Sync,
    ) {
        self.tiles_x = width.div_ceil(TILE);
        self.tiles_y = height.div_ceil(TILE);
        let tile_count = self.tiles_x * self.tiles_y;
        let (tiles_x, tiles_y) = (self.tiles_x as f32, self.tiles_y as f32);
        self.positions_filled = false;

        // Per splat, its tile rectangle and its sort key (see `rects_and_keys`).
        let n = splats.len();
        self.rects.resize(n, [0; 4]);
        self.sorted_keys.resize(n, 0);
        // Resizing writes only new elements: the buffer keeps its length from frame to frame.
        out.resize(n, T::default());
        splats
            .par_chunks(PASS_CHUNK)
            .zip(self.rects.par_chunks_mut(PASS_CHUNK))
            .zip(self.sorted_keys.par_chunks_mut(PASS_CHUNK))
            .enumerate()
            .for_each(|(c, ((splats, rects), keys))| {
                rects_and_keys(splats, c * PASS_CHUNK, (tiles_x, tiles_y), rects, keys);
            });

        // The entries per splat and the sort by depth run on one thread: `per_chunk` runs
        // beside them on the others.
        let (offsets, rects) = (&mut self.splat_offsets, &self.rects);
        let (keys, scratch) = (&mut self.sorted_keys, &mut self.sort_scratch);
        let ((total, covering), ()) = rayon::join(
            || {
                let counts = entries_per_splat(rects, offsets);
                radix_sort_by_high_half(keys, scratch);
                counts
            },
            || {
                out.par_chunks_mut(PASS_CHUNK)
                    .zip(splats.par_chunks(PASS_CHUNK))
                    .for_each(|(out, splats)| per_chunk(splats, out))
            },
        );
        self.sorted_keys.truncate(covering);

        // What the scatter reads of each splat, gathered into depth order once, so that the
        // chunks read one array front to back instead of jumping around two. The gather itself
        // jumps around the rectangles: each is prefetched a few keys ahead, so the misses
        // overlap instead of stalling one by one.
        let rects = &self.rects;
        self.by_depth.resize(covering, DepthOrdered::default());
        self.sorted_keys
            .par_chunks(GATHER_CHUNK)
            .zip(self.by_depth.par_chunks_mut(GATHER_CHUNK))
            .for_each(|(keys, by_depth)| {
                for (i, (&key, d)) in keys.iter().zip(by_depth).enumerate() {
                    if let Some(&ahead) = keys.get(i + GATHER_AHEAD) {
                        prefetch(rects, ahead as u32 as usize);
                    }
                    let s = key as u32;
                    *d = DepthOrdered {
                        splat: s,
                        rect: rects[s as usize],
                    };
                }
            });

        // Entries per chunk and tile, from a 2-D difference array of each chunk's rectangles:
        // +1 at the corners (x0, y0) and (x1, y1), −1 at (x1, y0) and (x0, y1), then prefix
        // sums along rows and columns. That costs four additions per splat instead of one per
        // entry.
        let chunk_len = chunk_len(covering);
        let chunks = covering.div_ceil(chunk_len);
        let stride = self.tiles_x + 1;
        let corners_len = stride * (self.tiles_y + 1);
        self.chunk_corners.resize(chunks * corners_len, 0);
        self.chunk_starts.resize(chunks * tile_count, 0);
        let (tiles_x, tiles_y) = (self.tiles_x, self.tiles_y);
        self.by_depth
            .par_chunks(chunk_len)
            .zip(self.chunk_corners.par_chunks_mut(corners_len.max(1)))
            .zip(self.chunk_starts.par_chunks_mut(tile_count.max(1)))
            .for_each(|((splats, corners), counts)| {
                corners.fill(0);
                for d in splats {
                    let [x0, y0, x1, y1] = d.rect.map(|v| v as usize);
                    corners[y0 * stride + x0] += 1;
                    corners[y0 * stride + x1] -= 1;
                    corners[y1 * stride + x0] -= 1;
                    corners[y1 * stride + x1] += 1;
                }
                for ty in 0..tiles_y {
                    let mut row_sum = 0i32;
                    for tx in 0..tiles_x {
                        let tile = ty * tiles_x + tx;
                        row_sum += corners[ty * stride + tx];
                        let above = if ty > 0 { counts[tile - tiles_x] } else { 0 };
                        counts[tile] = above.wrapping_add_signed(row_sum);
                    }
                }
            });

        // Each tile's entries: chunk by chunk, so chunk c starts in tile t after the entries
        // of the chunks before it.
        self.tile_offsets.clear();
        self.tile_offsets.push(0);
        let mut next = 0u32;
        for tile in 0..tile_count {
            for chunk in 0..chunks {
                let count = &mut self.chunk_starts[chunk * tile_count + tile];
                (*count, next) = (next, next + *count);
            }
            self.tile_offsets.push(next);
        }

        self.sorted_splats.resize(total as usize, 0);
        let sorted_splats = Disjoint(self.sorted_splats.as_mut_ptr());
        self.scatter(|d, _, k| {
            // SAFETY: k is a position that only this chunk's entry in this tile takes, below
            // the total, the buffer's length.
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
            let (splat_offsets, tiles_x) = (std::mem::take(&mut self.splat_offsets), self.tiles_x);
            self.scatter(|d, tile, k| {
                let [x0, y0, x1, _] = d.rect;
                let (tx, ty) = ((tile % tiles_x) as u32, (tile / tiles_x) as u32);
                let entry = splat_offsets[d.splat as usize] + (ty - y0) * (x1 - x0) + (tx - x0);
                // SAFETY: every (splat, tile) pair has its own entry, below the total, and
                // only the chunk of the splat writes it.
                unsafe { sorted_position.write(entry as usize, k as u32) };
            });
            self.splat_offsets = splat_offsets;
            self.positions_filled = true;
        }
        &self.sorted_position
    }

    /// Calls `place(splat, tile, k)` for every entry of the bins, k its sorted position: the
    /// chunks of `by_depth` in parallel, each in depth order from its starting positions.
    fn scatter(&mut self, place: impl Fn(&DepthOrdered, usize, usize) + Sync) {
        let tile_count = self.tiles_x * self.tiles_y;
        let chunk_len = chunk_len(self.by_depth.len());
        let tiles_x = self.tiles_x;
        self.chunk_fill.clone_from(&self.chunk_starts);
        self.by_depth
            .par_chunks(chunk_len)
            .zip(self.chunk_fill.par_chunks_mut(tile_count.max(1)))
            .for_each(|(splats, fill)| {
                for d in splats {
                    let [x0, y0, x1, y1] = d.rect.map(|v| v as usize);
                    for ty in y0..y1 {
                        let row = ty * tiles_x;
                        for (tile, next) in (row + x0..).zip(&mut fill[row + x0..row + x1]) {
                            place(d, tile, *next as usize);
                            *next += 1;
                        }
                    }
                }
            });
    }
}

/// Fills `offsets` with the prefix sums of the entries of each splat (splat-major order, one
/// more than splats); returns the entries in all and the splats that cover a tile.
fn entries_per_splat(rects: &[[u32; 4]], offsets: &mut Vec<u32>) -> (u32, usize) {
    offsets.clear();
    offsets.reserve(rects.len() + 1);
    offsets.push(0);
    let (mut total, mut covering) = (0u32, 0);
    for r in rects {
        let area = (r[2] - r[0]) * (r[3] - r[1]);
        total += area;
        covering += (area > 0) as usize;
        offsets.push(total);
    }
    (total, covering)
}

/// Keys per parallel task of the gather into depth order.
const GATHER_CHUNK: usize = 16 * 1024;
/// How many keys ahead that gather prefetches.
const GATHER_AHEAD: usize = 16;

/// How many of `items` splats each chunk of the binning takes (the last may take fewer): a few
/// chunks per thread, so an uneven chunk does not hold the others up, but none below 8 192
/// splats, where the per-chunk arrays would cost more than the parallelism gains. The bins
/// come out the same for any chunk length.
fn chunk_len(items: usize) -> usize {
    let chunks = (items / 8192).clamp(1, 4 * rayon::current_num_threads());
    items.div_ceil(chunks).max(1)
}

/// Sorts keys by their high 32 bits, stably (keys with equal high halves keep their order), by
/// least-significant-digit radix sort in bytes; a byte that is the same in every key (the
/// exponent of depths of one scale, say) costs one counting pass and no move. (It is bound by
/// memory: counting and moving in parallel chunks was no faster on two cores.)
fn radix_sort_by_high_half(keys: &mut Vec<u64>, scratch: &mut Vec<u64>) {
    scratch.resize(keys.len(), 0);
    for shift in [32, 40, 48, 56] {
        let digit = |k: u64| ((k >> shift) & 0xff) as usize;
        let mut next = [0u32; 256];
        for &k in keys.iter() {
            next[digit(k)] += 1;
        }
        if keys
            .first()
            .is_none_or(|&k| next[digit(k)] as usize == keys.len())
        {
            continue;
        }
        let mut sum = 0;
        for count in next.iter_mut() {
            (*count, sum) = (sum, sum + *count);
        }
        for &k in keys.iter() {
            let slot = &mut next[digit(k)];
            scratch[*slot as usize] = k;
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

/// Splats per parallel task of the per-splat pass of the binning.
const PASS_CHUNK: usize = 4096;

simd_kernel! {
    /// The tile rectangle and sort key of each splat of a chunk whose first splat has index
    /// `first`: depth bits (high) and index (low), so the index breaks ties. Depths are
    /// positive (beyond the near plane), so their bits order like the values. A splat that
    /// covers no tile gets the largest key, which sorts it last, where it is cut off. (A
    /// kernel of its own so that the rectangles' floors are instructions, not libm calls.)
    fn rects_and_keys(
        splats: &[Splat],
        first: usize,
        tiles: (f32, f32),
        rects: &mut [[u32; 4]],
        keys: &mut [u64],
    ) {
        for (s, ((splat, rect), key)) in splats.iter().zip(rects).zip(keys).enumerate() {
            *rect = tile_rect(splat, tiles.0, tiles.1);
            *key = if rect[2] > rect[0] {
                ((splat.depth.to_bits() as u64) << 32) | (first + s) as u64
            } else {
                u64::MAX
            };
        }
    }
}

/// The tiles a splat's screen box overlaps, as [x0, y0, x1, y1) in tile units.
#[inline(always)]
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
