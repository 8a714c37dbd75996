//! Forward blending: front-to-back alpha compositing per 16×16 tile.

use rayon::prelude::*;

use super::{
    ALPHA_MAX, ALPHA_MIN, F16, GROUPS, GroupBits, LANES, M16, PREFETCH_AHEAD, Packed, Pairs,
    Rasterizer, RenderOutput, RowSpans, SLOTS, Splat, TILE, TILE_PIXELS, TRANSMITTANCE_MIN,
    box_in_tile, falloff_pair, prefetch_entry, row_spans, simd_kernel,
};

impl Rasterizer {
    /// Renders `splats` into a `width × height` image over `background`.
    pub fn forward(
        &mut self,
        splats: &[Splat],
        width: usize,
        height: usize,
        background: [f32; 3],
        out: &mut RenderOutput,
    ) {
        self.bin(splats, width, height);
        self.blend(width, height, background, out);
    }

    /// Bins `splats` into depth-sorted tile lists (the first half of [`Rasterizer::forward`]).
    pub fn bin(&mut self, splats: &[Splat], width: usize, height: usize) {
        self.bins
            .build_with(splats, width, height, &mut self.packed, pack_chunk);
    }

    /// Blends the splats binned by the last [`Rasterizer::bin`] call (the second half of
    /// [`Rasterizer::forward`]).
    pub fn blend(
        &mut self,
        width: usize,
        height: usize,
        background: [f32; 3],
        out: &mut RenderOutput,
    ) {
        self.background = background;
        let tile_count = self.bins.tiles_x * self.bins.tiles_y;
        let pixel_slots = tile_count * TILE_PIXELS;
        self.final_transmittance.resize(pixel_slots, 1.0);
        self.contributors.resize(pixel_slots, 0);
        self.tile_color.resize(3 * pixel_slots, 0.0);

        let tiles_x = self.bins.tiles_x;
        let bins = &self.bins;
        let packed = &self.packed;
        self.tile_color
            .par_chunks_mut(3 * TILE_PIXELS)
            .zip(self.final_transmittance.par_chunks_mut(TILE_PIXELS))
            .zip(self.contributors.par_chunks_mut(TILE_PIXELS))
            .enumerate()
            .with_max_len(1)
            .for_each(|(tile, ((color, transmittance), contributors))| {
                let entries = &bins.sorted_splats[bins.tile_range(tile)];
                let origin = ((tile % tiles_x) * TILE, (tile / tiles_x) * TILE);
                blend_tile(
                    entries,
                    packed,
                    origin,
                    (width, height),
                    background,
                    color,
                    transmittance,
                    contributors,
                );
            });
        self.write_output(width, height, out);
    }

    /// Reorders the tile-major colour and transmittance into the row-major image and alpha.
    fn write_output(&self, width: usize, height: usize, out: &mut RenderOutput) {
        out.image.width = width;
        out.image.height = height;
        out.image.data.resize(width * height, [0.0; 3]);
        out.alpha.resize(width * height, 0.0);
        let tiles_x = self.bins.tiles_x;
        out.image
            .data
            .par_chunks_mut(width.max(1))
            .zip(out.alpha.par_chunks_mut(width.max(1)))
            .enumerate()
            .for_each(|(y, (row, alpha))| {
                // Each tile holds 16 consecutive pixels of this row, per channel.
                let (ty, ly) = (y / TILE, y % TILE);
                for (tx, (values, alphas)) in
                    row.chunks_mut(TILE).zip(alpha.chunks_mut(TILE)).enumerate()
                {
                    let tile = ty * tiles_x + tx;
                    let first = tile * TILE_PIXELS + ly * TILE;
                    let len = values.len();
                    let channel = |c: usize| {
                        let start = 3 * tile * TILE_PIXELS + c * TILE_PIXELS + ly * TILE;
                        &self.tile_color[start..start + len]
                    };
                    let (red, green, blue) = (channel(0), channel(1), channel(2));
                    let transmittance = &self.final_transmittance[first..first + len];
                    for (i, (value, a)) in values.iter_mut().zip(alphas.iter_mut()).enumerate() {
                        *value = [red[i], green[i], blue[i]];
                        *a = 1.0 - transmittance[i];
                    }
                }
            });
    }
}

/// Gaussian–pixel pairs of one forward pass (see [`Rasterizer::pair_counts`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PairCounts {
    /// Pairs whose pixel is inside the splat's screen box and still blending when the splat's
    /// turn comes: what a tile rasterizer without finer culling evaluates.
    pub evaluated: u64,
    /// Pairs blended into their pixel (alpha at least 1/255, the pixel not yet stopped).
    pub blended: u64,
}

impl std::ops::Add for PairCounts {
    type Output = PairCounts;
    fn add(self, other: PairCounts) -> PairCounts {
        PairCounts {
            evaluated: self.evaluated + other.evaluated,
            blended: self.blended + other.blended,
        }
    }
}

impl Rasterizer {
    /// Counts the Gaussian–pixel pairs of the last forward pass on a `width × height` image,
    /// by a plain per-pixel walk of its tile lists with the blending rules of the forward
    /// (libm's exponential instead of the kernels' polynomial, so a pair at the 1/255 edge
    /// may count differently). For reports: it takes longer than the forward pass itself.
    pub fn pair_counts(&self, width: usize, height: usize) -> PairCounts {
        let tiles_x = self.bins.tiles_x;
        (0..tiles_x * self.bins.tiles_y)
            .into_par_iter()
            .map(|tile| {
                let origin = ((tile % tiles_x) * TILE, (tile / tiles_x) * TILE);
                let mut transmittance = [1f32; TILE_PIXELS];
                // Pixels outside the image, and those that stopped, take no more splats.
                let mut stopped: [bool; TILE_PIXELS] = std::array::from_fn(|p| {
                    origin.0 + p % TILE >= width || origin.1 + p / TILE >= height
                });
                let mut counts = PairCounts::default();
                for &s in &self.bins.sorted_splats[self.bins.tile_range(tile)] {
                    let sp = &self.packed[s as usize];
                    let [x0, x1, y0, y1] = box_in_tile(sp.mean, sp.extent, origin);
                    for y in y0..y1 {
                        for x in x0..x1 {
                            let p = y * TILE + x;
                            if stopped[p] {
                                continue;
                            }
                            counts.evaluated += 1;
                            let dx = (origin.0 + x) as f32 + 0.5 - sp.mean[0];
                            let dy = (origin.1 + y) as f32 + 0.5 - sp.mean[1];
                            let [a, b, c] = sp.conic;
                            let power = -0.5 * (a * dx * dx + c * dy * dy) - b * dx * dy;
                            let alpha = (sp.opacity * power.exp()).min(ALPHA_MAX);
                            if power > 0.0 || alpha < ALPHA_MIN {
                                continue;
                            }
                            let next = transmittance[p] * (1.0 - alpha);
                            if next < TRANSMITTANCE_MIN {
                                stopped[p] = true;
                            } else {
                                transmittance[p] = next;
                                counts.blended += 1;
                            }
                        }
                    }
                }
                counts
            })
            .reduce(PairCounts::default, |a, b| a + b)
    }
}

simd_kernel! {
    /// Packs a chunk of splats for the pixel loops (a kernel, so that the packing's arithmetic
    /// gets the CPU's vector instruction set).
    fn pack_chunk(splats: &[Splat], out: &mut [Packed]) {
        for (splat, packed) in splats.iter().zip(out) {
            *packed = Packed::new(splat);
        }
    }
}

/// How many entries the forward blend goes between refreshes of its live groups.
const LIVE_REFRESH: usize = 8;

/// The groups with at least one lane set.
#[inline(always)]
fn live_bits(live: &[[u32; LANES]; SLOTS]) -> GroupBits {
    let mut bits = 0;
    for (r, lanes) in live[..GROUPS].iter().enumerate() {
        let any = lanes.iter().fold(0, |acc, &l| acc | l) != 0;
        bits |= (any as GroupBits) << r;
    }
    bits
}

simd_kernel! {
    /// Blends one tile. Pixels outside the image keep transmittance 1 and no contributors.
    /// `color` holds the tile's 256 red, then green, then blue values.
    fn blend_tile(
        entries: &[u32],
        splats: &[Packed],
        origin: (usize, usize),
        size: (usize, usize),
        background: [f32; 3],
        color: &mut [f32],
        transmittance: &mut [f32],
        contributors: &mut [u32],
    ) {
        // Per-pixel state in lane groups: group r holds pixels r·8 .. r·8 + 8 of the tile.
        let mut t = [[1f32; LANES]; SLOTS];
        let mut rgb = [[[0f32; LANES]; SLOTS]; 3];
        let mut last = [[0u32; LANES]; SLOTS];
        // All bits set until the pixel stops (never set in the idle slot).
        let mut live = [[0u32; LANES]; SLOTS];
        for (r, group) in live[..GROUPS].iter_mut().enumerate() {
            for (x, l) in group.iter_mut().enumerate() {
                let p = r * LANES + x;
                let inside = origin.0 + p % TILE < size.0 && origin.1 + p / TILE < size.1;
                *l = if inside { !0 } else { 0 };
            }
        }
        // Groups with a pixel still blending, refreshed every few entries only: the groups a
        // splat visits then do not wait on the blending of the splats just before it, so the
        // loop over them is known early and successive splats overlap. A group that stopped
        // since the refresh is visited to no effect (its lanes are masked off).
        let mut live_groups: GroupBits = 0;
        let (zero, one) = (F16::splat(0.0), F16::splat(1.0));
        let (alpha_max, t_min) = (F16::splat(ALPHA_MAX), F16::splat(TRANSMITTANCE_MIN));

        let mut spans = RowSpans::default();
        for (k, &s) in entries.iter().enumerate() {
            if k % LIVE_REFRESH == 0 {
                live_groups = live_bits(&live);
                if live_groups == 0 {
                    break;
                }
            }
            prefetch_entry(splats, entries, k + PREFETCH_AHEAD);
            let sp = &splats[s as usize];
            let [x0, x1, y0, y1] = box_in_tile(sp.mean, sp.extent, origin);
            row_spans(&mut spans, sp, origin, (x0, x1));
            let contributor = k as u32 + 1;
            let opacity = F16::splat(sp.opacity);
            let splat_color = sp.color.map(F16::splat);
            for pair in Pairs::<WIDE>(spans.groups(y0, y1) & live_groups) {
                let g = falloff_pair::<FUSED, WIDE>(sp, &spans, pair).gauss;
                // Whole-register selects, never per-lane conditional stores (masked
                // stores are slow on some CPUs).
                let raw = opacity * g;
                let alpha = raw.select(raw.lt(alpha_max), alpha_max);
                let live_lanes = M16(pair.get(&live));
                let drawn = zero.lt(g) & live_lanes;
                let t_front = F16(pair.get(&t));
                let next = t_front * (one - alpha);
                let stop = drawn & next.lt(t_min);
                let blend = drawn.and_not(stop);
                let w = (alpha * t_front).select(blend, zero);
                for c in 0..3 {
                    let sum = splat_color[c].mul_add::<FUSED>(w, F16(pair.get(&rgb[c])));
                    pair.set(&mut rgb[c], sum.0);
                }
                pair.set(&mut t, next.select(blend, t_front).0);
                let latest = blend.select_u32(contributor, pair.get(&last));
                pair.set(&mut last, latest);
                pair.set(&mut live, live_lanes.and_not(stop).0);
            }
        }
        for r in 0..GROUPS {
            for x in 0..LANES {
                let p = r * LANES + x;
                for c in 0..3 {
                    color[c * TILE_PIXELS + p] = rgb[c][r][x] + t[r][x] * background[c];
                }
                transmittance[p] = t[r][x];
                contributors[p] = last[r][x];
            }
        }
    }
}
