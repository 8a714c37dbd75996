//! Trained 4D models on disk: every parameter component of every Gaussian in one safetensors
//! file (one `N × fields` f32 tensor per component), written atomically.
//!
//! The file holds all temporal parameters (Fourier motion, temporal centre and scale,
//! rotation and scale polynomials), so `tadgs eval` and `tadgs render` can rebuild the model
//! exactly. Metadata records the format version and the SH degree in use.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use bevy_ecs::prelude::*;
use safetensors::tensor::{Dtype, TensorView};

use crate::components::{
    Color, Fourier, GaussianParams, Opacity, Param, Position, Rotation, Scale, Temporal,
};

/// Value of the `format` metadata key.
pub const MODEL_FORMAT: &str = "tadgs-4d-gaussians";
/// Version of the layout; bumped when a component's fields change.
pub const MODEL_VERSION: &str = "1";

/// A model file could not be written or read.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    #[error("cannot read model {}: {source}", path.display())]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("cannot write model {}: {source}", path.display())]
    Write {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("model {} is not a valid safetensors file: {message}", path.display())]
    Format { path: PathBuf, message: String },
    #[error("model {}: tensor `{tensor}`: {message}", path.display())]
    Tensor {
        path: PathBuf,
        tensor: String,
        message: String,
    },
}

/// A trained model: the Gaussians' parameters and the SH degree they were trained up to.
#[derive(Clone, Debug, Default)]
pub struct Model {
    pub gaussians: Vec<GaussianParams>,
    pub sh_degree: u32,
}

impl Model {
    /// Reads every Gaussian's parameters out of `world`.
    pub fn from_world(world: &mut World, sh_degree: u32) -> Self {
        let gaussians = world
            .query::<(
                &Position,
                &Fourier,
                &Temporal,
                &Opacity,
                &Rotation,
                &Scale,
                &Color,
            )>()
            .iter(world)
            .map(
                |(position, fourier, temporal, opacity, rotation, scale, color)| GaussianParams {
                    position: *position,
                    fourier: *fourier,
                    temporal: *temporal,
                    opacity: *opacity,
                    rotation: *rotation,
                    scale: *scale,
                    color: *color,
                },
            )
            .collect();
        Self {
            gaussians,
            sh_degree,
        }
    }

    /// Spawns every Gaussian into `world` with fresh optimiser state.
    pub fn spawn_into(&self, world: &mut World) {
        world.spawn_batch(self.gaussians.iter().map(|g| g.bundle()));
    }

    /// Writes the model to `path` (temporary file, then rename: complete or absent).
    pub fn save(&self, path: &Path) -> Result<(), ModelError> {
        let tensors = [
            column::<Position>(&self.gaussians, |g| &g.position),
            column::<Fourier>(&self.gaussians, |g| &g.fourier),
            column::<Temporal>(&self.gaussians, |g| &g.temporal),
            column::<Opacity>(&self.gaussians, |g| &g.opacity),
            column::<Rotation>(&self.gaussians, |g| &g.rotation),
            column::<Scale>(&self.gaussians, |g| &g.scale),
            column::<Color>(&self.gaussians, |g| &g.color),
        ];
        let n = self.gaussians.len();
        let views: Vec<(&str, TensorView<'_>)> = tensors
            .iter()
            .map(|(name, width, bytes)| {
                let view = TensorView::new(Dtype::F32, vec![n, *width], bytes)
                    .expect("shape matches the data written");
                (*name, view)
            })
            .collect();
        let metadata = HashMap::from([
            ("format".to_string(), MODEL_FORMAT.to_string()),
            ("version".to_string(), MODEL_VERSION.to_string()),
            ("sh_degree".to_string(), self.sh_degree.to_string()),
        ]);
        let bytes =
            safetensors::serialize(views, Some(metadata)).map_err(|e| ModelError::Format {
                path: path.to_path_buf(),
                message: e.to_string(),
            })?;
        super::write_atomic(path, &bytes).map_err(|source| ModelError::Write {
            path: path.to_path_buf(),
            source,
        })
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
        let (_, header) = safetensors::SafeTensors::read_metadata(&bytes)
            .map_err(|e| format_error(e.to_string()))?;
        let metadata = header.metadata().clone().unwrap_or_default();
        if metadata.get("format").map(String::as_str) != Some(MODEL_FORMAT) {
            return Err(format_error(format!(
                "metadata `format` is {:?}, expected {MODEL_FORMAT:?}",
                metadata.get("format")
            )));
        }
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
        let tensors = safetensors::SafeTensors::deserialize(&bytes)
            .map_err(|e| format_error(e.to_string()))?;
        let positions = read_column::<Position>(path, &tensors, None)?;
        let n = positions.len();
        let fourier = read_column::<Fourier>(path, &tensors, Some(n))?;
        let temporal = read_column::<Temporal>(path, &tensors, Some(n))?;
        let opacity = read_column::<Opacity>(path, &tensors, Some(n))?;
        let rotation = read_column::<Rotation>(path, &tensors, Some(n))?;
        let scale = read_column::<Scale>(path, &tensors, Some(n))?;
        let color = read_column::<Color>(path, &tensors, Some(n))?;
        let gaussians = (0..n)
            .map(|i| GaussianParams {
                position: positions[i],
                fourier: fourier[i],
                temporal: temporal[i],
                opacity: opacity[i],
                rotation: rotation[i],
                scale: scale[i],
                color: color[i],
            })
            .collect();
        Ok(Self {
            gaussians,
            sh_degree,
        })
    }
}

/// One component of every Gaussian as little-endian f32 bytes: (name, fields, bytes).
fn column<P: Param>(
    gaussians: &[GaussianParams],
    field: impl Fn(&GaussianParams) -> &P,
) -> (&'static str, usize, Vec<u8>) {
    let width = P::default().values().len();
    let mut bytes = Vec::with_capacity(gaussians.len() * width * 4);
    for g in gaussians {
        for v in field(g).values() {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    (P::NAME, width, bytes)
}

/// Reads tensor `P::NAME` as `rows × fields` f32 values; `rows` must match when given.
fn read_column<P: Param>(
    path: &Path,
    tensors: &safetensors::SafeTensors<'_>,
    rows: Option<usize>,
) -> Result<Vec<P>, ModelError> {
    let tensor_error = |message: String| ModelError::Tensor {
        path: path.to_path_buf(),
        tensor: P::NAME.to_string(),
        message,
    };
    let view = tensors
        .tensor(P::NAME)
        .map_err(|_| tensor_error("missing".into()))?;
    let width = P::default().values().len();
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
    let mut out = vec![P::default(); shape[0]];
    for (item, chunk) in out.iter_mut().zip(view.data().chunks_exact(width * 4)) {
        for (value, bytes) in item.values_mut().iter_mut().zip(chunk.chunks_exact(4)) {
            *value = f32::from_le_bytes(bytes.try_into().expect("chunks of 4 bytes"));
        }
    }
    if out
        .iter()
        .any(|p| p.values().iter().any(|v| !v.is_finite()))
    {
        return Err(tensor_error("holds NaN or infinite values".into()));
    }
    Ok(out)
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
                g.color.sh[5] = [0.01, 0.02, 0.03];
                g
            })
            .collect();
        Model {
            gaussians,
            sh_degree: 2,
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
