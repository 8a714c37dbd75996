//! Shared by the tests that make densification clone and split on a freshly spawned world.

use bevy_ecs::prelude::*;
use tadgs::components::Scale;
use tadgs::resources::Settings;

/// Sets `densify.percent_dense` so that the median initial scale is the clone/split boundary:
/// the smaller half of the Gaussians clone and the larger half split.
pub fn split_at_median_scale(world: &mut World) {
    let mut scales: Vec<f32> = world
        .query::<&Scale>()
        .iter(world)
        .map(|s| s.d0[0].exp())
        .collect();
    scales.sort_by(f32::total_cmp);
    let mut settings = world.resource_mut::<Settings>();
    settings.densify.percent_dense = scales[scales.len() / 2] / settings.extent;
}
