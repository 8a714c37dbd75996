//! Adam's update rule (Kingma & Ba, with the 3DGS ε), shared by the CPU systems
//! ([`crate::systems::adam`]) and the GPU kernel ([`crate::gpu`]'s Adam), which must agree.

/// Adam's first-moment decay.
pub const BETA1: f32 = 0.9;
/// Adam's second-moment decay.
pub const BETA2: f32 = 0.999;
/// Adam's denominator guard (3DGS uses 1e-15).
pub const EPSILON: f32 = 1e-15;

/// Adam's bias corrections after `step` updates (counted from 1).
#[derive(Clone, Copy)]
pub struct BiasCorrection {
    /// 1 − β1^step.
    pub first: f32,
    /// 1 − β2^step.
    pub second: f32,
}

impl BiasCorrection {
    /// The corrections after `step` updates.
    pub fn after(step: i32) -> Self {
        Self {
            first: 1.0 - BETA1.powi(step),
            second: 1.0 - BETA2.powi(step),
        }
    }
}

/// One Adam update of the value `x` with gradient `g`, moments `m`/`v` and learning rate `lr`.
#[inline]
pub fn adam_update(x: &mut f32, g: f32, m: &mut f32, v: &mut f32, lr: f32, bias: BiasCorrection) {
    *m = BETA1 * *m + (1.0 - BETA1) * g;
    *v = BETA2 * *v + (1.0 - BETA2) * g * g;
    let step_size = lr / bias.first;
    *x -= step_size * *m / ((*v / bias.second).sqrt() + EPSILON);
}

/// The ratio r = β1/√β2 by which each skipped step's share of the first moment over the root
/// of the second falls: after j steps without a gradient, m̂/√v̂ is r^j times what it was
/// (bias corrections apart).
pub fn momentum_ratio() -> f64 {
    f64::from(BETA1) / f64::from(BETA2).sqrt()
}

/// The weight of step `step`'s learning rate in a deferred momentum step (see
/// [`DeferredSums`]): √(1 − β2^step) / (1 − β1^step), Adam's bias corrections as the dense
/// update applies them.
pub fn bias_weight(step: u32) -> f64 {
    let bias = BiasCorrection::after(step.min(i32::MAX as u32) as i32);
    f64::from(bias.second).sqrt() / f64::from(bias.first)
}

/// Running sums that turn any run of Adam steps without a gradient into one update.
///
/// Dense Adam steps a value whose gradient is zero on its momentum alone: after the last
/// step `s` with a gradient, step u > s moves it by lr_u·m_u/(1−β1^u) / √(v_u/(1−β2^u))
/// with m_u = β1^(u−s)·m_s and v_u = β2^(u−s)·v_s, that is by
/// lr_u·r^(u−s)·b_u·m_s/√v_s ([`momentum_ratio`] r, [`bias_weight`] b_u; ε neglected).
/// The steps s+1..=e together move it by C·m_s/√v_s with C = Σ lr_u·r^(u−s)·b_u, which
/// the sums S(u) = Σ_{w = start+1..=u} lr_w·r^(w−start)·b_w give as
/// C = r^(start−s)·(S(e) − S(s)) for any s ≥ start: one subtraction per value, whatever the
/// number of steps. `start` must be recent (the sums span at most a few hundred steps) so
/// that the difference keeps its precision in `f64`.
#[derive(Clone, Debug, Default)]
pub struct DeferredSums {
    /// The step the sums start after (S(start) = 0).
    start: u32,
    /// Values per step (one learning rate each).
    width: usize,
    /// S(start), S(start + 1), … one row of `width` values per step.
    rows: Vec<f64>,
    /// Per step k after `start`: r^−k, which turns a difference of sums into a coefficient.
    unscale: Vec<f64>,
    /// Per step k after `start`: [`deferred_epsilon`] of a value last stepped there.
    epsilons: Vec<f32>,
    /// Per count of steps d: [`moment_decay`] over d steps.
    decays: Vec<[f32; 2]>,
}

impl DeferredSums {
    /// Sums starting after step `start`, for `width` values per step.
    pub fn new(start: u32, width: usize) -> Self {
        Self {
            start,
            width,
            rows: vec![0.0; width],
            unscale: vec![1.0],
            epsilons: vec![deferred_epsilon(start)],
            decays: vec![moment_decay(0)],
        }
    }

    /// The step the sums start after.
    pub fn start(&self) -> u32 {
        self.start
    }

    /// The last step summed.
    pub fn end(&self) -> u32 {
        self.start + self.unscale.len() as u32 - 1
    }

    /// The values per step.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Adds step `end() + 1`, whose per-value learning rates are `rates` (`width` of them).
    pub fn push(&mut self, rates: &[f32]) {
        assert_eq!(rates.len(), self.width, "one learning rate per value");
        let step = self.end() + 1;
        let k = (step - self.start) as i32;
        let weight = bias_weight(step) * momentum_ratio().powi(k);
        let previous = self.rows.len() - self.width;
        for (j, &rate) in rates.iter().enumerate() {
            let sum = self.rows[previous + j] + f64::from(rate) * weight;
            self.rows.push(sum);
        }
        self.unscale.push(momentum_ratio().powi(-k));
        self.epsilons.push(deferred_epsilon(step));
        self.decays.push(moment_decay(k as u32));
    }

    /// The momentum coefficients C of steps `last + 1 ..= through` for a value last stepped
    /// at `last` (start ≤ last ≤ through ≤ [`Self::end`]), one per value, into `out`.
    pub fn coefficients(&self, last: u32, through: u32, out: &mut [f32]) {
        debug_assert!(self.start <= last && last <= through && through <= self.end());
        let row = |step: u32| {
            let at = (step - self.start) as usize * self.width;
            &self.rows[at..at + self.width]
        };
        let scale = self.unscale[(last - self.start) as usize];
        for ((c, to), from) in out.iter_mut().zip(row(through)).zip(row(last)) {
            *c = ((to - from) * scale) as f32;
        }
    }

    /// [`deferred_epsilon`] of a value last stepped at `last` (start ≤ last ≤ end).
    pub fn epsilon(&self, last: u32) -> f32 {
        self.epsilons[(last - self.start) as usize]
    }

    /// [`moment_decay`] over `steps` steps (at most end − start).
    pub fn decay(&self, steps: u32) -> [f32; 2] {
        self.decays[steps as usize]
    }
}

/// Applies steps of dense Adam without a gradient to the value `x` at once: moves it by the
/// momentum coefficient `coefficient` ([`DeferredSums::coefficients`]) times m/(√v + ε′) and
/// decays the moments by `decay` ([`moment_decay`]) as those steps would have. ε′ is Adam's ε
/// as the first skipped step sees it ([`deferred_epsilon`]): it matters only for values whose
/// gradients are ~1e-15 and below, where it keeps them from moving as if they had momentum.
#[inline]
pub fn deferred_update(
    x: &mut f32,
    m: &mut f32,
    v: &mut f32,
    coefficient: f32,
    epsilon: f32,
    decay: [f32; 2],
) {
    *x -= coefficient * *m / (v.sqrt() + epsilon);
    *m *= decay[0];
    *v *= decay[1];
}

/// ε on the scale of the raw second moment at the first step after `last`: dense Adam adds ε
/// to √(v/(1 − β2^u)), which is ε·√(1 − β2^u) added to √v.
pub fn deferred_epsilon(last: u32) -> f32 {
    EPSILON
        * BiasCorrection::after((last.saturating_add(1)).min(i32::MAX as u32) as i32)
            .second
            .sqrt()
}

/// The moments' decay [β1^steps, β2^steps] over `steps` steps without a gradient.
pub fn moment_decay(steps: u32) -> [f32; 2] {
    let steps = steps.min(i32::MAX as u32) as i32;
    [BETA1.powi(steps), BETA2.powi(steps)]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steps without a gradient applied at once equal dense Adam's one-by-one updates to
    /// 1e-5 relative (moments to 1e-5), for early steps (bias corrections far from 1), a
    /// learning rate that changes every step, and runs that start anywhere after the sums do.
    #[test]
    fn deferred_steps_equal_dense_steps() {
        let width = 3;
        let rate = |step: u32, j: usize| 1e-3 * (1.0 + j as f32) * 0.99f32.powi(step as i32);
        for (start, last, through) in [
            (0, 0, 1),
            (0, 0, 40),
            (0, 7, 90),
            (500, 530, 600),
            (5000, 5000, 5003),
        ] {
            let mut sums = DeferredSums::new(start, width);
            for step in start + 1..=through {
                let rates: Vec<f32> = (0..width).map(|j| rate(step, j)).collect();
                sums.push(&rates);
            }
            assert_eq!(sums.end(), through);
            let (x0, m0, v0) = (
                [0.5f32, -1.0, 2.0],
                [1e-3f32, -2e-4, 0.0],
                [4e-6f32, 1e-7, 0.0],
            );
            let (mut x, mut m, mut v) = (x0, m0, v0);
            for step in last + 1..=through {
                let bias = BiasCorrection::after(step as i32);
                for j in 0..width {
                    adam_update(&mut x[j], 0.0, &mut m[j], &mut v[j], rate(step, j), bias);
                }
            }
            let mut coefficient = [0.0; 3];
            sums.coefficients(last, through, &mut coefficient);
            let decay = sums.decay(through - last);
            assert_eq!(decay, moment_decay(through - last));
            let epsilon = sums.epsilon(last);
            assert_eq!(epsilon, deferred_epsilon(last));
            let (mut xd, mut md, mut vd) = (x0, m0, v0);
            for j in 0..width {
                deferred_update(
                    &mut xd[j],
                    &mut md[j],
                    &mut vd[j],
                    coefficient[j],
                    epsilon,
                    decay,
                );
                let close = |a: f32, b: f32, scale: f32| (a - b).abs() <= 1e-5 * scale.max(1e-30);
                // The dense run rounds x once per step: allow that on top of 1e-5 of the move.
                let moved = (x[j] - x0[j]).abs();
                assert!(
                    (xd[j] - x[j]).abs() <= 1e-5 * moved + 2e-6 * x0[j].abs(),
                    "x[{j}] {start} {last} {through}: {} vs {}",
                    xd[j],
                    x[j]
                );
                assert!(
                    close(md[j], m[j], m[j].abs()),
                    "m[{j}]: {} vs {}",
                    md[j],
                    m[j]
                );
                assert!(
                    close(vd[j], v[j], v[j].abs()),
                    "v[{j}]: {} vs {}",
                    vd[j],
                    v[j]
                );
            }
            // A value without momentum stays put.
            assert_eq!(xd[2], x0[2]);
        }
    }
}
