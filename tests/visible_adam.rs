//! `train.visible_adam`: Adam steps only the Gaussians that received a gradient this iteration.
//! A Gaussian seen at one iteration and unseen at the next keeps its parameters and moments
//! bit for bit with the option, moves on its momentum without it, and every seen Gaussian
//! steps exactly as with dense Adam.

use bevy_ecs::prelude::*;
use tadgs::bench::benchmark_world;
use tadgs::components::{Adam, Grad, Position, SplatSlot};
use tadgs::resources::{DeformedGrad, Settings, SplatBuffers};
use tadgs::systems::{adam, training_schedule};

/// Per Gaussian, in query order: position, its Adam moments and whether it got a gradient.
type Snapshot = Vec<(Position, Adam<Position>, bool)>;

fn snapshot(world: &mut World) -> Snapshot {
    let reached = world.resource::<SplatBuffers>().gradient_reached.clone();
    world
        .query::<(&Position, &Adam<Position>, &SplatSlot)>()
        .iter(world)
        .map(|(p, a, slot)| (*p, *a, reached[slot.0 as usize]))
        .collect()
}

/// One dense training iteration (every Gaussian in view gets moments), then every other seen
/// Gaussian is made unseen for a second, Adam-only step (its deformed gradient and its
/// position gradient zeroed, as the backward pass leaves a Gaussian nothing reaches).
fn world_after_two_steps(visible_adam: bool) -> (Snapshot, Snapshot) {
    let mut world = benchmark_world(3000, 96, 54, true);
    training_schedule().run(&mut world);
    let mut hide = Vec::new();
    {
        let buffers = &mut *world.resource_mut::<SplatBuffers>();
        let mut seen = 0;
        for (slot, d) in buffers.deformed_grads.iter_mut().enumerate() {
            assert_eq!(
                buffers.gradient_reached[slot],
                *d != DeformedGrad::default()
            );
            if buffers.gradient_reached[slot] {
                seen += 1;
                if seen % 2 == 0 {
                    *d = DeformedGrad::default();
                    buffers.gradient_reached[slot] = false;
                    hide.push(slot as u32);
                }
            }
        }
    }
    assert!(hide.len() > 100, "too few seen Gaussians: {}", hide.len());
    for (slot, mut grad) in world
        .query::<(&SplatSlot, &mut Grad<Position>)>()
        .iter_mut(&mut world)
    {
        if hide.binary_search(&slot.0).is_ok() {
            grad.0 = Position::default();
        }
    }
    world.resource_mut::<Settings>().train.visible_adam = visible_adam;
    let before = snapshot(&mut world);
    let mut adam_only = Schedule::default();
    adam_only.add_systems(adam::adam_systems());
    adam_only.run(&mut world);
    (before, snapshot(&mut world))
}

#[test]
fn visible_adam_freezes_unseen_gaussians_and_steps_seen_ones_as_dense_adam() {
    let (before, visible) = world_after_two_steps(true);
    let (_, dense) = world_after_two_steps(false);
    let (mut frozen, mut drifted, mut stepped) = (0, 0, 0);
    for ((b, v), d) in before.iter().zip(&visible).zip(&dense) {
        if b.2 {
            // Seen: the same step with or without the option.
            assert_eq!((v.0, v.1), (d.0, d.1));
            stepped += 1;
        } else {
            // Unseen: untouched with the option.
            assert_eq!((v.0, v.1), (b.0, b.1));
            frozen += 1;
            // Without it, a Gaussian with momentum moves on it (the test can tell them apart).
            if b.1.m != Position::default() {
                assert_ne!(d.0, b.0);
                drifted += 1;
            }
        }
    }
    assert!(
        stepped > 100 && frozen > 100 && drifted > 100,
        "{stepped} {frozen} {drifted}"
    );
}
