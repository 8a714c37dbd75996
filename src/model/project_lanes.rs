//! [`project_beyond`](super::project::project_beyond) for eight Gaussians at once, one vector
//! lane each: the same operations in the same order, so every lane's result equals the
//! one-Gaussian projection bit for bit (Rust never fuses a multiply and an add on its own).
//!
//! The splatting stage projects every Gaussian of every view; one at a time, most of its time
//! went on scalar 3×3 matrix arithmetic. Written as plain loops over eight-lane arrays, each
//! step becomes one vector instruction in a kernel compiled for AVX2 or AVX-512 (see
//! [`crate::raster::simd_kernel`]); only the logarithm of the screen box stays a call per lane.
//!
//! There is no backward here: the projection's gradient is taken one Gaussian at a time by
//! [`project_backward`](super::project::project_backward), for the splats that were drawn.

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

/// Row `k` of W·μ + t, glam's order of additions.
#[inline(always)]
fn affine_row(w: [f32; 3], t: f32, [mx, my, mz]: &[Lanes; 3]) -> Lanes {
    lanes!(|i| ((w[0] * mx[i] + w[1] * my[i]) + w[2] * mz[i]) + t)
}

/// x/z (or y/z) clamped to ±`limit`, times z: where the Jacobian is evaluated.
#[inline(always)]
fn clamped_times_z(coordinate: &Lanes, inv_z: &Lanes, z: &Lanes, limit: f32) -> Lanes {
    lanes!(|i| {
        let u = coordinate[i] * inv_z[i];
        let u = if u < -limit { -limit } else { u };
        let u = if u > limit { limit } else { u };
        u * z[i]
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

/// Projects eight Gaussians into the view of `terms`. Inline, so that it gets the vector
/// instructions of the kernel that calls it; it reads and writes memory (not values) so that
/// the compiler sees whole lane arrays loaded and stored, which it turns into vectors.
#[inline(always)]
pub fn project_lanes(g: &GaussianLanes, terms: &ViewTerms, out: &mut ProjectedLanes) {
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
    let tx = clamped_times_z(&p[0], &inv_z, &p[2], terms.limit[0]);
    let ty = clamped_times_z(&p[1], &inv_z, &p[2], terms.limit[1]);
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
    let det = lanes!(|i| cov2d[0][i] * cov2d[2][i] - cov2d[1][i] * cov2d[1][i]);
    let inv = lanes!(|i| 1.0 / det[i]);
    let conic = [
        lanes!(|i| cov2d[2][i] * inv[i]),
        lanes!(|i| -cov2d[1][i] * inv[i]),
        lanes!(|i| cov2d[0][i] * inv[i]),
    ];
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
        let (x, y) = (mean2d[0][i], mean2d[1][i]);
        let (ex, ey) = (extent[0][i], extent[1][i]);
        let on_screen = !(x + ex <= 0.0 || y + ey <= 0.0 || x - ex >= width || y - ey >= height);
        kept[i] = (g.opacity[i] >= MIN_OPACITY)
            & (p[2][i] >= terms.near_plane)
            & (det[i] > 0.0)
            & on_screen;
    }
    *out = ProjectedLanes {
        kept,
        mean2d,
        depth: p[2],
        conic,
        extent,
    };
}
