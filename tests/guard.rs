//! The numeric guard: a NaN stops the optimisation at the iteration it appears, names where it
//! is, and leaves every parameter as it was before that iteration.

mod tiny;

use bevy_ecs::prelude::*;
use tadgs::components::*;
use tadgs::resources::{Fault, NumericFault, TrainState};
use tadgs::systems::backward::backward_parameters;
use tadgs::systems::guard::{GradientGuard, check_gradients};
use tadgs::systems::training_schedule;
use tadgs::train::{insert_resources, spawn_initial_gaussians};

fn parameters(world: &mut World) -> Vec<(Position, Rotation, Scale, Opacity, Color)> {
    world
        .query::<(&Position, &Rotation, &Scale, &Opacity, &Color)>()
        .iter(world)
        .map(|(p, r, s, o, c)| (*p, *r, *s, *o, *c))
        .collect()
}

/// Makes one rotation gradient NaN at iteration 6, between the backward pass and the guard
/// (as a numerical fault in the backward maths would).
fn poison_at_iteration_6(state: Res<TrainState>, mut grads: Query<&mut Grad<Rotation>>) {
    if state.iteration == 6
        && let Some(mut grad) = grads.iter_mut().nth(7)
    {
        grad.0.c0[2] = f32::NAN;
    }
}

/// A NaN gradient at iteration 6 is caught at iteration 6 and named (rotation group,
/// Gaussian #7); the Gaussian count and every parameter stay as they were after iteration 5,
/// and later steps keep them so.
#[test]
fn nan_stops_the_optimisation_and_keeps_the_last_good_parameters() {
    let (config, dataset) = tiny::tiny_demo(48, 36, 200);
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset).expect("CPU backend");
    spawn_initial_gaussians(&mut world, &config).unwrap();
    let mut schedule = training_schedule();
    schedule.add_systems(
        poison_at_iteration_6
            .after(backward_parameters)
            .before(GradientGuard),
    );
    for _ in 0..5 {
        schedule.run(&mut world);
    }
    assert_eq!(world.resource::<NumericFault>().0, None);
    let before = parameters(&mut world);
    for _ in 0..3 {
        schedule.run(&mut world);
    }
    let fault = world
        .resource::<NumericFault>()
        .0
        .expect("the NaN is caught");
    assert_eq!(
        (fault.iteration, fault.group, fault.gaussian),
        (6, "rotation", Some(7))
    );
    assert_eq!(world.resource::<TrainState>().iteration, 8);
    assert_eq!(
        before,
        parameters(&mut world),
        "no parameter changed after the fault"
    );
}

/// An infinite scale gradient on the third Gaussian is reported as the scale group, Gaussian
/// #2, at the current iteration; finite gradients report nothing.
#[test]
fn the_fault_names_the_group_and_the_gaussian() {
    let mut world = World::new();
    world.insert_resource(NumericFault::default());
    world.insert_resource(TrainState {
        iteration: 42,
        ..Default::default()
    });
    for _ in 0..4 {
        world.spawn(GaussianParams::default().bundle());
    }
    let mut schedule = Schedule::default();
    schedule.add_systems(check_gradients());
    schedule.run(&mut world);
    assert_eq!(world.resource::<NumericFault>().0, None);

    for (i, mut grad) in world
        .query::<&mut Grad<Scale>>()
        .iter_mut(&mut world)
        .enumerate()
    {
        if i == 2 {
            grad.0.d0[1] = f32::INFINITY;
        }
    }
    schedule.run(&mut world);
    let fault: Fault = world.resource::<NumericFault>().0.expect("found");
    assert_eq!(
        (fault.iteration, fault.group, fault.gaussian),
        (42, "scale", Some(2))
    );
    assert_eq!(
        fault.to_string(),
        "iteration 42: non-finite gradient of the scale parameters (Gaussian #2)"
    );
}

/// Divergence the guard cannot see (finite but absurd values): a trained tiny scene has no
/// runaway Gaussian; one moved 10⁴ scene extents away, or to NaN, is counted.
#[test]
fn runaway_gaussians_are_counted() {
    let mut synthetic = tadgs::data::synthetic::demo_scene();
    (synthetic.frames, synthetic.width, synthetic.height) = (4, 32, 24);
    let dataset = std::sync::Arc::new(synthetic.build().unwrap());
    let mut scene =
        tadgs::scene::SceneConfig::new("runaway", tadgs::scene::DataSource::Synthetic(synthetic));
    scene.init.points_per_anchor = 100;
    let mut trainer = tadgs::train::Trainer::new(&scene, dataset);
    for _ in 0..5 {
        trainer.step();
    }
    assert_eq!(trainer.diverged_count(), 0);
    let extent = trainer
        .world
        .resource::<tadgs::resources::Settings>()
        .extent;
    let mut positions = trainer.world.query::<&mut Position>();
    let mut all: Vec<_> = positions.iter_mut(&mut trainer.world).collect();
    all[0].mean = [1e4 * extent, 0.0, 0.0];
    all[1].mean = [f32::NAN, 0.0, 0.0];
    drop(all);
    assert_eq!(trainer.diverged_count(), 2);
}
