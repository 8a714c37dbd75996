//! Backward blending: gradients of the loss with respect to every splat's 2D quantities.

use rayon::prelude::*;

use super::binning::for_each_tile_mut;
use super::{
    ALPHA_MAX, F16, Falloff, GROUPS, GroupBits, LANES, M16, PREFETCH_AHEAD, Packed, Pair, Pairs,
    Rasterizer, RowSpans, SLOTS, Splat, SplatGrad, TILE, TILE_PIXELS, box_in_tile, falloff_pair,
    prefetch, prefetch_entry, row_spans, simd_kernel,
};

/// How many entries ahead the reduction of the partial sums prefetches the splat it adds into.
const REDUCE_AHEAD: usize = 16;

impl Rasterizer {
    /// Back-propagates `d_color` (dL/d(rendered colour), row-major, same size as the last
    /// forward) to `grads[s]` for every splat `s` of the last [`Rasterizer::forward`] call.
    ///
    /// `splats` must be the slice given to that forward call.
    pub fn backward(
        &mut self,
        splats: &[Splat],
        d_color: &[[f32; 3]],
        width: usize,
        grads: &mut Vec<SplatGrad>,
    ) {
        let tiles_x = self.tiles_x();
        let height = d_color.len() / width.max(1);
        let background = self.background;
        // Only the entries a tile walks (its first ones, up to its largest contributor count)
        // get a partial sum: pixels stop early, so that is a fraction of the entries.
        let tile_count = self.bins.tile_offsets.len() - 1;
        let walked = &mut self.walked_offsets;
        walked.resize(tile_count + 1, 0);
        walked[0] = 0;
        walked[1..]
            .par_iter_mut()
            .zip(self.contributors.par_chunks(TILE_PIXELS))
            .for_each(|(walked, contributors)| {
                *walked = contributors.iter().copied().max().unwrap_or(0)
            });
        for t in 0..tile_count {
            walked[t + 1] += walked[t];
        }
        self.entry_grads
            .resize(walked[tile_count] as usize, SplatGrad::default());

        let bins = &self.bins;
        let packed = &self.packed;
        let final_t = &self.final_transmittance;
        let contributors = &self.contributors;
        for_each_tile_mut(
            &mut self.entry_grads,
            &self.walked_offsets,
            0..tile_count,
            &|tile, entry_grads| {
                let entries = &bins.sorted_splats[bins.tile_range(tile)];
                let pixels = tile * TILE_PIXELS..(tile + 1) * TILE_PIXELS;
                let origin = ((tile % tiles_x) * TILE, (tile / tiles_x) * TILE);
                backward_tile(
                    entries,
                    packed,
                    origin,
                    (width, height),
                    background,
                    d_color,
                    &final_t[pixels.clone()],
                    &contributors[pixels],
                    entry_grads,
                );
            },
        );

        // Reduce the per-(tile, splat) partial sums to one gradient per splat, in tile order:
        // the partial sums are read front to back and added into their splats. The first half
        // of the tiles adds into `grads` and the second into `lower_grads`, in parallel, and
        // the two are then added: two halves whatever the thread count, so the sums do not
        // depend on it. The entries their tiles did not walk were never reached and have zero
        // gradient.
        let (bins, entry_grads) = (&self.bins, &self.entry_grads);
        let walked = &self.walked_offsets;
        let add_tiles = |tiles: std::ops::Range<usize>, sums: &mut Vec<SplatGrad>| {
            sums.clear();
            sums.resize(splats.len(), SplatGrad::default());
            for tile in tiles {
                let walked_grads = &entry_grads[walked[tile] as usize..walked[tile + 1] as usize];
                let entries = &bins.sorted_splats[bins.tile_range(tile)];
                for (i, (&s, g)) in entries.iter().zip(walked_grads).enumerate() {
                    if let Some(&ahead) = entries.get(i + REDUCE_AHEAD) {
                        prefetch(sums, ahead as usize);
                    }
                    sums[s as usize].add(g);
                }
            }
        };
        let middle = tile_count / 2;
        let lower_grads = &mut self.lower_grads;
        rayon::join(
            || add_tiles(0..middle, grads),
            || add_tiles(middle..tile_count, lower_grads),
        );
        grads
            .par_iter_mut()
            .zip(&self.lower_grads)
            .for_each(|(g, lower)| g.add(lower));
    }
}

/// Per-pixel state of the backward walk, in lane groups (group r holds pixels r·8 .. r·8 + 8).
/// Colours enter the gradient only through their dot product with dL/dpixel, so the colour
/// behind a splat is carried as that one dot product instead of three channels.
struct PixelState {
    /// Transmittance in front of the splat being visited.
    transmittance: [[f32; LANES]; SLOTS],
    /// (colour of everything behind the splat being visited) · dL/dpixel.
    behind: [[f32; LANES]; SLOTS],
    d_pixel: [[[f32; LANES]; SLOTS]; 3],
    /// final transmittance · (background · dL/dpixel): the background's share of the gradient.
    background_term: [[f32; LANES]; SLOTS],
    contributors: [[u32; LANES]; SLOTS],
}

simd_kernel! {
    /// Walks every pixel's contributors back to front, accumulating one gradient per tile entry.
    fn backward_tile(
        entries: &[u32],
        splats: &[Packed],
        origin: (usize, usize),
        size: (usize, usize),
        background: [f32; 3],
        d_color: &[[f32; 3]],
        final_t: &[f32],
        contributors: &[u32],
        entry_grads: &mut [SplatGrad],
    ) {
        let zero = [[0f32; LANES]; SLOTS];
        let mut st = PixelState {
            transmittance: zero,
            behind: zero,
            d_pixel: [zero; 3],
            background_term: zero,
            contributors: [[0; LANES]; SLOTS],
        };
        // Groups whose pixels all stopped before entry k are skipped.
        let mut group_contributors = [0u32; GROUPS];
        for r in 0..GROUPS {
            for x in 0..LANES {
                let p = r * LANES + x;
                let (px, py) = (origin.0 + p % TILE, origin.1 + p / TILE);
                if px < size.0 && py < size.1 {
                    let d = d_color[py * size.0 + px];
                    st.transmittance[r][x] = final_t[p];
                    st.contributors[r][x] = contributors[p];
                    for c in 0..3 {
                        st.d_pixel[c][r][x] = d[c];
                    }
                    let bg_dot: f32 = (0..3).map(|c| background[c] * d[c]).sum();
                    st.background_term[r][x] = final_t[p] * bg_dot;
                    group_contributors[r] = group_contributors[r].max(contributors[p]);
                }
            }
        }
        let max_contributor = group_contributors.iter().copied().max().unwrap_or(0) as usize;

        let mut spans = RowSpans::default();
        for k in (0..max_contributor).rev() {
            if let Some(ahead) = k.checked_sub(PREFETCH_AHEAD) {
                prefetch_entry(splats, entries, ahead);
            }
            let sp = &splats[entries[k] as usize];
            let [x0, x1, y0, y1] = box_in_tile(sp.mean, sp.extent, origin);
            row_spans(&mut spans, sp, origin, (x0, x1));
            // Lane-wise partial sums of the nine gradient terms (see [`backward_lanes`]), reduced
            // once per (tile, splat).
            let mut acc = [F16::default(); 9];
            let mut walking: GroupBits = 0;
            for (r, &count) in group_contributors.iter().enumerate() {
                walking |= (((k as u32) < count) as GroupBits) << r;
            }
            for pair in Pairs::<WIDE>(spans.groups(y0, y1) & walking) {
                let falloff = falloff_pair::<FUSED, WIDE>(sp, &spans, pair);
                backward_lanes::<FUSED, WIDE>(sp, &mut st, pair, k as u32, falloff, &mut acc);
            }
            let [sx, sy, sxx, sxy, syy, opacity, r, g, b] = lane_sums(acc);
            // power = −½(a·dx² + c·dy²) − b·dx·dy, and dx = x − mean.x: dpower/dmean.x = a·dx + b·dy.
            let [ca, cb, cc] = sp.conic;
            entry_grads[k] = SplatGrad {
                mean2d: glam::Vec2::new(ca * sx + cb * sy, cc * sy + cb * sx),
                conic: [-0.5 * sxx, -sxy, -0.5 * syy],
                opacity,
                color: [r, g, b],
            };
        }
    }
}

/// The sum of each accumulator's lanes. Kept out of line on purpose: inlined into the kernel,
/// the sums let LLVM's SLP vectoriser regroup the accumulators of the lane loop across
/// registers, and the AVX-512 raster backward ran three times slower.
#[inline(never)]
fn lane_sums(acc: [F16; 9]) -> [f32; 9] {
    acc.map(F16::sum)
}

/// One pair of lane groups of the backward walk for splat entry `k`: un-blends it from every
/// pixel it was blended into and adds its gradient terms to `acc`: with p = dL/dpower, the
/// moments p·dx, p·dy, p·dx², p·dx·dy, p·dy² (the splat's mean and conic gradients are fixed
/// combinations of their sums), then dL/dopacity and dL/d(r, g, b).
#[inline(always)]
fn backward_lanes<const FUSED: bool, const WIDE: bool>(
    sp: &Packed,
    st: &mut PixelState,
    pair: Pair<WIDE>,
    k: u32,
    Falloff { dx, dy, gauss: g }: Falloff,
    acc: &mut [F16; 9],
) {
    let (zero, one) = (F16::splat(0.0), F16::splat(1.0));
    let opacity = F16::splat(sp.opacity);
    let blended = zero.lt(g) & M16::below(k, pair.get(&st.contributors));
    let raw_alpha = opacity * g;
    let unclamped = raw_alpha.lt(F16::splat(ALPHA_MAX));
    let alpha = raw_alpha.select(unclamped, F16::splat(ALPHA_MAX));
    let inv_one_minus = one / (one - alpha);
    // Transmittance in front of this splat.
    let t_behind = F16(pair.get(&st.transmittance));
    // Updates of the per-pixel state are written as "value op (select)", not "select(new,
    // old)": LLVM turns a select stored back where it was loaded into a masked store, which
    // costs a dozen cycles on AMD CPUs.
    let t = t_behind * inv_one_minus.select(blended, one);
    pair.set(&mut st.transmittance, t.0);
    let alpha_blended = alpha.select(blended, zero);
    let weight = alpha_blended * t;
    // This splat's colour · dL/dpixel, and its colour gradient.
    let mut color_dot = zero;
    for ch in 0..3 {
        let d_pixel = F16(pair.get(&st.d_pixel[ch]));
        color_dot = F16::splat(sp.color[ch]).mul_add::<FUSED>(d_pixel, color_dot);
        acc[6 + ch] = weight.mul_add::<FUSED>(d_pixel, acc[6 + ch]);
    }
    let behind = F16(pair.get(&st.behind));
    let towards_color = color_dot - behind;
    // Blending this splat over what is behind it: behind ← behind + alpha·(colour − behind).
    pair.set(
        &mut st.behind,
        alpha_blended.mul_add::<FUSED>(towards_color, behind).0,
    );
    // The background is seen through every splat: final_T = t·(1 − alpha)·(rest).
    let background = F16(pair.get(&st.background_term)) * inv_one_minus;
    let d_alpha = towards_color.mul_add::<FUSED>(t, zero - background);
    // A clamped alpha passes no gradient to opacity or shape.
    let d_alpha = d_alpha.select(blended & unclamped, zero);
    let g_d_alpha = g * d_alpha;
    let d_power = opacity * g_d_alpha;
    let (power_dx, power_dy) = (d_power * dx, d_power * dy);
    acc[0] = acc[0] + power_dx;
    acc[1] = acc[1] + power_dy;
    acc[2] = power_dx.mul_add::<FUSED>(dx, acc[2]);
    acc[3] = power_dx.mul_add::<FUSED>(dy, acc[3]);
    acc[4] = power_dy.mul_add::<FUSED>(dy, acc[4]);
    acc[5] = acc[5] + g_d_alpha;
}
