//! A ready-made training loop: builds the world from a scene and a dataset, steps the training
//! schedule, renders and evaluates held-out views.

use std::sync::Arc;

use bevy_ecs::prelude::*;
use rand::SeedableRng;

use crate::budget::{self, BudgetError, MemoryEstimate};
use crate::components::{
    Color, ColorRest, Fourier, GaussianParams, Opacity, Position, Rotation, Scale, Temporal,
    spawn_gaussians,
};
use crate::data::pointcloud::read_point_cloud;
use crate::data::{Camera, DataError, Dataset};
use crate::gpu::{GpuError, GpuTraining};
use crate::init::carve::{CarveError, CarvedPoints};
use crate::init::{InitPoint, anchor_points, nearest_neighbour_scales, scene_extent};
use crate::io::checkpoint::Checkpoint;
use crate::io::image::Image;
use crate::io::model::Model;
use crate::metrics::eval::{ViewScores, mean, score_view};
use crate::metrics::lpips::{Lpips, LpipsError};
use crate::metrics::psnr::psnr;
use crate::model::deform::{init_temporal_raw, lifespan_fraction, logit};
use crate::model::sh::rgb_to_sh_dc;
use crate::raster::RenderOutput;
use crate::report::TrainingLog;
use crate::resources::*;
use crate::scene::{InitMethod, SceneConfig};
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
///
/// With `backend: Gpu` this opens the GPU (see [`GpuTraining::open`]); that is the one way it
/// can fail.
pub fn insert_resources(
    world: &mut World,
    scene: &SceneConfig,
    dataset: Arc<Dataset>,
) -> Result<(), GpuError> {
    let first = dataset.train.first();
    let camera = first.map_or(dataset.cameras[0], |v| dataset.cameras[v.camera]);
    let extent = scene_extent(&dataset.scene_rig());
    insert_render_resources(world, scene, dataset.frame_count, extent, camera)?;
    *world.resource_mut::<ViewSample>() = ViewSample {
        camera,
        view: first.map(|_| 0),
        frame: first.map_or(0, |v| v.frame),
        time: first.map_or(0.0, |v| v.time),
        background: scene.train.background,
    };
    let train = &scene.train;
    if train.coarse_downscale > 1 && train.coarse_until > 0 {
        world.insert_resource(CoarseViews {
            views: Arc::new(dataset.downscaled_training_views(train.coarse_downscale)),
            until: train.coarse_until,
        });
    }
    if train.camera_exposure {
        world.insert_resource(CameraExposures::new(&dataset));
    }
    world.insert_resource(TrainingViews(dataset));
    world.insert_resource(ViewOrder::default());
    world.insert_resource(Rng::seeded(scene.train.seed));
    world.insert_resource(LossImage::default());
    world.insert_resource(NumericFault::default());
    world.insert_resource(ReadFault::default());
    Ok(())
}

/// Inserts the resources the render stages (time warp, deformation, splatting) read, for a
/// sequence of `frame_count` frames and a rig of the given extent, viewing from `camera` at
/// time 0. Enough to draw a trained model with [`render_schedule`] without a dataset. With
/// `backend: Gpu` this opens the GPU, the one way it can fail.
pub fn insert_render_resources(
    world: &mut World,
    scene: &SceneConfig,
    frame_count: usize,
    extent: f32,
    camera: Camera,
) -> Result<(), GpuError> {
    init_task_pool();
    world.insert_resource(Settings::new(scene, frame_count, extent));
    world.insert_resource(TrainState::default());
    world.insert_resource(ViewSample {
        camera,
        view: None,
        frame: 0,
        time: 0.0,
        background: scene.train.background,
    });
    // The systems tell the backends apart by the resources they find: `GpuTraining` runs the
    // whole iteration on the GPU, its absence the CPU schedule.
    if scene.train.backend == crate::scene::BackendKind::Gpu {
        // The whole iteration on the GPU with resident buffers; the blending-only
        // `GpuRasterizer` resource remains available to custom worlds.
        let gpu = GpuTraining::open(scene.train.gpu_float_atomics)?;
        tracing::info!("GPU backend: {}", gpu.describe());
        if gpu.is_software() {
            // A warning, so it shows under -q too: the run works but crawls.
            tracing::warn!(
                "the GPU backend runs on a software adapter, {}: expect it to be far slower \
                 than the CPU backend (`--backend cpu`); install the GPU's driver to use it",
                gpu.describe()
            );
        }
        world.insert_resource(gpu);
    }
    world.insert_resource(SplatBuffers::default());
    if let Some(config) = scene.model.shared_motion {
        // Zero bases; a model or checkpoint loaded into the world brings its own.
        world.insert_resource(SharedMotion::zeros(config));
    }
    Ok(())
}

/// With shared motion ([`SharedMotion`]), gives every Gaussian of `world` that lacks them its
/// weights of the bases, drawn with the world's [`Rng`] (see
/// [`crate::systems::densify::attach_motion_weights`]); nothing otherwise. The [`Trainer`]'s
/// constructors call it once the Gaussians are spawned.
pub fn attach_motion_weights_now(world: &mut World) {
    use bevy_ecs::system::RunSystemOnce;
    if world.contains_resource::<SharedMotion>() && world.contains_resource::<Rng>() {
        world
            .run_system_once(crate::systems::densify::attach_motion_weights)
            .expect("the system's resources are in the world");
        world.flush();
    }
}

/// A checkpoint does not fit the data it is resumed on.
#[derive(Debug, thiserror::Error)]
pub enum ResumeError {
    /// The checkpoint's saved view order names training view `index`, but the dataset has only
    /// `views` training views: the data changed since the checkpoint was written.
    #[error(
        "the checkpoint's view order refers to training view {index}, but the data has {views} \
         training views: the data changed since the checkpoint was written"
    )]
    ViewOrder {
        /// The out-of-range training-view index found in the view order.
        index: usize,
        /// Number of training views in the dataset resumed on.
        views: usize,
    },
    /// The checkpoint holds exposure corrections for `saved` cameras, but the data has
    /// `cameras`: the data changed since the checkpoint was written.
    #[error(
        "the checkpoint holds exposure corrections for {saved} cameras, but the data has \
         {cameras} cameras: the data changed since the checkpoint was written"
    )]
    ExposureCameras {
        /// Cameras in the checkpoint's exposure corrections.
        saved: usize,
        /// Cameras in the dataset resumed on.
        cameras: usize,
    },
    /// The checkpoint's backend could not be opened.
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// The initial Gaussians could not be made.
#[derive(Debug, thiserror::Error)]
pub enum InitError {
    /// Carving (`init.method: Carve`) produced no point cloud for an anchor frame.
    #[error("initialisation: {0}")]
    Carve(#[from] CarveError),
    /// The point-cloud file of `init.method: PointCloud(path)` could not be read.
    #[error("initialisation: {0}")]
    PointCloud(#[from] DataError),
    /// The initialisation method gave no points for an anchor frame.
    #[error("initialisation: no points for anchor frame {frame}")]
    Empty {
        /// The anchor frame index (not normalised time).
        frame: usize,
    },
    /// The initial Gaussians and the per-pixel buffers do not fit in the available memory.
    #[error("initialisation: {0}")]
    Memory(#[from] BudgetError),
    /// The scene asks for the GPU backend and no GPU rasterizer could be opened.
    #[error(transparent)]
    Gpu(#[from] GpuError),
}

/// Spawns the initial Gaussians: the points of `scene.init.method` at every anchor frame.
/// Returns how many were spawned.
pub fn spawn_initial_gaussians(world: &mut World, scene: &SceneConfig) -> Result<usize, InitError> {
    let settings = world.resource::<Settings>().clone();
    let dataset = world.resource::<TrainingViews>().0.clone();
    let init = &scene.init;
    let temporal_raw = |half_frames: f32, center: f32| {
        init_temporal_raw(
            settings.opacity,
            half_frames,
            dataset.frame_count,
            &settings.warp,
            center,
        )
    };
    let file_points = match &init.method {
        InitMethod::PointCloud(path) => Some(read_point_cloud(std::path::Path::new(path))?),
        _ => None,
    };
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(scene.train.seed ^ 0x5eed);
    let mut spawned = 0;
    for frame in dataset.anchor_frames(init.anchor_spacing) {
        let center = dataset.frame_time(frame);
        // Per anchor: a one-sided end window warps the lifespan differently at the ends.
        let temporal_scale = temporal_raw(init.lifespan_half_frames, center);
        let background_scale = init
            .background_lifespan_half_frames
            .map(|half_frames| temporal_raw(half_frames, center));
        let mut points = match &file_points {
            Some(points) => CarvedPoints::undivided(points.clone()),
            None => anchor_points(&dataset, frame, init, &mut rng)?,
        };
        // Without a lifespan of their own, background points are spawned with the others
        // (their nearest neighbours, and so their scales, looked up among all points).
        let groups = match background_scale {
            Some(scale) => vec![
                (points.foreground, temporal_scale),
                (points.background, scale),
            ],
            None => {
                points.foreground.append(&mut points.background);
                vec![(points.foreground, temporal_scale)]
            }
        };
        if groups.iter().all(|(points, _)| points.is_empty()) {
            return Err(InitError::Empty { frame });
        }
        for (points, scale) in groups {
            spawned += points.len();
            spawn_points(
                world,
                scene.model.sh_degree,
                &points,
                center,
                scale,
                init.opacity,
            );
        }
    }
    Ok(spawned)
}

/// Spawns one Gaussian per point at temporal centre `center`, for a model of SH degree
/// `sh_degree`.
pub fn spawn_points(
    world: &mut World,
    sh_degree: u32,
    points: &[InitPoint],
    center: f32,
    temporal_scale: [f32; 2],
    opacity: f32,
) {
    let positions: Vec<glam::Vec3> = points.iter().map(|p| p.position).collect();
    let scales = nearest_neighbour_scales(&positions);
    let gaussians = points.iter().zip(scales).map(|(p, s)| {
        let params = GaussianParams {
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
            color: Color {
                dc: p.color.map(rgb_to_sh_dc),
            },
            color_rest: ColorRest::default(),
        };
        (params.bundle(), params.optional_bundle())
    });
    spawn_gaussians(world, sh_degree, gaussians);
}

/// Logs the run's memory estimate and checks it against the available memory: an error
/// when the initial Gaussians do not fit, a lower population cap (with a warning) when
/// `densify.max_gaussians` does not (see [`crate::budget`]).
fn apply_memory_budget(
    world: &mut World,
    scene: &SceneConfig,
    dataset: &Dataset,
) -> Result<(), BudgetError> {
    let estimate = MemoryEstimate::new(scene, dataset);
    tracing::info!("{estimate}");
    let Some(available) = budget::available_memory() else {
        return Ok(());
    };
    let cap = estimate.check(available, budget::largest_camera(dataset))?;
    if cap < estimate.max_gaussians {
        tracing::warn!(
            "densify.max_gaussians lowered from {} to {cap}: more would not fit in the {:.2} GB \
             of memory available",
            estimate.max_gaussians,
            available as f64 / 1e9
        );
        world.resource_mut::<Settings>().densify.max_gaussians = cap as usize;
    }
    Ok(())
}

/// Why [`Trainer::evaluate`] could not score the held-out views.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// The LPIPS network failed.
    #[error(transparent)]
    Lpips(#[from] LpipsError),
    /// A held-out image could not be read (a streamed view whose file went missing).
    #[error(transparent)]
    Data(#[from] DataError),
}

/// Gaussians this many scene extents away from the cameras have diverged
/// ([`Trainer::diverged_count`]).
pub const DIVERGED_EXTENTS: f32 = 1000.0;

/// The scores of every held-out view and the time spent rendering them (metrics excluded).
#[derive(Clone, Debug, Default)]
pub struct Evaluation {
    /// The metrics of each held-out view, in the dataset's test order.
    pub scores: Vec<ViewScores>,
    /// Wall-clock seconds spent rendering all of them.
    pub render_seconds: f32,
}

impl Evaluation {
    /// Rendering speed in frames per second (rendering only).
    pub fn render_fps(&self) -> f32 {
        self.scores.len() as f32 / self.render_seconds.max(1e-9)
    }
}

/// A training run over one world: the schedules and the dataset.
pub struct Trainer {
    /// The ECS world: one entity per Gaussian plus the run's resources.
    pub world: World,
    train: Schedule,
    render: Schedule,
}

impl Trainer {
    /// Builds a world from `scene` and `dataset` and spawns the initial Gaussians; an
    /// initialisation that cannot run (a missing point-cloud file, masks that carve nothing
    /// with `Carve`) or a GPU backend without a GPU is an error.
    pub fn try_new(scene: &SceneConfig, dataset: Arc<Dataset>) -> Result<Self, InitError> {
        let mut world = World::new();
        insert_resources(&mut world, scene, dataset.clone())?;
        apply_memory_budget(&mut world, scene, &dataset)?;
        spawn_initial_gaussians(&mut world, scene)?;
        attach_motion_weights_now(&mut world);
        Ok(Self::with_world(world))
    }

    /// [`Trainer::try_new`] for scenes known to initialise (built-in scenes, tests).
    ///
    /// # Panics
    /// When the initialisation fails.
    pub fn new(scene: &SceneConfig, dataset: Arc<Dataset>) -> Self {
        Self::try_new(scene, dataset).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Builds a world from `scene` and `dataset` holding the Gaussians of a trained `model`
    /// (for evaluation, rendering, or training on from them); a GPU backend without a GPU is
    /// an error.
    pub fn try_from_model(
        scene: &SceneConfig,
        dataset: Arc<Dataset>,
        model: &Model,
    ) -> Result<Self, GpuError> {
        model.check_backend(scene.train.backend)?;
        let mut world = World::new();
        insert_resources(&mut world, scene, dataset)?;
        model.spawn_into(&mut world);
        world.resource_mut::<TrainState>().sh_degree = model.sh_degree;
        attach_motion_weights_now(&mut world);
        Ok(Self::with_world(world))
    }

    /// [`Trainer::try_from_model`] for the CPU backend (or a GPU known to be there).
    ///
    /// # Panics
    /// When the GPU backend cannot start.
    pub fn from_model(scene: &SceneConfig, dataset: Arc<Dataset>, model: &Model) -> Self {
        Self::try_from_model(scene, dataset, model).unwrap_or_else(|e| panic!("{e}"))
    }

    /// Continues a run from `checkpoint`: the world holds its Gaussians with their optimiser
    /// state, its counters, view order and RNG, so stepping on gives the same result as the
    /// run that wrote it. `dataset` must be the checkpoint scene's data.
    pub fn from_checkpoint(
        checkpoint: &Checkpoint,
        dataset: Arc<Dataset>,
    ) -> Result<Self, ResumeError> {
        let views = dataset.train.len();
        if let Some(&index) = checkpoint.state.view_order.iter().find(|&&i| i >= views) {
            return Err(ResumeError::ViewOrder { index, views });
        }
        if let Some(exposures) = &checkpoint.state.camera_exposures
            && exposures.cameras.len() != dataset.cameras.len()
        {
            return Err(ResumeError::ExposureCameras {
                saved: exposures.cameras.len(),
                cameras: dataset.cameras.len(),
            });
        }
        let mut world = World::new();
        insert_resources(&mut world, &checkpoint.state.scene, dataset)?;
        checkpoint.restore_into(&mut world);
        attach_motion_weights_now(&mut world);
        Ok(Self::with_world(world))
    }

    /// The run's full state for a checkpoint (`scene`: the settings it was started with).
    pub fn checkpoint(&mut self, scene: &SceneConfig, log: &TrainingLog) -> Checkpoint {
        self.sync();
        Checkpoint::from_world(&mut self.world, scene, log)
    }

    /// PSNR of the last training iteration's render against its training image.
    pub fn last_view_psnr(&self) -> f32 {
        let loss = self.world.resource::<LossImage>();
        // With exposure compensation the loss saw the corrected render.
        let render = if self.world.contains_resource::<CameraExposures>() {
            &loss.corrected
        } else {
            &self.world.resource::<SplatBuffers>().render.image
        };
        let target = &loss.target;
        if render.data.is_empty() || render.data.len() != target.data.len() {
            return f32::NAN;
        }
        psnr(render, target)
    }

    /// Normalised temporal lifespan ψ̄ of every Gaussian (see
    /// [`crate::model::deform::lifespan_fraction`]).
    pub fn lifespans(&mut self) -> Vec<f32> {
        self.sync();
        let settings = self.world.resource::<Settings>().clone();
        self.world
            .query::<&Temporal>()
            .iter(&self.world)
            .map(|t| lifespan_fraction(settings.opacity, t.scale, t.center, &settings.warp))
            .collect()
    }

    /// How many Gaussians have run away: their canonical position is not finite or lies
    /// farther than [`DIVERGED_EXTENTS`] scene extents from the training cameras' centre,
    /// where no scene has content. Non-zero means the learning rates are too high for the
    /// scene (the numeric guard only sees NaN and infinity).
    pub fn diverged_count(&mut self) -> usize {
        self.sync();
        // The centre of the cameras the extent was measured on.
        let rig = self.world.resource::<TrainingViews>().0.scene_rig();
        let centre = rig.iter().map(Camera::center).sum::<glam::Vec3>() / rig.len().max(1) as f32;
        let limit = DIVERGED_EXTENTS * self.world.resource::<Settings>().extent;
        self.world
            .query::<&Position>()
            .iter(&self.world)
            .filter(|p| !(glam::Vec3::from(p.mean).distance(centre) <= limit))
            .count()
    }

    fn with_world(world: World) -> Self {
        Self {
            world,
            train: training_schedule(),
            render: render_schedule(),
        }
    }

    /// Brings the components up to date with the GPU-resident pipeline (a no-op on the CPU
    /// backend): [`Trainer::checkpoint`], [`Trainer::model`] and [`Trainer::lifespans`] call
    /// it; call it before reading parameters, moments or statistics from [`Trainer::world`].
    ///
    /// # Panics
    /// If the GPU readback fails (the device was lost).
    pub fn sync(&mut self) {
        if let Err(e) = crate::systems::resident::sync_world(&mut self.world) {
            panic!("reading the GPU-resident training state back failed: {e}");
        }
    }

    /// Runs one training iteration.
    pub fn step(&mut self) {
        self.train.run(&mut self.world);
    }

    /// The numeric fault that stopped the optimisation, if any: once set, further steps
    /// leave every parameter as it is.
    pub fn fault(&self) -> Option<Fault> {
        self.world.resource::<NumericFault>().0
    }

    /// The training image that could not be read, if one stopped the run (a streamed view
    /// whose file went missing); [`Trainer::fault`] is then set too.
    pub fn read_failure(&self) -> Option<&ReadFailure> {
        self.world.resource::<ReadFault>().0.as_ref()
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
        let background = self.world.resource::<Settings>().train.background;
        *self.world.resource_mut::<ViewSample>() = ViewSample {
            camera: *camera,
            view: None,
            frame,
            time,
            background,
        };
        self.render.run(&mut self.world);
        self.world.resource::<SplatBuffers>().render.clone()
    }

    /// Renders every held-out view and scores it against its ground truth: PSNR and SSIM
    /// always, LPIPS when `lpips` is given, M-PSNR / M-SSIM where `masks` (one per held-out
    /// view, in `dataset.test` order; empty = none) has a mask. `on_view` sees each score with
    /// the render and the ground truth (for saving images and progress).
    pub fn evaluate(
        &mut self,
        lpips: Option<&Lpips>,
        masks: &[Option<Vec<bool>>],
        mut on_view: impl FnMut(&ViewScores, &Image, &Image),
    ) -> Result<Evaluation, EvalError> {
        let dataset = self.world.resource::<TrainingViews>().0.clone();
        let mut scores = Vec::with_capacity(dataset.test.len());
        let mut gt = Image::default();
        let mut render_seconds = 0.0;
        for (index, view) in dataset.test.iter().enumerate() {
            // A streamed next view is decoded while this one renders.
            if let Some(next) = dataset.test.get(index + 1) {
                next.image.prefetch();
            }
            let start = std::time::Instant::now();
            let out = self.render(&dataset.cameras[view.camera], view.time);
            render_seconds += start.elapsed().as_secs_f32();
            view.copy_image_into(&mut gt)?;
            let mask = masks
                .get(index)
                .and_then(Option::as_ref)
                .or(view.dynamic_mask.as_ref());
            let score = score_view(view, &out.image, &gt, mask.map(Vec::as_slice), lpips)?;
            on_view(&score, &out.image, &gt);
            scores.push(score);
        }
        Ok(Evaluation {
            scores,
            render_seconds,
        })
    }

    /// Mean PSNR over the held-out views (a quick check during training; a streamed view whose
    /// file cannot be read is left out with a warning, and reported by [`Trainer::evaluate`]).
    pub fn heldout_psnr(&mut self) -> Option<f32> {
        let dataset = self.world.resource::<TrainingViews>().0.clone();
        let mut gt = Image::default();
        let values: Vec<f32> = dataset
            .test
            .iter()
            .filter_map(|view| {
                if let Err(e) = view.copy_image_into(&mut gt) {
                    tracing::warn!("{e}");
                    return None;
                }
                let out = self.render(&dataset.cameras[view.camera], view.time);
                Some(psnr(&out.image, &gt))
            })
            .collect();
        mean(values.into_iter())
    }

    /// The trained Gaussians and the SH degree reached.
    pub fn model(&mut self) -> Model {
        self.sync();
        let sh_degree = self.state().sh_degree;
        let settings = self.world.resource::<Settings>();
        let (frame_count, config) = (settings.frame_count, settings.model.clone());
        let mut model = Model::from_world(&mut self.world, sh_degree);
        model.frame_count = Some(frame_count);
        model.config = Some(config);
        model
    }
}
