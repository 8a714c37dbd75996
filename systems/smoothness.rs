//! The motion-smoothness regulariser (`train.motion_smoothness`, CPU backend): after the
//! photometric backward pass, adds dL_s/d(motion) to every Gaussian's Fourier gradient, where
//! L_s penalises neighbours whose velocities differ ([`crate::model::smoothness`]).

use bevy_ecs::prelude::*;
use glam::Vec3;

use crate::components::{Deformed, Fourier, Grad, Param, WarpedTime};
use crate::model::deform::{fourier_velocity, fourier_velocity_backward};
use crate::model::smoothness::{NeighbourGraph, Penalty, smoothness_backward, smoothness_loss};
use crate::resources::{Settings, TrainState};
use crate::scene::SmoothnessForm;

/// The neighbour graph and the per-iteration buffers, kept between iterations. The graph's
/// indices are the order in which [`motion_smoothness`]'s query visits the Gaussians, which
/// holds until the population changes.
#[derive(Default)]
pub struct SmoothnessBuffers {
    graph: NeighbourGraph,
    /// Iteration at which `graph` was built (`None`: never).
    built_at: Option<u32>,
    /// Positions at the sampled time: gathered when the graph is rebuilt, and every iteration
    /// for the stretch form, whose edge directions they give.
    positions: Vec<Vec3>,
    velocities: Vec<Vec3>,
    d_velocities: Vec<Vec3>,
}

/// Whether the regulariser has a weight.
pub fn smoothness_enabled(settings: &Settings) -> bool {
    settings.train.motion_smoothness.weight > 0.0
}

/// Run condition: [`smoothness_enabled`].
pub fn smoothing(settings: Res<Settings>) -> bool {
    smoothness_enabled(&settings)
}

/// Adds the regulariser's gradient to each [`Grad<Fourier>`], rebuilding the k-nearest graph
/// (over the positions at the sampled time) every `rebuild_interval` iterations and after
/// every densification step.
pub fn motion_smoothness(
    settings: Res<Settings>,
    state: Res<TrainState>,
    mut gaussians: Query<(&Fourier, &WarpedTime, &Deformed, &mut Grad<Fourier>)>,
    mut buffers: Local<SmoothnessBuffers>,
) {
    let config = &settings.train.motion_smoothness;
    let motion = settings.motion_basis();
    let buffers = &mut *buffers;
    let iteration = state.iteration;
    // Velocities in the query's order.
    buffers.velocities.clear();
    for (fourier, warped, _, _) in gaussians.iter() {
        buffers.velocities.push(fourier_velocity(
            &fourier.cos,
            &fourier.sin,
            &fourier.phase,
            motion,
            warped.dtw,
        ));
    }
    let stale = match buffers.built_at {
        None => true,
        Some(built) => {
            iteration >= built + config.rebuild_interval
                // Densification after this graph was built (in the same iteration or later).
                || state.last_densify.iteration >= built
                || buffers.graph.len() != buffers.velocities.len()
        }
    };
    let stretch = config.form == SmoothnessForm::Stretch;
    if stale || stretch {
        buffers.positions.clear();
        buffers.positions.extend(
            gaussians
                .iter()
                .map(|(_, _, d, _)| Vec3::from_array(d.mean)),
        );
    }
    let penalty = if stretch {
        Penalty::Stretch(&buffers.positions)
    } else {
        Penalty::Velocity
    };
    if stale {
        buffers.graph = NeighbourGraph::k_nearest(&buffers.positions, config.neighbours as usize);
        buffers.built_at = Some(iteration);
        tracing::debug!(
            iteration,
            edges = buffers.graph.edge_count(),
            loss = smoothness_loss(&buffers.velocities, &buffers.graph, config.weight, penalty),
            "motion-smoothness graph rebuilt"
        );
    }
    smoothness_backward(
        &buffers.velocities,
        &buffers.graph,
        config.weight,
        penalty,
        &mut buffers.d_velocities,
    );
    for ((fourier, warped, _, mut grad), &d) in gaussians.iter_mut().zip(&buffers.d_velocities) {
        if d == Vec3::ZERO {
            continue;
        }
        let g = fourier_velocity_backward(
            &fourier.cos,
            &fourier.sin,
            &fourier.phase,
            motion,
            warped.dtw,
            d,
        );
        let added = Fourier {
            cos: g.cos,
            sin: g.sin,
            phase: g.phase,
        };
        for (value, add) in grad.0.values_mut().iter_mut().zip(added.values()) {
            *value += add;
        }
    }
}
