//! Temporal Offset Warping (TOW, SPEC §3).
//!
//! The offset Δt = t − t_i between the rendered time and a Gaussian's temporal centre is
//! remapped by a piecewise-linear, monotone function W before it enters the deformation:
//! a window of width λ around the centre is stretched (slope s_near = ρ/λ) and the rest is
//! compressed (slope s_far = (1 − ρ)/(1 − λ)), with the far branch continued from the window
//! edge (the paper writes it as s_far·Δt, which jumps at |Δt| = λ/2).
//!
//! What "preserves the total temporal span" means with these slopes: the sequence t ∈ [0, 1]
//! has length 1 and keeps it, W(1 − t_i) − W(−t_i) = ρ + s_far·(1 − λ) = 1, whenever both of
//! its ends lie outside the window; in particular W(±½) = ±½. A fraction ρ of that warped
//! length belongs to the window. W(±1) is *not* ±1 (it is ρ/2 + s_far·(1 − λ/2), 0.65 for
//! λ = 50/300, ρ = 0.75): slopes giving W(±1) = ±1 would have to differ from the paper's.
//!
//! The paper centres the window on every Gaussian, so for one centred at the sequence's first
//! or last instant half of it lies outside the sequence. The authors' code gives such a
//! Gaussian a one-sided window of the whole λ inside the sequence instead
//! (`model.tow.one_sided_ends`): W is then odd only about interior centres, and the sequence
//! keeps its length 1 for the end centres too (W(1) = 1 at t_i = 0).
//!
//! The piecewise-linear W has corners at the window's edges, where its slope jumps by
//! s_near/s_far (6× for λ = ⅓, ρ = 0.75), so a motion that is smooth in real time needs a
//! trajectory with a kink in warped time, which the few Fourier terms cannot follow. With
//! `model.tow.smooth` the corners are rounded: on a side whose window extent is e (λ/2, or
//! the one-sided λ or 0), |W| = s_far·|Δt| + (s_near − s_far)·e·tanh(|Δt|/e). That has the
//! same slope s_near at the centre and the same far branch as |Δt| grows (the gap,
//! (s_near − s_far)·e·(1 − tanh(|Δt|/e)), is under 1 % of the window's stretch from 2.7·e on),
//! and a slope that falls smoothly in between.

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
        /// Whether a Gaussian centred at t_i ≤ 0 (t_i ≥ 1) gets the window 0 ≤ Δt ≤ λ
        /// (−λ ≤ Δt ≤ 0) instead of |Δt| ≤ λ/2 (authors' implementation).
        one_sided_ends: bool,
        /// Round the window's corners (the tanh form of the module docs) instead of the
        /// paper's piecewise-linear W.
        smooth: bool,
    },
}

/// Newton steps of [`TimeWarp::inverse`] for the smooth warp at most; it converges in 3 to 8
/// from the piecewise-linear inverse, more only for ρ within a few thousandths of 0 or 1.
const SMOOTH_INVERSE_STEPS: usize = 40;

/// Smallest and largest ρ accepted by [`TimeWarp::tow`]; keeps both slopes positive so that
/// the warp stays invertible.
const RHO_RANGE: (f32, f32) = (1e-3, 1.0 - 1e-3);

impl TimeWarp {
    /// The TOW warp for a window of `window_frames` frames in a `frame_count`-frame sequence:
    /// λ = window_frames / frame_count, centred windows everywhere (the paper). Falls back to
    /// [`TimeWarp::Identity`] when λ is not in (0, 1) (the window covers the whole sequence).
    /// ρ is clamped into [1e-3, 1 − 1e-3].
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
        Self::Tow {
            lambda,
            rho,
            one_sided_ends: false,
            smooth: false,
        }
    }

    /// The same warp with rounded corners (`on`) or the paper's piecewise-linear form; the
    /// identity stays the identity.
    pub fn with_smooth_corners(mut self, on: bool) -> Self {
        if let Self::Tow { smooth, .. } = &mut self {
            *smooth = on;
        }
        self
    }

    /// The same warp with one-sided windows for Gaussians centred at the sequence's ends
    /// (`on`) or centred windows everywhere; the identity stays the identity.
    pub fn with_one_sided_ends(mut self, on: bool) -> Self {
        if let Self::Tow { one_sided_ends, .. } = &mut self {
            *one_sided_ends = on;
        }
        self
    }

    /// Slopes (s_near, s_far) of the warp; (1, 1) for the identity.
    #[inline]
    fn slopes(&self) -> (f32, f32) {
        match *self {
            Self::Identity => (1.0, 1.0),
            Self::Tow { lambda, rho, .. } => (rho / lambda, (1.0 - rho) / (1.0 - lambda)),
        }
    }

    /// The fraction of the window on the side of Δt (the sign of `offset`, raw or warped) for
    /// a Gaussian centred at `center`: ½, or with one-sided ends 1 on the sequence's side of
    /// an end centre and 0 on the other.
    #[inline]
    fn window_fraction(&self, center: f32, offset: f32) -> f32 {
        match *self {
            Self::Tow {
                one_sided_ends: true,
                ..
            } if center <= 0.0 || center >= 1.0 => {
                let towards_sequence = if center <= 0.0 {
                    offset >= 0.0
                } else {
                    offset <= 0.0
                };
                if towards_sequence { 1.0 } else { 0.0 }
            }
            _ => 0.5,
        }
    }

    /// W(Δt) for a Gaussian centred at `center`: s_near·Δt inside the window (|Δt| ≤ λ/2, or
    /// the one-sided end window), else sign(Δt)·(s_near·e + s_far·(|Δt| − e)) with e the
    /// window's extent on that side; with rounded corners sign(Δt)·(s_far·|Δt| +
    /// (s_near − s_far)·e·tanh(|Δt|/e)).
    #[inline]
    pub fn apply(&self, center: f32, dt: f32) -> f32 {
        match *self {
            Self::Identity => dt,
            Self::Tow {
                lambda,
                rho,
                smooth,
                ..
            } => {
                let (s_near, s_far) = self.slopes();
                let fraction = self.window_fraction(center, dt);
                let (a, e) = (dt.abs(), fraction * lambda);
                if smooth {
                    smooth_warp(a, e, s_near, s_far).0.copysign(dt)
                } else if a <= e {
                    s_near * dt
                } else {
                    // s_near·(fraction·λ) = fraction·ρ.
                    (fraction * rho + s_far * (a - e)).copysign(dt)
                }
            }
        }
    }

    /// dW/dΔt for a Gaussian centred at `center`: s_near inside its window, s_far outside (in
    /// between with rounded corners); 1 for the identity.
    #[inline]
    pub fn slope(&self, center: f32, dt: f32) -> f32 {
        match *self {
            Self::Identity => 1.0,
            Self::Tow { lambda, smooth, .. } => {
                let (s_near, s_far) = self.slopes();
                let e = self.window_fraction(center, dt) * lambda;
                if smooth {
                    smooth_warp(dt.abs(), e, s_near, s_far).1
                } else if dt.abs() <= e {
                    s_near
                } else {
                    s_far
                }
            }
        }
    }

    /// W⁻¹(w) for a Gaussian centred at `center`: the offset Δt with W(Δt) = w (W is
    /// continuous, strictly increasing and keeps the sign).
    #[inline]
    pub fn inverse(&self, center: f32, w: f32) -> f32 {
        match *self {
            Self::Identity => w,
            Self::Tow {
                lambda,
                rho,
                smooth,
                ..
            } => {
                let (s_near, s_far) = self.slopes();
                let fraction = self.window_fraction(center, w);
                let (a, e) = (w.abs(), fraction * lambda);
                let mut x = if a <= fraction * rho {
                    a / s_near
                } else {
                    e + (a - fraction * rho) / s_far
                };
                if smooth {
                    // Newton from the piecewise-linear inverse. The rounded |W| lies below
                    // the piecewise one where that is concave (ρ > λ) and above it where it
                    // is convex, so every step moves towards the root from the same side.
                    for _ in 0..SMOOTH_INVERSE_STEPS {
                        let (value, slope) = smooth_warp(x, e, s_near, s_far);
                        let step = (value - a) / slope;
                        x -= step;
                        if step.abs() <= 1e-7 * x.max(1.0) {
                            break;
                        }
                    }
                }
                x.copysign(w)
            }
        }
    }
}

/// The rounded warp on one side: (|W|, dW/dΔt) at |Δt| = `a` for a window extent `e` on
/// that side (no window, e = 0: the far slope throughout).
#[inline]
fn smooth_warp(a: f32, e: f32, s_near: f32, s_far: f32) -> (f32, f32) {
    if e <= 0.0 {
        return (s_far * a, s_far);
    }
    let th = (a / e).tanh();
    (
        s_far * a + (s_near - s_far) * e * th,
        s_far + (s_near - s_far) * (1.0 - th * th),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An interior temporal centre, where every window is centred.
    const MID: f32 = 0.5;

    fn warps() -> [TimeWarp; 3] {
        [
            TimeWarp::tow(50.0, 300, 0.75),
            TimeWarp::tow(50.0, 300, 0.7),
            TimeWarp::Tow {
                lambda: 0.3,
                rho: 0.2,
                one_sided_ends: false,
                smooth: false,
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
                rho: 0.75,
                one_sided_ends: false,
                smooth: false,
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
            assert_eq!(w.apply(MID, x), x);
            assert_eq!(w.inverse(MID, x), x);
            assert_eq!(w.slope(MID, x), 1.0);
        }
    }

    #[test]
    fn continuous_at_window_edges() {
        for w in warps() {
            let TimeWarp::Tow { lambda, rho, .. } = w else {
                unreachable!()
            };
            for sign in [-1.0f32, 1.0] {
                let edge = sign * 0.5 * lambda;
                let inside = w.apply(MID, edge);
                let outside = w.apply(MID, edge + sign * 1e-6);
                assert!((inside - sign * 0.5 * rho).abs() < 1e-6, "{inside}");
                assert!((outside - inside).abs() < 1e-5, "{inside} vs {outside}");
            }
        }
    }

    #[test]
    fn odd_and_preserves_span() {
        for w in warps() {
            let TimeWarp::Tow { lambda, rho, .. } = w else {
                unreachable!()
            };
            // The unit-length span centred on t_i is preserved: W(±½) = ±½.
            assert!(
                (w.apply(MID, 0.5) - 0.5).abs() < 1e-6,
                "{}",
                w.apply(MID, 0.5)
            );
            assert!((w.apply(MID, -0.5) + 0.5).abs() < 1e-6);
            // More generally the whole sequence t ∈ [0, 1] keeps its length 1 in warped time,
            // W(1 − t_i) − W(−t_i) = 1, whenever both ends lie outside the window; a fraction ρ
            // of it is the window's.
            for i in 0..=100 {
                let center = i as f32 / 100.0;
                if center < 0.5 * lambda || 1.0 - center < 0.5 * lambda {
                    continue;
                }
                let span = w.apply(center, 1.0 - center) - w.apply(center, -center);
                assert!((span - 1.0).abs() < 1e-5, "t_i = {center}: span {span}");
                let window = w.apply(MID, 0.5 * lambda) - w.apply(MID, -0.5 * lambda);
                assert!((window - rho).abs() < 1e-6);
            }
            // Beyond: W(1) = ρ/2 + s_far·(1 − λ/2), i.e. not 1 (see the module docs).
            let s_far = (1.0 - rho) / (1.0 - lambda);
            assert!((w.apply(MID, 1.0) - (0.5 * rho + s_far * (1.0 - 0.5 * lambda))).abs() < 1e-6);
            assert_eq!(w.apply(MID, 0.0), 0.0);
            for i in 0..=200 {
                let x = -1.0 + 0.01 * i as f32;
                assert_eq!(w.apply(MID, -x), -w.apply(MID, x));
            }
        }
    }

    #[test]
    fn slope_and_monotonicity() {
        for w in warps() {
            let TimeWarp::Tow { lambda, rho, .. } = w else {
                unreachable!()
            };
            let s_near = rho / lambda;
            let s_far = (1.0 - rho) / (1.0 - lambda);
            assert_eq!(w.slope(MID, 0.0), s_near);
            assert_eq!(w.slope(MID, 0.49 * lambda), s_near);
            assert_eq!(w.slope(MID, -0.49 * lambda), s_near);
            assert_eq!(w.slope(MID, 0.51 * lambda), s_far);
            assert_eq!(w.slope(MID, -0.9), s_far);
            // Inside the window W(Δt) = (ρ/λ)·Δt.
            let x = 0.3 * lambda;
            assert!((w.apply(MID, x) - s_near * x).abs() < 1e-7);
            // Finite differences agree with the slope away from the kinks.
            for x in [-0.9f32, -0.2 * lambda, 0.1 * lambda, 0.7] {
                let h = 1e-3 * lambda;
                let fd = (w.apply(MID, x + h) - w.apply(MID, x - h)) / (2.0 * h);
                assert!(
                    (fd - w.slope(MID, x)).abs() < 1e-2 * w.slope(MID, x),
                    "{fd} vs {}",
                    w.slope(MID, x)
                );
            }
            let mut prev = w.apply(MID, -1.0);
            for i in 1..=400 {
                let next = w.apply(MID, -1.0 + 0.005 * i as f32);
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
                let back = w.inverse(MID, w.apply(MID, x));
                assert!((back - x).abs() < 1e-5, "{x} -> {back}");
                let fwd = w.apply(MID, w.inverse(MID, x));
                assert!((fwd - x).abs() < 1e-5, "{x} -> {fwd}");
            }
        }
    }

    /// Rounded corners: slope s_near at the centre (the paper's), the paper's far branch in
    /// the limit (the gap (s_near − s_far)·e·(1 − tanh(|Δt|/e)) exactly, under 1 % of the
    /// window's stretch from |Δt| = 2.7·e on), below the piecewise W where it is concave (ρ > λ)
    /// and above it where convex; odd for interior centres, strictly increasing, no kink
    /// (finite differences match the slope everywhere, the window's edges included), and the
    /// inverse round-trips to 1e-5, also for ρ close to 0 or 1 and for one-sided end windows.
    #[test]
    fn smooth_corners() {
        let extremes = [
            TimeWarp::Tow {
                lambda: 1.0 / 3.0,
                rho: 0.999,
                one_sided_ends: false,
                smooth: false,
            },
            TimeWarp::Tow {
                lambda: 1.0 / 3.0,
                rho: 0.001,
                one_sided_ends: false,
                smooth: false,
            },
        ];
        for paper in warps().into_iter().chain(extremes) {
            for one_sided in [false, true] {
                let paper = paper.with_one_sided_ends(one_sided);
                let w = paper.with_smooth_corners(true);
                let TimeWarp::Tow { lambda, rho, .. } = w else {
                    unreachable!()
                };
                let (s_near, s_far) = (rho / lambda, (1.0 - rho) / (1.0 - lambda));
                for center in [0.0f32, MID, 1.0] {
                    let e = |dt: f32| paper.window_fraction(center, dt) * lambda;
                    if e(1e-3) > 0.0 {
                        assert!((w.slope(center, 0.0) - s_near).abs() < 1e-5 * s_near);
                    }
                    let mut prev = w.apply(center, -1.2);
                    for i in 1..=480 {
                        let x = -1.2 + 0.005 * i as f32;
                        let (smooth, piecewise) = (w.apply(center, x), paper.apply(center, x));
                        assert!(smooth > prev, "not increasing at {x}");
                        prev = smooth;
                        if center == MID {
                            assert_eq!(w.apply(center, -x), -smooth);
                        }
                        // Rounded below a concave piecewise W, above a convex one.
                        let gap = (piecewise - smooth) * x.signum() * (rho - lambda).signum();
                        assert!(gap >= -1e-6, "{x}: {smooth} vs {piecewise}");
                        let ex = e(x);
                        let expected = if ex > 0.0 {
                            (s_near - s_far) * ex * (1.0 - (x.abs() / ex).tanh())
                        } else {
                            0.0
                        };
                        if x.abs() >= e(x) {
                            assert!(
                                (gap.abs() - expected.abs()).abs() < 1e-5,
                                "{x}: gap {gap} vs {expected}"
                            );
                            if x.abs() >= 2.7 * ex {
                                assert!(gap.abs() <= 0.01 * (s_near - s_far).abs() * ex + 1e-6);
                            }
                        }
                        let h = 1e-3;
                        let fd = (w.apply(center, x + h) - w.apply(center, x - h)) / (2.0 * h);
                        let slope = w.slope(center, x);
                        // Away from Δt = 0, where a one-sided window's two sides meet.
                        if x.abs() > 2.0 * h {
                            assert!(
                                (fd - slope).abs() < 2e-3 * slope.max(1.0),
                                "{x}: {fd} vs {slope}"
                            );
                        }
                        // A flat W (ρ near 0 or 1) magnifies the rounding of W(x) by 1/slope.
                        let back = w.inverse(center, smooth);
                        assert!(
                            (back - x).abs() < 1e-5 / slope.min(1.0),
                            "{w:?} at {center}: {x} -> {back}"
                        );
                        let fwd = w.apply(center, w.inverse(center, x));
                        assert!((fwd - x).abs() < 1e-5, "{w:?} at {center}: {x} -> {fwd}");
                    }
                }
            }
        }
        assert_eq!(
            TimeWarp::Identity.with_smooth_corners(true),
            TimeWarp::Identity
        );
    }

    /// One-sided end windows: a Gaussian centred at t_i = 0 (t_i = 1) has the whole window on
    /// the sequence's side: W = s_near·Δt up to Δt = λ (down to −λ), continuous there at ±ρ,
    /// W(±1) = ±1 so the sequence keeps its warped length 1; s_far on the outer side, the
    /// slope matches finite differences, W stays increasing and the inverse round-trips.
    /// Interior centres, and every centre with the option off, keep the centred window bit
    /// for bit.
    #[test]
    fn one_sided_end_windows() {
        for centred in warps() {
            let w = centred.with_one_sided_ends(true);
            let TimeWarp::Tow { lambda, rho, .. } = w else {
                unreachable!()
            };
            let (s_near, s_far) = (rho / lambda, (1.0 - rho) / (1.0 - lambda));
            for (center, side) in [(0.0f32, 1.0f32), (1.0, -1.0)] {
                let edge = side * lambda;
                assert!((w.apply(center, edge) - side * rho).abs() < 1e-6);
                let beyond = w.apply(center, edge + side * 1e-6);
                assert!((beyond - side * rho).abs() < 1e-5, "{beyond}");
                assert!(
                    (w.apply(center, side) - side).abs() < 1e-5,
                    "W(±1) = {}",
                    w.apply(center, side)
                );
                assert!(
                    (w.apply(center, side * 0.9 * lambda) - side * s_near * 0.9 * lambda).abs()
                        < 1e-6
                );
                assert_eq!(w.slope(center, side * 0.99 * lambda), s_near);
                assert_eq!(w.slope(center, side * 1.01 * lambda), s_far);
                // The side outside the sequence has no window.
                assert_eq!(w.slope(center, -side * 0.01 * lambda), s_far);
                assert!((w.apply(center, -side * 0.1) + side * s_far * 0.1).abs() < 1e-7);
                for x in [-0.9f32, -0.5 * lambda, 0.3 * lambda, 0.7] {
                    let h = 1e-3 * lambda;
                    let fd = (w.apply(center, x + h) - w.apply(center, x - h)) / (2.0 * h);
                    let slope = w.slope(center, x);
                    assert!((fd - slope).abs() < 1e-2 * slope, "{fd} vs {slope}");
                }
                let mut prev = w.apply(center, -1.2);
                for i in 1..=400 {
                    let x = -1.2 + 0.006 * i as f32;
                    let next = w.apply(center, x);
                    assert!(next > prev);
                    prev = next;
                    let back = w.inverse(center, next);
                    assert!((back - x).abs() < 1e-5, "{x} -> {back}");
                    let fwd = w.apply(center, w.inverse(center, x));
                    assert!((fwd - x).abs() < 1e-5, "{x} -> {fwd}");
                }
                for i in 0..=200 {
                    let x = -1.0 + 0.01 * i as f32;
                    assert_eq!(centred.apply(center, x), centred.apply(MID, x));
                    assert_eq!(centred.inverse(center, x), centred.inverse(MID, x));
                }
            }
            for center in [1e-6, 0.3, 0.999_999] {
                for i in 0..=200 {
                    let x = -1.0 + 0.01 * i as f32;
                    assert_eq!(
                        w.apply(center, x).to_bits(),
                        centred.apply(center, x).to_bits()
                    );
                    assert_eq!(w.slope(center, x), centred.slope(center, x));
                    assert_eq!(
                        w.inverse(center, x).to_bits(),
                        centred.inverse(center, x).to_bits()
                    );
                }
            }
        }
        assert_eq!(
            TimeWarp::Identity.with_one_sided_ends(true),
            TimeWarp::Identity
        );
    }
}
