//! Resources shared by the training systems: settings, counters, the sampled view and the
//! per-iteration scratch buffers (reused, never reallocated once warm).

use std::sync::Arc;

use bevy_ecs::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::data::{Camera, Dataset};
use crate::metrics::loss::{LossScratch, LossValue};
use crate::model::deform::{MotionBasis, TemporalOpacity};
use crate::model::exposure::Exposure;
use crate::model::shared_motion::MotionBases;
use crate::model::warp::TimeWarp;
use crate::raster::{Rasterizer, RenderOutput, Splat, SplatGrad};
use crate::scene::{
    DensifyConfig, ModelConfig, OpacityModel, PhaseModel, SceneConfig, SharedMotionConfig,
    TrainConfig,
};

/// Settings of a run, resolved from the scene file and the dataset.
#[derive(Resource, Clone, Debug)]
pub struct Settings {
    /// The scene's deformation-model options.
    pub model: ModelConfig,
    /// The scene's densification options (VAD, TAT, thresholds, schedule).
    pub densify: DensifyConfig,
    /// The scene's training options (iterations, learning rates, SSIM weight, background).
    pub train: TrainConfig,
    /// Number of frames T of the sequence.
    pub frame_count: usize,
    /// Scene extent (radius of the camera rig × 1.1, as in 3DGS); scales learning rates and
    /// densification sizes.
    pub extent: f32,
    /// The temporal warp W (identity when TOW is off).
    pub warp: TimeWarp,
    /// The temporal opacity form.
    pub opacity: TemporalOpacity,
}

impl Settings {
    /// Resolves a scene's settings for a sequence of `frame_count` frames with the given extent.
    pub fn new(scene: &SceneConfig, frame_count: usize, extent: f32) -> Self {
        let tow = scene.model.tow;
        // Debug, not a warning: short sequences meet this with the default window, and
        // nothing is wrong with the run.
        if tow.enabled && tow.window_frames >= frame_count as f32 {
            tracing::debug!(
                "model.tow.window_frames = {} covers all {frame_count} frames: the warp is the \
                 identity, so TOW has no effect on this sequence",
                tow.window_frames
            );
        }
        let warp = if tow.enabled {
            TimeWarp::tow(tow.window_frames, frame_count, tow.rho)
                .with_one_sided_ends(tow.one_sided_ends)
                .with_smooth_corners(tow.smooth)
        } else {
            TimeWarp::Identity
        };
        let opacity = match scene.model.opacity {
            OpacityModel::Rbf => TemporalOpacity::Rbf,
            OpacityModel::Asymmetric => TemporalOpacity::asymmetric(frame_count),
        };
        Self {
            model: scene.model.clone(),
            densify: scene.densify.clone(),
            train: scene.train.clone(),
            frame_count,
            extent,
            warp,
            opacity,
        }
    }

    /// How the Fourier motion reads time (phase layout and period).
    pub fn motion_basis(&self) -> MotionBasis {
        MotionBasis {
            shared_phase: self.model.phase == PhaseModel::PerGaussian,
            period: self.model.motion_period,
        }
    }
}

/// Counters of the run.
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct TrainState {
    /// The iteration being run, from 1 (0 before the first).
    pub iteration: u32,
    /// SH degree currently in use (raised on a schedule up to the model's degree).
    pub sh_degree: u32,
    /// Loss of the last iteration.
    pub loss: LossValue,
    /// Gaussians added and removed by the last densification step.
    pub last_densify: DensifyReport,
}

/// What a densification step did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DensifyReport {
    /// Iteration at which the step ran (0: no step yet).
    pub iteration: u32,
    /// Gaussians cloned (each adds one Gaussian).
    pub cloned: usize,
    /// Gaussians split in two (each adds one Gaussian).
    pub split: usize,
    /// Gaussians removed by pruning.
    pub pruned: usize,
}

/// The training images and cameras.
#[derive(Resource, Clone)]
pub struct TrainingViews(pub Arc<Dataset>);

/// Coarse-to-fine training (`train.coarse_downscale`): the training views at a lower
/// resolution, used by iterations up to `until`; later ones use [`TrainingViews`].
#[derive(Resource, Clone, Debug)]
pub struct CoarseViews {
    /// The downscaled training views and cameras (no held-out views).
    pub views: Arc<Dataset>,
    /// Last iteration trained on them.
    pub until: u32,
}

/// The dataset whose training views iteration `iteration` trains on.
pub fn views_at<'a>(
    full: &'a TrainingViews,
    coarse: Option<&'a CoarseViews>,
    iteration: u32,
) -> &'a Dataset {
    match coarse {
        Some(coarse) if iteration <= coarse.until => &coarse.views,
        _ => &full.0,
    }
}

/// The view of the current iteration.
#[derive(Resource, Clone, Copy, Debug)]
pub struct ViewSample {
    /// The camera to render from (OpenCV convention).
    pub camera: Camera,
    /// Index into the dataset's training views, when the view is one of them.
    pub view: Option<usize>,
    /// Frame index in the sequence, from 0.
    pub frame: usize,
    /// Normalised time in [0, 1].
    pub time: f32,
    /// Colour the render is composited over: `train.background`, or this iteration's random
    /// colour with `train.random_background` (the truth is then recomposited over it too).
    pub background: [f32; 3],
}

/// Random order of the training views (indices into the dataset's `train`), reshuffled every
/// epoch.
#[derive(Resource, Clone, Debug, Default)]
pub struct ViewOrder {
    /// The current epoch's permutation of the training-view indices.
    pub order: Vec<usize>,
    /// Position in `order` of the next view to sample; a new epoch starts at the end.
    pub next: usize,
    /// Loss of each training view when last drawn (None before its first draw), which
    /// `train.repeat_hard_views` ranks; empty when that is off.
    pub losses: Vec<Option<f32>>,
}

/// The run's single source of randomness (same seed, same run).
#[derive(Resource, Clone, Debug)]
pub struct Rng(pub ChaCha8Rng);

impl Rng {
    /// A ChaCha8 generator seeded with `seed`.
    pub fn seeded(seed: u64) -> Self {
        Self(ChaCha8Rng::seed_from_u64(seed))
    }
}

/// A NaN or infinity found by the numeric guard (`systems::guard`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Fault {
    /// The iteration whose backward pass produced it.
    pub iteration: u32,
    /// The parameter group whose gradient is not finite (`"loss"` for the loss itself).
    pub group: &'static str,
    /// Index (in query order) of the first Gaussian with a non-finite gradient in that group.
    pub gaussian: Option<usize>,
}

impl std::fmt::Display for Fault {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.gaussian {
            Some(i) => write!(
                f,
                "iteration {}: non-finite gradient of the {} parameters (Gaussian #{i})",
                self.iteration, self.group
            ),
            None => write!(
                f,
                "iteration {}: the {} is not finite",
                self.iteration, self.group
            ),
        }
    }
}

/// A training image that could not be read (a streamed view whose file went missing or
/// changed): the iteration and the error.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ReadFailure {
    /// The iteration that needed the image.
    pub iteration: u32,
    /// The read error, naming the file.
    pub message: String,
}

/// The first training image of the run that could not be read, if any. The loss stage then
/// reports a non-finite loss, so the numeric guard stops the optimisation as for a
/// [`NumericFault`].
#[derive(Resource, Clone, Debug, Default)]
pub struct ReadFault(pub Option<ReadFailure>);

/// The first numeric fault of the run, if any; while set, Adam and densification are skipped.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct NumericFault(pub Option<Fault>);

/// Asks the deformation stage to evaluate every Gaussian in full. Without it, a Gaussian whose
/// σ(t) is below what the splatting stage draws gets only its opacity (its other
/// [`crate::components::Deformed`] fields are left at [`crate::components::Deformed::faded`]'s
/// values), unless a built-in stage reads the geometry of such Gaussians (the baseline's
/// in-frustum view count, the motion-smoothness graph). Insert it when a system of your own
/// reads the deformed geometry of Gaussians that are not drawn.
#[derive(Resource, Clone, Copy, Debug, Default)]
pub struct DeformEveryGaussian;

/// Gradient of the loss with respect to a deformed Gaussian (at the current time).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct DeformedGrad {
    /// dL/dμ(t) (world space).
    pub mean: glam::Vec3,
    /// dL/dq(t), with respect to the normalised quaternion [w, x, y, z].
    pub rotation: [f32; 4],
    /// dL/ds(t), with respect to the exponentiated scales.
    pub scale: glam::Vec3,
    /// dL/dσ(t).
    pub opacity: f32,
    /// dL/d rgb.
    pub color: [f32; 3],
}

/// The splatting stage's per-iteration arrays, indexed by [`crate::components::SplatSlot`].
/// (The deformed Gaussians themselves stay in their [`crate::components::Deformed`]
/// components, whose table order the slots follow: copying them here cost a pass over 56 B
/// per Gaussian each iteration.)
#[derive(Resource, Default)]
pub struct SplatBuffers {
    /// The projected 2D splats, one per slot.
    pub splats: Vec<Splat>,
    /// The CPU tile rasterizer and its binning scratch.
    pub rasterizer: Rasterizer,
    /// The rendered image and alpha of the sampled view.
    pub render: RenderOutput,
    /// Gradients with respect to each splat's 2D parameters.
    pub splat_grads: Vec<SplatGrad>,
    /// Gradients with respect to each deformed Gaussian (zero for splats not drawn).
    pub deformed_grads: Vec<DeformedGrad>,
    /// Whether any gradient reached each slot (its deformed gradient is not zero): what
    /// `train.visible_adam` steps.
    pub gradient_reached: Vec<bool>,
    /// ‖∂L/∂μ2D‖ in NDC units per slot (0 for splats not drawn).
    pub ndc_grad_norm: Vec<f32>,
}

/// The loss of the current iteration and its gradient with respect to the rendered image.
#[derive(Resource, Default)]
pub struct LossImage {
    /// The loss value and its L1 and SSIM parts.
    pub value: LossValue,
    /// The ground truth of the sampled view as `f32` (decoded into the same buffer each time).
    pub target: crate::io::image::Image,
    /// dL/d rgb per pixel of the render, row-major.
    pub d_color: Vec<[f32; 3]>,
    /// Reused working buffers of the loss (SSIM maps, row sums).
    pub scratch: LossScratch,
    /// The render after the sampled camera's exposure correction, the image the loss compared
    /// (used only with [`CameraExposures`]).
    pub corrected: crate::io::image::Image,
}

/// The motion bases shared by every Gaussian (`model.shared_motion`, see
/// [`crate::model::shared_motion`]) with their gradient and Adam moments. Inserted only when
/// enabled (its presence switches the shared motion on in the deformation, backward and Adam
/// stages); each Gaussian's weights are its [`crate::components::MotionWeights`].
#[derive(Resource, Clone, Debug, Default, PartialEq)]
pub struct SharedMotion {
    /// The values U[b][k].
    pub bases: MotionBases,
    /// This iteration's dL/dU, laid out like [`MotionBases::values`].
    pub grad: Vec<[f32; 3]>,
    /// Adam's first moments, laid out like [`MotionBases::values`].
    pub m: Vec<[f32; 3]>,
    /// Adam's second moments.
    pub v: Vec<[f32; 3]>,
}

impl SharedMotion {
    /// `bases` with zero gradient and moments.
    pub fn new(bases: MotionBases) -> Self {
        let zeros = vec![[0.0; 3]; bases.values.len()];
        Self {
            bases,
            grad: zeros.clone(),
            m: zeros.clone(),
            v: zeros,
        }
    }

    /// Zero bases of the shape `config` asks for (the start of a run).
    pub fn zeros(config: SharedMotionConfig) -> Self {
        Self::new(MotionBases::zeros(
            config.bases as usize,
            config.knots as usize,
        ))
    }
}

/// Per-camera exposure compensation (`train.camera_exposure`), with each camera's Adam state.
/// Inserted only when enabled; the loss applies the sampled camera's correction and the Adam
/// stage steps it.
#[derive(Resource, Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraExposures {
    /// One per dataset camera, in the dataset's order.
    pub cameras: Vec<CameraExposure>,
    /// The camera trained on this iteration and the loss gradient of its correction.
    #[serde(skip)]
    pub grad: Option<(usize, Exposure)>,
}

/// One camera's exposure correction and its Adam moments.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CameraExposure {
    /// The correction applied to this camera's renders in the loss.
    pub exposure: Exposure,
    /// Whether the camera has training views. The corrections are centred over these; the
    /// others (held-out cameras) stay at the identity.
    pub trained: bool,
    /// Adam's first moments, in [`Exposure::values`] order.
    pub m: [f32; 6],
    /// Adam's second moments.
    pub v: [f32; 6],
    /// Adam steps taken on this camera (its own bias correction: a camera is trained only on
    /// the iterations that sample it).
    pub steps: u32,
}

impl CameraExposures {
    /// Identity corrections for `dataset`'s cameras, marking those with training views.
    pub fn new(dataset: &Dataset) -> Self {
        let mut cameras = vec![CameraExposure::default(); dataset.cameras.len()];
        for view in &dataset.train {
            cameras[view.camera].trained = true;
        }
        Self {
            cameras,
            grad: None,
        }
    }

    /// One line on the learnt corrections: the range of the training cameras' mean gain and
    /// mean offset, naming the cameras at the ends (dataset camera indices). `None` before any
    /// camera has been trained.
    pub fn summary(&self) -> Option<String> {
        let trained: Vec<(usize, f32, f32)> = self
            .cameras
            .iter()
            .enumerate()
            .filter(|(_, c)| c.trained && c.steps > 0)
            .map(|(i, c)| {
                let gain = c.exposure.gain().iter().sum::<f32>() / 3.0;
                let offset = c.exposure.offset.iter().sum::<f32>() / 3.0;
                (i, gain, offset)
            })
            .collect();
        let by = |key: fn(&(usize, f32, f32)) -> f32| {
            let min = trained.iter().min_by(|a, b| key(a).total_cmp(&key(b)))?;
            let max = trained.iter().max_by(|a, b| key(a).total_cmp(&key(b)))?;
            Some((*min, *max))
        };
        let (low_gain, high_gain) = by(|c| c.1)?;
        let (low_offset, high_offset) = by(|c| c.2)?;
        Some(format!(
            "gain {:.3} (camera {}) to {:.3} (camera {}), offset {:+.3} (camera {}) to {:+.3} \
             (camera {})",
            low_gain.1,
            low_gain.0,
            high_gain.1,
            high_gain.0,
            low_offset.2,
            low_offset.0,
            high_offset.2,
            high_offset.0
        ))
    }

    /// The correction of camera `index` (the identity for an unknown camera).
    pub fn exposure(&self, index: usize) -> Exposure {
        self.cameras
            .get(index)
            .map_or_else(Exposure::default, |c| c.exposure)
    }
}
