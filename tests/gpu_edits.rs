//! User systems that edit components on the GPU-resident backend (`GpuTraining`), where the
//! parameters and gradients live on the GPU between syncs: every edit is either honoured or
//! refused with an error that names the fix, never lost silently.
//!
//! - With `HostGradients`, a system between Backward and Adam that zeroes some Gaussians'
//!   position gradients keeps them exactly in place while the others move.
//! - Without it, the same system makes the iteration fail with an error naming `HostGradients`.
//! - A system after Adam that writes a parameter fails with an error naming `resident_sync`;
//!   with `resident_sync` run right before it, the value it writes is the one trained on.
//!
//! Checked by hand to fail: `resident_gradients_in` not uploading the edited gradients (the
//! frozen Gaussians move), and the edit checks comparing against the wrong tick (no error).

#[path = "common/demo.rs"]
mod demo;
#[path = "common/gpu.rs"]
mod gpu;

use std::panic::{AssertUnwindSafe, catch_unwind};

use bevy_ecs::prelude::*;
use tadgs::components::*;
use tadgs::gpu::{GpuContext, GpuTraining};
use tadgs::systems::resident::{HostGradients, resident_sync, sync_world};
use tadgs::systems::{TrainSet, training_schedule};
use tadgs::train::{insert_resources, spawn_initial_gaussians};

/// Marks the Gaussians the test systems act on: every fourth one.
#[derive(Component)]
struct Tagged;

/// A world of the demo scene at 64×48 over 4 frames (2 anchors × 300 random points, no
/// densification) training on the GPU-resident pipeline of `gpu`, every fourth Gaussian tagged.
fn gpu_world(gpu: &GpuContext) -> World {
    let (mut config, dataset) = demo::small_demo("edits", 4, 64, 48, 300);
    config.densify.from_iter = 100_000;
    config.densify.opacity_reset_interval = 0;
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset).expect("resources");
    world.insert_resource(GpuTraining::with_context(gpu.clone()));
    spawn_initial_gaussians(&mut world, &config).expect("random points initialise");
    let entities: Vec<Entity> = world.query::<Entity>().iter(&world).collect();
    for entity in entities.into_iter().step_by(4) {
        world.entity_mut(entity).insert(Tagged);
    }
    world
}

fn zero_position_gradients(mut tagged: Query<&mut Grad<Position>, With<Tagged>>) {
    for mut grad in &mut tagged {
        *grad = Grad::default();
    }
}

const OPACITY: f32 = -1.5;

fn set_opacity(mut tagged: Query<&mut Opacity, With<Tagged>>) {
    for mut opacity in &mut tagged {
        opacity.logit = OPACITY;
    }
}

/// Runs `iterations` of `schedule`; the panic message of the first failing system, if any.
fn run(schedule: &mut Schedule, world: &mut World, iterations: usize) -> Option<String> {
    let outcome = catch_unwind(AssertUnwindSafe(|| {
        for _ in 0..iterations {
            schedule.run(world);
        }
    }));
    outcome.err().map(|payload| {
        payload
            .downcast_ref::<String>()
            .cloned()
            .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
            .unwrap_or_default()
    })
}

fn positions(world: &mut World) -> Vec<(bool, [f32; 3])> {
    world
        .query::<(Has<Tagged>, &Position)>()
        .iter(world)
        .map(|(tagged, p)| (tagged, p.mean))
        .collect()
}

#[test]
fn gradient_edits_are_honoured_with_host_gradients_and_refused_without() {
    let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(false)) else {
        return;
    };
    let mut world = gpu_world(&ctx);
    world.insert_resource(HostGradients);
    let before = positions(&mut world);
    let mut schedule = training_schedule();
    schedule.add_systems(
        zero_position_gradients
            .after(TrainSet::Backward)
            .before(TrainSet::Adam),
    );
    assert_eq!(run(&mut schedule, &mut world, 10), None);
    sync_world(&mut world).expect("sync");
    let after = positions(&mut world);
    let (mut tagged, mut free, mut free_moved) = (0, 0, 0);
    for ((is_tagged, p0), (_, p1)) in before.iter().zip(&after) {
        if *is_tagged {
            tagged += 1;
            assert_eq!(
                p0, p1,
                "a Gaussian whose position gradient was zeroed moved"
            );
        } else {
            free += 1;
            free_moved += (p0 != p1) as usize;
        }
    }
    assert!(tagged > 100, "{tagged} tagged");
    assert!(free_moved * 10 > free * 9, "{free_moved} of {free} moved");

    world.remove_resource::<HostGradients>();
    let message = run(&mut schedule, &mut world, 2).expect("the edit is refused");
    assert!(
        message.contains("Grad<position>") && message.contains("HostGradients"),
        "{message}"
    );
}

#[test]
fn parameter_edits_need_a_sync_first() {
    let Some(ctx) = gpu::open_or_skip(|| GpuContext::new(false)) else {
        return;
    };
    let mut world = gpu_world(&ctx);
    let mut schedule = training_schedule();
    schedule.add_systems(set_opacity.after(TrainSet::Adam));
    let message = run(&mut schedule, &mut world, 3).expect("the edit is refused");
    assert!(
        message.contains("opacity") && message.contains("resident_sync"),
        "{message}"
    );

    let mut world = gpu_world(&ctx);
    let mut schedule = training_schedule();
    schedule.add_systems((resident_sync, set_opacity).chain().after(TrainSet::Adam));
    assert_eq!(run(&mut schedule, &mut world, 5), None);
    sync_world(&mut world).expect("sync");
    let opacities: Vec<(bool, f32)> = world
        .query::<(Has<Tagged>, &Opacity)>()
        .iter(&world)
        .map(|(tagged, o)| (tagged, o.logit))
        .collect();
    assert!(
        opacities
            .iter()
            .filter(|(t, _)| *t)
            .all(|(_, o)| *o == OPACITY),
        "the written opacity is kept"
    );
    assert!(
        opacities
            .iter()
            .filter(|(t, _)| !*t)
            .any(|(_, o)| *o != OPACITY),
        "the others train"
    );
}
