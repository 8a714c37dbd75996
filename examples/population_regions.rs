//! Where a trained population sits: on the moving foreground or on the static background.
//!
//! Reads run folders written by `tadgs train` on a dataset with foreground segmentation
//! (Panoptic with `foreground_masks: true`, the synthetic scenes with object masks) and
//! classifies every Gaussian at its temporal centre t_i, where it is most opaque: its deformed
//! mean μ(t_i) is projected into every training camera at the frame nearest t_i, and the
//! Gaussian is *foreground* when more than half of the cameras that see it in frame mark that
//! pixel as foreground; *unseen* when no training camera sees it. Per class it prints the
//! count, the normalised lifespan ψ̄ (the fraction of the sequence where σ(t) ≥ σ^s/5, the
//! quantity TAT reads), the spatial opacity σ^s and the largest world scale.
//!
//! It answers "where did densification put the budget?" when comparing the full method with
//! the baseline: at a population cap both runs have the same number of Gaussians, and the
//! share on the dynamic foreground is what VAD and TAT are meant to raise.
//!
//! ```text
//! cargo run --release --example population_regions -- runs/panoptic runs/panoptic-baseline
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use bevy_ecs::world::World;
use glam::Vec3;
use tadgs::components::{Deformed, Opacity, Scale, Temporal};
use tadgs::data::{Camera, Dataset};
use tadgs::init::scene_extent;
use tadgs::io::model::Model;
use tadgs::model::deform::{lifespan_fraction, sigmoid};
use tadgs::resources::{DeformEveryGaussian, Settings, TrainState, ViewSample};
use tadgs::scene::load_scene;
use tadgs::systems::render_schedule;
use tadgs::train::insert_render_resources;

/// Where a Gaussian sits at its temporal centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Region {
    Foreground,
    Background,
    Unseen,
}

/// One Gaussian's class and the figures summarised per class.
#[derive(Clone, Copy, Debug)]
struct Classified {
    region: Region,
    /// μ(t_i), where it was classified (the tests check the class against it).
    #[cfg_attr(not(test), allow(dead_code))]
    mean: Vec3,
    lifespan: f32,
    opacity: f32,
    max_scale: f32,
}

/// The foreground vote of the training cameras at one frame: true when more than half of the
/// cameras that see `point` in frame mark its pixel as foreground, None when none sees it.
fn foreground_vote(point: Vec3, views: &[(&Camera, &[bool])]) -> Option<bool> {
    let (mut seen, mut foreground) = (0usize, 0usize);
    for (camera, mask) in views {
        let (u, v, depth) = camera.project(point);
        let (w, h) = (camera.width as f32, camera.height as f32);
        if depth <= 0.0 || !(0.0..w).contains(&u) || !(0.0..h).contains(&v) {
            continue;
        }
        seen += 1;
        if mask[v as usize * camera.width as usize + u as usize] {
            foreground += 1;
        }
    }
    (seen > 0).then_some(2 * foreground > seen)
}

/// The training cameras with a foreground mask at `frame`.
fn masked_views(dataset: &Dataset, frame: usize) -> Vec<(&Camera, &[bool])> {
    dataset
        .train
        .iter()
        .filter(|view| view.frame == frame)
        .filter_map(|view| {
            let mask = view.foreground.as_deref()?;
            Some((&dataset.cameras[view.camera], mask))
        })
        .collect()
}

/// Classifies every Gaussian of the world (the model spawned, render resources inserted).
fn classify(world: &mut World, dataset: &Dataset) -> Vec<Classified> {
    let last_frame = dataset.frame_count.saturating_sub(1);
    let frame_of = |time: f32| (time * last_frame as f32).round() as usize;
    let mut centres: Vec<usize> = world
        .query::<&Temporal>()
        .iter(world)
        .map(|temporal| frame_of(temporal.center))
        .collect();
    centres.sort_unstable();
    centres.dedup();

    let settings = world.resource::<Settings>();
    let (model, warp) = (settings.opacity, settings.warp);
    let mut schedule = render_schedule();
    // The regions are judged from every Gaussian's deformed mean, drawn or not.
    world.insert_resource(DeformEveryGaussian);
    let mut classified = Vec::new();
    // Gaussians sit at a few anchor centres: deform once per centre.
    for frame in centres {
        world.resource_mut::<ViewSample>().time = dataset.frame_time(frame);
        world.resource_mut::<ViewSample>().frame = frame;
        schedule.run(world);
        let views = masked_views(dataset, frame);
        for (deformed, temporal, opacity, scale) in world
            .query::<(&Deformed, &Temporal, &Opacity, &Scale)>()
            .iter(world)
        {
            if frame_of(temporal.center) != frame {
                continue;
            }
            let region = match foreground_vote(deformed.mean(), &views) {
                Some(true) => Region::Foreground,
                Some(false) => Region::Background,
                None => Region::Unseen,
            };
            classified.push(Classified {
                region,
                mean: deformed.mean(),
                lifespan: lifespan_fraction(model, temporal.scale, temporal.center, &warp),
                opacity: sigmoid(opacity.logit),
                max_scale: Vec3::from_array(scale.d0).exp().max_element(),
            });
        }
    }
    classified
}

/// Loads a run and classifies its population.
fn analyse(run: &Path) -> Result<(Vec<Classified>, usize)> {
    let scene = load_scene(&run.join("scene.ron"))
        .with_context(|| format!("reading {}/scene.ron", run.display()))?;
    let model = Model::load(&run.join("model.safetensors"))?;
    let dataset = tadgs::data::load(&scene.data)?;
    if !dataset.train.iter().any(|view| view.foreground.is_some()) {
        bail!(
            "the dataset of {} has no foreground masks (for Panoptic, set \
             `foreground_masks: true`)",
            run.display()
        );
    }
    let camera = dataset.cameras[dataset.train[0].camera];
    let mut world = World::new();
    insert_render_resources(
        &mut world,
        &scene,
        dataset.frame_count,
        scene_extent(&dataset.cameras),
        camera,
    )?;
    world.resource_mut::<TrainState>().sh_degree = model.sh_degree;
    model.spawn_into(&mut world);
    Ok((classify(&mut world, &dataset), dataset.frame_count))
}

/// The q-quantile of `values` (sorted in place); NaN when empty.
fn quantile(values: &mut [f32], q: f32) -> f32 {
    if values.is_empty() {
        return f32::NAN;
    }
    values.sort_by(f32::total_cmp);
    values[((values.len() - 1) as f32 * q).round() as usize]
}

fn print_summary(run: &Path, classified: &[Classified], frame_count: usize) {
    println!("{} ({} Gaussians)", run.display(), classified.len());
    println!(
        "  {:<11} {:>8} {:>7} {:>22} {:>9} {:>11}",
        "region", "count", "share", "lifespan p10/p50/p90", "frames", "σs median"
    );
    for region in [Region::Foreground, Region::Background, Region::Unseen] {
        let members: Vec<&Classified> = classified.iter().filter(|c| c.region == region).collect();
        let mut lifespans: Vec<f32> = members.iter().map(|c| c.lifespan).collect();
        let mut opacities: Vec<f32> = members.iter().map(|c| c.opacity).collect();
        let (p10, p50, p90) = (
            quantile(&mut lifespans, 0.1),
            quantile(&mut lifespans, 0.5),
            quantile(&mut lifespans, 0.9),
        );
        println!(
            "  {:<11} {:>8} {:>6.1}% {:>8.3}/{:.3}/{:.3} {:>9.0} {:>11.3}",
            format!("{region:?}").to_lowercase(),
            members.len(),
            100.0 * members.len() as f32 / classified.len().max(1) as f32,
            p10,
            p50,
            p90,
            p50 * frame_count as f32,
            quantile(&mut opacities, 0.5),
        );
    }
    let mut scales: Vec<f32> = classified
        .iter()
        .filter(|c| c.region == Region::Foreground)
        .map(|c| c.max_scale)
        .collect();
    println!(
        "  foreground largest-axis scale, median {:.4}",
        quantile(&mut scales, 0.5)
    );
}

fn main() -> Result<()> {
    let runs: Vec<PathBuf> = std::env::args().skip(1).map(PathBuf::from).collect();
    if runs.is_empty() {
        bail!("usage: population_regions RUN_DIR [RUN_DIR ...]");
    }
    for run in &runs {
        let (classified, frame_count) = analyse(run)?;
        print_summary(run, &classified, frame_count);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at the origin looking down +z, 4×4 pixels, focal 4: the pixel of a point
    /// (x, y, 1) is (4x + 2, 4y + 2).
    fn camera() -> Camera {
        Camera::look_at(Vec3::ZERO, Vec3::Z, -Vec3::Y, 4, 4, 2.0 * (0.5f32).atan())
    }

    /// The vote is a strict majority of the cameras that see the point; cameras that do not
    /// see it (behind, outside the image) do not vote.
    #[test]
    fn the_vote_is_a_majority_of_the_cameras_that_see_the_point() {
        let cam = camera();
        let (u, v, _) = cam.project(Vec3::new(0.0, 0.0, 1.0));
        let pixel = v as usize * 4 + u as usize;
        let mut on = vec![false; 16];
        on[pixel] = true;
        let off = vec![false; 16];
        let point = Vec3::new(0.0, 0.0, 1.0);
        assert_eq!(foreground_vote(point, &[(&cam, &on)]), Some(true));
        assert_eq!(
            foreground_vote(point, &[(&cam, &on), (&cam, &off)]),
            Some(false)
        );
        assert_eq!(
            foreground_vote(point, &[(&cam, &on), (&cam, &on), (&cam, &off)]),
            Some(true)
        );
        // Behind the camera and outside the image: nobody votes.
        assert_eq!(foreground_vote(-point, &[(&cam, &on)]), None);
        assert_eq!(
            foreground_vote(Vec3::new(5.0, 0.0, 1.0), &[(&cam, &on)]),
            None
        );
    }

    /// On the synthetic TAD scene (object masks in every view), hand-placed Gaussians: one at
    /// the centre of every object that exists at an anchor time is foreground; floor points
    /// two units or more from every object are background; a point above all cameras' view is
    /// unseen.
    #[test]
    fn object_centres_are_foreground_floor_points_background() {
        use std::sync::Arc;
        use tadgs::scene::{DataSource, apply_overrides};
        use tadgs::train::Trainer;

        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let mut scene = load_scene(&root.join("scenes/tad.ron")).unwrap();
        apply_overrides(
            &mut scene,
            &["data.frames=41", "data.width=80", "data.height=60"],
        )
        .unwrap();
        let DataSource::Synthetic(synthetic) = &scene.data else {
            panic!("scenes/tad.ron is synthetic");
        };
        let objects = synthetic.objects.clone();
        let dataset = Arc::new(tadgs::data::load(&scene.data).unwrap());
        let mut model = Trainer::new(&scene, dataset.clone()).model();
        let template = model.gaussians[0];
        let place = |mean: Vec3, time: f32| {
            let mut gaussian = template;
            gaussian.position.mean = mean.to_array();
            gaussian.temporal.center = time;
            gaussian
        };
        let (mut on_objects, mut on_floor) = (0, 0);
        model.gaussians.clear();
        for frame in [0, 20, 40] {
            let time = dataset.frame_time(frame);
            let present: Vec<Vec3> = objects
                .iter()
                .filter(|object| object.exists_at(time))
                .map(|object| object.position_at(time))
                .collect();
            for &centre in &present {
                model.gaussians.push(place(centre, time));
                on_objects += 1;
            }
            for i in 0..10 {
                for j in 0..10 {
                    let floor = Vec3::new(-2.25 + 0.5 * i as f32, 0.0, -2.25 + 0.5 * j as f32);
                    let flat = |p: Vec3| Vec3::new(p.x, 0.0, p.z);
                    if present.iter().all(|&c| flat(c).distance(floor) >= 2.0) {
                        model.gaussians.push(place(floor, time));
                        on_floor += 1;
                    }
                }
            }
        }
        model.gaussians.push(place(Vec3::new(0.0, 100.0, 0.0), 0.0));
        let run = tempfile::tempdir().unwrap();
        let text = ron::ser::to_string_pretty(&scene, Default::default()).unwrap();
        std::fs::write(run.path().join("scene.ron"), text).unwrap();
        model.save(&run.path().join("model.safetensors")).unwrap();

        let (classified, _) = analyse(run.path()).unwrap();
        let count = |region: Region| classified.iter().filter(|c| c.region == region).count();
        assert!(
            on_objects >= 6 && on_floor >= 30,
            "{on_objects} / {on_floor}"
        );
        assert_eq!(count(Region::Foreground), on_objects);
        assert_eq!(count(Region::Background), on_floor);
        assert_eq!(count(Region::Unseen), 1);
        // The classes follow the placement, not the storage order.
        for c in &classified {
            let expected = if c.mean.y > 50.0 {
                Region::Unseen
            } else if c.mean.y == 0.0 {
                Region::Background
            } else {
                Region::Foreground
            };
            assert_eq!(c.region, expected, "at {}", c.mean);
        }
    }

    #[test]
    fn quantiles_of_sorted_values() {
        let mut values = [3.0, 1.0, 2.0, 5.0, 4.0];
        assert_eq!(quantile(&mut values, 0.5), 3.0);
        assert_eq!(quantile(&mut values, 0.0), 1.0);
        assert_eq!(quantile(&mut values, 1.0), 5.0);
        assert!(quantile(&mut [], 0.5).is_nan());
    }
}
