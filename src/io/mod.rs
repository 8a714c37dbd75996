//! File input and output: images (more formats join here: PLY, checkpoints, video).

pub mod image;
