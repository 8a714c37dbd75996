//! The `tadgs` command line: train a scene, evaluate a trained model, compute dynamic masks,
//! inspect a scene.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use tadgs::data::Dataset;
use tadgs::io::image::Image;
use tadgs::io::model::Model;
use tadgs::metrics::eval::{MaskSource, ScoreSummary, ViewScores, dynamic_masks};
use tadgs::metrics::flow::DEFAULT_FLOW_THRESHOLD;
use tadgs::metrics::lpips::Lpips;
use tadgs::scene::{SceneConfig, apply_overrides, load_scene, set_override};
use tadgs::train::{Evaluation, Trainer};

/// Dynamic (4D) Gaussian splatting with temporally aware densification (VAD, TAT, TOW).
///
/// A run folder (`--output`, default the scene's `output`) holds: scene.ron (the resolved
/// settings), model.safetensors (every Gaussian's parameters), metrics.json / metrics.csv
/// (per held-out view and means), heldout/ (render | ground truth PNGs) and masks/ (the
/// dynamic masks used by M-PSNR and M-SSIM).
#[derive(Parser)]
#[command(version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// More log output (-v: debug, -vv: trace).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    /// No progress bars; only warnings and the final summary.
    #[arg(short, long, global = true)]
    quiet: bool,
}

/// Options shared by the commands that score held-out views.
#[derive(clap::Args, Clone)]
struct EvalArgs {
    /// LPIPS (AlexNet) weights in safetensors form. Default: $TADGS_LPIPS, else
    /// ../shared/data/lpips/alex.safetensors when present; without weights LPIPS is skipped.
    #[arg(long, value_name = "FILE")]
    lpips: Option<PathBuf>,
    /// Folder of dynamic-mask PNGs (camCC_frameFFFF.png, white = dynamic) to use for M-PSNR and
    /// M-SSIM; missing masks are computed by optical flow and written there. Default:
    /// <output>/masks.
    #[arg(long, value_name = "DIR")]
    masks: Option<PathBuf>,
    /// Flow magnitude (pixels, between frames t−5 and t) above which a pixel is dynamic.
    #[arg(long, default_value_t = DEFAULT_FLOW_THRESHOLD)]
    flow_threshold: f32,
    /// Do not write the render | ground-truth PNG of every held-out view.
    #[arg(long)]
    no_renders: bool,
}

/// Which views `eval` scores.
#[derive(clap::ValueEnum, Clone, Copy, PartialEq, Eq)]
enum Split {
    /// The held-out views (the protocol).
    Test,
    /// The training views instead (how well the model fits what it saw; results go to
    /// <run>/train-split/).
    Train,
}

#[derive(Subcommand)]
enum Command {
    /// Train on a scene file, save the model, then evaluate every held-out view.
    Train {
        /// Scene file (RON), e.g. scenes/demo.ron or scenes/panoptic.ron.
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
        #[command(flatten)]
        eval: EvalArgs,
    },
    /// Evaluate a trained run: render every held-out view and write PSNR, SSIM, LPIPS,
    /// M-PSNR and M-SSIM per view and on average (metrics.json, metrics.csv).
    Eval {
        /// Run folder written by `tadgs train` (holds scene.ron and model.safetensors).
        run: PathBuf,
        /// Override scene settings (e.g. the data path) before loading the data.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Score the held-out views (test) or the training views (train).
        #[arg(long, value_enum, default_value_t = Split::Test)]
        split: Split,
        #[command(flatten)]
        eval: EvalArgs,
    },
    /// Compute the dynamic masks of a scene's held-out views (optical flow between frames t−5
    /// and t of each test camera) and save them as PNGs, for reuse by `train` and `eval`.
    Masks {
        /// Scene file (RON).
        scene: PathBuf,
        /// Override any scene setting.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Folder for the mask PNGs.
        #[arg(long)]
        output: PathBuf,
        /// Flow magnitude (pixels) above which a pixel is dynamic.
        #[arg(long, default_value_t = DEFAULT_FLOW_THRESHOLD)]
        flow_threshold: f32,
    },
    /// Time every stage of a training iteration on the fixed benchmark scene and print a table.
    Bench(tadgs::bench::BenchArgs),
    /// Show a scene's resolved settings and a summary of its data.
    Info {
        /// Scene file (RON).
        scene: PathBuf,
        /// Override any scene setting (as for `train`).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        overrides: Vec<String>,
        /// Also load the data and describe it (cameras, views, memory).
        #[arg(long)]
        data: bool,
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
    let quiet = cli.quiet;
    match cli.command {
        Command::Train {
            scene,
            iterations,
            overrides,
            output,
            eval,
        } => {
            let mut config = load_with_overrides(&scene, &overrides)?;
            if let Some(n) = iterations {
                set_override(&mut config, "train.iterations", &n.to_string())?;
            }
            let output = output.unwrap_or_else(|| PathBuf::from(&config.output));
            train(&config, &output, &eval, quiet)
        }
        Command::Eval {
            run,
            overrides,
            split,
            mut eval,
        } => {
            let config = load_with_overrides(&run.join("scene.ron"), &overrides)?;
            let model_path = run.join("model.safetensors");
            let model = Model::load(&model_path)?;
            let mut dataset = load_dataset(&config)?;
            let output = match split {
                Split::Test => run.clone(),
                Split::Train => {
                    // Score the training views through the same path as held-out ones.
                    dataset.test = std::mem::take(&mut dataset.train);
                    eval.masks = None;
                    run.join("train-split")
                }
            };
            std::fs::create_dir_all(&output)
                .with_context(|| format!("creating {}", output.display()))?;
            let dataset = Arc::new(dataset);
            let mut trainer = Trainer::from_model(&config, dataset.clone(), &model);
            let report = evaluate(&mut trainer, &dataset, &output, &eval, quiet)?;
            let summary = RunSummary::new(&config, &report, model.gaussians.len(), None);
            write_metrics(&output, &summary, &report.scores)?;
            summary.print(&output);
            Ok(())
        }
        Command::Masks {
            scene,
            overrides,
            output,
            flow_threshold,
        } => {
            let config = load_with_overrides(&scene, &overrides)?;
            let dataset = load_dataset(&config)?;
            let source = MaskSource {
                folder: Some(output.clone()),
                compute: true,
                threshold: flow_threshold,
            };
            let bar = progress_bar(dataset.test.len() as u64, quiet, "masks");
            let masks = dynamic_masks(&dataset, &source, || bar.inc(1))?;
            bar.finish_and_clear();
            let with_mask = masks.iter().flatten().count();
            let fraction = tadgs::metrics::eval::mean(
                masks
                    .iter()
                    .flatten()
                    .map(|m| m.iter().filter(|&&d| d).count() as f32 / m.len() as f32),
            );
            println!(
                "{with_mask} of {} held-out views have a dynamic mask ({:.1} % of their pixels dynamic on average), in {}",
                masks.len(),
                100.0 * fraction.unwrap_or(0.0),
                output.display()
            );
            Ok(())
        }
        Command::Bench(args) => tadgs::bench::cli(&args),
        Command::Info {
            scene,
            overrides,
            data,
        } => {
            let config = load_with_overrides(&scene, &overrides)?;
            println!(
                "{}",
                ron::ser::to_string_pretty(&config, ron::ser::PrettyConfig::default())?
            );
            if data {
                let dataset = load_dataset(&config)?;
                describe_dataset(&dataset);
            }
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
    let start = Instant::now();
    tracing::info!("scene `{}`: loading data", config.name);
    let dataset = tadgs::data::load(&config.data)
        .with_context(|| format!("loading the data of scene `{}`", config.name))?;
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

fn describe_dataset(dataset: &Dataset) {
    println!(
        "cameras {} (train {:?}, held out {:?})",
        dataset.cameras.len(),
        dataset.train_cameras(),
        dataset.test_cameras()
    );
    println!(
        "frames {}, training views {}, held-out views {}, image memory {:.0} MB",
        dataset.frame_count,
        dataset.train.len(),
        dataset.test.len(),
        dataset.memory_bytes() as f64 / 1e6
    );
}

fn progress_bar(len: u64, quiet: bool, what: &str) -> ProgressBar {
    if quiet {
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

fn train(config: &SceneConfig, output: &Path, eval: &EvalArgs, quiet: bool) -> Result<()> {
    let dataset = Arc::new(load_dataset(config)?);
    std::fs::create_dir_all(output).with_context(|| format!("creating {}", output.display()))?;
    let scene_text = ron::ser::to_string_pretty(config, ron::ser::PrettyConfig::default())?;
    write_atomic(&output.join("scene.ron"), scene_text.as_bytes())?;

    let init_start = Instant::now();
    let mut trainer = Trainer::try_new(config, dataset.clone())?;
    tracing::info!(
        "{} initial Gaussians in {:.1} s",
        trainer.gaussian_count(),
        init_start.elapsed().as_secs_f32()
    );

    let iterations = config.train.iterations;
    let bar = progress_bar(iterations as u64, quiet, "train");
    // Where no bar can be drawn (output to a file or pipe), log a line every 5 % instead.
    let log_every = if bar.is_hidden() && !quiet {
        (iterations / 20).max(1)
    } else {
        0
    };
    let train_start = Instant::now();
    for i in 1..=iterations {
        trainer.step();
        if log_every > 0 && (i % log_every == 0 || i == iterations) {
            let seconds = train_start.elapsed().as_secs_f32();
            tracing::info!(
                "iteration {i}/{iterations}: loss {:.4}, {} Gaussians, {:.2} it/s, {:.0} s",
                trainer.state().loss.total,
                trainer.gaussian_count(),
                i as f32 / seconds,
                seconds
            );
        }
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
        let every = config.train.eval_interval;
        if every > 0 && i % every == 0 && i < iterations {
            let psnr = trainer.heldout_psnr().unwrap_or(f32::NAN);
            bar.println(format!("iteration {i}: held-out PSNR {psnr:.2} dB"));
        }
    }
    bar.finish_and_clear();
    let train_seconds = train_start.elapsed().as_secs_f32();
    let model = trainer.model();
    model.save(&output.join("model.safetensors"))?;

    let report = evaluate(&mut trainer, &dataset, output, eval, quiet)?;
    let summary = RunSummary::new(config, &report, model.gaussians.len(), Some(train_seconds));
    write_metrics(output, &summary, &report.scores)?;
    summary.print(output);
    Ok(())
}

/// LPIPS weights: the given file, $TADGS_LPIPS, or the shared test data when present.
fn lpips_weights(given: Option<&Path>) -> Result<Option<Lpips>> {
    let path = given
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os("TADGS_LPIPS").map(PathBuf::from))
        .or_else(|| {
            let shared = PathBuf::from("../shared/data/lpips/alex.safetensors");
            shared.is_file().then_some(shared)
        });
    match path {
        Some(path) => Ok(Some(Lpips::load(&path)?)),
        None => {
            tracing::warn!(
                "no LPIPS weights (give --lpips FILE or set TADGS_LPIPS): LPIPS is not computed"
            );
            Ok(None)
        }
    }
}

/// Scores every held-out view (masks first, then renders) and writes the renders.
fn evaluate(
    trainer: &mut Trainer,
    dataset: &Dataset,
    output: &Path,
    args: &EvalArgs,
    quiet: bool,
) -> Result<Evaluation> {
    let lpips = lpips_weights(args.lpips.as_deref())?;
    let source = MaskSource {
        folder: Some(args.masks.clone().unwrap_or_else(|| output.join("masks"))),
        compute: true,
        threshold: args.flow_threshold,
    };
    let bar = progress_bar(dataset.test.len() as u64, quiet, "masks");
    let masks = dynamic_masks(dataset, &source, || bar.inc(1))?;
    bar.finish_and_clear();

    let heldout = output.join("heldout");
    if !args.no_renders {
        std::fs::create_dir_all(&heldout)
            .with_context(|| format!("creating {}", heldout.display()))?;
    }
    let bar = progress_bar(dataset.test.len() as u64, quiet, "eval");
    let mut save_error = None;
    let report = trainer.evaluate(lpips.as_ref(), &masks, |score, render, gt| {
        bar.inc(1);
        if args.no_renders {
            return;
        }
        let path = heldout.join(format!(
            "cam{:02}_frame{:04}.png",
            score.camera, score.frame
        ));
        if let Err(e) = side_by_side(render, gt).save_png(&path) {
            save_error.get_or_insert(e);
        }
    })?;
    bar.finish_and_clear();
    if let Some(e) = save_error {
        return Err(e.into());
    }
    Ok(report)
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

/// The figures of a run, as printed and as written to metrics.json.
#[derive(serde::Serialize)]
struct RunSummary {
    scene: String,
    iterations: u32,
    vad: bool,
    tat: bool,
    tow: bool,
    #[serde(flatten)]
    scores: ScoreSummary,
    lpips_network: &'static str,
    gaussians: usize,
    train_seconds: Option<f32>,
    render_fps: f32,
}

impl RunSummary {
    fn new(
        config: &SceneConfig,
        report: &Evaluation,
        gaussians: usize,
        train_seconds: Option<f32>,
    ) -> Self {
        Self {
            scene: config.name.clone(),
            iterations: config.train.iterations,
            vad: config.densify.vad,
            tat: config.densify.tat,
            tow: config.model.tow.enabled,
            scores: ScoreSummary::of(&report.scores),
            lpips_network: "alex",
            gaussians,
            train_seconds,
            render_fps: report.render_fps(),
        }
    }

    fn print(&self, output: &Path) {
        let db = |v: Option<f32>| v.map_or("n/a".to_string(), |v| format!("{v:.2} dB"));
        let plain = |v: Option<f32>| v.map_or("n/a".to_string(), |v| format!("{v:.4}"));
        let s = &self.scores;
        println!("scene            {}", self.scene);
        println!(
            "iterations       {}  (VAD {}, TAT {}, TOW {})",
            self.iterations, self.vad, self.tat, self.tow
        );
        println!("views scored     {}", s.views);
        println!("PSNR             {}", db(s.psnr));
        println!("SSIM             {}", plain(s.ssim));
        println!("LPIPS (alex)     {}", plain(s.lpips));
        println!(
            "M-PSNR           {}  ({} views with a dynamic mask)",
            db(s.masked_psnr),
            s.masked_views
        );
        println!("M-SSIM           {}", plain(s.masked_ssim));
        println!("Gaussians        {}", self.gaussians);
        if let Some(t) = self.train_seconds {
            println!("training time    {t:.1} s");
        }
        println!("render speed     {:.1} frames/s", self.render_fps);
        println!("results          {}", output.display());
    }
}

fn write_metrics(output: &Path, summary: &RunSummary, scores: &[ViewScores]) -> Result<()> {
    let json = serde_json::json!({"summary": summary, "views": scores});
    write_atomic(
        &output.join("metrics.json"),
        serde_json::to_string_pretty(&json)?.as_bytes(),
    )?;
    let cell = |v: Option<f32>| v.map_or(String::new(), |v| v.to_string());
    let mut csv =
        String::from("camera,frame,time,psnr,ssim,lpips,m_psnr,m_ssim,dynamic_fraction\n");
    for s in scores {
        csv.push_str(&format!(
            "{},{},{},{},{},{},{},{},{}\n",
            s.camera,
            s.frame,
            s.time,
            s.psnr,
            s.ssim,
            cell(s.lpips),
            cell(s.masked_psnr),
            cell(s.masked_ssim),
            cell(s.dynamic_fraction)
        ));
    }
    write_atomic(&output.join("metrics.csv"), csv.as_bytes())
}

/// Writes a whole file atomically (see [`tadgs::io::write_atomic`]).
fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    tadgs::io::write_atomic(path, bytes).with_context(|| format!("writing {}", path.display()))
}
