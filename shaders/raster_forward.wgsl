// Forward blending: one 16×16 workgroup per tile, one invocation per pixel; the tile's
// depth-sorted splats are staged through workgroup memory 256 at a time, and each pixel visits
// those that can be drawn in its segment (`mark_segments`). Appended to raster_common.wgsl and one of
// raster_lanes_plain.wgsl or raster_lanes_subgroup.wgsl.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> sorted_splats: array<u32>;
@group(0) @binding(3) var<storage, read> tile_offsets: array<u32>;
// Row-major: rgb over the background, and alpha = 1 − final transmittance.
@group(0) @binding(4) var<storage, read_write> out_rgba: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> final_transmittance: array<f32>;
// Per pixel: number of tile entries up to and including the last one blended.
@group(0) @binding(6) var<storage, read_write> contributors: array<u32>;

@compute @workgroup_size(16, 16)
fn forward(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    let at = tile_pixel(wg, lid);
    let origin = at.origin;
    var open = at.inside;
    var transmittance = 1.0;
    var color = vec3<f32>(0.0);
    var last = 0u;
    let start = tile_offsets[at.tile];
    let end = tile_offsets[at.tile + 1u];
    let segment = segment_of(lid.xy);

    for (var base = start; base < end; base += TILE_PIXELS) {
        // Stop once no pixel of the tile can take more colour.
        if workgroup_max(li, u32(open)) == 0u {
            break;
        }
        if base + li < end {
            stage(li, splats[sorted_splats[base + li]], origin);
        }
        workgroupBarrier();
        let count = min(TILE_PIXELS, end - base);
        mark_segments(li, count);
        workgroupBarrier();
        for (var w = 0u; w < (count + 31u) / 32u; w++) {
            if !any_open(open) {
                break;
            }
            var bits = lane_candidates(segment_masks[segment + w]);
            while bits != 0u {
                let j = 32u * w + countTrailingZeros(bits);
                bits &= bits - 1u;
                let box = staged_box(j, li);
                if !open || !in_box(box, lid.xy) {
                    continue;
                }
                let s = staged_splat(j, li);
                let f = falloff_at(s, origin, lid.xy);
                if f.w == 0.0 {
                    continue;
                }
                let alpha = min(s.color.w * f.z, ALPHA_MAX);
                let next = transmittance * (1.0 - alpha);
                if next < TRANSMITTANCE_MIN {
                    open = false;
                    continue;
                }
                color += s.color.xyz * (alpha * transmittance);
                transmittance = next;
                last = base - start + j + 1u;
            }
        }
    }

    if at.inside {
        let p = at.pixel.y * params.width + at.pixel.x;
        out_rgba[p] = vec4<f32>(color + transmittance * params.background.xyz, 1.0 - transmittance);
        final_transmittance[p] = transmittance;
        contributors[p] = last;
    }
}
