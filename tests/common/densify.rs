//! Shared by the tests that make densification clone and split on a freshly spawned world.

use bevy_ecs::prelude::*;
use bevy_ecs::schedule::IntoScheduleConfigs;
use bevy_ecs::system::ScheduleSystem;
use tadgs::components::Scale;
use tadgs::resources::Settings;
use tadgs::scene::DensifyConfig;
use tadgs::systems::{TrainSet, training_schedule};

/// The iteration of the first densification step that [`densify_everything_every_ten`] sets.
pub const FIRST_DENSIFICATION: u32 = 10;

/// Densification from iteration 0 every [`FIRST_DENSIFICATION`] iterations, with every
/// Gaussian seen over the gradient threshold and TAT off (its threshold would hold some back).
pub fn densify_everything_every_ten(densify: &mut DensifyConfig) {
    densify.from_iter = 0;
    densify.interval = FIRST_DENSIFICATION;
    densify.grad_threshold = 1e-9;
    densify.tat = false;
}

/// Runs the training schedule up to and including its first densification step, with
/// `snapshot` between Adam and densification (where a test records the state densification
/// starts from).
pub fn run_to_first_densification<M>(
    world: &mut World,
    snapshot: impl IntoScheduleConfigs<ScheduleSystem, M>,
) {
    let mut schedule = training_schedule();
    schedule.add_systems(snapshot.after(TrainSet::Adam).before(TrainSet::Densify));
    for _ in 0..FIRST_DENSIFICATION {
        schedule.run(world);
    }
}

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
