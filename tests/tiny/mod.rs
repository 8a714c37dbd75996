//! A tiny version of the demo scene for tests that step the trainer: 6 frames, anchors on
//! frames 0, 3 and 5, no supersampling.
#![allow(dead_code)]

use std::sync::Arc;

use tadgs::data::Dataset;
use tadgs::data::synthetic::demo_scene;
use tadgs::scene::{DataSource, SceneConfig};

/// The demo at `width × height` with `points_per_anchor` random points on each of 3 anchors,
/// and its rendered views.
pub fn tiny_demo(width: u32, height: u32, points_per_anchor: usize) -> (SceneConfig, Arc<Dataset>) {
    let mut synthetic = demo_scene();
    synthetic.frames = 6;
    synthetic.width = width;
    synthetic.height = height;
    synthetic.supersample = 1;
    let mut config = SceneConfig::new("tiny", DataSource::Synthetic(synthetic.clone()));
    config.init.points_per_anchor = points_per_anchor;
    config.init.anchor_spacing = 3;
    let dataset = Arc::new(synthetic.build().expect("tiny scene builds"));
    (config, dataset)
}

/// [`tiny_demo`] at 48×36 with 200 points per anchor, on a schedule that exercises every
/// structural step: 36 iterations, densification every 10 from 5 and an opacity reset at 30,
/// the SH degree raised every 8 iterations (to 3 at 24).
pub fn tiny_densifying_demo() -> (SceneConfig, Arc<Dataset>) {
    let (mut config, dataset) = tiny_demo(48, 36, 200);
    config.train.iterations = 36;
    config.train.sh_increase_interval = 8;
    config.densify.from_iter = 5;
    config.densify.interval = 10;
    config.densify.grad_threshold = 2e-5;
    config.densify.opacity_reset_interval = 30;
    (config, dataset)
}
