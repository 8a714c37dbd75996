//! Temporal Offset Warping (TOW, SPEC §3).
//!
//! The offset Δt = t − t_i between the rendered time and a Gaussian's temporal centre is
//! remapped by a piecewise-linear, odd, monotone function W before it enters the deformation:
//! a window of width λ around the centre is stretched (slope s_near = ρ/λ) and the rest is
//! compressed (slope s_far = (1 − ρ)/(1 − λ)), with the far branch continued from the window
//! edge (the paper writes it as s_far·Δt, which jumps at |Δt| = λ/2).
//!
//! What "preserves the total temporal span" means with these slopes: the sequence t ∈ [0, 1]
//! has length 1 and keeps it, W(1 − t_i) − W(−t_i) = ρ + s_far·(1 − λ) = 1, whenever both of
//! its ends lie outside the window; in particular W(±½) = ±½. A fraction ρ of that warped
//! length belongs to the window. W(±1) is *not* ±1 (it is ρ/2 + s_far·(1 − λ/2), 0.65 for
//! λ = 50/300, ρ = 0.75): slopes giving W(±1) = ±1 would have to differ from the paper's.

/// The temporal warp W applied to the offset Δt = t − t_i.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeWarp {
    /// W(Δt) = Δt (TOW off).
    Identity,
    /// Piecewise-linear warp: window width `lambda` (normalised time, in (0, 1)) mapped onto
    /// the warped width `rho` (in (0, 1)).
    Tow {
        /// Width λ of the near window in normalised time (the window is |Δt| ≤ λ/2).
        lambda: f32,
        /// Fraction ρ of the warped span given to the near window.
        rho: f32,
    },
}

/// Smallest and largest ρ accepted by [`TimeWarp::tow`]; keeps both slopes positive so that
/// the warp stays invertible.
const RHO_RANGE: (f32, f32) = (1e-3, 1.0 - 1e-3);

impl TimeWarp {
    /// The TOW warp for a window of `window_frames` frames in a `frame_count`-frame sequence:
    /// λ = window_frames / frame_count. Falls back to [`TimeWarp::Identity`] when λ is not in
    /// (0, 1) (the window covers the whole sequence). ρ is clamped into [1e-3, 1 − 1e-3].
    pub fn tow(window_frames: f32, frame_count: usize, rho: f32) -> Self {
        let lambda = window_frames / frame_count as f32;
        if !(lambda > 0.0 && lambda < 1.0) {
            return Self::Identity;
        }
        let rho = if rho.is_nan() {
            0.5
        } else {
            rho.clamp(RHO_RANGE.0, RHO_RANGE.1)
        };
        Self::Tow { lambda, rho }
    }

    /// Slopes (s_near, s_far) of the warp; (1, 1) for the identity.
    #[inline]
    fn slopes(&self) -> (f32, f32) {
        match *self {
            Self::Identity => (1.0, 1.0),
            Self::Tow { lambda, rho } => (rho / lambda, (1.0 - rho) / (1.0 - lambda)),
        }
    }

    /// W(Δt): s_near·Δt for |Δt| ≤ λ/2, else sign(Δt)·(s_near·λ/2 + s_far·(|Δt| − λ/2)).
    #[inline]
    pub fn apply(&self, dt: f32) -> f32 {
        match *self {
            Self::Identity => dt,
            Self::Tow { lambda, rho } => {
                let (s_near, s_far) = self.slopes();
                let half = 0.5 * lambda;
                let a = dt.abs();
                if a <= half {
                    s_near * dt
                } else {
                    // s_near·λ/2 = ρ/2.
                    (0.5 * rho + s_far * (a - half)).copysign(dt)
                }
            }
        }
    }

    /// dW/dΔt: s_near inside the window (|Δt| ≤ λ/2), s_far outside; 1 for the identity.
    #[inline]
    pub fn slope(&self, dt: f32) -> f32 {
        match *self {
            Self::Identity => 1.0,
            Self::Tow { lambda, .. } => {
                let (s_near, s_far) = self.slopes();
                if dt.abs() <= 0.5 * lambda {
                    s_near
                } else {
                    s_far
                }
            }
        }
    }

    /// W⁻¹(w): the offset Δt with W(Δt) = w (W is odd, continuous and strictly increasing).
    #[inline]
    pub fn inverse(&self, w: f32) -> f32 {
        match *self {
            Self::Identity => w,
            Self::Tow { lambda, rho } => {
                let (s_near, s_far) = self.slopes();
                let a = w.abs();
                if a <= 0.5 * rho {
                    w / s_near
                } else {
                    (0.5 * lambda + (a - 0.5 * rho) / s_far).copysign(w)
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn warps() -> [TimeWarp; 3] {
        [
            TimeWarp::tow(50.0, 300, 0.75),
            TimeWarp::tow(50.0, 300, 0.7),
            TimeWarp::Tow {
                lambda: 0.3,
                rho: 0.2,
            },
        ]
    }

    #[test]
    fn tow_constructor() {
        let w = TimeWarp::tow(50.0, 300, 0.75);
        assert_eq!(
            w,
            TimeWarp::Tow {
                lambda: 50.0 / 300.0,
                rho: 0.75
            }
        );
        // Window covering the whole sequence: no warp.
        assert_eq!(TimeWarp::tow(50.0, 50, 0.75), TimeWarp::Identity);
        assert_eq!(TimeWarp::tow(50.0, 20, 0.75), TimeWarp::Identity);
        assert_eq!(TimeWarp::tow(0.0, 20, 0.75), TimeWarp::Identity);
        assert_eq!(TimeWarp::tow(50.0, 0, 0.75), TimeWarp::Identity);
    }

    #[test]
    fn identity_is_identity() {
        let w = TimeWarp::Identity;
        for x in [-1.0, -0.3, 0.0, 0.2, 1.0] {
            assert_eq!(w.apply(x), x);
            assert_eq!(w.inverse(x), x);
            assert_eq!(w.slope(x), 1.0);
        }
    }

    #[test]
    fn continuous_at_window_edges() {
        for w in warps() {
            let TimeWarp::Tow { lambda, rho } = w else {
                unreachable!()
            };
            for sign in [-1.0f32, 1.0] {
                let edge = sign * 0.5 * lambda;
                let inside = w.apply(edge);
                let outside = w.apply(edge + sign * 1e-6);
                assert!((inside - sign * 0.5 * rho).abs() < 1e-6, "{inside}");
                assert!((outside - inside).abs() < 1e-5, "{inside} vs {outside}");
            }
        }
    }

    #[test]
    fn odd_and_preserves_span() {
        for w in warps() {
            let TimeWarp::Tow { lambda, rho } = w else {
                unreachable!()
            };
            // The unit-length span centred on t_i is preserved: W(±½) = ±½.
            assert!((w.apply(0.5) - 0.5).abs() < 1e-6, "{}", w.apply(0.5));
            assert!((w.apply(-0.5) + 0.5).abs() < 1e-6);
            // More generally the whole sequence t ∈ [0, 1] keeps its length 1 in warped time,
            // W(1 − t_i) − W(−t_i) = 1, whenever both ends lie outside the window; a fraction ρ
            // of it is the window's.
            for i in 0..=100 {
                let center = i as f32 / 100.0;
                if center < 0.5 * lambda || 1.0 - center < 0.5 * lambda {
                    continue;
                }
                let span = w.apply(1.0 - center) - w.apply(-center);
                assert!((span - 1.0).abs() < 1e-5, "t_i = {center}: span {span}");
                let window = w.apply(0.5 * lambda) - w.apply(-0.5 * lambda);
                assert!((window - rho).abs() < 1e-6);
            }
            // Beyond: W(1) = ρ/2 + s_far·(1 − λ/2), i.e. not 1 (see the module docs).
            let s_far = (1.0 - rho) / (1.0 - lambda);
            assert!((w.apply(1.0) - (0.5 * rho + s_far * (1.0 - 0.5 * lambda))).abs() < 1e-6);
            assert_eq!(w.apply(0.0), 0.0);
            for i in 0..=200 {
                let x = -1.0 + 0.01 * i as f32;
                assert_eq!(w.apply(-x), -w.apply(x));
            }
        }
    }

    #[test]
    fn slope_and_monotonicity() {
        for w in warps() {
            let TimeWarp::Tow { lambda, rho } = w else {
                unreachable!()
            };
            let s_near = rho / lambda;
            let s_far = (1.0 - rho) / (1.0 - lambda);
            assert_eq!(w.slope(0.0), s_near);
            assert_eq!(w.slope(0.49 * lambda), s_near);
            assert_eq!(w.slope(-0.49 * lambda), s_near);
            assert_eq!(w.slope(0.51 * lambda), s_far);
            assert_eq!(w.slope(-0.9), s_far);
            // Inside the window W(Δt) = (ρ/λ)·Δt.
            let x = 0.3 * lambda;
            assert!((w.apply(x) - s_near * x).abs() < 1e-7);
            // Finite differences agree with the slope away from the kinks.
            for x in [-0.9f32, -0.2 * lambda, 0.1 * lambda, 0.7] {
                let h = 1e-3 * lambda;
                let fd = (w.apply(x + h) - w.apply(x - h)) / (2.0 * h);
                assert!(
                    (fd - w.slope(x)).abs() < 1e-2 * w.slope(x),
                    "{fd} vs {}",
                    w.slope(x)
                );
            }
            let mut prev = w.apply(-1.0);
            for i in 1..=400 {
                let next = w.apply(-1.0 + 0.005 * i as f32);
                assert!(next > prev);
                prev = next;
            }
        }
    }

    #[test]
    fn inverse_round_trips() {
        for w in warps() {
            for i in 0..=400 {
                let x = -1.2 + 0.006 * i as f32;
                let back = w.inverse(w.apply(x));
                assert!((back - x).abs() < 1e-5, "{x} -> {back}");
                let fwd = w.apply(w.inverse(x));
                assert!((fwd - x).abs() < 1e-5, "{x} -> {fwd}");
            }
        }
    }
}
