//! RON scene files: types with the SPEC's defaults, loading with file/line/column errors.

mod field_error;
pub mod load;
mod outline;
pub mod types;

pub use field_error::FieldError;
pub(crate) use field_error::{Check, fail};
pub use load::{SceneError, apply_overrides, load_scene, parse_scene, set_override, validate};
pub use outline::locate_field;
pub use types::*;
