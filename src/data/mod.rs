//! Cameras and multi-view video datasets.

pub mod camera;
pub mod init;
pub mod synthetic;

pub use camera::Camera;

use crate::io::image::Image;

/// A multi-view video held in memory: `images[camera][frame]`.
#[derive(Clone, Debug)]
pub struct Dataset {
    pub cameras: Vec<Camera>,
    pub frame_count: usize,
    /// Camera indices used for training.
    pub train_cameras: Vec<usize>,
    /// Held-out camera indices used for evaluation.
    pub test_cameras: Vec<usize>,
    /// `images[camera][frame]`, every image of its camera's size.
    pub images: Vec<Vec<Image>>,
    /// Optional exact dynamic-region masks, `masks[camera][frame][pixel]` (true = dynamic).
    pub dynamic_masks: Option<Vec<Vec<Vec<bool>>>>,
}

impl Dataset {
    /// Normalised time of a frame: `frame / (T − 1)` in [0, 1].
    pub fn frame_time(&self, frame: usize) -> f32 {
        if self.frame_count <= 1 {
            0.0
        } else {
            frame as f32 / (self.frame_count - 1) as f32
        }
    }
}
