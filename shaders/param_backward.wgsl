// Parameter gradients, one invocation per Gaussian: what systems/backward.rs computes after
// the blending backward. From the splat's gradient (dL/d mean2d, conic, opacity, colour) back
// through the projection (project_backward, covariance_3d_backward) to the deformed Gaussian
// (backward_splats, which also gives the NDC-space 2D mean gradient norm for densification),
// then through the SH colour and the deformation to every parameter component
// (backward_parameters). Splats not drawn pass a zero gradient, as on the CPU (the host clears
// the gradients first; their invocations only zero their NDC norm).

@group(0) @binding(3) var<storage, read> deformed: array<f32>;
@group(0) @binding(4) var<storage, read> splats: array<f32>;
@group(0) @binding(5) var<storage, read> splat_grads: array<f32>;
@group(0) @binding(6) var<storage, read_write> grads: array<f32>;
@group(0) @binding(7) var<storage, read_write> ndc_grad_norm: array<f32>;
// The smallest flat index of a non-finite gradient written (the host sets 0xffffffff first):
// the gradient check, done on the values as they are written rather than by reading them back.
@group(0) @binding(8) var<storage, read_write> fault: array<atomic<u32>>;

const NO_FAULT: u32 = 0xffffffffu;
// This invocation's first non-finite gradient so far.
var<private> first_fault: u32 = NO_FAULT;

// Gradient with respect to the deformed Gaussian (src/resources.rs::DeformedGrad).
struct DeformedGrad {
    mean: vec3<f32>,
    rotation: vec4<f32>,
    scale: vec3<f32>,
}

// dL/dq given dL/dR (entry (i, j) = g[j][i]) (src/model/project.rs).
fn quat_to_rotation_backward(q: vec4<f32>, g: mat3x3<f32>) -> vec4<f32> {
    let w = q.x;
    let x = q.y;
    let y = q.z;
    let z = q.w;
    let g00 = g[0].x;
    let g10 = g[0].y;
    let g20 = g[0].z;
    let g01 = g[1].x;
    let g11 = g[1].y;
    let g21 = g[1].z;
    let g02 = g[2].x;
    let g12 = g[2].y;
    let g22 = g[2].z;
    return vec4<f32>(
        2.0 * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21),
        2.0 * (y * g01 + z * g02 + y * g10 - 2.0 * x * g11 - w * g12 + z * g20 + w * g21
            - 2.0 * x * g22),
        2.0 * (-2.0 * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21
            - 2.0 * y * g22),
        2.0 * (-2.0 * z * g00 - w * g01 + x * g02 + w * g10 - 2.0 * z * g11 + y * g12
            + x * g20 + y * g21),
    );
}

// Matrix product A·B as glam computes it (each column of B through mat_vec).
fn mat_mul(a: mat3x3<f32>, b: mat3x3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(mat_vec(a, b[0]), mat_vec(a, b[1]), mat_vec(a, b[2]));
}

// a·bᵀ: column j is a·b_j.
fn outer(a: vec3<f32>, b: vec3<f32>) -> mat3x3<f32> {
    return mat3x3<f32>(a * b.x, a * b.y, a * b.z);
}

fn project_backward(mean: vec3<f32>, quat: vec4<f32>, scale: vec3<f32>, d_mean2d: vec2<f32>,
                    d_conic: vec3<f32>) -> DeformedGrad {
    let e = ewa(mean, quat, scale);
    let det = det_2x2(e.cov2d);
    var q = vec3<f32>(0.0);
    if det > 0.0 {
        q = inverse_2x2(e.cov2d, det);
    }
    // dL/dC = −Q·Gq·Q with the off-diagonal of Gq carrying half of dL/db.
    let gq = vec3<f32>(d_conic.x, 0.5 * d_conic.y, d_conic.z);
    let qg00 = q.x * gq.x + q.y * gq.y;
    let qg01 = q.x * gq.y + q.y * gq.z;
    let qg10 = q.y * gq.x + q.z * gq.y;
    let qg11 = q.y * gq.y + q.z * gq.z;
    let g00 = -(qg00 * q.x + qg01 * q.y);
    let g01 = -(qg00 * q.y + qg01 * q.z);
    let g11 = -(qg10 * q.y + qg11 * q.z);

    let t0 = e.t0;
    let t1 = e.t1;
    let s0 = mat_vec(e.cov3, t0);
    let s1 = mat_vec(e.cov3, t1);
    let d_t0 = 2.0 * (g00 * s0 + g01 * s1);
    let d_t1 = 2.0 * (g11 * s1 + g01 * s0);
    let d_cov3 = g00 * outer(t0, t0) + g01 * (outer(t0, t1) + outer(t1, t0))
        + g11 * outer(t1, t1);

    let w = camera_rotation();
    let d_j0 = mat_vec(w, d_t0);
    let d_j1 = mat_vec(w, d_t1);

    let fx = frame.focal.x;
    let fy = frame.focal.y;
    let p = e.p;
    let inv_z = 1.0 / p.z;
    let inv_z2 = inv_z * inv_z;
    let inv_z3 = inv_z2 * inv_z;
    var d_p = vec3<f32>(
        fx * inv_z * d_mean2d.x,
        fy * inv_z * d_mean2d.y,
        -(fx * p.x * d_mean2d.x + fy * p.y * d_mean2d.y) * inv_z2,
    );
    d_p.z -= (fx * d_j0.x + fy * d_j1.y) * inv_z2;
    let dj02 = d_j0.z;
    let dj12 = d_j1.z;
    if e.clamped_x {
        d_p.z += fx * e.tx * inv_z3 * dj02;
    } else {
        d_p.x -= fx * inv_z2 * dj02;
        d_p.z += 2.0 * fx * e.tx * inv_z3 * dj02;
    }
    if e.clamped_y {
        d_p.z += fy * e.ty * inv_z3 * dj12;
    } else {
        d_p.y -= fy * inv_z2 * dj12;
        d_p.z += 2.0 * fy * e.ty * inv_z3 * dj12;
    }

    // covariance_3d_backward: Σ = M Mᵀ → dL/dM = (G + Gᵀ) M.
    let r = quat_to_rotation(quat);
    let m = scaled_rotation(r, scale);
    let d_m = mat_mul(d_cov3 + transpose(d_cov3), m);
    let d_scale = vec3<f32>(dot3(d_m[0], r[0]), dot3(d_m[1], r[1]), dot3(d_m[2], r[2]));
    let d_r = scaled_rotation(d_m, scale);
    return DeformedGrad(mat_t_vec(w, d_p), quat_to_rotation_backward(quat, d_r), d_scale);
}

// Σ_k d_basis[k]·∇b_k(n) for the first `count` coefficients (src/model/sh.rs).
fn sh_basis_backward(count: u32, n: vec3<f32>, db: array<f32, 16>) -> vec3<f32> {
    let x = n.x;
    let y = n.y;
    let z = n.z;
    var g = vec3<f32>(0.0);
    if count > 1u {
        g += vec3<f32>(-SH_C1 * db[3], -SH_C1 * db[1], SH_C1 * db[2]);
    }
    if count > 4u {
        let xx = x * x;
        let yy = y * y;
        let zz = z * z;
        g += vec3<f32>(y, x, 0.0) * (SH_C2_0 * db[4]);
        g += vec3<f32>(0.0, z, y) * (SH_C2_1 * db[5]);
        g += vec3<f32>(-2.0 * x, -2.0 * y, 4.0 * z) * (SH_C2_2 * db[6]);
        g += vec3<f32>(z, 0.0, x) * (SH_C2_3 * db[7]);
        g += vec3<f32>(2.0 * x, -2.0 * y, 0.0) * (SH_C2_4 * db[8]);
        if count > 9u {
            g += vec3<f32>(6.0 * x * y, 3.0 * (xx - yy), 0.0) * (SH_C3_0 * db[9]);
            g += vec3<f32>(y * z, x * z, x * y) * (SH_C3_1 * db[10]);
            g += vec3<f32>(-2.0 * x * y, 4.0 * zz - xx - 3.0 * yy, 8.0 * y * z)
                * (SH_C3_2 * db[11]);
            g += vec3<f32>(-6.0 * x * z, -6.0 * y * z, 6.0 * zz - 3.0 * xx - 3.0 * yy)
                * (SH_C3_3 * db[12]);
            g += vec3<f32>(4.0 * zz - 3.0 * xx - yy, -2.0 * x * y, 8.0 * x * z)
                * (SH_C3_4 * db[13]);
            g += vec3<f32>(2.0 * x * z, -2.0 * y * z, xx - yy) * (SH_C3_5 * db[14]);
            g += vec3<f32>(3.0 * (xx - yy), -6.0 * x * y, 0.0) * (SH_C3_6 * db[15]);
        }
    }
    return g;
}

// Writes gradient `at` and notes it when it is not finite.
fn write_at(at: u32, value: f32) {
    grads[at] = value;
    if (bitcast<u32>(value) & 0x7f800000u) == 0x7f800000u {
        first_fault = min(first_fault, at);
    }
}

fn write_grad(i: u32, prefix: u32, width: u32, k: u32, value: f32) {
    write_at(frame.count * prefix + i * width + k, value);
}

fn write_grad3(i: u32, prefix: u32, width: u32, k: u32, value: vec3<f32>) {
    let at = frame.count * prefix + i * width + k;
    write_at(at, value.x);
    write_at(at + 1u, value.y);
    write_at(at + 2u, value.z);
}

fn write_grad4(i: u32, prefix: u32, width: u32, k: u32, value: vec4<f32>) {
    let at = frame.count * prefix + i * width + k;
    write_at(at, value.x);
    write_at(at + 1u, value.y);
    write_at(at + 2u, value.z);
    write_at(at + 3u, value.w);
}

@compute @workgroup_size(64)
fn backward(@builtin(global_invocation_id) gid: vec3<u32>,
            @builtin(num_workgroups) groups: vec3<u32>) {
    let i = gaussian_index(gid, groups);
    if i >= frame.count {
        return;
    }
    // Splats not drawn pass a zero gradient, as on the CPU: the host clears the gradients
    // before this pass, so their Gaussians (on a trained 4D model most of them, faded at the
    // view's time) neither read their parameters nor write.
    if splats[i * SPLAT_STRIDE + 12u] == 0.0 {
        ndc_grad_norm[i] = 0.0;
        return;
    }
    let sg = i * SPLAT_GRAD_STRIDE;
    let d_mean2d = vec2<f32>(splat_grads[sg], splat_grads[sg + 1u]);
    let d_conic = vec3<f32>(splat_grads[sg + 2u], splat_grads[sg + 3u], splat_grads[sg + 4u]);
    let d_opacity = splat_grads[sg + 5u];
    let d_color = vec3<f32>(splat_grads[sg + 6u], splat_grads[sg + 7u], splat_grads[sg + 8u]);

    let d = i * DEFORMED_STRIDE;
    let deformed_mean = vec3<f32>(deformed[d], deformed[d + 1u], deformed[d + 2u]);

    // backward_splats: NDC spans the image over [−1, 1], one pixel is 2/W (2/H) NDC units.
    let half = vec2<f32>(0.5 * frame.view.x, 0.5 * frame.view.y);
    let g = d_mean2d * half;
    ndc_grad_norm[i] = sqrt(g.x * g.x + g.y * g.y);
    let quat = vec4<f32>(deformed[d + 3u], deformed[d + 4u], deformed[d + 5u], deformed[d + 6u]);
    let scale = vec3<f32>(deformed[d + 7u], deformed[d + 8u], deformed[d + 9u]);
    let dg = project_backward(deformed_mean, quat, scale, d_mean2d, d_conic);

    // backward_parameters.
    let gs = load_gaussian(i);
    let dtw = warped_dtw(i);

    // SH colour (sh_to_rgb_backward): clamped channels pass no gradient.
    let count = sh_count(frame.sh_degree);
    let unit = sh_unit(deformed_mean - frame.eye.xyz);
    let n = unit.xyz;
    var b = sh_basis(count, n);
    let raw = sh_raw_rgb(count, gs.sh, b);
    let gc = select(d_color, vec3<f32>(0.0), raw < vec3<f32>(0.0));
    var coeffs = gs.sh;
    var d_basis: array<f32, 16>;
    for (var k = 0u; k < SH_COEFFS; k++) {
        var d_coeff = vec3<f32>(0.0);
        if k < count {
            d_coeff = gc * b[k];
            d_basis[k] = dot3(gc, coeffs[k]);
        }
        write_grad3(i, PREFIX_COLOR, WIDTH_COLOR, 3u * k, d_coeff);
    }
    let d_n = sh_basis_backward(count, n, d_basis);
    let d_dir = (d_n - n * dot3(n, d_n)) * unit.w;
    let d_mean = dg.mean + d_dir;
    write_grad3(i, PREFIX_POSITION, WIDTH_POSITION, 0u, d_mean);

    // Fourier motion (fourier_offset_backward).
    let shared_phase = (frame.flags & FLAG_SHARED_PHASE) != 0u;
    var cos_terms = gs.fourier_cos;
    var sin_terms = gs.fourier_sin;
    var d_phase = vec4<f32>(0.0);
    for (var f = 0u; f < FOURIER_TERMS; f++) {
        let sc = sin_cos(fourier_angle(f, dtw, gs.phase, shared_phase));
        write_grad3(i, PREFIX_FOURIER, WIDTH_FOURIER, 3u * f, d_mean * sc.y);
        write_grad3(i, PREFIX_FOURIER, WIDTH_FOURIER, 12u + 3u * f, d_mean * sc.x);
        let d_angle = dot3(d_mean, sin_terms[f] * sc.y - cos_terms[f] * sc.x);
        let slot = select(f, 0u, shared_phase);
        d_phase[slot] += d_angle;
    }
    write_grad4(i, PREFIX_FOURIER, WIDTH_FOURIER, 24u, d_phase);

    // Rotation (rotation_at_backward): d(q/|q|) = (I − q̂ q̂ᵀ) dq / |q|.
    let q = raw_rotation(gs.c0, gs.c1, dtw);
    let n2 = dot4(q, q);
    var d_c0 = vec4<f32>(0.0);
    var d_c1 = vec4<f32>(0.0);
    if !(n2 <= MIN_POSITIVE) {
        let inv = 1.0 / sqrt(n2);
        let along = dot4(q, dg.rotation) * inv * inv;
        d_c0 = (dg.rotation - q * along) * inv;
        d_c1 = d_c0 * dtw;
    }
    write_grad4(i, PREFIX_ROTATION, WIDTH_ROTATION, 0u, d_c0);
    write_grad4(i, PREFIX_ROTATION, WIDTH_ROTATION, 4u, d_c1);

    // Scale (scale_at_backward); d1 gets none without scale motion.
    let d_s = dg.scale * scale_at(gs.d0, scale_velocity(gs.d1), dtw);
    let scale_motion = (frame.flags & FLAG_SCALE_MOTION) != 0u;
    write_grad3(i, PREFIX_SCALE, WIDTH_SCALE, 0u, d_s);
    write_grad3(i, PREFIX_SCALE, WIDTH_SCALE, 3u, select(vec3<f32>(0.0), d_s * dtw, scale_motion));

    // Opacity (temporal_opacity_backward); the temporal centre is fixed on this backend
    // (a learnt centre, `train.lr.temporal_center`, is refused by the scene check).
    let spatial = sigmoid(gs.logit);
    let tf = temporal_factor(gs.temporal_scale, dtw);
    let sigma = spatial * tf.factor;
    var d_raw = vec2<f32>(0.0);
    d_raw[tf.index] = d_opacity * sigma * tf.d_exponent;
    write_grad(i, PREFIX_OPACITY, WIDTH_OPACITY, 0u, d_opacity * tf.factor * spatial * (1.0 - spatial));
    write_grad3(i, PREFIX_TEMPORAL, WIDTH_TEMPORAL, 0u, vec3<f32>(0.0, d_raw));
    if first_fault != NO_FAULT {
        atomicMin(&fault[0], first_fault);
    }
}
