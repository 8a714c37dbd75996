//! `tadgs export`: per-frame splat PLY files, or the self-contained 4D model.

use std::path::PathBuf;

use anyhow::{Result, bail};
use tadgs::io::ply::{snapshot, write_splat_ply};
use tadgs::resources::Settings;

use super::Ui;
use super::input::{Input, ensure_parent};

/// Export formats.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// One PLY per chosen time in the standard 3DGS layout (binary little endian; position,
    /// zero normals, f_dc_*, f_rest_*, logit opacity, log scales, rotation), the Gaussians
    /// evaluated at that time; opens in common splat viewers.
    Ply,
    /// Every Gaussian's full temporal parameters in one safetensors file with the frame count
    /// and deformation settings, which `tadgs render`, `export` and `info` read on their own.
    #[value(name = "4d")]
    FourD,
}

/// `tadgs export`.
#[derive(clap::Args, Debug)]
// Negative numbers are values (and refused with a clear message), not unknown flags.
#[command(allow_negative_numbers = true)]
pub struct ExportCommand {
    /// What to export: a run folder, a model file (.safetensors) or a splat file (.ply).
    pub input: PathBuf,
    /// Output format.
    #[arg(long, value_enum, default_value_t = ExportFormat::Ply)]
    pub format: ExportFormat,
    /// PLY: normalised times in [0, 1] to export, comma-separated (e.g. 0,0.5,1).
    #[arg(long, value_name = "T,..", value_delimiter = ',', num_args = 1..)]
    pub times: Vec<f32>,
    /// PLY: frame indices to export, comma-separated (time = frame / (T − 1)).
    #[arg(long, value_name = "F,..", value_delimiter = ',', num_args = 1..)]
    pub frames: Vec<usize>,
    /// PLY: export every frame of the sequence.
    #[arg(long)]
    pub every_frame: bool,
    /// PLY: leave out Gaussians whose opacity σ(t) at that time is below this (the rasterizer
    /// never draws those under 1/255).
    #[arg(long, default_value_t = 1.0 / 255.0, value_name = "OPACITY")]
    pub min_opacity: f32,
    /// Output: for ply, a folder (frame_FFFF.ply for frames, time_T.TTTT.ply for times), or a
    /// .ply file when one time is exported; for 4d, a .safetensors file. Default: export/ or
    /// model_4d.safetensors in the run folder (beside a model file).
    #[arg(long, short, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// Override settings of a run's scene (e.g. the data path), as for `train`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

pub fn export(args: ExportCommand, ui: Ui) -> Result<()> {
    let mut input = Input::load(&args.input, &args.overrides)?;
    let frame_count = input.resolve_frame_count(None)?;
    if args.format == ExportFormat::FourD {
        if !args.times.is_empty() || !args.frames.is_empty() || args.every_frame {
            bail!("--times, --frames and --every-frame apply to --format ply");
        }
        let path = args
            .output
            .clone()
            .unwrap_or_else(|| input.default_output("model_4d.safetensors"));
        if path
            .extension()
            .is_none_or(|e| !e.eq_ignore_ascii_case("safetensors"))
        {
            bail!(
                "--format 4d writes a safetensors file: name the output *.safetensors, not {}",
                path.display()
            );
        }
        ensure_parent(&path)?;
        let mut model = input.model.clone();
        if model.config.is_none() {
            model.config = Some(input.scene(None).model);
        }
        model.save(&path)?;
        println!(
            "{} Gaussians with their temporal parameters ({} frames) written to {}",
            model.gaussians.len(),
            frame_count,
            path.display()
        );
        return Ok(());
    }

    if !(0.0..=1.0).contains(&args.min_opacity) {
        bail!(
            "--min-opacity: {} is not an opacity in [0, 1]",
            args.min_opacity
        );
    }
    // (file name, time) of every PLY to write.
    let frame_time = |f: usize| tadgs::data::frame_time(f, frame_count);
    let mut exports: Vec<(String, f32)> = Vec::new();
    for &t in &args.times {
        if !(0.0..=1.0).contains(&t) {
            bail!("--times: {t} is outside [0, 1]");
        }
        exports.push((format!("time_{t:.4}.ply"), t));
    }
    let frames: Vec<usize> = if args.every_frame {
        (0..frame_count).collect()
    } else {
        args.frames.clone()
    };
    for f in frames {
        if f >= frame_count {
            bail!("--frames: frame {f} is past the sequence's {frame_count} frames");
        }
        exports.push((format!("frame_{f:04}.ply"), frame_time(f)));
    }
    let mut names: Vec<&str> = exports.iter().map(|(name, _)| name.as_str()).collect();
    names.sort_unstable();
    if let Some(twice) = names.windows(2).find(|w| w[0] == w[1]) {
        bail!(
            "{} would be written twice: give each time (to 4 decimals) and frame once",
            twice[0]
        );
    }
    if exports.is_empty() {
        bail!("choose what to export: --times, --frames or --every-frame (or --format 4d)");
    }
    let single_file = args
        .output
        .as_ref()
        .is_some_and(|p| p.extension().is_some_and(|e| e.eq_ignore_ascii_case("ply")));
    if single_file && exports.len() > 1 {
        bail!(
            "{} exports but one .ply output file: give a folder",
            exports.len()
        );
    }
    let target = args
        .output
        .clone()
        .unwrap_or_else(|| input.default_output("export"));
    if single_file {
        ensure_parent(&target)?;
    } else {
        super::create_dir(&target)?;
    }
    let settings = Settings::new(&input.scene(None), frame_count, 1.0);
    let bar = ui.progress_bar(exports.len() as u64, "export");
    for (name, time) in &exports {
        let cloud = snapshot(&input.model, &settings, *time, args.min_opacity);
        let path = if single_file {
            target.clone()
        } else {
            target.join(name)
        };
        write_splat_ply(&path, &cloud)?;
        tracing::info!(
            "t = {time:.4}: {} of {} Gaussians in {}",
            cloud.splats.len(),
            input.model.gaussians.len(),
            path.display()
        );
        bar.inc(1);
    }
    bar.finish_and_clear();
    println!(
        "{} PLY file{} (SH degree {}) written to {}",
        exports.len(),
        if exports.len() == 1 { "" } else { "s" },
        input.model.sh_degree,
        target.display()
    );
    Ok(())
}
