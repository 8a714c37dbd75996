//! Initial point clouds from files (PLY, COLMAP `points3D`) and PLY export.
//!
//! Accepted inputs, by extension:
//! - `.ply`: ascii, binary little- or big-endian; element `vertex` with `x`, `y`, `z` (any
//!   numeric type) and optionally `red`, `green`, `blue` (integers are scaled by their type's
//!   maximum: uchar /255, ushort /65535; floats are taken as 0–1). Points without colour
//!   get 0.5 grey. Other elements (faces, ...) and other vertex properties are skipped.
//! - `.txt` / `.bin`: COLMAP `points3D` (see [`super::colmap::read_points3d`]).
//!
//! NumPy `.npz`/`.npy` clouds are not read: their array names are not standardised, so a
//! guess would risk a silently wrong cloud. Convert them to PLY.

use std::path::Path;

use glam::Vec3;
use ply_rs_bw::ply::{Property, PropertyAccess, PropertyAccessResult};

use super::DataError;
use super::colmap;
use crate::init::InitPoint;

/// Colour given to points of a cloud that has none.
pub const DEFAULT_GREY: [f32; 3] = [0.5, 0.5, 0.5];

/// Reads a point cloud, choosing the reader by the file's extension.
pub fn read_point_cloud(path: &Path) -> Result<Vec<InitPoint>, DataError> {
    let extension = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match extension.as_deref() {
        Some("ply") => read_ply(path),
        Some("txt") | Some("bin") => colmap::read_points3d(path),
        Some("npz") | Some("npy") => Err(DataError::format(
            path,
            "NumPy point clouds are not supported (their array names are not standardised); \
             convert the cloud to PLY with vertex properties x, y, z, red, green, blue",
        )),
        _ => Err(DataError::format(
            path,
            "unknown point cloud format: expected a .ply file or COLMAP points3D.txt / points3D.bin",
        )),
    }
}

/// One vertex as read from a PLY file; fields not in the file keep their defaults.
struct PlyVertex {
    position: [f32; 3],
    color: [f32; 3],
}

impl PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self {
            position: [0.0; 3],
            color: DEFAULT_GREY,
        }
    }

    fn set_property(&mut self, name: &str, property: Property) -> PropertyAccessResult {
        let (slot, value) = match name {
            "x" => (&mut self.position[0], property.to_f32_lossy()),
            "y" => (&mut self.position[1], property.to_f32_lossy()),
            "z" => (&mut self.position[2], property.to_f32_lossy()),
            "red" => (&mut self.color[0], color_component(&property)),
            "green" => (&mut self.color[1], color_component(&property)),
            "blue" => (&mut self.color[2], color_component(&property)),
            _ => return PropertyAccessResult::Ignored,
        };
        match value {
            Some(v) => {
                *slot = v;
                PropertyAccessResult::Set
            }
            None => PropertyAccessResult::UnsupportedType,
        }
    }
}

/// A colour channel in [0, 1]: unsigned integers over their type's range, floats as they are.
fn color_component(property: &Property) -> Option<f32> {
    match *property {
        Property::UChar(v) => Some(f32::from(v) / 255.0),
        Property::UShort(v) => Some(f32::from(v) / 65535.0),
        Property::Float(v) => Some(v),
        Property::Double(v) => Some(v as f32),
        // Signed or 32-bit integer colours are unusual; read them on the 8-bit scale.
        ref other => other.to_f32_lossy().map(|v| v / 255.0),
    }
}

/// Reads the `vertex` element of a PLY file.
fn read_ply(path: &Path) -> Result<Vec<InitPoint>, DataError> {
    let vertices: Vec<PlyVertex> = crate::io::ply::read_vertex_element(
        path,
        |e| DataError::io(path, e),
        |message| DataError::format(path, message),
        |vertex_def| {
            for axis in ["x", "y", "z"] {
                if !vertex_def.properties.contains_key(axis) {
                    return Err(DataError::field(
                        path,
                        format!("vertex.{axis}"),
                        "missing: a point cloud needs vertex properties x, y and z",
                    ));
                }
            }
            let color_channels = ["red", "green", "blue"]
                .iter()
                .filter(|c| vertex_def.properties.contains_key(**c))
                .count();
            if color_channels != 0 && color_channels != 3 {
                return Err(DataError::field(
                    path,
                    "vertex.red/green/blue",
                    "only some colour channels are present: give all three or none",
                ));
            }
            Ok(())
        },
    )?;

    vertices
        .into_iter()
        .enumerate()
        .map(|(index, vertex)| {
            let position = Vec3::from_array(vertex.position);
            if !position.is_finite() {
                return Err(DataError::format(
                    path,
                    format!("vertex {index} has a non-finite position {position}"),
                ));
            }
            Ok(InitPoint {
                position,
                color: vertex.color,
            })
        })
        .collect()
}

/// Writes `points` as a binary little-endian PLY (float x, y, z; uchar red, green, blue).
///
/// The file is written under a temporary name next to `path` and renamed into place, so a
/// crash or a full disk never leaves a half-written cloud where a reader expects a whole one.
pub fn write_point_cloud_ply(path: &Path, points: &[InitPoint]) -> Result<(), DataError> {
    let header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by tadgs\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        points.len()
    );
    let mut bytes = Vec::with_capacity(header.len() + points.len() * 15);
    bytes.extend_from_slice(header.as_bytes());
    for point in points {
        for value in point.position.to_array() {
            bytes.extend_from_slice(&value.to_le_bytes());
        }
        for value in point.color {
            bytes.push((value.clamp(0.0, 1.0) * 255.0).round() as u8);
        }
    }
    crate::io::write_atomic(path, &bytes).map_err(|e| DataError::io(path, e))
}
