//! The fixed benchmark scene of the performance work and a per-stage timer, shared by the
//! criterion benches (`benches/`) and `tadgs bench`.
//!
//! Scene: N Gaussians from a seeded RNG, means x ~ U(−2, 2), y ~ U(−1.2, 1.2), z ~ U(2, 6);
//! normalised standard-normal quaternions; scales exp(U(−4.5, −2.5)) per axis; opacity
//! U(0.1, 0.9); colour U(0, 1) (SH degree 0). Camera: identity world-to-camera,
//! fx = fy = 0.8·W, principal point at the image centre, black background.

use std::sync::Arc;
use std::time::Instant;

use bevy_ecs::prelude::*;
use glam::Mat4;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::components::*;
use crate::data::{Camera, Dataset};
use crate::gpu::{GpuError, GpuTraining, profile};
use crate::io::image::Image;
use crate::model::deform::{FOURIER_TERMS, logit};
use crate::model::sh::rgb_to_sh_dc;
use crate::raster::PairCounts;
use crate::resources::{LossImage, Settings, SplatBuffers, TrainState, ViewSample};
use crate::scene::{BackendKind, DataSource, SceneConfig};
use crate::systems::{
    adam, backward, deform, densify, guard, loss, render_schedule, resident, sample_view, splat,
};
use crate::systems::{time_warp, training_schedule};
use crate::train::insert_resources;

/// The benchmark camera: identity pose, fx = fy = 0.8·W, centred principal point.
pub fn benchmark_camera(width: u32, height: u32) -> Camera {
    let f = 0.8 * width as f32;
    Camera {
        width,
        height,
        fx: f,
        fy: f,
        cx: 0.5 * width as f32,
        cy: 0.5 * height as f32,
        world_to_camera: Mat4::IDENTITY,
    }
}

/// The benchmark population of `n` Gaussians. Static ones are centred at t = 0 with a lifespan
/// long enough to be drawn at any time; with `motion`, the Fourier coefficients, phases,
/// temporal centres and widths are random too (for the deformation benches).
pub fn benchmark_gaussians(n: usize, seed: u64, motion: bool) -> Vec<GaussianParams> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let mut q = [0f32; 4];
            q.iter_mut().for_each(|c| *c = rng.sample(StandardNormal));
            let norm = q.iter().map(|c| c * c).sum::<f32>().sqrt();
            let color = Color {
                dc: [rng.random::<f32>(), rng.random(), rng.random()].map(rgb_to_sh_dc),
            };
            let mut params = GaussianParams {
                position: Position {
                    mean: [
                        rng.random_range(-2.0..2.0),
                        rng.random_range(-1.2..1.2),
                        rng.random_range(2.0..6.0),
                    ],
                },
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
            };
            if motion {
                let mut small = || [(); 3].map(|_| rng.random_range(-0.05..0.05));
                params.fourier = Fourier {
                    cos: [(); FOURIER_TERMS].map(|_| small()),
                    sin: [(); FOURIER_TERMS].map(|_| small()),
                    phase: [(); FOURIER_TERMS].map(|_| rng.random_range(0.0..6.3)),
                };
                // log ψ in [0, 4]: lifespans from most of the sequence down to a few frames.
                let log_psi = rng.random_range(0.0..4.0);
                params.temporal = Temporal {
                    center: rng.random_range(0.0..1.0),
                    scale: [log_psi, log_psi],
                };
                params.rotation.c1 = [(); 4].map(|_| rng.random_range(-0.1..0.1));
            }
            params
        })
        .collect()
}

/// A training world on the benchmark scene: `n` Gaussians, one `width × height` view of a fixed
/// target image, SH degree 0, no densification, on the CPU backend.
pub fn benchmark_world(n: usize, width: u32, height: u32, motion: bool) -> World {
    benchmark_world_on(n, width, height, motion, BackendKind::Cpu).expect("the CPU backend opens")
}

/// [`benchmark_world`] on `backend`; with [`BackendKind::Gpu`] the GPU-resident pipeline runs
/// the iteration (as `backend: Gpu` does in a scene file), which fails where no GPU opens.
pub fn benchmark_world_on(
    n: usize,
    width: u32,
    height: u32,
    motion: bool,
    backend: BackendKind,
) -> Result<World, GpuError> {
    benchmark_world_with(&benchmark_config(backend), n, width, height, motion)
}

/// The settings of the benchmark scene on `backend`: SH degree 0, no densification or opacity
/// resets, everything else the defaults.
pub fn benchmark_config(backend: BackendKind) -> SceneConfig {
    let mut config = SceneConfig::new(
        "bench",
        DataSource::Synthetic(crate::data::synthetic::demo_scene()),
    );
    config.model.sh_degree = 0;
    config.densify.from_iter = 0;
    config.densify.until_iter = 0;
    config.densify.opacity_reset_interval = 0;
    config.train.backend = backend;
    config
}

/// [`benchmark_world`] under the settings `config` (from [`benchmark_config`], possibly
/// changed: `tadgs bench --set`); its data source is ignored.
pub fn benchmark_world_with(
    config: &SceneConfig,
    n: usize,
    width: u32,
    height: u32,
    motion: bool,
) -> Result<World, GpuError> {
    let camera = benchmark_camera(width, height);
    let (w, h) = (width as usize, height as usize);
    let target = Image {
        width: w,
        height: h,
        data: (0..w * h)
            .map(|i| [((i % 97) as f32) / 97.0, 0.5, 0.3])
            .collect(),
    };
    let dataset = Dataset::single_camera(camera, 1, &target);
    let mut world = World::new();
    insert_resources(&mut world, config, Arc::new(dataset))?;
    let gaussians = benchmark_gaussians(n, 42, motion);
    spawn_gaussians(
        &mut world,
        config.model.sh_degree,
        gaussians
            .iter()
            .map(|g| (g.bundle(), g.optional_bundle()))
            .collect::<Vec<_>>(),
    );
    Ok(world)
}

/// Median times of one stage, in milliseconds.
#[derive(Clone, Debug)]
pub struct StageTime {
    /// Stage name as printed (sub-stages of splatting are indented by two spaces).
    pub stage: &'static str,
    /// Wall-clock time.
    pub ms: f64,
    /// CPU time of the whole process (all threads): the work done, which stays meaningful on a
    /// machine shared with other jobs, where the wall time also counts waiting.
    pub cpu_ms: f64,
}

/// What [`run`] measured.
#[derive(Clone, Debug)]
pub struct BenchReport {
    /// What was timed: the synthetic bench scene, or a scene's name.
    pub label: String,
    /// The training iteration the world was at when timing began.
    pub iteration: u32,
    /// The SH degree in use.
    pub sh_degree: u32,
    /// Number of Gaussians in the world.
    pub gaussians: usize,
    /// Width in pixels of the last view trained on.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// The backend that ran the iteration.
    pub backend: BackendKind,
    /// The GPU adapter, with the GPU backend.
    pub device: Option<String>,
    /// Splats drawn (projected inside the image); not read back from a GPU.
    pub visible: Option<usize>,
    /// (tile, splat) pairs.
    pub intersections: usize,
    /// Gaussian–pixel pairs evaluated and blended by the last render (CPU backend only).
    pub pairs: Option<PairCounts>,
    /// Median times per stage, in the order measured.
    pub stages: Vec<StageTime>,
    /// Bytes per Gaussian of its ECS components (parameters, gradients, Adam moments, state).
    pub component_bytes: usize,
    /// Whether the Gaussians hold gradient components (not under `train.fused_adam`).
    pub gradient_components: bool,
    /// Heap bytes per Gaussian of the per-iteration scratch buffers after warm-up.
    pub scratch_bytes: f64,
    /// Device time per kernel of the GPU stages, with [`profile`] on (else empty).
    pub kernels: Vec<KernelRow>,
}

/// One kernel's device time within a GPU stage of [`BenchReport`], per repeat.
#[derive(Clone, Debug)]
pub struct KernelRow {
    /// The stage that dispatched it.
    pub stage: &'static str,
    /// The kernel ("shader/entry point").
    pub kernel: String,
    /// Dispatches per repeat.
    pub passes: f64,
    /// Mean device time per repeat, milliseconds.
    pub ms: f64,
}

/// Heap bytes held by the splatting stage's buffers.
fn scratch_bytes(b: &SplatBuffers) -> usize {
    fn bytes<T>(v: &Vec<T>) -> usize {
        v.capacity() * std::mem::size_of::<T>()
    }
    bytes(&b.splats)
        + bytes(&b.splat_grads)
        + bytes(&b.deformed_grads)
        + bytes(&b.ndc_grad_norm)
        + bytes(&b.gradient_reached)
        + bytes(&b.render.image.data)
        + bytes(&b.render.alpha)
        + b.rasterizer.heap_bytes()
}

/// CPU time used so far by every thread of this process, in milliseconds (0 where unknown).
fn process_cpu_ms() -> f64 {
    #[cfg(unix)]
    {
        let mut ts = libc::timespec {
            tv_sec: 0,
            tv_nsec: 0,
        };
        // SAFETY: `ts` is a valid timespec for clock_gettime to write.
        if unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) } == 0 {
            return ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6;
        }
    }
    0.0
}

/// (wall, CPU) milliseconds of `f`.
fn time_ms(f: impl FnOnce()) -> (f64, f64) {
    let (start, cpu) = (Instant::now(), process_cpu_ms());
    f();
    (start.elapsed().as_secs_f64() * 1e3, process_cpu_ms() - cpu)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Wall and CPU milliseconds of each stage, in the order first recorded, and the kernel
/// times of the GPU stages summed over the repeats.
#[derive(Default)]
struct Samples(Vec<(&'static str, Vec<f64>, Vec<f64>)>, Vec<KernelRow>);

impl Samples {
    fn record(&mut self, stage: &'static str, (ms, cpu): (f64, f64)) {
        match self.0.iter_mut().find(|s| s.0 == stage) {
            Some(s) => {
                s.1.push(ms);
                s.2.push(cpu);
            }
            None => self.0.push((stage, vec![ms], vec![cpu])),
        }
    }

    /// Times `f` run once on `world`.
    fn stage(&mut self, world: &mut World, stage: &'static str, f: impl FnOnce(&mut World)) {
        self.record(stage, time_ms(|| f(world)));
    }

    /// Times `f` (which runs a GPU stage) on `world` until the device has finished its work.
    fn gpu_stage(
        &mut self,
        world: &mut World,
        stage: &'static str,
        f: impl FnOnce(&mut World) -> bevy_ecs::error::Result,
    ) -> Result<(), GpuError> {
        // Drop the passes of earlier work (the profile holds only this stage's).
        profile::take(world.resource::<GpuTraining>().context())?;
        let mut result = Ok(());
        let time = time_ms(|| {
            result = match f(world) {
                Ok(()) => world.resource::<GpuTraining>().wait(),
                Err(e) => Err(GpuError::Readback(e.to_string())),
            };
        });
        self.record(stage, time);
        result?;
        for kernel in profile::take(world.resource::<GpuTraining>().context())? {
            match self
                .1
                .iter_mut()
                .find(|row| row.stage == stage && row.kernel == kernel.kernel)
            {
                Some(row) => {
                    row.passes += kernel.passes as f64;
                    row.ms += kernel.ms;
                }
                None => self.1.push(KernelRow {
                    stage,
                    kernel: kernel.kernel,
                    passes: kernel.passes as f64,
                    ms: kernel.ms,
                }),
            }
        }
        Ok(())
    }

    /// The kernel rows as means over `repeats`.
    fn kernel_means(&self, repeats: usize) -> Vec<KernelRow> {
        let per = |v: f64| v / repeats as f64;
        self.1
            .iter()
            .map(|row| KernelRow {
                passes: per(row.passes),
                ms: per(row.ms),
                ..row.clone()
            })
            .collect()
    }

    fn medians(self) -> Vec<StageTime> {
        self.0
            .into_iter()
            .map(|(stage, wall, cpu)| StageTime {
                stage,
                ms: median(wall),
                cpu_ms: median(cpu),
            })
            .collect()
    }
}

/// Counts the iteration and samples the view.
fn sample(world: &mut World) {
    world
        .run_system_cached(sample_view::advance_iteration)
        .unwrap();
    world.run_system_cached(sample_view::sample_view).unwrap();
}

/// A stage's name and what runs it.
type Stage = (&'static str, fn(&mut World));

/// Runs the time-warp stage (on the CPU with either backend).
fn time_warp_stage(world: &mut World) {
    world.run_system_cached(time_warp::time_warp).unwrap();
}

/// Runs the loss stage (on the CPU with either backend).
fn loss_stage(world: &mut World) {
    world.run_system_cached(loss::loss).unwrap();
}

/// The CPU stages of one iteration, each timed on its own, then the splatting stage's parts
/// re-run on the buffers it just used.
fn time_cpu_stages(
    world: &mut World,
    guard: &mut Schedule,
    adam_only: &mut Schedule,
    catch_up: &mut Schedule,
    samples: &mut Samples,
) {
    let stages: [Stage; 7] = [
        ("sample view", sample),
        ("time warp", time_warp_stage),
        ("deform", |w| w.run_system_cached(deform::deform).unwrap()),
        ("splat (project + bin + blend)", |w| {
            w.run_system_cached(splat::splat).unwrap()
        }),
        ("loss (L1 + D-SSIM)", loss_stage),
        ("backward (raster + projection)", |w| {
            w.run_system_cached(backward::backward_splats).unwrap()
        }),
        ("backward (deformation)", |w| {
            w.run_system_cached(backward::backward_parameters).unwrap()
        }),
    ];
    let fused = world.resource::<Settings>().train.fuses_adam();
    for (stage, f) in stages {
        if fused && stage == "backward (deformation)" {
            // Part of the fused Adam pass, timed below.
            continue;
        }
        if stage == "deform" && world.resource::<Settings>().train.deferred_adam {
            // Deferred Adam's catch-up of the Gaussians the view can draw runs before them.
            samples.stage(world, "adam: catch-up before drawing", |w| catch_up.run(w));
        }
        samples.stage(world, stage, f);
    }
    if fused {
        samples.stage(world, "adam (fused: deformation backward + guard)", |w| {
            adam_only.run(w)
        });
    } else {
        samples.stage(world, "guard (finite gradients)", |w| guard.run(w));
        samples.stage(world, "adam", |w| adam_only.run(w));
    }
    samples.stage(world, "densification statistics", |w| {
        w.run_system_cached(densify::accumulate_stats).unwrap()
    });
    let camera = world.resource::<ViewSample>().camera;
    let (w, h) = (camera.width as usize, camera.height as usize);
    let train = &world.resource::<Settings>().train;
    let (near_plane, background) = (train.near_plane, train.background);
    let deformed = splat::deformed_by_slot(world);
    let mut buffers = world.resource_mut::<SplatBuffers>();
    let b = &mut *buffers;
    samples.record(
        "  project",
        time_ms(|| splat::project_all(&deformed, &camera, near_plane, &mut b.splats)),
    );
    samples.record(
        "  bin + depth sort",
        time_ms(|| b.rasterizer.bin(&b.splats, w, h)),
    );
    samples.record(
        "  blend",
        time_ms(|| b.rasterizer.blend(w, h, background, &mut b.render)),
    );
    let d_color = std::mem::take(&mut world.resource_mut::<LossImage>().d_color);
    let mut buffers = world.resource_mut::<SplatBuffers>();
    let b = &mut *buffers;
    samples.record(
        "  raster backward",
        time_ms(|| {
            b.rasterizer
                .backward(&b.splats, &d_color, w, &mut b.splat_grads)
        }),
    );
    world.resource_mut::<LossImage>().d_color = d_color;
}

/// The stages of one iteration on the GPU-resident pipeline, each timed until the device has
/// finished it.
fn time_gpu_stages(world: &mut World, samples: &mut Samples) -> Result<(), GpuError> {
    samples.stage(world, "sample view", sample);
    samples.stage(world, "time warp", time_warp_stage);
    samples.gpu_stage(world, "GPU deform … blend, image back", |w| {
        w.run_system_cached::<bevy_ecs::error::Result, _, _>(resident::resident_upload)
            .unwrap()?;
        w.run_system_cached(resident::resident_forward).unwrap()
    })?;
    samples.stage(world, "loss (L1 + D-SSIM)", loss_stage);
    samples.gpu_stage(world, "GPU backward + gradient check", |w| {
        w.run_system_cached(resident::resident_backward).unwrap()
    })?;
    samples.gpu_stage(world, "GPU adam", |w| {
        w.run_system_cached(resident::resident_adam).unwrap();
        Ok(())
    })?;
    samples.gpu_stage(world, "GPU densification statistics", |w| {
        w.run_system_cached(resident::resident_stats).unwrap();
        Ok(())
    })
}

/// Times every stage of a training iteration on the benchmark scene (`repeats` runs each, the
/// median reported), then a whole iteration and a render at a new time, under the settings
/// `config` (see [`benchmark_config`]).
pub fn run(
    config: &SceneConfig,
    n: usize,
    width: u32,
    height: u32,
    repeats: usize,
) -> Result<BenchReport, GpuError> {
    let world = benchmark_world_with(config, n, width, height, false)?;
    time_world(world, "synthetic bench scene", repeats)
}

/// Times the stages of a training iteration of `world` (a training world as
/// [`crate::train::Trainer`] builds it: a real scene's images, population, SH degree and
/// iteration), as [`run`] does for the benchmark scene. Densification and opacity resets are
/// switched off first so that every repeat times the same population.
pub fn time_world(mut world: World, label: &str, repeats: usize) -> Result<BenchReport, GpuError> {
    let repeats = repeats.max(1);
    {
        let mut settings = world.resource_mut::<Settings>();
        settings.densify.until_iter = 0;
        settings.densify.opacity_reset_interval = 0;
    }
    let backend = world.resource::<Settings>().train.backend;
    let iteration = world.resource::<TrainState>().iteration;
    let mut train = training_schedule();
    let mut guard_only = Schedule::default();
    guard_only.add_systems(guard::check_gradients());
    let mut adam_only = Schedule::default();
    adam_only.add_systems(adam::adam_systems());
    let mut catch_up = Schedule::default();
    catch_up.add_systems(adam::catch_up_systems());
    // Warm-up: buffers reach their size.
    train.run(&mut world);
    train.run(&mut world);

    let mut samples = Samples::default();
    for _ in 0..repeats {
        match backend {
            BackendKind::Cpu => time_cpu_stages(
                &mut world,
                &mut guard_only,
                &mut adam_only,
                &mut catch_up,
                &mut samples,
            ),
            BackendKind::Gpu => time_gpu_stages(&mut world, &mut samples)?,
        }
    }
    for _ in 0..repeats {
        samples.record("training iteration", time_ms(|| train.run(&mut world)));
    }
    let camera = world.resource::<ViewSample>().camera;
    let (width, height) = (camera.width, camera.height);
    let mut render = render_schedule();
    render.run(&mut world);
    for r in 0..repeats {
        world.resource_mut::<ViewSample>().time = 0.1 + 0.8 * r as f32 / repeats as f32;
        samples.record("render at a new time", time_ms(|| render.run(&mut world)));
    }

    let (device, visible, intersections, pairs) = match world.get_resource::<GpuTraining>() {
        Some(gpu) => (Some(gpu.describe()), None, gpu.intersections(), None),
        None => {
            let buffers = world.resource::<SplatBuffers>();
            let visible = buffers.splats.iter().filter(|s| s.visible).count();
            let pairs = buffers
                .rasterizer
                .pair_counts(width as usize, height as usize);
            let tile_pairs = buffers.rasterizer.intersections();
            (None, Some(visible), tile_pairs, Some(pairs))
        }
    };
    let gaussians = world.query::<&Position>().iter(&world).count();
    let sh_degree = world.resource::<TrainState>().sh_degree;
    let scratch = scratch_bytes(world.resource::<SplatBuffers>());
    let kernels = samples.kernel_means(repeats);
    let settings = world.resource::<Settings>();
    let gradient_components = !settings.train.fuses_adam();
    Ok(BenchReport {
        label: label.to_string(),
        iteration,
        sh_degree,
        gaussians,
        width,
        height,
        backend,
        device,
        visible,
        intersections,
        pairs,
        stages: samples.medians(),
        component_bytes: gaussian_bytes(settings.model.sh_degree, gradient_components),
        gradient_components,
        scratch_bytes: scratch as f64 / gaussians.max(1) as f64,
        kernels,
    })
}

impl BenchReport {
    /// The report as a plain-text table.
    pub fn table(&self) -> String {
        let pixels = self.width as usize * self.height as usize;
        let mut out = format!(
            "{:<32} {:>10} {:>10} {:>10} {:>10}\n",
            "stage", "ms", "CPU ms", "Gaussians", "pixels"
        );
        for s in &self.stages {
            out += &format!(
                "{:<32} {:>10.2} {:>10.2} {:>10} {:>10}\n",
                s.stage, s.ms, s.cpu_ms, self.gaussians, pixels
            );
        }
        let visible = match self.visible {
            Some(v) => format!(" ({v} visible)"),
            None => String::new(),
        };
        out += &format!(
            "\n{} × {}, {} Gaussians{visible}, {} tile-splat pairs, {:?} backend\n\
             {} at iteration {}, SH degree {} (densification paused while timing)\n",
            self.width,
            self.height,
            self.gaussians,
            self.intersections,
            self.backend,
            self.label,
            self.iteration,
            self.sh_degree
        );
        if let Some(device) = &self.device {
            out += &format!("GPU: {device}\n");
        }
        if let Some(pairs) = self.pairs {
            out += &self.pair_lines(pairs);
        }
        out += &format!(
            "memory per Gaussian: {} B of components ({}), {:.0} B of per-iteration buffers, \
             {:.0} B in all\n",
            self.component_bytes,
            if self.gradient_components {
                "parameters, gradients, Adam moments"
            } else {
                "parameters and Adam moments; `train.fused_adam` keeps no gradients"
            },
            self.scratch_bytes,
            self.component_bytes as f64 + self.scratch_bytes
        );
        if !self.kernels.is_empty() {
            out += &self.kernel_lines();
        }
        out
    }

    /// The device time per kernel of each GPU stage.
    fn kernel_lines(&self) -> String {
        let mut out = format!(
            "\nGPU kernels (device time from timestamp queries, mean per repeat):\n\
             {:<32} {:<36} {:>7} {:>10}\n",
            "stage", "kernel", "passes", "ms"
        );
        for row in &self.kernels {
            out += &format!(
                "{:<32} {:<36} {:>7.1} {:>10.2}\n",
                row.stage, row.kernel, row.passes, row.ms
            );
        }
        out
    }

    /// The Gaussian–pixel pairs of the render and the CPU time per pair of the blend and the
    /// raster backward (CPU time: the work per pair, whatever the number of threads).
    fn pair_lines(&self, pairs: PairCounts) -> String {
        let cpu_ms = |stage: &str| {
            self.stages
                .iter()
                .find(|s| s.stage.trim() == stage)
                .map_or(f64::NAN, |s| s.cpu_ms)
        };
        let ns_per = |ms: f64, count: u64| ms * 1e6 / count.max(1) as f64;
        let (blend, backward) = (cpu_ms("blend"), cpu_ms("raster backward"));
        format!(
            "Gaussian-pixel pairs: {:.1} M evaluated (pixel in the splat's screen box and still \
             blending), {:.1} M blended\n\
             CPU ns per pair: blend {:.2} per evaluated, {:.2} per blended; raster backward \
             {:.2} per blended\n",
            pairs.evaluated as f64 / 1e6,
            pairs.blended as f64 / 1e6,
            ns_per(blend, pairs.evaluated),
            ns_per(blend, pairs.blended),
            ns_per(backward, pairs.blended),
        )
    }
}
