//! The GPU Adam step and densification statistics equal the CPU systems
//! (`systems::adam::adam_step`, `systems::densify::accumulate_stats`), run in a bevy_ecs world
//! on the same random Gaussians.

#[path = "common/gpu.rs"]
mod gpu;

use bevy_ecs::prelude::*;
use bevy_ecs::system::RunSystemOnce;
use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use tadgs::components::{
    Adam, Color, ColorRest, Deformed, Fourier, Grad, GradAccum, Opacity, Param, Position, Rotation,
    Scale, SplatSlot, Temporal, WarpedTime,
};
use tadgs::data::Camera;
use tadgs::data::synthetic::demo_scene;
use tadgs::gpu::{GpuAdam, GpuContext, GpuParamGroup, GpuStats, StatsConfig};
use tadgs::model::deform::TemporalOpacity;
use tadgs::model::warp::TimeWarp;
use tadgs::raster::Splat;
use tadgs::resources::{Settings, SplatBuffers, TrainState, ViewSample};
use tadgs::scene::{BaselineViews, DataSource, SceneConfig};
use tadgs::systems::adam::{ParamGroup, adam_step, position_lr};
use tadgs::systems::densify::accumulate_stats;

/// Settings of the default scene for a 300-frame sequence of extent 2.
fn settings() -> Settings {
    let scene = SceneConfig::new("gpu", DataSource::Synthetic(demo_scene()));
    Settings::new(&scene, 300, 2.0)
}

fn random_values<P: Param>(rng: &mut ChaCha8Rng, range: f32) -> P {
    let mut p = P::default();
    for x in p.values_mut() {
        *x = rng.random_range(-range..range);
    }
    p
}

/// Largest |gpu − cpu| / (|cpu| + floor) over paired values.
fn worst_relative(gpu: &[f32], cpu: &[f32], floor: f32) -> f32 {
    gpu.iter()
        .zip(cpu)
        .map(|(g, c)| (g - c).abs() / (c.abs() + floor))
        .fold(0.0, f32::max)
}

/// Runs `steps` Adam steps of group `P` on the CPU system and on the GPU, each from the same
/// values, moments and gradients (gradients from 1e-8 to 1, some exactly zero; the GPU is
/// given the CPU's moments before each step, since it keeps them in `f32` and the CPU rounds
/// them to bfloat16), and returns the worst relative errors of the values, m and v over all
/// steps.
fn adam_parity<P: ParamGroup>(gpu: &GpuContext, adam: &GpuAdam, n: usize, steps: u32) -> [f32; 3] {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let settings = settings();
    let lr = settings.train.lr.clone();
    let (iterations, extent) = (settings.train.iterations, settings.extent);
    let mut world = World::new();
    world.insert_resource(settings);
    // At SH degree 3 every colour coefficient is active, so the CPU updates every slot the
    // GPU kernel does (below the top degree it leaves the zero-gradient ones alone).
    world.insert_resource(TrainState {
        sh_degree: 3,
        ..Default::default()
    });
    let entities: Vec<Entity> = (0..n)
        .map(|_| {
            let adam = Adam::<P>::new(&random_values(&mut rng, 1e-3), &P::default());
            world
                .spawn((random_values::<P>(&mut rng, 1.0), Grad(P::default()), adam))
                .id()
        })
        .collect();
    let stride = size_of::<P>() / 4;
    let gather = |world: &World| {
        let (mut x, mut m, mut v) = (Vec::new(), Vec::new(), Vec::new());
        for &e in &entities {
            x.extend_from_slice(world.get::<P>(e).unwrap().values());
            let adam = world.get::<Adam<P>>(e).unwrap();
            m.extend_from_slice(adam.m().values());
            v.extend_from_slice(adam.v().values());
        }
        (x, m, v)
    };
    let mut group = GpuParamGroup::new(gpu, stride);
    let mut worst = [0f32; 3];
    let (mut gx, mut gm, mut gv) = (Vec::new(), Vec::new(), Vec::new());
    // Start late in the run so the position rate has decayed, with the bias correction of a
    // few first steps too.
    for iteration in [1, 2, 3, 1000, 1001].into_iter().take(steps as usize) {
        let mut grads = Vec::with_capacity(n * stride);
        for &e in &entities {
            let mut g = P::default();
            for x in g.values_mut() {
                *x = match rng.random_range(0..10) {
                    0 => 0.0,
                    _ => rng.random_range(-1.0f32..1.0) * 10f32.powi(-rng.random_range(0..8)),
                };
            }
            grads.extend_from_slice(g.values());
            world.get_mut::<Grad<P>>(e).unwrap().0 = g;
        }
        let (x, m, v) = gather(&world);
        group.upload(&x, &m, &v);
        world.resource_mut::<TrainState>().iteration = iteration;
        world.run_system_once(adam_step::<P>).unwrap();
        group.upload_grads(&grads);
        let rates = P::learning_rates(&lr, position_lr(&lr, iteration, iterations, extent));
        adam.step(&mut group, rates.values(), iteration);
        group.read(&mut gx, &mut gm, &mut gv).unwrap();
        let (x, m, v) = gather(&world);
        // Moments may cancel to near zero: their floor is 1e-6 of the group's largest.
        let floor = |c: &[f32]| 1e-6 * c.iter().fold(0f32, |a, b| a.max(b.abs())) + 1e-30;
        worst[0] = worst[0].max(worst_relative(&gx, &x, 1e-30));
        worst[1] = worst[1].max(worst_relative(&gm, &m, floor(&m)));
        worst[2] = worst[2].max(worst_relative(&gv, &v, floor(&v)));
    }
    worst
}

/// Every parameter group (strides 1 to 48, per-slot rates, the decaying position rate, the
/// fixed temporal centre with rate 0) over five steps, and one group dispatched as a 2D grid:
/// values within 1e-6 relative of the CPU's; m and v within 2⁻⁷ relative, the largest spacing
/// of the CPU's bfloat16 moments (m rounded to nearest, v to either neighbour).
#[test]
fn gpu_adam_equals_cpu_adam_step() {
    let Some(ctx) = gpu::gpu_context() else {
        return;
    };
    tadgs::train::init_task_pool();
    let adam = GpuAdam::new(&ctx);
    let n = 3000;
    let results = [
        ("position", adam_parity::<Position>(&ctx, &adam, n, 5)),
        ("fourier", adam_parity::<Fourier>(&ctx, &adam, n, 5)),
        ("temporal", adam_parity::<Temporal>(&ctx, &adam, n, 5)),
        ("opacity", adam_parity::<Opacity>(&ctx, &adam, n, 5)),
        ("rotation", adam_parity::<Rotation>(&ctx, &adam, n, 5)),
        ("scale", adam_parity::<Scale>(&ctx, &adam, n, 5)),
        ("color", adam_parity::<Color>(&ctx, &adam, n, 5)),
        ("color_rest", adam_parity::<ColorRest>(&ctx, &adam, n, 5)),
    ];
    // Dispatches as 2D grids (as beyond 65 535 workgroups): 36 workgroups in rows of 2.
    tadgs::gpu::set_max_dispatch_width(2);
    let grid = (
        "position, 2D grid",
        adam_parity::<Position>(&ctx, &adam, n, 5),
    );
    tadgs::gpu::set_max_dispatch_width(65_535);
    for (name, [x, m, v]) in results.into_iter().chain([grid]) {
        eprintln!("adam {name}: worst relative error values {x:e}, m {m:e}, v {v:e}");
        assert!(
            x <= 1e-6 && m <= 1.0 / 128.0 && v <= 1.0 / 128.0,
            "{name}: values {x:e}, m {m:e}, v {v:e}"
        );
    }
}

/// One view's random inputs per slot: splats (10% invisible, radii up to 40 px), σ(t) (some
/// exactly at the minimum opacity 0.3), gradient norms.
fn random_view(rng: &mut ChaCha8Rng, n: usize) -> (Vec<Splat>, Vec<f32>, Vec<f32>) {
    let splats = (0..n)
        .map(|_| Splat {
            extent: Vec2::new(rng.random_range(0.0..40.0), rng.random_range(0.0..40.0)),
            visible: rng.random_bool(0.9),
            ..Default::default()
        })
        .collect();
    let opacity = (0..n)
        .map(|_| {
            if rng.random_bool(0.05) {
                0.3
            } else {
                rng.random_range(0.0..1.0)
            }
        })
        .collect();
    let grad_norm = (0..n).map(|_| rng.random_range(0.0..1e-3)).collect();
    (splats, opacity, grad_norm)
}

/// Temporal components for `model`: centres in [0, 1] (some at the ends), raw scales over the
/// range training produces plus extremes whose exponentials over- or underflow.
fn random_temporal(rng: &mut ChaCha8Rng, n: usize, model: TemporalOpacity) -> Vec<Temporal> {
    (0..n)
        .map(|_| {
            let center = match rng.random_range(0..10) {
                0 => 0.0,
                1 => 1.0,
                _ => rng.random_range(0.0..1.0),
            };
            let mut raw = || match rng.random_range(0..50) {
                0 => -200.0,
                1 => 200.0,
                _ => match model {
                    TemporalOpacity::Rbf => rng.random_range(-2.0..10.0),
                    TemporalOpacity::Asymmetric { .. } => rng.random_range(-2.0..4.0),
                },
            };
            Temporal {
                center,
                scale: [raw(), raw()],
            }
        })
        .collect()
}

/// `accumulate_stats` on the GPU equals the CPU system over three views at random times, for
/// VAD on and off, minimum opacity on and off, both temporal opacity models and the three time
/// warps (identity, TOW with centred and with one-sided end windows): counts and radii
/// exactly, the weighted gradient and weight sums within 1e-6 relative, the
/// gradient-weighted time offset within 1e-6 of Σw·g, the lifespan sums
/// (three lifespans in [0, 1]) within 1e-5 absolute: Vulkan lets `exp` err by 3 + 2|x| ulp,
/// about 2e-6 relative for the raw temporal scales of training, and the time warp's far slope
/// (0.3) magnifies that in the lifespan.
#[test]
fn gpu_stats_equal_cpu_accumulate_stats() {
    let Some(ctx) = gpu::gpu_context() else {
        return;
    };
    tadgs::train::init_task_pool();
    let mut stats = GpuStats::new(&ctx);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let n = 4000;
    let mut worst = [0f32; 4];
    let mut out = Vec::new();
    for vad in [false, true] {
        for min_opacity in [None, Some(0.3)] {
            for model in [TemporalOpacity::Rbf, TemporalOpacity::asymmetric(300)] {
                for warp in [
                    TimeWarp::Identity,
                    TimeWarp::tow(50.0, 300, 0.75),
                    TimeWarp::tow(50.0, 300, 0.75).with_one_sided_ends(true),
                    TimeWarp::tow(50.0, 300, 0.75).with_smooth_corners(true),
                    TimeWarp::tow(50.0, 300, 0.75)
                        .with_one_sided_ends(true)
                        .with_smooth_corners(true),
                ] {
                    // With VAD, dispatches as 2D grids (16 workgroups in rows of 3).
                    tadgs::gpu::set_max_dispatch_width(if vad { 3 } else { 65_535 });
                    let mut settings = settings();
                    settings.densify.vad = vad;
                    settings.densify.vad_min_opacity = min_opacity;
                    // The boxes uploaded here come from CPU splats, which carry no `faded`
                    // mark (the projection kernel sets it; tests/gpu_pipeline.rs checks that
                    // path): compare the count of drawn splats.
                    settings.densify.baseline_views = BaselineViews::Drawn;
                    (settings.opacity, settings.warp) = (model, warp);
                    let temporal = random_temporal(&mut rng, n, model);
                    // Slots in a shuffled order, so that slot ≠ spawn order.
                    let mut slots: Vec<u32> = (0..n as u32).collect();
                    for i in (1..n).rev() {
                        slots.swap(i, rng.random_range(0..=i));
                    }
                    let mut world = World::new();
                    world.insert_resource(settings.clone());
                    // Read only to count faded Gaussians, which `Drawn` does not.
                    world.insert_resource(ViewSample {
                        camera: Camera::look_at(Vec3::Z, Vec3::ZERO, Vec3::Y, 64, 64, 1.0),
                        view: None,
                        frame: 0,
                        time: 0.0,
                        background: [0.0; 3],
                    });
                    let entities: Vec<Entity> = slots
                        .iter()
                        .map(|&slot| {
                            world
                                .spawn((
                                    SplatSlot(slot),
                                    Deformed::default(),
                                    temporal[slot as usize],
                                    WarpedTime::default(),
                                    GradAccum::default(),
                                ))
                                .id()
                        })
                        .collect();
                    stats.reset(n);
                    for _view in 0..3 {
                        let (splats, opacity, grad_norm) = random_view(&mut rng, n);
                        let time: f32 = rng.random();
                        let config = StatsConfig::from_settings(&settings, time);
                        for (&e, &slot) in entities.iter().zip(&slots) {
                            world.get_mut::<Deformed>(e).unwrap().opacity = opacity[slot as usize];
                            world.get_mut::<WarpedTime>(e).unwrap().dt =
                                time - temporal[slot as usize].center;
                        }
                        world.insert_resource(SplatBuffers {
                            splats: splats.clone(),
                            ndc_grad_norm: grad_norm.clone(),
                            ..Default::default()
                        });
                        world.run_system_once(accumulate_stats).unwrap();
                        stats.accumulate(&config, &splats, &opacity, &grad_norm, &temporal);
                    }
                    stats.read_accum(&mut out).unwrap();
                    let case = format!("vad {vad}, min {min_opacity:?}, {model:?}, {warp:?}");
                    let mut counted = 0;
                    for (&e, &slot) in entities.iter().zip(&slots) {
                        let cpu = world.get::<GradAccum>(e).unwrap();
                        let gpu = &out[slot as usize];
                        assert_eq!(gpu.count, cpu.count, "{case}: slot {slot}");
                        assert_eq!(gpu.max_radius, cpu.max_radius, "{case}: slot {slot}");
                        counted += (cpu.count > 0) as usize;
                        let rel = |g: f32, c: f32| (g - c).abs() / (c.abs() + 1e-30);
                        let errors = [
                            rel(gpu.weighted_grad, cpu.weighted_grad),
                            rel(gpu.weight, cpu.weight),
                            (gpu.lifespan_sum - cpu.lifespan_sum).abs(),
                            // A sum of signed terms: relative to the sum of their sizes.
                            (gpu.weighted_offset - cpu.weighted_offset).abs()
                                / (cpu.weighted_grad + 1e-30),
                        ];
                        for (w, e) in worst.iter_mut().zip(errors) {
                            *w = w.max(e);
                        }
                        assert!(
                            errors[0] <= 1e-6
                                && errors[1] <= 1e-6
                                && errors[2] <= 1e-5
                                && errors[3] <= 1e-6,
                            "{case}: slot {slot}: GPU {gpu:?} vs CPU {cpu:?}"
                        );
                    }
                    assert!(counted > n / 2, "{case}: most Gaussians counted");
                }
            }
        }
    }
    tadgs::gpu::set_max_dispatch_width(65_535);
    eprintln!(
        "stats: worst relative error weighted gradient {:e}, weight {:e}; worst absolute \
         lifespan sum error {:e}; time offset error {:e} of Σw·g",
        worst[0], worst[1], worst[2], worst[3]
    );
}
