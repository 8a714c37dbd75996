//! Backward blending: gradients of the loss with respect to every splat's 2D quantities.

use rayon::prelude::*;

use super::binning::split_by_offsets;
use super::{
    ALPHA_MAX, Rasterizer, Splat, SplatGrad, TILE, TILE_PIXELS, box_pixels, falloff_at, min_power,
};

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
        self.entry_grads.clear();
        self.entry_grads
            .resize(self.bins.entry_count(), SplatGrad::default());

        let bins = &self.bins;
        let final_t = &self.final_transmittance;
        let contributors = &self.contributors;
        let mut per_tile = split_by_offsets(&mut self.entry_grads, &bins.tile_offsets);
        per_tile
            .par_iter_mut()
            .enumerate()
            .for_each(|(tile, entry_grads)| {
                let entries = &bins.sorted_splats[bins.tile_range(tile)];
                let pixels = tile * TILE_PIXELS..(tile + 1) * TILE_PIXELS;
                let origin = ((tile % tiles_x) * TILE, (tile / tiles_x) * TILE);
                backward_tile(
                    entries,
                    splats,
                    origin,
                    (width, height),
                    background,
                    d_color,
                    &final_t[pixels.clone()],
                    &contributors[pixels],
                    entry_grads,
                );
            });
        drop(per_tile);

        // Reduce the per-(tile, splat) partial sums to one gradient per splat.
        let bins = &self.bins;
        let entry_grads = &self.entry_grads;
        grads.clear();
        grads.resize(splats.len(), SplatGrad::default());
        grads.par_iter_mut().enumerate().for_each(|(s, g)| {
            for e in bins.splat_range(s) {
                g.add(&entry_grads[bins.sorted_position[e] as usize]);
            }
        });
    }
}

/// Walks every pixel's contributors back to front, accumulating one gradient per tile entry.
#[allow(clippy::too_many_arguments)]
fn backward_tile(
    entries: &[u32],
    splats: &[Splat],
    origin: (usize, usize),
    size: (usize, usize),
    background: [f32; 3],
    d_color: &[[f32; 3]],
    final_t: &[f32],
    contributors: &[u32],
    entry_grads: &mut [SplatGrad],
) {
    let mut transmittance = [0f32; TILE_PIXELS];
    let mut d_pixel = [[0f32; 3]; TILE_PIXELS];
    let mut bg_dot = [0f32; TILE_PIXELS];
    let mut accum = [[0f32; 3]; TILE_PIXELS];
    let mut last_alpha = [0f32; TILE_PIXELS];
    let mut last_color = [[0f32; 3]; TILE_PIXELS];
    let mut max_contributor = 0usize;
    for p in 0..TILE_PIXELS {
        let (x, y) = (origin.0 + p % TILE, origin.1 + p / TILE);
        if x < size.0 && y < size.1 {
            transmittance[p] = final_t[p];
            d_pixel[p] = d_color[y * size.0 + x];
            bg_dot[p] = (0..3).map(|c| background[c] * d_pixel[p][c]).sum();
            max_contributor = max_contributor.max(contributors[p] as usize);
        }
    }

    for k in (0..max_contributor).rev() {
        let sp = &splats[entries[k] as usize];
        let mut g = SplatGrad::default();
        let min_power = min_power(sp);
        for p in box_pixels(sp, origin) {
            if k >= contributors[p] as usize {
                continue;
            }
            let Some((dx, dy, gauss)) = falloff_at(sp, origin, p, min_power) else {
                continue;
            };
            let raw_alpha = sp.opacity * gauss;
            let alpha = raw_alpha.min(ALPHA_MAX);
            // Transmittance in front of this splat.
            let t = transmittance[p] / (1.0 - alpha);
            transmittance[p] = t;
            let mut d_alpha = 0.0;
            for c in 0..3 {
                // Colour of everything behind this splat, as seen through it.
                accum[p][c] =
                    last_alpha[p] * last_color[p][c] + (1.0 - last_alpha[p]) * accum[p][c];
                last_color[p][c] = sp.color[c];
                d_alpha += (sp.color[c] - accum[p][c]) * d_pixel[p][c];
                g.color[c] += alpha * t * d_pixel[p][c];
            }
            d_alpha *= t;
            last_alpha[p] = alpha;
            // The background is seen through every splat: final_T = t·(1 − alpha)·(rest).
            d_alpha -= final_t[p] / (1.0 - alpha) * bg_dot[p];
            if raw_alpha >= ALPHA_MAX {
                continue; // clamped: no gradient to opacity or shape
            }
            g.opacity += gauss * d_alpha;
            let d_power = sp.opacity * gauss * d_alpha;
            g.mean2d.x += d_power * (sp.conic[0] * dx + sp.conic[1] * dy);
            g.mean2d.y += d_power * (sp.conic[2] * dy + sp.conic[1] * dx);
            g.conic[0] -= 0.5 * dx * dx * d_power;
            g.conic[1] -= dx * dy * d_power;
            g.conic[2] -= 0.5 * dy * dy * d_power;
        }
        entry_grads[k] = g;
    }
}
