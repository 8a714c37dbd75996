//! A tiny version of the demo scene for tests that step the trainer: 6 frames, anchors on
//! frames 0, 3 and 5, no supersampling.

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
