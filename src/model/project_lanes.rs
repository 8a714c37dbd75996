//! [`project_beyond`](super::project::project_beyond) for eight Gaussians at once, one vector
//! lane each: the same operations in the same order, so every lane's result equals the
//! one-Gaussian projection bit for bit (Rust never fuses a multiply and an add on its own).
//!
//! The splatting stage projects every Gaussian of every view; one at a time, most of its time
//! went on scalar 3×3 matrix arithmetic. Written as plain loops over eight-lane arrays, each
//! step becomes one vector instruction in a kernel compiled for AVX2 or AVX-512 (see
//! `crate::raster::simd_kernel!`); only the logarithm of the screen box stays a call per lane.
//!
//! [`project_backward_lanes`] is [`project_backward`](super::project::project_backward) the
//! same way, for the backward stage's chain rule through the projection.

use crate::data::camera::Camera;

use super::project::{FOV_CLAMP, LOW_PASS, MIN_OPACITY, NEAR_PLANE};

/// Gaussians projected together.
pub const LANES: usize = 8;

/// One scalar of eight Gaussians.
pub type Lanes = [f32; LANES];

/// What the projection reads of eight Gaussians, one array per scalar.
#[derive(Clone, Copy, Debug, Default)]
pub struct GaussianLanes {
    /// World-space mean x, y, z.
    pub mean: [Lanes; 3],
    /// Unit quaternion w, x, y, z.
    pub quat: [Lanes; 4],
    /// Per-axis standard deviations.
    pub scale: [Lanes; 3],
    /// Opacity at the view's time.
    pub opacity: Lanes,
}

/// Eight projected Gaussians; a lane's values mean something only where `kept` is set
/// (where [`project_beyond`](super::project::project_beyond) returns `Some`).
#[derive(Clone, Copy, Debug, Default)]
pub struct ProjectedLanes {
    /// Drawable, in front of the near plane, non-degenerate and overlapping the image.
    pub kept: [bool; LANES],
    /// Centre in pixels, x and y.
    pub mean2d: [Lanes; 2],
    /// Camera-space depth.
    pub depth: Lanes,
    /// Inverse 2D covariance (a, b, c).
    pub conic: [Lanes; 3],
    /// Half-size of the screen box, x and y.
    pub extent: [Lanes; 2],
}

/// The camera's part of the projection, worked out once per view.
#[derive(Clone, Copy, Debug)]
pub struct ViewTerms {
    /// World-to-camera rotation, `rotation[row][column]`.
    rotation: [[f32; 3]; 3],
    translation: [f32; 3],
    focal: [f32; 2],
    principal: [f32; 2],
    /// Limits of x/z and y/z where the Jacobian is evaluated.
    limit: [f32; 2],
    size: [f32; 2],
    near_plane: f32,
}

impl ViewTerms {
    /// The terms of `cam`, culling nearer than `near_plane` (never below [`NEAR_PLANE`]).
    pub fn new(cam: &Camera, near_plane: f32) -> Self {
        let w = cam.rotation();
        let t = cam.translation();
        Self {
            rotation: [
                w.row(0).to_array(),
                w.row(1).to_array(),
                w.row(2).to_array(),
            ],
            translation: t.to_array(),
            focal: [cam.fx, cam.fy],
            principal: [cam.cx, cam.cy],
            // As the one-Gaussian Jacobian computes them.
            limit: [
                FOV_CLAMP * 0.5 * cam.width as f32 / cam.fx,
                FOV_CLAMP * 0.5 * cam.height as f32 / cam.fy,
            ],
            size: [cam.width as f32, cam.height as f32],
            near_plane: near_plane.max(NEAR_PLANE),
        }
    }
}

/// `f(i)` for every lane.
macro_rules! lanes {
    (|$i:ident| $e:expr) => {{
        let mut out = [0f32; LANES];
        for $i in 0..LANES {
            out[$i] = $e;
        }
        out
    }};
}

/// Rotation matrix columns of the eight quaternions, as
/// [`quat_to_rotation`](super::project::quat_to_rotation) writes them: `r[column][row]`.
#[inline(always)]
fn rotation_lanes([w, x, y, z]: &[Lanes; 4]) -> [[Lanes; 3]; 3] {
    [
        [
            lanes!(|i| 1.0 - 2.0 * (y[i] * y[i] + z[i] * z[i])),
            lanes!(|i| 2.0 * (x[i] * y[i] + w[i] * z[i])),
            lanes!(|i| 2.0 * (x[i] * z[i] - w[i] * y[i])),
        ],
        [
            lanes!(|i| 2.0 * (x[i] * y[i] - w[i] * z[i])),
            lanes!(|i| 1.0 - 2.0 * (x[i] * x[i] + z[i] * z[i])),
            lanes!(|i| 2.0 * (y[i] * z[i] + w[i] * x[i])),
        ],
        [
            lanes!(|i| 2.0 * (x[i] * z[i] + w[i] * y[i])),
            lanes!(|i| 2.0 * (y[i] * z[i] - w[i] * x[i])),
            lanes!(|i| 1.0 - 2.0 * (x[i] * x[i] + y[i] * y[i])),
        ],
    ]
}

// Helpers are functions rather than closures or `std::array::from_fn`: those can stay out of
// line, and then they run without the vector instructions of the kernel that calls them.

/// `matrix · v` with glam's order of additions, `matrix[column][row]`.
#[inline(always)]
fn mul_lanes(matrix: &[[Lanes; 3]; 3], v: &[Lanes; 3]) -> [Lanes; 3] {
    let [c0, c1, c2] = matrix;
    [
        lanes!(|i| (c0[0][i] * v[0][i] + c1[0][i] * v[1][i]) + c2[0][i] * v[2][i]),
        lanes!(|i| (c0[1][i] * v[0][i] + c1[1][i] * v[1][i]) + c2[1][i] * v[2][i]),
        lanes!(|i| (c0[2][i] * v[0][i] + c1[2][i] * v[1][i]) + c2[2][i] * v[2][i]),
    ]
}

/// `a · b` with glam's order of additions.
#[inline(always)]
fn dot_lanes(a: &[Lanes; 3], b: &[Lanes; 3]) -> Lanes {
    lanes!(|i| (a[0][i] * b[0][i] + a[1][i] * b[1][i]) + a[2][i] * b[2][i])
}

/// Σ = R S Sᵀ Rᵀ as [`covariance_3d`](super::project::covariance_3d) computes it, with the
/// glam products' order and their multiplications by the zeros of the diagonal matrix (kept
/// so that signed zeros and non-finite values come out the same): `cov[column][row]`.
#[inline(always)]
fn covariance_lanes(quat: &[Lanes; 4], [sx, sy, sz]: &[Lanes; 3]) -> [[Lanes; 3]; 3] {
    let r = rotation_lanes(quat);
    let zero = [0f32; LANES];
    // Column j of M = R·diag(s) is R times the diagonal's column j.
    let m = [
        mul_lanes(&r, &[*sx, zero, zero]),
        mul_lanes(&r, &[zero, *sy, zero]),
        mul_lanes(&r, &[zero, zero, *sz]),
    ];
    // Column j of M·Mᵀ is M times row j of M.
    let [m0, m1, m2] = &m;
    [
        mul_lanes(&m, &[m0[0], m1[0], m2[0]]),
        mul_lanes(&m, &[m0[1], m1[1], m2[1]]),
        mul_lanes(&m, &[m0[2], m1[2], m2[2]]),
    ]
}

/// A row `w` of a matrix times `v`, glam's order of additions.
#[inline(always)]
fn dot_row(w: [f32; 3], v: &[Lanes; 3]) -> Lanes {
    lanes!(|i| (w[0] * v[0][i] + w[1] * v[1][i]) + w[2] * v[2][i])
}

/// A row of W·μ + t: `w` the row of W and `t` the entry of t.
#[inline(always)]
fn affine_row(w: [f32; 3], t: f32, mean: &[Lanes; 3]) -> Lanes {
    let product = dot_row(w, mean);
    lanes!(|i| product[i] + t)
}

/// x/z (or y/z) clamped to ±`limit`: where the Jacobian is evaluated.
#[inline(always)]
fn clamped(u: &Lanes, limit: f32) -> Lanes {
    lanes!(|i| {
        let u = u[i];
        let u = if u < -limit { -limit } else { u };
        if u > limit { limit } else { u }
    })
}

/// A row of J·W: Wᵀ times a Jacobian row (Wᵀ's column c is W's row c, `w[row][column]`).
#[inline(always)]
fn jacobian_times_rotation(w: &[[f32; 3]; 3], jac: &[Lanes; 3]) -> [Lanes; 3] {
    let column = |k: usize| [w[0][k], w[1][k], w[2][k]];
    let (c0, c1, c2) = (column(0), column(1), column(2));
    [
        lanes!(|i| (c0[0] * jac[0][i] + c0[1] * jac[1][i]) + c0[2] * jac[2][i]),
        lanes!(|i| (c1[0] * jac[0][i] + c1[1] * jac[1][i]) + c1[2] * jac[2][i]),
        lanes!(|i| (c2[0] * jac[0][i] + c2[1] * jac[1][i]) + c2[2] * jac[2][i]),
    ]
}

/// The forward quantities of the EWA projection of eight Gaussians, shared by the projection
/// and its backward (the one-Gaussian `Ewa`).
struct EwaLanes {
    /// Camera-space mean.
    p: [Lanes; 3],
    inv_z: Lanes,
    mean2d: [Lanes; 2],
    /// x/z and y/z, and the same clamped to the limits of the Jacobian.
    u: [Lanes; 2],
    clamped: [Lanes; 2],
    /// x' and y': the clamped coordinates times z.
    tx: Lanes,
    ty: Lanes,
    /// Rows of T = J·W.
    t0: [Lanes; 3],
    t1: [Lanes; 3],
    cov3: [[Lanes; 3]; 3],
    /// (xx, xy, yy) including the dilation.
    cov2d: [Lanes; 3],
}

#[inline(always)]
fn ewa_lanes(g: &GaussianLanes, terms: &ViewTerms) -> EwaLanes {
    let (w, t) = (&terms.rotation, &terms.translation);
    let p = [
        affine_row(w[0], t[0], &g.mean),
        affine_row(w[1], t[1], &g.mean),
        affine_row(w[2], t[2], &g.mean),
    ];
    let inv_z = lanes!(|i| 1.0 / p[2][i]);
    let ([fx, fy], [cx, cy]) = (terms.focal, terms.principal);
    let mean2d = [
        lanes!(|i| fx * p[0][i] * inv_z[i] + cx),
        lanes!(|i| fy * p[1][i] * inv_z[i] + cy),
    ];
    let u = [
        lanes!(|i| p[0][i] * inv_z[i]),
        lanes!(|i| p[1][i] * inv_z[i]),
    ];
    let clamped = [
        clamped(&u[0], terms.limit[0]),
        clamped(&u[1], terms.limit[1]),
    ];
    let tx = lanes!(|i| clamped[0][i] * p[2][i]);
    let ty = lanes!(|i| clamped[1][i] * p[2][i]);
    let zero = [0f32; LANES];
    let jac0 = [
        lanes!(|i| fx * inv_z[i]),
        zero,
        lanes!(|i| -fx * tx[i] * inv_z[i] * inv_z[i]),
    ];
    let jac1 = [
        zero,
        lanes!(|i| fy * inv_z[i]),
        lanes!(|i| -fy * ty[i] * inv_z[i] * inv_z[i]),
    ];
    let t0 = jacobian_times_rotation(w, &jac0);
    let t1 = jacobian_times_rotation(w, &jac1);
    let cov3 = covariance_lanes(&g.quat, &g.scale);
    let (s0, s1) = (mul_lanes(&cov3, &t0), mul_lanes(&cov3, &t1));
    let (d00, d01, d11) = (
        dot_lanes(&t0, &s0),
        dot_lanes(&t0, &s1),
        dot_lanes(&t1, &s1),
    );
    let cov2d = [
        lanes!(|i| d00[i] + LOW_PASS),
        d01,
        lanes!(|i| d11[i] + LOW_PASS),
    ];
    EwaLanes {
        p,
        inv_z,
        mean2d,
        u,
        clamped,
        tx,
        ty,
        t0,
        t1,
        cov3,
        cov2d,
    }
}

/// The determinant of the 2D covariances and their inverses (the conics), as the
/// one-Gaussian `inverse_2x2` computes them; a conic means something only where the
/// determinant is positive.
#[inline(always)]
fn conic_lanes(cov2d: &[Lanes; 3]) -> (Lanes, [Lanes; 3]) {
    let det = lanes!(|i| cov2d[0][i] * cov2d[2][i] - cov2d[1][i] * cov2d[1][i]);
    let inv = lanes!(|i| 1.0 / det[i]);
    let conic = [
        lanes!(|i| cov2d[2][i] * inv[i]),
        lanes!(|i| -cov2d[1][i] * inv[i]),
        lanes!(|i| cov2d[0][i] * inv[i]),
    ];
    (det, conic)
}

/// Projects eight Gaussians into the view of `terms`. Inline, so that it gets the vector
/// instructions of the kernel that calls it; it reads and writes memory (not values) so that
/// the compiler sees whole lane arrays loaded and stored, which it turns into vectors.
#[inline(always)]
pub fn project_lanes(g: &GaussianLanes, terms: &ViewTerms, out: &mut ProjectedLanes) {
    let e = ewa_lanes(g, terms);
    let (det, conic) = conic_lanes(&e.cov2d);
    let cov2d = &e.cov2d;
    // A libm call per lane, as the one-Gaussian projection makes it.
    let mut log = [0f32; LANES];
    for (log, opacity) in log.iter_mut().zip(g.opacity) {
        *log = (255.0 * opacity).ln();
    }
    let radius = lanes!(|i| (2.0 * log[i]).max(0.0).sqrt());
    let extent = [
        lanes!(|i| radius[i] * cov2d[0][i].sqrt()),
        lanes!(|i| radius[i] * cov2d[2][i].sqrt()),
    ];
    let [width, height] = terms.size;
    let mut kept = [false; LANES];
    for i in 0..LANES {
        let (x, y) = (e.mean2d[0][i], e.mean2d[1][i]);
        let (ex, ey) = (extent[0][i], extent[1][i]);
        let on_screen = !(x + ex <= 0.0 || y + ey <= 0.0 || x - ex >= width || y - ey >= height);
        kept[i] = (g.opacity[i] >= MIN_OPACITY)
            & (e.p[2][i] >= terms.near_plane)
            & (det[i] > 0.0)
            & on_screen;
    }
    *out = ProjectedLanes {
        kept,
        mean2d: e.mean2d,
        depth: e.p[2],
        conic,
        extent,
    };
}

/// Gradients of eight projections: dL/d of the world mean, the quaternion and the scale
/// (the one-Gaussian [`ProjectGrad`](super::project::ProjectGrad)).
#[derive(Clone, Copy, Debug, Default)]
pub struct ProjectGradLanes {
    /// dL/d world mean x, y, z.
    pub mean: [Lanes; 3],
    /// dL/d quaternion w, x, y, z (as used, already normalised).
    pub quat: [Lanes; 4],
    /// dL/d scale.
    pub scale: [Lanes; 3],
}

/// [`project_backward`](super::project::project_backward) for eight Gaussians, bit for bit,
/// given dL/d mean2d and dL/d conic per lane (`g.opacity` is not read). Every lane is
/// computed; a lane's result means something only for a Gaussian the projection kept.
#[inline(always)]
pub fn project_backward_lanes(
    g: &GaussianLanes,
    d_mean2d: &[Lanes; 2],
    d_conic: &[Lanes; 3],
    terms: &ViewTerms,
    out: &mut ProjectGradLanes,
) {
    let e = ewa_lanes(g, terms);
    let (det, conic) = conic_lanes(&e.cov2d);
    let q: [Lanes; 3] = [
        lanes!(|i| if det[i] > 0.0 { conic[0][i] } else { 0.0 }),
        lanes!(|i| if det[i] > 0.0 { conic[1][i] } else { 0.0 }),
        lanes!(|i| if det[i] > 0.0 { conic[2][i] } else { 0.0 }),
    ];
    // dL/dC = −Q·Gq·Q (see the one-Gaussian backward).
    let gq1 = lanes!(|i| 0.5 * d_conic[1][i]);
    let (gq0, gq2) = (&d_conic[0], &d_conic[2]);
    let qg00 = lanes!(|i| q[0][i] * gq0[i] + q[1][i] * gq1[i]);
    let qg01 = lanes!(|i| q[0][i] * gq1[i] + q[1][i] * gq2[i]);
    let qg10 = lanes!(|i| q[1][i] * gq0[i] + q[2][i] * gq1[i]);
    let qg11 = lanes!(|i| q[1][i] * gq1[i] + q[2][i] * gq2[i]);
    let g00 = lanes!(|i| -(qg00[i] * q[0][i] + qg01[i] * q[1][i]));
    let g01 = lanes!(|i| -(qg00[i] * q[1][i] + qg01[i] * q[2][i]));
    let g11 = lanes!(|i| -(qg10[i] * q[1][i] + qg11[i] * q[2][i]));

    let (t0, t1) = (&e.t0, &e.t1);
    let (s0, s1) = (mul_lanes(&e.cov3, t0), mul_lanes(&e.cov3, t1));
    let d_t0 = [
        lanes!(|i| 2.0 * (g00[i] * s0[0][i] + g01[i] * s1[0][i])),
        lanes!(|i| 2.0 * (g00[i] * s0[1][i] + g01[i] * s1[1][i])),
        lanes!(|i| 2.0 * (g00[i] * s0[2][i] + g01[i] * s1[2][i])),
    ];
    let d_t1 = [
        lanes!(|i| 2.0 * (g11[i] * s1[0][i] + g01[i] * s0[0][i])),
        lanes!(|i| 2.0 * (g11[i] * s1[1][i] + g01[i] * s0[1][i])),
        lanes!(|i| 2.0 * (g11[i] * s1[2][i] + g01[i] * s0[2][i])),
    ];
    // dL/dΣ, entry [column j][row i]: g00·t0ᵢt0ⱼ + g01·(t0ᵢt1ⱼ + t1ᵢt0ⱼ) + g11·t1ᵢt1ⱼ.
    let mut d_cov3 = [[[0f32; LANES]; 3]; 3];
    for j in 0..3 {
        for r in 0..3 {
            d_cov3[j][r] = lanes!(|i| (g00[i] * (t0[r][i] * t0[j][i])
                + g01[i] * (t0[r][i] * t1[j][i] + t1[r][i] * t0[j][i]))
                + g11[i] * (t1[r][i] * t1[j][i]));
        }
    }

    // dL/djᵢ = W dL/dtᵢ: only the entries the Jacobian depends on.
    let w = &terms.rotation;
    let (dj00, dj02) = (dot_row(w[0], &d_t0), dot_row(w[2], &d_t0));
    let (dj11, dj12) = (dot_row(w[1], &d_t1), dot_row(w[2], &d_t1));

    let [fx, fy] = terms.focal;
    let (p, inv_z) = (&e.p, &e.inv_z);
    let inv_z2 = lanes!(|i| inv_z[i] * inv_z[i]);
    let inv_z3 = lanes!(|i| inv_z2[i] * inv_z[i]);
    let [dmx, dmy] = d_mean2d;
    let mut dpx = lanes!(|i| fx * inv_z[i] * dmx[i]);
    let mut dpy = lanes!(|i| fy * inv_z[i] * dmy[i]);
    let mut dpz = lanes!(|i| -(fx * p[0][i] * dmx[i] + fy * p[1][i] * dmy[i]) * inv_z2[i]);
    dpz = lanes!(|i| dpz[i] - (fx * dj00[i] + fy * dj11[i]) * inv_z2[i]);
    // Inside the clamp x' = x; outside, x' = ±limit·z (the one-Gaussian branches as selects).
    for i in 0..LANES {
        let inside = e.clamped[0][i] == e.u[0][i];
        let z_outside = dpz[i] + fx * e.tx[i] * inv_z3[i] * dj02[i];
        let x_inside = dpx[i] - fx * inv_z2[i] * dj02[i];
        let z_inside = dpz[i] + 2.0 * fx * e.tx[i] * inv_z3[i] * dj02[i];
        dpx[i] = if inside { x_inside } else { dpx[i] };
        dpz[i] = if inside { z_inside } else { z_outside };
    }
    for i in 0..LANES {
        let inside = e.clamped[1][i] == e.u[1][i];
        let z_outside = dpz[i] + fy * e.ty[i] * inv_z3[i] * dj12[i];
        let y_inside = dpy[i] - fy * inv_z2[i] * dj12[i];
        let z_inside = dpz[i] + 2.0 * fy * e.ty[i] * inv_z3[i] * dj12[i];
        dpy[i] = if inside { y_inside } else { dpy[i] };
        dpz[i] = if inside { z_inside } else { z_outside };
    }

    let (quat, scale) = covariance_backward_lanes(&g.quat, &g.scale, &d_cov3);
    *out = ProjectGradLanes {
        mean: jacobian_times_rotation(w, &[dpx, dpy, dpz]),
        quat,
        scale,
    };
}

/// [`covariance_3d_backward`](super::project::covariance_3d_backward) for eight Gaussians:
/// (dL/dquat, dL/dscale) given dL/dΣ (`d_cov[column][row]`).
#[inline(always)]
fn covariance_backward_lanes(
    quat: &[Lanes; 4],
    [sx, sy, sz]: &[Lanes; 3],
    d_cov: &[[Lanes; 3]; 3],
) -> ([Lanes; 4], [Lanes; 3]) {
    let r = rotation_lanes(quat);
    let zero = [0f32; LANES];
    let diagonal = [[*sx, zero, zero], [zero, *sy, zero], [zero, zero, *sz]];
    let m = [
        mul_lanes(&r, &diagonal[0]),
        mul_lanes(&r, &diagonal[1]),
        mul_lanes(&r, &diagonal[2]),
    ];
    // Σ = M Mᵀ → dL/dM = (G + Gᵀ) M.
    let mut sym = [[[0f32; LANES]; 3]; 3];
    for j in 0..3 {
        for k in 0..3 {
            sym[j][k] = lanes!(|i| d_cov[j][k][i] + d_cov[k][j][i]);
        }
    }
    let d_m = [
        mul_lanes(&sym, &m[0]),
        mul_lanes(&sym, &m[1]),
        mul_lanes(&sym, &m[2]),
    ];
    let d_scale = [
        dot_lanes(&d_m[0], &r[0]),
        dot_lanes(&d_m[1], &r[1]),
        dot_lanes(&d_m[2], &r[2]),
    ];
    let d_r = [
        mul_lanes(&d_m, &diagonal[0]),
        mul_lanes(&d_m, &diagonal[1]),
        mul_lanes(&d_m, &diagonal[2]),
    ];
    // quat_to_rotation_backward, g_ij = row i, column j = d_r[j][i].
    let [w, x, y, z] = quat;
    let [[g00, g10, g20], [g01, g11, g21], [g02, g12, g22]] = &d_r;
    let d_quat = [
        lanes!(|i| 2.0
            * (-z[i] * g01[i] + y[i] * g02[i] + z[i] * g10[i] - x[i] * g12[i] - y[i] * g20[i]
                + x[i] * g21[i])),
        lanes!(|i| 2.0
            * (y[i] * g01[i] + z[i] * g02[i] + y[i] * g10[i]
                - 2.0 * x[i] * g11[i]
                - w[i] * g12[i]
                + z[i] * g20[i]
                + w[i] * g21[i]
                - 2.0 * x[i] * g22[i])),
        lanes!(|i| 2.0
            * (-2.0 * y[i] * g00[i]
                + x[i] * g01[i]
                + w[i] * g02[i]
                + x[i] * g10[i]
                + z[i] * g12[i]
                - w[i] * g20[i]
                + z[i] * g21[i]
                - 2.0 * y[i] * g22[i])),
        lanes!(|i| 2.0
            * (-2.0 * z[i] * g00[i] - w[i] * g01[i] + x[i] * g02[i] + w[i] * g10[i]
                - 2.0 * z[i] * g11[i]
                + y[i] * g12[i]
                + x[i] * g20[i]
                + y[i] * g21[i])),
    ];
    (d_quat, d_scale)
}
