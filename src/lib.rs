#![warn(missing_docs)]
//! # tadgs: dynamic (4D) Gaussian splatting with temporally aware densification
//!
//! A population of Gaussians is a set of bevy_ecs entities with plain-data components
//! ([`components`]): canonical position, Fourier motion, temporal centre and scale, opacity,
//! rotation and scale polynomials, spherical-harmonic colour, and per-parameter gradients, Adam
//! moments and densification statistics. One training iteration is a schedule of systems
//! ([`systems`]), one per stage and each in its [`systems::TrainSet`]:
//!
//! ```text
//! SampleView → TimeWarp → Deform → Splat → Loss → Backward → Adam → Densify
//! ```
//!
//! The maths of each stage is a pure function with its gradient beside it ([`model`],
//! [`raster`]); only densification changes the population's structure. Scenes are RON files
//! ([`scene`]); datasets are read by [`data`]; [`metrics`] has PSNR, SSIM, LPIPS and the masked
//! metrics of the evaluation protocol; [`train::Trainer`] is a ready-made loop.
//!
//! ## Train a few iterations and render
//!
//! ```
//! use std::sync::Arc;
//! use tadgs::data::synthetic::demo_scene;
//! use tadgs::scene::{DataSource, SceneConfig};
//! use tadgs::train::Trainer;
//!
//! // A tiny version of the built-in synthetic scene: 4 frames of 32×24 pixels.
//! let mut synthetic = demo_scene();
//! (synthetic.frames, synthetic.width, synthetic.height) = (4, 32, 24);
//! let dataset = Arc::new(synthetic.build()?);
//! let mut scene = SceneConfig::new("tiny", DataSource::Synthetic(synthetic));
//! scene.init.points_per_anchor = 200;
//!
//! let mut trainer = Trainer::try_new(&scene, dataset.clone())?;
//! for _ in 0..10 {
//!     trainer.step();
//! }
//! assert_eq!(trainer.state().iteration, 10);
//!
//! let view = &dataset.test[0];
//! let render = trainer.render(&dataset.cameras[view.camera], view.time);
//! assert_eq!((render.image.width, render.image.height), (32, 24));
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! ## Use the stages in your own schedule
//!
//! Insert the resources with [`train::insert_resources`], spawn Gaussians with
//! [`components::GaussianParams::bundle`] (or [`train::spawn_initial_gaussians`]), add the
//! stages with [`systems::add_training_systems`] and order your own systems against the
//! [`systems::TrainSet`]s, e.g. `.after(TrainSet::Backward).before(TrainSet::Adam)`.
//! [`train::insert_render_resources`] with [`systems::render_schedule`] draws a trained model
//! without any training system. The `examples/` folder shows all three.

pub mod bench;
pub mod budget;
pub mod components;
pub mod data;
pub mod gpu;
pub mod init;
pub mod io;
pub mod layout;
pub mod metrics;
pub mod model;
pub mod raster;
pub mod report;
pub mod resources;
pub mod scene;
pub mod segment;
#[path = "../systems/mod.rs"]
pub mod systems;
pub mod train;
pub mod view;
