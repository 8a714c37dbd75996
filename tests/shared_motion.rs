//! `model.shared_motion`: motion bases shared by every Gaussian. Training with them moves the
//! bases off zero with a finite loss; densification hands a parent's weights to its clones and
//! split children; the bases' gradient is the same whatever the thread count and equals the
//! direct sum; a saved model renders as the trained one; and without the setting nothing of
//! it is in the world.

#[path = "common/demo.rs"]
mod demo;
#[path = "common/densify.rs"]
mod densify;

use std::collections::HashMap;
use std::sync::Arc;

use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;
use densify::{densify_everything_every_ten, run_to_first_densification, split_at_median_scale};
use glam::Vec3;
use tadgs::components::*;
use tadgs::data::{Camera, Dataset};
use tadgs::io::model::Model;
use tadgs::model::shared_motion::{KnotSpan, MAX_MOTION_BASES, MotionBases};
use tadgs::resources::{SharedMotion, TrainState, ViewSample};
use tadgs::scene::{SceneConfig, SharedMotionConfig};
use tadgs::systems::backward::backward_shared_motion;
use tadgs::train::{Trainer, attach_motion_weights_now, insert_resources, spawn_initial_gaussians};

const BASES: usize = 4;
const KNOTS: usize = 5;

/// A 6-frame, 48×36 demo scene, with shared motion bases when `shared`.
fn tiny_scene(shared: bool) -> (SceneConfig, Arc<Dataset>) {
    let (mut config, dataset) = demo::small_demo("shared", 6, 48, 36, 300);
    config.train.iterations = 200;
    if shared {
        config.model.shared_motion = Some(SharedMotionConfig {
            bases: BASES as u32,
            knots: KNOTS as u32,
        });
    }
    (config, dataset)
}

fn weights(world: &mut World) -> Vec<MotionWeights> {
    world
        .query::<&MotionWeights>()
        .iter(world)
        .copied()
        .collect()
}

/// Every Gaussian starts with small random weights (the first B only) and zero bases; twenty
/// iterations keep the loss finite and move the bases and the weights.
#[test]
fn training_moves_the_bases_off_zero() {
    let (config, dataset) = tiny_scene(true);
    let mut trainer = Trainer::new(&config, dataset);
    let n = trainer.gaussian_count();
    let start = weights(&mut trainer.world);
    assert_eq!(start.len(), n, "every Gaussian has weights");
    assert!(start.iter().all(|w| w.w[BASES..].iter().all(|&v| v == 0.0)));
    let used: Vec<f32> = start.iter().flat_map(|w| w.w[..BASES].to_vec()).collect();
    let std = (used.iter().map(|v| v * v).sum::<f32>() / used.len() as f32).sqrt();
    assert!(
        (0.08..0.12).contains(&std),
        "weights' spread {std}, not 0.1"
    );
    let shared = trainer.world.resource::<SharedMotion>();
    assert_eq!((shared.bases.bases, shared.bases.knots), (BASES, KNOTS));
    assert!(shared.bases.values.iter().flatten().all(|&v| v == 0.0));

    for i in 0..20 {
        trainer.step();
        let loss = trainer.state().loss.total;
        assert!(loss.is_finite(), "iteration {i}: loss {loss}");
        assert!(trainer.fault().is_none(), "{:?}", trainer.fault());
    }
    let shared = trainer.world.resource::<SharedMotion>();
    let moved = shared
        .bases
        .values
        .iter()
        .flatten()
        .filter(|&&v| v != 0.0)
        .count();
    assert!(moved > 0, "the bases stayed at zero");
    assert!(shared.m.iter().flatten().any(|&m| m != 0.0));
    let after = weights(&mut trainer.world);
    assert!(after.iter().zip(&start).any(|(a, b)| a != b));
    assert!(after.iter().all(|w| w.w[BASES..].iter().all(|&v| v == 0.0)));
    let grads = trainer
        .world
        .query::<&Grad<MotionWeights>>()
        .iter(&trainer.world)
        .filter(|g| g.0.w[..BASES].iter().any(|&v| v != 0.0))
        .count();
    assert!(grads > 0, "some weights received a gradient");
}

/// Without `model.shared_motion` the world holds no bases and no weights, before and after
/// training.
#[test]
fn off_by_default_adds_nothing() {
    let (config, dataset) = tiny_scene(false);
    assert_eq!(config.model.shared_motion, None);
    let mut trainer = Trainer::new(&config, dataset);
    for _ in 0..3 {
        trainer.step();
    }
    let world = &mut trainer.world;
    assert!(!world.contains_resource::<SharedMotion>());
    assert_eq!(world.query::<&MotionWeights>().iter(world).count(), 0);
    assert_eq!(world.query::<&Grad<MotionWeights>>().iter(world).count(), 0);
    assert_eq!(world.query::<&Adam<MotionWeights>>().iter(world).count(), 0);
    assert!(trainer.model().shared_motion.is_none());
}

/// Each Gaussian's weights and scale just before densification, and whether any weights had
/// Adam moments then.
#[derive(Resource, Default)]
struct Before(HashMap<Entity, (MotionWeights, Scale)>, bool);

fn snapshot(
    mut before: ResMut<Before>,
    q: Query<(Entity, &MotionWeights, &Scale, &Adam<MotionWeights>)>,
) {
    before.0 = q.iter().map(|(e, w, s, _)| (e, (*w, *s))).collect();
    before.1 = q.iter().any(|(_, _, _, adam)| *adam != Adam::default());
}

/// Clones and split children carry their parent's weights with zeroed moments.
#[test]
fn densification_hands_the_weights_to_the_children() {
    let (mut config, dataset) = tiny_scene(true);
    densify_everything_every_ten(&mut config.densify);
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset).expect("CPU backend");
    spawn_initial_gaussians(&mut world, &config).expect("random points initialise");
    attach_motion_weights_now(&mut world);
    split_at_median_scale(&mut world);
    world.init_resource::<Before>();
    run_to_first_densification(&mut world, snapshot);
    let report = world.resource::<TrainState>().last_densify;
    assert!(report.cloned > 0 && report.split > 0, "{report:?}");

    assert!(
        world.resource::<Before>().1,
        "weights have moments before densification"
    );
    let before = std::mem::take(&mut world.resource_mut::<Before>().0);
    let rows: Vec<(Entity, MotionWeights, Adam<MotionWeights>, Scale)> = world
        .query::<(Entity, &MotionWeights, &Adam<MotionWeights>, &Scale)>()
        .iter(&world)
        .map(|(e, w, a, s)| (e, *w, *a, *s))
        .collect();
    assert_eq!(
        rows.len(),
        world
            .query_filtered::<Entity, With<Position>>()
            .iter(&world)
            .count(),
        "every Gaussian has weights and moments"
    );
    let (mut children, mut split_parents) = (0, 0);
    for (entity, weights, adam, scale) in rows {
        match before.get(&entity) {
            None => {
                children += 1;
                assert_eq!(adam, Adam::default(), "a child starts with zero moments");
                assert!(
                    before.values().any(|(w, _)| *w == weights),
                    "a child has its parent's weights"
                );
            }
            Some((w, old_scale)) => {
                assert_eq!(*w, weights, "a Gaussian keeps its weights");
                if *old_scale != scale {
                    split_parents += 1;
                    assert_eq!(adam, Adam::default(), "a split restarts its moments");
                }
            }
        }
    }
    assert_eq!(children, report.cloned + report.split);
    assert_eq!(split_parents, report.split);
}

/// The backward system's gradients on 10 000 Gaussians (several chunks): bit for bit the same
/// on 1 and 3 threads, dL/dw = g·u_b(t), and dL/dU the direct sum Σ_i λ_k·w_ib·g_i.
#[test]
fn bases_gradient_is_the_same_on_any_thread_count() {
    let (bases, knots, time) = (3, 6, 0.47);
    let value = |i: usize, salt: f32| ((i as f32 * 0.618_034 + salt).fract() - 0.5) * 2.0;
    let mut u = MotionBases::zeros(bases, knots);
    for (i, v) in u.values.iter_mut().enumerate() {
        *v = [value(i, 0.1), value(i, 0.2), value(i, 0.3)];
    }
    let gaussians: Vec<(MotionWeights, Vec3)> = (0..10_000)
        .map(|i| {
            let mut w = MotionWeights::default();
            for b in 0..bases {
                w.w[b] = 0.1 * value(i * 7 + b, 0.4);
            }
            // Every third Gaussian got no gradient.
            let g = if i % 3 == 0 {
                Vec3::ZERO
            } else {
                1e-3 * Vec3::new(value(i, 0.5), value(i, 0.6), value(i, 0.7))
            };
            (w, g)
        })
        .collect();
    let run = |threads: usize| {
        let mut world = World::new();
        world.insert_resource(ViewSample {
            camera: Camera::look_at(Vec3::new(0.0, 0.0, 4.0), Vec3::ZERO, Vec3::Y, 8, 8, 1.0),
            view: None,
            frame: 0,
            time,
            background: [0.0; 3],
        });
        world.insert_resource(SharedMotion::new(u.clone()));
        world.spawn_batch(gaussians.iter().map(|(w, g)| {
            (
                *w,
                Grad(Position { mean: g.to_array() }),
                // Stale values from an earlier iteration must be overwritten.
                Grad(MotionWeights { w: [9.0; 16] }),
            )
        }));
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| world.run_system_once(backward_shared_motion).unwrap());
        let d_weights: Vec<MotionWeights> = world
            .query::<&Grad<MotionWeights>>()
            .iter(&world)
            .map(|g| g.0)
            .collect();
        (world.resource::<SharedMotion>().grad.clone(), d_weights)
    };
    let (one, d_weights) = run(1);
    let (three, d_weights_three) = run(3);
    let bits = |v: &[[f32; 3]]| v.iter().flatten().map(|f| f.to_bits()).collect::<Vec<_>>();
    assert_eq!(
        bits(&one),
        bits(&three),
        "dL/dU depends on the thread count"
    );
    assert_eq!(d_weights, d_weights_three);

    let at = u.evaluate(time);
    let span = KnotSpan::at(knots, time);
    for ((_, g), d_w) in gaussians.iter().zip(&d_weights) {
        for b in 0..MAX_MOTION_BASES {
            let want = if b < bases { g.dot(at.bases()[b]) } else { 0.0 };
            assert_eq!(d_w.w[b], want);
        }
    }
    let mut checked = 0;
    for b in 0..bases {
        let sum = gaussians.iter().fold([0.0f64; 3], |s, (w, g)| {
            std::array::from_fn(|c| s[c] + f64::from(w.w[b]) * f64::from(g[c]))
        });
        for k in 0..knots {
            let lambda = match k {
                k if k == span.first => span.lambda[0],
                k if k == span.first + 1 => span.lambda[1],
                _ => 0.0,
            };
            for c in 0..3 {
                let want = f64::from(lambda) * sum[c];
                let got = f64::from(one[b * knots + k][c]);
                assert!(
                    (got - want).abs() <= 1e-5 * want.abs() + 1e-12,
                    "dU[{b}][{k}][{c}]: {got} vs {want}"
                );
                checked += usize::from(want != 0.0);
            }
        }
    }
    assert_eq!(checked, bases * 2 * 3, "two knots per basis get a gradient");
}

/// A trained model saved and loaded back renders exactly as the trainer that made it, and
/// keeps its bases and weights bit for bit.
#[test]
fn saved_model_renders_like_the_trained_one() {
    let (config, dataset) = tiny_scene(true);
    let mut trainer = Trainer::new(&config, dataset.clone());
    for _ in 0..15 {
        trainer.step();
    }
    let model = trainer.model();
    let motion = model
        .shared_motion
        .clone()
        .expect("the model has shared motion");
    assert_eq!(motion.weights.len(), model.gaussians.len());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("model.safetensors");
    model.save(&path).unwrap();
    let loaded = Model::load(&path).unwrap();
    assert_eq!(loaded.shared_motion, Some(motion));
    let mut again = Trainer::from_model(&config, dataset.clone(), &loaded);
    for view in dataset.test.iter().chain(&dataset.train).step_by(5) {
        let camera = &dataset.cameras[view.camera];
        let a = trainer.render(camera, view.time);
        let b = again.render(camera, view.time);
        assert!(a.image == b.image, "the loaded model renders differently");
    }
    // Without its shared motion the same Gaussians render differently: it is drawn.
    let mut plain = loaded.clone();
    plain.shared_motion = None;
    let mut scene = config.clone();
    scene.model.shared_motion = None;
    let mut without = Trainer::from_model(&scene, dataset.clone(), &plain);
    let view = &dataset.train[0];
    let camera = &dataset.cameras[view.camera];
    assert!(trainer.render(camera, view.time).image != without.render(camera, view.time).image);
}
