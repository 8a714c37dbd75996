//! Training checkpoints: everything needed to continue a run bit for bit.
//!
//! A checkpoint is a folder of three files, each written atomically:
//! - `tensors.safetensors`: per Gaussian, every parameter component (as in the model file),
//!   both Adam moments of every group (`adam.m.<group>`, `adam.v.<group>`) and the
//!   densification statistics (`grad_accum`: Σw·g, Σw, Σψ̄, max radius; `grad_accum_count`;
//!   `grad_accum_offset`: Σw·g·Δt, absent from older checkpoints, which read it as 0), and
//!   `adam_clock`, the iteration each Gaussian's Adam state is current at (behind the
//!   checkpoint's only under `train.deferred_adam`; older checkpoints read the iteration).
//!   Adam's step count is the iteration (bias correction uses the global step). With
//!   `model.shared_motion`, also the bases (`shared_motion`, B × 3K) and each Gaussian's
//!   weights (`motion_weights`, N × B), each with its Adam moments (`adam.m.`, `adam.v.`).
//! - `log.json`: the run's history for the report ([`TrainingLog`]).
//! - `state.ron`, written last: the scene settings, the counters (iteration, SH degree, last
//!   densification), the view order of the current epoch and the RNG state.
//!
//! Both data files record the iteration; a checkpoint whose files disagree (one replaced, a
//! crash between two writes) is refused with an error naming the file.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;
use rand_chacha::ChaCha8Rng;
use safetensors::tensor::Dtype;
use serde::{Deserialize, Serialize};

use super::model::{
    MOTION_WEIGHTS_TENSOR, ModelError, ModelMotion, NamedTensor, SHARED_MOTION_TENSOR,
    bases_tensor, checked_metadata, param_tensors, read_bases_tensor, read_param_tensors,
    read_weights_tensor, weights_tensor, write_tensors,
};
use crate::components::{
    Adam, AdamClock, AdamRefs, GaussianParams, Grad, GradAccum, MotionWeights, ParamRefs,
    spawn_gaussians, spawn_gaussians_with,
};
use crate::model::shared_motion::MotionBases;
use crate::report::TrainingLog;
use crate::resources::{
    CameraExposures, DensifyReport, Rng, Settings, SharedMotion, TrainState, ViewOrder,
};
use crate::scene::SceneConfig;

/// The tensors of a checkpoint.
pub const TENSORS_FILE: &str = "tensors.safetensors";
/// The settings and counters of a checkpoint.
pub const STATE_FILE: &str = "state.ron";
/// The history of the run up to the checkpoint.
pub const LOG_FILE: &str = "log.json";
/// Value of the `format` field and metadata key.
pub const CHECKPOINT_FORMAT: &str = "tadgs-checkpoint";
/// Layout version; bumped when a file's content changes.
pub const CHECKPOINT_VERSION: u32 = 1;

/// A checkpoint could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// One of the checkpoint's files could not be read (missing folder or file, permissions).
    #[error("cannot read checkpoint file {}: {source}", path.display())]
    Read {
        /// The file that could not be read.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A file or folder of the checkpoint could not be written, renamed or removed.
    #[error("cannot write checkpoint file {}: {source}", path.display())]
    Write {
        /// The file or folder (`<dir>`, `<dir>.partial`, `<dir>.old`) the operation was on.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A file's content is wrong: not parseable, another format or version, tensors of the
    /// wrong shape, or an iteration or Gaussian count that disagrees with `state.ron`; when
    /// saving, its content could not be serialised.
    #[error("checkpoint file {}: {message}", path.display())]
    Invalid {
        /// The offending file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
    /// Writing `tensors.safetensors`, or reading one of its tensors, failed (the error names
    /// the file).
    #[error("checkpoint tensors: {0}")]
    Tensors(#[from] ModelError),
}

/// One Gaussian's trainable state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GaussianState {
    /// Every parameter component.
    pub params: GaussianParams,
    /// Adam first moments of every parameter group (zero for a group the Gaussian lacks).
    pub m: GaussianParams,
    /// Adam second moments of every parameter group.
    pub v: GaussianParams,
    /// Densification statistics since the last densification step.
    pub accum: GradAccum,
    /// The iteration the Adam state is current at ([`AdamClock`]).
    pub clock: u32,
    /// The weights of the shared motion bases (zero without `model.shared_motion`).
    pub motion_weights: MotionWeights,
    /// Their Adam moments.
    pub motion_adam: Adam<MotionWeights>,
}

/// The ChaCha8 generator's position: seed, stream and word position (128-bit, as text).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RngState {
    /// The 32-byte ChaCha seed.
    pub seed: [u8; 32],
    /// The ChaCha stream number.
    pub stream: u64,
    /// Position in the key stream in 32-bit words, a decimal `u128` (RON has no 128-bit
    /// integers).
    pub word_pos: String,
}

impl RngState {
    fn of(rng: &ChaCha8Rng) -> Self {
        Self {
            seed: rng.get_seed(),
            stream: rng.get_stream(),
            word_pos: rng.get_word_pos().to_string(),
        }
    }

    fn restore(&self) -> Option<ChaCha8Rng> {
        use rand::SeedableRng;
        let mut rng = ChaCha8Rng::from_seed(self.seed);
        rng.set_stream(self.stream);
        rng.set_word_pos(self.word_pos.parse().ok()?);
        Some(rng)
    }
}

/// Counters of the run at the checkpoint (the `state.ron` file, with the scene).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CheckpointState {
    /// Always [`CHECKPOINT_FORMAT`].
    pub format: String,
    /// Layout version, [`CHECKPOINT_VERSION`] when written.
    pub version: u32,
    /// Iterations completed.
    pub iteration: u32,
    /// SH degree in use.
    pub sh_degree: u32,
    /// Number of Gaussians (rows of every tensor in `tensors.safetensors`).
    pub gaussians: usize,
    /// The last densification step: iteration, cloned, split, pruned.
    pub last_densify: (u32, usize, usize, usize),
    /// Shuffled training-view indices of the current epoch and the next position in it.
    pub view_order: Vec<usize>,
    /// Index into `view_order` of the next view to train on.
    pub view_next: usize,
    /// Loss of each training view when last drawn, with `train.repeat_hard_views` (empty
    /// otherwise, and in checkpoints from before it existed).
    #[serde(default)]
    pub view_losses: Vec<Option<f32>>,
    /// State of the run's random generator.
    pub rng: RngState,
    /// The scene configuration the run was trained with.
    pub scene: SceneConfig,
    /// The per-camera exposure corrections and their Adam moments, with
    /// `train.camera_exposure` (absent otherwise, and in checkpoints from before it existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_exposures: Option<CameraExposures>,
}

/// A whole checkpoint in memory.
#[derive(Clone, Debug)]
pub struct Checkpoint {
    /// Counters, settings and RNG state (`state.ron`).
    pub state: CheckpointState,
    /// Every Gaussian's parameters, Adam moments and statistics (`tensors.safetensors`).
    pub gaussians: Vec<GaussianState>,
    /// The shared motion bases and their Adam moments, with `model.shared_motion`
    /// (`tensors.safetensors`; the gradient is not kept). The Gaussians' weights are then in
    /// [`GaussianState::motion_weights`].
    pub shared_motion: Option<SharedMotion>,
    /// The run's history (`log.json`).
    pub log: TrainingLog,
}

impl Checkpoint {
    /// Captures the run in `world` (trained with `scene`) and its `log`.
    pub fn from_world(world: &mut World, scene: &SceneConfig, log: &TrainingLog) -> Self {
        let train = *world.resource::<TrainState>();
        // Only deferred Adam leaves Gaussians behind; any other run is current everywhere.
        let deferred = world.resource::<Settings>().train.deferred_adam;
        type Weights<'a> = (Option<&'a MotionWeights>, Option<&'a Adam<MotionWeights>>);
        let gaussians: Vec<GaussianState> = world
            .query::<(ParamRefs, AdamRefs, &GradAccum, Option<&AdamClock>, Weights)>()
            .iter(world)
            .map(|(params, adam, accum, clock, (weights, motion_adam))| {
                let [m, v] = GaussianParams::moments_from_refs(adam);
                GaussianState {
                    params: GaussianParams::from_refs(params),
                    m,
                    v,
                    accum: *accum,
                    clock: clock.filter(|_| deferred).map_or(train.iteration, |c| c.0),
                    motion_weights: weights.copied().unwrap_or_default(),
                    motion_adam: motion_adam.copied().unwrap_or_default(),
                }
            })
            .collect();
        let shared_motion = world.get_resource::<SharedMotion>().cloned();
        let order = world.resource::<ViewOrder>();
        let d = train.last_densify;
        let state = CheckpointState {
            format: CHECKPOINT_FORMAT.into(),
            version: CHECKPOINT_VERSION,
            iteration: train.iteration,
            sh_degree: train.sh_degree,
            gaussians: gaussians.len(),
            last_densify: (d.iteration, d.cloned, d.split, d.pruned),
            view_order: order.order.clone(),
            view_next: order.next,
            view_losses: order.losses.clone(),
            rng: RngState::of(&world.resource::<Rng>().0),
            scene: scene.clone(),
            camera_exposures: world.get_resource::<CameraExposures>().cloned(),
        };
        let mut log = log.clone();
        log.truncate(train.iteration);
        Self {
            state,
            gaussians,
            shared_motion,
            log,
        }
    }

    /// The model this checkpoint holds (its Gaussians' parameters, SH degree, deformation
    /// settings and shared motion); the frame count is not recorded.
    pub fn model(&self) -> crate::io::model::Model {
        crate::io::model::Model {
            gaussians: self.gaussians.iter().map(|g| g.params).collect(),
            sh_degree: self.state.sh_degree,
            frame_count: None,
            config: Some(self.state.scene.model.clone()),
            time_windows: None,
            shared_motion: self.shared_motion.as_ref().map(|shared| ModelMotion {
                bases: shared.bases.clone(),
                weights: self.gaussians.iter().map(|g| g.motion_weights).collect(),
            }),
        }
    }

    /// Puts the checkpoint into `world`, which holds the resources of its scene and dataset
    /// (see [`crate::train::insert_resources`]) and no Gaussians: spawns the Gaussians in the
    /// saved order with their Adam moments and statistics, and restores the counters, the
    /// view order and the RNG.
    pub fn restore_into(&self, world: &mut World) {
        let s = &self.state;
        let bundles = self.gaussians.iter().map(|g| {
            let (mut bundle, optional) = g.params.bundles_with_moments(&g.m, &g.v);
            bundle.2.0 = g.accum;
            bundle.2.4 = AdamClock(g.clock);
            (bundle, optional)
        });
        match &self.shared_motion {
            None => spawn_gaussians(world, s.scene.model.sh_degree, bundles),
            Some(shared) => {
                world.insert_resource(shared.clone());
                let weights = self.gaussians.iter().map(|g| {
                    (
                        g.motion_weights,
                        Grad::<MotionWeights>::default(),
                        g.motion_adam,
                    )
                });
                spawn_gaussians_with(
                    world,
                    s.scene.model.sh_degree,
                    bundles
                        .zip(weights)
                        .map(|((bundle, optional), weights)| (bundle, optional, weights)),
                );
            }
        }
        *world.resource_mut::<TrainState>() = TrainState {
            iteration: s.iteration,
            sh_degree: s.sh_degree,
            loss: Default::default(),
            last_densify: DensifyReport {
                iteration: s.last_densify.0,
                cloned: s.last_densify.1,
                split: s.last_densify.2,
                pruned: s.last_densify.3,
            },
        };
        *world.resource_mut::<ViewOrder>() = ViewOrder {
            order: s.view_order.clone(),
            next: s.view_next,
            losses: s.view_losses.clone(),
        };
        // Checked when loading.
        let rng = s.rng.restore().expect("word position checked by load");
        world.resource_mut::<Rng>().0 = rng;
        if let Some(saved) = &s.camera_exposures
            && let Some(mut exposures) = world.get_resource_mut::<CameraExposures>()
        {
            *exposures = saved.clone();
        }
    }

    /// Writes the checkpoint as folder `dir`, replacing the one there without a moment where
    /// neither is complete: the files go into `<dir>.partial`, then the old folder is renamed
    /// to `<dir>.old`, the new one into place, and the old one removed. A crash at any point
    /// leaves `dir` complete, or (between the two renames) `<dir>.old` complete, which
    /// [`Checkpoint::load`] falls back to.
    pub fn save(&self, dir: &Path) -> Result<(), CheckpointError> {
        let write_err = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CheckpointError::Write { path, source }
        };
        let partial = sibling(dir, "partial");
        let old = sibling(dir, "old");
        if partial.exists() {
            std::fs::remove_dir_all(&partial).map_err(write_err(&partial))?;
        }
        std::fs::create_dir_all(&partial).map_err(write_err(&partial))?;
        self.write_files(&partial)?;
        if dir.exists() {
            if old.exists() {
                std::fs::remove_dir_all(&old).map_err(write_err(&old))?;
            }
            std::fs::rename(dir, &old).map_err(write_err(dir))?;
        }
        std::fs::rename(&partial, dir).map_err(write_err(dir))?;
        if old.exists() {
            std::fs::remove_dir_all(&old).map_err(write_err(&old))?;
        }
        Ok(())
    }

    /// Writes the three files into the existing folder `dir`: tensors, log, then state.
    fn write_files(&self, dir: &Path) -> Result<(), CheckpointError> {
        let params: Vec<GaussianParams> = self.gaussians.iter().map(|g| g.params).collect();
        let mut tensors = param_tensors(&params, "");
        let moments: [(&str, fn(&GaussianState) -> GaussianParams); 2] =
            [("adam.m.", |g| g.m), ("adam.v.", |g| g.v)];
        for (prefix, moments) in moments {
            let moments: Vec<GaussianParams> = self.gaussians.iter().map(moments).collect();
            tensors.extend(param_tensors(&moments, prefix));
        }
        tensors.extend(accum_tensors(&self.gaussians));
        if let Some(shared) = &self.shared_motion {
            let b = &shared.bases;
            let like_bases = |values: &[[f32; 3]]| MotionBases {
                values: values.to_vec(),
                ..b.clone()
            };
            type WeightsOf = fn(&GaussianState) -> MotionWeights;
            let weights: [(&str, WeightsOf); 3] = [
                ("", |g| g.motion_weights),
                ("adam.m.", |g| g.motion_adam.m()),
                ("adam.v.", |g| g.motion_adam.v()),
            ];
            for ((prefix, weights), values) in
                weights.into_iter().zip([&b.values, &shared.m, &shared.v])
            {
                tensors.push(bases_tensor(
                    format!("{prefix}{SHARED_MOTION_TENSOR}"),
                    &like_bases(values),
                ));
                let weights: Vec<MotionWeights> = self.gaussians.iter().map(weights).collect();
                tensors.push(weights_tensor(
                    format!("{prefix}{MOTION_WEIGHTS_TENSOR}"),
                    b.bases,
                    &weights,
                ));
            }
        }
        tensors.push(NamedTensor {
            name: "adam_clock".into(),
            dtype: Dtype::U32,
            width: 1,
            bytes: self
                .gaussians
                .iter()
                .flat_map(|g| g.clock.to_le_bytes())
                .collect(),
        });
        let metadata = HashMap::from([
            ("format".to_string(), CHECKPOINT_FORMAT.to_string()),
            ("version".to_string(), CHECKPOINT_VERSION.to_string()),
            ("iteration".to_string(), self.state.iteration.to_string()),
        ]);
        write_tensors(&dir.join(TENSORS_FILE), &tensors, metadata)?;

        let write = |name: &str, text: Result<String, String>| {
            let path = dir.join(name);
            let text = text.map_err(|message| CheckpointError::Invalid {
                path: path.clone(),
                message,
            })?;
            super::write_atomic(&path, text.as_bytes())
                .map_err(|source| CheckpointError::Write { path, source })
        };
        let log = LogFile {
            iteration: self.state.iteration,
            log: self.log.clone(),
        };
        write(
            LOG_FILE,
            serde_json::to_string(&log).map_err(|e| e.to_string()),
        )?;
        let pretty = ron::ser::PrettyConfig::default().compact_arrays(true);
        write(
            STATE_FILE,
            ron::ser::to_string_pretty(&self.state, pretty).map_err(|e| e.to_string()),
        )
    }

    /// Reads the checkpoint in folder `dir`, checking that its three files belong together.
    /// When `dir` is missing and `<dir>.old` exists (a crash while [`Checkpoint::save`]
    /// swapped folders), reads that one.
    pub fn load(dir: &Path) -> Result<Self, CheckpointError> {
        Self::load_folder(&existing_folder(dir))
    }

    /// Only the state of the checkpoint in `dir` (iteration, scene, counters), checked as
    /// [`Checkpoint::load`] checks it, without reading the tensors: cheap, for describing a run.
    pub fn load_state(dir: &Path) -> Result<CheckpointState, CheckpointError> {
        read_state(&existing_folder(dir))
    }

    fn load_folder(dir: &Path) -> Result<Self, CheckpointError> {
        let read = |name: &str| {
            let path = dir.join(name);
            std::fs::read(&path)
                .map(|bytes| (path.clone(), bytes))
                .map_err(|source| CheckpointError::Read { path, source })
        };
        let invalid = |path: &Path, message: String| CheckpointError::Invalid {
            path: path.to_path_buf(),
            message,
        };

        let state = read_state(dir)?;

        let (log_path, bytes) = read(LOG_FILE)?;
        let log: LogFile =
            serde_json::from_slice(&bytes).map_err(|e| invalid(&log_path, e.to_string()))?;
        if log.iteration != state.iteration {
            return Err(invalid(
                &log_path,
                format!(
                    "written at iteration {}, but {STATE_FILE} is from iteration {}",
                    log.iteration, state.iteration
                ),
            ));
        }

        let (tensor_path, bytes) = read(TENSORS_FILE)?;
        let (gaussians, shared_motion) = read_gaussian_states(&tensor_path, &bytes, &state)?;
        Ok(Self {
            state,
            gaussians,
            shared_motion,
            log: log.log,
        })
    }
}

/// `log.json`: the log and the iteration it was written at.
#[derive(Serialize, Deserialize)]
struct LogFile {
    iteration: u32,
    log: TrainingLog,
}

/// The densification statistics: `grad_accum` (f32: Σw·g, Σw, Σψ̄, max radius),
/// `grad_accum_count` (u32) and `grad_accum_offset` (f32: Σw·g·Δt).
fn accum_tensors(gaussians: &[GaussianState]) -> [NamedTensor; 3] {
    let mut floats = Vec::with_capacity(gaussians.len() * 16);
    let mut counts = Vec::with_capacity(gaussians.len() * 4);
    let mut offsets = Vec::with_capacity(gaussians.len() * 4);
    for g in gaussians {
        let a = &g.accum;
        for v in [a.weighted_grad, a.weight, a.lifespan_sum, a.max_radius] {
            floats.extend_from_slice(&v.to_le_bytes());
        }
        counts.extend_from_slice(&a.count.to_le_bytes());
        offsets.extend_from_slice(&a.weighted_offset.to_le_bytes());
    }
    [
        NamedTensor {
            name: "grad_accum".into(),
            dtype: Dtype::F32,
            width: 4,
            bytes: floats,
        },
        NamedTensor {
            name: "grad_accum_count".into(),
            dtype: Dtype::U32,
            width: 1,
            bytes: counts,
        },
        NamedTensor {
            name: "grad_accum_offset".into(),
            dtype: Dtype::F32,
            width: 1,
            bytes: offsets,
        },
    ]
}

/// `dir`, or the copy a checkpoint write left beside it when it was interrupted between its
/// renames (`dir` missing, the old one still there).
fn existing_folder(dir: &Path) -> PathBuf {
    let old = sibling(dir, "old");
    if !dir.exists() && old.is_dir() {
        tracing::warn!(
            "{} is missing; using {}, left by an interrupted checkpoint write",
            dir.display(),
            old.display()
        );
        return old;
    }
    dir.to_path_buf()
}

/// Reads and checks the state file of the checkpoint folder `dir`.
fn read_state(dir: &Path) -> Result<CheckpointState, CheckpointError> {
    let state_path = dir.join(STATE_FILE);
    let invalid = |message: String| CheckpointError::Invalid {
        path: state_path.clone(),
        message,
    };
    let bytes = std::fs::read(&state_path).map_err(|source| CheckpointError::Read {
        path: state_path.clone(),
        source,
    })?;
    let text = String::from_utf8(bytes).map_err(|_| invalid("not UTF-8 text".into()))?;
    let state: CheckpointState = ron::from_str(&text).map_err(|e| invalid(e.to_string()))?;
    if state.format != CHECKPOINT_FORMAT || state.version != CHECKPOINT_VERSION {
        return Err(invalid(format!(
            "format {:?} version {}, this tadgs reads {CHECKPOINT_FORMAT:?} version \
             {CHECKPOINT_VERSION}",
            state.format, state.version
        )));
    }
    if state.rng.restore().is_none() {
        return Err(invalid("rng.word_pos is not a number".into()));
    }
    if state.view_next > state.view_order.len() {
        return Err(invalid("view_next is past the end of view_order".into()));
    }
    Ok(state)
}

/// Reads `tensors.safetensors` and checks it against `state` (iteration, Gaussian count, and
/// the shape of the shared motion bases its scene asks for): every Gaussian's state, and the
/// shared motion bases with their Adam moments when the scene has them.
fn read_gaussian_states(
    path: &Path,
    bytes: &[u8],
    state: &CheckpointState,
) -> Result<(Vec<GaussianState>, Option<SharedMotion>), CheckpointError> {
    let invalid = |message: String| CheckpointError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    let metadata = checked_metadata(bytes, CHECKPOINT_FORMAT)
        .map_err(|e| invalid(format!("not a valid checkpoint tensor file: {e}")))?;
    let iteration = metadata
        .get("iteration")
        .and_then(|s| s.parse::<u32>().ok());
    if iteration != Some(state.iteration) {
        let written = iteration.map_or("no recorded iteration".into(), |i| {
            format!("written at iteration {i}")
        });
        return Err(invalid(format!(
            "{written}, but {STATE_FILE} is from iteration {}",
            state.iteration
        )));
    }
    let tensors = safetensors::SafeTensors::deserialize(bytes)
        .map_err(|e| invalid(format!("not a valid safetensors file: {e}")))?;
    let n = state.gaussians;
    let params = read_param_tensors(path, &tensors, "", Some(n)).map_err(|e| match e {
        ModelError::Tensor {
            message, tensor, ..
        } => invalid(format!(
            "tensor `{tensor}`: {message} ({STATE_FILE} records {n} Gaussians)"
        )),
        other => other.into(),
    })?;
    let m = read_param_tensors(path, &tensors, "adam.m.", Some(n))?;
    let v = read_param_tensors(path, &tensors, "adam.v.", Some(n))?;
    let floats = raw_tensor(&tensors, "grad_accum", Dtype::F32, [n, 4]).map_err(&invalid)?;
    let counts = raw_tensor(&tensors, "grad_accum_count", Dtype::U32, [n, 1]).map_err(&invalid)?;
    // Checkpoints written before `densify.clone_time` have no offsets: their sums start at 0.
    let offsets = match tensors.tensor("grad_accum_offset") {
        Ok(_) => {
            Some(raw_tensor(&tensors, "grad_accum_offset", Dtype::F32, [n, 1]).map_err(&invalid)?)
        }
        Err(_) => None,
    };
    // Checkpoints written before `train.deferred_adam` are current at their iteration.
    let clocks = match tensors.tensor("adam_clock") {
        Ok(_) => Some(raw_tensor(&tensors, "adam_clock", Dtype::U32, [n, 1]).map_err(&invalid)?),
        Err(_) => None,
    };
    // The shared motion, with its moments: present exactly when the scene has it.
    let shared_motion = match state.scene.model.shared_motion {
        None => None,
        Some(config) => {
            let shape = (config.bases as usize, config.knots as usize);
            let bases = |prefix: &str| {
                read_bases_tensor(
                    path,
                    &tensors,
                    &format!("{prefix}{SHARED_MOTION_TENSOR}"),
                    Some(shape),
                )
            };
            let weights = |prefix: &str| {
                read_weights_tensor(
                    path,
                    &tensors,
                    &format!("{prefix}{MOTION_WEIGHTS_TENSOR}"),
                    shape.0,
                    n,
                )
            };
            let mut shared = SharedMotion::new(bases("")?);
            shared.m = bases("adam.m.")?.values;
            shared.v = bases("adam.v.")?.values;
            Some((
                shared,
                [weights("")?, weights("adam.m.")?, weights("adam.v.")?],
            ))
        }
    };
    let word = |bytes: &[u8], i: usize| -> [u8; 4] {
        bytes[4 * i..4 * i + 4].try_into().expect("4 bytes")
    };
    let gaussians = (0..n)
        .map(|i| GaussianState {
            params: params[i],
            m: m[i],
            v: v[i],
            accum: GradAccum {
                weighted_grad: f32::from_le_bytes(word(floats, 4 * i)),
                weight: f32::from_le_bytes(word(floats, 4 * i + 1)),
                lifespan_sum: f32::from_le_bytes(word(floats, 4 * i + 2)),
                max_radius: f32::from_le_bytes(word(floats, 4 * i + 3)),
                count: u32::from_le_bytes(word(counts, i)),
                weighted_offset: offsets.map_or(0.0, |o| f32::from_le_bytes(word(o, i))),
            },
            clock: clocks.map_or(state.iteration, |c| u32::from_le_bytes(word(c, i))),
            motion_weights: shared_motion
                .as_ref()
                .map_or_else(Default::default, |(_, w)| w[0][i]),
            motion_adam: shared_motion
                .as_ref()
                .map_or_else(Default::default, |(_, w)| Adam::new(&w[1][i], &w[2][i])),
        })
        .collect();
    Ok((gaussians, shared_motion.map(|(shared, _)| shared)))
}

/// The bytes of tensor `name`, checked for type and shape.
fn raw_tensor<'data>(
    tensors: &safetensors::SafeTensors<'data>,
    name: &str,
    dtype: Dtype,
    shape: [usize; 2],
) -> Result<&'data [u8], String> {
    let view = tensors
        .tensor(name)
        .map_err(|_| format!("tensor `{name}` is missing"))?;
    if view.dtype() != dtype || view.shape() != shape {
        return Err(format!(
            "tensor `{name}` is {:?} {:?}, expected {dtype:?} {shape:?}",
            view.dtype(),
            view.shape()
        ));
    }
    Ok(view.data())
}

/// `<dir>.<suffix>` beside `dir` (same parent, so a rename between them is atomic).
fn sibling(dir: &Path, suffix: &str) -> PathBuf {
    let mut name = dir.file_name().unwrap_or_default().to_os_string();
    name.push(".");
    name.push(suffix);
    dir.with_file_name(name)
}
