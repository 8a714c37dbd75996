//! Shared by the examples: the demo scene from its RON file, shrunk so an example runs in
//! seconds, in a world with the tadgs resources and the initial Gaussians.

use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use bevy_ecs::world::World;
use tadgs::scene::{SceneConfig, apply_overrides, load_scene};
use tadgs::train::{insert_resources, spawn_initial_gaussians};

/// The demo at 64×48 over 8 frames with 400 points on each of its anchors, plus `overrides`
/// (`key=value`), and a world holding it. Returns the scene, the world and how many Gaussians
/// were spawned.
pub fn small_demo_world(overrides: &[&str]) -> Result<(SceneConfig, World, usize)> {
    let mut scene = load_scene(&Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes/demo.ron"))?;
    let mut all = vec![
        "data.frames=8",
        "data.width=64",
        "data.height=48",
        "init.points_per_anchor=400",
        "init.anchor_spacing=4",
    ];
    all.extend_from_slice(overrides);
    apply_overrides(&mut scene, &all)?;
    let dataset = Arc::new(tadgs::data::load(&scene.data)?);
    let mut world = World::new();
    insert_resources(&mut world, &scene, dataset)?;
    let spawned = spawn_initial_gaussians(&mut world, &scene)?;
    Ok((scene, world, spawned))
}
