//! `tadgs info`: what a scene file, run folder, model, splat file or checkpoint holds.

use std::path::{Path, PathBuf};

use anyhow::Result;
use tadgs::io::checkpoint::{Checkpoint, STATE_FILE};
use tadgs::io::model::Model;
use tadgs::model::deform::{lifespan_fraction, sigmoid};
use tadgs::resources::Settings;

use super::input::Input;
use super::{load_dataset, load_with_overrides, scene_text};

/// `tadgs info`.
#[derive(clap::Args, Debug)]
pub struct InfoCommand {
    /// A scene file (.ron: prints the resolved settings), a run folder (settings, model,
    /// metrics and checkpoint), a model (.safetensors), a splat file (.ply) or a checkpoint
    /// folder.
    pub path: PathBuf,
    /// Override any scene setting (as for `train`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Also load the scene's data and describe it (cameras, views, memory).
    #[arg(long)]
    pub data: bool,
}

pub fn info(args: InfoCommand) -> Result<()> {
    let path = &args.path;
    let is_ron = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("ron"));
    if is_ron {
        let config = load_with_overrides(path, &args.overrides)?;
        println!("{}", scene_text(&config)?);
        if args.data {
            describe_dataset(&load_dataset(&config)?);
        }
        return Ok(());
    }
    if path.join(STATE_FILE).is_file() {
        return describe_checkpoint(path);
    }
    let mut input = Input::load(path, &args.overrides)?;
    let dataset = if args.data { input.dataset()? } else { None };
    let frames = input.resolve_frame_count(dataset.as_ref())?;
    if let Some(scene) = &input.scene {
        println!(
            "run              {} (scene `{}`)",
            path.display(),
            scene.name
        );
    }
    describe_model(
        &input.model,
        &Settings::new(&input.scene(None), frames, 1.0),
    );
    let file = if path.is_dir() {
        path.join("model.safetensors")
    } else {
        path.clone()
    };
    if let Ok(meta) = std::fs::metadata(&file) {
        println!("file size        {:.1} MB", meta.len() as f64 / 1e6);
    }
    if path.is_dir() {
        describe_run(path);
    }
    if let Some(dataset) = dataset {
        describe_dataset(&dataset);
    }
    Ok(())
}

fn describe_model(model: &Model, settings: &Settings) {
    let n = model.gaussians.len();
    println!("Gaussians        {n}");
    println!("SH degree        {}", model.sh_degree);
    println!(
        "frames           {}",
        model
            .frame_count
            .map_or("unknown".into(), |f| f.to_string())
    );
    if let Some(windows) = &model.time_windows {
        let mut segments: Vec<(f32, f32)> = windows.iter().map(|w| (w.start, w.end)).collect();
        segments.sort_by(|a, b| a.0.total_cmp(&b.0));
        segments.dedup();
        println!(
            "segments         {} merged (time windows, CPU backend only)",
            segments.len()
        );
    }
    if let Some(motion) = &model.shared_motion {
        println!(
            "shared motion    {} bases of {} knots (CPU backend only)",
            motion.bases.bases, motion.bases.knots
        );
    }
    let m = &settings.model;
    println!(
        "deformation      opacity {:?}, phase {:?}, scale motion {}, TOW {}",
        m.opacity, m.phase, m.scale_motion, m.tow.enabled
    );
    if n == 0 {
        return;
    }
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for g in &model.gaussians {
        for axis in 0..3 {
            lo[axis] = lo[axis].min(g.position.mean[axis]);
            hi[axis] = hi[axis].max(g.position.mean[axis]);
        }
    }
    println!("bounds           {lo:.3?} to {hi:.3?}");
    let mut opacity: Vec<f32> = model
        .gaussians
        .iter()
        .map(|g| sigmoid(g.opacity.logit))
        .collect();
    opacity.sort_by(f32::total_cmp);
    println!(
        "spatial opacity  median {:.3} (10 % below {:.3}, 10 % above {:.3})",
        opacity[n / 2],
        opacity[n / 10],
        opacity[n * 9 / 10]
    );
    let mut centres: Vec<f32> = model.gaussians.iter().map(|g| g.temporal.center).collect();
    centres.sort_by(f32::total_cmp);
    centres.dedup();
    let lifespans: Vec<f32> = model
        .gaussians
        .iter()
        .map(|g| {
            lifespan_fraction(
                settings.opacity,
                g.temporal.scale,
                g.temporal.center,
                &settings.warp,
            )
        })
        .collect();
    println!(
        "temporal         {} distinct centres, mean lifespan ψ̄ {:.3}",
        centres.len(),
        lifespans.iter().sum::<f32>() / n as f32
    );
}

fn describe_run(run: &Path) {
    if let Ok(text) = std::fs::read_to_string(run.join("metrics.json"))
        && let Ok(json) = serde_json::from_str::<serde_json::Value>(&text)
    {
        let s = &json["summary"];
        let value = |key: &str| s[key].as_f64().map_or("n/a".into(), |v| format!("{v:.4}"));
        println!(
            "metrics          PSNR {}, SSIM {}, LPIPS {}, M-PSNR {}",
            value("psnr"),
            value("ssim"),
            value("lpips"),
            value("masked_psnr")
        );
    }
    let checkpoint = run.join("checkpoint");
    if checkpoint.join(STATE_FILE).is_file() {
        match Checkpoint::load(&checkpoint) {
            Ok(c) => println!(
                "checkpoint       iteration {} of {}, {} Gaussians",
                c.state.iteration,
                c.state.scene.train.iterations,
                c.gaussians.len()
            ),
            Err(e) => println!("checkpoint       unreadable: {e}"),
        }
    }
    if run.join("report/index.html").is_file() {
        println!(
            "report           {}",
            run.join("report/index.html").display()
        );
    }
}

fn describe_checkpoint(dir: &Path) -> Result<()> {
    let c = Checkpoint::load(dir)?;
    let s = &c.state;
    println!("checkpoint       {}", dir.display());
    println!("scene            {}", s.scene.name);
    println!(
        "iteration        {} of {}",
        s.iteration, s.scene.train.iterations
    );
    println!("Gaussians        {}", c.gaussians.len());
    println!("SH degree        {}", s.sh_degree);
    println!(
        "epoch            view {} of {}",
        s.view_next,
        s.view_order.len()
    );
    println!(
        "training time    {:.1} s over {} logged iterations",
        c.log.train_seconds,
        c.log.steps.len()
    );
    Ok(())
}

fn describe_dataset(dataset: &tadgs::data::Dataset) {
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
    if !dataset.frame_points.is_empty() {
        let frames: Vec<usize> = dataset.frame_points.iter().map(|(f, _)| *f).collect();
        let points: usize = dataset.frame_points.iter().map(|(_, p)| p.len()).sum();
        println!("initial points {points} in per-frame clouds at frames {frames:?}");
    } else if let Some(points) = &dataset.points {
        println!("initial points {} in the dataset's cloud", points.len());
    }
}
