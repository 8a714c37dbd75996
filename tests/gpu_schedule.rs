//! The GPU backend inside the training schedule: the same systems, blending on the GPU
//! (`GpuRasterizer`), give the CPU backend's render and parameter gradients, and `backend: Gpu`
//! (the GPU-resident pipeline, `GpuTraining`) trains to the same quality as the CPU.

#[path = "common/demo.rs"]
mod demo;
#[path = "common/gpu.rs"]
mod gpu;

use std::sync::Arc;

use bevy_ecs::prelude::*;
use tadgs::components::*;
use tadgs::data::Dataset;
use tadgs::gpu::GpuRasterizer;
use tadgs::resources::{CameraExposures, SplatBuffers, TrainState, ViewSample};
use tadgs::scene::{BackendKind, SceneConfig};
use tadgs::systems::gradient_schedule;
use tadgs::train::{Trainer, insert_resources, spawn_initial_gaussians};

/// A small demo scene: 6 frames at 96×72 (6 × 5 tiles), 2 anchors × 400 random points.
fn small_scene() -> (SceneConfig, Arc<Dataset>) {
    demo::small_demo("gpu", 6, 96, 72, 400)
}

/// A world of the small scene on `backend`, looking at training view 5 with SH degree 3.
fn world_on(backend: BackendKind, config: &SceneConfig, dataset: &Arc<Dataset>) -> World {
    let mut config = config.clone();
    // The blending-only GPU path: `backend: Gpu` now opens the resident pipeline, which
    // leaves the gradients on the GPU (tests/gpu_pipeline.rs covers it).
    config.train.backend = BackendKind::Cpu;
    let mut world = World::new();
    insert_resources(&mut world, &config, dataset.clone()).expect("backend opens");
    if backend == BackendKind::Gpu {
        world.insert_resource(GpuRasterizer::new().expect("GPU opens"));
    }
    spawn_initial_gaussians(&mut world, &config).expect("random points initialise");
    world.resource_mut::<TrainState>().sh_degree = 3;
    let view = &dataset.train[5];
    *world.resource_mut::<ViewSample>() = ViewSample {
        camera: dataset.cameras[view.camera],
        view: Some(5),
        frame: view.frame,
        time: view.time,
        ..*world.resource::<ViewSample>()
    };
    world
}

/// Every gradient component of every Gaussian, flattened, in spawn order.
fn gradients(world: &mut World) -> Vec<(&'static str, Vec<f32>)> {
    fn field<P: Param + bytemuck::Pod>(
        world: &mut World,
        name: &'static str,
    ) -> (&'static str, Vec<f32>) {
        let mut rows: Vec<(Entity, Grad<P>)> = world
            .query::<(Entity, &Grad<P>)>()
            .iter(world)
            .map(|(e, g)| (e, *g))
            .collect();
        rows.sort_by_key(|(e, _)| *e);
        let values = rows
            .iter()
            .flat_map(|(_, g)| bytemuck::cast_slice::<P, f32>(std::slice::from_ref(&g.0)).to_vec())
            .collect();
        (name, values)
    }
    vec![
        field::<Position>(world, "position"),
        field::<Fourier>(world, "fourier"),
        field::<Temporal>(world, "temporal"),
        field::<Opacity>(world, "opacity"),
        field::<Rotation>(world, "rotation"),
        field::<Scale>(world, "scale"),
        field::<Color>(world, "color"),
        field::<ColorRest>(world, "color_rest"),
    ]
}

/// With the same Gaussians and view, the GPU backend's render equals the CPU's to 1e-4
/// relative (floor 1e-2 on values in [0, 1]) and every parameter gradient of every Gaussian
/// equals the CPU's to 1e-4 relative with a floor of 1e-4 × the largest value of that
/// component (the blending sums run in a different order; see tests/gpu_raster.rs), as do the
/// NDC gradient norms that densification uses.
#[test]
fn gpu_backend_gives_cpu_render_and_parameter_gradients() {
    if gpu::gpu_rasterizer(GpuRasterizer::new).is_none() {
        return;
    }
    let (config, dataset) = small_scene();
    let mut cpu = world_on(BackendKind::Cpu, &config, &dataset);
    let mut gpu = world_on(BackendKind::Gpu, &config, &dataset);
    gradient_schedule().run(&mut cpu);
    gradient_schedule().run(&mut gpu);

    let (c, g) = (
        cpu.resource::<SplatBuffers>(),
        gpu.resource::<SplatBuffers>(),
    );
    assert!(
        c.rasterizer.intersections() > 1000,
        "the view sees the Gaussians"
    );
    for (i, (a, b)) in g
        .render
        .image
        .data
        .iter()
        .zip(&c.render.image.data)
        .enumerate()
    {
        for ch in 0..3 {
            assert!(
                (a[ch] - b[ch]).abs() <= 1e-4 * (b[ch].abs() + 1e-2),
                "pixel {i}: GPU {a:?} vs CPU {b:?}"
            );
        }
    }
    let mut series = vec![(
        "ndc_grad_norm",
        g.ndc_grad_norm.clone(),
        c.ndc_grad_norm.clone(),
    )];
    for ((name, on_gpu), (_, on_cpu)) in gradients(&mut gpu).into_iter().zip(gradients(&mut cpu)) {
        series.push((name, on_gpu, on_cpu));
    }
    for (name, on_gpu, on_cpu) in series {
        assert_eq!(on_gpu.len(), on_cpu.len());
        let largest = on_cpu.iter().fold(0f32, |m, v| m.max(v.abs()));
        // Initial Gaussians are isotropic, so their rotation gradient is zero on both backends.
        assert!(
            largest > 0.0 || name == "rotation",
            "{name}: some gradient is non-zero"
        );
        for (i, (a, b)) in on_gpu.iter().zip(&on_cpu).enumerate() {
            assert!(
                (a - b).abs() <= 1e-4 * b.abs() + 1e-4 * largest,
                "{name}[{i}]: GPU {a} vs CPU {b}"
            );
        }
    }
}

/// Training the small scene for 80 iterations (densification included) on each backend ends
/// at the same held-out PSNR within 0.3 dB, and training improves it on both; also with
/// per-camera exposure compensation (whose loss gradient feeds the GPU's backward pass), where
/// the learnt corrections (learning rate 0.01) move from the identity by more than 0.005 and
/// agree between the two backends to 0.01.
#[test]
fn gpu_backend_trains_like_cpu_backend() {
    if gpu::gpu_rasterizer(GpuRasterizer::new).is_none() {
        return;
    }
    let (mut config, dataset) = small_scene();
    config.train.iterations = 80;
    config.densify.from_iter = 40;
    config.densify.interval = 40;
    config.train.lr.exposure = 0.01;
    for camera_exposure in [false, true] {
        config.train.camera_exposure = camera_exposure;
        let mut psnr = Vec::new();
        let mut exposures = Vec::new();
        for backend in [BackendKind::Cpu, BackendKind::Gpu] {
            config.train.backend = backend;
            let mut trainer = Trainer::new(&config, dataset.clone());
            let before = trainer.heldout_psnr().expect("held-out views");
            for _ in 0..config.train.iterations {
                trainer.step();
            }
            let after = trainer.heldout_psnr().expect("held-out views");
            eprintln!(
                "{backend:?}, exposure {camera_exposure}: held-out PSNR {before:.2} → {after:.2} dB"
            );
            assert!(after > before + 1.0, "{backend:?} trains");
            psnr.push(after);
            exposures.push(trainer.world.get_resource::<CameraExposures>().cloned());
        }
        assert!(
            (psnr[0] - psnr[1]).abs() <= 0.3,
            "exposure {camera_exposure}: CPU {:.2} dB vs GPU {:.2} dB",
            psnr[0],
            psnr[1]
        );
        let [cpu, gpu] = [&exposures[0], &exposures[1]];
        assert_eq!(cpu.is_some(), camera_exposure);
        if let (Some(cpu), Some(gpu)) = (cpu, gpu) {
            let moved = gpu.cameras.iter().flat_map(|c| c.exposure.values());
            assert!(moved.fold(0.0f32, |m, v| m.max(v.abs())) > 0.005);
            for (i, (a, b)) in cpu.cameras.iter().zip(&gpu.cameras).enumerate() {
                let (a, b) = (a.exposure.values(), b.exposure.values());
                for k in 0..6 {
                    assert!(
                        (a[k] - b[k]).abs() <= 0.01,
                        "camera {i}: CPU {a:?} vs GPU {b:?}"
                    );
                }
            }
        }
    }
}

/// Runs `tadgs -q train` on the small scene with `--backend gpu` and `WGPU_BACKEND=value`,
/// into the run folder `dir/name`; returns the process output and the run folder.
fn train_on_gpu_with(
    dir: &std::path::Path,
    name: &str,
    value: &str,
) -> (std::process::Output, std::path::PathBuf) {
    let (config, _) = small_scene();
    let scene = dir.join("small.ron");
    let text = ron::ser::to_string_pretty(&config, ron::ser::PrettyConfig::default()).unwrap();
    std::fs::write(&scene, text).unwrap();
    let run = dir.join(name);
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["-q", "train", scene.to_str().unwrap(), "--backend", "gpu"])
        .args(["--output", run.to_str().unwrap()])
        .env("WGPU_BACKEND", value)
        .output()
        .expect("the tadgs binary runs");
    (out, run)
}

/// `tadgs train --backend gpu` where no adapter exists (wgpu limited to a backend this
/// platform lacks) fails with one line that says so and suggests the CPU backend, after
/// recording the chosen backend in the run's scene.ron.
#[cfg(target_os = "linux")]
#[test]
fn gpu_backend_without_adapter_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let (out, run) = train_on_gpu_with(dir.path(), "run", "metal");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        stderr.contains("no GPU adapter found") && stderr.contains("backend: Cpu"),
        "{stderr}"
    );
    let saved = std::fs::read_to_string(run.join("scene.ron")).unwrap();
    assert!(saved.contains("backend: Gpu"), "{saved}");
}

/// An empty or misspelt `WGPU_BACKEND` (which asks wgpu for no backend at all) is an error
/// that names the variable and its value, and lists the backends it can name.
#[test]
fn unknown_wgpu_backend_names_the_variable() {
    let dir = tempfile::tempdir().unwrap();
    for value in ["", "vulcan"] {
        let (out, _) = train_on_gpu_with(dir.path(), &format!("run-{value}"), value);
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(
            stderr.contains(&format!("WGPU_BACKEND=\"{value}\" names no GPU backend"))
                && stderr.contains("vulkan, metal, dx12, gl"),
            "{stderr}"
        );
    }
}
