//! Render a trained model over time without any training system.
//!
//! Reads a run folder written by `tadgs train` (its `scene.ron` and `model.safetensors`),
//! builds a world with only the render resources and the render schedule (time warp,
//! deformation, splatting), and writes a time sweep from the first held-out camera as PNGs.
//!
//! ```text
//! cargo run --release -- train scenes/demo.ron --iterations 500 --output runs/demo-short
//! cargo run --release --example render_only -- runs/demo-short 12
//! ```

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use bevy_ecs::world::World;
use tadgs::init::scene_extent;
use tadgs::io::image::Image;
use tadgs::io::model::Model;
use tadgs::resources::{SplatBuffers, TrainState, ViewSample};
use tadgs::scene::load_scene;
use tadgs::systems::render_schedule;
use tadgs::train::insert_render_resources;

/// Renders `steps` evenly spaced times in [0, 1] from the first held-out camera of the run.
fn render_sweep(run: &Path, steps: usize) -> Result<Vec<(f32, Image)>> {
    let scene = load_scene(&run.join("scene.ron"))?;
    let model = Model::load(&run.join("model.safetensors"))?;
    // The dataset gives the cameras and the frame count; no image is used.
    let dataset = tadgs::data::load(&scene.data)?;
    let camera = dataset.cameras[*dataset
        .test_cameras()
        .first()
        .context("the run's dataset has no held-out camera")?];

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

    let mut schedule = render_schedule();
    let mut frames = Vec::with_capacity(steps);
    for step in 0..steps {
        let time = step as f32 / (steps.max(2) - 1) as f32;
        world.resource_mut::<ViewSample>().time = time;
        schedule.run(&mut world);
        frames.push((time, world.resource::<SplatBuffers>().render.image.clone()));
    }
    Ok(frames)
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let run = PathBuf::from(args.next().context("usage: render_only RUN_DIR [STEPS]")?);
    let steps = args.next().map(|s| s.parse()).transpose()?.unwrap_or(12);
    let out = run.join("sweep");
    std::fs::create_dir_all(&out)?;
    for (index, (time, image)) in render_sweep(&run, steps)?.iter().enumerate() {
        let path = out.join(format!("t{index:03}.png"));
        image.save_png(&path)?;
        println!("t = {time:.3} → {}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use tadgs::scene::{SceneConfig, apply_overrides};
    use tadgs::train::Trainer;

    use super::*;

    /// A model trained for 40 iterations, saved, loaded again and drawn by the render schedule
    /// alone gives the same pixels (to 1e-6) as the trainer's own render at each time.
    #[test]
    fn render_only_world_matches_the_trainer() {
        let mut scene: SceneConfig =
            load_scene(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/demo.ron")).unwrap();
        apply_overrides(
            &mut scene,
            &[
                "data.frames=6",
                "data.width=48",
                "data.height=36",
                "init.points_per_anchor=300",
            ],
        )
        .unwrap();
        let dataset = Arc::new(tadgs::data::load(&scene.data).unwrap());
        let mut trainer = Trainer::new(&scene, dataset.clone());
        for _ in 0..40 {
            trainer.step();
        }
        let run = tempfile::tempdir().unwrap();
        let text = ron::ser::to_string_pretty(&scene, Default::default()).unwrap();
        std::fs::write(run.path().join("scene.ron"), text).unwrap();
        trainer
            .model()
            .save(&run.path().join("model.safetensors"))
            .unwrap();

        let sweep = render_sweep(run.path(), 4).unwrap();
        let camera = dataset.cameras[dataset.test_cameras()[0]];
        for (time, image) in sweep {
            let expected = trainer.render(&camera, time).image;
            let worst = image
                .data
                .iter()
                .zip(&expected.data)
                .flat_map(|(a, b)| (0..3).map(move |c| (a[c] - b[c]).abs()))
                .fold(0.0f32, f32::max);
            assert!(worst <= 1e-6, "t = {time}: max difference {worst}");
        }
    }
}
