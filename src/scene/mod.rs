//! RON scene files: types with the SPEC's defaults, loading with file/line/column errors.

pub mod load;
pub mod types;

pub use load::{SceneError, load_scene, parse_scene};
pub use types::*;
