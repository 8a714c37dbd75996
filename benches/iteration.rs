//! One training iteration (forward + loss + backward + Adam, no densification) at 640×360 on
//! the fixed benchmark population: N Gaussians from a seeded RNG, static, SH degree 0, on the
//! CPU backend and on the GPU backend (skipped with a message where no adapter opens).

use std::sync::Arc;

use bevy_ecs::prelude::*;
use criterion::{Criterion, criterion_group, criterion_main};
use glam::{Mat4, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use tadgs::components::*;
use tadgs::data::{Camera, Dataset};
use tadgs::gpu::{GpuError, GpuRasterizer};
use tadgs::io::image::Image;
use tadgs::model::deform::logit;
use tadgs::model::sh::rgb_to_sh_dc;
use tadgs::raster::{Rasterizer, RenderOutput};
use tadgs::resources::SplatBuffers;
use tadgs::scene::{BackendKind, DataSource, SceneConfig};
use tadgs::systems::training_schedule;
use tadgs::train::insert_resources;

const WIDTH: u32 = 640;
const HEIGHT: u32 = 360;

fn camera() -> Camera {
    Camera {
        width: WIDTH,
        height: HEIGHT,
        fx: 500.0,
        fy: 500.0,
        cx: 320.0,
        cy: 180.0,
        world_to_camera: Mat4::IDENTITY,
    }
}

/// The benchmark population: means x ~ U(−2, 2), y ~ U(−1.2, 1.2), z ~ U(2, 6); normalised
/// standard-normal quaternions; scales exp(U(−4.5, −2.5)); opacity U(0.1, 0.9); colour U(0, 1).
fn benchmark_gaussians(n: usize, seed: u64) -> Vec<GaussianParams> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut q = [0f32; 4];
            q.iter_mut().for_each(|c| *c = rng.sample(StandardNormal));
            let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
            let mut color = Color::default();
            color.sh[0] = [rng.random::<f32>(), rng.random(), rng.random()].map(rgb_to_sh_dc);
            GaussianParams {
                position: Position {
                    mean: Vec3::new(
                        rng.random_range(-2.0..2.0),
                        rng.random_range(-1.2..1.2),
                        rng.random_range(2.0..6.0),
                    )
                    .to_array(),
                },
                // Centred at t = 0 with a long lifespan, so every Gaussian is drawn.
                temporal: Temporal {
                    center: 0.0,
                    scale: [-10.0, -10.0],
                },
                opacity: Opacity {
                    logit: logit(rng.random_range(0.1..0.9)),
                },
                rotation: Rotation {
                    c0: q.map(|c| c / norm),
                    c1: [0.0; 4],
                },
                scale: Scale {
                    d0: [(); 3].map(|_| rng.random_range(-4.5..-2.5)),
                    d1: [0.0; 3],
                },
                color,
                ..Default::default()
            }
        })
        .collect()
}

/// The benchmark world on `backend`, or None when that backend cannot start.
fn world_with(n: usize, backend: BackendKind) -> Option<World> {
    let cam = camera();
    let target: Vec<[f32; 3]> = (0..(WIDTH * HEIGHT) as usize)
        .map(|i| [((i % 97) as f32) / 97.0, 0.5, 0.3])
        .collect();
    let image = Image {
        width: WIDTH as usize,
        height: HEIGHT as usize,
        data: target,
    };
    let dataset = Dataset::single_camera(cam, 1, &image);
    let mut config = SceneConfig::new(
        "bench",
        DataSource::Synthetic(tadgs::data::synthetic::demo_scene()),
    );
    config.model.sh_degree = 0;
    config.densify.until_iter = 0; // no densification
    config.densify.opacity_reset_interval = 0;
    config.train.backend = backend;
    let mut world = World::new();
    if let Err(e) = insert_resources(&mut world, &config, Arc::new(dataset)) {
        eprintln!("skipping the {backend:?} backend: {e}");
        return None;
    }
    world.spawn_batch(
        benchmark_gaussians(n, 42)
            .into_iter()
            .map(GaussianParams::bundle)
            .collect::<Vec<_>>(),
    );
    Some(world)
}

fn bench_iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("train_iteration_640x360");
    group.sample_size(10);
    for n in [100_000usize] {
        for (backend, name) in [(BackendKind::Cpu, "cpu"), (BackendKind::Gpu, "gpu")] {
            let Some(mut world) = world_with(n, backend) else {
                continue;
            };
            if let Some(gpu) = world.get_resource::<tadgs::gpu::GpuRasterizer>() {
                eprintln!("GPU backend: {}", gpu.describe());
            }
            let mut schedule = training_schedule();
            schedule.run(&mut world); // warm-up: buffers reach their size
            group.bench_function(format!("{n}_gaussians_{name}"), |b| {
                b.iter(|| schedule.run(&mut world))
            });
        }
    }
    group.finish();
}

/// Blending alone (forward + backward, the splats of the benchmark population at 640×360) on
/// the CPU rasterizer and on each GPU backward path.
fn bench_blending(c: &mut Criterion) {
    let n = 100_000;
    let Some(mut world) = world_with(n, BackendKind::Cpu) else {
        return;
    };
    tadgs::systems::render_schedule().run(&mut world);
    let splats = world.resource::<SplatBuffers>().splats.clone();
    let (width, height) = (WIDTH as usize, HEIGHT as usize);
    let d_color = vec![[1e-3f32, -2e-3, 5e-4]; width * height];
    let mut out = RenderOutput::default();
    let mut grads = Vec::new();
    let mut group = c.benchmark_group("blend_forward_backward_640x360");
    group.sample_size(10);
    let mut cpu = Rasterizer::new();
    group.bench_function(format!("{n}_gaussians_cpu"), |b| {
        b.iter(|| {
            cpu.forward(&splats, width, height, [0.0; 3], &mut out);
            cpu.backward(&splats, &d_color, width, &mut grads);
        })
    });
    let open: [(&str, fn() -> Result<GpuRasterizer, GpuError>); 2] = [
        ("gpu_default", GpuRasterizer::new),
        ("gpu_tile_sums", GpuRasterizer::portable),
    ];
    for (name, open) in open {
        let mut gpu = match open() {
            Ok(gpu) => gpu,
            Err(e) => {
                eprintln!("skipping {name}: {e}");
                continue;
            }
        };
        eprintln!("{name}: {}", gpu.describe());
        group.bench_function(format!("{n}_gaussians_{name}"), |b| {
            b.iter(|| {
                gpu.forward(&splats, width, height, [0.0; 3], &mut out)
                    .expect("GPU forward");
                gpu.backward(&splats, &d_color, &mut grads)
                    .expect("GPU backward");
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench_iteration, bench_blending);
criterion_main!(benches);
