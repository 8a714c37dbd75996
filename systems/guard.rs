//! The numeric guard: after the backward stage, every gradient must be finite. The first
//! non-finite value stops the iteration before Adam can write it into a parameter; the
//! [`NumericFault`] names the parameter group, the Gaussian and the iteration, and the
//! optimiser and densification stages do not run while it is set.

use bevy_ecs::prelude::*;

use bevy_ecs::schedule::ScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;

use crate::components::{Grad, Param, each_param};
use crate::resources::{Fault, NumericFault, TrainState};

/// Records a [`NumericFault`] when the loss is NaN or infinite.
pub fn check_loss(state: Res<TrainState>, mut fault: ResMut<NumericFault>) {
    if fault.0.is_none() && !state.loss.total.is_finite() {
        fault.0 = Some(Fault {
            iteration: state.iteration,
            group: "loss",
            gaussian: None,
        });
    }
}

/// Records a [`NumericFault`] naming the first Gaussian whose gradient of group `P` is NaN or
/// infinite, unless a fault is already recorded.
pub fn check_gradient<P: Param>(
    state: Res<TrainState>,
    mut fault: ResMut<NumericFault>,
    grads: Query<&Grad<P>>,
) {
    if fault.0.is_some() {
        return;
    }
    let first = grads
        .iter()
        .position(|g| !g.0.values().iter().all(|v| v.is_finite()));
    if let Some(gaussian) = first {
        fault.0 = Some(Fault {
            iteration: state.iteration,
            group: P::NAME,
            gaussian: Some(gaussian),
        });
    }
}

/// The systems of the guard, for ordering your own systems before or after it.
#[derive(SystemSet, Debug, Clone, PartialEq, Eq, Hash)]
pub struct GradientGuard;

/// The guard, in [`GradientGuard`]: [`check_loss`], then [`check_gradient`] of every parameter
/// group in declaration order ([`crate::components::param_groups!`]), so the fault names the
/// first bad group.
pub fn check_gradients() -> ScheduleConfigs<ScheduleSystem> {
    macro_rules! checks {
        ($($group:ty,)*) => {
            (check_loss, $(check_gradient::<$group>,)*).chain().in_set(GradientGuard)
        };
    }
    each_param!(checks)
}

/// Run condition: no numeric fault has been recorded.
pub fn healthy(fault: Res<NumericFault>) -> bool {
    fault.0.is_none()
}
