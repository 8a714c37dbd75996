//! `tadgs view`: serves the interactive 4D viewer ([`tadgs::view`]) for a run, a model file or
//! a splat PLY; [`LiveView`] serves it during `tadgs train --view`.

use std::io::Write;
use std::net::IpAddr;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use glam::Vec3;
use tadgs::data::Dataset;
use tadgs::io::model::Model;
use tadgs::scene::{BackendKind, SceneConfig};
use tadgs::train::Trainer;
use tadgs::view::{Renderer, SceneInfo, TrainingStatus, ViewOptions, Viewer};

use super::Ui;
use super::input::{Input, parse_rgb, parse_vec3};

/// `tadgs view`.
#[derive(clap::Args, Debug)]
pub struct ViewCommand {
    /// What to show: a run folder (scene.ron + model.safetensors, or its checkpoint while the
    /// run is unfinished), a model file (.safetensors) or a static 3DGS splat file (.ply).
    pub input: PathBuf,
    /// Address to listen on. The default, 127.0.0.1, keeps the viewer on this machine; give
    /// 0.0.0.0 (or one of this machine's addresses) to let other machines open it.
    #[arg(long, default_value = "127.0.0.1", value_name = "ADDRESS")]
    pub host: IpAddr,
    /// Port to listen on; 0 picks a free one (the URL printed says which).
    #[arg(long, default_value_t = 0, value_name = "PORT")]
    pub port: u16,
    /// Background colour as r,g,b in [0, 1]. Default: the scene's, black for model files.
    #[arg(long, value_name = "R,G,B", value_parser = parse_rgb)]
    pub background: Option<[f32; 3]>,
    /// World up direction as x,y,z: orbiting turns around it. Default: the cameras' mean
    /// image-up (run folders), 0,-1,0 for model files, as for `render --orbit`.
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    pub up: Option<Vec3>,
    /// Splatting backend: cpu (any machine), or gpu through wgpu (the pixels `tadgs render`
    /// gives for a run whose scene says `backend: Gpu`).
    #[arg(long, value_parser = ["cpu", "gpu"], default_value = "cpu")]
    pub backend: String,
    /// Do not load a run's data: starts faster and needs less memory, but the page has no
    /// dataset cameras to jump to and orbits the Gaussians instead of the camera rig.
    #[arg(long)]
    pub no_data: bool,
    /// Override settings of a run's scene (e.g. the data path), as for `train`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

pub fn view(args: ViewCommand, _ui: Ui) -> Result<()> {
    let mut input = Input::load(&args.input, &args.overrides)?;
    let dataset = if args.no_data { None } else { input.dataset()? };
    let frames = input.resolve_frame_count(dataset.as_ref())?;
    let mut scene = input.scene(args.background);
    // The CPU backend unless asked: the viewer must start on any machine.
    super::set_backend(&mut scene, super::backend_kind(&args.backend))?;
    let (cameras, heldout) = match &dataset {
        Some(dataset) => (dataset.cameras.clone(), dataset.test_cameras()),
        None => (Vec::new(), Vec::new()),
    };
    // Only the cameras are kept: the images are not needed to view the model.
    drop(dataset);
    // The folder or file name: short, and no private path in screenshots.
    let name = input.path.file_name().map_or_else(
        || input.path.display().to_string(),
        |n| n.to_string_lossy().into_owned(),
    );
    let info = SceneInfo::new(&name, &input.model, frames, &cameras, &heldout, args.up);
    let options = ViewOptions {
        host: args.host,
        port: args.port,
    };
    let viewer =
        serve(&scene, &input.model, frames, info, options).context("starting the viewer")?;
    if !args.host.is_loopback() {
        tracing::warn!(
            "the viewer listens on {}: anyone who can reach this machine can open it",
            viewer.address()
        );
    }
    tracing::info!(
        "{} Gaussians over {frames} frames; open the URL below, Ctrl-C stops the viewer",
        input.model.gaussians.len()
    );
    // The URL on stdout (and flushed), so scripts and tests can read it.
    println!("{}", viewer.url());
    std::io::stdout().flush().ok();
    viewer.wait()?;
    Ok(())
}

/// Starts the viewer of `model` over `frames` frames, rendered with `scene`'s settings.
fn serve(
    scene: &SceneConfig,
    model: &Model,
    frames: usize,
    info: SceneInfo,
    options: ViewOptions,
) -> Result<Viewer> {
    let renderer = Renderer::new(scene, model, frames)?;
    Ok(Viewer::start(renderer, info, options)?)
}

/// The viewer serving a run while it trains (`tadgs train --view`).
pub struct LiveView {
    viewer: Viewer,
    /// When the model shown was last replaced.
    updated: Instant,
    /// The iteration of the model shown.
    shown: u32,
}

impl LiveView {
    /// Serves `trainer`'s current model on 127.0.0.1:`port` (0: a free port) and prints the
    /// page's address on stderr (stdout holds the run's results).
    pub fn start(
        config: &SceneConfig,
        dataset: &Dataset,
        trainer: &mut Trainer,
        port: u16,
    ) -> Result<Self> {
        let model = trainer.model();
        let mut scene = config.clone();
        // The viewer renders on the CPU whatever the run trains on: a GPU run keeps its device
        // to itself.
        super::set_backend(&mut scene, BackendKind::Cpu)?;
        let frames = dataset.frame_count;
        let info = SceneInfo::new(
            &config.name,
            &model,
            frames,
            &dataset.cameras,
            &dataset.test_cameras(),
            None,
        );
        let options = ViewOptions {
            host: IpAddr::from([127, 0, 0, 1]),
            port,
        };
        let viewer =
            serve(&scene, &model, frames, info, options).context("starting the viewer (--view)")?;
        eprintln!(
            "viewer: {} (the model shown follows training while the page is open)",
            viewer.url()
        );
        Ok(Self {
            viewer,
            updated: Instant::now(),
            shown: trainer.state().iteration,
        })
    }

    /// Publishes `status` and, while a page is open, replaces the model shown by the trainer's
    /// current one once a second. Nobody watching costs one uncontended lock per iteration.
    pub fn update(&mut self, trainer: &mut Trainer, mut status: TrainingStatus) {
        let due =
            self.updated.elapsed() >= Duration::from_secs(1) && status.iteration != self.shown;
        if due && self.viewer.sessions() > 0 {
            self.viewer.set_model(&trainer.model());
            self.shown = status.iteration;
            self.updated = Instant::now();
        }
        status.shown_iteration = self.shown;
        self.viewer.set_training(status);
    }
}
