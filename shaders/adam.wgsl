// One Adam step on a parameter group stored as flat f32 arrays (systems/adam.rs::adam_step):
// element i has the learning-rate slot i % stride (the component's field layout). The host
// passes the step size of each slot already divided by the bias correction 1 − β1^step, and
// the constants as the CPU computes them in f32. Element i of the step is element
// `offset + i` of the bound arrays, so one call can update a section of a larger buffer (the
// resident parameters of src/gpu/pipeline.rs); the slot is still i % stride.

struct AdamParams {
    len: u32,
    stride: u32,
    beta1: f32,
    beta2: f32,
    // 1 − β1 and 1 − β2, rounded to f32 as on the CPU.
    one_minus_beta1: f32,
    one_minus_beta2: f32,
    // 1 − β2^step.
    bias2: f32,
    epsilon: f32,
    offset: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

@group(0) @binding(0) var<uniform> params: AdamParams;
@group(0) @binding(1) var<storage, read> step_sizes: array<f32>;
@group(0) @binding(2) var<storage, read> grads: array<f32>;
@group(0) @binding(3) var<storage, read_write> values: array<f32>;
@group(0) @binding(4) var<storage, read_write> m: array<f32>;
@group(0) @binding(5) var<storage, read_write> v: array<f32>;

@compute @workgroup_size(256)
fn adam(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = (wid.y * groups.x + wid.x) * 256u + lid;
    if i >= params.len {
        return;
    }
    let j = params.offset + i;
    let g = grads[j];
    let m_i = params.beta1 * m[j] + params.one_minus_beta1 * g;
    let v_i = params.beta2 * v[j] + params.one_minus_beta2 * g * g;
    m[j] = m_i;
    v[j] = v_i;
    let step_size = step_sizes[i % params.stride];
    values[j] -= step_size * m_i / (sqrt(v_i / params.bias2) + params.epsilon);
}
