//! Shared motion bases (`model.shared_motion`): a low-rank motion common to every Gaussian,
//! added to each one's own (Fourier) motion,
//!
//! mean_i(t) = μ_i + Fourier_i(Δt') + Σ_{b<B} w_ib·u_b(t),
//!
//! with B trajectories u_b(t) ∈ R³ shared by all Gaussians and a weight vector w_i ∈ R^B per
//! Gaussian. Each u_b is piecewise linear in the view's normalised time t ∈ [0, 1] (not the
//! Gaussian's warped offset) over K knots spaced uniformly on [0, 1], knot k at k/(K − 1), with
//! values U[b][k] ∈ R³.
//!
//! Not part of the paper. On monocular captures (one view per instant), independent
//! trajectories can fit each training view on its own; a motion most Gaussians share is
//! constrained by every view.
//!
//! The maths and its gradient: [`MotionBases::evaluate`] gives every u_b(t) once per view,
//! [`shared_offset`] a Gaussian's Σ_b w_ib·u_b(t); with g_i = dL/d(mean_i),
//! [`weights_gradient`] gives dL/dw_ib = g_i·u_b(t), and [`MotionBases::evaluate_backward`]
//! scatters dL/du_b(t) = Σ_i w_ib·g_i onto the two knots around t
//! (dL/dU[b][k] += λ_k(t)·dL/du_b(t)).

use glam::Vec3;

/// The most shared motion bases B a model may have (the width of
/// [`crate::components::MotionWeights`]).
pub const MAX_MOTION_BASES: usize = 16;

/// The two knots around a time and their linear-interpolation weights: a basis at that time is
/// `lambda[0]·U[first] + lambda[1]·U[first + 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KnotSpan {
    /// The knot at or before the time (at most K − 2).
    pub first: usize,
    /// Weights of knots `first` and `first + 1` (non-negative, summing to 1).
    pub lambda: [f32; 2],
}

impl KnotSpan {
    /// The span of normalised time `time` (clamped to [0, 1]) over `knots` ≥ 2 knots spaced
    /// uniformly on [0, 1]. A time on a knot k < K − 1 gives `first = k` with weights [1, 0];
    /// t = 1 gives the last segment with weights [0, 1].
    pub fn at(knots: usize, time: f32) -> Self {
        debug_assert!(knots >= 2, "a piecewise-linear basis needs two knots");
        let segments = knots.saturating_sub(1).max(1);
        let time = if time.is_nan() {
            0.0
        } else {
            time.clamp(0.0, 1.0)
        };
        let s = time * segments as f32;
        let first = (s.floor() as usize).min(segments - 1);
        let fraction = (s - first as f32).clamp(0.0, 1.0);
        Self {
            first,
            lambda: [1.0 - fraction, fraction],
        }
    }
}

/// The values U[b][k] of B piecewise-linear trajectories over K knots, basis-major
/// (`values[b·K + k]`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MotionBases {
    /// B, the number of bases (1..=[`MAX_MOTION_BASES`]).
    pub bases: usize,
    /// K, the number of knots per basis (≥ 2).
    pub knots: usize,
    /// U[b][k] ∈ R³ (scene units) at `values[b·knots + k]`.
    pub values: Vec<[f32; 3]>,
}

/// Every basis at one time: u_b(t) for b < B (the rest zero).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BasesAt {
    /// The knot span of the time.
    pub span: KnotSpan,
    /// u_b(t) for b < `count`.
    pub values: [Vec3; MAX_MOTION_BASES],
    /// B.
    pub count: usize,
}

impl BasesAt {
    /// u_b(t) for b < B.
    pub fn bases(&self) -> &[Vec3] {
        &self.values[..self.count]
    }
}

impl MotionBases {
    /// B bases of K knots, all zero (no shared motion yet).
    pub fn zeros(bases: usize, knots: usize) -> Self {
        Self {
            bases,
            knots,
            values: vec![[0.0; 3]; bases * knots],
        }
    }

    /// U[b][k].
    pub fn value(&self, basis: usize, knot: usize) -> Vec3 {
        Vec3::from_array(self.values[basis * self.knots + knot])
    }

    /// Every u_b(t), b < B, at normalised time `time`: evaluated once per view and shared by
    /// every Gaussian.
    pub fn evaluate(&self, time: f32) -> BasesAt {
        let span = KnotSpan::at(self.knots, time);
        let mut values = [Vec3::ZERO; MAX_MOTION_BASES];
        let count = self.bases.min(MAX_MOTION_BASES);
        for (b, value) in values.iter_mut().enumerate().take(count) {
            *value = span.lambda[0] * self.value(b, span.first)
                + span.lambda[1] * self.value(b, span.first + 1);
        }
        BasesAt {
            span,
            values,
            count,
        }
    }

    /// Adds the gradient of [`MotionBases::evaluate`] to `grad` (laid out like
    /// [`MotionBases::values`]): `d_bases[b]` = dL/du_b(t) goes to the two knots around the time
    /// with their interpolation weights.
    pub fn evaluate_backward(&self, span: KnotSpan, d_bases: &[Vec3], grad: &mut [[f32; 3]]) {
        for (b, d) in d_bases.iter().enumerate().take(self.bases) {
            for (j, lambda) in span.lambda.into_iter().enumerate() {
                let cell = &mut grad[b * self.knots + span.first + j];
                for (c, v) in cell.iter_mut().zip((lambda * *d).to_array()) {
                    *c += v;
                }
            }
        }
    }
}

/// A Gaussian's shared motion Σ_b w_b·u_b(t) (`at`: [`MotionBases::evaluate`]; weights past B
/// are ignored).
#[inline]
pub fn shared_offset(weights: &[f32; MAX_MOTION_BASES], at: &BasesAt) -> Vec3 {
    at.bases()
        .iter()
        .zip(weights)
        .fold(Vec3::ZERO, |sum, (u, &w)| sum + w * *u)
}

/// dL/dw_b = g·u_b(t) for b < B (zero past B), with `d_mean` = g = dL/d(mean) of the Gaussian.
#[inline]
pub fn weights_gradient(at: &BasesAt, d_mean: Vec3) -> [f32; MAX_MOTION_BASES] {
    let mut d = [0.0; MAX_MOTION_BASES];
    for (d, u) in d.iter_mut().zip(at.bases()) {
        *d = d_mean.dot(*u);
    }
    d
}

/// Adds one Gaussian's share of dL/du_b(t), w_b·g, to `d_bases` (b < B), with `d_mean` = g.
/// Summed over the Gaussians and passed to [`MotionBases::evaluate_backward`], it gives dL/dU.
#[inline]
pub fn accumulate_bases_gradient(
    weights: &[f32; MAX_MOTION_BASES],
    d_mean: Vec3,
    d_bases: &mut [[f64; 3]],
) {
    let g = d_mean.as_dvec3();
    for (d, &w) in d_bases.iter_mut().zip(weights) {
        let share = (f64::from(w) * g).to_array();
        for (d, s) in d.iter_mut().zip(share) {
            *d += s;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::fd::{assert_grad, central};

    const BASES: usize = 3;
    const KNOTS: usize = 5;

    fn bases() -> MotionBases {
        let mut u = MotionBases::zeros(BASES, KNOTS);
        for (i, v) in u.values.iter_mut().enumerate() {
            let x = i as f32;
            *v = [
                0.3 * (0.7 * x).sin(),
                -0.2 + 0.05 * x,
                0.4 * (1.3 * x + 0.5).cos(),
            ];
        }
        u
    }

    /// A few Gaussians: weights, canonical means (standing in for μ + Fourier) and targets.
    fn gaussians() -> Vec<([f32; MAX_MOTION_BASES], Vec3, Vec3)> {
        (0..4)
            .map(|i| {
                let x = i as f32;
                let mut w = [0.0; MAX_MOTION_BASES];
                for (b, w) in w.iter_mut().enumerate().take(BASES) {
                    *w = 0.5 * (x + 1.7 * b as f32).sin() + 0.1;
                }
                let mean = Vec3::new(0.1 * x, -0.3 + 0.2 * x, 0.5 - 0.1 * x);
                let target = Vec3::new(0.2 - 0.05 * x, 0.1 * x, -0.4 + 0.3 * x);
                (w, mean, target)
            })
            .collect()
    }

    /// L = Σ_i ‖mean_i(t) − target_i‖² with mean_i(t) = mean_i + Σ_b w_ib·u_b(t).
    fn loss(u: &MotionBases, gaussians: &[([f32; MAX_MOTION_BASES], Vec3, Vec3)], t: f32) -> f32 {
        let at = u.evaluate(t);
        gaussians
            .iter()
            .map(|(w, mean, target)| (*mean + shared_offset(w, &at) - *target).length_squared())
            .sum()
    }

    /// The analytic gradients of [`loss`]: per Gaussian dL/dw, and dL/dU.
    fn gradients(
        u: &MotionBases,
        gaussians: &[([f32; MAX_MOTION_BASES], Vec3, Vec3)],
        t: f32,
    ) -> (Vec<[f32; MAX_MOTION_BASES]>, Vec<[f32; 3]>) {
        let at = u.evaluate(t);
        let mut d_bases = vec![[0.0f64; 3]; u.bases];
        let d_weights = gaussians
            .iter()
            .map(|(w, mean, target)| {
                let g = 2.0 * (*mean + shared_offset(w, &at) - *target);
                accumulate_bases_gradient(w, g, &mut d_bases);
                weights_gradient(&at, g)
            })
            .collect();
        let d_bases: Vec<Vec3> = d_bases
            .iter()
            .map(|d| Vec3::new(d[0] as f32, d[1] as f32, d[2] as f32))
            .collect();
        let mut d_u = vec![[0.0; 3]; u.values.len()];
        u.evaluate_backward(at.span, &d_bases, &mut d_u);
        (d_weights, d_u)
    }

    /// Times inside segments, exactly on interior knots, and at both ends.
    const TIMES: [f32; 6] = [0.0, 0.13, 0.25, 0.5, 0.87, 1.0];

    #[test]
    fn weights_gradient_matches_finite_differences() {
        let (u, gaussians) = (bases(), gaussians());
        for t in TIMES {
            let (d_weights, _) = gradients(&u, &gaussians, t);
            for (i, d_w) in d_weights.iter().enumerate() {
                for (b, &analytic) in d_w.iter().enumerate().take(BASES) {
                    let fd = central(
                        |x| {
                            let mut g = gaussians.clone();
                            g[i].0[b] = x;
                            loss(&u, &g, t)
                        },
                        gaussians[i].0[b],
                        1e-2,
                    );
                    assert_grad(&format!("t = {t}, w[{i}][{b}]"), analytic, fd);
                }
                assert!(
                    d_w[BASES..].iter().all(|&d| d == 0.0),
                    "weights past B get no gradient"
                );
            }
        }
    }

    #[test]
    fn bases_gradient_matches_finite_differences() {
        let (u, gaussians) = (bases(), gaussians());
        for t in TIMES {
            let (_, d_u) = gradients(&u, &gaussians, t);
            let mut touched = 0;
            for (cell, analytic) in d_u.iter().enumerate() {
                for c in 0..3 {
                    let fd = central(
                        |x| {
                            let mut v = u.clone();
                            v.values[cell][c] = x;
                            loss(&v, &gaussians, t)
                        },
                        u.values[cell][c],
                        1e-2,
                    );
                    assert_grad(
                        &format!("t = {t}, U[{}][{}][{c}]", cell / KNOTS, cell % KNOTS),
                        analytic[c],
                        fd,
                    );
                    touched += usize::from(analytic[c] != 0.0);
                }
            }
            assert!(touched > 0, "t = {t}: some knot gets a gradient");
        }
    }

    /// With U = 0 and w ≠ 0 the bases get a gradient (and the weights none): training can
    /// start from zero bases.
    #[test]
    fn zero_bases_still_get_a_gradient() {
        let u = MotionBases::zeros(BASES, KNOTS);
        let (d_weights, d_u) = gradients(&u, &gaussians(), 0.4);
        assert!(d_weights.iter().flatten().all(|&d| d == 0.0));
        assert!(d_u.iter().flatten().any(|&d| d != 0.0));
    }

    #[test]
    fn spans_interpolate_between_the_knots_around_the_time() {
        // Five knots at 0, 0.25, 0.5, 0.75, 1.
        assert_eq!(
            KnotSpan::at(5, 0.0),
            KnotSpan {
                first: 0,
                lambda: [1.0, 0.0]
            }
        );
        assert_eq!(
            KnotSpan::at(5, 0.5),
            KnotSpan {
                first: 2,
                lambda: [1.0, 0.0]
            }
        );
        assert_eq!(
            KnotSpan::at(5, 1.0),
            KnotSpan {
                first: 3,
                lambda: [0.0, 1.0]
            }
        );
        let span = KnotSpan::at(5, 0.3);
        assert_eq!(span.first, 1);
        assert!((span.lambda[1] - 0.2).abs() < 1e-6);
        // Outside [0, 1] (and NaN) the ends hold.
        assert_eq!(KnotSpan::at(5, -0.5), KnotSpan::at(5, 0.0));
        assert_eq!(KnotSpan::at(5, 1.5), KnotSpan::at(5, 1.0));
        assert_eq!(KnotSpan::at(5, f32::NAN), KnotSpan::at(5, 0.0));
        // Two knots: one segment.
        assert_eq!(KnotSpan::at(2, 1.0).first, 0);

        // The bases pass through their knot values and are linear in between.
        let u = bases();
        for k in 0..KNOTS {
            let at = u.evaluate(k as f32 / (KNOTS - 1) as f32);
            for b in 0..BASES {
                assert!((at.bases()[b] - u.value(b, k)).length() < 1e-6);
            }
        }
        let at = u.evaluate(0.3);
        let want = 0.8 * u.value(2, 1) + 0.2 * u.value(2, 2);
        assert!((at.bases()[2] - want).length() < 1e-6);
        assert_eq!(at.bases().len(), BASES);
    }
}
