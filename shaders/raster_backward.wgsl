// Backward blending: one workgroup per tile (PIXEL_ROWS pixels of a tile column per
// invocation) walks the tile's entries back to front and every pixel computes its share of
// each entry's gradient, with the same arithmetic as the CPU reference's `backward_tile`; an
// invocation adds up its pixels' shares. What becomes of the sums is `add_shares`, defined by
// one of raster_backward_tiles.wgsl (portable) or raster_backward_atomic.wgsl (float atomics).

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> sorted_splats: array<u32>;
@group(0) @binding(3) var<storage, read> tile_offsets: array<u32>;
@group(0) @binding(4) var<storage, read> final_transmittance: array<f32>;
@group(0) @binding(5) var<storage, read> contributors: array<u32>;
// dL/d(pixel colour), row-major, three floats per pixel.
@group(0) @binding(6) var<storage, read> d_color: array<f32>;

// Gradient fields: dL/d(mean.x, mean.y, conic.a, conic.b, conic.c, opacity, r, g, b).
const FIELDS: u32 = 9u;

// What a pixel knows while the entries are walked back to front.
struct Behind {
    // Transmittance in front of the entries walked so far.
    transmittance: f32,
    final_t: f32,
    d_pixel: vec3<f32>,
    bg_dot: f32,
    // Number of tile entries up to and including the last one blended.
    contributor: u32,
    // Colour of everything behind the current entry, and the entry behind it.
    accum: vec3<f32>,
    last_alpha: f32,
    last_color: vec3<f32>,
}

// The pixel at tile-local `local` before the walk (all zeros outside the image).
fn behind_pixel(origin: vec2<u32>, local: vec2<u32>) -> Behind {
    var pixel = Behind(0.0, 0.0, vec3<f32>(0.0), 0.0, 0u, vec3<f32>(0.0), 0.0, vec3<f32>(0.0));
    if inside_image(origin, local) {
        let p = image_index(origin, local);
        pixel.final_t = final_transmittance[p];
        pixel.transmittance = pixel.final_t;
        pixel.d_pixel = vec3<f32>(d_color[3u * p], d_color[3u * p + 1u], d_color[3u * p + 2u]);
        pixel.bg_dot = dot(params.background.xyz, pixel.d_pixel);
        pixel.contributor = contributors[p];
    }
    return pixel;
}

// The share of the pixel at tile-local `local` in the gradient of staged splat `s`, an entry
// before the pixel's last contributor whose screen box holds the pixel, and the pixel's state
// moved in front of that entry.
fn pixel_share(
    pixel: ptr<function, Behind>,
    s: Splat,
    origin: vec2<u32>,
    local: vec2<u32>,
) -> array<f32, FIELDS> {
    var share = array<f32, FIELDS>();
    let f = falloff_at(s, origin, local);
    if f.w == 0.0 {
        return share;
    }
    let raw_alpha = s.color.w * f.z;
    let alpha = min(raw_alpha, ALPHA_MAX);
    // Transmittance in front of this splat.
    let t = (*pixel).transmittance / (1.0 - alpha);
    (*pixel).transmittance = t;
    let last_alpha = (*pixel).last_alpha;
    let accum = last_alpha * (*pixel).last_color + (1.0 - last_alpha) * (*pixel).accum;
    (*pixel).accum = accum;
    (*pixel).last_color = s.color.xyz;
    (*pixel).last_alpha = alpha;
    let d_pixel = (*pixel).d_pixel;
    let g_color = alpha * t * d_pixel;
    share[6] = g_color.x;
    share[7] = g_color.y;
    share[8] = g_color.z;
    var d_alpha = dot(s.color.xyz - accum, d_pixel) * t;
    // The background is seen through every splat.
    d_alpha -= (*pixel).final_t / (1.0 - alpha) * (*pixel).bg_dot;
    if raw_alpha < ALPHA_MAX {
        share[5] = f.z * d_alpha;
        let d_power = s.color.w * f.z * d_alpha;
        let dx = f.x;
        let dy = f.y;
        share[0] = d_power * (s.conic.x * dx + s.conic.y * dy);
        share[1] = d_power * (s.conic.z * dy + s.conic.y * dx);
        share[2] = -d_power * (0.5 * dx * dx);
        share[3] = -d_power * (dx * dy);
        share[4] = -d_power * (0.5 * dy * dy);
    }
    return share;
}

@compute @workgroup_size(TILE, INVOCATION_ROWS)
fn backward(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    begin_lanes(li);
    let tile = tile_index(wg);
    let origin = wg.xy * TILE;
    let start = tile_offsets[tile];
    let segment = segment_of(lid);
    var pixels: array<Behind, PIXEL_ROWS>;
    var contributor = 0u;
    for (var r = 0u; r < PIXEL_ROWS; r++) {
        pixels[r] = behind_pixel(origin, local_pixel(lid, r));
        contributor = max(contributor, pixels[r].contributor);
    }

    var batch_end = workgroup_max(li, contributor);
    // Entries at or past this one add nothing to the pixels that visit together.
    let visit_end = contributor_bound(contributor, batch_end);

    while batch_end > 0u {
        let batch_start = select(0u, batch_end - BATCH, batch_end > BATCH);
        let count = batch_end - batch_start;
        workgroupBarrier();
        stage_batch(li, start + batch_start, count, origin);
        workgroupBarrier();
        mark_segments(li, count);
        workgroupBarrier();
        for (var w = (count + 31u) / 32u; w > 0u; w--) {
            let useful = slot_bits(w - 1u, min(count, max(visit_end, batch_start) - batch_start));
            var bits = entry_candidates(segment_masks[segment + w - 1u], w - 1u, useful);
            while bits != 0u {
                let b = 31u - countLeadingZeros(bits);
                bits ^= 1u << b;
                let j = 32u * (w - 1u) + b;
                let k = batch_start + j;
                let box = staged_box(j);
                var in_splat = array<bool, PIXEL_ROWS>();
                var any_in = false;
                for (var r = 0u; r < PIXEL_ROWS; r++) {
                    in_splat[r] = k < pixels[r].contributor && in_box(box, local_pixel(lid, r));
                    any_in |= in_splat[r];
                }
                // The sum of the invocation's pixels' shares.
                var shares = array<f32, FIELDS>();
                if visit_splat(any_in) {
                    let s = staged_splat(j);
                    for (var r = 0u; r < PIXEL_ROWS; r++) {
                        if in_splat[r] {
                            // Through a whole variable (SPIR-V takes no pointer to an element),
                            // and the share in a variable so it can be indexed dynamically.
                            var pixel = pixels[r];
                            var share = pixel_share(&pixel, s, origin, local_pixel(lid, r));
                            pixels[r] = pixel;
                            for (var field = 0u; field < FIELDS; field++) {
                                shares[field] += share[field];
                            }
                        }
                    }
                }
                add_shares(li, start + k, shares);
            }
        }
        batch_end = batch_start;
    }
}
