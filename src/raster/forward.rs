//! Forward blending: front-to-back alpha compositing per 16×16 tile.

use rayon::prelude::*;

use super::{
    ALPHA_MAX, Rasterizer, RenderOutput, Splat, TILE, TILE_PIXELS, TRANSMITTANCE_MIN, box_pixels,
    falloff_at, min_power, untile,
};

/// Gaussian falloff exponent at offset (dx, dy) from the centre.
#[inline(always)]
pub(super) fn power(conic: &[f32; 3], dx: f32, dy: f32) -> f32 {
    -0.5 * (conic[0] * dx * dx + conic[2] * dy * dy) - conic[1] * dx * dy
}

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
        self.blend(splats, width, height, background, out);
    }

    /// Bins `splats` into depth-sorted tile lists (the first half of [`Rasterizer::forward`]).
    pub fn bin(&mut self, splats: &[Splat], width: usize, height: usize) {
        self.bins.build(splats, width, height);
    }

    /// Blends the splats binned by the last [`Rasterizer::bin`] call (the second half of
    /// [`Rasterizer::forward`]).
    pub fn blend(
        &mut self,
        splats: &[Splat],
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
        self.tile_color.resize(pixel_slots, [0.0; 3]);

        let tiles_x = self.bins.tiles_x;
        let bins = &self.bins;
        self.tile_color
            .par_chunks_mut(TILE_PIXELS)
            .zip(self.final_transmittance.par_chunks_mut(TILE_PIXELS))
            .zip(self.contributors.par_chunks_mut(TILE_PIXELS))
            .enumerate()
            .for_each(|(tile, ((color, transmittance), contributors))| {
                let entries = &bins.sorted_splats[bins.tile_range(tile)];
                let origin = ((tile % tiles_x) * TILE, (tile / tiles_x) * TILE);
                blend_tile(
                    entries,
                    splats,
                    origin,
                    (width, height),
                    background,
                    color,
                    transmittance,
                    contributors,
                );
            });

        out.image.width = width;
        out.image.height = height;
        untile(
            &self.tile_color,
            tiles_x,
            width,
            height,
            &mut out.image.data,
            [0.0; 3],
        );
        untile(
            &self.final_transmittance,
            tiles_x,
            width,
            height,
            &mut out.alpha,
            1.0,
        );
        out.alpha.par_iter_mut().for_each(|a| *a = 1.0 - *a);
    }
}

/// Blends one tile. Pixels outside the image keep transmittance 1 and no contributors.
#[allow(clippy::too_many_arguments)]
fn blend_tile(
    entries: &[u32],
    splats: &[Splat],
    origin: (usize, usize),
    size: (usize, usize),
    background: [f32; 3],
    color: &mut [[f32; 3]],
    transmittance: &mut [f32],
    contributors: &mut [u32],
) {
    let mut active = [false; TILE_PIXELS];
    let mut remaining = 0;
    for (p, a) in active.iter_mut().enumerate() {
        *a = origin.0 + p % TILE < size.0 && origin.1 + p / TILE < size.1;
        remaining += *a as usize;
    }
    color.fill([0.0; 3]);
    transmittance.fill(1.0);
    contributors.fill(0);

    for (k, &s) in entries.iter().enumerate() {
        if remaining == 0 {
            break;
        }
        let sp = &splats[s as usize];
        let min_power = min_power(sp);
        for p in box_pixels(sp, origin) {
            if !active[p] {
                continue;
            }
            let Some((_, _, gauss)) = falloff_at(sp, origin, p, min_power) else {
                continue;
            };
            let alpha = (sp.opacity * gauss).min(ALPHA_MAX);
            let t = transmittance[p];
            let next = t * (1.0 - alpha);
            if next < TRANSMITTANCE_MIN {
                active[p] = false;
                remaining -= 1;
                continue;
            }
            let w = alpha * t;
            for c in 0..3 {
                color[p][c] += sp.color[c] * w;
            }
            transmittance[p] = next;
            contributors[p] = k as u32 + 1;
        }
    }
    for p in 0..TILE_PIXELS {
        for c in 0..3 {
            color[p][c] += transmittance[p] * background[c];
        }
    }
}
