//! A ready-made training loop: builds the world from a scene and a dataset, steps the training
//! schedule, renders and evaluates held-out views.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use rand::SeedableRng;

use crate::components::{
    Color, Fourier, GaussianParams, Opacity, Position, Rotation, Scale, Temporal,
};
use crate::data::init::{
    InitPoint, anchor_frames, nearest_neighbour_scales, random_points_in_view, scene_extent,
};
use crate::data::{Camera, Dataset};
use crate::io::image::Image;
use crate::metrics::psnr::{masked_psnr, psnr};
use crate::model::deform::{init_temporal_raw, logit};
use crate::model::sh::rgb_to_sh_dc;
use crate::raster::RenderOutput;
use crate::resources::*;
use crate::scene::SceneConfig;
use crate::systems::{render_schedule, training_schedule};

/// Makes bevy's compute task pool (used by `par_iter_mut`) once per process.
pub fn init_task_pool() {
    bevy_tasks::ComputeTaskPool::get_or_init(|| {
        bevy_tasks::TaskPoolBuilder::new()
            .num_threads(rayon::current_num_threads())
            .thread_name("tadgs".into())
            .build()
    });
}

/// Inserts every resource the tadgs systems read into `world`.
pub fn insert_resources(world: &mut World, scene: &SceneConfig, dataset: Arc<Dataset>) {
    init_task_pool();
    let settings = Settings::new(scene, dataset.frame_count, scene_extent(&dataset.cameras));
    let first = dataset.train.first();
    world.insert_resource(ViewSample {
        camera: first.map_or(dataset.cameras[0], |v| dataset.cameras[v.camera]),
        view: first.map(|_| 0),
        frame: first.map_or(0, |v| v.frame),
        time: first.map_or(0.0, |v| v.time),
    });
    world.insert_resource(settings);
    world.insert_resource(TrainState::default());
    world.insert_resource(TrainingViews(dataset));
    world.insert_resource(ViewOrder::default());
    world.insert_resource(Rng::seeded(scene.train.seed));
    world.insert_resource(match scene.train.backend {
        crate::scene::BackendKind::Cpu => Backend::Cpu,
    });
    world.insert_resource(SplatBuffers::default());
    world.insert_resource(LossImage::default());
}

/// Spawns the initial Gaussians: random points in the common view volume at every anchor frame.
pub fn spawn_initial_gaussians(world: &mut World, scene: &SceneConfig) -> usize {
    let settings = world.resource::<Settings>().clone();
    let dataset = world.resource::<TrainingViews>().0.clone();
    let train_cameras: Vec<Camera> = dataset
        .train_cameras()
        .iter()
        .map(|&c| dataset.cameras[c])
        .collect();
    let init = &scene.init;
    let temporal_scale = init_temporal_raw(
        settings.opacity,
        init.lifespan_half_frames,
        dataset.frame_count,
        &settings.warp,
    );
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(scene.train.seed ^ 0x5eed);
    let mut spawned = 0;
    for frame in anchor_frames(dataset.frame_count, init.anchor_spacing) {
        let points = random_points_in_view(&train_cameras, init.points_per_anchor, &mut rng);
        let center = dataset.frame_time(frame);
        spawned += points.len();
        spawn_points(world, &points, center, temporal_scale, init.opacity);
    }
    spawned
}

/// Spawns one Gaussian per point at temporal centre `center`.
pub fn spawn_points(
    world: &mut World,
    points: &[InitPoint],
    center: f32,
    temporal_scale: [f32; 2],
    opacity: f32,
) {
    let positions: Vec<glam::Vec3> = points.iter().map(|p| p.position).collect();
    let scales = nearest_neighbour_scales(&positions);
    let bundles: Vec<_> = points
        .iter()
        .zip(scales)
        .map(|(p, s)| {
            let mut color = Color::default();
            color.sh[0] = p.color.map(rgb_to_sh_dc);
            GaussianParams {
                position: Position {
                    mean: p.position.to_array(),
                },
                fourier: Fourier::default(),
                temporal: Temporal {
                    center,
                    scale: temporal_scale,
                },
                opacity: Opacity {
                    logit: logit(opacity),
                },
                rotation: Rotation {
                    c0: [1.0, 0.0, 0.0, 0.0],
                    c1: [0.0; 4],
                },
                scale: Scale {
                    d0: [s.ln(); 3],
                    d1: [0.0; 3],
                },
                color,
            }
            .bundle()
        })
        .collect();
    world.spawn_batch(bundles);
}

/// Metrics of one held-out view.
#[derive(Clone, Debug, PartialEq)]
pub struct ViewMetrics {
    pub camera: usize,
    pub frame: usize,
    pub psnr: f32,
    /// PSNR over the dynamic pixels (None where the mask is empty or absent).
    pub masked_psnr: Option<f32>,
}

/// A training run over one world: the schedules and the dataset.
pub struct Trainer {
    pub world: World,
    train: Schedule,
    render: Schedule,
}

impl Trainer {
    /// Builds a world from `scene` and `dataset` and spawns the initial Gaussians.
    pub fn new(scene: &SceneConfig, dataset: Arc<Dataset>) -> Self {
        let mut world = World::new();
        insert_resources(&mut world, scene, dataset);
        spawn_initial_gaussians(&mut world, scene);
        Self {
            world,
            train: training_schedule(),
            render: render_schedule(),
        }
    }

    /// Runs one training iteration.
    pub fn step(&mut self) {
        self.train.run(&mut self.world);
    }

    /// Counters of the run.
    pub fn state(&self) -> TrainState {
        *self.world.resource::<TrainState>()
    }

    /// Number of Gaussians alive.
    pub fn gaussian_count(&mut self) -> usize {
        self.world.query::<&Position>().iter(&self.world).len()
    }

    /// Renders the model from `camera` at normalised time `time`.
    pub fn render(&mut self, camera: &Camera, time: f32) -> RenderOutput {
        let frame = self.world.resource::<ViewSample>().frame;
        *self.world.resource_mut::<ViewSample>() = ViewSample {
            camera: *camera,
            view: None,
            frame,
            time,
        };
        self.render.run(&mut self.world);
        self.world.resource::<SplatBuffers>().render.clone()
    }

    /// Renders every held-out view and compares it with its ground truth.
    /// `on_view` sees each render next to its ground truth (for saving images).
    pub fn evaluate(
        &mut self,
        mut on_view: impl FnMut(&ViewMetrics, &Image, &Image),
    ) -> Vec<ViewMetrics> {
        let dataset = self.world.resource::<TrainingViews>().0.clone();
        let mut metrics = Vec::with_capacity(dataset.test.len());
        for view in &dataset.test {
            let out = self.render(&dataset.cameras[view.camera], view.time);
            let gt = view.to_image();
            let result = ViewMetrics {
                camera: view.camera,
                frame: view.frame,
                psnr: psnr(&out.image, &gt),
                masked_psnr: view
                    .dynamic_mask
                    .as_ref()
                    .and_then(|m| masked_psnr(&out.image, &gt, m)),
            };
            on_view(&result, &out.image, &gt);
            metrics.push(result);
        }
        metrics
    }
}

/// Mean of the finite values (None when there are none).
pub fn mean(values: impl Iterator<Item = f32>) -> Option<f32> {
    let (sum, n) = values
        .filter(|v| v.is_finite())
        .fold((0.0f64, 0usize), |(s, n), v| (s + v as f64, n + 1));
    (n > 0).then(|| (sum / n as f64) as f32)
}
