//! RON scene files: types with the SPEC's defaults, loading with file/line/column errors.

pub mod load;
pub mod types;

pub use load::{
    SceneError, apply_overrides, load_scene, locate_field, parse_scene, set_override, validate,
};
pub use types::*;
