//! CPU against GPU (wgpu) on the fixed benchmark scene (see `tadgs::bench`) at 100k Gaussians
//! and 640×360: a whole training iteration on the CPU schedule and on the GPU-resident one
//! (`backend: Gpu`), and blending alone (forward + backward) on the CPU rasterizer and on each
//! GPU backward path. GPU benches are skipped with a message where no
//! adapter opens. On Mesa's lavapipe (a CPU driver) this checks that the GPU path runs, not
//! its speed.

use std::time::Duration;

use criterion::{
    BenchmarkGroup, Criterion, criterion_group, criterion_main, measurement::WallTime,
};
use tadgs::bench::{benchmark_world, benchmark_world_on};
use tadgs::gpu::{GpuError, GpuRasterizer, GpuTraining};
use tadgs::raster::{Rasterizer, RenderOutput};
use tadgs::resources::SplatBuffers;
use tadgs::scene::BackendKind;
use tadgs::systems::{render_schedule, training_schedule};

const N: usize = 100_000;
const WIDTH: u32 = 640;
const HEIGHT: u32 = 360;

/// Criterion's smallest sample (10 runs): on a software driver one run takes many seconds.
fn few_samples(group: &mut BenchmarkGroup<'_, WallTime>) {
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(5));
}

/// A whole training iteration (view, time warp, deformation, projection, binning, blending,
/// loss, backward, Adam, statistics) on each backend, after two warm-up iterations.
fn bench_iteration(c: &mut Criterion) {
    let mut group = c.benchmark_group("train_iteration_640x360");
    few_samples(&mut group);
    for (name, backend) in [
        ("cpu", BackendKind::Cpu),
        ("gpu_resident", BackendKind::Gpu),
    ] {
        let mut world = match benchmark_world_on(N, WIDTH, HEIGHT, false, backend) {
            Ok(world) => world,
            Err(e) => {
                eprintln!("skipping the {name} backend: {e}");
                continue;
            }
        };
        if let Some(gpu) = world.get_resource::<GpuTraining>() {
            eprintln!("GPU backend: {}", gpu.describe());
        }
        let mut schedule = training_schedule();
        schedule.run(&mut world);
        schedule.run(&mut world);
        group.bench_function(format!("{N}_gaussians_{name}"), |b| {
            b.iter(|| schedule.run(&mut world))
        });
    }
    group.finish();
}

fn bench_blending(c: &mut Criterion) {
    let mut world = benchmark_world(N, WIDTH, HEIGHT, false);
    render_schedule().run(&mut world);
    let splats = world.resource::<SplatBuffers>().splats.clone();
    let (width, height) = (WIDTH as usize, HEIGHT as usize);
    let d_color = vec![[1e-3f32, -2e-3, 5e-4]; width * height];
    let mut out = RenderOutput::default();
    let mut grads = Vec::new();
    let mut group = c.benchmark_group("blend_forward_backward_640x360");
    few_samples(&mut group);
    let mut cpu = Rasterizer::new();
    group.bench_function(format!("{N}_gaussians_cpu"), |b| {
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
        group.bench_function(format!("{N}_gaussians_{name}"), |b| {
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

// No plots: criterion's plotters text rendering panics when this crate's plotters (built
// with ab_glyph for the run reports) has no font registered; the figures are printed anyway.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = bench_iteration, bench_blending
}
criterion_main!(benches);
