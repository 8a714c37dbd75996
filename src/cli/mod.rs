//! The command implementations behind `src/main.rs`: one module per command, shared helpers
//! here.

pub mod bench;
pub mod eval;
pub mod export;
pub mod info;
pub mod input;
pub mod render;
pub mod run_folder;
pub mod segment;
pub mod train;
pub mod view;

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use indicatif::{ProgressBar, ProgressStyle};
use tadgs::data::Dataset;
use tadgs::io::checkpoint::STATE_FILE;
use tadgs::scene::{BackendKind, SceneConfig, apply_overrides, load_scene, set_override};

/// How much the commands print: `quiet` hides progress bars and informational logs.
#[derive(Clone, Copy, Debug)]
pub struct Ui {
    pub quiet: bool,
}

impl Ui {
    /// A bar counting `len` steps of `what`, with rate and time left; hidden when quiet.
    pub fn progress_bar(&self, len: u64, what: &str) -> ProgressBar {
        if self.quiet {
            return ProgressBar::hidden();
        }
        let bar = ProgressBar::new(len);
        bar.set_style(
            ProgressStyle::with_template(&format!(
                "{what:>8} {{bar:30}} {{pos}}/{{len}} [{{elapsed_precise}}<{{eta_precise}}] {{per_sec}} {{msg}}"
            ))
            .expect("valid template"),
        );
        bar
    }
}

/// A scene file with `--set` overrides applied.
pub fn load_with_overrides(path: &Path, overrides: &[String]) -> Result<SceneConfig> {
    let mut config = load_scene(path)?;
    apply_overrides(&mut config, overrides)?;
    Ok(config)
}

/// The backend a `--backend cpu|gpu` flag names (clap allows only those two).
pub fn backend_kind(flag: &str) -> BackendKind {
    if flag == "gpu" {
        BackendKind::Gpu
    } else {
        BackendKind::Cpu
    }
}

/// Sets `train.backend`, checked like any `--set` (settings the backend cannot run are
/// refused).
pub fn set_backend(config: &mut SceneConfig, backend: BackendKind) -> Result<()> {
    set_override(config, "train.backend", &format!("{backend:?}"))?;
    Ok(())
}

/// The checkpoint folder and the run folder of `dir`, which names either (as `--resume` and
/// `bench --checkpoint` take it).
pub fn checkpoint_and_run(dir: &Path) -> (PathBuf, PathBuf) {
    if dir.join(STATE_FILE).is_file() {
        let run = dir.parent().unwrap_or(Path::new("."));
        (dir.to_path_buf(), run.to_path_buf())
    } else {
        (dir.join("checkpoint"), dir.to_path_buf())
    }
}

/// Loads (or renders, for synthetic scenes) a scene's data, logging what it holds.
pub fn load_dataset(config: &SceneConfig) -> Result<Dataset> {
    let start = Instant::now();
    tracing::info!("scene `{}`: loading data", config.name);
    let mut dataset = tadgs::data::load(&config.data)
        .with_context(|| format!("loading the data of scene `{}`", config.name))?;
    if let Some(segment) = config.segment {
        dataset
            .restrict_to_segment(segment)
            .map_err(|message| anyhow::anyhow!("scene `{}`: {message}", config.name))?;
        tracing::info!(
            "segment: frames {} to {} of {}",
            segment.first_frame,
            segment.last_frame,
            dataset.frame_count
        );
    }
    tracing::info!(
        "{} cameras ({} train, {} held out), {} frames, {} training and {} held-out views, {}×{} px, {:.0} MB, in {:.1} s",
        dataset.cameras.len(),
        dataset.train_cameras().len(),
        dataset.test_cameras().len(),
        dataset.frame_count,
        dataset.train.len(),
        dataset.test.len(),
        dataset.cameras[0].width,
        dataset.cameras[0].height,
        dataset.memory_bytes() as f64 / 1e6,
        start.elapsed().as_secs_f32()
    );
    Ok(dataset)
}

/// Creates folder `dir` and its parents.
pub fn create_dir(dir: &Path) -> Result<()> {
    if dir.exists() && !dir.is_dir() {
        anyhow::bail!(
            "{} is a file, not a folder: choose another path",
            dir.display()
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))
}

/// Writes a whole file atomically (see [`tadgs::io::write_atomic`]).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    tadgs::io::write_atomic(path, bytes).with_context(|| format!("writing {}", path.display()))
}

/// A scene as pretty RON (for scene.ron and `info`).
pub fn scene_text(config: &SceneConfig) -> Result<String> {
    Ok(ron::ser::to_string_pretty(
        config,
        ron::ser::PrettyConfig::default(),
    )?)
}
