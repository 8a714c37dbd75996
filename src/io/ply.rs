//! Gaussian splats as PLY files in the standard 3DGS layout, which splat viewers open.
//!
//! Layout (binary little endian, one `vertex` element, every property `float`, in this order):
//! `x y z nx ny nz f_dc_0..2 f_rest_0..(3·((d+1)²−1) − 1) opacity scale_0..2 rot_0..3`,
//! where d is the SH degree (0–3; 0, 9, 24 or 45 `f_rest` values). Conventions, as in 3DGS:
//! opacity is a logit, scales are natural logs, the rotation is a quaternion (w, x, y, z)
//! (unnormalised on input), `f_rest` is channel-major (all red coefficients of bands 1..d,
//! then green, then blue), colour = SH + 0.5, normals are zero.
//!
//! A 4D model is written per frame: every Gaussian evaluated at one time ([`snapshot`]). A
//! static PLY reads back as time-invariant Gaussians ([`SplatCloud::into_static_model`]), so
//! splats trained elsewhere render and export like a tadgs model.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use glam::Vec3;
use ply_rs_bw::parser::{Parser, Reader};
use ply_rs_bw::ply::{ElementDef, Property, PropertyAccess, PropertyAccessResult};

use crate::components::{
    Fourier, GaussianParams, Opacity, Position, Rotation, Scale, Temporal, split_sh,
};
use crate::io::model::Model;
use crate::model::deform::{
    fourier_offset, logit, rotation_at, scale_velocity, temporal_opacity, window_factor,
};
use crate::model::sh::{SH_COEFFS, coeff_count};
use crate::model::shared_motion::shared_offset;
use crate::resources::Settings;
use crate::scene::{ModelConfig, OpacityModel};

/// Raw temporal scale of an imported static Gaussian: ψ = e^−30 ≈ 1e−13, so the RBF factor
/// exp(−ψ·Δt'²) is exactly 1 in f32 for every time in the sequence.
pub const STATIC_TEMPORAL_RAW: f32 = -30.0;

/// A PLY file could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum PlyError {
    /// The file could not be opened or read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The PLY file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file could not be written (atomically, through a temporary file beside it).
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The PLY file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not a 3DGS splat PLY: unparseable header or body, a missing property, an
    /// `f_rest_*` count that is no SH degree 0–3, or a NaN or infinite value.
    #[error("{}: {message}", path.display())]
    Format {
        /// The PLY file.
        path: PathBuf,
        /// What is wrong with it.
        message: String,
    },
}

/// One Gaussian at a fixed time, in the 3DGS parametrisation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StaticSplat {
    /// World-space centre (`x y z`).
    pub mean: [f32; 3],
    /// SH coefficients, `sh[k][channel]`; only the first (d + 1)² are written.
    pub sh: [[f32; 3]; SH_COEFFS],
    /// Opacity as a logit (`opacity`); for a [`snapshot`], logit of σ(t), the temporal factor
    /// included.
    pub opacity_logit: f32,
    /// Natural log of the per-axis standard deviations (`scale_0..2`).
    pub log_scale: [f32; 3],
    /// Quaternion (w, x, y, z).
    pub rotation: [f32; 4],
}

/// A static set of Gaussians and the SH degree its colours use.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SplatCloud {
    /// SH degree 0–3: how many coefficients of each splat are meaningful and written.
    pub sh_degree: u32,
    /// The Gaussians, in file order.
    pub splats: Vec<StaticSplat>,
}

/// The vertex property names of the standard layout at SH degree `sh_degree`, in file order.
pub fn property_names(sh_degree: u32) -> Vec<String> {
    let mut names: Vec<String> = ["x", "y", "z", "nx", "ny", "nz"].map(String::from).into();
    names.extend((0..3).map(|i| format!("f_dc_{i}")));
    names.extend((0..rest_count(sh_degree)).map(|i| format!("f_rest_{i}")));
    names.push("opacity".into());
    names.extend((0..3).map(|i| format!("scale_{i}")));
    names.extend((0..4).map(|i| format!("rot_{i}")));
    names
}

/// Number of `f_rest` values at `sh_degree`: 3 channels × the coefficients above band 0.
fn rest_count(sh_degree: u32) -> usize {
    3 * (coeff_count(sh_degree) - 1)
}

/// Writes `cloud` as a binary little-endian PLY in the standard layout, atomically.
pub fn write_splat_ply(path: &Path, cloud: &SplatCloud) -> Result<(), PlyError> {
    let names = property_names(cloud.sh_degree);
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n",
        cloud.splats.len()
    );
    for name in &names {
        header.push_str(&format!("property float {name}\n"));
    }
    header.push_str("end_header\n");
    let rest = coeff_count(cloud.sh_degree);
    let mut bytes = Vec::with_capacity(header.len() + cloud.splats.len() * names.len() * 4);
    bytes.extend_from_slice(header.as_bytes());
    let mut push = |v: f32| bytes.extend_from_slice(&v.to_le_bytes());
    for s in &cloud.splats {
        s.mean.into_iter().for_each(&mut push);
        [0.0; 3].into_iter().for_each(&mut push);
        s.sh[0].into_iter().for_each(&mut push);
        for channel in 0..3 {
            (1..rest).for_each(|k| push(s.sh[k][channel]));
        }
        push(s.opacity_logit);
        s.log_scale.into_iter().for_each(&mut push);
        s.rotation.into_iter().for_each(&mut push);
    }
    super::write_atomic(path, &bytes).map_err(|source| PlyError::Write {
        path: path.to_path_buf(),
        source,
    })
}

/// Slots of the properties in [`SplatVertex::values`].
const F_DC: usize = 3;
const F_REST: usize = 6;
const OPACITY: usize = F_REST + 45;
const SCALE: usize = OPACITY + 1;
const ROT: usize = SCALE + 3;
const SLOTS: usize = ROT + 4;

/// One vertex of a splat PLY: every property of the standard layout by slot.
struct SplatVertex {
    values: [f32; SLOTS],
}

/// The slot of a standard property name, if it is one.
fn slot(name: &str) -> Option<usize> {
    let indexed = |prefix: &str, count: usize| {
        name.strip_prefix(prefix)
            .and_then(|i| i.parse::<usize>().ok())
            .filter(|&i| i < count)
    };
    match name {
        "x" => Some(0),
        "y" => Some(1),
        "z" => Some(2),
        "opacity" => Some(OPACITY),
        _ => indexed("f_dc_", 3)
            .map(|i| F_DC + i)
            .or_else(|| indexed("f_rest_", 45).map(|i| F_REST + i))
            .or_else(|| indexed("scale_", 3).map(|i| SCALE + i))
            .or_else(|| indexed("rot_", 4).map(|i| ROT + i)),
    }
}

impl PropertyAccess for SplatVertex {
    fn new() -> Self {
        Self {
            values: [0.0; SLOTS],
        }
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let Some(slot) = slot(name) else {
            return PropertyAccessResult::Ignored;
        };
        match property.to_f32_lossy() {
            Some(v) => {
                self.values[slot] = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::UnsupportedType,
        }
    }
}

/// Reads a 3DGS splat PLY (ascii or binary, any numeric property types, SH degree 0–3; the
/// degree follows from the number of `f_rest_*` properties). Properties may come in any
/// order; normals and other extra properties are ignored.
pub fn read_splat_ply(path: &Path) -> Result<SplatCloud, PlyError> {
    let format_error = |message: String| PlyError::Format {
        path: path.to_path_buf(),
        message,
    };
    let mut sh_degree = 0;
    let vertices: Vec<SplatVertex> = read_vertex_element(
        path,
        |source| PlyError::Read {
            path: path.to_path_buf(),
            source,
        },
        format_error,
        |vertex| {
            let required = property_names(0)
                .into_iter()
                .filter(|n| !n.starts_with('n'));
            for name in required {
                if !vertex.properties.contains_key(&name) {
                    return Err(format_error(format!(
                        "vertex property `{name}` is missing: not a 3D Gaussian splat file \
                         (expected the 3DGS layout x, y, z, f_dc_*, f_rest_*, opacity, \
                         scale_*, rot_*)"
                    )));
                }
            }
            let rest = vertex
                .properties
                .keys()
                .filter(|k| k.starts_with("f_rest_"))
                .count();
            sh_degree = (0..=3).find(|&d| rest_count(d) == rest).ok_or_else(|| {
                format_error(format!(
                    "{rest} `f_rest_*` properties: expected 0, 9, 24 or 45 (SH degree 0–3)"
                ))
            })?;
            if let Some(i) =
                (0..rest).find(|i| !vertex.properties.contains_key(&format!("f_rest_{i}")))
            {
                return Err(format_error(format!(
                    "`f_rest_{i}` is missing among {rest} `f_rest_*` properties"
                )));
            }
            Ok(())
        },
    )?;
    let coeffs = coeff_count(sh_degree);
    let splats = vertices
        .iter()
        .enumerate()
        .map(|(index, vertex)| {
            let v = &vertex.values;
            if v.iter().any(|x| !x.is_finite()) {
                return Err(format_error(format!(
                    "vertex {index} holds a NaN or infinite value"
                )));
            }
            let mut sh = [[0.0; 3]; SH_COEFFS];
            sh[0] = [v[F_DC], v[F_DC + 1], v[F_DC + 2]];
            for channel in 0..3 {
                for k in 1..coeffs {
                    sh[k][channel] = v[F_REST + channel * (coeffs - 1) + k - 1];
                }
            }
            Ok(StaticSplat {
                mean: [v[0], v[1], v[2]],
                sh,
                opacity_logit: v[OPACITY],
                log_scale: [v[SCALE], v[SCALE + 1], v[SCALE + 2]],
                rotation: [v[ROT], v[ROT + 1], v[ROT + 2], v[ROT + 3]],
            })
        })
        .collect::<Result<_, _>>()?;
    Ok(SplatCloud { sh_degree, splats })
}

/// The PLY parser's message on one line: the parser's internal state (its `Error:` part,
/// with the set of tokens it expected) is left out, the line it could not read is kept.
fn one_line(error: &dyn std::fmt::Display) -> String {
    let text = error.to_string();
    let text = text.split("\n\tError:").next().unwrap_or(&text);
    text.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// Reads the `vertex` element of a PLY file: `check` sees its definition first (to reject
/// files that lack properties); elements before it are parsed and dropped.
pub(crate) fn read_vertex_element<V: PropertyAccess, E>(
    path: &Path,
    io_error: impl Fn(std::io::Error) -> E,
    format_error: impl Fn(String) -> E,
    check: impl FnOnce(&ElementDef) -> Result<(), E>,
) -> Result<Vec<V>, E> {
    let file = File::open(path).map_err(&io_error)?;
    let mut reader = Reader::new(BufReader::new(file));
    let vertex_parser = Parser::<V>::new();
    let header = vertex_parser
        .read_header(&mut reader)
        .map_err(|e| format_error(format!("invalid PLY header: {}", one_line(&e))))?;
    let Some(vertex_def) = header.elements.get("vertex") else {
        let found: Vec<&str> = header.elements.keys().map(String::as_str).collect();
        return Err(format_error(format!(
            "PLY has no `vertex` element (elements found: {found:?})"
        )));
    };
    check(vertex_def)?;
    // Elements are stored in header order: skip the ones before `vertex`.
    for (name, element_def) in &header.elements {
        let body_error = |e: ply_rs_bw::parser::ParseError| {
            format_error(format!(
                "truncated or malformed PLY body in element `{name}` ({} declared): {}",
                element_def.count,
                one_line(&e)
            ))
        };
        if name == "vertex" {
            return vertex_parser
                .read_payload_for_element(&mut reader, element_def, &header)
                .map_err(body_error);
        }
        Parser::<SkippedElement>::new()
            .read_payload_for_element(&mut reader, element_def, &header)
            .map_err(body_error)?;
    }
    unreachable!("the vertex element was found in the header")
}

/// Any element other than `vertex`: parsed (to move past it) and dropped.
struct SkippedElement;

impl PropertyAccess for SkippedElement {
    fn new() -> Self {
        Self
    }
}

impl SplatCloud {
    /// Time-invariant Gaussians: no motion, constant rotation and scale, an RBF temporal
    /// opacity that is 1 at every time ([`STATIC_TEMPORAL_RAW`]). The model records one frame
    /// and TOW off, so it renders the same at every time.
    pub fn into_static_model(self) -> Model {
        let gaussians = self
            .splats
            .iter()
            .map(|s| {
                let (color, color_rest) = split_sh(&s.sh);
                GaussianParams {
                    position: Position { mean: s.mean },
                    fourier: Fourier::default(),
                    temporal: Temporal {
                        center: 0.5,
                        scale: [STATIC_TEMPORAL_RAW; 2],
                    },
                    opacity: Opacity {
                        logit: s.opacity_logit,
                    },
                    rotation: Rotation {
                        c0: s.rotation,
                        c1: [0.0; 4],
                    },
                    scale: Scale {
                        d0: s.log_scale,
                        d1: [0.0; 3],
                    },
                    color,
                    color_rest,
                }
            })
            .collect();
        let mut config = ModelConfig {
            sh_degree: self.sh_degree,
            opacity: OpacityModel::Rbf,
            scale_motion: false,
            ..ModelConfig::default()
        };
        config.tow.enabled = false;
        Model {
            gaussians,
            sh_degree: self.sh_degree,
            frame_count: Some(1),
            config: Some(config),
            time_windows: None,
            shared_motion: None,
        }
    }
}

/// Every Gaussian of `model` evaluated at normalised time `time` (motion, rotation, scale and
/// temporal opacity, with TOW as the model was trained, and the time window of a merged
/// segment model), keeping those whose opacity σ(t) is
/// at least `min_opacity`. SH coefficients are kept as they are (the colour stays
/// view-dependent). `settings` must be the model's (see [`Model::scene`]).
pub fn snapshot(model: &Model, settings: &Settings, time: f32, min_opacity: f32) -> SplatCloud {
    let motion = settings.motion_basis();
    let shared = model
        .shared_motion
        .as_ref()
        .map(|shared| (shared.bases.evaluate(time), &shared.weights));
    let splats = model
        .gaussians
        .iter()
        .enumerate()
        .filter_map(|(index, g)| {
            let dtw = settings
                .warp
                .apply(g.temporal.center, time - g.temporal.center);
            let window = model
                .time_windows
                .as_ref()
                .map_or(1.0, |windows| window_factor(&windows[index], time));
            let sigma =
                temporal_opacity(settings.opacity, g.opacity.logit, g.temporal.scale, dtw) * window;
            if sigma < min_opacity {
                return None;
            }
            let f = &g.fourier;
            let mut mean =
                Vec3::from(g.position.mean) + fourier_offset(&f.cos, &f.sin, &f.phase, motion, dtw);
            if let Some((at, weights)) = &shared {
                mean += shared_offset(&weights[index].w, at);
            }
            let velocity = scale_velocity(g.scale.d1, settings.model.scale_motion);
            Some(StaticSplat {
                mean: mean.to_array(),
                sh: g.sh(),
                opacity_logit: logit(sigma),
                log_scale: std::array::from_fn(|i| g.scale.d0[i] + velocity[i] * dtw),
                rotation: rotation_at(g.rotation.c0, g.rotation.c1, dtw),
            })
        })
        .collect();
    SplatCloud {
        sh_degree: model.sh_degree,
        splats,
    }
}
