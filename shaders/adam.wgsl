// One Adam step on a parameter group stored as flat f32 arrays (systems/adam.rs::adam_step):
// element i has the learning-rate slot i % stride (the component's field layout). The host
// passes the step size of each slot already divided by the bias correction 1 − β1^step (in the
// uniform block: on lavapipe a uniform read at a per-invocation index is one gather, where a
// storage read is a loop over the SIMD lanes), and
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
    // step_sizes[slot / 4][slot % 4]: MAX_STRIDE slots (uniform arrays have a 16-byte stride).
    step_sizes: array<vec4<f32>, 64>,
}

@group(0) @binding(0) var<uniform> params: AdamParams;
// Read and written four values at a time: on lavapipe every access of storage memory is a loop
// over the SIMD lanes, one loop for all components of a vector, so a quad costs about what one
// value did. The bindings cover the quads that hold elements offset .. offset + len.
@group(0) @binding(2) var<storage, read> grads: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> values: array<vec4<f32>>;
@group(0) @binding(4) var<storage, read_write> m: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> v: array<vec4<f32>>;

fn step_size_at(slot: u32) -> f32 {
    return params.step_sizes[slot / 4u][slot % 4u];
}

// One quad of elements per invocation: the quads from the one holding element `offset` to the
// one holding the last. Elements of a quad outside offset .. offset + len (the neighbouring
// sections of the resident buffers) are written back as they were read.
@compute @workgroup_size(256)
fn adam(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let quad = params.offset / 4u + (wid.y * groups.x + wid.x) * 256u + lid;
    let end = params.offset + params.len;
    if 4u * quad >= end {
        return;
    }
    let element = vec4<u32>(4u * quad) + vec4<u32>(0u, 1u, 2u, 3u);
    let inside = element >= vec4<u32>(params.offset) & element < vec4<u32>(end);
    // The step's own index of each element gives its learning-rate slot (any slot for the
    // elements outside, which keep their values): one division for the quad's last element
    // (never before `offset`), the three before it at most three strides back (stride 1).
    let last = (element.w - params.offset) % params.stride;
    let stride = vec3<u32>(params.stride);
    var before = vec3<u32>(last) + 3u * stride - vec3<u32>(3u, 2u, 1u);
    for (var k = 0u; k < 3u; k++) {
        before = select(before, before - stride, before >= stride);
    }
    let slot = vec4<u32>(before, last);
    let step_size = vec4<f32>(
        step_size_at(slot.x), step_size_at(slot.y), step_size_at(slot.z), step_size_at(slot.w),
    );
    let g = grads[quad];
    let m_old = m[quad];
    let v_old = v[quad];
    let value = values[quad];
    let m_new = params.beta1 * m_old + params.one_minus_beta1 * g;
    let v_new = params.beta2 * v_old + params.one_minus_beta2 * g * g;
    m[quad] = select(m_old, m_new, inside);
    v[quad] = select(v_old, v_new, inside);
    let stepped = value - step_size * m_new / (sqrt(v_new / params.bias2) + params.epsilon);
    values[quad] = select(value, stepped, inside);
}
