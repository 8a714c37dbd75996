// Forward blending: one workgroup per tile, one invocation per PIXEL_ROWS pixels of a tile
// column; the tile's depth-sorted splats are staged through workgroup memory 256 at a time, and
// each invocation visits those that can be drawn in its segment (`mark_segments`). Appended to
// raster_common.wgsl and one of raster_lanes_plain.wgsl or raster_lanes_subgroup.wgsl.

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> splats: array<Splat>;
@group(0) @binding(2) var<storage, read> sorted_splats: array<u32>;
@group(0) @binding(3) var<storage, read> tile_offsets: array<u32>;
// Row-major: rgb over the background, and alpha = 1 − final transmittance.
@group(0) @binding(4) var<storage, read_write> out_rgba: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> final_transmittance: array<f32>;
// Per pixel: number of tile entries up to and including the last one blended.
@group(0) @binding(6) var<storage, read_write> contributors: array<u32>;

// What a pixel has blended so far.
struct Blended {
    transmittance: f32,
    color: vec3<f32>,
    // Number of tile entries up to and including the last one blended.
    last: u32,
    // Still taking colour: inside the image and not yet stopped.
    open: bool,
}

// Blends staged splat `s`, tile entry number `entry` (counted from 1), into the pixel at
// tile-local `local`, inside the splat's screen box.
fn blend_into(
    pixel: ptr<function, Blended>,
    s: Splat,
    origin: vec2<u32>,
    local: vec2<u32>,
    entry: u32,
) {
    let f = falloff_at(s, origin, local);
    if f.w == 0.0 {
        return;
    }
    let alpha = min(s.color.w * f.z, ALPHA_MAX);
    let next = (*pixel).transmittance * (1.0 - alpha);
    if next < TRANSMITTANCE_MIN {
        (*pixel).open = false;
        return;
    }
    (*pixel).color += s.color.xyz * (alpha * (*pixel).transmittance);
    (*pixel).transmittance = next;
    (*pixel).last = entry;
}

// Whether any of an invocation's pixels still takes colour.
fn any_pixel_open(pixels: ptr<function, array<Blended, PIXEL_ROWS>>) -> bool {
    var open = false;
    for (var r = 0u; r < PIXEL_ROWS; r++) {
        open |= (*pixels)[r].open;
    }
    return open;
}

// Writes a pixel's colour over the background, alpha, final transmittance and contributors.
fn write_pixel(pixel: Blended, origin: vec2<u32>, local: vec2<u32>) {
    if inside_image(origin, local) {
        let p = image_index(origin, local);
        let t = pixel.transmittance;
        out_rgba[p] = vec4<f32>(pixel.color + t * params.background.xyz, 1.0 - t);
        final_transmittance[p] = t;
        contributors[p] = pixel.last;
    }
}

@compute @workgroup_size(TILE, INVOCATION_ROWS)
fn forward(
    @builtin(workgroup_id) wg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(local_invocation_index) li: u32,
) {
    begin_lanes(li);
    let tile = tile_index(wg);
    let origin = wg.xy * TILE;
    var pixels: array<Blended, PIXEL_ROWS>;
    for (var r = 0u; r < PIXEL_ROWS; r++) {
        pixels[r] = Blended(1.0, vec3<f32>(0.0), 0u, inside_image(origin, local_pixel(lid, r)));
    }
    let start = tile_offsets[tile];
    let end = tile_offsets[tile + 1u];
    let segment = segment_of(lid);

    for (var base = start; base < end; base += BATCH) {
        // Stop once no pixel of the tile can take more colour.
        if workgroup_max(li, u32(any_pixel_open(&pixels))) == 0u {
            break;
        }
        let count = min(BATCH, end - base);
        stage_batch(li, base, count, origin);
        workgroupBarrier();
        mark_segments(li, count);
        workgroupBarrier();
        for (var w = 0u; w < (count + 31u) / 32u; w++) {
            if !any_open(any_pixel_open(&pixels)) {
                break;
            }
            var bits = lane_candidates(segment_masks[segment + w]);
            while bits != 0u {
                let j = 32u * w + countTrailingZeros(bits);
                bits &= bits - 1u;
                let box = staged_box(j);
                var in_splat = array<bool, PIXEL_ROWS>();
                var any_in = false;
                for (var r = 0u; r < PIXEL_ROWS; r++) {
                    in_splat[r] = pixels[r].open && in_box(box, local_pixel(lid, r));
                    any_in |= in_splat[r];
                }
                if !visit_splat(any_in) {
                    continue;
                }
                let s = staged_splat(j);
                let entry = base - start + j + 1u;
                for (var r = 0u; r < PIXEL_ROWS; r++) {
                    if in_splat[r] {
                        // Through a whole variable: SPIR-V takes no pointer to an element.
                        var pixel = pixels[r];
                        blend_into(&pixel, s, origin, local_pixel(lid, r), entry);
                        pixels[r] = pixel;
                    }
                }
            }
        }
    }

    for (var r = 0u; r < PIXEL_ROWS; r++) {
        write_pixel(pixels[r], origin, local_pixel(lid, r));
    }
}
