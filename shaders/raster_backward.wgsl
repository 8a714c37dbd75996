// Backward blending: one 16×16 workgroup per tile walks the tile's entries back to front and
// every pixel computes its share of each entry's gradient, with the same arithmetic as the CPU
// reference's `backward_tile`. What becomes of the shares is `add_shares`, defined by one of
// raster_backward_tiles.wgsl (portable) or raster_backward_atomic.wgsl (float atomics).

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

@compute @workgroup_size(16, 16)
fn backward(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let at = tile_pixel(wg, lid);
    let origin = at.origin;
    let start = tile_offsets[at.tile];
    let segment = segment_of(lid.xy);

    var transmittance = 0.0;
    var final_t = 0.0;
    var d_pixel = vec3<f32>(0.0);
    var bg_dot = 0.0;
    var contributor = 0u;
    if at.inside {
        let p = at.pixel.y * params.width + at.pixel.x;
        final_t = final_transmittance[p];
        transmittance = final_t;
        d_pixel = vec3<f32>(d_color[3u * p], d_color[3u * p + 1u], d_color[3u * p + 2u]);
        bg_dot = dot(params.background.xyz, d_pixel);
        contributor = contributors[p];
    }
    var batch_end = workgroup_max(li, contributor);
    // Entries at or past this one add nothing to the pixels that visit together.
    let visit_end = contributor_bound(contributor, batch_end);

    // Colour of everything behind the current entry, and the entry behind it.
    var accum = vec3<f32>(0.0);
    var last_alpha = 0.0;
    var last_color = vec3<f32>(0.0);

    while batch_end > 0u {
        let batch_start = select(0u, batch_end - TILE_PIXELS, batch_end > TILE_PIXELS);
        let count = batch_end - batch_start;
        workgroupBarrier();
        if li < count {
            stage(li, splats[sorted_splats[start + batch_start + li]], origin);
        }
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
                let box = staged_box(j, li);
                var g_mean = vec2<f32>(0.0);
                var g_conic = vec3<f32>(0.0);
                var g_opacity = 0.0;
                var g_color = vec3<f32>(0.0);
                if k < contributor && in_box(box, lid.xy) {
                    let s = staged_splat(j, li);
                    let f = falloff_at(s, origin, lid.xy);
                    if f.w != 0.0 {
                        let raw_alpha = s.color.w * f.z;
                        let alpha = min(raw_alpha, ALPHA_MAX);
                        // Transmittance in front of this splat.
                        let t = transmittance / (1.0 - alpha);
                        transmittance = t;
                        accum = last_alpha * last_color + (1.0 - last_alpha) * accum;
                        last_color = s.color.xyz;
                        g_color = alpha * t * d_pixel;
                        var d_alpha = dot(s.color.xyz - accum, d_pixel) * t;
                        last_alpha = alpha;
                        // The background is seen through every splat.
                        d_alpha -= final_t / (1.0 - alpha) * bg_dot;
                        if raw_alpha < ALPHA_MAX {
                            g_opacity = f.z * d_alpha;
                            let d_power = s.color.w * f.z * d_alpha;
                            let dx = f.x;
                            let dy = f.y;
                            g_mean = d_power * vec2<f32>(
                                s.conic.x * dx + s.conic.y * dy,
                                s.conic.z * dy + s.conic.y * dx,
                            );
                            g_conic = -d_power * vec3<f32>(0.5 * dx * dx, dx * dy, 0.5 * dy * dy);
                        }
                    }
                }
                add_shares(li, start + k, array<f32, FIELDS>(
                    g_mean.x, g_mean.y, g_conic.x, g_conic.y, g_conic.z, g_opacity,
                    g_color.x, g_color.y, g_color.z,
                ));
            }
        }
        batch_end = batch_start;
    }
}
