//! EWA projection of a 3D Gaussian to a 2D screen-space Gaussian (3DGS / gsplat conventions,
//! SPEC §4) and its backward pass.
//!
//! Σ = R S Sᵀ Rᵀ, p = R_wc μ + t_wc, cov2d = J R_wc Σ R_wcᵀ Jᵀ + 0.3·I with the perspective
//! Jacobian J evaluated at the point clamped to 1.3× the field of view.

use glam::{Mat3, Vec2, Vec3};

use crate::data::camera::Camera;

/// Gaussians closer than this (camera z) are culled.
pub const NEAR_PLANE: f32 = 0.01;
/// Screen-space dilation added to the diagonal of the 2D covariance (anti-aliasing low-pass).
pub const LOW_PASS: f32 = 0.3;
/// Gaussians whose opacity is below this cannot produce a visible alpha and are culled.
pub(crate) const MIN_OPACITY: f32 = 1.0 / 255.0;

/// Whether a Gaussian of opacity σ can be drawn (σ ≥ [`MIN_OPACITY`]; a NaN cannot).
#[inline]
pub(crate) fn drawable(opacity: f32) -> bool {
    opacity >= MIN_OPACITY
}
/// The Jacobian is evaluated at x/z clamped to this multiple of tan(fov/2).
pub(crate) const FOV_CLAMP: f32 = 1.3;

/// Rotation matrix of a unit quaternion [w, x, y, z]. The formula is applied as is (no
/// normalisation), so its derivatives are those of the polynomial entries.
#[inline]
pub fn quat_to_rotation(q: [f32; 4]) -> Mat3 {
    let [w, x, y, z] = q;
    Mat3::from_cols(
        Vec3::new(
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y + w * z),
            2.0 * (x * z - w * y),
        ),
        Vec3::new(
            2.0 * (x * y - w * z),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z + w * x),
        ),
        Vec3::new(
            2.0 * (x * z + w * y),
            2.0 * (y * z - w * x),
            1.0 - 2.0 * (x * x + y * y),
        ),
    )
}

/// Backward of [`quat_to_rotation`]: dL/dq given dL/dR (`g`, entry (i, j) = `g.col(j)[i]`).
#[inline]
fn quat_to_rotation_backward(q: [f32; 4], g: Mat3) -> [f32; 4] {
    let [w, x, y, z] = q;
    let (c0, c1, c2) = (g.x_axis, g.y_axis, g.z_axis);
    // g_ij = row i, column j.
    let (g00, g10, g20) = (c0.x, c0.y, c0.z);
    let (g01, g11, g21) = (c1.x, c1.y, c1.z);
    let (g02, g12, g22) = (c2.x, c2.y, c2.z);
    [
        2.0 * (-z * g01 + y * g02 + z * g10 - x * g12 - y * g20 + x * g21),
        2.0 * (y * g01 + z * g02 + y * g10 - 2.0 * x * g11 - w * g12 + z * g20 + w * g21
            - 2.0 * x * g22),
        2.0 * (-2.0 * y * g00 + x * g01 + w * g02 + x * g10 + z * g12 - w * g20 + z * g21
            - 2.0 * y * g22),
        2.0 * (-2.0 * z * g00 - w * g01 + x * g02 + w * g10 - 2.0 * z * g11
            + y * g12
            + x * g20
            + y * g21),
    ]
}

/// World-space covariance Σ = R S Sᵀ Rᵀ of a Gaussian with unit quaternion `quat` ([w, x, y, z])
/// and per-axis standard deviations `scale`.
#[inline]
pub fn covariance_3d(quat: [f32; 4], scale: Vec3) -> Mat3 {
    let m = quat_to_rotation(quat) * Mat3::from_diagonal(scale);
    m * m.transpose()
}

/// Backward of [`covariance_3d`]: (dL/dquat, dL/dscale) given dL/dΣ with every one of the nine
/// entries treated as independent (`d_cov`, entry (i, j) = `d_cov.col(j)[i]`).
#[inline]
pub fn covariance_3d_backward(quat: [f32; 4], scale: Vec3, d_cov: Mat3) -> ([f32; 4], Vec3) {
    let r = quat_to_rotation(quat);
    let m = r * Mat3::from_diagonal(scale);
    // Σ = M Mᵀ → dL/dM = (G + Gᵀ) M.
    let d_m = (d_cov + d_cov.transpose()) * m;
    // M = R diag(s): column j of M is s_j · column j of R.
    let d_scale = Vec3::new(
        d_m.x_axis.dot(r.x_axis),
        d_m.y_axis.dot(r.y_axis),
        d_m.z_axis.dot(r.z_axis),
    );
    let d_r = d_m * Mat3::from_diagonal(scale);
    (quat_to_rotation_backward(quat, d_r), d_scale)
}

/// A Gaussian projected to the screen.
#[derive(Clone, Copy, Debug, Default)]
pub struct Projected {
    /// Centre in pixels (pixel (x, y) has its centre at (x + 0.5, y + 0.5)).
    pub mean2d: Vec2,
    /// Camera-space depth z.
    pub depth: f32,
    /// (a, b, c) of the inverse 2D covariance: power = −½(a·dx² + c·dy²) − b·dx·dy.
    pub conic: [f32; 3],
    /// (xx, xy, yy) of the 2D covariance after the +0.3 dilation.
    pub cov2d: [f32; 3],
    /// Half-size in pixels of the screen box where opacity·G ≥ 1/255.
    pub extent: Vec2,
}

/// Rows of the perspective Jacobian at camera-space point `p`, and for each image axis the
/// clamped coordinate x' (resp. y') and whether the clamp is active.
#[derive(Clone, Copy, Debug)]
struct Jacobian {
    row0: Vec3,
    row1: Vec3,
    tx: f32,
    ty: f32,
    clamped_x: bool,
    clamped_y: bool,
}

#[inline]
fn jacobian(p: Vec3, cam: &Camera) -> Jacobian {
    let inv_z = p.z.recip();
    let lim_x = FOV_CLAMP * 0.5 * cam.width as f32 / cam.fx;
    let lim_y = FOV_CLAMP * 0.5 * cam.height as f32 / cam.fy;
    let (u, v) = (p.x * inv_z, p.y * inv_z);
    let (cu, cv) = (u.clamp(-lim_x, lim_x), v.clamp(-lim_y, lim_y));
    let (tx, ty) = (cu * p.z, cv * p.z);
    Jacobian {
        row0: Vec3::new(cam.fx * inv_z, 0.0, -cam.fx * tx * inv_z * inv_z),
        row1: Vec3::new(0.0, cam.fy * inv_z, -cam.fy * ty * inv_z * inv_z),
        tx,
        ty,
        clamped_x: cu != u,
        clamped_y: cv != v,
    }
}

/// Forward quantities shared by [`project`] and [`project_backward`].
#[derive(Clone, Copy, Debug)]
struct Ewa {
    /// Camera-space mean.
    p: Vec3,
    mean2d: Vec2,
    jac: Jacobian,
    /// Rows of T = J·R_wc (as vectors, T = [t0ᵀ; t1ᵀ]).
    t0: Vec3,
    t1: Vec3,
    cov3: Mat3,
    /// (xx, xy, yy) including the dilation.
    cov2d: [f32; 3],
}

#[inline]
fn ewa(mean: Vec3, quat: [f32; 4], scale: Vec3, cam: &Camera) -> Ewa {
    let w = cam.rotation();
    let p = w * mean + cam.translation();
    let inv_z = p.z.recip();
    let mean2d = Vec2::new(cam.fx * p.x * inv_z + cam.cx, cam.fy * p.y * inv_z + cam.cy);
    let jac = jacobian(p, cam);
    // Row i of J·W is (Wᵀ jᵢ)ᵀ.
    let wt = w.transpose();
    let (t0, t1) = (wt * jac.row0, wt * jac.row1);
    let cov3 = covariance_3d(quat, scale);
    let (s0, s1) = (cov3 * t0, cov3 * t1);
    let cov2d = [t0.dot(s0) + LOW_PASS, t0.dot(s1), t1.dot(s1) + LOW_PASS];
    Ewa {
        p,
        mean2d,
        jac,
        t0,
        t1,
        cov3,
        cov2d,
    }
}

/// Inverse of the symmetric 2×2 matrix (a, b, c) as (a, b, c), or None if not positive
/// definite-ish (det ≤ 0).
#[inline]
fn inverse_2x2(m: [f32; 3]) -> Option<[f32; 3]> {
    let det = m[0] * m[2] - m[1] * m[1];
    if !(det > 0.0) {
        return None;
    }
    let inv = det.recip();
    Some([m[2] * inv, -m[1] * inv, m[0] * inv])
}

/// Projects a Gaussian (world mean, unit quaternion [w, x, y, z], scale, opacity at this
/// time) into `cam`. None when it is behind the near plane, too transparent (opacity < 1/255),
/// degenerate (det cov2d ≤ 0) or when its screen box lies entirely outside the image.
#[inline]
pub fn project(
    mean: Vec3,
    quat: [f32; 4],
    scale: Vec3,
    opacity: f32,
    cam: &Camera,
) -> Option<Projected> {
    project_beyond(mean, quat, scale, opacity, cam, NEAR_PLANE)
}

/// [`project`] with a farther near plane: also None when the camera-space depth is below
/// `near_plane` (which never goes below [`NEAR_PLANE`]).
#[inline]
pub fn project_beyond(
    mean: Vec3,
    quat: [f32; 4],
    scale: Vec3,
    opacity: f32,
    cam: &Camera,
    near_plane: f32,
) -> Option<Projected> {
    if !drawable(opacity) {
        return None;
    }
    let p_z = cam.rotation().row(2).dot(mean) + cam.translation().z;
    if !(p_z >= near_plane.max(NEAR_PLANE)) {
        return None;
    }
    let e = ewa(mean, quat, scale, cam);
    let conic = inverse_2x2(e.cov2d)?;
    // opacity·exp(−½ r²) ≥ 1/255 ⇔ r ≤ sqrt(2 ln(255·opacity)) standard deviations.
    let radius = (2.0 * (255.0 * opacity).ln()).max(0.0).sqrt();
    let extent = Vec2::new(radius * e.cov2d[0].sqrt(), radius * e.cov2d[2].sqrt());
    let (lo, hi) = (e.mean2d - extent, e.mean2d + extent);
    if hi.x <= 0.0 || hi.y <= 0.0 || lo.x >= cam.width as f32 || lo.y >= cam.height as f32 {
        return None;
    }
    Some(Projected {
        mean2d: e.mean2d,
        depth: e.p.z,
        conic,
        cov2d: e.cov2d,
        extent,
    })
}

/// Whether `cam` sees the Gaussian whatever its opacity, as the 3DGS rasterizer decides which
/// Gaussians are "visible" (radius > 0) for its densification statistics: in front of the near
/// plane, a non-degenerate 2D covariance, and a 3σ screen box that overlaps the image.
/// [`project_beyond`] additionally drops Gaussians fainter than 1/255, which draw nothing.
// The negated comparisons put NaN depths and determinants outside.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
pub fn in_frustum(mean: Vec3, quat: [f32; 4], scale: Vec3, cam: &Camera, near_plane: f32) -> bool {
    let p_z = cam.rotation().row(2).dot(mean) + cam.translation().z;
    if !(p_z >= near_plane.max(NEAR_PLANE)) {
        return false;
    }
    let e = ewa(mean, quat, scale, cam);
    let det = e.cov2d[0] * e.cov2d[2] - e.cov2d[1] * e.cov2d[1];
    if !(det > 0.0) {
        return false;
    }
    let extent = 3.0 * Vec2::new(e.cov2d[0].sqrt(), e.cov2d[2].sqrt());
    let (lo, hi) = (e.mean2d - extent, e.mean2d + extent);
    hi.x > 0.0 && hi.y > 0.0 && lo.x < cam.width as f32 && lo.y < cam.height as f32
}

/// Gradient of a loss with respect to the inputs of [`project`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ProjectGrad {
    /// dL/d world mean.
    pub mean: Vec3,
    /// dL/d quaternion components [w, x, y, z] (as used, i.e. already normalised; chain through
    /// the normalisation with [`super::deform::rotation_at_backward`]).
    pub quat: [f32; 4],
    /// dL/d scale.
    pub scale: Vec3,
}

/// Backward of [`project`] given dL/d mean2d and dL/d conic.
///
/// Conic convention: `d_conic` = (dL/da, dL/db, dL/dc) where the off-diagonal b appears once,
/// as in power = −½(a·dx² + c·dy²) − b·dx·dy (so the rasterizer's dL/db = −dx·dy·dL/dpower).
/// The mean receives gradient through mean2d and through the Jacobian; where x/z (y/z) is
/// clamped to the field of view, x' = ±lim·z, so there is no gradient through x' to x and the
/// z derivative is the exact one of the clamped expression (3DGS/gsplat instead hold x' fixed
/// there, which doubles that term; both agree inside the clamp). The depth and extent are not
/// differentiated. Must only be called for Gaussians that [`project`] kept (det > 0).
#[inline]
pub fn project_backward(
    mean: Vec3,
    quat: [f32; 4],
    scale: Vec3,
    cam: &Camera,
    d_mean2d: Vec2,
    d_conic: [f32; 3],
) -> ProjectGrad {
    let e = ewa(mean, quat, scale, cam);
    let q = inverse_2x2(e.cov2d).unwrap_or([0.0; 3]);

    // Conic Q = C⁻¹ → dL/dC = −Q·Gq·Q, with Gq the symmetric matrix gradient whose
    // off-diagonal entries each carry half of dL/db.
    let gq = [d_conic[0], 0.5 * d_conic[1], d_conic[2]];
    // Symmetric products of 2×2 matrices stored as (00, 01, 11); Q·Gq is not symmetric.
    let qg00 = q[0] * gq[0] + q[1] * gq[1];
    let qg01 = q[0] * gq[1] + q[1] * gq[2];
    let qg10 = q[1] * gq[0] + q[2] * gq[1];
    let qg11 = q[1] * gq[1] + q[2] * gq[2];
    let g00 = -(qg00 * q[0] + qg01 * q[1]);
    let g01 = -(qg00 * q[1] + qg01 * q[2]);
    let g11 = -(qg10 * q[1] + qg11 * q[2]);

    // C = T Σ Tᵀ (+ const): dL/dtᵢ = 2 Σⱼ Gᵢⱼ Σ tⱼ, dL/dΣ = Σᵢⱼ Gᵢⱼ tᵢ tⱼᵀ.
    let (t0, t1) = (e.t0, e.t1);
    let (s0, s1) = (e.cov3 * t0, e.cov3 * t1);
    let d_t0 = 2.0 * (g00 * s0 + g01 * s1);
    let d_t1 = 2.0 * (g11 * s1 + g01 * s0);
    let outer = |a: Vec3, b: Vec3| Mat3::from_cols(a * b.x, a * b.y, a * b.z);
    let d_cov3 = g00 * outer(t0, t0) + g01 * (outer(t0, t1) + outer(t1, t0)) + g11 * outer(t1, t1);

    // tᵢ = Wᵀ jᵢ → dL/djᵢ = W dL/dtᵢ.
    let w = cam.rotation();
    let (d_j0, d_j1) = (w * d_t0, w * d_t1);

    let (fx, fy) = (cam.fx, cam.fy);
    let p = e.p;
    let inv_z = p.z.recip();
    let inv_z2 = inv_z * inv_z;
    let inv_z3 = inv_z2 * inv_z;
    let jac = e.jac;
    // Through mean2d = (fx x/z + cx, fy y/z + cy).
    let mut d_p = Vec3::new(
        fx * inv_z * d_mean2d.x,
        fy * inv_z * d_mean2d.y,
        -(fx * p.x * d_mean2d.x + fy * p.y * d_mean2d.y) * inv_z2,
    );
    // Through J00 = fx/z, J11 = fy/z.
    d_p.z -= (fx * d_j0.x + fy * d_j1.y) * inv_z2;
    // Through J02 = −fx x'/z²: ∂x'/∂x = 1, ∂x'/∂z = 0 inside the clamp; 0 and x'/z outside.
    let (dj02, dj12) = (d_j0.z, d_j1.z);
    if jac.clamped_x {
        d_p.z += fx * jac.tx * inv_z3 * dj02;
    } else {
        d_p.x -= fx * inv_z2 * dj02;
        d_p.z += 2.0 * fx * jac.tx * inv_z3 * dj02;
    }
    if jac.clamped_y {
        d_p.z += fy * jac.ty * inv_z3 * dj12;
    } else {
        d_p.y -= fy * inv_z2 * dj12;
        d_p.z += 2.0 * fy * jac.ty * inv_z3 * dj12;
    }

    let (d_quat, d_scale) = covariance_3d_backward(quat, scale, d_cov3);
    ProjectGrad {
        mean: w.transpose() * d_p,
        quat: d_quat,
        scale: d_scale,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::fd::{Fd, assert_grad, central};
    use glam::{DMat3, DVec2, DVec3, Quat};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn camera() -> Camera {
        Camera::look_at(
            Vec3::new(0.5, -0.3, -4.0),
            Vec3::new(0.1, 0.2, 0.0),
            Vec3::Y,
            64,
            48,
            1.0,
        )
    }

    fn random_quat(rng: &mut ChaCha8Rng) -> [f32; 4] {
        let q: [f32; 4] = std::array::from_fn(|_| rng.random_range(-1.0..1.0));
        let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
        q.map(|v| v / n)
    }

    #[test]
    fn rotation_matches_glam() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for _ in 0..8 {
            let q = random_quat(&mut rng);
            let expect = Mat3::from_quat(Quat::from_xyzw(q[1], q[2], q[3], q[0]));
            assert!(quat_to_rotation(q).abs_diff_eq(expect, 1e-6));
        }
    }

    #[test]
    fn covariance_examples() {
        let s = Vec3::new(1.0, 2.0, 3.0);
        let id = covariance_3d([1.0, 0.0, 0.0, 0.0], s);
        assert!(id.abs_diff_eq(Mat3::from_diagonal(s * s), 1e-6));
        // 90° about z swaps the x and y variances.
        let h = 0.5f32.sqrt();
        let rz = covariance_3d([h, 0.0, 0.0, h], s);
        assert!(rz.abs_diff_eq(Mat3::from_diagonal(Vec3::new(4.0, 1.0, 9.0)), 1e-5));
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let c = covariance_3d(random_quat(&mut rng), s);
        assert!(c.abs_diff_eq(c.transpose(), 1e-5));
        assert!((c.determinant() - 36.0).abs() < 1e-3);
    }

    #[test]
    fn projects_on_axis_gaussian() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 100, 80, 1.0);
        let pr = project(
            Vec3::ZERO,
            [1.0, 0.0, 0.0, 0.0],
            Vec3::splat(0.1),
            1.0,
            &cam,
        )
        .unwrap();
        assert!((pr.mean2d - Vec2::new(50.0, 40.0)).length() < 1e-4);
        assert!((pr.depth - 5.0).abs() < 1e-5);
        let var = (cam.fx * 0.1 / 5.0).powi(2) + LOW_PASS;
        assert!(
            (pr.cov2d[0] - var).abs() < 1e-3
                && (pr.cov2d[2] - var).abs() < 1e-3
                && pr.cov2d[1].abs() < 1e-5
        );
        assert!((pr.conic[0] - 1.0 / var).abs() < 1e-5 && (pr.conic[2] - 1.0 / var).abs() < 1e-5);
        // At opacity 1 the box is sqrt(2 ln 255) ≈ 3.33 σ.
        let r = (2.0 * 255.0f32.ln()).sqrt();
        assert!((pr.extent.x - r * var.sqrt()).abs() < 1e-4);
        let half = project(
            Vec3::ZERO,
            [1.0, 0.0, 0.0, 0.0],
            Vec3::splat(0.1),
            0.5,
            &cam,
        )
        .unwrap();
        assert!(half.extent.x < pr.extent.x);
    }

    #[test]
    fn conic_inverts_cov2d() {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for _ in 0..8 {
            let q = random_quat(&mut rng);
            let s = Vec3::new(
                rng.random_range(0.02..0.5),
                rng.random_range(0.02..0.5),
                rng.random_range(0.02..0.5),
            );
            let pr = project(Vec3::ZERO, q, s, 0.8, &cam).unwrap();
            let [a, b, c] = pr.cov2d;
            let [ia, ib, ic] = pr.conic;
            assert!((a * ia + b * ib - 1.0).abs() < 1e-4);
            assert!((a * ib + b * ic).abs() < 1e-4);
            assert!((b * ib + c * ic - 1.0).abs() < 1e-4);
        }
    }

    #[test]
    fn culling() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 100, 80, 1.0);
        let q = [1.0, 0.0, 0.0, 0.0];
        let s = Vec3::splat(0.05);
        // Behind the camera and at the near plane.
        assert!(project(Vec3::new(0.0, 0.0, -6.0), q, s, 1.0, &cam).is_none());
        assert!(
            project(
                Vec3::new(0.0, 0.0, -5.0 + 0.5 * NEAR_PLANE),
                q,
                s,
                1.0,
                &cam
            )
            .is_none()
        );
        // Too transparent.
        assert!(project(Vec3::ZERO, q, s, 0.9 / 255.0, &cam).is_none());
        assert!(project(Vec3::ZERO, q, s, 1.1 / 255.0, &cam).is_some());
        // Off to the side: box entirely outside the image.
        assert!(project(Vec3::new(10.0, 0.0, 0.0), q, s, 1.0, &cam).is_none());
        assert!(project(Vec3::new(0.0, -10.0, 0.0), q, s, 1.0, &cam).is_none());
        // Centre outside but box overlapping the image: kept.
        let edge = project(Vec3::new(2.9, 0.0, 0.0), q, Vec3::splat(0.3), 1.0, &cam);
        let pr = edge.expect("overlapping box is kept");
        assert!(pr.mean2d.x - 100.0 > 0.0 || pr.mean2d.x < 0.0);
    }

    /// The projection's (mean2d, conic) re-evaluated in f64, without the culling, so that finite
    /// differences are free of f32 round-off (the conic depends on small covariance entries
    /// next to the 0.3 dilation, where f32 differences are mostly noise). Same formulas as
    /// `ewa`, written with full matrix products instead of Jacobian rows.
    fn project_f64(mean: DVec3, quat: [f64; 4], scale: DVec3, cam: &Camera) -> (DVec2, [f64; 3]) {
        let w = cam.rotation().as_dmat3();
        let p = w * mean + cam.translation().as_dvec3();
        let (fx, fy) = (cam.fx as f64, cam.fy as f64);
        let mean2d = DVec2::new(
            fx * p.x / p.z + cam.cx as f64,
            fy * p.y / p.z + cam.cy as f64,
        );
        let lim_x = 1.3 * 0.5 * cam.width as f64 / fx;
        let lim_y = 1.3 * 0.5 * cam.height as f64 / fy;
        let tx = (p.x / p.z).clamp(-lim_x, lim_x) * p.z;
        let ty = (p.y / p.z).clamp(-lim_y, lim_y) * p.z;
        // J as the top two rows of a 3×3 matrix (third row zero).
        let j = DMat3::from_cols(
            DVec3::new(fx / p.z, 0.0, 0.0),
            DVec3::new(0.0, fy / p.z, 0.0),
            DVec3::new(-fx * tx / (p.z * p.z), -fy * ty / (p.z * p.z), 0.0),
        );
        let [qw, qx, qy, qz] = quat;
        let r = DMat3::from_cols(
            DVec3::new(
                1.0 - 2.0 * (qy * qy + qz * qz),
                2.0 * (qx * qy + qw * qz),
                2.0 * (qx * qz - qw * qy),
            ),
            DVec3::new(
                2.0 * (qx * qy - qw * qz),
                1.0 - 2.0 * (qx * qx + qz * qz),
                2.0 * (qy * qz + qw * qx),
            ),
            DVec3::new(
                2.0 * (qx * qz + qw * qy),
                2.0 * (qy * qz - qw * qx),
                1.0 - 2.0 * (qx * qx + qy * qy),
            ),
        );
        let m = r * DMat3::from_diagonal(scale);
        let t = j * w;
        let cov = t * m * m.transpose() * t.transpose();
        let (a, b, c) = (cov.x_axis.x + 0.3, cov.y_axis.x, cov.y_axis.y + 0.3);
        let det = a * c - b * b;
        (mean2d, [c / det, -b / det, a / det])
    }

    /// Fourth-order central difference in f64.
    fn central_f64(f: impl Fn(f64) -> f64, x: f64, h: f64) -> f64 {
        (8.0 * (f(x + h) - f(x - h)) - (f(x + 2.0 * h) - f(x - 2.0 * h))) / (12.0 * h)
    }

    fn check_project_grad(
        mean: Vec3,
        quat: [f32; 4],
        scale: Vec3,
        cam: &Camera,
        rng: &mut ChaCha8Rng,
    ) {
        // The f32 forward agrees with the f64 reference.
        let (m64, c64) = project_f64(mean.as_dvec3(), quat.map(f64::from), scale.as_dvec3(), cam);
        let e = ewa(mean, quat, scale, cam);
        let conic = inverse_2x2(e.cov2d).unwrap();
        assert!((e.mean2d.as_dvec2() - m64).length() < 1e-4 * m64.length());
        for k in 0..3 {
            assert!((conic[k] as f64 - c64[k]).abs() < 1e-4 * (c64[0].abs() + c64[2].abs()));
        }
        // Each output separately (one-hot upstream gradients), then a random mix.
        let mut upstream: Vec<(Vec2, [f32; 3])> = vec![
            (Vec2::X, [0.0; 3]),
            (Vec2::Y, [0.0; 3]),
            (Vec2::ZERO, [1.0, 0.0, 0.0]),
            (Vec2::ZERO, [0.0, 1.0, 0.0]),
            (Vec2::ZERO, [0.0, 0.0, 1.0]),
        ];
        upstream.push((
            Vec2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)),
            std::array::from_fn(|_| rng.random_range(-1.0..1.0)),
        ));
        let (mean, quat, scale) = (mean.as_dvec3(), quat.map(f64::from), scale.as_dvec3());
        for (d_mean2d, d_conic) in upstream {
            let g = project_backward(
                mean.as_vec3(),
                quat.map(|v| v as f32),
                scale.as_vec3(),
                cam,
                d_mean2d,
                d_conic,
            );
            let (dm, dc) = (d_mean2d.as_dvec2(), d_conic.map(f64::from));
            let loss = |m: DVec3, q: [f64; 4], s: DVec3| {
                let (m2, c) = project_f64(m, q, s, cam);
                dm.dot(m2) + dc[0] * c[0] + dc[1] * c[1] + dc[2] * c[2]
            };
            let mut fd_mean = [0.0; 3];
            let mut fd_scale = [0.0; 3];
            let mut fd_quat = [0.0; 4];
            for k in 0..3 {
                let h = 1e-4;
                fd_mean[k] = central_f64(
                    |v| {
                        let mut m = mean;
                        m[k] = v;
                        loss(m, quat, scale)
                    },
                    mean[k],
                    h,
                );
                fd_scale[k] = central_f64(
                    |v| {
                        let mut s = scale;
                        s[k] = v;
                        loss(mean, quat, s)
                    },
                    scale[k],
                    h * scale[k],
                );
            }
            for k in 0..4 {
                fd_quat[k] = central_f64(
                    |v| {
                        let mut q = quat;
                        q[k] = v;
                        loss(mean, q, scale)
                    },
                    quat[k],
                    1e-4,
                );
            }
            // The f64 differences are accurate to ~1e-9 relative, so the only floor needed is
            // for the f32 analytic gradient itself: it is assembled from terms (e.g. of
            // −Q·Gq·Q and the Jacobian chain) that can be much larger than a component that
            // nearly cancels, so allow 1e-5 of the largest gradient component of this call
            // (~100 f32 roundings of the largest term).
            let largest = fd_mean
                .iter()
                .chain(&fd_scale)
                .chain(&fd_quat)
                .fold(0.0f64, |m, v| m.max(v.abs()));
            let floor = (1e-5 * largest) as f32;
            let check = |name: &str, analytic: f32, fd: f64| {
                assert_grad(
                    name,
                    analytic,
                    Fd {
                        value: fd as f32,
                        noise: floor,
                    },
                );
            };
            for k in 0..3 {
                check("mean", g.mean[k], fd_mean[k]);
                check("scale", g.scale[k], fd_scale[k]);
            }
            for k in 0..4 {
                check("quat", g.quat[k], fd_quat[k]);
            }
        }
    }

    #[test]
    fn project_backward_matches_fd() {
        let cam = camera();
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        let mut tested = 0;
        while tested < 12 {
            let mean = Vec3::new(
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
                rng.random_range(-1.0..1.0),
            );
            let quat = random_quat(&mut rng);
            let scale = Vec3::new(
                rng.random_range(0.05..0.4),
                rng.random_range(0.05..0.4),
                rng.random_range(0.05..0.4),
            );
            if project(mean, quat, scale, 0.9, &cam).is_none() {
                continue;
            }
            check_project_grad(mean, quat, scale, &cam, &mut rng);
            tested += 1;
        }
    }

    #[test]
    fn project_backward_matches_fd_when_clamped() {
        let cam = Camera::look_at(Vec3::new(0.0, 0.0, -5.0), Vec3::ZERO, Vec3::Y, 100, 80, 1.0);
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        // Far outside the field of view along x, y and both (camera-space x/z ≈ 1, y/z ≈ −1.2).
        for mean in [
            Vec3::new(-5.0, 0.3, 0.0),
            Vec3::new(0.2, 6.0, 0.0),
            Vec3::new(-5.0, 6.0, 1.0),
        ] {
            let p = cam.world_to_camera.transform_point3(mean);
            let j = jacobian(p, &cam);
            assert!(j.clamped_x || j.clamped_y);
            let quat = random_quat(&mut rng);
            check_project_grad(mean, quat, Vec3::new(0.3, 0.1, 0.2), &cam, &mut rng);
        }
    }

    #[test]
    fn covariance_backward_matches_fd() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for _ in 0..8 {
            let quat = random_quat(&mut rng);
            let scale = Vec3::new(
                rng.random_range(0.1..2.0),
                rng.random_range(0.1..2.0),
                rng.random_range(0.1..2.0),
            );
            let d_cov =
                Mat3::from_cols_array(&std::array::from_fn(|_| rng.random_range(-1.0..1.0)));
            let loss = |q: [f32; 4], s: Vec3| {
                let c = covariance_3d(q, s);
                (0..3).map(|j| c.col(j).dot(d_cov.col(j))).sum::<f32>()
            };
            let (gq, gs) = covariance_3d_backward(quat, scale, d_cov);
            for k in 0..4 {
                let fd = central(
                    |v| {
                        let mut q = quat;
                        q[k] = v;
                        loss(q, scale)
                    },
                    quat[k],
                    1e-2,
                );
                assert_grad("quat", gq[k], fd);
            }
            for k in 0..3 {
                let fd = central(
                    |v| {
                        let mut s = scale;
                        s[k] = v;
                        loss(quat, s)
                    },
                    scale[k],
                    1e-2,
                );
                assert_grad("scale", gs[k], fd);
            }
        }
    }
}
