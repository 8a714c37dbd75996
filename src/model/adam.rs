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
