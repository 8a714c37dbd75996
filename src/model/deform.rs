//! Deformation of a Gaussian at time t (SPEC §2): Fourier motion, temporal opacity,
//! polynomial rotation and scale, with their backward passes.
//!
//! Every function takes the warped offset `dtw` = W(t − t_i) (see [`TimeWarp`]). The paper
//! keeps the temporal centre t_i fixed at its anchor frame; where it is learnt
//! (`train.lr.temporal_center` > 0), its gradient is [`centre_gradient`] of the dL/d(dtw)
//! that the backward functions below give beside their parameter gradients.

use std::f32::consts::TAU;

use glam::Vec3;

use super::warp::TimeWarp;
use crate::components::TimeWindow;

/// Number K of Fourier frequencies of the motion.
pub const FOURIER_TERMS: usize = 4;

/// ln 5: σ(t)/σ^s = 0.2 ⇔ the exponent of the temporal Gaussian is −ln 5.
const LN_5: f32 = 1.609_438;

/// Largest width w of the asymmetric temporal opacity (implementation form).
pub const ASYMMETRIC_MAX_WIDTH: f32 = 1.1;

/// How the Fourier motion reads time: its phases and the period of its lowest frequency.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionBasis {
    /// One phase φ shared by the K frequencies (paper) rather than one per frequency.
    pub shared_phase: bool,
    /// Period P of the lowest frequency in normalised time (paper: 1). With P = 1 a Gaussian
    /// that lives the whole sequence (dtw spanning a unit interval) ends where it started;
    /// P = 2 lets it end elsewhere.
    pub period: f32,
}

impl MotionBasis {
    /// The paper's basis: one phase per Gaussian, period 1.
    pub const PAPER: Self = Self {
        shared_phase: true,
        period: 1.0,
    };

    /// Index of the phase that frequency f (0-based) uses: 0 when shared, else f.
    #[inline]
    fn phase_slot(&self, f: usize) -> usize {
        if self.shared_phase { 0 } else { f }
    }

    /// Angular frequency ω_f = 2πf/P of frequency f (0-based index).
    #[inline]
    fn frequency(&self, f: usize) -> f32 {
        TAU * (f + 1) as f32 / self.period
    }

    /// Angle ω_f·dtw + φ_f of frequency f (0-based index).
    #[inline]
    fn angle(&self, phase: &[f32; FOURIER_TERMS], f: usize, dtw: f32) -> f32 {
        self.frequency(f) * dtw + phase[self.phase_slot(f)]
    }
}

/// Motion offset μ(t) − μ = Σ_{f=1..K} (M^c_f cos(2πf·dtw/P + φ_f) + M^s_f sin(2πf·dtw/P + φ_f)).
///
/// φ_f = `phase[0]` for every f with a shared phase (paper: one phase per Gaussian), else
/// `phase[f − 1]` (implementation: one per frequency); P is the basis period (paper: 1).
#[inline]
pub fn fourier_offset(
    cos: &[[f32; 3]; FOURIER_TERMS],
    sin: &[[f32; 3]; FOURIER_TERMS],
    phase: &[f32; FOURIER_TERMS],
    basis: MotionBasis,
    dtw: f32,
) -> Vec3 {
    let mut out = Vec3::ZERO;
    for f in 0..FOURIER_TERMS {
        let angle = basis.angle(phase, f, dtw);
        let (s, c) = angle.sin_cos();
        out += Vec3::from(cos[f]) * c + Vec3::from(sin[f]) * s;
    }
    out
}

/// Gradient of a loss with respect to the Fourier motion parameters.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FourierGrad {
    /// dL/dM^c.
    pub cos: [[f32; 3]; FOURIER_TERMS],
    /// dL/dM^s.
    pub sin: [[f32; 3]; FOURIER_TERMS],
    /// dL/dφ (only `phase[0]` is non-zero with a shared phase).
    pub phase: [f32; FOURIER_TERMS],
    /// dL/d(dtw) through the motion: Σ_f (2πf/P)·dL/dangle_f.
    pub dtw: f32,
}

/// Backward of [`fourier_offset`] given `d_offset` = dL/d(offset).
#[inline]
pub fn fourier_offset_backward(
    cos: &[[f32; 3]; FOURIER_TERMS],
    sin: &[[f32; 3]; FOURIER_TERMS],
    phase: &[f32; FOURIER_TERMS],
    basis: MotionBasis,
    dtw: f32,
    d_offset: Vec3,
) -> FourierGrad {
    let mut grad = FourierGrad::default();
    for f in 0..FOURIER_TERMS {
        let angle = basis.angle(phase, f, dtw);
        let (s, c) = angle.sin_cos();
        grad.cos[f] = (d_offset * c).to_array();
        grad.sin[f] = (d_offset * s).to_array();
        // d/dangle (M^c cos + M^s sin) = −M^c sin + M^s cos.
        let d_angle = d_offset.dot(Vec3::from(sin[f]) * c - Vec3::from(cos[f]) * s);
        grad.phase[basis.phase_slot(f)] += d_angle;
        grad.dtw += d_angle * basis.frequency(f);
    }
    grad
}

/// Velocity of the Fourier motion in warped time, d(μ(t) − μ)/d(dtw) =
/// Σ_f ω_f (M^s_f cos a_f − M^c_f sin a_f) with a_f = ω_f·dtw + φ_f and ω_f = 2πf/P: the
/// quantity the motion-smoothness regulariser compares between neighbours.
#[inline]
pub fn fourier_velocity(
    cos: &[[f32; 3]; FOURIER_TERMS],
    sin: &[[f32; 3]; FOURIER_TERMS],
    phase: &[f32; FOURIER_TERMS],
    basis: MotionBasis,
    dtw: f32,
) -> Vec3 {
    let mut out = Vec3::ZERO;
    for f in 0..FOURIER_TERMS {
        let (s, c) = basis.angle(phase, f, dtw).sin_cos();
        out += basis.frequency(f) * (Vec3::from(sin[f]) * c - Vec3::from(cos[f]) * s);
    }
    out
}

/// Backward of [`fourier_velocity`] given `d_velocity` = dL/d(velocity), with the warped time
/// held constant (the regulariser shapes trajectories, not lifespans): `dtw` of the result is 0.
#[inline]
pub fn fourier_velocity_backward(
    cos: &[[f32; 3]; FOURIER_TERMS],
    sin: &[[f32; 3]; FOURIER_TERMS],
    phase: &[f32; FOURIER_TERMS],
    basis: MotionBasis,
    dtw: f32,
    d_velocity: Vec3,
) -> FourierGrad {
    let mut grad = FourierGrad::default();
    for f in 0..FOURIER_TERMS {
        let (s, c) = basis.angle(phase, f, dtw).sin_cos();
        let w = basis.frequency(f);
        grad.cos[f] = (d_velocity * (-w * s)).to_array();
        grad.sin[f] = (d_velocity * (w * c)).to_array();
        // d/da (M^s cos a − M^c sin a) = −(M^s sin a + M^c cos a).
        let d_angle = -w * d_velocity.dot(Vec3::from(sin[f]) * s + Vec3::from(cos[f]) * c);
        grad.phase[basis.phase_slot(f)] += d_angle;
    }
    grad
}

/// Form of the temporal opacity σ(t)/σ^s.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TemporalOpacity {
    /// Paper: exp(−ψ·dtw²) with ψ = exp(`temporal_raw[0]`).
    Rbf,
    /// Implementation: exp(−(dtw/w)²) with separate left (dtw < 0, `temporal_raw[0]`) and
    /// right (dtw ≥ 0, `temporal_raw[1]`) widths w = min(w_min·exp(s), 1.1).
    Asymmetric {
        /// Smallest width w_min (the width at s = 0).
        w_min: f32,
    },
}

impl TemporalOpacity {
    /// The asymmetric form for a `frame_count`-frame sequence:
    /// w_min = h / sqrt(−ln 0.2) with h = ((50 − 1)/2)/(T − 1), so that at s = 0 the factor
    /// exp(−(dtw/w)²) falls to 0.2 at |dtw| = h, as in the authors' implementation. (SPEC §2
    /// writes exp(−½(dtw/w)²), which with this w_min is √2 wider than the authors' code.)
    pub fn asymmetric(frame_count: usize) -> Self {
        let h = 0.5 * (50.0 - 1.0) / frame_intervals(frame_count);
        Self::Asymmetric {
            w_min: h / LN_5.sqrt(),
        }
    }
}

/// T − 1 (at least 1), the normalised-time length of one frame's reciprocal.
#[inline]
fn frame_intervals(frame_count: usize) -> f32 {
    (frame_count.max(2) - 1) as f32
}

/// Logistic sigmoid 1/(1 + e^−x), stable for large |x|.
#[inline]
pub fn sigmoid(x: f32) -> f32 {
    if x >= 0.0 {
        1.0 / (1.0 + (-x).exp())
    } else {
        let e = x.exp();
        e / (1.0 + e)
    }
}

/// Inverse of [`sigmoid`]: ln(p/(1 − p)), with p clamped into [1e-6, 1 − 1e-6] to stay finite.
#[inline]
pub fn logit(p: f32) -> f32 {
    let p = p.clamp(1e-6, 1.0 - 1e-6);
    (p / (1.0 - p)).ln()
}

/// Asymmetric width for the side of `dtw`: (index of the raw value, w, whether w is clamped).
#[inline]
fn asymmetric_width(w_min: f32, temporal_raw: [f32; 2], dtw: f32) -> (usize, f32, bool) {
    let side = usize::from(dtw >= 0.0);
    let w = w_min * temporal_raw[side].exp();
    if w > ASYMMETRIC_MAX_WIDTH {
        (side, ASYMMETRIC_MAX_WIDTH, true)
    } else {
        (side, w, false)
    }
}

/// Temporal factor σ(t)/σ^s and the derivative of its exponent with respect to the raw
/// value it depends on (index, d exponent / d raw).
#[inline]
fn temporal_factor(model: TemporalOpacity, temporal_raw: [f32; 2], dtw: f32) -> (f32, usize, f32) {
    match model {
        TemporalOpacity::Rbf => {
            let psi = temporal_raw[0].exp();
            let e = -psi * dtw * dtw;
            // d(−ψ dtw²)/d raw = −ψ dtw² (ψ = e^raw).
            (e.exp(), 0, e)
        }
        TemporalOpacity::Asymmetric { w_min } => {
            let (side, w, clamped) = asymmetric_width(w_min, temporal_raw, dtw);
            let r2 = (dtw / w) * (dtw / w);
            // d(−dtw²/w²)/ds = 2·dtw²/w² (w = w_min e^s); zero through the clamp.
            ((-r2).exp(), side, if clamped { 0.0 } else { 2.0 * r2 })
        }
    }
}

/// Opacity at time t: σ(t) = sigmoid(opacity_logit)·(σ(t)/σ^s) where the temporal factor is
/// exp(−ψ·dtw²), ψ = exp(`temporal_raw[0]`) for [`TemporalOpacity::Rbf`] and
/// exp(−(dtw/w)²), w = min(w_min·exp(s), 1.1), s = `temporal_raw[0]` for dtw < 0 and
/// `temporal_raw[1]` for dtw ≥ 0, for [`TemporalOpacity::Asymmetric`].
#[inline]
pub fn temporal_opacity(
    model: TemporalOpacity,
    opacity_logit: f32,
    temporal_raw: [f32; 2],
    dtw: f32,
) -> f32 {
    sigmoid(opacity_logit) * temporal_factor(model, temporal_raw, dtw).0
}

/// Opacity factor of a [`TimeWindow`] at normalised time `time`: the product of a rising
/// ramp centred on `start` and a falling one centred on `end`, each `fade` wide (steps when
/// `fade` is 0). Two windows that share an end sum to 1 across it. It does not depend on any
/// optimised parameter, so its backward is a scaling of dL/dσ by the same factor.
#[inline]
pub fn window_factor(window: &TimeWindow, time: f32) -> f32 {
    if window.fade > 0.0 {
        let ramp = |distance_inside: f32| (distance_inside / window.fade + 0.5).clamp(0.0, 1.0);
        ramp(time - window.start) * ramp(window.end - time)
    } else {
        // The end is exclusive, so a time on a shared end belongs to one window.
        f32::from((window.start..window.end).contains(&time))
    }
}

/// Backward of [`temporal_opacity`]: (dL/d opacity_logit, dL/d temporal_raw) given
/// `d_sigma` = dL/dσ(t). The gradient through a clamped asymmetric width is 0.
#[inline]
pub fn temporal_opacity_backward(
    model: TemporalOpacity,
    opacity_logit: f32,
    temporal_raw: [f32; 2],
    dtw: f32,
    d_sigma: f32,
) -> (f32, [f32; 2]) {
    let spatial = sigmoid(opacity_logit);
    let (factor, index, d_exponent) = temporal_factor(model, temporal_raw, dtw);
    let sigma = spatial * factor;
    let mut d_raw = [0.0; 2];
    d_raw[index] = d_sigma * sigma * d_exponent;
    (d_sigma * factor * spatial * (1.0 - spatial), d_raw)
}

/// dL/d(dtw) through the temporal opacity, given `d_sigma` = dL/dσ(t): σ(t)·d exponent/d dtw,
/// with exponent −ψ·dtw² (Rbf) or −(dtw/w)² (asymmetric, w of the side dtw is on).
#[inline]
pub fn temporal_opacity_dtw_backward(
    model: TemporalOpacity,
    opacity_logit: f32,
    temporal_raw: [f32; 2],
    dtw: f32,
    d_sigma: f32,
) -> f32 {
    let sigma = temporal_opacity(model, opacity_logit, temporal_raw, dtw);
    let d_exponent = match model {
        TemporalOpacity::Rbf => -2.0 * temporal_raw[0].exp() * dtw,
        TemporalOpacity::Asymmetric { w_min } => {
            let w = asymmetric_width(w_min, temporal_raw, dtw).1;
            -2.0 * dtw / (w * w)
        }
    };
    d_sigma * sigma * d_exponent
}

/// dL/d(dtw) through the rotation and scale polynomials c0 + c1·dtw and d0 + d1·dtw, given
/// their gradients `d_c0` = dL/dc0 and `d_d0` = dL/dd0 (which equal dL/d of the polynomial).
#[inline]
pub fn polynomial_dtw_backward(d_c0: [f32; 4], c1: [f32; 4], d_d0: [f32; 3], d1: [f32; 3]) -> f32 {
    dot4(d_c0, c1) + Vec3::from(d_d0).dot(Vec3::from(d1))
}

/// dL/dt_i of a temporal centre `center`, given dL/d(dtw) and the unwarped offset
/// dt = t − t_i: dtw = W(t − t_i), so d dtw/d t_i = −W'(dt) (a one-sided end window, which
/// holds only at t_i = 0 or 1 exactly, is taken as fixed).
#[inline]
pub fn centre_gradient(d_dtw: f32, warp: &TimeWarp, center: f32, dt: f32) -> f32 {
    -warp.slope(center, dt) * d_dtw
}

/// Normalised lifespan ψ̄ ∈ [0, 1] used by TAT.
///
/// Definition: the Lebesgue measure of {t ∈ [0, 1] : σ(t)/σ^s > 0.2}, where σ(t) is evaluated
/// at dtw = `warp.apply(center, t − center)`. Since the temporal factor is a decreasing function of
/// |dtw| on each side, the set is the interval of t with W(t − center) ∈ (−a_left, a_right):
/// a = sqrt(ln 5 / ψ) on both sides for [`TemporalOpacity::Rbf`] and a = w·sqrt(ln 5) per
/// side for [`TemporalOpacity::Asymmetric`]. Mapping back, l = −W⁻¹(−a_left),
/// r = W⁻¹(a_right), and ψ̄ = length([center − l, center + r] ∩ [0, 1]).
pub fn lifespan_fraction(
    model: TemporalOpacity,
    temporal_raw: [f32; 2],
    center: f32,
    warp: &TimeWarp,
) -> f32 {
    let (a_left, a_right) = match model {
        TemporalOpacity::Rbf => {
            // ψ may underflow to 0 for very long-lived Gaussians: a = ∞, covering everything.
            let a = (LN_5 / temporal_raw[0].exp()).sqrt();
            (a, a)
        }
        TemporalOpacity::Asymmetric { w_min } => {
            let k = LN_5.sqrt();
            let left = asymmetric_width(w_min, temporal_raw, -1.0).1;
            let right = asymmetric_width(w_min, temporal_raw, 1.0).1;
            (left * k, right * k)
        }
    };
    let lo = (center + warp.inverse(center, -a_left)).max(0.0);
    let hi = (center + warp.inverse(center, a_right)).min(1.0);
    (hi - lo).clamp(0.0, 1.0)
}

/// Initial raw temporal values for a Gaussian centred at `center` such that σ(t)/σ^s = 0.2
/// exactly at t − t_i = ±half_width_frames/(T − 1) (in warped time).
///
/// Rbf: ψ = ln 5 / W(h)², raw = [ln ψ, 0] (`temporal_raw[1]` is unused); with a one-sided
/// end window, where W(h) ≠ −W(−h), the side inside the sequence (the larger |W|) sets ψ.
/// Asymmetric: each side s = ln(|W(±h)| / (sqrt(ln 5)·w_min)); if that width exceeds the
/// 1.1 cap, s is set (a hair below) where the cap starts, so the width is the cap but the
/// gradient is not cut off. `half_width_frames` should be positive.
pub fn init_temporal_raw(
    model: TemporalOpacity,
    half_width_frames: f32,
    frame_count: usize,
    warp: &TimeWarp,
    center: f32,
) -> [f32; 2] {
    let h = half_width_frames / frame_intervals(frame_count);
    // A zero half-width would give an infinite ψ; keep it finite.
    let (left, right) = (
        (-warp.apply(center, -h)).max(1e-6),
        warp.apply(center, h).max(1e-6),
    );
    match model {
        TemporalOpacity::Rbf => {
            let wh = left.max(right);
            [(LN_5 / (wh * wh)).ln(), 0.0]
        }
        TemporalOpacity::Asymmetric { w_min } => {
            let raw = |wh: f32| {
                let w = wh / LN_5.sqrt();
                if w < ASYMMETRIC_MAX_WIDTH {
                    (w / w_min).ln()
                } else {
                    // A few ulps below ln(1.1/w_min) so that w_min·e^s does not round above
                    // the cap.
                    (ASYMMETRIC_MAX_WIDTH / w_min).ln() - 1e-5
                }
            };
            [raw(left), raw(right)]
        }
    }
}

/// Rotation at time t: q = normalise(c0 + c1·dtw), quaternions stored as [w, x, y, z].
/// A zero quaternion yields the identity.
#[inline]
pub fn rotation_at(c0: [f32; 4], c1: [f32; 4], dtw: f32) -> [f32; 4] {
    let q = raw_rotation(c0, c1, dtw);
    let n2 = dot4(q, q);
    if n2 <= f32::MIN_POSITIVE {
        return [1.0, 0.0, 0.0, 0.0];
    }
    let inv = n2.sqrt().recip();
    q.map(|v| v * inv)
}

/// Backward of [`rotation_at`]: (dL/dc0, dL/dc1) given `d_q` = dL/dq (q normalised).
#[inline]
pub fn rotation_at_backward(
    c0: [f32; 4],
    c1: [f32; 4],
    dtw: f32,
    d_q: [f32; 4],
) -> ([f32; 4], [f32; 4]) {
    let q = raw_rotation(c0, c1, dtw);
    let n2 = dot4(q, q);
    if n2 <= f32::MIN_POSITIVE {
        return ([0.0; 4], [0.0; 4]);
    }
    let inv = n2.sqrt().recip();
    // d(q/|q|) = (I − q̂ q̂ᵀ) dq / |q|.
    let along = dot4(q, d_q) * inv * inv;
    let d_raw: [f32; 4] = std::array::from_fn(|i| (d_q[i] - q[i] * along) * inv);
    (d_raw, d_raw.map(|v| v * dtw))
}

#[inline]
fn raw_rotation(c0: [f32; 4], c1: [f32; 4], dtw: f32) -> [f32; 4] {
    std::array::from_fn(|i| c0[i] + c1[i] * dtw)
}

#[inline]
fn dot4(a: [f32; 4], b: [f32; 4]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
}

/// The log-scale velocity the model uses: d1 with `model.scale_motion`, else 0 (the authors'
/// constant scale).
#[inline]
pub fn scale_velocity(d1: [f32; 3], scale_motion: bool) -> [f32; 3] {
    if scale_motion { d1 } else { [0.0; 3] }
}

/// Scale at time t: exp(d0 + d1·dtw) per axis.
#[inline]
pub fn scale_at(d0: [f32; 3], d1: [f32; 3], dtw: f32) -> Vec3 {
    (Vec3::from(d0) + Vec3::from(d1) * dtw).exp()
}

/// Backward of [`scale_at`]: (dL/dd0, dL/dd1) given `d_scale` = dL/d scale.
#[inline]
pub fn scale_at_backward(
    d0: [f32; 3],
    d1: [f32; 3],
    dtw: f32,
    d_scale: Vec3,
) -> ([f32; 3], [f32; 3]) {
    let g = d_scale * scale_at(d0, d1, dtw);
    (g.to_array(), (g * dtw).to_array())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::fd::{assert_grad, central};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn rng() -> ChaCha8Rng {
        ChaCha8Rng::seed_from_u64(7)
    }

    fn uniform<const N: usize>(rng: &mut ChaCha8Rng, range: f32) -> [f32; N] {
        std::array::from_fn(|_| rng.random_range(-range..range))
    }

    #[test]
    fn fourier_matches_definition() {
        let mut cos = [[0.0; 3]; 4];
        let mut sin = [[0.0; 3]; 4];
        cos[1] = [1.0, 0.0, 0.0];
        sin[2] = [0.0, 2.0, 0.0];
        let phase = [0.3, 0.0, 0.0, 0.0];
        let dtw = 0.1;
        let shared = fourier_offset(&cos, &sin, &phase, MotionBasis::PAPER, dtw);
        let expect_x = (TAU * 2.0 * dtw + 0.3).cos();
        let expect_y = 2.0 * (TAU * 3.0 * dtw + 0.3).sin();
        assert!((shared - Vec3::new(expect_x, expect_y, 0.0)).length() < 1e-6);
        // Per-frequency phases: only phase[f-1] shifts frequency f.
        let per_frequency = MotionBasis {
            shared_phase: false,
            period: 1.0,
        };
        let per = fourier_offset(&cos, &sin, &phase, per_frequency, dtw);
        let expect = Vec3::new((TAU * 2.0 * dtw).cos(), 2.0 * (TAU * 3.0 * dtw).sin(), 0.0);
        assert!((per - expect).length() < 1e-6);
        // Period P: frequency f turns f/P times per unit of time.
        let period_two = MotionBasis {
            shared_phase: true,
            period: 2.0,
        };
        let slow = fourier_offset(&cos, &sin, &phase, period_two, dtw);
        let expect = Vec3::new(
            (TAU * dtw + 0.3).cos(),
            2.0 * (TAU * 1.5 * dtw + 0.3).sin(),
            0.0,
        );
        assert!((slow - expect).length() < 1e-6);
        // Zero coefficients: no motion.
        assert_eq!(
            fourier_offset(
                &[[0.0; 3]; 4],
                &[[0.0; 3]; 4],
                &phase,
                MotionBasis::PAPER,
                dtw
            ),
            Vec3::ZERO
        );
    }

    #[test]
    fn motion_period_one_returns_to_the_start_and_two_does_not() {
        let cos: [[f32; 3]; 4] = [[0.5, 0.0, 0.0]; 4];
        let sin: [[f32; 3]; 4] = [[0.0, 0.25, 0.1]; 4];
        let phase = [0.7, 0.0, 0.0, 0.0];
        let at = |basis, dtw| fourier_offset(&cos, &sin, &phase, basis, dtw);
        let paper = MotionBasis::PAPER;
        assert!((at(paper, 0.0) - at(paper, 1.0)).length() < 1e-5);
        let period_two = MotionBasis {
            period: 2.0,
            ..paper
        };
        assert!((at(period_two, 0.0) - at(period_two, 1.0)).length() > 0.1);
    }

    #[test]
    fn fourier_velocity_is_the_time_derivative_and_its_backward_matches_fd() {
        let mut rng = rng();
        for trial in 0..6 {
            let cos: [[f32; 3]; 4] = std::array::from_fn(|_| uniform(&mut rng, 1.0));
            let sin: [[f32; 3]; 4] = std::array::from_fn(|_| uniform(&mut rng, 1.0));
            let phase: [f32; 4] = uniform(&mut rng, 3.0);
            let dtw = rng.random_range(-1.0..1.0);
            let d = Vec3::from(uniform::<3>(&mut rng, 1.0));
            let basis = MotionBasis {
                shared_phase: trial % 2 == 0,
                period: [1.0, 4.0, 0.5][trial % 3],
            };
            // The velocity is d(offset)/d(dtw), checked per axis by finite differences.
            let v = fourier_velocity(&cos, &sin, &phase, basis, dtw);
            for k in 0..3 {
                let fd = central(
                    |t| fourier_offset(&cos, &sin, &phase, basis, t)[k],
                    dtw,
                    1e-3,
                );
                assert_grad("velocity", v[k], fd);
            }
            let g = fourier_velocity_backward(&cos, &sin, &phase, basis, dtw, d);
            assert_eq!(g.dtw, 0.0);
            let loss = |c: &[[f32; 3]; 4], s: &[[f32; 3]; 4], p: &[f32; 4]| {
                d.dot(fourier_velocity(c, s, p, basis, dtw))
            };
            for f in 0..4 {
                for k in 0..3 {
                    let fd = central(
                        |x| {
                            let mut c = cos;
                            c[f][k] = x;
                            loss(&c, &sin, &phase)
                        },
                        cos[f][k],
                        1e-2,
                    );
                    assert_grad("cos", g.cos[f][k], fd);
                    let fd = central(
                        |x| {
                            let mut s = sin;
                            s[f][k] = x;
                            loss(&cos, &s, &phase)
                        },
                        sin[f][k],
                        1e-2,
                    );
                    assert_grad("sin", g.sin[f][k], fd);
                }
                let fd = central(
                    |x| {
                        let mut p = phase;
                        p[f] = x;
                        loss(&cos, &sin, &p)
                    },
                    phase[f],
                    1e-2,
                );
                assert_grad("phase", g.phase[f], fd);
            }
        }
    }

    #[test]
    fn fourier_backward_matches_fd() {
        let mut rng = rng();
        for trial in 0..8 {
            let cos: [[f32; 3]; 4] = std::array::from_fn(|_| uniform(&mut rng, 1.0));
            let sin: [[f32; 3]; 4] = std::array::from_fn(|_| uniform(&mut rng, 1.0));
            let phase: [f32; 4] = uniform(&mut rng, 3.0);
            let dtw = rng.random_range(-1.0..1.0);
            let d = Vec3::from(uniform::<3>(&mut rng, 1.0));
            let basis = MotionBasis {
                shared_phase: trial % 2 == 0,
                period: [1.0, 2.0, 0.5][trial % 3],
            };
            let g = fourier_offset_backward(&cos, &sin, &phase, basis, dtw, d);
            let loss = |c: &[[f32; 3]; 4], s: &[[f32; 3]; 4], p: &[f32; 4]| {
                d.dot(fourier_offset(c, s, p, basis, dtw))
            };
            let h = 1e-2;
            for f in 0..4 {
                for k in 0..3 {
                    let fd = central(
                        |v| {
                            let mut c = cos;
                            c[f][k] = v;
                            loss(&c, &sin, &phase)
                        },
                        cos[f][k],
                        h,
                    );
                    assert_grad("cos", g.cos[f][k], fd);
                    let fd = central(
                        |v| {
                            let mut s = sin;
                            s[f][k] = v;
                            loss(&cos, &s, &phase)
                        },
                        sin[f][k],
                        h,
                    );
                    assert_grad("sin", g.sin[f][k], fd);
                }
                let fd = central(
                    |v| {
                        let mut p = phase;
                        p[f] = v;
                        loss(&cos, &sin, &p)
                    },
                    phase[f],
                    1e-2,
                );
                assert_grad("phase", g.phase[f], fd);
                if basis.shared_phase && f > 0 {
                    assert_eq!(g.phase[f], 0.0);
                }
            }
            let fd = central(
                |t| d.dot(fourier_offset(&cos, &sin, &phase, basis, t)),
                dtw,
                1e-3,
            );
            assert_grad("dtw", g.dtw, fd);
        }
    }

    #[test]
    fn sigmoid_logit_round_trip() {
        for p in [0.005f32, 0.1, 0.5, 0.9, 0.99] {
            assert!((sigmoid(logit(p)) - p).abs() < 1e-6);
        }
        assert_eq!(sigmoid(0.0), 0.5);
        assert!(sigmoid(-200.0) >= 0.0 && sigmoid(200.0) <= 1.0);
        assert!(logit(0.0).is_finite() && logit(1.0).is_finite());
    }

    #[test]
    fn asymmetric_w_min() {
        let TemporalOpacity::Asymmetric { w_min } = TemporalOpacity::asymmetric(300) else {
            unreachable!()
        };
        let h = 24.5 / 299.0;
        assert!((w_min - h / (-(0.2f32.ln())).sqrt()).abs() < 1e-7);
    }

    #[test]
    fn windows_sharing_an_end_sum_to_one() {
        // Two segments meeting at t = 0.5 with a 0.1-wide cross-fade, and the same without.
        for fade in [0.1, 0.0] {
            let first = TimeWindow {
                start: -1.0,
                end: 0.5,
                fade,
            };
            let second = TimeWindow {
                start: 0.5,
                end: 2.0,
                fade,
            };
            for i in 0..=100 {
                let t = i as f32 / 100.0;
                let sum = window_factor(&first, t) + window_factor(&second, t);
                assert!((sum - 1.0).abs() < 1e-6, "fade {fade}, t {t}: {sum}");
            }
        }
        let fading = TimeWindow {
            start: 0.2,
            end: 0.6,
            fade: 0.1,
        };
        assert_eq!(window_factor(&fading, 0.4), 1.0);
        assert_eq!(window_factor(&fading, 0.1), 0.0);
        assert!((window_factor(&fading, 0.2) - 0.5).abs() < 1e-6);
        assert!((window_factor(&fading, 0.625) - 0.25).abs() < 1e-5);
        assert_eq!(window_factor(&fading, 0.7), 0.0);
        let step = TimeWindow {
            start: 0.2,
            end: 0.6,
            fade: 0.0,
        };
        assert_eq!(window_factor(&step, 0.2), 1.0);
        assert_eq!(window_factor(&step, 0.6), 0.0);
        assert_eq!(window_factor(&TimeWindow::ALWAYS, 0.0), 1.0);
        assert_eq!(window_factor(&TimeWindow::ALWAYS, 1.0), 1.0);
    }

    #[test]
    fn temporal_opacity_matches_definition() {
        let sig = sigmoid(0.4);
        let v = temporal_opacity(TemporalOpacity::Rbf, 0.4, [1.5, 9.0], 0.3);
        assert!((v - sig * (-(1.5f32.exp()) * 0.09).exp()).abs() < 1e-6);
        let model = TemporalOpacity::Asymmetric { w_min: 0.05 };
        let left = temporal_opacity(model, 0.4, [1.0, 2.0], -0.2);
        let w = 0.05 * 1.0f32.exp();
        assert!((left - sig * (-(0.2 / w) * (0.2 / w)).exp()).abs() < 1e-6);
        let right = temporal_opacity(model, 0.4, [1.0, 2.0], 0.2);
        let w = 0.05 * 2.0f32.exp();
        assert!((right - sig * (-(0.2 / w) * (0.2 / w)).exp()).abs() < 1e-6);
        // Clamped width.
        let wide = temporal_opacity(model, 0.4, [1.0, 10.0], 0.5);
        assert!((wide - sig * (-(0.5f32 / 1.1).powi(2)).exp()).abs() < 1e-6);
        // Peak equals the spatial opacity.
        assert_eq!(temporal_opacity(model, 0.4, [1.0, 2.0], 0.0), sig);
    }

    #[test]
    fn temporal_opacity_backward_matches_fd() {
        let mut rng = rng();
        let models = [
            TemporalOpacity::Rbf,
            TemporalOpacity::asymmetric(300),
            TemporalOpacity::Asymmetric { w_min: 0.2 },
        ];
        for model in models {
            for _ in 0..16 {
                let logit_v = rng.random_range(-4.0..4.0);
                // Includes raw values past the asymmetric cap (zero gradient there).
                let raw: [f32; 2] = std::array::from_fn(|_| rng.random_range(-1.0..3.0));
                let dtw = rng.random_range(-0.6..0.6);
                let d_sigma = rng.random_range(-2.0..2.0);
                // Skip the far tail (σ(t)/σ^s < 1e-4, invisible anyway): there the f32 rounding
                // of the large exponent, not the gradient, dominates the finite difference.
                if temporal_opacity(model, 20.0, raw, dtw) < 1e-4 {
                    continue;
                }
                let (g_logit, g_raw) = temporal_opacity_backward(model, logit_v, raw, dtw, d_sigma);
                let h = 1e-2;
                let fd = central(
                    |v| d_sigma * temporal_opacity(model, v, raw, dtw),
                    logit_v,
                    h,
                );
                assert_grad("logit", g_logit, fd);
                for k in 0..2 {
                    // Stay away from the kink of the width clamp.
                    if let TemporalOpacity::Asymmetric { w_min } = model
                        && ((w_min * raw[k].exp()).ln() - ASYMMETRIC_MAX_WIDTH.ln()).abs() < 2.0 * h
                    {
                        continue;
                    }
                    let fd = central(
                        |v| {
                            let mut r = raw;
                            r[k] = v;
                            d_sigma * temporal_opacity(model, logit_v, r, dtw)
                        },
                        raw[k],
                        h,
                    );
                    assert_grad("raw", g_raw[k], fd);
                }
                // Away from dtw = 0, where the asymmetric form switches sides.
                if dtw.abs() > 2.0 * h {
                    let g_dtw = temporal_opacity_dtw_backward(model, logit_v, raw, dtw, d_sigma);
                    let fd = central(
                        |t| d_sigma * temporal_opacity(model, logit_v, raw, t),
                        dtw,
                        1e-3,
                    );
                    assert_grad("dtw", g_dtw, fd);
                }
            }
        }
    }

    /// The dtw gradients of the rotation and scale polynomials and the chain through the warp
    /// to the temporal centre match finite differences of a loss of the deformed rotation and
    /// scale: L = d_q·rotation_at(c0, c1, W(t − t_i)) + d_s·scale_at(d0, d1, W(t − t_i)).
    #[test]
    fn centre_gradient_matches_fd() {
        let mut rng = rng();
        for warp in [
            TimeWarp::tow(20.0, 100, 0.75),
            TimeWarp::tow(20.0, 100, 0.75).with_smooth_corners(true),
        ] {
            centre_gradient_matches_fd_for(&mut rng, warp);
        }
    }

    fn centre_gradient_matches_fd_for(rng: &mut ChaCha8Rng, warp: TimeWarp) {
        for _ in 0..16 {
            let c0: [f32; 4] = uniform(rng, 1.0);
            let c1: [f32; 4] = uniform(rng, 1.0);
            let d0: [f32; 3] = uniform(rng, 1.0);
            let d1: [f32; 3] = uniform(rng, 1.0);
            let d_q: [f32; 4] = uniform(rng, 1.0);
            let d_s = Vec3::from(uniform::<3>(rng, 1.0));
            let (t, centre): (f32, f32) = (rng.random_range(0.0..1.0), rng.random_range(0.0..1.0));
            // Stay away from the piecewise warp's kinks at |t − t_i| = λ/2.
            let lambda = 0.2f32;
            if ((t - centre).abs() - 0.5 * lambda).abs() < 1e-2 {
                continue;
            }
            let loss = |c: f32| {
                let dtw = warp.apply(c, t - c);
                dot4(d_q, rotation_at(c0, c1, dtw)) + d_s.dot(scale_at(d0, d1, dtw))
            };
            let dtw = warp.apply(centre, t - centre);
            let (d_c0, _) = rotation_at_backward(c0, c1, dtw, d_q);
            let (d_d0, _) = scale_at_backward(d0, d1, dtw, d_s);
            let d_dtw = polynomial_dtw_backward(d_c0, c1, d_d0, d1);
            let g = centre_gradient(d_dtw, &warp, centre, t - centre);
            assert_grad("centre", g, central(loss, centre, 1e-3));
        }
    }

    /// Brute-force ψ̄ from the definition: fraction of a fine grid of t with ratio > 0.2.
    fn lifespan_by_sampling(
        model: TemporalOpacity,
        raw: [f32; 2],
        center: f32,
        warp: &TimeWarp,
    ) -> f32 {
        let n = 200_000;
        let count = (0..n)
            .filter(|&i| {
                let t = (i as f32 + 0.5) / n as f32;
                temporal_opacity(model, 10.0, raw, warp.apply(center, t - center)) / sigmoid(10.0)
                    > 0.2
            })
            .count();
        count as f32 / n as f32
    }

    #[test]
    fn lifespan_fraction_cases() {
        let id = TimeWarp::Identity;
        let rbf = TemporalOpacity::Rbf;
        // Long-lived: ψ tiny.
        assert_eq!(lifespan_fraction(rbf, [-30.0, 0.0], 0.5, &id), 1.0);
        assert_eq!(lifespan_fraction(rbf, [-200.0, 0.0], 0.3, &id), 1.0);
        // Hand-computed: ψ = ln5/0.1² → alive for |Δt| < 0.1, i.e. 0.2 of the sequence.
        let raw = [(LN_5 / 0.01).ln(), 0.0];
        assert!((lifespan_fraction(rbf, raw, 0.5, &id) - 0.2).abs() < 1e-5);
        // Clipped at the sequence ends.
        assert!((lifespan_fraction(rbf, raw, 0.0, &id) - 0.1).abs() < 1e-5);
        assert!((lifespan_fraction(rbf, raw, 0.95, &id) - 0.15).abs() < 1e-5);
        // Shorter when ψ is larger.
        let short = lifespan_fraction(rbf, [raw[0] + 1.0, 0.0], 0.5, &id);
        assert!(short < 0.2 && (short - 0.2 / 1.0f32.exp().sqrt()).abs() < 1e-5);
        // With TOW (λ = 0.2, ρ = 0.5: s_near = 2.5, s_far = 0.625), warped radius 0.4 is past
        // the window edge (ρ/2 = 0.25): Δt = 0.1 + (0.4 − 0.25)/0.625 = 0.34 → ψ̄ = 0.68.
        let warp = TimeWarp::Tow {
            lambda: 0.2,
            rho: 0.5,
            one_sided_ends: false,
            smooth: false,
        };
        let raw = [(LN_5 / 0.16).ln(), 0.0];
        assert!((lifespan_fraction(rbf, raw, 0.5, &warp) - 0.68).abs() < 1e-5);
        // Asymmetric: w = a / sqrt(ln 5) per side; left 0.1, right 0.3 (clipped at 1).
        let w_min = 0.05;
        let model = TemporalOpacity::Asymmetric { w_min };
        let k = LN_5.sqrt();
        let raw = [(0.1 / k / w_min).ln(), (0.3 / k / w_min).ln()];
        assert!((lifespan_fraction(model, raw, 0.5, &id) - 0.4).abs() < 1e-5);
        assert!((lifespan_fraction(model, raw, 0.8, &id) - 0.3).abs() < 1e-5);
        // Capped width 1.1: alive for |Δt| < 1.1·sqrt(ln 5) > 1 → whole sequence.
        assert_eq!(lifespan_fraction(model, [20.0, 20.0], 0.0, &id), 1.0);
    }

    #[test]
    fn lifespan_fraction_matches_sampled_definition() {
        let warps = [
            TimeWarp::Identity,
            TimeWarp::tow(50.0, 300, 0.75),
            TimeWarp::Tow {
                lambda: 0.4,
                rho: 0.3,
                one_sided_ends: false,
                smooth: false,
            },
            TimeWarp::tow(50.0, 300, 0.75).with_one_sided_ends(true),
            TimeWarp::tow(50.0, 300, 0.75).with_smooth_corners(true),
            TimeWarp::tow(50.0, 300, 0.75)
                .with_one_sided_ends(true)
                .with_smooth_corners(true),
        ];
        let models = [TemporalOpacity::Rbf, TemporalOpacity::asymmetric(300)];
        let mut rng = rng();
        for warp in warps {
            for model in models {
                for i in 0..6 {
                    let raw = match model {
                        TemporalOpacity::Rbf => [rng.random_range(0.0..8.0), 0.0],
                        _ => [rng.random_range(-1.0..3.0), rng.random_range(-1.0..3.0)],
                    };
                    // The sequence's ends too, where one-sided windows apply.
                    let center = match i {
                        0 => 0.0,
                        1 => 1.0,
                        _ => rng.random_range(0.0..1.0),
                    };
                    let closed = lifespan_fraction(model, raw, center, &warp);
                    let sampled = lifespan_by_sampling(model, raw, center, &warp);
                    assert!(
                        (closed - sampled).abs() < 1e-4,
                        "{model:?} {warp:?}: {closed} vs {sampled}"
                    );
                }
            }
        }
    }

    #[test]
    fn init_temporal_raw_hits_one_fifth() {
        let frames = 300;
        let warps = [
            TimeWarp::Identity,
            TimeWarp::tow(50.0, frames, 0.75),
            TimeWarp::tow(50.0, frames, 0.7),
            TimeWarp::tow(50.0, frames, 0.75).with_one_sided_ends(true),
            TimeWarp::tow(50.0, frames, 0.75).with_smooth_corners(true),
        ];
        let models = [TemporalOpacity::Rbf, TemporalOpacity::asymmetric(frames)];
        for warp in warps {
            for model in models {
                for half in [5.0, 25.0, 60.0] {
                    let h = half / (frames - 1) as f32;
                    let sig = sigmoid(0.3);
                    // The middle, where both sides are inside the sequence, and the ends,
                    // where only the side towards the sequence is.
                    for (center, offsets) in [(0.5, vec![-h, h]), (0.0, vec![h]), (1.0, vec![-h])] {
                        let raw = init_temporal_raw(model, half, frames, &warp, center);
                        for dt in offsets {
                            let v = temporal_opacity(model, 0.3, raw, warp.apply(center, dt));
                            assert!(
                                (v - 0.2 * sig).abs() < 1e-5 * sig,
                                "{model:?} {warp:?} {half} at {center}: {}",
                                v / sig
                            );
                        }
                        // Consistent with the lifespan definition: alive for 2h around the
                        // middle, h from an end.
                        let alive = if center == 0.5 { 2.0 * h } else { h };
                        let lifespan = lifespan_fraction(model, raw, center, &warp);
                        assert!((lifespan - alive).abs() < 1e-4, "{lifespan} vs {alive}");
                    }
                }
            }
        }
        // Asymmetric target width above the cap: width is the cap, gradient still flows.
        let model = TemporalOpacity::asymmetric(frames);
        let raw = init_temporal_raw(model, 700.0, frames, &TimeWarp::Identity, 0.5);
        let TemporalOpacity::Asymmetric { w_min } = model else {
            unreachable!()
        };
        assert!((w_min * raw[0].exp() - ASYMMETRIC_MAX_WIDTH).abs() < 1e-4);
        let (_, g) = temporal_opacity_backward(model, 0.0, raw, 0.5, 1.0);
        assert!(g[1] != 0.0);
    }

    #[test]
    fn rotation_at_normalises() {
        let q = rotation_at([1.0, 0.0, 0.0, 0.0], [0.0, 2.0, 0.0, 0.0], 0.5);
        let s = 0.5f32.sqrt();
        assert!((q[0] - s).abs() < 1e-6 && (q[1] - s).abs() < 1e-6);
        assert_eq!(rotation_at([0.0; 4], [0.0; 4], 0.3), [1.0, 0.0, 0.0, 0.0]);
    }

    #[test]
    fn rotation_at_backward_matches_fd() {
        let mut rng = rng();
        for _ in 0..16 {
            let c0: [f32; 4] = uniform(&mut rng, 1.0);
            let c1: [f32; 4] = uniform(&mut rng, 1.0);
            let dtw = rng.random_range(-1.0..1.0);
            let d_q: [f32; 4] = uniform(&mut rng, 1.0);
            let (g0, g1) = rotation_at_backward(c0, c1, dtw, d_q);
            let loss = |a: [f32; 4], b: [f32; 4]| dot4(d_q, rotation_at(a, b, dtw));
            for k in 0..4 {
                let h = 1e-2;
                let fd = central(
                    |v| {
                        let mut a = c0;
                        a[k] = v;
                        loss(a, c1)
                    },
                    c0[k],
                    h,
                );
                assert_grad("c0", g0[k], fd);
                let fd = central(
                    |v| {
                        let mut b = c1;
                        b[k] = v;
                        loss(c0, b)
                    },
                    c1[k],
                    h,
                );
                assert_grad("c1", g1[k], fd);
            }
        }
    }

    #[test]
    fn scale_at_backward_matches_fd() {
        let mut rng = rng();
        for _ in 0..16 {
            let d0: [f32; 3] = uniform(&mut rng, 3.0);
            let d1: [f32; 3] = uniform(&mut rng, 1.0);
            let dtw = rng.random_range(-1.0..1.0);
            let d_s = Vec3::from(uniform::<3>(&mut rng, 1.0));
            let expect = Vec3::new(
                (d0[0] + d1[0] * dtw).exp(),
                (d0[1] + d1[1] * dtw).exp(),
                (d0[2] + d1[2] * dtw).exp(),
            );
            assert!((scale_at(d0, d1, dtw) - expect).length() <= 1e-6 * expect.length());
            let (g0, g1) = scale_at_backward(d0, d1, dtw, d_s);
            for k in 0..3 {
                let h = 1e-2;
                let fd = central(
                    |v| {
                        let mut a = d0;
                        a[k] = v;
                        d_s.dot(scale_at(a, d1, dtw))
                    },
                    d0[k],
                    h,
                );
                assert_grad("d0", g0[k], fd);
                let fd = central(
                    |v| {
                        let mut b = d1;
                        b[k] = v;
                        d_s.dot(scale_at(d0, b, dtw))
                    },
                    d1[k],
                    h,
                );
                assert_grad("d1", g1[k], fd);
            }
        }
    }
}
