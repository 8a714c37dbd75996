//! The `tadgs` command line: train a scene, inspect it.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use tadgs::data::Dataset;
use tadgs::io::image::Image;
use tadgs::scene::{DataSource, SceneConfig, apply_overrides, load_scene, set_override};
use tadgs::train::{Trainer, ViewMetrics, mean};

/// Dynamic (4D) Gaussian splatting with temporally aware densification (VAD, TAT, TOW).
#[derive(Parser)]
#[command(version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// More log output (-v: debug, -vv: trace).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// No progress bar; only the final summary.
    #[arg(short, long, global = true)]
    quiet: bool,
}

#[derive(Subcommand)]
enum Command {
    /// Train on a scene file, then evaluate the held-out cameras and write their renders.
    ///
    /// Writes to the scene's output folder (or --output): heldout/ with PNGs of render | ground
    /// truth for every held-out camera and frame, and metrics.json / metrics.csv per view.
    Train {
        /// Scene file (RON), e.g. scenes/demo.ron.
        scene: PathBuf,
        /// Override the number of iterations (train.iterations).
        #[arg(long)]
        iterations: Option<u32>,
        /// Override any scene setting, e.g. --set densify.vad=false --set model.tow.rho=0.7.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Output folder (default: the scene's `output`).
        #[arg(long)]
        output: Option<PathBuf>,
    },
    /// Show a scene's resolved settings and its data.
    Info {
        /// Scene file (RON).
        scene: PathBuf,
        /// Override any scene setting (as for `train`).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
    },
}

fn main() -> std::process::ExitCode {
    match run(Cli::parse()) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("error: {}", describe(&error));
            std::process::ExitCode::FAILURE
        }
    }
}

/// The error and its causes on one line, skipping causes the message already quotes.
fn describe(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !text.contains(&cause) {
            text = format!("{text}: {cause}");
        }
    }
    text
}

fn run(cli: Cli) -> Result<()> {
    let level = match (cli.quiet, cli.verbose) {
        (true, _) => "warn",
        (false, 0) => "info",
        (false, 1) => "debug",
        _ => "trace",
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| level.into()),
        )
        .with_target(false)
        .without_time()
        .init();
    match cli.command {
        Command::Train {
            scene,
            iterations,
            overrides,
            output,
        } => {
            let mut config = load_with_overrides(&scene, &overrides)?;
            if let Some(n) = iterations {
                set_override(&mut config, "train.iterations", &n.to_string())?;
            }
            let output = output.unwrap_or_else(|| PathBuf::from(&config.output));
            train(&config, &output, cli.quiet)
        }
        Command::Info { scene, overrides } => {
            let config = load_with_overrides(&scene, &overrides)?;
            println!(
                "{}",
                ron::ser::to_string_pretty(&config, ron::ser::PrettyConfig::default())?
            );
            Ok(())
        }
    }
}

fn load_with_overrides(path: &Path, overrides: &[String]) -> Result<SceneConfig> {
    let mut config = load_scene(path)?;
    apply_overrides(&mut config, overrides)?;
    Ok(config)
}

fn load_dataset(config: &SceneConfig) -> Result<Dataset> {
    match &config.data {
        DataSource::Synthetic(scene) => scene
            .build()
            .map_err(anyhow::Error::msg)
            .context("building the synthetic scene"),
    }
}

fn train(config: &SceneConfig, output: &Path, quiet: bool) -> Result<()> {
    let start = Instant::now();
    tracing::info!("scene `{}`: preparing data", config.name);
    let dataset = Arc::new(load_dataset(config)?);
    tracing::info!(
        "{} cameras ({} train, {} held out), {} frames, {} training views, {}×{} px, in {:.1} s",
        dataset.cameras.len(),
        dataset.train_cameras().len(),
        dataset.test_cameras().len(),
        dataset.frame_count,
        dataset.train.len(),
        dataset.cameras[0].width,
        dataset.cameras[0].height,
        start.elapsed().as_secs_f32()
    );
    let mut trainer = Trainer::new(config, dataset.clone());
    tracing::info!("{} initial Gaussians", trainer.gaussian_count());

    let iterations = config.train.iterations;
    let bar = if quiet {
        ProgressBar::hidden()
    } else {
        ProgressBar::new(iterations as u64)
    };
    bar.set_style(
        ProgressStyle::with_template(
            "{bar:30} {pos}/{len} [{elapsed_precise}<{eta_precise}] {per_sec} {msg}",
        )
        .expect("valid template"),
    );
    let train_start = Instant::now();
    for i in 1..=iterations {
        trainer.step();
        if i % 10 == 0 || i == iterations {
            let state = trainer.state();
            bar.set_position(i as u64);
            bar.set_message(format!(
                "loss {:.4}  gaussians {}",
                state.loss.total,
                trainer.gaussian_count()
            ));
            if !state.loss.total.is_finite() {
                bar.abandon();
                bail!(
                    "the loss became {} at iteration {i}: training diverged",
                    state.loss.total
                );
            }
        }
        let eval = config.train.eval_interval;
        if eval > 0 && i % eval == 0 && i < iterations {
            let metrics = trainer.evaluate(|_, _, _| {});
            bar.println(format!(
                "iteration {i}: held-out PSNR {:.2} dB",
                mean(metrics.iter().map(|m| m.psnr)).unwrap_or(f32::NAN)
            ));
        }
    }
    bar.finish_and_clear();
    let train_time = train_start.elapsed().as_secs_f32();

    let heldout = output.join("heldout");
    std::fs::create_dir_all(&heldout).with_context(|| format!("creating {}", heldout.display()))?;
    let render_start = Instant::now();
    let mut save_error = None;
    let metrics = trainer.evaluate(|view, render, gt| {
        let path = heldout.join(format!("cam{:02}_frame{:04}.png", view.camera, view.frame));
        if let Err(e) = side_by_side(render, gt).save_png(&path) {
            save_error.get_or_insert(e);
        }
    });
    if let Some(e) = save_error {
        return Err(e.into());
    }
    let eval_time = render_start.elapsed().as_secs_f32();
    let summary = Summary::new(
        config,
        &metrics,
        trainer.gaussian_count(),
        train_time,
        eval_time,
    );
    write_metrics(output, &summary, &metrics)?;
    summary.print(output);
    Ok(())
}

/// Render on the left, ground truth on the right.
fn side_by_side(render: &Image, gt: &Image) -> Image {
    let mut out = Image::filled(
        render.width + gt.width,
        render.height.max(gt.height),
        [0.0; 3],
    );
    for y in 0..out.height {
        for x in 0..out.width {
            let pixel = if x < render.width {
                (y < render.height).then(|| render.get(x, y))
            } else {
                (y < gt.height).then(|| gt.get(x - render.width, y))
            };
            out.data[y * out.width + x] = pixel.unwrap_or([0.0; 3]);
        }
    }
    out
}

#[derive(serde::Serialize)]
struct Summary {
    scene: String,
    iterations: u32,
    vad: bool,
    tat: bool,
    tow: bool,
    psnr: Option<f32>,
    dynamic_psnr: Option<f32>,
    gaussians: usize,
    train_seconds: f32,
    render_fps: f32,
}

impl Summary {
    fn new(
        config: &SceneConfig,
        metrics: &[ViewMetrics],
        gaussians: usize,
        train_seconds: f32,
        eval_seconds: f32,
    ) -> Self {
        Self {
            scene: config.name.clone(),
            iterations: config.train.iterations,
            vad: config.densify.vad,
            tat: config.densify.tat,
            tow: config.model.tow.enabled,
            psnr: mean(metrics.iter().map(|m| m.psnr)),
            dynamic_psnr: mean(metrics.iter().filter_map(|m| m.masked_psnr)),
            gaussians,
            train_seconds,
            render_fps: metrics.len() as f32 / eval_seconds.max(1e-6),
        }
    }

    fn print(&self, output: &Path) {
        let show = |v: Option<f32>| v.map_or("n/a".to_string(), |v| format!("{v:.2} dB"));
        println!("scene            {}", self.scene);
        println!(
            "iterations       {}  (VAD {}, TAT {}, TOW {})",
            self.iterations, self.vad, self.tat, self.tow
        );
        println!("held-out PSNR    {}", show(self.psnr));
        println!(
            "dynamic PSNR     {}  (exact motion masks)",
            show(self.dynamic_psnr)
        );
        println!("Gaussians        {}", self.gaussians);
        println!("training time    {:.1} s", self.train_seconds);
        println!(
            "render speed     {:.1} frames/s (with metrics)",
            self.render_fps
        );
        println!("renders          {}", output.join("heldout").display());
    }
}

fn write_metrics(output: &Path, summary: &Summary, metrics: &[ViewMetrics]) -> Result<()> {
    let views: Vec<_> = metrics
        .iter()
        .map(|m| serde_json::json!({"camera": m.camera, "frame": m.frame, "psnr": m.psnr, "dynamic_psnr": m.masked_psnr}))
        .collect();
    let json = serde_json::json!({"summary": summary, "views": views});
    write_atomic(
        &output.join("metrics.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    let mut csv = String::from("camera,frame,psnr,dynamic_psnr\n");
    for m in metrics {
        let dynamic = m.masked_psnr.map_or(String::new(), |v| v.to_string());
        csv.push_str(&format!(
            "{},{},{},{}\n",
            m.camera, m.frame, m.psnr, dynamic
        ));
    }
    write_atomic(&output.join("metrics.csv"), csv.as_bytes())
}

/// Writes a file through a temporary file and a rename, so it is either complete or absent.
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = path.with_extension("tmp");
    std::fs::write(&tmp, bytes).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, path).with_context(|| format!("renaming to {}", path.display()))
}
