//! The numeric guard: after the backward stage, every gradient must be finite. The first
//! non-finite value stops the iteration before Adam can write it into a parameter; the
//! [`NumericFault`] names the parameter group, the Gaussian and the iteration, and the
//! optimiser and densification stages do not run while it is set.

use bevy_ecs::prelude::*;

use crate::components::*;
use crate::resources::{NumericFault, TrainState};

/// Index of the first Gaussian whose gradient of group `P` is not finite.
fn first_nonfinite<P: Param>(grads: &Query<&Grad<P>>) -> Option<usize> {
    grads
        .iter()
        .position(|g| !g.0.values().iter().all(|v| v.is_finite()))
}

/// Records a [`NumericFault`] when the loss or any gradient is NaN or infinite.
#[allow(clippy::too_many_arguments)]
pub fn check_gradients(
    state: Res<TrainState>,
    mut fault: ResMut<NumericFault>,
    position: Query<&Grad<Position>>,
    fourier: Query<&Grad<Fourier>>,
    temporal: Query<&Grad<Temporal>>,
    opacity: Query<&Grad<Opacity>>,
    rotation: Query<&Grad<Rotation>>,
    scale: Query<&Grad<Scale>>,
    color: Query<&Grad<Color>>,
    color_rest: Query<&Grad<ColorRest>>,
) {
    if fault.0.is_some() {
        return;
    }
    let found = if !state.loss.total.is_finite() {
        Some(("loss", None))
    } else {
        [
            (Position::NAME, first_nonfinite(&position)),
            (Fourier::NAME, first_nonfinite(&fourier)),
            (Temporal::NAME, first_nonfinite(&temporal)),
            (Opacity::NAME, first_nonfinite(&opacity)),
            (Rotation::NAME, first_nonfinite(&rotation)),
            (Scale::NAME, first_nonfinite(&scale)),
            (Color::NAME, first_nonfinite(&color)),
            (ColorRest::NAME, first_nonfinite(&color_rest)),
        ]
        .into_iter()
        .find_map(|(group, index)| index.map(|i| (group, Some(i))))
    };
    if let Some((group, gaussian)) = found {
        fault.0 = Some(crate::resources::Fault {
            iteration: state.iteration,
            group,
            gaussian,
        });
    }
}

/// Run condition: no numeric fault has been recorded.
pub fn healthy(fault: Res<NumericFault>) -> bool {
    fault.0.is_none()
}
