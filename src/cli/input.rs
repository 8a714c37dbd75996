//! What `render`, `export` and `info` read: a run folder, a model file or a splat PLY.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use tadgs::data::Dataset;
use tadgs::io::checkpoint::{Checkpoint, STATE_FILE};
use tadgs::io::model::Model;
use tadgs::io::ply::read_splat_ply;
use tadgs::scene::SceneConfig;

use super::{load_dataset, load_with_overrides};

/// A model and, for run folders, the scene it was trained on.
pub struct Input {
    pub path: PathBuf,
    pub model: Model,
    /// The run's scene.ron with the `--set` overrides (run folders only).
    pub scene: Option<SceneConfig>,
}

impl Input {
    /// Reads `path`: a run folder (scene.ron + model.safetensors, or its checkpoint when the
    /// run has not finished), a model file
    /// (`.safetensors`, as written by `train` or `export --format 4d`) or a 3DGS splat PLY.
    pub fn load(path: &Path, overrides: &[String]) -> Result<Self> {
        let extension = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        let (model, scene) = if path.is_dir() {
            let scene = load_with_overrides(&path.join("scene.ron"), overrides)?;
            let model_path = path.join("model.safetensors");
            let checkpoint = path.join("checkpoint");
            let model = if !model_path.exists() && checkpoint.join(STATE_FILE).is_file() {
                // A run stopped before its end: its latest checkpoint.
                let checkpoint = Checkpoint::load(&checkpoint)?;
                tracing::info!(
                    "{} has no model yet: using its checkpoint of iteration {}",
                    path.display(),
                    checkpoint.state.iteration
                );
                checkpoint.model()
            } else {
                Model::load(&model_path)?
            };
            (model, Some(scene))
        } else {
            if !overrides.is_empty() {
                bail!(
                    "--set applies to run folders (scene.ron); {} is a file",
                    path.display()
                );
            }
            match extension.as_deref() {
                Some("ply") => (read_splat_ply(path)?.into_static_model(), None),
                Some("safetensors") => (Model::load(path)?, None),
                _ if !path.exists() => bail!("{}: no such file or folder", path.display()),
                _ => bail!(
                    "{}: expected a run folder, a model .safetensors file or a splat .ply file",
                    path.display()
                ),
            }
        };
        tracing::info!(
            "{}: {} Gaussians, SH degree {}",
            path.display(),
            model.gaussians.len(),
            model.sh_degree
        );
        Ok(Self {
            path: path.to_path_buf(),
            model,
            scene,
        })
    }

    /// The run's data (run folders only).
    pub fn dataset(&self) -> Result<Option<Dataset>> {
        self.scene.as_ref().map(load_dataset).transpose()
    }

    /// Makes sure the model knows its frame count: older model files do not record it, and
    /// then the run's data says.
    pub fn resolve_frame_count(&mut self, dataset: Option<&Dataset>) -> Result<usize> {
        if let Some(frames) = self.model.frame_count {
            return Ok(frames);
        }
        let frames = match dataset {
            Some(dataset) => dataset.frame_count,
            None => match &self.scene {
                Some(scene) => load_dataset(scene)?.frame_count,
                None => 1,
            },
        };
        self.model.frame_count = Some(frames);
        Ok(frames)
    }

    /// The settings to render and evaluate the model with: the run's scene, or the model's
    /// own (with `background`, default black).
    pub fn scene(&self, background: Option<[f32; 3]>) -> SceneConfig {
        let mut scene = match &self.scene {
            Some(scene) => scene.clone(),
            None => self.model.scene("model", [0.0; 3]),
        };
        if let Some(background) = background {
            scene.train.background = background;
        }
        scene
    }

    /// A name for outputs derived from the input (the folder or file stem).
    pub fn stem(&self) -> String {
        self.path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_else(|| "model".into())
    }

    /// Where outputs go by default: inside a run folder, beside a file.
    pub fn default_output(&self, name: &str) -> PathBuf {
        if self.scene.is_some() {
            self.path.join(name)
        } else {
            self.path.with_file_name(format!("{}_{name}", self.stem()))
        }
    }
}

/// Parses "r,g,b" (each in [0, 1]).
pub fn parse_rgb(text: &str) -> Result<[f32; 3], String> {
    let values: Vec<f32> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>().map_err(|e| format!("{v:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match values.as_slice() {
        &[r, g, b] if values.iter().all(|v| (0.0..=1.0).contains(v)) => Ok([r, g, b]),
        _ => Err(format!(
            "expected three values in [0, 1] as r,g,b, got {text:?}"
        )),
    }
}

/// Parses "x,y,z".
pub fn parse_vec3(text: &str) -> Result<glam::Vec3, String> {
    let values: Vec<f32> = text
        .split(',')
        .map(|v| v.trim().parse::<f32>().map_err(|e| format!("{v:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match values.as_slice() {
        &[x, y, z] if values.iter().all(|v| v.is_finite()) => Ok(glam::Vec3::new(x, y, z)),
        _ => Err(format!("expected three numbers as x,y,z, got {text:?}")),
    }
}

/// Fails unless `input` is a run folder (whose scene says where the data is).
pub fn needs_run(what: &str, input: &Input) -> Result<()> {
    if input.scene.is_none() {
        bail!(
            "{what} needs a run folder (its scene.ron says where the data is); {} is a model file",
            input.path.display()
        );
    }
    Ok(())
}

/// Creates the folder that will hold `path`, naming it on failure.
pub fn ensure_parent(path: &Path) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("creating {}", parent.display()))?;
    }
    Ok(())
}
