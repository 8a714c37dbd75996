// One Adam step on a parameter group stored as flat f32 arrays (systems/adam.rs::adam_step):
// element i has the learning-rate slot i % stride (the component's field layout). The host
// passes the step size of each slot already divided by the bias correction 1 − β1^step, and
// the constants as the CPU computes them in f32.

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
    let g = grads[i];
    let m_i = params.beta1 * m[i] + params.one_minus_beta1 * g;
    let v_i = params.beta2 * v[i] + params.one_minus_beta2 * g * g;
    m[i] = m_i;
    v[i] = v_i;
    let step_size = step_sizes[i % params.stride];
    values[i] -= step_size * m_i / (sqrt(v_i / params.bias2) + params.epsilon);
}
