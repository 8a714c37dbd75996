//! Shared by the tests that train on a shrunk copy of the built-in demo scene.

use std::sync::Arc;

use tadgs::data::Dataset;
use tadgs::data::synthetic::demo_scene;
use tadgs::scene::{DataSource, SceneConfig};

/// The demo scene over `frames` frames at `width`×`height`, initialised with
/// `points_per_anchor` random points on an anchor every third frame; its scene (named `name`)
/// and its dataset.
pub fn small_demo(
    name: &str,
    frames: usize,
    width: u32,
    height: u32,
    points_per_anchor: usize,
) -> (SceneConfig, Arc<Dataset>) {
    let mut synthetic = demo_scene();
    synthetic.frames = frames;
    synthetic.width = width;
    synthetic.height = height;
    let mut config = SceneConfig::new(name, DataSource::Synthetic(synthetic.clone()));
    config.init.points_per_anchor = points_per_anchor;
    config.init.anchor_spacing = 3;
    let dataset = Arc::new(synthetic.build().expect("the small demo scene builds"));
    (config, dataset)
}
