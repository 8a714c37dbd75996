// Shared by the rasterizer kernels: the splat layout, the constants of SPEC §4 and the
// Gaussian falloff, written to agree with the CPU reference (src/raster/) pixel for pixel.

const TILE: u32 = 16u;
// Blending workgroups have 16 × INVOCATION_ROWS invocations per 16×16 tile, each invocation
// blending PIXEL_ROWS pixels of one column, rows PIXEL_ROWS·y + r: what an invocation reads of
// a splat, and what its subgroup votes and sums, then serves several pixels (on lavapipe each
// read of workgroup memory and each subgroup operation is a loop over the lanes, the main cost
// of these kernels).
const PIXEL_ROWS: u32 = 8u;
const INVOCATION_ROWS: u32 = TILE / PIXEL_ROWS;
const BLEND_INVOCATIONS: u32 = TILE * INVOCATION_ROWS;
// Splats staged per batch, BATCH / BLEND_INVOCATIONS per invocation.
const BATCH: u32 = 256u;
const ALPHA_MIN: f32 = 0.003921569; // 1/255
const ALPHA_MAX: f32 = 0.99;
const TRANSMITTANCE_MIN: f32 = 1e-4;

// A projected Gaussian. `conic.w` is the exponent below which alpha < 1/255 (computed on the
// CPU with the reference's formula); `color.w` is the opacity.
struct Splat {
    mean: vec2<f32>,
    extent: vec2<f32>,
    conic: vec4<f32>,
    color: vec4<f32>,
}

struct Params {
    width: u32,
    height: u32,
    tiles_x: u32,
    tiles_y: u32,
    background: vec4<f32>,
}

// A batch of a tile's splats, staged in workgroup memory by the blending kernels.
var<workgroup> batch: array<Splat, BATCH>;
// Per staged splat, its screen box in tile-local pixels (see `stage`).
var<workgroup> batch_box: array<u32, BATCH>;
// Per staged splat, the segments of the tile its ellipse reaches (see `segments_reached`).
var<workgroup> batch_reach: array<u32, BATCH>;
// Per segment of the tile (8 columns of PIXEL_ROWS rows: the pixels of 8 neighbouring
// invocations; 2 · INVOCATION_ROWS segments), which staged splats reach it: bit b of word w
// stands for slot 32·w + b (see `mark_segments`).
var<workgroup> segment_masks: array<u32, BLEND_INVOCATIONS>;
const SEGMENT_WORDS: u32 = 8u; // BATCH / 32
// The same for the whole tile: which staged splats reach any of its segments.
var<workgroup> tile_mask: array<u32, SEGMENT_WORDS>;
var<workgroup> max_slot: atomic<u32>;
var<workgroup> max_result: u32;

// The tile of a blending workgroup (one workgroup per tile) and its origin in the image.
fn tile_index(wg: vec3<u32>) -> u32 {
    return wg.y * params.tiles_x + wg.x;
}

// Tile-local pixel `row` (0 ≤ row < PIXEL_ROWS) of invocation `lid` of a blending workgroup.
fn local_pixel(lid: vec3<u32>, row: u32) -> vec2<u32> {
    return vec2<u32>(lid.x, PIXEL_ROWS * lid.y + row);
}

// Whether tile-local pixel `local` of the tile at `origin` lies inside the image (edge tiles
// overhang it).
fn inside_image(origin: vec2<u32>, local: vec2<u32>) -> bool {
    let pixel = origin + local;
    return pixel.x < params.width && pixel.y < params.height;
}

// The index of tile-local pixel `local` in row-major image buffers.
fn image_index(origin: vec2<u32>, local: vec2<u32>) -> u32 {
    let pixel = origin + local;
    return pixel.y * params.width + pixel.x;
}

// Stages the tile's sorted entries `first .. first + count` (count ≤ BATCH) in the batch,
// several per invocation. Call it between barriers.
fn stage_batch(li: u32, first: u32, count: u32, origin: vec2<u32>) {
    for (var slot = li; slot < count; slot += BLEND_INVOCATIONS) {
        stage(slot, splats[sorted_splats[first + slot]], origin);
    }
}

// The largest `value` over the workgroup, as a workgroup-uniform value (so loops may depend on
// it around barriers). Every invocation must call it.
fn workgroup_max(li: u32, value: u32) -> u32 {
    if li == 0u {
        atomicStore(&max_slot, 0u);
    }
    workgroupBarrier();
    atomicMax(&max_slot, value);
    workgroupBarrier();
    if li == 0u {
        max_result = atomicLoad(&max_slot);
    }
    return workgroupUniformLoad(&max_result);
}

// e^x for x ≤ 0 by the reference's power-of-two split and degree-6 polynomial, so GPU and CPU
// agree to rounding (WGSL's exp has implementation-defined precision).
fn exp_falloff(x: f32) -> f32 {
    let t = max(x * 1.442695041, -126.0);
    let n = round(t);
    let f = t - n;
    let p = 1.0 + f * (0.6931472 + f * (0.2402265 + f * (0.05550411
        + f * (0.009618129 + f * (0.0013333558 + f * 0.0001540353)))));
    return bitcast<f32>(u32(i32(n) + 127) << 23u) * p;
}

// Stages splat `s` in slot `slot` of the batch for the tile at `origin`, with its screen box in
// tile-local pixels, worked out once per (tile, splat) rather than per pixel: [lo, hi] per
// axis, clamped to [−1, 16] (which leaves every pixel's test as it was; a NaN bound becomes
// the open end, as a NaN comparison let the pixel through), stored as the bytes lo.x + 1,
// hi.x + 1, lo.y + 1, hi.y + 1. The pixel loops test the box (`in_box`) before they read the
// splat: most of a tile's pixels are outside most of its splats' boxes, and reading a whole
// splat from workgroup memory costs more than the test (on lavapipe the forward kernel took
// 28 % less time, the float-atomic backward 19 % less).
fn stage(slot: u32, s: Splat, origin: vec2<u32>) {
    batch[slot] = s;
    let o = vec2<f32>(origin);
    let lo_f = floor(s.mean - s.extent - 0.5 - o);
    let hi_f = ceil(s.mean + s.extent - 0.5 - o);
    let lo = select(vec2<f32>(-1.0), clamp(lo_f, vec2<f32>(-1.0), vec2<f32>(16.0)), lo_f == lo_f);
    let hi = select(vec2<f32>(16.0), clamp(hi_f, vec2<f32>(-1.0), vec2<f32>(16.0)), hi_f == hi_f);
    let lo_u = vec2<u32>(lo + 1.0);
    let hi_u = vec2<u32>(hi + 1.0);
    batch_box[slot] = lo_u.x | (hi_u.x << 8u) | (lo_u.y << 16u) | (hi_u.y << 24u);
    batch_reach[slot] = segments_reached(s, o, lo, hi);
}

// The segments of the tile (bit 2·(row / PIXEL_ROWS) + column / 8) where the splat can be
// drawn: where its box meets {power ≥ conic.w}, the ellipse outside which `falloff_at` draws
// nothing, found row by row from the roots of the quadratic in dx. Conservative, so that visiting only these
// segments draws what testing every pixel would: the discriminant is widened by far more than
// rounding can move it, the span by a pixel each side, and a NaN falls back to the box.
fn segments_reached(s: Splat, o: vec2<f32>, lo: vec2<f32>, hi: vec2<f32>) -> u32 {
    let a = s.conic.x;
    let b = s.conic.y;
    let c = s.conic.z;
    let w = s.conic.w;
    // The tile-local column whose pixel centre lies at the mean.
    let centre = s.mean.x - o.x - 0.5;
    var bits = 0u;
    for (var row = 0u; row < TILE; row++) {
        let y = f32(row);
        if y < lo.y || y > hi.y {
            continue;
        }
        let dy = o.y + y + 0.5 - s.mean.y;
        // power ≥ w  ⟺  0.5·a·dx² + b·dy·dx + 0.5·c·dy² + w ≤ 0.
        let bb = b * b * dy * dy;
        let ac = a * c * dy * dy;
        let disc = bb - ac - 2.0 * a * w + 1e-3 * (bb + abs(ac) + abs(2.0 * a * w));
        if disc < 0.0 {
            continue;
        }
        let r = sqrt(disc);
        var span_lo = floor(centre + (-b * dy - r) / a) - 1.0;
        var span_hi = ceil(centre + (-b * dy + r) / a) + 1.0;
        if !(a > 0.0) || disc != disc || span_lo != span_lo || span_hi != span_hi {
            span_lo = -1.0;
            span_hi = 16.0;
        }
        span_lo = max(span_lo, lo.x);
        span_hi = min(span_hi, hi.x);
        if span_lo <= span_hi {
            let first_bit = 2u * (row / PIXEL_ROWS);
            bits |= select(0u, 1u << first_bit, span_lo <= 7.0 && span_hi >= 0.0);
            bits |= select(0u, 2u << first_bit, span_lo <= 15.0 && span_hi >= 8.0);
        }
    }
    return bits;
}

// Whether tile-local pixel `local` lies in a staged splat's packed screen box (`stage`).
fn in_box(box: u32, local: vec2<u32>) -> bool {
    let l = local + 1u;
    return l.x >= (box & 0xffu) && l.x <= ((box >> 8u) & 0xffu)
        && l.y >= ((box >> 16u) & 0xffu) && l.y <= (box >> 24u);
}

// Fills `segment_masks` and `tile_mask` for the `count` splats of the batch: call it between
// the barrier that follows the staging and another barrier. Invocation li builds word li % 8
// of segment li / 8 from 32 splats' reach (the first 8 invocations, whose words cover every
// slot once, also the tile's word), so the pixel loops visit only the slots that can draw in
// their segment instead of testing every slot at every pixel.
fn mark_segments(li: u32, count: u32) {
    let segment = li / SEGMENT_WORDS;
    let first = (li % SEGMENT_WORDS) * 32u;
    var bits = 0u;
    var reached = 0u;
    for (var b = 0u; b < min(32u, max(count, first) - first); b++) {
        let reach = batch_reach[first + b];
        bits |= ((reach >> segment) & 1u) << b;
        reached |= select(0u, 1u << b, reach != 0u);
    }
    segment_masks[li] = bits;
    if li < SEGMENT_WORDS {
        tile_mask[li] = reached;
    }
}

// Index in `segment_masks` of the first word of the segment of invocation `lid`'s pixels.
fn segment_of(lid: vec3<u32>) -> u32 {
    return (lid.y * 2u + lid.x / 8u) * SEGMENT_WORDS;
}

// The bits of word `w` of a segment mask that stand for one of the first `n` slots.
fn slot_bits(w: u32, n: u32) -> u32 {
    let m = u32(clamp(i32(n) - i32(32u * w), 0, 32));
    return select((1u << m) - 1u, 0xffffffffu, m == 32u);
}

// (dx, dy, G, drawn) of splat `s` at tile-local pixel `local` of the tile at `origin`, a pixel
// inside the splat's screen box (`in_box`): drawn is 1 where opacity·G ≥ 1/255, as in the
// reference's `falloff_at`.
fn falloff_at(s: Splat, origin: vec2<u32>, local: vec2<u32>) -> vec4<f32> {
    let d = vec2<f32>(origin + local) + 0.5 - s.mean;
    let pw = -0.5 * (s.conic.x * d.x * d.x + s.conic.z * d.y * d.y) - s.conic.y * d.x * d.y;
    if pw > 0.0 || pw < s.conic.w {
        return vec4<f32>(0.0);
    }
    let g = exp_falloff(pw);
    if s.color.w * g < ALPHA_MIN {
        return vec4<f32>(0.0);
    }
    return vec4<f32>(d, g, 1.0);
}
