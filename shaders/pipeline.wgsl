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
// atomic minimum into `fault[0]` (which the host sets to 0xffffffff first).

const ALPHA_MIN: f32 = 0.003921569; // 1/255

struct PipelineParams {
    count: u32,
    grad_len: u32,
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> params: PipelineParams;
@group(0) @binding(1) var<storage, read> splats: array<f32>;
@group(0) @binding(2) var<storage, read_write> boxes: array<u32>;
@group(0) @binding(3) var<storage, read_write> raster_splats: array<f32>;
@group(0) @binding(4) var<storage, read_write> opacity: array<f32>;
@group(0) @binding(5) var<storage, read> grads: array<f32>;
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
    let s = i * 16u;
    let b = i * 6u;
    for (var k = 0u; k < 4u; k++) {
        boxes[b + k] = bitcast<u32>(splats[s + k]);
    }
    boxes[b + 4u] = bitcast<u32>(splats[s + 7u]);
    let visible = splats[s + 12u] != 0.0;
    let faded = splats[s + 13u] != 0.0;
    boxes[b + 5u] = select(select(0u, 2u, faded), 1u, visible);
    let r = i * 12u;
    let alpha = splats[s + 11u];
    for (var k = 0u; k < 7u; k++) {
        raster_splats[r + k] = splats[s + k];
    }
    raster_splats[r + 7u] = log(ALPHA_MIN / alpha) - 1e-4;
    raster_splats[r + 8u] = splats[s + 8u];
    raster_splats[r + 9u] = splats[s + 9u];
    raster_splats[r + 10u] = splats[s + 10u];
    raster_splats[r + 11u] = alpha;
    opacity[i] = alpha;
}

@compute @workgroup_size(256)
fn check(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = flat_index(lid, wid, groups);
    if i >= params.grad_len {
        return;
    }
    let bits = bitcast<u32>(grads[i]);
    if (bits & 0x7f800000u) == 0x7f800000u {
        atomicMin(&fault[0], i);
    }
}
