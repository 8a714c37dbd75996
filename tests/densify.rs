//! Where densification puts a clone in time (`densify.clone_time`).

mod tiny;

use bevy_ecs::system::RunSystemOnce;
use bevy_ecs::world::World;
use tadgs::components::{Color, GradAccum, Scale, Temporal};
use tadgs::scene::CloneTime;
use tadgs::systems::densify::{densify_and_prune, gradient_time};
use tadgs::train::{insert_resources, spawn_initial_gaussians};

/// The temporal centres after one densification step in which every Gaussian qualifies and
/// is small enough to clone, with gradients from 0.3 after its centre (Gaussians marked by
/// their DC colour): `(mark, centre)` of every Gaussian, sorted.
fn centres_after_one_step(clone_time: CloneTime) -> (Vec<(usize, f32)>, Vec<f32>) {
    let (mut config, dataset) = tiny::tiny_demo(32, 24, 60);
    config.densify.tat = false;
    config.densify.clone_time = clone_time;
    let threshold = config.densify.grad_threshold;
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset).expect("CPU backend");
    spawn_initial_gaussians(&mut world, &config).expect("random points initialise");
    let mut parents = Vec::new();
    let mut query = world.query::<(&mut Color, &mut Scale, &Temporal, &mut GradAccum)>();
    for (i, (mut color, mut scale, temporal, mut accum)) in query.iter_mut(&mut world).enumerate() {
        color.dc = [i as f32, 0.0, 0.0];
        scale.d0 = [-12.0; 3]; // far below percent_dense: every one clones
        // Two views: g 3τ at Δt = +0.4 and g τ at Δt = 0 (weights σ 1): t_g = t_i + 0.3.
        *accum = GradAccum {
            weighted_grad: 4.0 * threshold,
            weight: 2.0,
            lifespan_sum: 2.0,
            count: 2,
            max_radius: 1.0,
            weighted_offset: 3.0 * threshold * 0.4,
        };
        parents.push(gradient_time(&accum, temporal.center));
    }
    world
        .run_system_once(densify_and_prune)
        .expect("densification runs");
    let mut centres: Vec<(usize, f32)> = world
        .query::<(&Color, &Temporal)>()
        .iter(&world)
        .map(|(color, temporal)| (color.dc[0] as usize, temporal.center))
        .collect();
    centres.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.total_cmp(&b.1)));
    (centres, parents)
}

/// With `Parent` (the paper) a clone keeps its parent's centre; with `Gradient` the parent
/// keeps its centre and the clone is centred where the gradient came from (t_i + 0.3,
/// clamped to the sequence).
#[test]
fn clones_are_centred_where_their_gradient_came_from() {
    let (paper, _) = centres_after_one_step(CloneTime::Parent);
    for pair in paper.chunks(2) {
        assert_eq!(pair[0], pair[1], "a clone and its parent");
    }
    let (moved, gradient_times) = centres_after_one_step(CloneTime::Gradient);
    assert_eq!(moved.len(), paper.len());
    for (pair, original) in moved.chunks(2).zip(paper.chunks(2)) {
        let mark = pair[0].0;
        let parent = original[0].1;
        let expected = (parent + 0.3).min(1.0);
        assert!((gradient_times[mark] - expected).abs() < 1e-6);
        let mut found = [pair[0].1, pair[1].1];
        found.sort_by(f32::total_cmp);
        let mut want = [parent, expected];
        want.sort_by(f32::total_cmp);
        assert!(
            (found[0] - want[0]).abs() < 1e-6 && (found[1] - want[1]).abs() < 1e-6,
            "Gaussian {mark}: centres {found:?}, expected {want:?}"
        );
    }
}
