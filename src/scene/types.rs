//! The scene file: data source, model and schedule settings, with the SPEC's defaults.
//!
//! Every struct denies unknown fields so a typo is an error, not a silently ignored setting.

use serde::{Deserialize, Serialize};

use crate::data::colmap_video::ColmapSource;
use crate::data::dnerf::DNerfSource;
use crate::data::n3dv::N3dvSource;
use crate::data::nerfstudio::NerfstudioSource;
use crate::data::panoptic::PanopticSource;
use crate::data::synthetic::SyntheticScene;
use crate::init::carve::CarveSettings;

/// One scene file: where the data comes from and how to train on it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneConfig {
    /// Short name used in logs and output folders.
    pub name: String,
    /// Where the multi-view video comes from.
    pub data: DataSource,
    /// How the initial Gaussians are made (the `init:` block).
    #[serde(default)]
    pub init: InitConfig,
    /// The deformation model (the `model:` block).
    #[serde(default)]
    pub model: ModelConfig,
    /// Densification schedule and criteria (the `densify:` block).
    #[serde(default)]
    pub densify: DensifyConfig,
    /// Optimisation schedule, loss and learning rates (the `train:` block).
    #[serde(default)]
    pub train: TrainConfig,
    /// Output directory for renders and reports (relative to the working directory).
    #[serde(default = "default_output")]
    pub output: String,
    /// Train on a temporal segment of the sequence only (written by `tadgs segment plan`);
    /// `None` trains on every frame.
    #[serde(default)]
    pub segment: Option<Segment>,
}

/// A temporal segment: the frames one run trains on, out of the whole sequence. Time stays
/// that of the whole sequence (frame f at f/(T − 1), the TOW window λ = window/T), so the
/// segments' Gaussians can be merged into one model of the whole sequence.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct Segment {
    /// First frame trained, a frame number of the whole sequence (from 0).
    pub first_frame: usize,
    /// Last frame trained (inclusive).
    pub last_frame: usize,
}

impl SceneConfig {
    /// A scene with the given data source and every other setting at its default.
    pub fn new(name: impl Into<String>, data: DataSource) -> Self {
        Self {
            name: name.into(),
            data,
            init: InitConfig::default(),
            model: ModelConfig::default(),
            densify: DensifyConfig::default(),
            train: TrainConfig::default(),
            output: default_output(),
            segment: None,
        }
    }
}

impl SceneConfig {
    /// Sets the run length to `iterations` and stretches every iteration-counted part of the
    /// schedule by the same factor, so a shorter or longer run keeps the scene file's shape:
    /// densification starts and ends at the same fractions of the run, opacity resets and SH
    /// degree increases come as often relative to its length. The densification interval is
    /// kept: it is the number of views each step's statistics gather, not a share of the run.
    /// The coarse-to-fine switch (`train.coarse_until`) and the end of the static warm-up
    /// (`train.static_until`) move with the run too.
    pub fn scale_schedule(&mut self, iterations: u32) {
        let old = self.train.iterations.max(1) as f64;
        let factor = iterations as f64 / old;
        let scale = |n: u32| (n as f64 * factor).round().min(u32::MAX as f64) as u32;
        self.densify.from_iter = scale(self.densify.from_iter);
        self.densify.until_iter = scale(self.densify.until_iter);
        self.densify.opacity_reset_interval = match self.densify.opacity_reset_interval {
            0 => 0,
            n => scale(n).max(1),
        };
        self.train.sh_increase_interval = scale(self.train.sh_increase_interval).max(1);
        self.train.coarse_until = scale(self.train.coarse_until);
        self.train.static_until = scale(self.train.static_until);
        self.train.iterations = iterations;
    }
}

fn default_output() -> String {
    "runs/out".into()
}

/// Where the images and cameras come from.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub enum DataSource {
    /// Analytic objects rendered by the built-in ray caster (no files needed).
    Synthetic(SyntheticScene),
    /// A Dynamic3DGaussians / CMU Panoptic capture (train_meta.json, test_meta.json, ims/, seg/).
    Panoptic(PanopticSource),
    /// A D-NeRF scene (transforms_{train,val,test}.json with per-image time, RGBA images).
    DNerf(DNerfSource),
    /// An N3DV / LLFF multi-view video (poses_bounds.npy + camXX.mp4 or frame folders).
    N3dv(N3dvSource),
    /// A nerfstudio capture (transforms.json with pinhole intrinsics, optional per-frame time,
    /// optional ply_file_path).
    Nerfstudio(NerfstudioSource),
    /// Per-frame COLMAP folders, as SpacetimeGaussians and TAD-GS preprocess N3DV:
    /// `colmap_<frame>/images/<camera>.png`, and `colmap_<frame>/sparse/0/` on the frames
    /// COLMAP ran on (their points initialise those anchor frames).
    ColmapFrames(ColmapSource),
    /// One COLMAP model of a static rig (`sparse/0/`, an image per camera) and per-camera
    /// frame folders `frames/<camera>/<index>.png` (or videos `<camera>.mp4`).
    ColmapRig(ColmapSource),
}

impl SceneConfig {
    /// Every file or folder path the scene names: the data folder and an initial point cloud.
    pub fn paths_mut(&mut self) -> Vec<&mut String> {
        let mut paths = Vec::new();
        match &mut self.data {
            DataSource::Synthetic(_) => {}
            DataSource::Panoptic(source) => paths.push(&mut source.path),
            DataSource::DNerf(source) => paths.push(&mut source.path),
            DataSource::N3dv(source) => paths.push(&mut source.path),
            DataSource::Nerfstudio(source) => paths.push(&mut source.path),
            DataSource::ColmapFrames(source) | DataSource::ColmapRig(source) => {
                paths.push(&mut source.path)
            }
        }
        if let InitMethod::PointCloud(path) = &mut self.init.method {
            paths.push(path);
        }
        paths
    }

    /// Makes every relative path the scene names absolute (against the working directory),
    /// so that a run folder's scene.ron works from any directory.
    pub fn absolute_paths(&mut self) {
        for path in self.paths_mut() {
            if let Ok(absolute) = std::path::absolute(path.as_str()) {
                *path = absolute.to_string_lossy().into_owned();
            }
        }
    }
}

/// Where the initial points of each anchor frame come from.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub enum InitMethod {
    /// The visual hull of the foreground masks plus photo-consistent background points where
    /// the training views of the anchor frame have masks (Panoptic `seg/`, D-NeRF alpha);
    /// otherwise the dataset's own point cloud (the nearest frame's, where the dataset has one
    /// per frame, as per-frame COLMAP folders do); otherwise random points. Falls back to random
    /// points (with a warning) when carving finds nothing.
    Auto,
    /// Random points in the cameras' common view volume with random colours.
    Random,
    /// Space carving: the visual hull of the masks, or photo-consistency without masks
    /// (see `init.carve`); an error when nothing survives.
    Carve,
    /// A point cloud file (PLY, or COLMAP points3D.txt / .bin), used at every anchor frame.
    PointCloud(String),
}

/// How the initial Gaussians are made.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct InitConfig {
    /// Where the points come from.
    pub method: InitMethod,
    /// Settings of the carving initialiser (used by `Auto` and `Carve`).
    pub carve: CarveSettings,
    /// Anchor (temporal centre) spacing in frames; the last frame is always an anchor.
    pub anchor_spacing: usize,
    /// Points per anchor frame (a point-cloud file is used whole).
    pub points_per_anchor: usize,
    /// Initial opacity (SPEC: 0.1).
    pub opacity: f32,
    /// Half-width, in frames, over which a new Gaussian keeps σ(t)/σ^s > 0.2.
    pub lifespan_half_frames: f32,
    /// The same for the carved background points (outside the visual hull of the foreground
    /// masks: the static part of the scene), so they can live long enough to be trained by
    /// every frame's views instead of one anchor's share; `None` uses `lifespan_half_frames`.
    pub background_lifespan_half_frames: Option<f32>,
}

impl Default for InitConfig {
    fn default() -> Self {
        Self {
            method: InitMethod::Auto,
            carve: CarveSettings::default(),
            anchor_spacing: 20,
            points_per_anchor: 2000,
            opacity: 0.1,
            lifespan_half_frames: 25.0,
            background_lifespan_half_frames: None,
        }
    }
}

/// The form of the temporal opacity σ(t).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub enum OpacityModel {
    /// Paper: σ^s·exp(−ψ·Δt'²), ψ = exp(raw).
    Rbf,
    /// Implementation: asymmetric Gaussian with left/right widths w = w_min·exp(s) ≤ 1.1.
    Asymmetric,
}

/// Fourier phase: one per Gaussian (paper) or one per frequency (implementation).
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub enum PhaseModel {
    /// One phase φ shared by the K frequencies of a Gaussian (paper, the default).
    PerGaussian,
    /// A separate phase for each frequency (authors' implementation).
    PerFrequency,
}

/// Temporal Offset Warping settings.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TowConfig {
    /// Apply the warp; false uses the identity W(Δt) = Δt (ablation baseline).
    pub enabled: bool,
    /// Focus window in frames; λ = window_frames / T. When λ ≥ 1 (a sequence no longer than
    /// the window) the warp falls back to the identity.
    pub window_frames: f32,
    /// Fraction of the temporal capacity inside the window (paper 0.75, implementation 0.7).
    pub rho: f32,
    /// Give a Gaussian centred at the sequence's first (last) instant the whole window after
    /// (before) its centre, inside the sequence, instead of half of it outside (authors'
    /// implementation; the paper centres every window: false).
    pub one_sided_ends: bool,
    /// Round the warp's corners at the window's edges: the same slope at the centre and the
    /// same far branch, with the slope falling smoothly in between (a tanh), so that a motion
    /// smooth in real time stays smooth in warped time (false: the paper's piecewise-linear
    /// warp).
    pub smooth: bool,
}

impl Default for TowConfig {
    fn default() -> Self {
        Self {
            enabled: true,
            window_frames: 50.0,
            rho: 0.75,
            one_sided_ends: false,
            smooth: false,
        }
    }
}

/// Deformation model settings.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Highest SH degree (0..=3).
    pub sh_degree: u32,
    /// Form of the temporal opacity σ(t).
    pub opacity: OpacityModel,
    /// Whether the Fourier phase is per Gaussian or per frequency.
    pub phase: PhaseModel,
    /// Period of the lowest Fourier frequency in normalised time (paper: 1). With 1, a
    /// Gaussian that lives the whole sequence must end where it started; 2 lets it end
    /// elsewhere (monocular scenes whose Gaussians live the whole sequence, e.g. D-NeRF).
    pub motion_period: f32,
    /// Scale polynomial of degree 1 (paper); false keeps the scale constant (implementation).
    pub scale_motion: bool,
    /// Temporal Offset Warping.
    pub tow: TowConfig,
    /// Motion bases shared by every Gaussian, added to each one's Fourier motion (`None`, the
    /// default: every Gaussian moves on its own, as in the paper). CPU backend only.
    pub shared_motion: Option<SharedMotionConfig>,
}

/// Shared motion bases (`tadgs::model::shared_motion`): mean_i(t) = μ_i + Fourier_i(Δt') +
/// Σ_{b<B} w_ib·u_b(t), with B trajectories u_b shared by every Gaussian, each piecewise linear
/// in the view's normalised time over K knots spaced uniformly on [0, 1], and B weights per
/// Gaussian. Not part of the paper; meant for monocular captures (D-NeRF), where trajectories
/// learnt one per Gaussian can fit each training view alone. The bases start at zero, the
/// weights at small random values (N(0, 0.1²)); learning rates `train.lr.motion_bases` and
/// `train.lr.motion_weights`.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
#[serde(deny_unknown_fields)]
pub struct SharedMotionConfig {
    /// B, the number of shared trajectories (1 to 16).
    pub bases: u32,
    /// K, the number of knots of each trajectory (at least 2), knot k at time k/(K − 1).
    pub knots: u32,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            sh_degree: 3,
            opacity: OpacityModel::Rbf,
            phase: PhaseModel::PerGaussian,
            motion_period: 1.0,
            scale_motion: true,
            tow: TowConfig::default(),
            shared_motion: None,
        }
    }
}

/// The densification threshold's dependence on lifespan.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum TatForm {
    /// Paper: τ·(1 / (1 + β(1 − ψ̄)))^α.
    Paper {
        /// β ≥ 0: how much a short lifespan lowers the threshold (default 0.3).
        beta: f32,
        /// Exponent α > 0 (default 1).
        alpha: f32,
    },
    /// Implementation: τ·(β + (1 − β)·ψ̄^α).
    Implementation {
        /// β in [0, 1]: the threshold factor at lifespan 0 (the implementation uses 0.75).
        beta: f32,
        /// Exponent α > 0 on ψ̄ (the implementation uses 0.8).
        alpha: f32,
    },
}

/// Densification schedule and criteria.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct DensifyConfig {
    /// Visibility-aware densification: opacity-weighted mean of the 2D gradient.
    pub vad: bool,
    /// Implementation option: count a view for VAD only where σ(t) exceeds this.
    pub vad_min_opacity: Option<f32>,
    /// Without VAD: which views a Gaussian's mean gradient averages over.
    pub baseline_views: BaselineViews,
    /// Temporally adaptive threshold.
    pub tat: bool,
    /// Formula of the TAT threshold (used when `tat` is on).
    pub tat_form: TatForm,
    /// Base threshold on the NDC-space 2D mean gradient (3DGS: 2e-4).
    pub grad_threshold: f32,
    /// Clone if max scale ≤ this fraction of the scene extent, else split.
    pub percent_dense: f32,
    /// Densify and prune every this many iterations (must be > 0).
    pub interval: u32,
    /// Densification steps happen only at iterations strictly after this one.
    pub from_iter: u32,
    /// Last iteration (inclusive) at which gradient statistics are gathered, densification
    /// runs and opacities are reset.
    pub until_iter: u32,
    /// Cap every spatial opacity at 0.01 every this many iterations (up to `until_iter`);
    /// 0 disables the reset.
    pub opacity_reset_interval: u32,
    /// Prune Gaussians whose spatial opacity σ^s (after the sigmoid, in [0, 1)) is below this.
    pub prune_opacity: f32,
    /// Also prune Gaussians whose screen radius > 20 px or world scale > 0.1·extent (only
    /// after the first `opacity_reset_interval` iterations, as in 3DGS).
    pub prune_big: bool,
    /// Upper bound on the population; densification stops growing at the cap.
    pub max_gaussians: usize,
    /// Which Gaussians are densified when more qualify than the cap leaves room for.
    pub at_cap: CapPolicy,
    /// The temporal centre of a clone: the parent's (paper) or where its gradient came from.
    pub clone_time: CloneTime,
}

/// Which views the 3DGS mean gradient (VAD off) averages a Gaussian's gradient over. With VAD
/// on only the views that draw a Gaussian count: a view weighs σ(t), so one where it has faded
/// out (σ(t) < 1/255) would weigh almost nothing.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub enum BaselineViews {
    /// Every view whose frustum holds the Gaussian (in front of the near plane, its 3σ screen
    /// box on the image), drawn or not: 3DGS counts every Gaussian with a screen radius, and so
    /// does the authors' code without VAD. A Gaussian that has faded out of a view (σ(t) <
    /// 1/255) counts there with gradient 0, which dilutes the mean gradient of short-lived
    /// Gaussians: what VAD corrects.
    #[default]
    InFrustum,
    /// Only the views that draw it (σ(t) ≥ 1/255), as earlier versions did: this already
    /// leaves out most of the times a Gaussian is absent, so the baseline takes much of
    /// VAD's effect.
    Drawn,
}

/// Where in time a clone is centred. Not part of the paper, whose children inherit t_i.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub enum CloneTime {
    /// The parent's temporal centre t_i (the paper: "children inherit t_i").
    #[default]
    Parent,
    /// The mean time of the parent's gradient samples since the last step, weighted as ḡ is
    /// (Σ w·g·t / Σ w·g), clamped to [0, 1]. The clone is moved so that at that time its
    /// position, rotation and scale equal the parent's: it adds coverage where the parent's
    /// lifespan is thin instead of doubling it at the anchor. Splits keep the parent's centre.
    Gradient,
}

/// How a densification step chooses when more Gaussians qualify for cloning or splitting than
/// `max_gaussians` leaves room for. Not part of the paper, which has no cap.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq)]
pub enum CapPolicy {
    /// In the population's storage order until the cap is reached (earlier releases): which
    /// ones get the room is arbitrary.
    InOrder,
    /// The ones whose mean gradient exceeds their threshold by the largest factor.
    Strongest,
    /// As `Strongest`, and then faint Gaussians (spatial opacity below `max_opacity`) are
    /// pruned, faintest first, to make room for the qualifying ones that were left out.
    Replace {
        /// Spatial opacity σ^s in (0, 1) below which a Gaussian may give up its place.
        max_opacity: f32,
    },
}

impl Default for DensifyConfig {
    fn default() -> Self {
        Self {
            vad: true,
            vad_min_opacity: None,
            baseline_views: BaselineViews::InFrustum,
            tat: true,
            tat_form: TatForm::Paper {
                beta: 0.3,
                alpha: 1.0,
            },
            grad_threshold: 2e-4,
            percent_dense: 0.01,
            interval: 200,
            from_iter: 500,
            until_iter: 17_000,
            opacity_reset_interval: 3000,
            prune_opacity: 0.005,
            prune_big: false,
            max_gaussians: 5_000_000,
            at_cap: CapPolicy::InOrder,
            clone_time: CloneTime::Parent,
        }
    }
}

/// The motion-smoothness regulariser (`tadgs::model::smoothness`): λ/|E|·Σ‖v_i − v_j‖² over
/// the edges of a k-nearest-neighbour graph of the Gaussians' positions, v being each motion's
/// velocity at the sampled time (or, with [`SmoothnessForm::Stretch`], only the part of
/// v_i − v_j along the edge). Not part of the paper; for monocular captures, whose
/// trajectories one view per instant constrains too little. CPU backend only.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct MotionSmoothness {
    /// λ, added to the photometric loss (0 = off).
    pub weight: f32,
    /// k: each Gaussian is joined to its k nearest (the graph is the union, undirected).
    pub neighbours: u32,
    /// Rebuild the graph from the positions at the sampled time every this many iterations,
    /// and whenever densification changed the population.
    pub rebuild_interval: u32,
    /// Which part of a neighbour's relative velocity is penalised.
    pub form: SmoothnessForm,
}

/// Which part of the relative velocity v_i − v_j of two neighbours the regulariser penalises.
#[derive(Clone, Copy, Debug, Default, Serialize, Deserialize, PartialEq, Eq)]
pub enum SmoothnessForm {
    /// All of it: neighbours should move alike (a rotation about a joint costs).
    #[default]
    Velocity,
    /// Only its component along the edge, ((x_i − x_j)/‖x_i − x_j‖ · (v_i − v_j))²: the rate
    /// at which the neighbours' distance changes. Any rigid motion, rotations included, costs
    /// nothing (the infinitesimal form of an isometry prior).
    Stretch,
}

impl Default for MotionSmoothness {
    fn default() -> Self {
        Self {
            weight: 0.0,
            neighbours: 8,
            rebuild_interval: 100,
            form: SmoothnessForm::Velocity,
        }
    }
}

/// Learning rates (SPEC §1).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct LearningRates {
    /// Initial position lr, multiplied by the scene extent.
    pub position: f32,
    /// Final position lr (exponential decay over the run), multiplied by the scene extent.
    pub position_final: f32,
    /// Fourier coefficients: this fraction of the current position lr.
    pub fourier_cos_sin: f32,
    /// Fourier phase: this fraction of the current position lr.
    pub fourier_phase: f32,
    /// Temporal scale (raw values: log ψ for the RBF opacity, the left/right width
    /// parameters s of the asymmetric form).
    pub temporal_scale: f32,
    /// Temporal centre t_i, in normalised time. 0 keeps every centre at its anchor frame
    /// (the paper and the authors' code); above 0 the centres are learnt, so that Gaussians
    /// can drift in time towards the frames between anchors (CPU backend only).
    pub temporal_center: f32,
    /// Spatial opacity σ^s, on its logit.
    pub opacity: f32,
    /// Rotation quaternion constant term c_0.
    pub rotation: f32,
    /// Rotation quaternion linear term c_1 (per unit of warped normalised time).
    pub rotation_velocity: f32,
    /// Log-scale constant term d_0.
    pub scale: f32,
    /// Log-scale linear term d_1 (ignored while `model.scale_motion` is false).
    pub scale_velocity: f32,
    /// SH DC (degree-0) coefficients.
    pub sh_dc: f32,
    /// Higher SH bands use sh_dc divided by this.
    pub sh_rest_divisor: f32,
    /// Per-camera exposure (log-gain and offset per channel, `train.camera_exposure`).
    pub exposure: f32,
    /// Shared motion bases U (`model.shared_motion`), multiplied by the scene extent (the
    /// bases are displacements in scene units) and decayed over the run in the same ratio as
    /// the position rate (`position_final / position`).
    pub motion_bases: f32,
    /// Each Gaussian's weights of the shared motion bases (`model.shared_motion`).
    pub motion_weights: f32,
}

impl Default for LearningRates {
    fn default() -> Self {
        Self {
            position: 2.6e-4,
            position_final: 2.6e-6,
            fourier_cos_sin: 0.35,
            fourier_phase: 0.07,
            temporal_scale: 0.01,
            temporal_center: 0.0,
            opacity: 0.05,
            rotation: 1e-3,
            rotation_velocity: 1e-4,
            scale: 1.5e-3,
            scale_velocity: 1.5e-4,
            sh_dc: 2.5e-3,
            sh_rest_divisor: 20.0,
            exposure: 1e-3,
            motion_bases: 1.6e-5,
            motion_weights: 1e-3,
        }
    }
}

impl LearningRates {
    /// These rates with every time-dependent term's rate at 0: the motion (Fourier
    /// coefficients and phases, rotation and log-scale linear terms, shared motion bases and
    /// weights) and the temporal opacity (widths and centres). What the static warm-up trains
    /// with.
    pub fn frozen_in_time(&self) -> Self {
        Self {
            motion_bases: 0.0,
            motion_weights: 0.0,
            fourier_cos_sin: 0.0,
            fourier_phase: 0.0,
            temporal_scale: 0.0,
            temporal_center: 0.0,
            rotation_velocity: 0.0,
            scale_velocity: 0.0,
            ..self.clone()
        }
    }
}

/// Which backend runs splatting.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, Eq)]
pub enum BackendKind {
    /// The tile rasterizer on the CPU (rayon), forward and backward.
    Cpu,
    /// Forward and backward blending on a GPU through wgpu (Vulkan, Metal, DX12, GL).
    Gpu,
}

/// Optimisation schedule.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct TrainConfig {
    /// Training iterations, one view each (also the horizon of the position lr decay).
    pub iterations: u32,
    /// Seed of the random numbers: initial points, view sampling and splits.
    pub seed: u64,
    /// Background colour the renders are composited over.
    pub background: [f32; 3],
    /// Train every iteration over a new random uniform background colour, with the truth
    /// recomposited over the same colour from the view's alpha matte (datasets of RGBA images:
    /// D-NeRF, Blender-style nerfstudio scenes; views without a matte keep `background`).
    /// Over a fixed background, Gaussians of its colour are invisible wherever they cover only
    /// background in the training views, and they show as floaters in held-out views; over
    /// random colours they cost loss and fade. Evaluation and renders use `background`.
    pub random_background: bool,
    /// Fraction of the training views drawn a second time in each epoch: those whose loss was
    /// highest when last drawn (0 = every view once per epoch, the default). Spends more
    /// iterations where the model fits worst, e.g. the fast end of a monocular sequence.
    pub repeat_hard_views: f32,
    /// Weight of D-SSIM in the loss (0.2).
    pub lambda_dssim: f32,
    /// Gaussians closer to the camera than this (camera-space depth, scene units) are not
    /// drawn (default 0.01, as the projection's own near plane). Rigs whose cameras sit in the
    /// captured walls (Panoptic's dome) need more, or wall Gaussians next to a held-out camera
    /// cover its whole view.
    pub near_plane: f32,
    /// Raise the SH degree by one every this many iterations.
    pub sh_increase_interval: u32,
    /// Coarse-to-fine: train the first `coarse_until` iterations on the training views
    /// downscaled by this factor (1 = off), then at the data's own resolution. The cheap
    /// coarse iterations see every view more often; the fine ones sharpen the detail that the
    /// evaluation at full resolution scores.
    pub coarse_downscale: u32,
    /// Last iteration trained at the coarse resolution (see `coarse_downscale`).
    pub coarse_until: u32,
    /// Static warm-up: during the first `static_until` iterations the Gaussians neither move
    /// nor change their lifespans (the motion terms — Fourier coefficients and phases, the
    /// rotation and log-scale linear terms — and the temporal widths and centres keep their
    /// initial values), so a static model is fitted to every view before the trajectories
    /// start to learn, as in the static first stage of deformation-field methods
    /// (4DGaussians, Deformable 3D Gaussians). 0 = off (the paper).
    pub static_until: u32,
    /// Learn an affine colour per training camera (`exp(log_gain)·render + offset` per
    /// channel, applied before the loss) that absorbs the cameras' differences in exposure and
    /// white balance, so that the Gaussians need not average them into blur. For multi-camera
    /// captures; held-out cameras are rendered without a correction. The corrections are kept
    /// centred (mean log-gain and offset 0 over the training cameras), so the model's colours
    /// are those of an average training camera.
    pub camera_exposure: bool,
    /// Adam steps only the Gaussians that received a gradient this iteration (drawn in the
    /// view and not hidden behind opaque pixels); the others keep their parameters and
    /// moments. Off (the paper and 3DGS): every Gaussian steps, the unseen ones on their
    /// momentum alone. In a 4D model most Gaussians live far from the view's time, so this
    /// skips most of the optimiser's work (as gsplat's `visible_adam`). CPU backend only.
    pub visible_adam: bool,
    /// Adam steps only the Gaussians that received a gradient, like `visible_adam`, but keeps
    /// dense Adam's trajectory: the momentum steps a Gaussian missed are applied in one update
    /// before it is next drawn (its opacity and temporal parameters, which decide that, are
    /// stepped densely), and to every Gaussian every 100 iterations, at densification and
    /// opacity-reset steps and at the end. Training then follows dense Adam up to rounding
    /// while skipping the work `visible_adam` skips. CPU backend only; not with
    /// `visible_adam`.
    pub deferred_adam: bool,
    /// Chain each Gaussian's gradient through the deformation and step Adam on it in one pass,
    /// block by block, instead of writing every gradient into `Grad` components and stepping
    /// them in a later stage: the Gaussians then carry no gradient components (at SH degree 3,
    /// 388 of their 1 260 bytes) and the gradients never travel through main memory. The
    /// same model bit for bit, with dense, visible or deferred Adam. CPU backend only; not
    /// with `motion_smoothness` or `model.shared_motion`, which read the gradient components.
    pub fused_adam: bool,
    /// Motion-smoothness regulariser: neighbouring Gaussians move alike (off by default).
    pub motion_smoothness: MotionSmoothness,
    /// Learning rates per parameter group.
    pub lr: LearningRates,
    /// Which backend renders and back-propagates.
    pub backend: BackendKind,
    /// GPU backend: sum the raster backward's gradients with float atomics where the adapter
    /// offers them (SHADER_FLOAT32_ATOMIC and SUBGROUP), the fast path. `false` takes the
    /// portable path every adapter runs (per-tile partial sums and a reduction pass) even
    /// where atomics are offered: for a driver whose float atomics misbehave, or to time one
    /// path against the other (`tadgs bench --backend gpu --set
    /// train.gpu_float_atomics=false`). Both give the same gradients up to rounding.
    pub gpu_float_atomics: bool,
    /// Print an evaluation line every this many iterations (0 = only at the end).
    pub eval_interval: u32,
    /// Write a checkpoint (`<output>/checkpoint/`) every this many iterations, and always at
    /// the end (0 = only at the end).
    pub checkpoint_interval: u32,
}

impl TrainConfig {
    /// Whether the Gaussians go without gradient components and fused Adam steps them:
    /// `fused_adam` on the CPU backend.
    pub fn fuses_adam(&self) -> bool {
        self.fused_adam && self.backend == BackendKind::Cpu
    }

    /// The learning rates of iteration `iteration` (1-based): `lr`, with the time-dependent
    /// terms frozen during the static warm-up (`static_until`).
    pub fn rates_at(&self, iteration: u32) -> LearningRates {
        if iteration <= self.static_until {
            self.lr.frozen_in_time()
        } else {
            self.lr.clone()
        }
    }
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            iterations: 40_000,
            seed: 0,
            background: [0.0; 3],
            random_background: false,
            repeat_hard_views: 0.0,
            lambda_dssim: 0.2,
            near_plane: 0.01,
            sh_increase_interval: 1000,
            coarse_downscale: 1,
            coarse_until: 0,
            static_until: 0,
            camera_exposure: false,
            visible_adam: false,
            deferred_adam: false,
            fused_adam: false,
            motion_smoothness: MotionSmoothness::default(),
            lr: LearningRates::default(),
            backend: BackendKind::Cpu,
            gpu_float_atomics: true,
            eval_interval: 0,
            checkpoint_interval: 5000,
        }
    }
}
