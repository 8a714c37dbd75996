//! Pinhole cameras in the OpenCV convention (x right, y down, looking along +z).

use glam::{Mat3, Mat4, Vec3};
use serde::{Deserialize, Serialize};

/// A pinhole camera: intrinsics in pixels and a world-to-camera rigid transform.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Camera {
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal focal length in pixels.
    pub fx: f32,
    /// Vertical focal length in pixels.
    pub fy: f32,
    /// Principal point x in pixels, in image coordinates where pixel column `x` spans
    /// `[x, x + 1)` (its centre is at `x + 0.5`).
    pub cx: f32,
    /// Principal point y in pixels, same convention as `cx` (row `y` has its centre at
    /// `y + 0.5`).
    pub cy: f32,
    /// World-to-camera transform (OpenCV: x right, y down, +z forward).
    pub world_to_camera: Mat4,
}

impl Camera {
    /// The same camera with an image `factor` times smaller in each direction (the size
    /// rounded down, as [`crate::io::image::box_downscale`] crops the remainder).
    pub fn downscaled(&self, factor: u32) -> Self {
        let factor = factor.max(1);
        let scale = factor as f32;
        Self {
            width: self.width / factor,
            height: self.height / factor,
            fx: self.fx / scale,
            fy: self.fy / scale,
            cx: self.cx / scale,
            cy: self.cy / scale,
            world_to_camera: self.world_to_camera,
        }
    }

    /// Camera centre in world coordinates.
    pub fn center(&self) -> Vec3 {
        self.world_to_camera.inverse().transform_point3(Vec3::ZERO)
    }

    /// Rotation part of world-to-camera.
    pub fn rotation(&self) -> Mat3 {
        Mat3::from_mat4(self.world_to_camera)
    }

    /// Translation part of world-to-camera.
    pub fn translation(&self) -> Vec3 {
        self.world_to_camera.w_axis.truncate()
    }

    /// A camera at `eye` looking at `target`, with `up` as the world up direction
    /// (image y points along −up). `fov_x` is the horizontal field of view in radians.
    pub fn look_at(eye: Vec3, target: Vec3, up: Vec3, width: u32, height: u32, fov_x: f32) -> Self {
        let forward = (target - eye).normalize();
        let right = forward.cross(up).normalize();
        let down = forward.cross(right);
        let rotation = Mat3::from_cols(right, down, forward).transpose();
        let translation = -(rotation * eye);
        let fx = 0.5 * width as f32 / (0.5 * fov_x).tan();
        Self {
            width,
            height,
            fx,
            fy: fx,
            cx: 0.5 * width as f32,
            cy: 0.5 * height as f32,
            world_to_camera: Mat4::from_cols(
                rotation.x_axis.extend(0.0),
                rotation.y_axis.extend(0.0),
                rotation.z_axis.extend(0.0),
                translation.extend(1.0),
            ),
        }
    }

    /// Projects a world point to pixel coordinates (pixel centres at +0.5) and depth.
    pub fn project(&self, world: Vec3) -> (f32, f32, f32) {
        let p = self.world_to_camera.transform_point3(world);
        (
            self.fx * p.x / p.z + self.cx,
            self.fy * p.y / p.z + self.cy,
            p.z,
        )
    }

    /// World-space direction of the ray through pixel coordinates (u, v), normalised.
    pub fn ray_direction(&self, u: f32, v: f32) -> Vec3 {
        let dir_cam = Vec3::new((u - self.cx) / self.fx, (v - self.cy) / self.fy, 1.0);
        (self.rotation().transpose() * dir_cam).normalize()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_projects_target_to_principal_point() {
        let cam = Camera::look_at(Vec3::new(3.0, -1.0, 2.0), Vec3::ZERO, Vec3::Y, 64, 48, 1.0);
        let (u, v, z) = cam.project(Vec3::ZERO);
        assert!((u - 32.0).abs() < 1e-4 && (v - 24.0).abs() < 1e-4);
        assert!((z - Vec3::new(3.0, -1.0, 2.0).length()).abs() < 1e-4);
        assert!((cam.center() - Vec3::new(3.0, -1.0, 2.0)).length() < 1e-4);
        // World up appears towards the top of the image (smaller v).
        let (_, v_up, _) = cam.project(Vec3::Y * 0.1);
        assert!(v_up < v);
        let dir = cam.ray_direction(u, v);
        assert!((dir - (-cam.center()).normalize()).length() < 1e-4);
    }
}
