//! `tadgs render`: images or a video of a model along a camera path.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::{Result, bail};
use glam::Vec3;
use tadgs::data::{Camera, Dataset};
use tadgs::io::camera_path::{Orbit, Shot, interpolate, load_camera, load_path};
use tadgs::io::video::{VideoWriter, ffmpeg_available};
use tadgs::train::Trainer;

use super::Ui;
use super::input::{Input, ensure_parent, needs_run, parse_rgb, parse_vec3};

/// Where the cameras come from (one of them; `--orbit` when none is given).
#[derive(clap::Args, Debug, Default)]
#[group(multiple = false)]
pub struct CameraSource {
    /// Circle the scene: around the point the training cameras look at, at their mean
    /// distance and height (run folders), or around the Gaussians' median at 2.5× their
    /// spread, 30° up (model files). The default.
    #[arg(long)]
    pub orbit: bool,
    /// A dataset camera over time: camera index CAM (default: the first held-out camera) at
    /// every frame of the sequence. Needs a run folder; loads its data.
    #[arg(long, value_name = "CAM", num_args = 0..=1, default_missing_value = "-1")]
    pub heldout: Option<i64>,
    /// One camera from a RON file (width, height, fx, fy, cx, cy, 4×4 world_to_camera
    /// written row by row, OpenCV convention: x right, y down, z forward).
    #[arg(long, value_name = "FILE")]
    pub camera: Option<PathBuf>,
    /// A camera path from a RON file: (keys: [(camera: (..), time: 0.0), ...]); with
    /// --frames larger than the number of keys it is interpolated between them.
    #[arg(long, value_name = "FILE")]
    pub path: Option<PathBuf>,
}

/// `tadgs render`.
#[derive(clap::Args, Debug)]
// Negative numbers are values (and refused with a clear message), not unknown flags.
#[command(allow_negative_numbers = true)]
pub struct RenderCommand {
    /// What to render: a run folder (scene.ron + model.safetensors), a model file
    /// (.safetensors) or a static 3DGS splat file (.ply).
    pub input: PathBuf,
    #[command(flatten)]
    pub cameras: CameraSource,
    /// Number of frames. Default: 120 for --orbit and --camera, the sequence's frames for
    /// --heldout, the number of keys for --path, 1 for a .png output.
    #[arg(long, value_name = "N")]
    pub frames: Option<usize>,
    /// Show every frame at this normalised time in [0, 1] instead of sweeping from 0 to 1
    /// (paths use their keys' times unless this is given).
    #[arg(long, value_name = "T")]
    pub time: Option<f32>,
    /// Output: a .mp4 file (encoded by the system ffmpeg; PNG frames in a folder of that name
    /// without .mp4 when ffmpeg is missing), a .png file for a single frame, or a folder for
    /// PNG frames (frame_0000.png, ...). Default: render.mp4 in the run folder (beside a model
    /// file), or a render/ folder without ffmpeg.
    #[arg(long, short, value_name = "PATH")]
    pub output: Option<PathBuf>,
    /// Video frame rate.
    #[arg(long, default_value_t = 30.0, value_name = "FPS")]
    pub fps: f32,
    /// Background colour as r,g,b in [0, 1]. Default: the scene's, black for model files.
    #[arg(long, value_name = "R,G,B", value_parser = parse_rgb)]
    pub background: Option<[f32; 3]>,
    /// Orbit image size in pixels as WIDTHxHEIGHT. Default: the first dataset camera's, or
    /// 960x540 for model files.
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    pub size: Option<(u32, u32)>,
    /// Orbit: world up direction as x,y,z. Default: the cameras' mean image-up (run folders),
    /// 0,-1,0 for model files (the usual COLMAP orientation of splats trained elsewhere).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_vec3)]
    pub up: Option<Vec3>,
    /// Orbit: scale the orbit's radius and height by this factor (below 1 moves closer).
    #[arg(long, default_value_t = 1.0, value_name = "F")]
    pub distance: f32,
    /// Override settings of a run's scene (e.g. the data path), as for `train`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

/// Parses "WIDTHxHEIGHT".
fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let parsed = text
        .split_once(['x', 'X'])
        .and_then(|(w, h)| Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?)));
    let max = tadgs::data::MAX_IMAGE_SIDE;
    match parsed {
        Some((w, h)) if (1..=max).contains(&w) && (1..=max).contains(&h) => Ok((w, h)),
        Some(_) => Err(format!(
            "{text:?}: each side must be between 1 and {max} pixels"
        )),
        None => Err(format!(
            "expected WIDTHxHEIGHT such as 960x540, got {text:?}"
        )),
    }
}

/// Normalised time of frame `k` of `n` when sweeping 0 → 1.
fn sweep(k: usize, n: usize) -> f32 {
    if n <= 1 {
        0.0
    } else {
        k as f32 / (n - 1) as f32
    }
}

pub fn render(mut args: RenderCommand, ui: Ui) -> Result<()> {
    // Only a given output can be a .png (the default is a video or a folder).
    let is_png = args
        .output
        .as_ref()
        .and_then(|p| p.extension())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"));
    if is_png && args.frames.is_none() {
        // One image is one frame.
        args.frames = Some(1);
    }
    if let Some(n) = args
        .frames
        .filter(|n| !(1..=tadgs::data::MAX_FRAMES).contains(n))
    {
        bail!(
            "--frames must be between 1 and {}, got {n}",
            tadgs::data::MAX_FRAMES
        );
    }
    if args.time.is_some_and(|t| !(0.0..=1.0).contains(&t)) {
        bail!("--time must lie in [0, 1]");
    }
    if !(args.fps > 0.0 && args.fps.is_finite()) {
        bail!("--fps must be positive");
    }
    let mut input = Input::load(&args.input, &args.overrides)?;
    let c = &args.cameras;
    // Run folders load their data only where the cameras are needed.
    let needs_data = c.heldout.is_some() || (c.camera.is_none() && c.path.is_none());
    let dataset = if needs_data { input.dataset()? } else { None };
    let frame_count = input.resolve_frame_count(dataset.as_ref())?;
    let shots = shots(&args, &input, dataset.as_ref())?;

    let scene = input.scene(args.background);
    let first = shots[0].camera;
    let render_data = Dataset {
        cameras: vec![first],
        frame_count,
        ..Dataset::default()
    };
    let mut trainer = Trainer::try_from_model(&scene, Arc::new(render_data), &input.model)?;

    let output = output_path(&args, &input, shots.len())?;
    ensure_parent(&output)?;
    let bar = ui.progress_bar(shots.len() as u64, "render");
    let is_mp4 = output
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mp4"));
    if is_png && shots.len() > 1 {
        bail!(
            "{} is one image but {} frames are rendered: give a folder or a .mp4 file",
            output.display(),
            shots.len()
        );
    }
    let written = if is_png {
        let image = trainer.render(&first, shots[0].time).image;
        image.save_png(&output)?;
        output
    } else if is_mp4 && ffmpeg_available() {
        let mut video = VideoWriter::start(
            &output,
            first.width as usize,
            first.height as usize,
            args.fps,
        )?;
        for shot in &shots {
            video.push(&trainer.render(&shot.camera, shot.time).image)?;
            bar.inc(1);
        }
        video.finish()?
    } else {
        let folder = if is_mp4 {
            let folder = output.with_extension("");
            tracing::warn!(
                "ffmpeg is not installed: writing PNG frames to {} instead of {}",
                folder.display(),
                output.display()
            );
            folder
        } else {
            output
        };
        super::create_dir(&folder)?;
        for (k, shot) in shots.iter().enumerate() {
            let image = trainer.render(&shot.camera, shot.time).image;
            image.save_png(&folder.join(format!("frame_{k:04}.png")))?;
            bar.inc(1);
        }
        folder
    };
    bar.finish_and_clear();
    println!(
        "{} frame{} of {}×{} written to {}",
        shots.len(),
        if shots.len() == 1 { "" } else { "s" },
        first.width,
        first.height,
        written.display()
    );
    Ok(())
}

/// The default output: a video where ffmpeg is installed, else a folder of frames.
fn output_path(args: &RenderCommand, input: &Input, frames: usize) -> Result<PathBuf> {
    if let Some(path) = &args.output {
        // A folder has no extension; .png and .mp4 are files; anything else is a mistake.
        if let Some(ext) = path.extension().map(|e| e.to_string_lossy().to_lowercase()) {
            if ext != "png" && ext != "mp4" {
                bail!(
                    "-o {}: renders are written as .png, .mp4 or a folder of PNGs, not .{ext}",
                    path.display()
                );
            }
        }
        return Ok(path.clone());
    }
    Ok(if frames > 1 && ffmpeg_available() {
        input.default_output("render.mp4")
    } else {
        input.default_output("render")
    })
}

/// The cameras and times to render.
fn shots(args: &RenderCommand, input: &Input, dataset: Option<&Dataset>) -> Result<Vec<Shot>> {
    let c = &args.cameras;
    let at = |camera: Camera, k: usize, n: usize| Shot {
        camera,
        time: args.time.unwrap_or_else(|| sweep(k, n)),
    };
    if let Some(path) = &c.path {
        let keys = load_path(path)?;
        let mut shots = interpolate(&keys, args.frames.unwrap_or(keys.len()));
        if let Some(time) = args.time {
            shots.iter_mut().for_each(|s| s.time = time);
        }
        return Ok(shots);
    }
    if let Some(file) = &c.camera {
        let camera = load_camera(file)?;
        let n = args.frames.unwrap_or(120);
        return Ok((0..n).map(|k| at(camera, k, n)).collect());
    }
    if let Some(index) = c.heldout {
        needs_run("--heldout", input)?;
        let dataset = dataset.expect("run folders load their data for --heldout");
        let camera = if index < 0 {
            match dataset.test_cameras().first() {
                Some(&camera) => camera,
                None => bail!("the scene has no held-out camera: give --heldout CAM"),
            }
        } else {
            index as usize
        };
        let Some(&cam) = dataset.cameras.get(camera) else {
            bail!(
                "camera {camera} does not exist (the scene has {} cameras)",
                dataset.cameras.len()
            );
        };
        let n = args.frames.unwrap_or(dataset.frame_count);
        return Ok((0..n).map(|k| at(cam, k, n)).collect());
    }
    let mut orbit = match dataset {
        Some(dataset) => Orbit::around_rig(&dataset.cameras),
        None => {
            let points: Vec<Vec3> = input
                .model
                .gaussians
                .iter()
                .map(|g| Vec3::from(g.position.mean))
                .collect();
            if points.is_empty() {
                bail!("{} holds no Gaussians", input.path.display());
            }
            Orbit::around_points(&points, Vec3::NEG_Y, 960, 540)
        }
    };
    if let Some(up) = args.up {
        if !(up.length() > 1e-6 && up.is_finite()) {
            bail!("--up {},{},{} is not a direction", up.x, up.y, up.z);
        }
        orbit.up = up.normalize();
        orbit.start = (orbit.start - orbit.up * orbit.start.dot(orbit.up))
            .normalize_or(orbit.up.any_orthonormal_vector());
    }
    if let Some((w, h)) = args.size {
        orbit.width = w;
        orbit.height_px = h;
    }
    if !(args.distance > 0.0 && args.distance.is_finite()) {
        bail!("--distance must be positive");
    }
    orbit.radius *= args.distance;
    orbit.height *= args.distance;
    let n = args.frames.unwrap_or(120);
    Ok(orbit
        .cameras(n)
        .into_iter()
        .enumerate()
        .map(|(k, camera)| at(camera, k, n))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sizes parse as WIDTHxHEIGHT and zero or malformed sizes are refused.
    #[test]
    fn size_parsing() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(parse_size("0x480").is_err());
        assert!(parse_size("100000x100000").is_err());
        assert_eq!(parse_size("16384x16384"), Ok((16384, 16384)));
        assert!(parse_size("640").is_err());
    }

    /// A sweep starts at 0 and ends at 1; a single frame is time 0.
    #[test]
    fn sweep_ends() {
        assert_eq!(sweep(0, 5), 0.0);
        assert_eq!(sweep(4, 5), 1.0);
        assert_eq!(sweep(0, 1), 0.0);
    }
}
