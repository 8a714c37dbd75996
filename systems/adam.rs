//! Adam with per-group learning rates and exponential decay of the position learning rate.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;

use crate::components::{
    Adam, Color, ColorRest, Fourier, Grad, Opacity, Param, Position, Rotation, Scale, SplatSlot,
    Temporal, each_param,
};
use crate::model::exposure::Exposure;
use crate::model::sh::{SH_COEFFS, coeff_count};
use crate::resources::{CameraExposures, Settings, SplatBuffers, TrainState};
use crate::scene::LearningRates;

pub use crate::model::adam::{BETA1, BETA2, EPSILON};
use crate::model::adam::{BiasCorrection, adam_update};

/// A parameter group: how each of its values' learning rate is set.
pub trait ParamGroup: Param {
    /// Per-value learning rates, laid out like the component itself. `position_lr` is the
    /// current (decayed, extent-scaled) position learning rate.
    fn learning_rates(lr: &LearningRates, position_lr: f32) -> Self;

    /// How many leading values of the flat layout ([`Param::values`]) can have a non-zero
    /// gradient at SH degree `sh_degree`; Adam leaves the rest alone. Their gradients and
    /// moments are exactly zero, so skipping them changes nothing but the memory traffic.
    fn active_values(_sh_degree: u32) -> usize {
        std::mem::size_of::<Self>() / std::mem::size_of::<f32>()
    }
}

impl ParamGroup for Position {
    fn learning_rates(_: &LearningRates, position_lr: f32) -> Self {
        Self {
            mean: [position_lr; 3],
        }
    }
}

impl ParamGroup for Fourier {
    fn learning_rates(lr: &LearningRates, position_lr: f32) -> Self {
        let coeff = [[lr.fourier_cos_sin * position_lr; 3]; 4];
        Self {
            cos: coeff,
            sin: coeff,
            phase: [lr.fourier_phase * position_lr; 4],
        }
    }
}

impl ParamGroup for Temporal {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        // The temporal centre stays at its anchor unless its rate is set.
        Self {
            center: lr.temporal_center,
            scale: [lr.temporal_scale; 2],
        }
    }
}

impl ParamGroup for Opacity {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self { logit: lr.opacity }
    }
}

impl ParamGroup for Rotation {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self {
            c0: [lr.rotation; 4],
            c1: [lr.rotation_velocity; 4],
        }
    }
}

impl ParamGroup for Scale {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self {
            d0: [lr.scale; 3],
            d1: [lr.scale_velocity; 3],
        }
    }
}

impl ParamGroup for Color {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self { dc: [lr.sh_dc; 3] }
    }
}

impl ParamGroup for ColorRest {
    fn learning_rates(lr: &LearningRates, _: f32) -> Self {
        Self {
            sh: [[lr.sh_dc / lr.sh_rest_divisor; 3]; SH_COEFFS - 1],
        }
    }

    /// Coefficients above the active degree get no gradient (the basis is band by band).
    fn active_values(sh_degree: u32) -> usize {
        3 * (coeff_count(sh_degree) - 1)
    }
}

/// Position learning rate at `iteration`: exponential interpolation from `position` to
/// `position_final` over the run, scaled by the scene extent.
pub fn position_lr(lr: &LearningRates, iteration: u32, iterations: u32, extent: f32) -> f32 {
    let t = (iteration as f32 / iterations.max(1) as f32).clamp(0.0, 1.0);
    (lr.position.ln() * (1.0 - t) + lr.position_final.ln() * t).exp() * extent
}

/// One Adam step on every Gaussian's `P`, with bias correction for the global step.
/// With `train.visible_adam`, Gaussians that received no gradient
/// ([`SplatBuffers::gradient_reached`]) are left as they are.
pub fn adam_step<P: ParamGroup>(
    settings: Res<Settings>,
    state: Res<TrainState>,
    buffers: Option<Res<SplatBuffers>>,
    mut params: Query<(&mut P, &Grad<P>, &mut Adam<P>, Option<&SplatSlot>)>,
) {
    let lr = &settings.train.rates_at(state.iteration);
    let rates = P::learning_rates(
        lr,
        position_lr(
            lr,
            state.iteration,
            settings.train.iterations,
            settings.extent,
        ),
    );
    let bias = BiasCorrection::after(state.iteration.max(1) as i32);
    let active = P::active_values(state.sh_degree);
    // Without the splatting stage's buffers (a world that only optimises), every Gaussian
    // counts as seen.
    let reached = buffers
        .as_deref()
        .filter(|_| settings.train.visible_adam)
        .map(|b| b.gradient_reached.as_slice());
    let unseen = |slot: Option<&SplatSlot>| match (reached, slot) {
        (Some(reached), Some(slot)) => !reached.get(slot.0 as usize).is_some_and(|&r| r),
        _ => false,
    };
    params
        .par_iter_mut()
        .for_each(|(mut value, grad, mut adam, slot)| {
            if unseen(slot) {
                return;
            }
            let adam = &mut *adam;
            let (m, v) = (adam.m.values_mut(), adam.v.values_mut());
            for (i, (x, g)) in value.values_mut()[..active]
                .iter_mut()
                .zip(grad.0.values())
                .enumerate()
            {
                adam_update(x, *g, &mut m[i], &mut v[i], rates.values()[i], bias);
            }
        });
}

/// One Adam step on the exposure correction of the camera the loss trained on (see
/// [`CameraExposures`]), then re-centres the corrections over the training cameras.
///
/// Scaling every camera's gain by k while dividing the Gaussians' colours by k (or shifting
/// offsets against colours) leaves the loss unchanged. Centring pins that freedom: the model
/// keeps the colours of an average training camera, which is what a held-out camera, drawn
/// without a correction, is assumed to see.
pub fn adam_exposure(settings: Res<Settings>, exposures: Option<ResMut<CameraExposures>>) {
    let Some(mut exposures) = exposures else {
        return;
    };
    let Some((index, grad)) = exposures.grad.take() else {
        return;
    };
    let lr = settings.train.lr.exposure;
    let camera = &mut exposures.cameras[index];
    camera.steps += 1;
    let bias = BiasCorrection::after(camera.steps.min(i32::MAX as u32) as i32);
    let mut values = camera.exposure.values();
    for (i, g) in grad.values().into_iter().enumerate() {
        adam_update(
            &mut values[i],
            g,
            &mut camera.m[i],
            &mut camera.v[i],
            lr,
            bias,
        );
    }
    camera.exposure = Exposure::from_values(values);

    let trained = exposures.cameras.iter().filter(|c| c.trained);
    let count = trained.clone().count().max(1) as f32;
    let mean: [f32; 6] = trained.fold([0.0; 6], |sum, c| {
        let v = c.exposure.values();
        std::array::from_fn(|i| sum[i] + v[i] / count)
    });
    for camera in exposures.cameras.iter_mut().filter(|c| c.trained) {
        let v = camera.exposure.values();
        camera.exposure = Exposure::from_values(std::array::from_fn(|i| v[i] - mean[i]));
    }
}

/// The Adam systems of every parameter group ([`crate::components::param_groups!`]).
pub fn adam_systems() -> ScheduleConfigs<ScheduleSystem> {
    macro_rules! adam_steps {
        ($($group:ty,)*) => {
            ($(adam_step::<$group>,)*).into_configs()
        };
    }
    each_param!(adam_steps)
}
