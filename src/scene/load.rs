//! Scene loading.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {}
pub fn load_scene() {}
pub fn parse_scene() {}
