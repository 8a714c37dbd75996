//! Steps the training schedule on a tiny synthetic scene: the loss goes down, and
//! densification keeps every component and optimiser state consistent.

#[path = "common/demo.rs"]
mod demo;
#[path = "common/densify.rs"]
mod densify;
#[path = "common/rows.rs"]
mod rows;

use std::collections::HashMap;
use std::sync::Arc;

use bevy_ecs::prelude::*;
use densify::{densify_everything_every_ten, run_to_first_densification, split_at_median_scale};
use rows::in_entity_order;
use tadgs::components::*;
use tadgs::data::Dataset;
use tadgs::data::synthetic::demo_scene;
use tadgs::metrics::loss::{LossScratch, training_loss};
use tadgs::resources::TrainState;
use tadgs::scene::{DataSource, SceneConfig};
use tadgs::systems::training_schedule;
use tadgs::train::{Trainer, insert_resources, spawn_initial_gaussians};

/// A 6-frame, 48×36 version of the demo scene.
fn tiny_scene() -> (SceneConfig, Arc<Dataset>) {
    let (mut config, dataset) = demo::small_demo("tiny", 6, 48, 36, 300);
    config.train.iterations = 200;
    (config, dataset)
}

fn fixed_view_loss(trainer: &mut Trainer, dataset: &Dataset) -> f32 {
    let view = dataset
        .train
        .iter()
        .find(|v| v.frame == 2)
        .expect("frame 2 is a training frame");
    let out = trainer.render(&dataset.cameras[view.camera], view.time);
    let mut d = Vec::new();
    training_loss(
        &mut LossScratch::default(),
        &out.image,
        &view.to_image().unwrap(),
        0.2,
        &mut d,
    )
    .total
}

/// Sixty iterations lower the loss of a fixed training view by at least 20 %.
#[test]
fn loss_decreases_when_stepping_the_schedule() {
    let (config, dataset) = tiny_scene();
    let mut trainer = Trainer::new(&config, dataset.clone());
    let before = fixed_view_loss(&mut trainer, &dataset);
    for _ in 0..60 {
        trainer.step();
    }
    let after = fixed_view_loss(&mut trainer, &dataset);
    assert_eq!(trainer.state().iteration, 60);
    assert!(after < 0.8 * before, "loss before {before}, after {after}");
}

/// Parameter values of one Gaussian, as seen just before densification.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Snapshot {
    position: Position,
    temporal: Temporal,
    scale: Scale,
    opacity: Opacity,
    adam_position: Adam<Position>,
}

#[derive(Resource, Default)]
struct Before(HashMap<Entity, Snapshot>);

fn snapshot(
    mut before: ResMut<Before>,
    q: Query<(
        Entity,
        &Position,
        &Temporal,
        &Scale,
        &Opacity,
        &Adam<Position>,
    )>,
) {
    before.0 = q
        .iter()
        .map(|(e, p, t, s, o, a)| {
            (
                e,
                Snapshot {
                    position: *p,
                    temporal: *t,
                    scale: *s,
                    opacity: *o,
                    adam_position: *a,
                },
            )
        })
        .collect();
}

fn adam_is_zero<P: Param>(world: &mut World, e: Entity) -> bool {
    let adam = world
        .get::<Adam<P>>(e)
        .expect("every Gaussian has Adam state for every group");
    adam.m()
        .values()
        .iter()
        .chain(adam.v().values())
        .all(|v| *v == 0.0)
}

fn all_adam_zero(world: &mut World, e: Entity) -> bool {
    adam_is_zero::<Position>(world, e)
        && adam_is_zero::<Fourier>(world, e)
        && adam_is_zero::<Temporal>(world, e)
        && adam_is_zero::<Opacity>(world, e)
        && adam_is_zero::<Rotation>(world, e)
        && adam_is_zero::<Scale>(world, e)
        && adam_is_zero::<Color>(world, e)
        && adam_is_zero::<ColorRest>(world, e)
}

/// Clone, split and prune keep the population consistent: the entity count adds up, every
/// Gaussian keeps every component, children inherit their parent's temporal centre, new and
/// split Gaussians start with zeroed Adam moments, others keep theirs.
#[test]
fn densification_keeps_components_and_adam_state_consistent() {
    let (mut config, dataset) = tiny_scene();
    densify_everything_every_ten(&mut config.densify);
    config.densify.prune_opacity = 0.1; // the initial opacity: about half fall below it
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset).expect("CPU backend");
    spawn_initial_gaussians(&mut world, &config).expect("random points initialise");
    split_at_median_scale(&mut world);

    world.init_resource::<Before>();
    run_to_first_densification(&mut world, snapshot);
    let report = world.resource::<TrainState>().last_densify;
    assert_eq!(report.iteration, 10);
    assert!(
        report.cloned > 0 && report.split > 0 && report.pruned > 0,
        "{report:?}"
    );

    let before = std::mem::take(&mut world.resource_mut::<Before>().0);
    let entities: Vec<Entity> = world
        .query_filtered::<Entity, With<Position>>()
        .iter(&world)
        .collect();
    assert_eq!(
        entities.len(),
        before.len() + report.cloned + report.split - report.pruned
    );
    let complete = world
        .query::<(
            (
                &Position,
                &Fourier,
                &Temporal,
                &Opacity,
                &Rotation,
                &Scale,
                &Color,
                &ColorRest,
            ),
            (
                &Grad<Position>,
                &Grad<Fourier>,
                &Grad<Temporal>,
                &Grad<Opacity>,
                &Grad<Rotation>,
                &Grad<Scale>,
                &Grad<Color>,
                &Grad<ColorRest>,
                &Adam<ColorRest>,
            ),
            (&GradAccum, &WarpedTime, &Deformed, &SplatSlot),
        )>()
        .iter(&world)
        .count();
    assert_eq!(
        complete,
        entities.len(),
        "every Gaussian has every component"
    );

    let mut new = 0;
    let mut split_parents = 0;
    let mut kept_moments = 0;
    for &e in &entities {
        let temporal = *world.get::<Temporal>(e).unwrap();
        let scale = *world.get::<Scale>(e).unwrap();
        assert_eq!(
            *world.get::<GradAccum>(e).unwrap(),
            GradAccum::default(),
            "statistics reset"
        );
        match before.get(&e) {
            None => {
                new += 1;
                assert!(
                    all_adam_zero(&mut world, e),
                    "new Gaussians start with zero moments"
                );
                let parent = before.values().find(|s| {
                    s.temporal == temporal
                        && (s.scale == scale || s.scale.d0[0] - scale.d0[0] > 0.46)
                });
                assert!(
                    parent.is_some(),
                    "a child inherits its parent's temporal centre and fields"
                );
            }
            Some(old) => {
                assert!(
                    tadgs::model::deform::sigmoid(old.opacity.logit) >= 0.1,
                    "survivors are above the prune threshold"
                );
                assert_eq!(old.temporal, temporal);
                if old.scale != scale {
                    split_parents += 1;
                    assert!(
                        (old.scale.d0[0] - scale.d0[0] - 1.6f32.ln()).abs() < 1e-5,
                        "split divides scales by 1.6"
                    );
                    assert!(
                        all_adam_zero(&mut world, e),
                        "split Gaussians restart their moments"
                    );
                } else {
                    assert_eq!(
                        *world.get::<Adam<Position>>(e).unwrap(),
                        old.adam_position,
                        "others keep their moments"
                    );
                    kept_moments += !adam_is_zero::<Position>(&mut world, e) as usize;
                }
            }
        }
    }
    assert_eq!(new, report.cloned + report.split);
    assert_eq!(split_parents, report.split);
    assert!(kept_moments > 0);
}

/// A model of SH degree 0 stores no higher bands (no `ColorRest`, nor its gradient or
/// moments), and trains bit for bit like the same Gaussians carrying zero higher bands while
/// the degree-3 model's active degree is still 0: bands above the active degree are never read.
#[test]
fn degree_zero_models_store_no_higher_bands() {
    let (mut config, dataset) = tiny_scene();
    config.model.sh_degree = 0;
    let mut lean = Trainer::new(&config, dataset.clone());
    config.model.sh_degree = 3;
    let mut full = Trainer::new(&config, dataset);
    let count = |t: &mut Trainer| {
        let w = &mut t.world;
        (
            w.query::<&Color>().iter(w).count(),
            w.query::<(&ColorRest, &Grad<ColorRest>, &Adam<ColorRest>)>()
                .iter(w)
                .count(),
        )
    };
    let n = lean.gaussian_count();
    assert!(n > 0);
    assert_eq!(count(&mut lean), (n, 0));
    assert_eq!(count(&mut full), (n, n));
    for i in 0..10 {
        lean.step();
        full.step();
        assert_eq!(full.state().sh_degree, 0);
        let (a, b) = (lean.state().loss.total, full.state().loss.total);
        assert_eq!(a.to_bits(), b.to_bits(), "iteration {i}: loss {a} vs {b}");
    }
}

/// `scale_schedule` keeps the shape of every shipped scene's schedule at any run length: the
/// densification window, the coarse-to-fine switch and the static warm-up's end fall at the
/// same fractions of the run, opacity resets come as often relative to its length, and no
/// opacity reset falls in the last 10 % of the run.
#[test]
fn scaled_schedules_keep_their_shape_and_never_reset_late() {
    use tadgs::scene::load_scene;
    use tadgs::systems::densify::is_opacity_reset;
    let scenes = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes");
    for name in ["demo", "panoptic", "dnerf", "n3dv"] {
        let mut file = load_scene(std::path::Path::new(&format!("{scenes}/{name}.ron")))
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        // No shipped file has a static warm-up; give each one to check that it stretches too.
        file.train.static_until = file.train.iterations / 10;
        let resets = |c: &SceneConfig| {
            (1..=c.train.iterations)
                .filter(|&i| is_opacity_reset(&c.densify, c.train.iterations, i))
                .collect::<Vec<u32>>()
        };
        let fraction = |n: u32, c: &SceneConfig| n as f64 / c.train.iterations as f64;
        for iterations in [100, 777, 1000, 5000, 15_000, 40_000, 100_000] {
            let mut scaled = file.clone();
            scaled.scale_schedule(iterations);
            let what = format!("{name} at {iterations} iterations");
            assert_eq!(scaled.train.iterations, iterations, "{what}");
            assert_eq!(scaled.densify.interval, file.densify.interval, "{what}");
            for (new, old) in [
                (scaled.densify.from_iter, file.densify.from_iter),
                (scaled.densify.until_iter, file.densify.until_iter),
                (scaled.train.coarse_until, file.train.coarse_until),
                (scaled.train.static_until, file.train.static_until),
            ] {
                let gap = (fraction(new, &scaled) - fraction(old, &file)).abs();
                assert!(gap <= 1.0 / iterations as f64, "{what}: {new} vs {old}");
            }
            let late = resets(&scaled)
                .into_iter()
                .filter(|&i| i as f64 > 0.9 * iterations as f64)
                .collect::<Vec<_>>();
            assert!(late.is_empty(), "{what}: resets at {late:?}");
            let (before, after) = (resets(&file).len(), resets(&scaled).len());
            assert!(
                before.abs_diff(after) <= 1,
                "{what}: {before} → {after} resets"
            );
        }
    }
    // The guard alone: a reset due at the very end of a run is skipped.
    let mut config = SceneConfig::new("late", DataSource::Synthetic(demo_scene()));
    config.train.iterations = 3000;
    config.densify.until_iter = 3000;
    config.densify.opacity_reset_interval = 1000;
    let due = |i| is_opacity_reset(&config.densify, 3000, i);
    assert!(due(1000) && due(2000) && !due(3000) && !due(2500));
}

/// The synthetic TAD scene (`scenes/tad.ron`) exercises what VAD, TAT and TOW are for — at
/// least 150 frames and at least four objects that each live for at most 30 % of the sequence
/// while crossing at least one unit of space — and it is deterministic: built twice (here at
/// 40×30), every image and dynamic mask is identical.
#[test]
fn synthetic_tad_scene_is_short_lived_fast_and_deterministic() {
    use tadgs::scene::load_scene;
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/tad.ron");
    let config = load_scene(std::path::Path::new(path)).expect("tad scene loads");
    let DataSource::Synthetic(mut synthetic) = config.data else {
        panic!("scenes/tad.ron is a synthetic scene");
    };
    assert!(synthetic.frames >= 150);
    let short_fast = synthetic
        .objects
        .iter()
        .filter(|o| {
            let Some((start, end)) = o.visible else {
                return false;
            };
            let travel = o.position_at(start).distance(o.position_at(end));
            end - start <= 0.3 && travel >= 1.0
        })
        .count();
    assert!(short_fast >= 4, "{short_fast} short-lived fast objects");

    (synthetic.width, synthetic.height, synthetic.supersample) = (40, 30, 1);
    let first = synthetic.build().expect("tad scene builds");
    let second = synthetic.build().expect("tad scene builds");
    assert_eq!(first.frame_count, synthetic.frames);
    for (a, b) in first
        .train
        .iter()
        .chain(&first.test)
        .zip(second.train.iter().chain(&second.test))
    {
        assert_eq!((a.camera, a.frame), (b.camera, b.frame));
        assert!(a.image == b.image, "camera {} frame {}", a.camera, a.frame);
        assert_eq!(a.dynamic_mask, b.dynamic_mask);
    }
    let dynamic: usize = first
        .test
        .iter()
        .filter_map(|v| v.dynamic_mask.as_ref())
        .map(|m| m.iter().filter(|&&d| d).count())
        .sum();
    assert!(dynamic > 0, "the held-out camera sees the moving objects");
    // Every training view has an object mask for carving, and it holds each view's dynamic
    // pixels (the moving objects are objects).
    for view in &first.train {
        let objects = view.foreground.as_ref().expect("object masks for carving");
        let dynamic = view.dynamic_mask.as_ref().unwrap();
        assert!(dynamic.iter().zip(objects).all(|(&d, &o)| !d || o));
    }
}

/// Coarse-to-fine (`train.coarse_downscale: 2`, `coarse_until: 4`): iterations 1–4 render and
/// compare at half the size (48×36 → 24×18) against the box-filtered view, iteration 5 onwards
/// at the data's own size, and the loss still goes down over the whole run.
#[test]
fn coarse_to_fine_switches_resolution_after_coarse_until() {
    use tadgs::resources::LossImage;
    let (mut config, dataset) = tiny_scene();
    config.train.coarse_downscale = 2;
    config.train.coarse_until = 4;
    let mut trainer = Trainer::new(&config, dataset.clone());
    let before = fixed_view_loss(&mut trainer, &dataset);
    let target_size = |trainer: &Trainer| {
        let target = &trainer.world.resource::<LossImage>().target;
        (target.width, target.height)
    };
    for _ in 0..4 {
        trainer.step();
        assert_eq!(target_size(&trainer), (24, 18));
    }
    trainer.step();
    assert_eq!(target_size(&trainer), (48, 36));
    for _ in 0..55 {
        trainer.step();
    }
    let after = fixed_view_loss(&mut trainer, &dataset);
    assert!(after < 0.8 * before, "loss before {before}, after {after}");

    let coarse = dataset.downscaled_training_views(2);
    let (view, full) = (&coarse.train[3], &dataset.train[3]);
    assert_eq!(view.image.dimensions(), (24, 18));
    let expected: u32 = [(2, 2), (3, 2), (2, 3), (3, 3)]
        .iter()
        .map(|&(x, y)| u32::from(full.image.pixels().unwrap().get_pixel(x, y).0[1]))
        .sum();
    assert!(
        (u32::from(view.image.pixels().unwrap().get_pixel(1, 1).0[1]) * 4).abs_diff(expected) <= 4
    );
    let camera = coarse.cameras[view.camera];
    assert_eq!((camera.width, camera.height), (24, 18));
    assert_eq!(camera.fx, dataset.cameras[view.camera].fx / 2.0);
}

/// Exposure compensation (`train.camera_exposure`): with camera 0's training images darkened
/// to 60 %, that camera learns the lowest gain in every channel, clearly below 1 (log-gain
/// < −0.1), while the corrections stay centred over the training cameras (mean log-gain and
/// offset 0 to 1e-5), the held-out camera keeps the identity, and the summary line names
/// camera 0 as the lowest gain.
#[test]
fn camera_exposure_learns_a_darker_cameras_gain() {
    use tadgs::resources::CameraExposures;
    let (mut config, dataset) = tiny_scene();
    let mut data = (*dataset).clone();
    for view in data.train.iter_mut().filter(|v| v.camera == 0) {
        let mut darker = (*view.image.pixels().unwrap()).clone();
        for value in darker.iter_mut() {
            *value = (f32::from(*value) * 0.6).round() as u8;
        }
        view.image = darker.into();
    }
    config.train.camera_exposure = true;
    config.train.lr.exposure = 0.02;
    config.densify.until_iter = 0;
    let mut trainer = Trainer::new(&config, Arc::new(data));
    for _ in 0..300 {
        trainer.step();
    }
    let exposures = trainer.world.resource::<CameraExposures>();
    let held_out = 5;
    assert!(!exposures.cameras[held_out].trained);
    assert_eq!(exposures.cameras[held_out].exposure, Default::default());
    let trained: Vec<_> = exposures.cameras.iter().filter(|c| c.trained).collect();
    assert_eq!(trained.len(), 15);
    for i in 0..6 {
        let mean = trained.iter().map(|c| c.exposure.values()[i]).sum::<f32>() / 15.0;
        assert!(mean.abs() < 1e-5, "value {i} not centred: mean {mean}");
    }
    let dark = exposures.cameras[0].exposure.log_gain;
    for k in 0..3 {
        assert!(dark[k] < -0.1, "camera 0 log-gain {dark:?}");
        for (i, c) in exposures.cameras.iter().enumerate().skip(1) {
            assert!(
                c.exposure.log_gain[k] > dark[k],
                "camera {i} log-gain {:?} not above camera 0's {dark:?}",
                c.exposure.log_gain
            );
        }
    }
    let summary = exposures.summary().expect("cameras were trained");
    assert!(summary.starts_with("gain 0."), "{summary}");
    assert!(summary.contains("(camera 0) to"), "{summary}");
}

/// Static warm-up (`train.static_until: 5`): after iterations 1–5 every Gaussian's motion
/// terms (Fourier coefficients and phases, rotation and log-scale linear terms) and temporal
/// parameters are bit-identical to their initial values while the positions have moved; five
/// iterations later the motion has started to learn.
#[test]
fn static_warm_up_freezes_motion_and_lifespans() {
    type TimeTerms = (Fourier, Temporal, [f32; 4], [f32; 3]);
    let snapshot = |trainer: &mut Trainer| -> Vec<(Entity, TimeTerms, Position)> {
        let world = &mut trainer.world;
        world
            .query::<(Entity, &Fourier, &Temporal, &Rotation, &Scale, &Position)>()
            .iter(world)
            .map(|(e, f, t, r, s, p)| (e, (*f, *t, r.c1, s.d1), *p))
            .collect()
    };
    let (mut config, dataset) = tiny_scene();
    config.train.static_until = 5;
    let mut trainer = Trainer::new(&config, dataset);
    let initial = snapshot(&mut trainer);
    for _ in 0..5 {
        trainer.step();
    }
    let warm = snapshot(&mut trainer);
    assert_eq!(initial.len(), warm.len(), "no densification in the warm-up");
    let mut moved = 0;
    for ((e0, time0, p0), (e1, time1, p1)) in initial.iter().zip(&warm) {
        assert_eq!(e0, e1);
        assert_eq!(time0, time1, "time-dependent terms changed in the warm-up");
        moved += usize::from(p0 != p1);
    }
    assert!(moved > initial.len() / 2, "only {moved} positions moved");
    for _ in 0..5 {
        trainer.step();
    }
    let after = snapshot(&mut trainer);
    let learning = after
        .iter()
        .zip(&warm)
        .filter(|((_, (f1, ..), _), (_, (f0, ..), _))| f1 != f0)
        .count();
    assert!(
        learning > warm.len() / 2,
        "only {learning} trajectories changed after the warm-up"
    );
}

/// `train.random_background` on views whose matte says they show nothing (alpha 0 over a
/// white truth), with every Gaussian recoloured white: over the fixed white background the
/// Gaussians cost almost no loss and keep most of their opacity; over random backgrounds
/// they cost loss wherever they cover the image, and after 60 iterations their mean spatial
/// opacity is below half of the fixed-background run's.
#[test]
fn random_background_fades_gaussians_of_the_background_colour() {
    use tadgs::data::Matte;
    use tadgs::model::deform::sigmoid;
    use tadgs::model::sh::rgb_to_sh_dc;
    let mean_opacity_after = |random: bool| -> (f32, f32) {
        let (mut config, dataset) = tiny_scene();
        let mut data = (*dataset).clone();
        for view in &mut data.train {
            let (w, h) = view.image.dimensions();
            view.image = image::RgbImage::from_pixel(w, h, image::Rgb([255; 3])).into();
            view.matte = Some(Matte {
                alpha: vec![0; (w * h) as usize],
                background: [1.0; 3],
            });
        }
        config.train.background = [1.0; 3];
        config.train.random_background = random;
        config.densify.until_iter = 0;
        let mut trainer = Trainer::new(&config, Arc::new(data));
        let world = &mut trainer.world;
        for mut color in world.query::<&mut Color>().iter_mut(world) {
            color.dc = [rgb_to_sh_dc(1.0); 3];
        }
        for mut rest in world.query::<&mut ColorRest>().iter_mut(world) {
            *rest = ColorRest::default();
        }
        let mean = |world: &mut World| {
            let opacities: Vec<f32> = world
                .query::<&Opacity>()
                .iter(world)
                .map(|o| sigmoid(o.logit))
                .collect();
            opacities.iter().sum::<f32>() / opacities.len() as f32
        };
        let before = mean(world);
        for _ in 0..60 {
            trainer.step();
        }
        (before, mean(&mut trainer.world))
    };
    let (start, fixed) = mean_opacity_after(false);
    let (_, random) = mean_opacity_after(true);
    assert!(fixed > 0.5 * start, "fixed background: {start} → {fixed}");
    assert!(
        random < 0.5 * fixed,
        "random {random} against fixed {fixed}"
    );
}

/// The deformation stage leaves Gaussians too faded to draw (σ(t) < 1/255) at
/// `Deformed::faded`, and that changes nothing the iteration computes: against a world that
/// evaluates every Gaussian (`DeformEveryGaussian`), the render, every gradient and the
/// densification statistics are equal bit for bit, and the drawable Gaussians' `Deformed`
/// too.
#[test]
fn faded_gaussians_are_not_evaluated_and_change_nothing() {
    use tadgs::bench::benchmark_world;
    use tadgs::resources::{DeformEveryGaussian, SplatBuffers};

    let world_with = |every: bool| {
        let mut world = benchmark_world(3000, 96, 64, true);
        // Every third Gaussian fades below what is drawn.
        for (i, mut opacity) in world
            .query::<&mut Opacity>()
            .iter_mut(&mut world)
            .enumerate()
        {
            if i % 3 == 0 {
                opacity.logit = -8.0;
            }
        }
        if every {
            world.insert_resource(DeformEveryGaussian);
        }
        training_schedule().run(&mut world);
        world
    };
    let (mut skipping, mut evaluating) = (world_with(false), world_with(true));

    fn bits<P: Param>(world: &mut World) -> Vec<u32> {
        let grads = in_entity_order::<Grad<P>>(world);
        grads
            .iter()
            .flat_map(|g| g.0.values().iter().map(|v| v.to_bits()).collect::<Vec<_>>())
            .collect()
    }
    let (skipped, evaluated) = (
        in_entity_order::<Deformed>(&mut skipping),
        in_entity_order::<Deformed>(&mut evaluating),
    );
    let faded = skipped
        .iter()
        .filter(|d| **d == Deformed::faded(d.opacity))
        .count();
    assert!(
        faded >= 900,
        "a third of the Gaussians are faded ({faded} left unevaluated)"
    );
    for (s, e) in skipped.iter().zip(&evaluated) {
        assert_eq!(
            s.opacity.to_bits(),
            e.opacity.to_bits(),
            "the opacity of every Gaussian"
        );
        if s.opacity >= 1.0 / 255.0 {
            assert_eq!(s, e, "a drawable Gaussian is evaluated in full");
        } else {
            assert_eq!(*s, Deformed::faded(s.opacity), "a faded Gaussian is not");
        }
    }
    let render = |world: &World| -> Vec<u32> {
        let image = &world.resource::<SplatBuffers>().render.image.data;
        image.iter().flat_map(|p| p.map(f32::to_bits)).collect()
    };
    assert_eq!(render(&skipping), render(&evaluating), "render");
    macro_rules! same_grads {
        ($($group:ty),*) => {
            $(assert_eq!(
                bits::<$group>(&mut skipping),
                bits::<$group>(&mut evaluating),
                "gradient of {}",
                stringify!($group)
            );)*
        };
    }
    same_grads!(Position, Fourier, Temporal, Opacity, Rotation, Scale, Color);
    assert_eq!(
        in_entity_order::<GradAccum>(&mut skipping),
        in_entity_order::<GradAccum>(&mut evaluating),
        "statistics"
    );
}
