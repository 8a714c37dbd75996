//! Temporal Offset Warping: Δt' = W(t − t_i) for every Gaussian.

use bevy_ecs::prelude::*;

use crate::components::{Temporal, WarpedTime};
use crate::resources::{Settings, ViewSample};

/// Writes each Gaussian's raw and warped temporal offset at the sampled time.
pub fn time_warp(
    settings: Res<Settings>,
    sample: Res<ViewSample>,
    mut gaussians: Query<(&Temporal, &mut WarpedTime)>,
) {
    let warp = settings.warp;
    let t = sample.time;
    gaussians
        .contiguous_par_iter_mut()
        .expect("Temporal and WarpedTime are stored in tables, so the query is dense")
        .for_each(|(temporal, mut warped)| {
            for (temporal, warped) in temporal.iter().zip(warped.iter_mut()) {
                let dt = t - temporal.center;
                *warped = WarpedTime {
                    dt,
                    dtw: warp.apply(temporal.center, dt),
                };
            }
        });
}
