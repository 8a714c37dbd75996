//! Criterion benches of the CPU backend on the fixed benchmark scene (see `tadgs::bench`):
//! every stage of a training iteration, a whole iteration and a render at a new time, at
//! 100k Gaussians and 640×360.
//!
//! `TADGS_BENCH_SWEEP=1 cargo bench --bench iteration` adds the sweep over 10k / 100k / 1M
//! Gaussians × 320×180 / 640×360 / 1280×720 (forward and backward rasterization, and whole
//! iterations), which takes several minutes.

use std::time::Duration;

use bevy_ecs::prelude::*;
use criterion::{
    BenchmarkGroup, Criterion, criterion_group, criterion_main, measurement::WallTime,
};
use tadgs::bench::benchmark_world;
use tadgs::resources::{LossImage, SplatBuffers, ViewSample};
use tadgs::systems::{adam, backward, deform, render_schedule, splat, training_schedule};

fn short(group: &mut BenchmarkGroup<'_, WallTime>) {
    group.sample_size(10);
    group.warm_up_time(Duration::from_secs(1));
    group.measurement_time(Duration::from_secs(3));
}

/// A world at 100k / 640×360 after two training iterations (buffers at their size).
fn warm_world(n: usize, width: u32, height: u32, motion: bool) -> World {
    let mut world = benchmark_world(n, width, height, motion);
    let mut train = training_schedule();
    train.run(&mut world);
    train.run(&mut world);
    world
}

fn stages(c: &mut Criterion) {
    let (n, w, h) = (100_000, 640, 360);
    let mut group = c.benchmark_group("stage_100k_640x360");
    short(&mut group);

    // Deformation of a moving population (random Fourier motion, temporal centres and widths).
    let mut moving = warm_world(n, w, h, true);
    group.bench_function("deform", |b| {
        b.iter(|| moving.run_system_cached(deform::deform).unwrap())
    });

    let mut world = warm_world(n, w, h, false);
    let camera = world.resource::<ViewSample>().camera;
    let (wu, hu) = (w as usize, h as usize);
    let deformed = splat::deformed_by_slot(&mut world);
    group.bench_function("project_and_bin", |b| {
        b.iter(|| {
            let mut buffers = world.resource_mut::<SplatBuffers>();
            let buffers = &mut *buffers;
            splat::project_all(&deformed, &camera, 0.01, &mut buffers.splats);
            buffers.rasterizer.bin(&buffers.splats, wu, hu);
        })
    });
    group.bench_function("forward_blend", |b| {
        b.iter(|| {
            let mut buffers = world.resource_mut::<SplatBuffers>();
            let buffers = &mut *buffers;
            buffers
                .rasterizer
                .blend(wu, hu, [0.0; 3], &mut buffers.render);
        })
    });
    group.bench_function("loss", |b| {
        b.iter(|| world.run_system_cached(tadgs::systems::loss::loss).unwrap())
    });
    group.bench_function("backward_raster", |b| {
        let d_color = world.resource::<LossImage>().d_color.clone();
        b.iter(|| {
            let mut buffers = world.resource_mut::<SplatBuffers>();
            let buffers = &mut *buffers;
            buffers
                .rasterizer
                .backward(&buffers.splats, &d_color, wu, &mut buffers.splat_grads);
        })
    });
    group.bench_function("backward_projection_and_deformation", |b| {
        b.iter(|| {
            let splats: bevy_ecs::error::Result =
                world.run_system_cached(backward::backward_splats).unwrap();
            splats.unwrap();
            world
                .run_system_cached(backward::backward_parameters)
                .unwrap();
        })
    });
    let mut adam_only = Schedule::default();
    adam_only.add_systems(adam::adam_systems());
    group.bench_function("adam", |b| b.iter(|| adam_only.run(&mut world)));

    let mut train = training_schedule();
    group.bench_function("training_iteration", |b| b.iter(|| train.run(&mut world)));
    let mut render = render_schedule();
    let mut t = 0.0f32;
    group.bench_function("render_at_new_time", |b| {
        b.iter(|| {
            t = (t + 0.37) % 1.0;
            world.resource_mut::<ViewSample>().time = t;
            render.run(&mut world);
        })
    });
    group.finish();
}

fn sweep(c: &mut Criterion) {
    if std::env::var_os("TADGS_BENCH_SWEEP").is_none() {
        return;
    }
    let mut group = c.benchmark_group("sweep");
    short(&mut group);
    for n in [10_000usize, 100_000, 1_000_000] {
        for (w, h) in [(320u32, 180u32), (640, 360), (1280, 720)] {
            let mut world = warm_world(n, w, h, false);
            let mut train = training_schedule();
            let mut render = render_schedule();
            group.bench_function(format!("render/{n}/{w}x{h}"), |b| {
                b.iter(|| render.run(&mut world))
            });
            group.bench_function(format!("iteration/{n}/{w}x{h}"), |b| {
                b.iter(|| train.run(&mut world))
            });
        }
    }
    group.finish();
}

// No plots: criterion's plotters text rendering panics when this crate's plotters (built
// with ab_glyph for the run reports) has no font registered; the figures are printed anyway.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = stages, sweep
}
criterion_main!(benches);
