//! Trained 4D models on disk: every parameter component of every Gaussian in one safetensors
//! file (one `N × fields` f32 tensor per component), written atomically.
//!
//! The file holds all temporal parameters (Fourier motion, temporal centre and scale,
//! rotation and scale polynomials), so `tadgs eval` and `tadgs render` can rebuild the model
//! exactly. Metadata records the format version, the SH degree in use and, when known, the
//! number of frames and the deformation settings (`model` of the scene file, as RON), which
//! make the file self-contained: `tadgs render` and `tadgs export` need nothing else.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;
use safetensors::tensor::{Dtype, TensorView};

use crate::components::{
    Adam, GaussianParams, Grad, MotionWeights, ParamRefs, TimeWindow, spawn_gaussians,
    spawn_gaussians_with,
};
use crate::gpu::GpuError;
use crate::layout::{SECTION_NAMES, SECTIONS, WIDTHS, gaussians_of, sections_of};
use crate::model::shared_motion::{MAX_MOTION_BASES, MotionBases};
use crate::resources::SharedMotion;
use crate::scene::{BackendKind, DataSource, ModelConfig, SceneConfig};

/// Name of the optional `N × 3` tensor of time windows (start, end, fade) of a merged
/// segment model.
pub const TIME_WINDOW_TENSOR: &str = "time_window";

/// Name of the `B × 3K` tensor of shared motion bases U (`model.shared_motion`): row b holds
/// U[b][0..K] as x, y, z per knot.
pub const SHARED_MOTION_TENSOR: &str = "shared_motion";

/// Name of the `N × B` tensor of each Gaussian's weights of the shared motion bases.
pub const MOTION_WEIGHTS_TENSOR: &str = "motion_weights";

/// Value of the `format` metadata key.
pub const MODEL_FORMAT: &str = "tadgs-4d-gaussians";
/// Version of the layout; bumped when a component's fields change.
pub const MODEL_VERSION: &str = "1";

/// A model file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The file could not be read.
    #[error("cannot read model {}: {source}", path.display())]
    Read {
        /// The model file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file could not be written (atomically, through a temporary file beside it).
    #[error("cannot write model {}: {source}", path.display())]
    Write {
        /// The model file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not a safetensors file of this format and version, or its metadata
    /// (`sh_degree`, `frame_count`, `model`) is invalid; when saving, the tensors or the
    /// metadata could not be serialised.
    #[error("model {} is not a valid safetensors file: {message}", path.display())]
    Format {
        /// The model file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// A parameter tensor is missing, not `f32`, of the wrong shape, or holds NaN or infinite
    /// values.
    #[error("model {}: tensor `{tensor}`: {message}", path.display())]
    Tensor {
        /// The model (or checkpoint tensor) file.
        path: PathBuf,
        /// The tensor's name (a [`Param::NAME`], with a prefix in checkpoints).
        tensor: String,
        /// What is wrong with it.
        message: String,
    },
}

/// A trained model: the Gaussians' parameters and the SH degree they were trained up to.
#[derive(Clone, Debug, Default)]
pub struct Model {
    /// Every Gaussian's parameter components.
    pub gaussians: Vec<GaussianParams>,
    /// SH degree in use at the end of training (0..=3).
    pub sh_degree: u32,
    /// Frames T of the sequence it was trained on (sets the TOW window); `None` in files that
    /// do not record it.
    pub frame_count: Option<usize>,
    /// The deformation settings it was trained with; `None` in files that do not record them.
    pub config: Option<ModelConfig>,
    /// One time window per Gaussian in a model merged from temporal segments (`tadgs segment
    /// merge`); `None` in trained models, whose Gaussians draw at every time.
    pub time_windows: Option<Vec<TimeWindow>>,
    /// The shared motion bases and each Gaussian's weights, in a model trained with
    /// `model.shared_motion`; `None` otherwise.
    pub shared_motion: Option<ModelMotion>,
}

/// The shared motion of a model (`model.shared_motion`, see
/// [`crate::model::shared_motion`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ModelMotion {
    /// The bases U.
    pub bases: MotionBases,
    /// Each Gaussian's weights, in the order of [`Model::gaussians`].
    pub weights: Vec<MotionWeights>,
}

impl Model {
    /// Reads every Gaussian's parameters out of `world`.
    pub fn from_world(world: &mut World, sh_degree: u32) -> Self {
        let mut gaussians = Vec::new();
        let mut windows = Vec::new();
        let mut weights = Vec::new();
        let mut rows = world.query::<(ParamRefs, Option<&TimeWindow>, Option<&MotionWeights>)>();
        for (params, window, w) in rows.iter(world) {
            gaussians.push(GaussianParams::from_refs(params));
            windows.push(window.copied());
            // A Gaussian without weights has no shared motion: weights 0 draw it alike.
            weights.push(w.copied().unwrap_or_default());
        }
        let time_windows = windows.iter().any(Option::is_some).then(|| {
            windows
                .iter()
                .map(|w| w.unwrap_or(TimeWindow::ALWAYS))
                .collect()
        });
        let shared_motion = world
            .get_resource::<SharedMotion>()
            .map(|shared| ModelMotion {
                bases: shared.bases.clone(),
                weights,
            });
        Self {
            gaussians,
            sh_degree,
            frame_count: None,
            config: None,
            time_windows,
            shared_motion,
        }
    }

    /// Fails when `backend` cannot draw this model: the GPU backend draws no time windows and
    /// no shared motion bases.
    pub fn check_backend(&self, backend: BackendKind) -> Result<(), GpuError> {
        if backend == BackendKind::Gpu && self.time_windows.is_some() {
            return Err(GpuError::Unsupported(
                "the time windows of a merged segment model",
            ));
        }
        if backend == BackendKind::Gpu && self.shared_motion.is_some() {
            return Err(GpuError::Unsupported(
                "the shared motion bases of a model trained with `model.shared_motion`",
            ));
        }
        Ok(())
    }

    /// A scene that renders this model on its own: its deformation settings (the defaults when
    /// unknown) and `background`. The data source is a placeholder that is never loaded.
    pub fn scene(&self, name: &str, background: [f32; 3]) -> SceneConfig {
        let mut scene = SceneConfig::new(
            name,
            DataSource::Synthetic(crate::data::synthetic::demo_scene()),
        );
        if let Some(config) = &self.config {
            scene.model = config.clone();
        }
        scene.model.sh_degree = self.sh_degree;
        scene.train.background = background;
        scene
    }

    /// The ways in which this model does not belong to `scene` with `frame_count` frames: a
    /// different number of frames (time would be normalised differently), other deformation
    /// settings, or a higher SH degree than the scene allows. Empty when they match (or the
    /// file does not record the value).
    pub fn mismatches(&self, scene: &SceneConfig, frame_count: usize) -> Vec<String> {
        let mut found = Vec::new();
        if let Some(frames) = self.frame_count.filter(|&f| f != frame_count) {
            found.push(format!(
                "the model was trained on {frames} frames, the scene's data has {frame_count}"
            ));
        }
        if let Some(config) = &self.config {
            let mut ours = config.clone();
            ours.sh_degree = scene.model.sh_degree;
            if ours != scene.model {
                found.push(
                    "the model's deformation settings (`model` of its scene) differ from the scene's"
                        .into(),
                );
            }
        }
        if self.sh_degree > scene.model.sh_degree {
            found.push(format!(
                "the model uses SH degree {}, the scene allows {}",
                self.sh_degree, scene.model.sh_degree
            ));
        }
        found
    }

    /// Spawns every Gaussian into `world` with fresh optimiser state, with the higher SH
    /// bands when the model's degree, or that of the scene in the world's
    /// [`Settings`](crate::resources::Settings) (training on from the model), is above 0.
    /// A model with shared motion also puts its bases into the world's [`SharedMotion`]
    /// (replacing any there, with fresh Adam moments) and gives each Gaussian its weights.
    pub fn spawn_into(&self, world: &mut World) {
        let scene_degree = world
            .get_resource::<crate::resources::Settings>()
            .map_or(0, |s| s.model.sh_degree);
        let sh_degree = self.sh_degree.max(scene_degree);
        let bundles = self
            .gaussians
            .iter()
            .map(|g| (g.bundle(), g.optional_bundle()));
        let weights = self.shared_motion.as_ref().map(|motion| {
            world.insert_resource(SharedMotion::new(motion.bases.clone()));
            motion.weights.iter().map(|&w| {
                (
                    w,
                    Grad::<MotionWeights>::default(),
                    Adam::<MotionWeights>::default(),
                )
            })
        });
        match (&self.time_windows, weights) {
            (None, None) => spawn_gaussians(world, sh_degree, bundles),
            (Some(windows), None) => spawn_gaussians_with(
                world,
                sh_degree,
                bundles
                    .zip(windows)
                    .map(|((bundle, optional), window)| (bundle, optional, *window)),
            ),
            (None, Some(weights)) => spawn_gaussians_with(
                world,
                sh_degree,
                bundles
                    .zip(weights)
                    .map(|((bundle, optional), weights)| (bundle, optional, weights)),
            ),
            (Some(windows), Some(weights)) => spawn_gaussians_with(
                world,
                sh_degree,
                bundles
                    .zip(windows)
                    .zip(weights)
                    .map(|(((bundle, optional), window), weights)| {
                        (bundle, optional, (*window, weights))
                    }),
            ),
        }
    }

    /// Writes the model to `path` (temporary file, then rename: complete or absent).
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let mut metadata = HashMap::from([
            ("format".to_string(), MODEL_FORMAT.to_string()),
            ("version".to_string(), MODEL_VERSION.to_string()),
            ("sh_degree".to_string(), self.sh_degree.to_string()),
        ]);
        if let Some(frames) = self.frame_count {
            metadata.insert("frame_count".into(), frames.to_string());
        }
        if let Some(config) = &self.config {
            let text = ron::to_string(config).map_err(|e| ModelError::Format {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
            metadata.insert("model".into(), text);
        }
        let mut tensors = param_tensors(&self.gaussians, "");
        if let Some(windows) = &self.time_windows {
            tensors.push(float_tensor(
                TIME_WINDOW_TENSOR.into(),
                3,
                bytemuck::cast_slice(windows),
            ));
        }
        if let Some(motion) = &self.shared_motion {
            tensors.push(bases_tensor(SHARED_MOTION_TENSOR.into(), &motion.bases));
            tensors.push(weights_tensor(
                MOTION_WEIGHTS_TENSOR.into(),
                motion.bases.bases,
                &motion.weights,
            ));
        }
        write_tensors(path, &tensors, metadata)
    }

    /// Reads a model written by [`Model::save`], checking every tensor's type and shape.
    pub fn load(path: &Path) -> Result<Self, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let format_error = |message: String| ModelError::Format {
            path: path.to_path_buf(),
            message,
        };
        let metadata = checked_metadata(&bytes, MODEL_FORMAT).map_err(format_error)?;
        if metadata.get("version").map(String::as_str) != Some(MODEL_VERSION) {
            return Err(format_error(format!(
                "metadata `version` is {:?}, this tadgs reads version {MODEL_VERSION}",
                metadata.get("version")
            )));
        }
        let sh_degree = metadata
            .get("sh_degree")
            .and_then(|s| s.parse::<u32>().ok())
            .filter(|&d| d <= 3)
            .ok_or_else(|| format_error("metadata `sh_degree` must be 0..=3".into()))?;
        let frame_count =
            match metadata.get("frame_count") {
                None => None,
                Some(text) => Some(text.parse::<usize>().ok().filter(|n| (1..=crate::data::MAX_FRAMES).contains(n)).ok_or_else(
                    || {
                        format_error(format!(
                            "metadata `frame_count` is {text:?}, expected a whole number from 1 to {}", crate::data::MAX_FRAMES
                        ))
                    },
                )?),
            };
        let config = match metadata.get("model") {
            None => None,
            Some(text) => Some(
                ron::from_str::<ModelConfig>(text)
                    .map_err(|e| format_error(format!("metadata `model`: {e}")))?,
            ),
        };
        let tensors = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| format_error(e.to_string()))?;
        let gaussians = read_param_tensors(path, &tensors, "", None)?;
        let time_windows = if tensors.names().contains(&TIME_WINDOW_TENSOR) {
            let values = read_floats(
                path,
                &tensors,
                TIME_WINDOW_TENSOR.into(),
                3,
                Some(gaussians.len()),
            )?;
            let windows = bytemuck::cast_slice::<f32, TimeWindow>(&values).to_vec();
            if let Some(index) = windows
                .iter()
                .position(|w| !(w.fade >= 0.0 && w.start <= w.end))
            {
                return Err(ModelError::Tensor {
                    path: path.to_path_buf(),
                    tensor: TIME_WINDOW_TENSOR.into(),
                    message: format!(
                        "row {index} is {:?}: a window needs start ≤ end and fade ≥ 0",
                        windows[index]
                    ),
                });
            }
            Some(windows)
        } else {
            None
        };
        let shared_motion = read_model_motion(path, &tensors, "", gaussians.len())?;
        if let (Some(motion), Some(wanted)) = (
            &shared_motion,
            config.as_ref().and_then(|c| c.shared_motion),
        ) && (motion.bases.bases, motion.bases.knots)
            != (wanted.bases as usize, wanted.knots as usize)
        {
            return Err(format_error(format!(
                "tensor `{SHARED_MOTION_TENSOR}` holds {} bases of {} knots, but metadata \
                 `model` asks for {} of {}",
                motion.bases.bases, motion.bases.knots, wanted.bases, wanted.knots
            )));
        }
        Ok(Self {
            gaussians,
            sh_degree,
            frame_count,
            config,
            time_windows,
            shared_motion,
        })
    }
}

/// The shared motion bases `bases` as the F32 tensor `name` of shape [B, 3K].
pub(crate) fn bases_tensor(name: String, bases: &MotionBases) -> NamedTensor {
    float_tensor(
        name,
        3 * bases.knots,
        bytemuck::cast_slice(bases.values.as_slice()),
    )
}

/// The first `bases` weights of each Gaussian as the F32 tensor `name` of shape [N, B].
pub(crate) fn weights_tensor(name: String, bases: usize, weights: &[MotionWeights]) -> NamedTensor {
    let values: Vec<f32> = weights
        .iter()
        .flat_map(|w| w.w[..bases].iter().copied())
        .collect();
    float_tensor(name, bases, &values)
}

/// Reads the tensor `name` written by [`bases_tensor`]; `shape` (B, K) must match when given.
pub(crate) fn read_bases_tensor(
    path: &Path,
    tensors: &safetensors::SafeTensors<'_>,
    name: &str,
    shape: Option<(usize, usize)>,
) -> Result<MotionBases, ModelError> {
    let tensor_error = |message: String| ModelError::Tensor {
        path: path.to_path_buf(),
        tensor: name.to_string(),
        message,
    };
    let view = tensors
        .tensor(name)
        .map_err(|_| tensor_error("missing".into()))?;
    let (bases, knots) = match view.shape() {
        &[rows, width] if width % 3 == 0 => (rows, width / 3),
        other => {
            return Err(tensor_error(format!(
                "shape {other:?}, expected [B, 3K] (x, y, z of each knot per basis)"
            )));
        }
    };
    if !(1..=MAX_MOTION_BASES).contains(&bases) || knots < 2 {
        return Err(tensor_error(format!(
            "{bases} bases of {knots} knots: expected 1 to {MAX_MOTION_BASES} bases of at least \
             2 knots"
        )));
    }
    if let Some((want_bases, want_knots)) = shape
        && (bases, knots) != (want_bases, want_knots)
    {
        return Err(tensor_error(format!(
            "{bases} bases of {knots} knots, expected {want_bases} of {want_knots}"
        )));
    }
    let values = read_floats(path, tensors, name.to_string(), 3 * knots, Some(bases))?;
    Ok(MotionBases {
        bases,
        knots,
        values: bytemuck::cast_slice::<f32, [f32; 3]>(&values).to_vec(),
    })
}

/// Reads the tensor `name` written by [`weights_tensor`]: `rows` Gaussians of `bases` weights.
pub(crate) fn read_weights_tensor(
    path: &Path,
    tensors: &safetensors::SafeTensors<'_>,
    name: &str,
    bases: usize,
    rows: usize,
) -> Result<Vec<MotionWeights>, ModelError> {
    let values = read_floats(path, tensors, name.to_string(), bases, Some(rows))?;
    Ok(values
        .chunks_exact(bases.max(1))
        .map(|row| {
            let mut w = MotionWeights::default();
            w.w[..bases].copy_from_slice(row);
            w
        })
        .collect())
}

/// The shared motion of a model or checkpoint file (tensors `prefix` + `shared_motion` and
/// `motion_weights`, `rows` Gaussians): `None` when it has neither, an error when it has only
/// one of them.
pub(crate) fn read_model_motion(
    path: &Path,
    tensors: &safetensors::SafeTensors<'_>,
    prefix: &str,
    rows: usize,
) -> Result<Option<ModelMotion>, ModelError> {
    let (bases_name, weights_name) = (
        format!("{prefix}{SHARED_MOTION_TENSOR}"),
        format!("{prefix}{MOTION_WEIGHTS_TENSOR}"),
    );
    let names = tensors.names();
    match (
        names.contains(&bases_name.as_str()),
        names.contains(&weights_name.as_str()),
    ) {
        (false, false) => Ok(None),
        (true, true) => {
            let bases = read_bases_tensor(path, tensors, &bases_name, None)?;
            let weights = read_weights_tensor(path, tensors, &weights_name, bases.bases, rows)?;
            Ok(Some(ModelMotion { bases, weights }))
        }
        (has_bases, _) => {
            let (present, missing) = if has_bases {
                (&bases_name, &weights_name)
            } else {
                (&weights_name, &bases_name)
            };
            Err(ModelError::Tensor {
                path: path.to_path_buf(),
                tensor: missing.clone(),
                message: format!("missing, though tensor `{present}` is there (shared motion)"),
            })
        }
    }
}

/// The metadata of a safetensors file, checked to name `expected` as its `format`.
pub(crate) fn checked_metadata(
    bytes: &[u8],
    expected: &str,
) -> Result<HashMap<String, String>, String> {
    let (_, header) = safetensors::SafeTensors::read_metadata(bytes).map_err(|e| e.to_string())?;
    let metadata = header.metadata().clone().unwrap_or_default();
    if metadata.get("format").map(String::as_str) != Some(expected) {
        return Err(format!(
            "metadata `format` is {:?}, expected {expected:?}",
            metadata.get("format")
        ));
    }
    Ok(metadata)
}

/// A named `rows × width` tensor as little-endian bytes.
pub(crate) struct NamedTensor {
    pub name: String,
    pub dtype: Dtype,
    pub width: usize,
    pub bytes: Vec<u8>,
}

/// Serialises `tensors` (all with the same number of rows) and `metadata` to `path`,
/// atomically.
pub(crate) fn write_tensors(
    path: &Path,
    tensors: &[NamedTensor],
    metadata: HashMap<String, String>,
) -> Result<(), ModelError> {
    let views: Vec<(&str, TensorView<'_>)> = tensors
        .iter()
        .map(|t| {
            let rows = t.bytes.len() / (4 * t.width.max(1));
            let view = TensorView::new(t.dtype, vec![rows, t.width], &t.bytes)
                .expect("shape matches the data written");
            (t.name.as_str(), view)
        })
        .collect();
    let bytes = safetensors::serialize(views, Some(metadata)).map_err(|e| ModelError::Format {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    super::write_atomic(path, &bytes).map_err(|source| ModelError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Every parameter group of `gaussians`, one tensor per section of the layout
/// ([`crate::layout`]), named `prefix` + section name: the `color` tensor holds every SH band
/// (48 values per Gaussian) whether or not the Gaussians carry
/// [`crate::components::ColorRest`], so files do not depend on the in-memory layout.
pub(crate) fn param_tensors(gaussians: &[GaussianParams], prefix: &str) -> Vec<NamedTensor> {
    let sections = sections_of(gaussians);
    sections
        .iter()
        .zip(SECTION_NAMES)
        .zip(WIDTHS)
        .map(|((values, section), width)| float_tensor(format!("{prefix}{section}"), width, values))
        .collect()
}

/// Reads the tensors written by [`param_tensors`] with the same `prefix`; `rows` must match
/// when given.
pub(crate) fn read_param_tensors(
    path: &Path,
    tensors: &safetensors::SafeTensors<'_>,
    prefix: &str,
    rows: Option<usize>,
) -> Result<Vec<GaussianParams>, ModelError> {
    let mut rows = rows;
    let mut sections: [Vec<f32>; SECTIONS] = Default::default();
    for ((section, name), width) in sections.iter_mut().zip(SECTION_NAMES).zip(WIDTHS) {
        *section = read_floats(path, tensors, format!("{prefix}{name}"), width, rows)?;
        rows = Some(section.len() / width);
    }
    Ok(gaussians_of(&sections))
}

/// `values`, `width` per row, as the F32 tensor `name`.
fn float_tensor(name: String, width: usize, values: &[f32]) -> NamedTensor {
    NamedTensor {
        name,
        dtype: Dtype::F32,
        width,
        bytes: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

/// Reads the F32 tensor `name` of shape [rows, `width`], refusing NaN and infinite values;
/// `rows` must match when given.
pub(crate) fn read_floats(
    path: &Path,
    tensors: &safetensors::SafeTensors<'_>,
    name: String,
    width: usize,
    rows: Option<usize>,
) -> Result<Vec<f32>, ModelError> {
    let tensor_error = |message: String| ModelError::Tensor {
        path: path.to_path_buf(),
        tensor: name.clone(),
        message,
    };
    let view = tensors
        .tensor(&name)
        .map_err(|_| tensor_error("missing".into()))?;
    if view.dtype() != Dtype::F32 {
        return Err(tensor_error(format!(
            "dtype {:?}, expected F32",
            view.dtype()
        )));
    }
    let shape = view.shape();
    if shape.len() != 2 || shape[1] != width || rows.is_some_and(|n| n != shape[0]) {
        return Err(tensor_error(format!(
            "shape {shape:?}, expected [{}, {width}]",
            rows.map_or("N".to_string(), |n| n.to_string())
        )));
    }
    let values: Vec<f32> = view
        .data()
        .chunks_exact(4)
        .map(|bytes| f32::from_le_bytes(bytes.try_into().expect("chunks of 4 bytes")))
        .collect();
    if values.iter().any(|v| !v.is_finite()) {
        return Err(tensor_error("holds NaN or infinite values".into()));
    }
    Ok(values)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_model() -> Model {
        let gaussians = (0..5)
            .map(|i| {
                let mut g = GaussianParams::default();
                g.position.mean = [i as f32, 0.5, -1.0];
                g.fourier.cos[2] = [0.1 * i as f32, 0.2, 0.3];
                g.fourier.phase[0] = 0.7;
                g.temporal.center = 0.25;
                g.temporal.scale = [1.5, -0.5];
                g.opacity.logit = -2.0;
                g.rotation.c0 = [1.0, 0.0, 0.0, 0.0];
                g.rotation.c1 = [0.0, 0.1, 0.0, 0.0];
                g.scale.d0 = [-3.0; 3];
                g.color_rest.sh[4] = [0.01, 0.02, 0.03];
                g
            })
            .collect();
        Model {
            gaussians,
            sh_degree: 2,
            frame_count: Some(30),
            config: Some(ModelConfig {
                scale_motion: false,
                ..ModelConfig::default()
            }),
            time_windows: None,
            shared_motion: None,
        }
    }

    /// Writing a model and reading it back gives the same parameters bit for bit.
    #[test]
    fn save_and_load_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.safetensors");
        let model = sample_model();
        model.save(&path).unwrap();
        let back = Model::load(&path).unwrap();
        assert_eq!(back.sh_degree, 2);
        assert_eq!(back.frame_count, Some(30));
        assert_eq!(back.config, model.config);
        assert_eq!(back.gaussians.len(), 5);
        for (a, b) in model.gaussians.iter().zip(&back.gaussians) {
            assert_eq!(a.position, b.position);
            assert_eq!(a.fourier, b.fourier);
            assert_eq!(a.temporal, b.temporal);
            assert_eq!(a.opacity, b.opacity);
            assert_eq!(a.rotation, b.rotation);
            assert_eq!(a.scale, b.scale);
            assert_eq!(a.color, b.color);
        }
        // Nothing but the model is left in the folder (no temporary file).
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, vec![std::ffi::OsString::from("model.safetensors")]);
    }

    /// Property: a merged model's time windows survive saving, come back as components of
    /// the spawned Gaussians (and out of the world again), and a window with a negative fade
    /// or its ends swapped is refused naming the tensor and row.
    #[test]
    fn time_windows_round_trip_and_bad_windows_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("merged.safetensors");
        let mut model = sample_model();
        let windows: Vec<TimeWindow> = (0..5)
            .map(|i| TimeWindow {
                start: i as f32 * 0.1,
                end: 0.5 + i as f32 * 0.1,
                fade: 0.01,
            })
            .collect();
        model.time_windows = Some(windows.clone());
        model.save(&path).unwrap();
        let back = Model::load(&path).unwrap();
        assert_eq!(back.time_windows.as_deref(), Some(windows.as_slice()));
        assert!(back.check_backend(BackendKind::Gpu).is_err());
        assert!(back.check_backend(BackendKind::Cpu).is_ok());
        assert!(
            Model::load(&{
                let plain = dir.path().join("plain.safetensors");
                sample_model().save(&plain).unwrap();
                plain
            })
            .unwrap()
            .time_windows
            .is_none()
        );

        let mut world = World::new();
        back.spawn_into(&mut world);
        let mut spawned: Vec<TimeWindow> =
            world.query::<&TimeWindow>().iter(&world).copied().collect();
        spawned.sort_by(|a, b| a.start.total_cmp(&b.start));
        assert_eq!(spawned, windows);
        let mut again = Model::from_world(&mut world, 2).time_windows.unwrap();
        again.sort_by(|a, b| a.start.total_cmp(&b.start));
        assert_eq!(again, windows);

        for bad in [
            TimeWindow {
                start: 0.0,
                end: 1.0,
                fade: -0.1,
            },
            TimeWindow {
                start: 0.6,
                end: 0.5,
                fade: 0.0,
            },
        ] {
            let mut model = sample_model();
            let mut rows = windows.clone();
            rows[3] = bad;
            model.time_windows = Some(rows);
            model.save(&path).unwrap();
            let message = Model::load(&path).unwrap_err().to_string();
            assert!(
                message.contains("time_window") && message.contains("row 3"),
                "{message}"
            );
        }
    }

    /// A model's shared motion (bases and per-Gaussian weights) survives saving bit for bit,
    /// comes back into a world as its resource and components (and out again); a file with
    /// only one of its two tensors is refused naming the missing one; the GPU backend refuses
    /// such a model.
    #[test]
    fn shared_motion_round_trips_and_half_of_it_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("shared.safetensors");
        let mut model = sample_model();
        let mut bases = MotionBases::zeros(3, 4);
        for (i, v) in bases.values.iter_mut().enumerate() {
            *v = [i as f32 * 0.01, -0.02, 0.5 - i as f32 * 0.03];
        }
        let weights: Vec<MotionWeights> = (0..5)
            .map(|i| {
                let mut w = MotionWeights::default();
                w.w[..3].copy_from_slice(&[0.1 * i as f32, -0.05, 0.2]);
                w
            })
            .collect();
        model.shared_motion = Some(ModelMotion {
            bases: bases.clone(),
            weights: weights.clone(),
        });
        model.save(&path).unwrap();
        let back = Model::load(&path).unwrap();
        assert_eq!(back.shared_motion, model.shared_motion);
        assert!(back.check_backend(BackendKind::Gpu).is_err());

        let mut world = World::new();
        back.spawn_into(&mut world);
        assert_eq!(world.resource::<SharedMotion>().bases, bases);
        let again = Model::from_world(&mut world, 2).shared_motion.unwrap();
        let sorted = |mut w: Vec<MotionWeights>| {
            w.sort_by(|a, b| a.w[0].total_cmp(&b.w[0]));
            w
        };
        assert_eq!(sorted(again.weights), sorted(weights));

        let bytes = std::fs::read(&path).unwrap();
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
        let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
        for dropped in [SHARED_MOTION_TENSOR, MOTION_WEIGHTS_TENSOR] {
            let kept: Vec<_> = tensors
                .tensors()
                .into_iter()
                .filter(|(name, _)| name != dropped)
                .collect();
            let half = dir.path().join("half.safetensors");
            safetensors::serialize_to_file(kept, header.metadata().clone(), &half).unwrap();
            let message = Model::load(&half).unwrap_err().to_string();
            assert!(message.contains(&format!("`{dropped}`")), "{message}");
        }
    }

    /// A truncated file is an error naming the file, never a panic.
    #[test]
    fn truncated_model_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("model.safetensors");
        sample_model().save(&path).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        std::fs::write(&path, &bytes[..bytes.len() - 7]).unwrap();
        let error = Model::load(&path).unwrap_err().to_string();
        assert!(error.contains("model.safetensors"), "{error}");
    }
}
