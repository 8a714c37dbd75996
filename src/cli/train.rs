//! `tadgs train`: train on a scene (or continue a checkpoint), save the model, evaluate it and
//! write the run report.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use tadgs::data::Dataset;
use tadgs::io::checkpoint::Checkpoint;
use tadgs::report::{DensifyRecord, FrameScores, HeldoutRecord, Report, StepRecord, TrainingLog};
use tadgs::resources::CameraExposures;
use tadgs::scene::{SceneConfig, apply_overrides};
use tadgs::train::Trainer;
use tadgs::view::TrainingStatus;

use super::eval::{EvalArgs, RunSummary, evaluate, write_metrics};
use super::run_folder::{RunLock, refuse_existing_run, remove_run_outputs, same_folder};
use super::view::LiveView;
use super::{
    Ui, backend_kind, checkpoint_and_run, load_dataset, load_with_overrides, scene_text,
    set_backend, write_atomic,
};

/// Held-out views shown in the run report.
const REPORT_VIEWS: usize = 4;

/// Set by Ctrl-C: the training loop writes a checkpoint and stops.
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

/// The first Ctrl-C stops training after the current iteration with a checkpoint; a second
/// one stops at once.
fn catch_ctrl_c() {
    let result = ctrlc::set_handler(|| {
        if INTERRUPTED.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    });
    if let Err(e) = result {
        tracing::warn!("Ctrl-C will stop training without a checkpoint: {e}");
    }
}

/// Training stopped on Ctrl-C, with a checkpoint: not a failure, reported as a plain line
/// with the shell's exit status for an interrupt (130).
#[derive(Debug)]
pub struct Stopped(pub String);

impl std::fmt::Display for Stopped {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for Stopped {}

/// `tadgs train`.
#[derive(clap::Args, Debug)]
// Negative numbers are values (and refused with a clear message), not unknown flags.
#[command(allow_negative_numbers = true)]
pub struct TrainCommand {
    /// Scene file (RON), e.g. scenes/demo.ron or scenes/panoptic.ron. Not given with --resume
    /// (the checkpoint holds the scene).
    #[arg(required_unless_present = "resume")]
    pub scene: Option<PathBuf>,
    /// Train N iterations (train.iterations). The scene file's schedule stretches with it:
    /// densification window, opacity-reset and SH-increase intervals are scaled by
    /// N / train.iterations (the densification interval is kept); values given with --set
    /// are kept as given.
    #[arg(long, value_name = "N")]
    pub iterations: Option<u32>,
    /// Override any scene setting, e.g. --set densify.vad=false --set model.tow.rho=0.7.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Output folder (default: the scene's `output`; with --resume, the resumed run's folder).
    #[arg(long, short, value_name = "DIR")]
    pub output: Option<PathBuf>,
    /// Continue a run from its checkpoint (written every --checkpoint-every iterations, at
    /// --until and on Ctrl-C): DIR is the run folder or its checkpoint/ folder.
    /// The run goes on exactly as if it had not stopped (same final parameters); --set and
    /// --iterations still apply but then the result differs from an uninterrupted run.
    #[arg(long, value_name = "DIR", conflicts_with = "scene")]
    pub resume: Option<PathBuf>,
    /// Replace the run already in the output folder (its model, metrics, renders, checkpoint
    /// and report; masks are kept). Without it, training into a folder that holds a run is
    /// refused.
    #[arg(long)]
    pub force: bool,
    /// Write a checkpoint (<output>/checkpoint/) every N iterations, and at the end; 0 = only
    /// at the end. Overrides train.checkpoint_interval.
    #[arg(long, value_name = "N")]
    pub checkpoint_every: Option<u32>,
    /// Stop after iteration N with a checkpoint, without evaluating (the schedule still spans
    /// train.iterations); continue later with --resume.
    #[arg(long, value_name = "N")]
    pub until: Option<u32>,
    /// Measure the held-out PSNR every N iterations (for the progress log and the report's
    /// PSNR plot; 0 = only at the end). Overrides train.eval_interval.
    #[arg(long, value_name = "N")]
    pub eval_every: Option<u32>,
    /// Do not write the run report (<output>/report/index.html and its plots).
    #[arg(long)]
    pub no_report: bool,
    /// Splatting backend (overrides train.backend): cpu, or gpu through wgpu (Vulkan, Metal,
    /// DX12 or GL; no CUDA needed).
    #[arg(long, value_parser = ["cpu", "gpu"])]
    pub backend: Option<String>,
    /// Serve the viewer of `tadgs view` on 127.0.0.1 while training (its URL is printed): the
    /// page shows the model as it trains, replaced once a second while a page is open, with
    /// the iteration, loss and PSNR. Renders on the CPU.
    #[arg(long)]
    pub view: bool,
    /// Port of the --view server; 0 picks a free one.
    #[arg(long, default_value_t = 0, value_name = "PORT", requires = "view")]
    pub view_port: u16,
    #[command(flatten)]
    pub eval: EvalArgs,
}

/// `--iterations N`: stretches the scene's schedule to `n` iterations, keeping what the
/// `overrides` (`--set`) name as given.
pub fn set_iterations(config: &mut SceneConfig, n: u32, overrides: &[String]) -> Result<()> {
    let from = config.train.iterations;
    config.scale_schedule(n);
    apply_overrides(config, overrides)?;
    if n != from {
        tracing::info!(
            "--iterations {n}: the schedule of {from} iterations stretched ×{:.3}: \
             densification after iteration {} until {}, opacity reset every {}, SH degree up \
             every {}",
            n as f64 / from.max(1) as f64,
            config.densify.from_iter,
            config.densify.until_iter,
            config.densify.opacity_reset_interval,
            config.train.sh_increase_interval,
        );
    }
    Ok(())
}

pub fn train(args: TrainCommand, ui: Ui) -> Result<()> {
    args.eval.check()?;
    let (mut config, checkpoint, output, continuing) = match &args.resume {
        None => {
            let scene = args
                .scene
                .as_ref()
                .expect("clap requires a scene without --resume");
            let config = load_with_overrides(scene, &args.overrides)?;
            let output = args
                .output
                .clone()
                .unwrap_or_else(|| PathBuf::from(&config.output));
            (config, None, output, false)
        }
        Some(dir) => {
            let (folder, run) = checkpoint_and_run(dir);
            let checkpoint = Checkpoint::load(&folder)?;
            refuse_edited_scene(&run, &checkpoint.state.scene)?;
            let mut config = checkpoint.state.scene.clone();
            apply_overrides(&mut config, &args.overrides)?;
            let output = args.output.clone().unwrap_or_else(|| run.clone());
            let continuing = same_folder(&run, &output);
            (config, Some(checkpoint), output, continuing)
        }
    };
    if let Some(n) = args.iterations {
        set_iterations(&mut config, n, &args.overrides)?;
    }
    if let Some(n) = args.checkpoint_every {
        config.train.checkpoint_interval = n;
    }
    if let Some(n) = args.eval_every {
        config.train.eval_interval = n;
    }
    if let Some(backend) = &args.backend {
        set_backend(&mut config, backend_kind(backend))?;
    }

    // The run's scene.ron (and checkpoint) must work from any working directory.
    config.absolute_paths();
    // A new run never mixes its files with another run's: checked before the (slow) data
    // loading, and again once the folder is locked.
    if !continuing {
        refuse_existing_run(&output, args.force)?;
    }
    catch_ctrl_c();
    let dataset = Arc::new(load_dataset(&config)?);
    let _lock = RunLock::acquire(&output)?;
    if !continuing {
        if args.force {
            remove_run_outputs(&output)?;
        } else {
            refuse_existing_run(&output, false)?;
        }
    }
    // A resumed run's scene.ron is rewritten with its next checkpoint (its settings may
    // change with --set), so that the two always agree for the next --resume.
    if checkpoint.is_none() {
        write_atomic(&output.join("scene.ron"), scene_text(&config)?.as_bytes())?;
    }
    let (mut trainer, log) = match checkpoint {
        None => {
            let start = Instant::now();
            let mut trainer = Trainer::try_new(&config, dataset.clone())?;
            tracing::info!(
                "{} initial Gaussians in {:.1} s",
                trainer.gaussian_count(),
                start.elapsed().as_secs_f32()
            );
            (trainer, TrainingLog::default())
        }
        Some(mut checkpoint) => {
            if !same_schedule(&checkpoint.state.scene, &config) {
                tracing::warn!(
                    "the settings differ from the checkpoint's: the result will differ from an \
                     uninterrupted run"
                );
            }
            checkpoint.state.scene = config.clone();
            let trainer = Trainer::from_checkpoint(&checkpoint, dataset.clone())?;
            tracing::info!(
                "resuming at iteration {} of {} with {} Gaussians",
                checkpoint.state.iteration,
                config.train.iterations,
                checkpoint.gaussians.len()
            );
            (trainer, checkpoint.log)
        }
    };
    let live = if args.view {
        Some(LiveView::start(
            &config,
            &dataset,
            &mut trainer,
            args.view_port,
        )?)
    } else {
        None
    };
    let mut run = Run {
        config: &config,
        output: &output,
        trainer: &mut trainer,
        log,
        ui,
        live,
    };
    if !run.train_until(args.until)? {
        return Ok(());
    }
    run.finish(&dataset, &args)
}

/// A resumed run trains with its checkpoint's settings: fails when `run/scene.ron` was edited
/// since (the edit would otherwise be silently dropped), listing the lines that differ.
fn refuse_edited_scene(run: &Path, checkpoint: &SceneConfig) -> Result<()> {
    let path = run.join("scene.ron");
    if !path.is_file() {
        return Ok(());
    }
    let edited = tadgs::scene::load_scene(&path)?;
    if edited == *checkpoint {
        return Ok(());
    }
    let (ours, theirs) = (scene_text(checkpoint)?, scene_text(&edited)?);
    let changes: Vec<String> = ours
        .lines()
        .zip(theirs.lines())
        .filter(|(a, b)| a != b)
        .take(6)
        .map(|(a, b)| format!("`{}` → `{}`", a.trim(), b.trim()))
        .collect();
    bail!(
        "{} differs from the checkpoint's settings ({}): a resumed run keeps the settings it \
         started with. Give changes with --set KEY=VALUE or --iterations N, or restore the file",
        path.display(),
        changes.join(", ")
    )
}

/// Whether two scenes train the same way (everything but where the output goes).
fn same_schedule(a: &SceneConfig, b: &SceneConfig) -> bool {
    let mut b = b.clone();
    b.output.clone_from(&a.output);
    b.train.checkpoint_interval = a.train.checkpoint_interval;
    b.train.eval_interval = a.train.eval_interval;
    *a == b
}

/// A run in progress.
struct Run<'a> {
    config: &'a SceneConfig,
    output: &'a Path,
    trainer: &'a mut Trainer,
    log: TrainingLog,
    ui: Ui,
    /// The viewer of `--view`.
    live: Option<LiveView>,
}

impl Run<'_> {
    /// Trains up to iteration `until` (default: the end), writing checkpoints on the way and
    /// at the stop. Returns whether the run reached its last iteration.
    fn train_until(&mut self, until: Option<u32>) -> Result<bool> {
        let iterations = self.config.train.iterations;
        let start = self.trainer.state().iteration;
        let until = until.unwrap_or(iterations).min(iterations);
        if until <= start {
            bail!(
                "the run is already at iteration {start}, and --until / train.iterations ask to \
                 stop at {until}"
            );
        }
        let bar = self.ui.progress_bar(iterations as u64, "train");
        bar.set_position(start as u64);
        bar.reset_eta();
        // Where no bar can be drawn (output to a file or pipe), log a line every 5 % instead.
        let log_every = if bar.is_hidden() && !self.ui.quiet {
            (iterations / 20).max(1)
        } else {
            0
        };
        let mut smoothed_psnr = f32::NAN;
        let session_start = Instant::now();
        for i in start + 1..=until {
            let step_start = Instant::now();
            self.trainer.step();
            self.log.train_seconds += step_start.elapsed().as_secs_f64();
            let state = self.trainer.state();
            let gaussians = self.trainer.gaussian_count() as u32;
            let psnr = self.trainer.last_view_psnr();
            self.log.steps.push(StepRecord {
                iteration: i,
                loss: state.loss.total,
                psnr,
                gaussians,
            });
            let d = state.last_densify;
            if d.iteration == i {
                self.log.densify.push(DensifyRecord {
                    iteration: i,
                    cloned: d.cloned as u32,
                    split: d.split as u32,
                    pruned: d.pruned as u32,
                    gaussians,
                });
                tracing::debug!(
                    "iteration {i}: densified: {} cloned, {} split, {} pruned, {gaussians} Gaussians",
                    d.cloned,
                    d.split,
                    d.pruned
                );
            }
            if INTERRUPTED.load(Ordering::SeqCst) {
                bar.abandon();
                let dir = self.save_checkpoint()?;
                return Err(Stopped(format!(
                    "stopped after iteration {i}: checkpoint written to {}; continue with \
                     `tadgs train --resume {}`",
                    dir.display(),
                    self.output.display()
                ))
                .into());
            }
            if let Some(failure) = self.trainer.read_failure() {
                bar.abandon();
                bail!(
                    "iteration {}: {}: training stopped before anything was updated; the last \
                     checkpoint in {} is kept",
                    failure.iteration,
                    failure.message,
                    self.output.join("checkpoint").display()
                );
            }
            if let Some(fault) = self.trainer.fault() {
                bar.abandon();
                bail!(
                    "{fault}: training stopped before the value reached any parameter; the last \
                     checkpoint in {} is kept",
                    self.output.join("checkpoint").display()
                );
            }
            if psnr.is_finite() {
                // Exponential moving average: one view's PSNR is noisy.
                smoothed_psnr = if smoothed_psnr.is_finite() {
                    0.95 * smoothed_psnr + 0.05 * psnr
                } else {
                    psnr
                };
            }
            bar.set_position(i as u64);
            bar.set_message(format!(
                "loss {:.4} · PSNR {smoothed_psnr:.2} dB · {gaussians} Gaussians",
                state.loss.total
            ));
            if log_every > 0 && (i % log_every == 0 || i == until) {
                let seconds = session_start.elapsed().as_secs_f32();
                tracing::info!(
                    "iteration {i}/{iterations}: loss {:.4}, PSNR {smoothed_psnr:.2} dB, {gaussians} Gaussians, {:.2} it/s, {:.0} s",
                    state.loss.total,
                    (i - start) as f32 / seconds,
                    seconds
                );
            }
            if let Some(live) = &mut self.live {
                let status = TrainingStatus {
                    iteration: i,
                    iterations,
                    loss: self.trainer.state().loss.total,
                    psnr: smoothed_psnr,
                    gaussians: gaussians as usize,
                    shown_iteration: 0,
                };
                live.update(self.trainer, status);
            }
            let every = self.config.train.eval_interval;
            if every > 0 && i % every == 0 && i < iterations {
                if let Some(psnr) = self.trainer.heldout_psnr() {
                    self.log.heldout.push(HeldoutRecord { iteration: i, psnr });
                    let line = format!("iteration {i}: held-out PSNR {psnr:.2} dB");
                    // A hidden bar prints nothing: log the line instead.
                    if bar.is_hidden() {
                        tracing::info!("{line}");
                    } else {
                        bar.println(line);
                    }
                }
            }
            let every = self.config.train.checkpoint_interval;
            if every > 0 && i % every == 0 && i < until {
                self.save_checkpoint()?;
            }
        }
        bar.finish_and_clear();
        let path = self.save_checkpoint()?;
        if until < iterations {
            println!(
                "stopped after iteration {until} of {iterations}; checkpoint in {}\ncontinue with: tadgs train --resume {}",
                path.display(),
                self.output.display()
            );
            return Ok(false);
        }
        Ok(true)
    }

    fn save_checkpoint(&mut self) -> Result<PathBuf> {
        let start = Instant::now();
        let dir = self.output.join("checkpoint");
        let checkpoint = self.trainer.checkpoint(self.config, &self.log);
        write_atomic(
            &self.output.join("scene.ron"),
            scene_text(self.config)?.as_bytes(),
        )?;
        checkpoint.save(&dir)?;
        // The checkpoint synced the parameters: a cheap moment to look for a runaway.
        let diverged = self.trainer.diverged_count();
        if diverged > 0 {
            tracing::warn!(
                "iteration {}: {diverged} Gaussians are more than {} scene extents from the \
                 cameras: training is diverging; lower the learning rates (train.lr.*)",
                checkpoint.state.iteration,
                tadgs::train::DIVERGED_EXTENTS
            );
        }
        tracing::debug!(
            "checkpoint at iteration {} written to {} in {:.2} s",
            checkpoint.state.iteration,
            dir.display(),
            start.elapsed().as_secs_f32()
        );
        Ok(dir)
    }

    /// Saves the model, evaluates it, writes the metrics and the report, prints the summary.
    fn finish(mut self, dataset: &Dataset, args: &TrainCommand) -> Result<()> {
        let model = self.trainer.model();
        model.save(&self.output.join("model.safetensors"))?;
        let exposure = self
            .trainer
            .world
            .get_resource::<CameraExposures>()
            .and_then(CameraExposures::summary);
        if let Some(line) = &exposure {
            tracing::info!("camera exposure: {line}");
        }
        let keep = if args.no_report { 0 } else { REPORT_VIEWS };
        let (evaluation, views) = evaluate(
            self.trainer,
            dataset,
            self.output,
            &args.eval,
            self.ui,
            keep,
        )?;
        let summary = RunSummary::new(
            self.config,
            &evaluation,
            model.gaussians.len(),
            Some(self.log.train_seconds as f32),
        );
        write_metrics(self.output, &summary, &evaluation.scores)?;
        summary.print(self.output);
        if args.no_report {
            return Ok(());
        }
        if let Some(psnr) = summary.psnr() {
            self.log.heldout.push(HeldoutRecord {
                iteration: self.config.train.iterations,
                psnr,
            });
        }
        let mut figures = summary.rows();
        figures.push((
            "densification steps".into(),
            self.log.densify.len().to_string(),
        ));
        if let Some(line) = exposure {
            figures.push(("camera exposure (mean per camera)".into(), line));
        }
        let report = Report {
            title: format!("tadgs run: {}", self.config.name),
            figures,
            log: &self.log,
            lifespans: self.trainer.lifespans(),
            views,
            frames: FrameScores::per_frame(
                evaluation
                    .scores
                    .iter()
                    .map(|v| (v.frame, v.psnr, v.masked_psnr)),
            ),
            anchor_frames: dataset.anchor_frames(self.config.init.anchor_spacing),
        };
        let page = report
            .write(&self.output.join("report"))
            .context("writing the run report")?;
        println!("{:<16} {}", "report", page.display());
        Ok(())
    }
}
