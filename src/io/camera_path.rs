//! Cameras and camera paths for `tadgs render`: RON files and orbits.
//!
//! A camera file holds one pinhole camera in the OpenCV convention (x right, y down, looking
//! along +z), its 4×4 world-to-camera matrix written row by row:
//!
//! ```ron
//! (
//!     width: 640, height: 480,
//!     fx: 525.0, fy: 525.0, cx: 320.0, cy: 240.0,
//!     world_to_camera: [
//!         [1.0, 0.0, 0.0, 0.0],
//!         [0.0, 1.0, 0.0, 0.0],
//!         [0.0, 0.0, 1.0, 4.0],
//!         [0.0, 0.0, 0.0, 1.0],
//!     ],
//! )
//! ```
//!
//! A path file lists keys, each a camera and the normalised scene time it shows:
//! `(keys: [(camera: (..), time: 0.0), (camera: (..), time: 1.0)])`. Rendered with more
//! frames than keys, the path is interpolated between consecutive keys (camera centre and
//! intrinsics linearly, orientation by quaternion slerp, time linearly).

use std::path::{Path, PathBuf};

use glam::{Mat3, Mat4, Quat, Vec3, Vec4};
use serde::{Deserialize, Serialize};

use crate::data::Camera;

/// A camera or path file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum CameraFileError {
    /// The file could not be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The camera or path file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The file is not valid RON of the expected shape, or a camera or key in it is unusable
    /// (empty image, bad intrinsics, a matrix that is not a rigid transform, keys of different
    /// image sizes, a time outside [0, 1], no keys).
    #[error("{}: {message}", path.display())]
    Invalid {
        /// The camera or path file.
        path: PathBuf,
        /// What is wrong, naming the key where there is one.
        message: String,
    },
}

/// A camera as written in a RON file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraSpec {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal focal length in pixels.
    pub fx: f32,
    /// Vertical focal length in pixels.
    pub fy: f32,
    /// Principal point x in pixels (pixel column `x` has its centre at `x + 0.5`).
    pub cx: f32,
    /// Principal point y in pixels (pixel row `y` has its centre at `y + 0.5`).
    pub cy: f32,
    /// World-to-camera, 4 rows of 4 (OpenCV convention); the last row must be 0 0 0 1.
    /// (Lists rather than arrays, so the file can write `[[..], ..]`.)
    pub world_to_camera: Vec<Vec<f32>>,
}

impl CameraSpec {
    /// The camera, or what is wrong with it.
    pub fn to_camera(&self) -> Result<Camera, String> {
        let max = crate::data::MAX_IMAGE_SIDE;
        if !(1..=max).contains(&self.width) || !(1..=max).contains(&self.height) {
            return Err(format!(
                "image size {}×{} is empty or larger than {max} pixels a side",
                self.width, self.height
            ));
        }
        let intrinsics = [self.fx, self.fy, self.cx, self.cy];
        if intrinsics.iter().any(|v| !v.is_finite()) || self.fx <= 0.0 || self.fy <= 0.0 {
            return Err("fx and fy must be positive, fx, fy, cx, cy finite".into());
        }
        let rows = &self.world_to_camera;
        if rows.len() != 4 || rows.iter().any(|r| r.len() != 4) {
            return Err("world_to_camera must be 4 rows of 4 numbers".into());
        }
        let m: [[f32; 4]; 4] = std::array::from_fn(|i| std::array::from_fn(|j| rows[i][j]));
        if m.iter().flatten().any(|v| !v.is_finite()) {
            return Err("world_to_camera holds a NaN or infinite value".into());
        }
        if m[3] != [0.0, 0.0, 0.0, 1.0] {
            return Err(format!(
                "world_to_camera's last row is {:?}, expected [0, 0, 0, 1]",
                m[3]
            ));
        }
        let matrix = Mat4::from_cols_array_2d(&m).transpose();
        let rotation = Mat3::from_mat4(matrix);
        let orthonormal = (rotation * rotation.transpose() - Mat3::IDENTITY)
            .to_cols_array()
            .iter()
            .all(|v| v.abs() < 1e-3);
        if !orthonormal || rotation.determinant() < 0.0 {
            return Err(
                "world_to_camera's upper-left 3×3 block is not a rotation (orthonormal, \
                 determinant +1)"
                    .into(),
            );
        }
        Ok(Camera {
            width: self.width,
            height: self.height,
            fx: self.fx,
            fy: self.fy,
            cx: self.cx,
            cy: self.cy,
            world_to_camera: matrix,
        })
    }

    /// The file form of `camera`.
    pub fn of(camera: &Camera) -> Self {
        Self {
            width: camera.width,
            height: camera.height,
            fx: camera.fx,
            fy: camera.fy,
            cx: camera.cx,
            cy: camera.cy,
            world_to_camera: camera
                .world_to_camera
                .transpose()
                .to_cols_array_2d()
                .iter()
                .map(|row| row.to_vec())
                .collect(),
        }
    }
}

/// One key of a camera path.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathKey {
    /// The camera at this key.
    pub camera: CameraSpec,
    /// Normalised scene time in [0, 1].
    pub time: f32,
}

/// A camera path file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PathSpec {
    /// The keys in path order (at least one, all of one image size).
    pub keys: Vec<PathKey>,
}

/// One frame to render: a camera and a normalised time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shot {
    /// The camera (OpenCV convention).
    pub camera: Camera,
    /// Normalised scene time in [0, 1].
    pub time: f32,
}

fn read_ron<T: serde::de::DeserializeOwned>(path: &Path) -> Result<T, CameraFileError> {
    let text = std::fs::read_to_string(path).map_err(|source| CameraFileError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    ron::from_str(&text).map_err(|e| CameraFileError::Invalid {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Reads a camera file.
pub fn load_camera(path: &Path) -> Result<Camera, CameraFileError> {
    let spec: CameraSpec = read_ron(path)?;
    spec.to_camera()
        .map_err(|message| CameraFileError::Invalid {
            path: path.to_path_buf(),
            message,
        })
}

/// Reads a path file: its keys as shots, checked (at least one key, one image size, times in
/// [0, 1]).
pub fn load_path(path: &Path) -> Result<Vec<Shot>, CameraFileError> {
    let spec: PathSpec = read_ron(path)?;
    let invalid = |message: String| CameraFileError::Invalid {
        path: path.to_path_buf(),
        message,
    };
    if spec.keys.is_empty() {
        return Err(invalid("the path has no keys".into()));
    }
    let size = (spec.keys[0].camera.width, spec.keys[0].camera.height);
    spec.keys
        .iter()
        .enumerate()
        .map(|(i, key)| {
            let camera = key
                .camera
                .to_camera()
                .map_err(|m| invalid(format!("key {i}: {m}")))?;
            if (camera.width, camera.height) != size {
                return Err(invalid(format!(
                    "key {i} is {}×{}, key 0 is {}×{}: every key needs the same image size",
                    camera.width, camera.height, size.0, size.1
                )));
            }
            if !(0.0..=1.0).contains(&key.time) {
                return Err(invalid(format!(
                    "key {i}: time {} is outside [0, 1]",
                    key.time
                )));
            }
            Ok(Shot {
                camera,
                time: key.time,
            })
        })
        .collect()
}

/// `frames` shots along `keys`, evenly spaced in key index (the keys themselves for
/// `frames == keys.len()`); one key gives that key `frames` times.
pub fn interpolate(keys: &[Shot], frames: usize) -> Vec<Shot> {
    if keys.len() < 2 || frames < 2 {
        return keys.iter().cycle().take(frames).copied().collect();
    }
    (0..frames)
        .map(|k| {
            let s = k as f32 * (keys.len() - 1) as f32 / (frames - 1) as f32;
            let i = (s.floor() as usize).min(keys.len() - 2);
            blend(&keys[i], &keys[i + 1], s - i as f32)
        })
        .collect()
}

/// The shot a fraction `f` of the way from `a` to `b`.
fn blend(a: &Shot, b: &Shot, f: f32) -> Shot {
    let (ca, cb) = (a.camera, b.camera);
    let lerp = |x: f32, y: f32| x + (y - x) * f;
    let qa = Quat::from_mat3(&ca.rotation());
    let qb = Quat::from_mat3(&cb.rotation());
    let rotation = Mat3::from_quat(qa.slerp(qb, f));
    let center = ca.center().lerp(cb.center(), f);
    let translation = -(rotation * center);
    Shot {
        camera: Camera {
            width: ca.width,
            height: ca.height,
            fx: lerp(ca.fx, cb.fx),
            fy: lerp(ca.fy, cb.fy),
            cx: lerp(ca.cx, cb.cx),
            cy: lerp(ca.cy, cb.cy),
            world_to_camera: Mat4::from_cols(
                rotation.x_axis.extend(0.0),
                rotation.y_axis.extend(0.0),
                rotation.z_axis.extend(0.0),
                Vec4::from((translation, 1.0)),
            ),
        },
        time: lerp(a.time, b.time),
    }
}

/// A circle of cameras around a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// The point looked at.
    pub center: Vec3,
    /// World up (unit).
    pub up: Vec3,
    /// Horizontal distance of the cameras from the centre.
    pub radius: f32,
    /// Height of the cameras above the centre, along `up`.
    pub height: f32,
    /// Unit direction (orthogonal to `up`) of the first camera from the centre.
    pub start: Vec3,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels (`height` is the cameras' elevation).
    pub height_px: u32,
    /// Horizontal field of view in radians.
    pub fov_x: f32,
}

impl Orbit {
    /// The orbit through a rig of cameras: around the point they look at, with their mean
    /// image-up as up, their mean distance and height, starting at the first camera, with its
    /// image size and field of view.
    pub fn around_rig(cameras: &[Camera]) -> Self {
        let center = crate::init::rig_focus(cameras);
        let up = cameras
            .iter()
            .map(|c| c.rotation().transpose() * Vec3::NEG_Y)
            .sum::<Vec3>()
            .normalize_or(Vec3::Y);
        let offsets: Vec<Vec3> = cameras.iter().map(|c| c.center() - center).collect();
        let n = offsets.len().max(1) as f32;
        let height = offsets.iter().map(|o| o.dot(up)).sum::<f32>() / n;
        let horizontal = |o: Vec3| o - up * o.dot(up);
        let radius = offsets.iter().map(|&o| horizontal(o).length()).sum::<f32>() / n;
        let first = &cameras[0];
        Self {
            center,
            up,
            radius,
            height,
            start: horizontal(offsets[0]).normalize_or(up.any_orthonormal_vector()),
            width: first.width,
            height_px: first.height,
            fov_x: 2.0 * (0.5 * first.width as f32 / first.fx).atan(),
        }
    }

    /// An orbit around a cloud of points seen from outside: centred on the per-axis median, at
    /// 2.5× the distance that holds 80 % of the points, 30° above the horizon.
    pub fn around_points(points: &[Vec3], up: Vec3, width: u32, height: u32) -> Self {
        let median = |axis: usize| {
            let mut v: Vec<f32> = points.iter().map(|p| p[axis]).collect();
            v.sort_by(f32::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(0.0)
        };
        let center = Vec3::new(median(0), median(1), median(2));
        let mut distances: Vec<f32> = points.iter().map(|p| p.distance(center)).collect();
        distances.sort_by(f32::total_cmp);
        let spread = distances
            .get(distances.len() * 4 / 5)
            .copied()
            .unwrap_or(1.0)
            .max(1e-3);
        let up = up.normalize_or(Vec3::Y);
        let distance = 2.5 * spread;
        Self {
            center,
            up,
            radius: distance * 30f32.to_radians().cos(),
            height: distance * 30f32.to_radians().sin(),
            start: up.any_orthonormal_vector(),
            width,
            height_px: height,
            fov_x: 50f32.to_radians(),
        }
    }

    /// `frames` cameras, one full turn, evenly spaced.
    pub fn cameras(&self, frames: usize) -> Vec<Camera> {
        let side = self.up.cross(self.start);
        (0..frames)
            .map(|k| {
                let angle = std::f32::consts::TAU * k as f32 / frames.max(1) as f32;
                let direction = self.start * angle.cos() + side * angle.sin();
                let eye = self.center + direction * self.radius + self.up * self.height;
                Camera::look_at(
                    eye,
                    self.center,
                    self.up,
                    self.width,
                    self.height_px,
                    self.fov_x,
                )
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera written as RON reads back as the same camera (row-major matrix in the file).
    #[test]
    fn camera_file_round_trip() {
        let camera = Camera::look_at(Vec3::new(1.0, 2.0, 3.0), Vec3::ZERO, Vec3::Y, 64, 48, 1.0);
        let spec = CameraSpec::of(&camera);
        // Row-major: the translation is the last column of the first three rows.
        assert_eq!(spec.world_to_camera[0][3], camera.translation().x);
        let text = ron::to_string(&spec).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("camera.ron");
        std::fs::write(&path, text).unwrap();
        assert_eq!(load_camera(&path).unwrap(), camera);
    }

    /// A matrix that is not a rigid transform is refused with the file named.
    #[test]
    fn non_rigid_camera_is_refused() {
        let mut spec = CameraSpec::of(&Camera::look_at(
            Vec3::new(0.0, 0.0, -3.0),
            Vec3::ZERO,
            Vec3::Y,
            8,
            8,
            1.0,
        ));
        spec.world_to_camera[0][0] = 2.0;
        // The file form a person writes: nested lists.
        assert!(
            ron::to_string(&spec)
                .unwrap()
                .contains("world_to_camera:[[")
        );
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("bad.ron");
        std::fs::write(&path, ron::to_string(&spec).unwrap()).unwrap();
        let error = load_camera(&path).unwrap_err().to_string();
        assert!(
            error.contains("bad.ron") && error.contains("rotation"),
            "{error}"
        );
    }

    /// Every orbit camera looks at the centre (it projects to the principal point) from the
    /// orbit's distance and height.
    #[test]
    fn orbit_cameras_look_at_the_centre() {
        let orbit = Orbit {
            center: Vec3::new(0.5, 0.2, -0.3),
            up: Vec3::Y,
            radius: 3.0,
            height: 1.0,
            start: Vec3::X,
            width: 64,
            height_px: 48,
            fov_x: 1.0,
        };
        for camera in orbit.cameras(7) {
            let (u, v, _) = camera.project(orbit.center);
            assert!((u - 32.0).abs() < 1e-3 && (v - 24.0).abs() < 1e-3);
            let offset = camera.center() - orbit.center;
            assert!((offset.y - 1.0).abs() < 1e-4);
            assert!((Vec3::new(offset.x, 0.0, offset.z).length() - 3.0).abs() < 1e-4);
        }
    }

    /// Interpolating a path passes through its keys and moves the time linearly.
    #[test]
    fn path_interpolation_hits_the_keys() {
        let a = Camera::look_at(Vec3::new(3.0, 1.0, 0.0), Vec3::ZERO, Vec3::Y, 32, 32, 1.0);
        let b = Camera::look_at(Vec3::new(0.0, 1.0, 3.0), Vec3::ZERO, Vec3::Y, 32, 32, 1.0);
        let keys = [
            Shot {
                camera: a,
                time: 0.0,
            },
            Shot {
                camera: b,
                time: 1.0,
            },
        ];
        let shots = interpolate(&keys, 5);
        assert_eq!(shots.len(), 5);
        assert!((shots[0].camera.center() - a.center()).length() < 1e-4);
        assert!((shots[4].camera.center() - b.center()).length() < 1e-4);
        assert!((shots[2].time - 0.5).abs() < 1e-6);
        let middle = shots[2].camera.center();
        assert!((middle - (a.center() + b.center()) * 0.5).length() < 1e-4);
    }
}
