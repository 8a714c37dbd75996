// Shared by the per-Gaussian kernels (deform.wgsl, project.wgsl, param_backward.wgsl): the
// buffer layouts, the frame uniform, and the forward maths of src/model/ (deform.rs, sh.rs,
// project.rs) written operation for operation like the CPU reference, so the kernels agree
// with it to f32 rounding. Each kernel is param_layout.wgsl (the parameter sections' WIDTH_,
// PREFIX_ and OFFSET_ constants, generated from the declaration in src/components.rs), this
// file, optionally gaussian_params.wgsl, and its own file, concatenated (src/gpu/deform.rs).
//
// Buffer layouts (all `array<f32>`; N = frame.count Gaussians):
// - params (and grads, same layout): structure of arrays by section. Section c occupies
//   [N·PREFIX_c, N·(PREFIX_c + WIDTH_c)), Gaussian i's values at N·PREFIX_c + i·WIDTH_c, in
//   the field order of the #[repr(C)] components in src/components.rs:
//     Position 3 | Fourier 28 (cos 4×3, sin 4×3, phase 4) | Temporal 3 (center, scale 2) |
//     Opacity 1 | Rotation 8 (c0 wxyz, c1 wxyz) | Scale 6 (d0, d1) |
//     Color 48 (Color: sh 0, then ColorRest: sh 1–15, each ×3)
//   so each section is a byte-for-byte copy of a slice of its components.
// - warped: WarpedTime records (dt, dtw), stride 2.
// - deformed: Deformed records (mean 3, rotation 4, scale 3, opacity, color 3), stride 14.
// - splats: stride 16: mean2d 2, extent 2, conic 3, depth, color 3, opacity, visible (1 or 0),
//   faded (1 when culled but inside the 3σ frustum test, under FLAG_MARK_FADED; else 0),
//   2 unused. An invisible splat is all zeros (the CPU's Splat::default()) but for `faded`.
// - splat_grads: stride 9, the rasterizer's per-splat gradient layout (src/gpu/raster.rs):
//   d mean2d 2, d conic 3, d opacity, d color 3.
// - ndc_grad_norm: one f32 per Gaussian.

const WORKGROUP: u32 = 64u;

const WARPED_STRIDE: u32 = 2u;
const DEFORMED_STRIDE: u32 = 14u;
const SPLAT_STRIDE: u32 = 16u;
const SPLAT_GRAD_STRIDE: u32 = 9u;

const FLAG_SHARED_PHASE: u32 = 1u;
const FLAG_SCALE_MOTION: u32 = 2u;
// Mark the culled splats that the 3σ frustum test keeps (the baseline's statistics).
const FLAG_MARK_FADED: u32 = 4u;
const OPACITY_RBF: u32 = 0u;

// f32::MIN_POSITIVE (smallest normal).
const MIN_POSITIVE: f32 = 1.17549435e-38;
// 2π as the CPU's f32 TAU, and split for the range reduction of sin_cos: TAU_HI has few
// mantissa bits so k·TAU_HI is exact for small integers k.
const TAU: f32 = 6.2831855;
const INV_TAU: f32 = 0.15915494;
const TAU_HI: f32 = 6.28125;
const TAU_LO: f32 = 0.0019353071795864769;

// SH constants of src/model/sh.rs.
const SH_C0: f32 = 0.28209479177387814;
const SH_C1: f32 = 0.4886025119029199;
const SH_C2_0: f32 = 1.0925484305920792;
const SH_C2_1: f32 = -1.0925484305920792;
const SH_C2_2: f32 = 0.31539156525252005;
const SH_C2_3: f32 = -1.0925484305920792;
const SH_C2_4: f32 = 0.5462742152960396;
const SH_C3_0: f32 = -0.5900435899266435;
const SH_C3_1: f32 = 2.890611442640554;
const SH_C3_2: f32 = -0.4570457994644658;
const SH_C3_3: f32 = 0.3731763325901154;
const SH_C3_4: f32 = -0.4570457994644658;
const SH_C3_5: f32 = 1.445305721320277;
const SH_C3_6: f32 = -0.5900435899266435;

// The camera and the model settings of one view (`FrameUniform` in src/gpu/deform.rs).
struct Frame {
    // Columns of the world-to-camera rotation W (xyz).
    rotation0: vec4<f32>,
    rotation1: vec4<f32>,
    rotation2: vec4<f32>,
    // World-to-camera translation (xyz).
    translation: vec4<f32>,
    // Camera centre in world space (xyz), as Camera::center().
    eye: vec4<f32>,
    // fx, fy, cx, cy.
    focal: vec4<f32>,
    // width, height, and the Jacobian's clamp limits lim_x, lim_y on x/z and y/z.
    view: vec4<f32>,
    // near plane (already ≥ NEAR_PLANE), minimum opacity 1/255, low-pass dilation 0.3, unused.
    cull: vec4<f32>,
    // Asymmetric temporal opacity: w_min and the largest width 1.1; 1 / the motion period; unused.
    temporal: vec4<f32>,
    count: u32,
    sh_degree: u32,
    flags: u32,
    opacity_model: u32,
}

@group(0) @binding(0) var<uniform> frame: Frame;

// The Gaussian of invocation `gid` of a (possibly 2D) dispatch of WORKGROUP-wide groups.
fn gaussian_index(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.y * groups.x * WORKGROUP + gid.x;
}

fn camera_rotation() -> mat3x3<f32> {
    return mat3x3<f32>(frame.rotation0.xyz, frame.rotation1.xyz, frame.rotation2.xyz);
}

// Dot products summed left to right, as glam and the reference's dot4.
fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn dot4(a: vec4<f32>, b: vec4<f32>) -> f32 {
    return a.x * b.x + a.y * b.y + a.z * b.z + a.w * b.w;
}

// M·v as glam computes it: column 0·v.x + column 1·v.y + column 2·v.z.
fn mat_vec(m: mat3x3<f32>, v: vec3<f32>) -> vec3<f32> {
    return m[0] * v.x + m[1] * v.y + m[2] * v.z;
}

// Mᵀ·v: (column i · v) per row.
fn mat_t_vec(m: mat3x3<f32>, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot3(m[0], v), dot3(m[1], v), dot3(m[2], v));
}

// ---- Deformation (src/model/deform.rs) ----

// sin and cos of `angle` after reducing it to about [−π, π] (driver sin/cos are only accurate
// there); the reduction adds about 1e-7 absolute error for the angles of the motion model.
fn sin_cos(angle: f32) -> vec2<f32> {
    let k = round(angle * INV_TAU);
    let r = (angle - k * TAU_HI) - k * TAU_LO;
    return vec2<f32>(sin(r), cos(r));
}

// Angle 2π(f + 1)·dtw/P + φ_f of frequency f (0-based), φ_f = phase[0] when shared, P the
// motion period (MotionBasis::angle).
fn fourier_angle(f: u32, dtw: f32, phase: vec4<f32>, shared_phase: bool) -> f32 {
    var ph = phase;
    let p = select(ph[f], ph[0], shared_phase);
    return TAU * f32(f + 1u) * dtw * frame.temporal.z + p;
}

// Logistic sigmoid, stable for large |x| (src/model/deform.rs::sigmoid).
fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        return 1.0 / (1.0 + exp(-x));
    }
    let e = exp(x);
    return e / (1.0 + e);
}

// σ(t)/σ^s and the derivative of its exponent with respect to raw[index]
// (src/model/deform.rs::temporal_factor).
struct TemporalFactor {
    factor: f32,
    index: u32,
    d_exponent: f32,
}

fn temporal_factor(raw: vec2<f32>, dtw: f32) -> TemporalFactor {
    if frame.opacity_model == OPACITY_RBF {
        let psi = exp(raw.x);
        let e = -psi * dtw * dtw;
        return TemporalFactor(exp(e), 0u, e);
    }
    let side = select(0u, 1u, dtw >= 0.0);
    var r = raw;
    var w = frame.temporal.x * exp(r[side]);
    let clamped = w > frame.temporal.y;
    if clamped {
        w = frame.temporal.y;
    }
    let r2 = (dtw / w) * (dtw / w);
    // exp(−(dtw/w)²), as the authors' implementation; d exponent / ds = 2 r².
    return TemporalFactor(exp(-r2), side, select(2.0 * r2, 0.0, clamped));
}

fn raw_rotation(c0: vec4<f32>, c1: vec4<f32>, dtw: f32) -> vec4<f32> {
    return c0 + c1 * dtw;
}

// q = normalise(c0 + c1·dtw), identity for a zero quaternion.
fn rotation_at(c0: vec4<f32>, c1: vec4<f32>, dtw: f32) -> vec4<f32> {
    let q = raw_rotation(c0, c1, dtw);
    let n2 = dot4(q, q);
    if n2 <= MIN_POSITIVE {
        return vec4<f32>(1.0, 0.0, 0.0, 0.0);
    }
    let inv = 1.0 / sqrt(n2);
    return q * inv;
}

// The log-scale velocity in use: d1, or zero without scale motion.
fn scale_velocity(d1: vec3<f32>) -> vec3<f32> {
    return select(vec3<f32>(0.0), d1, (frame.flags & FLAG_SCALE_MOTION) != 0u);
}

fn scale_at(d0: vec3<f32>, d1: vec3<f32>, dtw: f32) -> vec3<f32> {
    return exp(d0 + d1 * dtw);
}

// ---- Spherical harmonics (src/model/sh.rs) ----

// (degree + 1)² coefficients, degree clamped to 3.
fn sh_count(degree: u32) -> u32 {
    let d = min(degree, 3u) + 1u;
    return d * d;
}

// Unit direction (xyz) and 1/length (w); a zero direction maps to +z with 1/length 0.
fn sh_unit(dir: vec3<f32>) -> vec4<f32> {
    let len2 = dot3(dir, dir);
    if len2 > MIN_POSITIVE {
        let inv = 1.0 / sqrt(len2);
        return vec4<f32>(dir * inv, inv);
    }
    return vec4<f32>(0.0, 0.0, 1.0, 0.0);
}

fn sh_basis(count: u32, n: vec3<f32>) -> array<f32, 16> {
    let x = n.x;
    let y = n.y;
    let z = n.z;
    var b: array<f32, 16>;
    b[0] = SH_C0;
    if count > 1u {
        b[1] = -SH_C1 * y;
        b[2] = SH_C1 * z;
        b[3] = -SH_C1 * x;
    }
    if count > 4u {
        let xx = x * x;
        let yy = y * y;
        let zz = z * z;
        b[4] = SH_C2_0 * x * y;
        b[5] = SH_C2_1 * y * z;
        b[6] = SH_C2_2 * (2.0 * zz - xx - yy);
        b[7] = SH_C2_3 * x * z;
        b[8] = SH_C2_4 * (xx - yy);
        if count > 9u {
            b[9] = SH_C3_0 * y * (3.0 * xx - yy);
            b[10] = SH_C3_1 * x * y * z;
            b[11] = SH_C3_2 * y * (4.0 * zz - xx - yy);
            b[12] = SH_C3_3 * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            b[13] = SH_C3_4 * x * (4.0 * zz - xx - yy);
            b[14] = SH_C3_5 * z * (xx - yy);
            b[15] = SH_C3_6 * x * (xx - 3.0 * yy);
        }
    }
    return b;
}

// Σ basis·coeff + 0.5 before the clamp, summed coefficient by coefficient.
fn sh_raw_rgb(count: u32, sh: array<vec3<f32>, 16>, basis: array<f32, 16>) -> vec3<f32> {
    var coeffs = sh;
    var b = basis;
    var rgb = vec3<f32>(0.5);
    for (var k = 0u; k < count; k++) {
        rgb += b[k] * coeffs[k];
    }
    return rgb;
}

// ---- EWA projection (src/model/project.rs) ----

// Rotation matrix of a quaternion (w, x, y, z), applied as is.
fn quat_to_rotation(q: vec4<f32>) -> mat3x3<f32> {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    return mat3x3<f32>(
        vec3<f32>(1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y + w * z), 2.0 * (x * z - w * y)),
        vec3<f32>(2.0 * (x * y - w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z + w * x)),
        vec3<f32>(2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)),
    );
}

// M = R·diag(scale), column by column.
fn scaled_rotation(r: mat3x3<f32>, scale: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(r[0] * scale.x, r[1] * scale.y, r[2] * scale.z);
}

// A·Bᵀ... for the covariance: entry (i, j) of M·Mᵀ is Σ_k M_ik M_jk.
fn mul_transpose(m: mat3x3<f32>) -> mat3x3<f32> {
    let mt = transpose(m);
    return mat3x3<f32>(mat_vec(m, mt[0]), mat_vec(m, mt[1]), mat_vec(m, mt[2]));
}

// Forward quantities of the projection shared by project.wgsl and param_backward.wgsl.
struct Ewa {
    // Camera-space mean.
    p: vec3<f32>,
    mean2d: vec2<f32>,
    // x' and y' (the clamped x/z, y/z times z) and whether each clamp is active.
    tx: f32,
    ty: f32,
    clamped_x: bool,
    clamped_y: bool,
    // Rows of J·W.
    t0: vec3<f32>,
    t1: vec3<f32>,
    cov3: mat3x3<f32>,
    // (xx, xy, yy) with the dilation.
    cov2d: vec3<f32>,
}

fn ewa(mean: vec3<f32>, quat: vec4<f32>, scale: vec3<f32>) -> Ewa {
    let w = camera_rotation();
    let p = mat_vec(w, mean) + frame.translation.xyz;
    let fx = frame.focal.x;
    let fy = frame.focal.y;
    let inv_z = 1.0 / p.z;
    let mean2d = vec2<f32>(fx * p.x * inv_z + frame.focal.z, fy * p.y * inv_z + frame.focal.w);
    let lim_x = frame.view.z;
    let lim_y = frame.view.w;
    let u = p.x * inv_z;
    let v = p.y * inv_z;
    let cu = clamp(u, -lim_x, lim_x);
    let cv = clamp(v, -lim_y, lim_y);
    let tx = cu * p.z;
    let ty = cv * p.z;
    let row0 = vec3<f32>(fx * inv_z, 0.0, -fx * tx * inv_z * inv_z);
    let row1 = vec3<f32>(0.0, fy * inv_z, -fy * ty * inv_z * inv_z);
    let t0 = mat_t_vec(w, row0);
    let t1 = mat_t_vec(w, row1);
    let cov3 = mul_transpose(scaled_rotation(quat_to_rotation(quat), scale));
    let s0 = mat_vec(cov3, t0);
    let s1 = mat_vec(cov3, t1);
    let low_pass = frame.cull.z;
    let cov2d = vec3<f32>(dot3(t0, s0) + low_pass, dot3(t0, s1), dot3(t1, s1) + low_pass);
    return Ewa(p, mean2d, tx, ty, cu != u, cv != v, t0, t1, cov3, cov2d);
}

// Determinant of the symmetric 2×2 matrix (a, b, c); the inverse exists where it is > 0.
fn det_2x2(m: vec3<f32>) -> f32 {
    return m.x * m.z - m.y * m.y;
}

fn inverse_2x2(m: vec3<f32>, det: f32) -> vec3<f32> {
    let inv = 1.0 / det;
    return vec3<f32>(m.z * inv, -m.y * inv, m.x * inv);
}
