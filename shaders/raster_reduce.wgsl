// Sums each splat's per-entry partial gradients (one per tile it covers) into one gradient.

@group(0) @binding(0) var<storage, read> splat_offsets: array<u32>;
@group(0) @binding(1) var<storage, read> sorted_position: array<u32>;
@group(0) @binding(2) var<storage, read> entry_grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> splat_grads: array<f32>;

const FIELDS: u32 = 9u;

@compute @workgroup_size(256)
fn reduce(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let s = gid.y * groups.x * 256u + gid.x;
    if s + 1u >= arrayLength(&splat_offsets) {
        return;
    }
    var sum: array<f32, 9>;
    for (var e = splat_offsets[s]; e < splat_offsets[s + 1u]; e++) {
        let k = sorted_position[e];
        for (var field = 0u; field < FIELDS; field++) {
            sum[field] += entry_grads[FIELDS * k + field];
        }
    }
    for (var field = 0u; field < FIELDS; field++) {
        splat_grads[FIELDS * s + field] = sum[field];
    }
}
