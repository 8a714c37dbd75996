//! tadgs: dynamic (4D) Gaussian splatting with temporally aware densification.

pub mod bench;
pub mod components;
pub mod data;
pub mod io;
pub mod metrics;
pub mod model;
pub mod raster;
pub mod resources;
pub mod scene;
#[path = "../systems/mod.rs"]
pub mod systems;
pub mod train;
