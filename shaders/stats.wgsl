// Densification statistics of one view (systems/densify.rs::accumulate_stats), one invocation
// per splat slot: a visible splat or a faded one (`visible` 2, marked only when the baseline
// counts them; its σ(t) and gradient read 0), with a minimum only where σ(t) exceeds it, adds its
// gradient norm weighted by σ(t) (VAD) or 1, the weight, its normalised lifespan ψ̄
// (model/deform.rs::lifespan_fraction through the inverse time warp of model/warp.rs), one to
// the count, the gradient-weighted offset of the view's time from the centre, and raises the
// largest screen radius.

struct SplatBox {
    mean: vec2<f32>,
    extent: vec2<f32>,
    depth: f32,
    visible: u32,
}

// The Temporal component: centre t_i and the raw temporal scale.
struct Temporal {
    center: f32,
    scale0: f32,
    scale1: f32,
}

// The GradAccum component.
struct GradAccum {
    weighted_grad: f32,
    weight: f32,
    lifespan_sum: f32,
    count: u32,
    max_radius: f32,
    weighted_offset: f32,
}

struct StatsParams {
    count: u32,
    vad: u32,
    has_min_opacity: u32,
    min_opacity: f32,
    // 0: Rbf; 1: Asymmetric with smallest width w_min.
    model: u32,
    w_min: f32,
    // sqrt(2 ln 5), as the CPU rounds it.
    asymmetric_k: f32,
    // 0: identity; 1: TOW with (rho, s_near, s_far).
    warp: u32,
    rho: f32,
    s_near: f32,
    s_far: f32,
    lambda: f32,
    // The view's normalised time t (for Σw·g·(t − t_i)).
    time: f32,
    // 1: a Gaussian centred at t_i ≤ 0 (≥ 1) has the whole window on the sequence's side.
    one_sided_ends: u32,
    // 1: the warp's corners are rounded (TimeWarp's `smooth`).
    smooth_corners: u32,
}

const LN_5: f32 = 1.609438;
// model/warp.rs's SMOOTH_INVERSE_STEPS.
const SMOOTH_INVERSE_STEPS: u32 = 40u;
const ASYMMETRIC_MAX_WIDTH: f32 = 1.1;
// exp() arguments are capped here so that they stay finite (e^80 ≈ 5.5e34); the CPU's
// infinities give the same lifespans.
const EXP_CAP: f32 = 80.0;

@group(0) @binding(0) var<uniform> params: StatsParams;
@group(0) @binding(1) var<storage, read> splats: array<SplatBox>;
@group(0) @binding(2) var<storage, read> opacity: array<f32>;
@group(0) @binding(3) var<storage, read> grad_norm: array<f32>;
@group(0) @binding(4) var<storage, read> temporal: array<Temporal>;
@group(0) @binding(5) var<storage, read_write> accum: array<GradAccum>;

// The fraction of the window on one side (`right`: Δt ≥ 0) of a Gaussian centred at
// `center` (TimeWarp::window_fraction).
fn window_fraction(center: f32, right: bool) -> f32 {
    if params.one_sided_ends == 1u && (center <= 0.0 || center >= 1.0) {
        return select(0.0, 1.0, right == (center <= 0.0));
    }
    return 0.5;
}

// |W⁻¹| of a warped offset w ≥ 0 on the side of the window holding `fraction` of it
// (TimeWarp::inverse).
fn warp_inverse(w: f32, fraction: f32) -> f32 {
    if params.warp == 0u {
        return w;
    }
    let e = fraction * params.lambda;
    var x = e + (w - fraction * params.rho) / params.s_far;
    if w <= fraction * params.rho {
        x = w / params.s_near;
    }
    if params.smooth_corners == 1u && e > 0.0 {
        // Newton from the piecewise-linear inverse, as model/warp.rs does (tanh's argument
        // capped: tanh(20) is 1 in f32, and a large one may overflow inside tanh).
        for (var i = 0u; i < SMOOTH_INVERSE_STEPS; i++) {
            let th = tanh(min(x / e, 20.0));
            let value = params.s_far * x + (params.s_near - params.s_far) * e * th;
            let slope = params.s_far + (params.s_near - params.s_far) * (1.0 - th * th);
            let step = (value - w) / slope;
            x -= step;
            if abs(step) <= 1e-7 * max(x, 1.0) {
                break;
            }
        }
    }
    return x;
}

// min(w_min · e^raw, 1.1).
fn asymmetric_width(raw: f32) -> f32 {
    let w = params.w_min * exp(min(raw, EXP_CAP));
    if w > ASYMMETRIC_MAX_WIDTH {
        return ASYMMETRIC_MAX_WIDTH;
    }
    return w;
}

// ψ̄: the length of {t ∈ [0, 1] : σ(t)/σ^s > 0.2}.
fn lifespan_fraction(t: Temporal) -> f32 {
    var a_left: f32;
    var a_right: f32;
    if params.model == 0u {
        // sqrt(ln 5 / ψ), ψ = e^raw.
        let a = sqrt(LN_5 * exp(min(-t.scale0, EXP_CAP)));
        a_left = a;
        a_right = a;
    } else {
        a_left = asymmetric_width(t.scale0) * params.asymmetric_k;
        a_right = asymmetric_width(t.scale1) * params.asymmetric_k;
    }
    let lo = max(t.center - warp_inverse(a_left, window_fraction(t.center, false)), 0.0);
    let hi = min(t.center + warp_inverse(a_right, window_fraction(t.center, true)), 1.0);
    return clamp(hi - lo, 0.0, 1.0);
}

@compute @workgroup_size(256)
fn accumulate_stats(
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = (wid.y * groups.x + wid.x) * 256u + lid;
    if i >= params.count {
        return;
    }
    let b = splats[i];
    let sigma = opacity[i];
    if b.visible == 0u || (params.has_min_opacity != 0u && sigma <= params.min_opacity) {
        return;
    }
    var weight = 1.0;
    if params.vad != 0u {
        weight = sigma;
    }
    var a = accum[i];
    let g = grad_norm[i];
    a.weighted_offset += weight * g * (params.time - temporal[i].center);
    a.weighted_grad += weight * g;
    a.weight += weight;
    a.lifespan_sum += lifespan_fraction(temporal[i]);
    a.count += 1u;
    a.max_radius = max(a.max_radius, max(b.extent.x, b.extent.y));
    accum[i] = a;
}
