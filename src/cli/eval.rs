//! `tadgs eval` and `tadgs masks`, and the evaluation that `train` runs at its end.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::{Result, bail};
use tadgs::data::Dataset;
use tadgs::io::image::Image;
use tadgs::io::model::Model;
use tadgs::metrics::eval::{MaskSource, ScoreSummary, ViewScores, dynamic_masks};
use tadgs::metrics::flow::DEFAULT_FLOW_THRESHOLD;
use tadgs::metrics::lpips::Lpips;
use tadgs::report::ReportView;
use tadgs::scene::SceneConfig;
use tadgs::train::{Evaluation, Trainer};

use super::run_folder::RunLock;
use super::{Ui, create_dir, load_dataset, load_with_overrides, write_atomic};

/// Options shared by the commands that score held-out views.
#[derive(clap::Args, Clone, Debug)]
pub struct EvalArgs {
    /// LPIPS (AlexNet) weights in safetensors form. Default: $TADGS_LPIPS, else
    /// ../shared/data/lpips/alex.safetensors when present; without weights LPIPS is skipped.
    #[arg(long, value_name = "FILE")]
    pub lpips: Option<PathBuf>,
    /// Folder of dynamic-mask PNGs (camCC_frameFFFF.png, white = dynamic) to use for M-PSNR and
    /// M-SSIM; missing masks are computed by optical flow and written there. Default:
    /// <output>/masks.
    #[arg(long, value_name = "DIR")]
    pub masks: Option<PathBuf>,
    /// Flow magnitude (pixels, between frames t−5 and t) above which a pixel is dynamic.
    #[arg(long, default_value_t = DEFAULT_FLOW_THRESHOLD, value_name = "PIXELS")]
    pub flow_threshold: f32,
    /// Do not write the render | ground-truth PNG of every held-out view.
    #[arg(long)]
    pub no_renders: bool,
}

/// Which views `eval` scores.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split {
    /// The held-out views (the protocol).
    Test,
    /// The training views instead (how well the model fits what it saw; results go to
    /// <run>/train-split/).
    Train,
}

/// `tadgs eval`.
#[derive(clap::Args, Debug)]
// Negative numbers are values (and refused with a clear message), not unknown flags.
#[command(allow_negative_numbers = true)]
pub struct EvalCommand {
    /// Run folder written by `tadgs train` (holds scene.ron and model.safetensors).
    pub run: PathBuf,
    /// Override scene settings (e.g. the data path) before loading the data.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Score the held-out views (test) or the training views (train).
    #[arg(long, value_enum, default_value_t = Split::Test)]
    pub split: Split,
    #[command(flatten)]
    pub eval: EvalArgs,
}

/// `tadgs masks`.
#[derive(clap::Args, Debug)]
// Negative numbers are values (and refused with a clear message), not unknown flags.
#[command(allow_negative_numbers = true)]
pub struct MasksCommand {
    /// Scene file (RON).
    pub scene: PathBuf,
    /// Override any scene setting.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Folder for the mask PNGs (with masks.ron recording the threshold; masks made with
    /// another threshold are computed again).
    #[arg(long, short, value_name = "DIR")]
    pub output: PathBuf,
    /// Flow magnitude (pixels) above which a pixel is dynamic.
    #[arg(long, default_value_t = DEFAULT_FLOW_THRESHOLD, value_name = "PIXELS")]
    pub flow_threshold: f32,
}

/// A flow threshold is a positive number of pixels.
fn check_flow_threshold(threshold: f32) -> Result<()> {
    if !(threshold > 0.0 && threshold.is_finite()) {
        bail!("--flow-threshold must be a positive number of pixels, got {threshold}");
    }
    Ok(())
}

impl EvalArgs {
    /// Checks the paths and numbers given, so that a typo stops the command before training
    /// or loading data rather than after.
    pub fn check(&self) -> Result<()> {
        check_flow_threshold(self.flow_threshold)?;
        if let Some(path) = &self.lpips {
            if !path.is_file() {
                bail!("--lpips {}: no such file", path.display());
            }
        }
        if let Some(dir) = &self.masks {
            if dir.exists() && !dir.is_dir() {
                bail!("--masks {}: not a folder", dir.display());
            }
            if !dir.exists() {
                tracing::warn!(
                    "--masks {}: no such folder yet; the masks will be computed and written there",
                    dir.display()
                );
            }
        }
        Ok(())
    }
}

pub fn eval(args: EvalCommand, ui: Ui) -> Result<()> {
    let EvalCommand {
        run,
        overrides,
        split,
        mut eval,
    } = args;
    eval.check()?;
    let config = load_with_overrides(&run.join("scene.ron"), &overrides)?;
    let model_path = run.join("model.safetensors");
    if !model_path.is_file() && run.join("checkpoint").is_dir() {
        bail!(
            "{} is an unfinished run (no model.safetensors yet): finish it with `tadgs train \
             --resume {}`; `tadgs render` shows its checkpoint as it is",
            run.display(),
            run.display()
        );
    }
    let model = Model::load(&model_path)?;
    let mut dataset = load_dataset(&config)?;
    let mismatches = model.mismatches(&config, dataset.frame_count);
    if !mismatches.is_empty() {
        bail!(
            "{} does not belong to {}: {}; nothing was written",
            model_path.display(),
            run.join("scene.ron").display(),
            mismatches.join("; ")
        );
    }
    let output = match split {
        Split::Test => run.clone(),
        Split::Train => {
            // Score the training views through the same path as held-out ones.
            dataset.test = std::mem::take(&mut dataset.train);
            eval.masks = None;
            run.join("train-split")
        }
    };
    let _lock = RunLock::acquire(&output)?;
    let dataset = Arc::new(dataset);
    let mut trainer = Trainer::try_from_model(&config, dataset.clone(), &model)?;
    let (report, _) = evaluate(&mut trainer, &dataset, &output, &eval, ui, 0)?;
    let summary = RunSummary::new(&config, &report, model.gaussians.len(), None);
    write_metrics(&output, &summary, &report.scores)?;
    summary.print(&output);
    Ok(())
}

pub fn masks(args: MasksCommand, ui: Ui) -> Result<()> {
    check_flow_threshold(args.flow_threshold)?;
    let config = load_with_overrides(&args.scene, &args.overrides)?;
    let dataset = load_dataset(&config)?;
    let source = MaskSource {
        folder: Some(args.output.clone()),
        compute: true,
        threshold: args.flow_threshold,
    };
    let bar = ui.progress_bar(dataset.test.len() as u64, "masks");
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
        args.output.display()
    );
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

/// Scores every held-out view (masks first, then renders) and writes the renders. Also
/// returns up to `keep` views, evenly spread over the held-out set, for the run report.
pub fn evaluate(
    trainer: &mut Trainer,
    dataset: &Dataset,
    output: &Path,
    args: &EvalArgs,
    ui: Ui,
    keep: usize,
) -> Result<(Evaluation, Vec<ReportView>)> {
    let lpips = lpips_weights(args.lpips.as_deref())?;
    let source = MaskSource {
        folder: Some(args.masks.clone().unwrap_or_else(|| output.join("masks"))),
        compute: true,
        threshold: args.flow_threshold,
    };
    let bar = ui.progress_bar(dataset.test.len() as u64, "masks");
    let masks = dynamic_masks(dataset, &source, || bar.inc(1))?;
    bar.finish_and_clear();

    let heldout = output.join("heldout");
    if !args.no_renders {
        create_dir(&heldout)?;
    }
    let count = dataset.test.len();
    let kept: Vec<usize> = match (keep, count) {
        (0, _) | (_, 0) => Vec::new(),
        (1, _) => vec![count / 2],
        _ => {
            let mut picks: Vec<usize> = (0..keep).map(|k| k * (count - 1) / (keep - 1)).collect();
            picks.dedup();
            picks
        }
    };
    let mut views = Vec::new();
    let bar = ui.progress_bar(count as u64, "eval");
    let mut save_error = None;
    let mut index = 0;
    let report = trainer.evaluate(lpips.as_ref(), &masks, |score, render, gt| {
        bar.inc(1);
        if kept.contains(&index) {
            views.push(ReportView {
                caption: format!(
                    "Camera {}, frame {}: PSNR {:.2} dB, SSIM {:.3}",
                    score.camera, score.frame, score.psnr, score.ssim
                ),
                render: render.clone(),
                ground_truth: gt.clone(),
            });
        }
        index += 1;
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
    Ok((report, views))
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
pub struct RunSummary {
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
    pub fn new(
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

    /// The summary as (name, value) rows, as printed.
    pub fn rows(&self) -> Vec<(String, String)> {
        let db = |v: Option<f32>| v.map_or("n/a".to_string(), |v| format!("{v:.2} dB"));
        let plain = |v: Option<f32>| v.map_or("n/a".to_string(), |v| format!("{v:.4}"));
        let s = &self.scores;
        let mut rows = vec![
            ("scene", self.scene.clone()),
            (
                "iterations",
                format!(
                    "{}  (VAD {}, TAT {}, TOW {})",
                    self.iterations, self.vad, self.tat, self.tow
                ),
            ),
            ("views scored", s.views.to_string()),
            ("PSNR", db(s.psnr)),
            ("SSIM", plain(s.ssim)),
            ("LPIPS (alex)", plain(s.lpips)),
            (
                "M-PSNR",
                format!(
                    "{}  ({} views with a dynamic mask)",
                    db(s.masked_psnr),
                    s.masked_views
                ),
            ),
            ("M-SSIM", plain(s.masked_ssim)),
            ("Gaussians", self.gaussians.to_string()),
        ];
        if let Some(t) = self.train_seconds {
            rows.push(("training time", format!("{t:.1} s")));
        }
        rows.push(("render speed", format!("{:.1} frames/s", self.render_fps)));
        rows.into_iter().map(|(k, v)| (k.to_string(), v)).collect()
    }

    pub fn print(&self, output: &Path) {
        for (name, value) in self.rows() {
            println!("{name:<16} {value}");
        }
        println!("{:<16} {}", "results", output.display());
    }

    /// Mean held-out PSNR, if any view was scored.
    pub fn psnr(&self) -> Option<f32> {
        self.scores.psnr
    }
}

pub fn write_metrics(output: &Path, summary: &RunSummary, scores: &[ViewScores]) -> Result<()> {
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
