//! What the carving tests share: a sphere seen by a ring of cameras, small settings and a
//! seeded generator.

use glam::Vec3;
use image::RgbImage;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::CarveSettings;
use crate::data::{Camera, Dataset, View};

const RED: [u8; 3] = [220, 30, 30];
const GREY: [u8; 3] = [128, 128, 128];
pub(super) const WIDTH: u32 = 64;
pub(super) const HEIGHT: u32 = 48;

/// A sphere seen by cameras around it: its analytic masks and red-on-grey images.
pub(super) struct SphereScene {
    pub(super) centre: Vec3,
    pub(super) radius: f32,
    pub(super) dataset: Dataset,
}

/// Whether the ray from `origin` along unit `dir` hits the sphere.
fn ray_hits_sphere(origin: Vec3, dir: Vec3, centre: Vec3, radius: f32) -> bool {
    let oc = origin - centre;
    let b = oc.dot(dir);
    let c = oc.length_squared() - radius * radius;
    let disc = b * b - c;
    disc >= 0.0 && -b + disc.sqrt() > 0.0
}

/// Ten cameras on a ring of radius 4 (alternately 1 above and below its plane) looking at
/// the origin, and a sphere of radius 0.8 slightly off the origin.
pub(super) fn sphere_scene() -> SphereScene {
    let count = 10;
    let elevation = 1.0;
    let centre = Vec3::new(0.15, -0.1, 0.05);
    let radius = 0.8;
    let cameras: Vec<Camera> = (0..count)
        .map(|i| {
            let a = i as f32 * std::f32::consts::TAU / count as f32;
            let height = if i % 2 == 0 { elevation } else { -elevation };
            let eye = Vec3::new(4.0 * a.cos(), height, 4.0 * a.sin());
            Camera::look_at(eye, Vec3::ZERO, Vec3::Y, WIDTH, HEIGHT, 1.0)
        })
        .collect();
    let train = cameras
        .iter()
        .enumerate()
        .map(|(index, cam)| {
            let eye = cam.center();
            let mut mask = vec![false; (WIDTH * HEIGHT) as usize];
            let image = RgbImage::from_fn(WIDTH, HEIGHT, |x, y| {
                let dir = cam.ray_direction(x as f32 + 0.5, y as f32 + 0.5);
                let hit = ray_hits_sphere(eye, dir, centre, radius);
                mask[(y * WIDTH + x) as usize] = hit;
                image::Rgb(if hit { RED } else { GREY })
            });
            View {
                camera: index,
                frame: 0,
                time: 0.0,
                image: image.into(),
                dynamic_mask: None,
                foreground: Some(mask),
                matte: None,
            }
        })
        .collect();
    SphereScene {
        centre,
        radius,
        dataset: Dataset {
            cameras,
            frame_count: 1,
            train,
            ..Dataset::default()
        },
    }
}

pub(super) fn test_settings() -> CarveSettings {
    CarveSettings {
        resolution: 40,
        ..CarveSettings::default()
    }
}

pub(super) fn rng() -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(7)
}
