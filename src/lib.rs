//! tadgs: dynamic (4D) Gaussian splatting with temporally aware densification.

pub mod components;
pub mod data;
pub mod io;
pub mod metrics;
pub mod model;
pub mod raster;
// LEAD-PENDING pub mod resources;
pub mod scene;
// LEAD-PENDING pub mod train;
// LEAD-PENDING #[path = "../systems/mod.rs"]
// LEAD-PENDING pub mod systems;
