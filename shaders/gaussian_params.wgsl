// Shared by deform.wgsl and param_backward.wgsl: the parameter and warped-time bindings and
// the load of one Gaussian's parameters from the structure-of-arrays layout described in
// gaussian_common.wgsl.

@group(0) @binding(1) var<storage, read> params: array<f32>;
@group(0) @binding(2) var<storage, read> warped: array<f32>;

// One Gaussian's parameter components (src/components.rs), quaternions as (w, x, y, z).
struct Gaussian {
    mean: vec3<f32>,
    fourier_cos: array<vec3<f32>, 4>,
    fourier_sin: array<vec3<f32>, 4>,
    phase: vec4<f32>,
    temporal_center: f32,
    temporal_scale: vec2<f32>,
    logit: f32,
    c0: vec4<f32>,
    c1: vec4<f32>,
    d0: vec3<f32>,
    d1: vec3<f32>,
    sh: array<vec3<f32>, 16>,
}

// Index of value k of Gaussian i in the component section at `prefix` with `width` values.
fn param_index(i: u32, prefix: u32, width: u32, k: u32) -> u32 {
    return frame.count * prefix + i * width + k;
}

fn param_vec3(i: u32, prefix: u32, width: u32, k: u32) -> vec3<f32> {
    let at = param_index(i, prefix, width, k);
    return vec3<f32>(params[at], params[at + 1u], params[at + 2u]);
}

fn param_vec4(i: u32, prefix: u32, width: u32, k: u32) -> vec4<f32> {
    let at = param_index(i, prefix, width, k);
    return vec4<f32>(params[at], params[at + 1u], params[at + 2u], params[at + 3u]);
}

fn load_gaussian(i: u32) -> Gaussian {
    var g: Gaussian;
    g.mean = param_vec3(i, PREFIX_POSITION, WIDTH_POSITION, 0u);
    for (var f = 0u; f < FOURIER_TERMS; f++) {
        g.fourier_cos[f] = param_vec3(i, PREFIX_FOURIER, WIDTH_FOURIER, 3u * f);
        g.fourier_sin[f] = param_vec3(i, PREFIX_FOURIER, WIDTH_FOURIER, 12u + 3u * f);
    }
    g.phase = param_vec4(i, PREFIX_FOURIER, WIDTH_FOURIER, 24u);
    let temporal = param_vec3(i, PREFIX_TEMPORAL, WIDTH_TEMPORAL, 0u);
    g.temporal_center = temporal.x;
    g.temporal_scale = temporal.yz;
    g.logit = params[param_index(i, PREFIX_OPACITY, WIDTH_OPACITY, 0u)];
    g.c0 = param_vec4(i, PREFIX_ROTATION, WIDTH_ROTATION, 0u);
    g.c1 = param_vec4(i, PREFIX_ROTATION, WIDTH_ROTATION, 4u);
    g.d0 = param_vec3(i, PREFIX_SCALE, WIDTH_SCALE, 0u);
    g.d1 = param_vec3(i, PREFIX_SCALE, WIDTH_SCALE, 3u);
    // Only the coefficients of the degree in use are read; the rest stay zero.
    let count = sh_count(frame.sh_degree);
    for (var k = 0u; k < count; k++) {
        g.sh[k] = param_vec3(i, PREFIX_COLOR, WIDTH_COLOR, 3u * k);
    }
    return g;
}

// The warped offset Δt' = W(t − t_i) of Gaussian i.
fn warped_dtw(i: u32) -> f32 {
    return warped[i * WARPED_STRIDE + 1u];
}

// Motion offset μ(t) − μ (src/model/deform.rs::fourier_offset).
fn fourier_offset(g: Gaussian, dtw: f32) -> vec3<f32> {
    var cos_terms = g.fourier_cos;
    var sin_terms = g.fourier_sin;
    let shared_phase = (frame.flags & FLAG_SHARED_PHASE) != 0u;
    var out = vec3<f32>(0.0);
    for (var f = 0u; f < FOURIER_TERMS; f++) {
        let sc = sin_cos(fourier_angle(f, dtw, g.phase, shared_phase));
        out += cos_terms[f] * sc.y + sin_terms[f] * sc.x;
    }
    return out;
}
