// Glue of the GPU-resident training pipeline (src/gpu/pipeline.rs).
//
// `pack`: the projected splats of `project.wgsl` (16 floats each: mean 2, extent 2, conic 3,
// depth, colour 3, opacity, visible, faded, padding) → the binner's and the statistics'
// `SplatBox` records (mean 2, extent 2, depth, visible: 1 drawn, 2 faded, else 0), the
// rasterizer's splats (mean 2, extent 2, conic 3, the exponent cut-off
// ln(ALPHA_MIN / opacity) − 1e-4, colour 3, opacity) and σ(t) per splat, as
// `crate::raster::min_power` and `crate::gpu::sort::SplatBox::from` compute them.
//
// `check`: the smallest flat index of a non-finite value in the parameter gradients, by an
// atomic minimum into `fault[0]` (which the host sets to 0xffffffff first), one quad of
// gradients per invocation.

const ALPHA_MIN: f32 = 0.003921569; // 1/255
const NO_FAULT: u32 = 0xffffffffu;

struct PipelineParams {
    count: u32,
    grad_len: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> params: PipelineParams;
// Read and written in vectors: on lavapipe every access of storage memory at a per-invocation
// address is a loop over the SIMD lanes, one loop for all components of a vector.
@group(0) @binding(1) var<storage, read> splats: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read_write> boxes: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read_write> raster_splats: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> opacity: array<f32>;
// Bound rounded up to whole quads; elements from `params.grad_len` on are not checked.
@group(0) @binding(5) var<storage, read> grads: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read_write> fault: array<atomic<u32>>;

fn flat_index(lid: u32, wid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return (wid.y * groups.x + wid.x) * 256u + lid;
}

@compute @workgroup_size(256)
fn pack(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = flat_index(lid, wid, groups);
    if i >= params.count {
        return;
    }
    // The projected splat's quads: mean, extent; conic, depth; colour, opacity; visible, faded.
    let a = splats[4u * i];
    let b = splats[4u * i + 1u];
    let c = splats[4u * i + 2u];
    let d = splats[4u * i + 3u];
    let visible = d.x != 0.0;
    let faded = d.y != 0.0;
    boxes[3u * i] = bitcast<vec2<u32>>(a.xy);
    boxes[3u * i + 1u] = bitcast<vec2<u32>>(a.zw);
    boxes[3u * i + 2u] = vec2(bitcast<u32>(b.w), select(select(0u, 2u, faded), 1u, visible));
    let alpha = c.w;
    raster_splats[3u * i] = a;
    raster_splats[3u * i + 1u] = vec4(b.xyz, log(ALPHA_MIN / alpha) - 1e-4);
    raster_splats[3u * i + 2u] = vec4(c.xyz, alpha);
    opacity[i] = alpha;
}

@compute @workgroup_size(256)
fn check(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let quad = flat_index(lid, wid, groups);
    let element = vec4<u32>(4u * quad) + vec4<u32>(0u, 1u, 2u, 3u);
    if element.x >= params.grad_len {
        return;
    }
    let bits = bitcast<vec4<u32>>(grads[quad]);
    let bad = (bits & vec4(0x7f800000u)) == vec4(0x7f800000u) & element < vec4(params.grad_len);
    if any(bad) {
        // The quad's first non-finite element.
        let found = select(vec4(NO_FAULT), element, bad);
        atomicMin(&fault[0], min(min(found.x, found.y), min(found.z, found.w)));
    }
}
