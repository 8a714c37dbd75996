//! Pure per-Gaussian maths (SPEC §2–4): the temporal warp, the deformation at time t
//! (motion, opacity, rotation, scale), spherical-harmonics colour and EWA projection, each
//! with a hand-written backward pass checked against finite differences; and the per-camera
//! exposure compensation applied to a whole render before the loss ([`exposure`]); Adam's
//! update rule ([`adam`]); the motion-smoothness regulariser over a neighbour graph
//! ([`smoothness`]); and the motion bases shared by every Gaussian ([`shared_motion`]).
//!
//! The per-Gaussian maths is allocation-free and works on one Gaussian at a time.

pub mod adam;
pub mod deform;
pub mod exposure;
pub mod project;
pub mod project_lanes;
pub mod sh;
pub mod shared_motion;
pub mod smoothness;
pub mod warp;

pub use deform::{
    ASYMMETRIC_MAX_WIDTH, FOURIER_TERMS, FourierGrad, MotionBasis, TemporalOpacity, fourier_offset,
    fourier_offset_backward, fourier_velocity, fourier_velocity_backward, init_temporal_raw,
    lifespan_fraction, logit, rotation_at, rotation_at_backward, scale_at, scale_at_backward,
    sigmoid, temporal_opacity, temporal_opacity_backward,
};
pub use exposure::Exposure;
pub use project::{
    LOW_PASS, NEAR_PLANE, ProjectGrad, Projected, covariance_3d, covariance_3d_backward, project,
    project_backward, quat_to_rotation,
};
pub use sh::{SH_COEFFS, rgb_to_sh_dc, sh_to_rgb, sh_to_rgb_backward};
pub use warp::TimeWarp;

/// Finite-difference helpers shared by the gradient tests of this module.
#[cfg(test)]
pub(crate) mod fd {
    /// Relative tolerance between analytic and finite-difference gradients.
    pub const REL_TOL: f32 = 1e-3;

    /// A finite-difference derivative and the size of its round-off error.
    #[derive(Clone, Copy, Debug)]
    pub struct Fd {
        pub value: f32,
        /// Absolute floor for the comparison. The forward functions run in f32, so each
        /// evaluation carries an absolute error δ of a few ulps of |f| (we allow δ = 4ε·|f|);
        /// the five-point quotient below combines four evaluations with weights 8, 8, 1, 1
        /// over 12h, i.e. an error up to 18δ/(12h) = 6ε·|f|/h. Below this level the FD value
        /// is rounding noise, not a gradient.
        pub noise: f32,
    }

    /// Fourth-order central difference of `f` at `x` with step `h`:
    /// (8(f(x+h) − f(x−h)) − (f(x+2h) − f(x−2h))) / 12h. Its truncation error is O(h⁴), so a
    /// fairly large step (≈ 1e-2 of the scale on which f varies) keeps it far below the 1e-3
    /// tolerance while the round-off (∝ 1/h) stays small.
    pub fn central(f: impl Fn(f32) -> f32, x: f32, h: f32) -> Fd {
        let (f1, fm1, f2, fm2) = (f(x + h), f(x - h), f(x + 2.0 * h), f(x - 2.0 * h));
        let value = (8.0 * (f1 - fm1) - (f2 - fm2)) / (12.0 * h);
        let magnitude = f1.abs().max(fm1.abs()).max(f2.abs()).max(fm2.abs());
        Fd {
            value,
            noise: 6.0 * f32::EPSILON * magnitude / h,
        }
    }

    /// Asserts |analytic − fd| ≤ REL_TOL·max(|fd|, |analytic|) + noise floor.
    #[track_caller]
    pub fn assert_grad(name: &str, analytic: f32, fd: Fd) {
        let err = (analytic - fd.value).abs();
        let bound = REL_TOL * fd.value.abs().max(analytic.abs()) + fd.noise;
        assert!(
            err <= bound,
            "{name}: analytic {analytic} vs finite difference {} (error {err}, bound {bound})",
            fd.value
        );
    }
}
