//! File input and output: images and trained models (more formats join here: PLY, video).

pub mod image;
pub mod model;
