//! The built-in demo scene.

use std::f32::consts::PI;

use super::{CameraRing, Floor, Keyframe, SceneObject, Shape, SyntheticScene, Texture};

/// The built-in demo: 60 frames from 16 cameras (camera 5 held out) at 160 × 120, a checkered
/// floor, two static objects (a checkered box and a striped sphere), a sphere bouncing across
/// the scene, a striped box spinning once in place, and a cube that slides across the middle
/// while it exists, from t = 0.3 to t = 0.7.
pub fn demo_scene() -> SyntheticScene {
    let key = |time: f32, position: [f32; 3]| Keyframe { time, position };
    SyntheticScene {
        frames: 60,
        width: 160,
        height: 120,
        cameras: CameraRing {
            count: 16,
            radius: 4.0,
            height: 1.5,
            target: [0.0, 0.35, 0.0],
            fov_x_degrees: 50.0,
        },
        held_out: vec![5],
        background: [0.62, 0.72, 0.85],
        floor: Some(Floor {
            y: 0.0,
            half_size: 2.5,
            texture: Texture::Checker {
                a: [0.78, 0.76, 0.70],
                b: [0.42, 0.45, 0.50],
                cells: 1.0,
            },
        }),
        objects: vec![
            // Static checkered box.
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.35, 0.35, 0.35],
                },
                texture: Texture::Checker {
                    a: [0.85, 0.30, 0.25],
                    b: [0.95, 0.88, 0.72],
                    cells: 2.5,
                },
                path: vec![key(0.0, [-0.8, 0.35, -0.6])],
                spin: 0.0,
                visible: None,
            },
            // Static striped sphere.
            SceneObject {
                shape: Shape::Sphere { radius: 0.4 },
                texture: Texture::Stripes {
                    a: [0.20, 0.35, 0.80],
                    b: [0.90, 0.92, 0.95],
                    count: 4.0,
                },
                path: vec![key(0.0, [0.8, 0.4, -0.5])],
                spin: 0.0,
                visible: None,
            },
            // Sphere bouncing across the front, from left to right.
            SceneObject {
                shape: Shape::Sphere { radius: 0.28 },
                texture: Texture::Checker {
                    a: [0.95, 0.80, 0.15],
                    b: [0.85, 0.35, 0.10],
                    cells: 3.0,
                },
                path: vec![
                    key(0.0, [-1.0, 0.28, 0.7]),
                    key(0.25, [-0.5, 0.85, 0.7]),
                    key(0.5, [0.0, 0.28, 0.7]),
                    key(0.75, [0.5, 0.85, 0.7]),
                    key(1.0, [1.0, 0.28, 0.7]),
                ],
                spin: 0.0,
                visible: None,
            },
            // Striped box spinning one full turn in place.
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.28, 0.45, 0.28],
                },
                texture: Texture::Stripes {
                    a: [0.55, 0.25, 0.70],
                    b: [0.95, 0.95, 0.90],
                    count: 3.0,
                },
                path: vec![key(0.0, [0.0, 0.45, -1.0])],
                spin: 2.0 * PI,
                visible: None,
            },
            // Cube that appears at t = 0.3, slides across the middle and disappears at t = 0.7.
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.2, 0.2, 0.2],
                },
                texture: Texture::Solid([0.15, 0.75, 0.70]),
                path: vec![key(0.3, [0.9, 0.2, 0.15]), key(0.7, [-0.9, 0.2, 0.15])],
                spin: 0.0,
                visible: Some((0.3, 0.7)),
            },
        ],
        supersample: 2,
        foreground_masks: false,
    }
}
