//! `train.fused_adam`: the Gaussians carry no gradient components, and the chain rule, the
//! numeric guard and Adam run in one pass. It trains the same model bit for bit as the
//! unfused stages (dense, visible and deferred Adam, through densification, an opacity reset
//! and the rise of the SH degree), and a NaN gradient is caught and named as the guard names
//! it.

#[path = "common/rows.rs"]
mod rows;
mod tiny;

use bevy_ecs::prelude::*;
use rows::in_entity_order;
use tadgs::components::*;
use tadgs::resources::{NumericFault, SplatBuffers, TrainState};
use tadgs::systems::backward::{backward_parameters, backward_splats};
use tadgs::systems::training_schedule;
use tadgs::train::{Trainer, insert_resources, spawn_initial_gaussians};

/// Every parameter group's values and Adam moments, in entity order, as bytes.
fn optimised_state(world: &mut World) -> Vec<(&'static str, Vec<u8>)> {
    let mut groups = Vec::new();
    macro_rules! read {
        ($($group:ty,)*) => {
            $(
                let values = in_entity_order::<$group>(world);
                let moments = in_entity_order::<Adam<$group>>(world);
                groups.push((<$group as Param>::NAME, bytemuck::cast_slice(&values).to_vec()));
                groups.push(("moments", bytemuck::cast_slice(&moments).to_vec()));
            )*
        };
    }
    read!(
        Position, Fourier, Temporal, Opacity, Rotation, Scale, Color, ColorRest,
    );
    groups
}

/// How many Gaussians hold a gradient component of any group.
fn with_gradients(world: &mut World) -> usize {
    let mut count = 0;
    macro_rules! count {
        ($($group:ty,)*) => {
            $(count += world.query::<&Grad<$group>>().iter(world).count();)*
        };
    }
    count!(
        Position, Fourier, Temporal, Opacity, Rotation, Scale, Color, ColorRest,
    );
    count
}

/// Property: with dense, visible and deferred Adam, 36 iterations with `train.fused_adam` end
/// with the same parameters and Adam moments, bit for bit, as without it, through two
/// densification steps (clones and splits get fresh moments and no gradient components), an
/// opacity reset and SH degrees 0 to 3; the fused Gaussians never hold a gradient component.
#[test]
fn fused_adam_trains_the_same_model_bit_for_bit() {
    let (config, dataset) = tiny::tiny_densifying_demo();
    for mode in ["dense", "visible", "deferred"] {
        let mut config = config.clone();
        config.train.visible_adam = mode == "visible";
        config.train.deferred_adam = mode == "deferred";
        let mut unfused = Trainer::new(&config, dataset.clone());
        config.train.fused_adam = true;
        let mut fused = Trainer::new(&config, dataset.clone());
        let initial = fused.gaussian_count();
        for _ in 0..config.train.iterations {
            unfused.step();
            fused.step();
            assert_eq!(with_gradients(&mut fused.world), 0, "{mode}");
        }
        assert_eq!(fused.fault(), None);
        assert_eq!(fused.state().sh_degree, 3);
        assert!(
            fused.gaussian_count() > initial,
            "{mode}: densification should have added Gaussians ({initial} at the start)"
        );
        assert!(with_gradients(&mut unfused.world) > 0);
        assert_eq!(fused.gaussian_count(), unfused.gaussian_count(), "{mode}");
        let (a, b) = (
            optimised_state(&mut unfused.world),
            optimised_state(&mut fused.world),
        );
        for ((name, a), (_, b)) in a.iter().zip(&b) {
            assert!(a == b, "{mode}: {name} differs");
        }
    }
}

/// Property: training on from a merged segment model, whose Gaussians carry a
/// [`TimeWindow`] (half of them fading out mid-sequence), gives the same parameters and
/// moments bit for bit with and without fused Adam: the window scales dL/dσ alike in both.
#[test]
fn fused_adam_matches_on_a_model_with_time_windows() {
    let (config, dataset) = tiny::tiny_densifying_demo();
    let mut model = Trainer::new(&config, dataset.clone()).model();
    let windows = (0..model.gaussians.len())
        .map(|i| TimeWindow {
            start: 0.0,
            end: if i % 2 == 0 { 0.5 } else { 1.0 },
            fade: 0.2,
        })
        .collect();
    model.time_windows = Some(windows);
    let mut trained = Vec::new();
    for fused in [false, true] {
        let mut config = config.clone();
        config.train.fused_adam = fused;
        let mut trainer = Trainer::from_model(&config, dataset.clone(), &model);
        for _ in 0..12 {
            trainer.step();
        }
        assert_eq!(trainer.fault(), None);
        assert_eq!(
            trainer
                .world
                .query::<&TimeWindow>()
                .iter(&trainer.world)
                .count(),
            trainer.gaussian_count()
        );
        trained.push(optimised_state(&mut trainer.world));
    }
    for ((name, a), (_, b)) in trained[0].iter().zip(&trained[1]) {
        assert!(a == b, "{name} differs");
    }
}

/// Makes slot 7's deformed scale gradient NaN at iteration 6, before the chain rule through
/// the deformation (as a numerical fault in the raster backward would).
fn poison_at_iteration_6(state: Res<TrainState>, mut buffers: ResMut<SplatBuffers>) {
    if state.iteration == 6 {
        buffers.deformed_grads[7].scale[1] = f32::NAN;
    }
}

/// The Gaussian drawn into slot 7 and its parameters.
fn slot_7(world: &mut World) -> (Entity, Position, Scale, Rotation, Opacity, Color) {
    world
        .query::<(
            Entity,
            &SplatSlot,
            &Position,
            &Scale,
            &Rotation,
            &Opacity,
            &Color,
        )>()
        .iter(world)
        .find(|row| row.1.0 == 7)
        .map(|(e, _, p, s, r, o, c)| (e, *p, *s, *r, *o, *c))
        .expect("a Gaussian in slot 7")
}

/// A NaN reaching the fused pass at iteration 6 is recorded as the unfused guard records it
/// (same iteration, group and Gaussian); the Gaussian that holds it keeps the parameters it
/// had after iteration 5, and no later iteration steps any Gaussian.
#[test]
fn a_nan_gradient_stops_fused_adam_as_it_stops_the_guard() {
    let (config, dataset) = tiny::tiny_densifying_demo();
    let mut faults = Vec::new();
    for fused in [false, true] {
        let mut config = config.clone();
        config.train.fused_adam = fused;
        let mut world = World::new();
        insert_resources(&mut world, &config, dataset.clone()).expect("CPU backend");
        spawn_initial_gaussians(&mut world, &config).unwrap();
        let mut schedule = training_schedule();
        schedule.add_systems(
            poison_at_iteration_6
                .after(backward_splats)
                .before(backward_parameters),
        );
        for _ in 0..5 {
            schedule.run(&mut world);
        }
        let before = slot_7(&mut world);
        schedule.run(&mut world);
        let after_fault = optimised_state(&mut world);
        assert_eq!(slot_7(&mut world), before, "fused: {fused}");
        schedule.run(&mut world);
        assert!(
            optimised_state(&mut world) == after_fault,
            "fused: {fused}: nothing steps after the fault"
        );
        faults.push(
            world
                .resource::<NumericFault>()
                .0
                .expect("the NaN is caught"),
        );
    }
    assert_eq!(faults[0], faults[1]);
    assert_eq!((faults[1].iteration, faults[1].group), (6, "scale"));
}
