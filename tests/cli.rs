//! End-to-end runs of the `tadgs` binary on a tiny synthetic scene: train writes a model and
//! the metrics table, `eval` reproduces it from the saved model, `masks` writes PNGs, and bad
//! input fails with one clear line.

mod common;
#[path = "common/gpu.rs"]
mod gpu;
#[path = "common/cli.rs"]
mod tiny;

use std::path::Path;
use std::process::Command;

use tiny::{run_fails, run_ok, tadgs, tiny_demo_scene};

use tadgs::components::Param;

/// The demo scene shrunk to 6 frames at 48×36 and 40 iterations, written to `dir`.
fn tiny_scene(dir: &Path) -> std::path::PathBuf {
    tiny_demo_scene(dir, (48, 36), 200, 40, 10)
}

fn summary(run: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(run.join("metrics.json")).expect("metrics.json written");
    let json: serde_json::Value = serde_json::from_str(&text).expect("valid JSON");
    json["summary"].clone()
}

/// `train` saves scene.ron, model.safetensors, metrics.json/csv, renders and masks, with every
/// metric of the protocol; `eval` on the saved run reproduces PSNR, SSIM and M-PSNR exactly.
#[test]
fn train_then_eval_reproduces_the_metrics() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let run = dir.path().join("run");
    let lpips = common::data_dir().map(|d| d.join("lpips/alex.safetensors"));
    let mut args = vec![
        "-q",
        "train",
        scene.to_str().unwrap(),
        "--output",
        run.to_str().unwrap(),
    ];
    if let Some(path) = &lpips {
        args.extend(["--lpips", path.to_str().unwrap()]);
    }
    let out = tadgs(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    for line in [
        "PSNR",
        "SSIM",
        "LPIPS (alex)",
        "M-PSNR",
        "M-SSIM",
        "Gaussians",
    ] {
        assert!(stdout.contains(line), "summary lacks {line}: {stdout}");
    }
    for file in [
        "scene.ron",
        "model.safetensors",
        "metrics.json",
        "metrics.csv",
    ] {
        assert!(run.join(file).is_file(), "{file} missing");
    }
    assert!(run.join("heldout/cam05_frame0003.png").is_file());
    let trained = summary(&run);
    let psnr = trained["psnr"].as_f64().expect("PSNR");
    assert!(psnr > 10.0 && psnr < 60.0, "PSNR {psnr}");
    assert!(trained["ssim"].as_f64().unwrap() > 0.0);
    // The synthetic scene has exact dynamic masks for all 6 held-out frames.
    assert_eq!(trained["masked_views"].as_u64(), Some(6));
    if lpips.is_some() {
        assert!(
            trained["lpips"]
                .as_f64()
                .is_some_and(|v| v > 0.0 && v < 1.0)
        );
    }
    let csv = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    assert_eq!(csv.lines().count(), 1 + 6);

    let mut args = vec!["-q", "eval", run.to_str().unwrap(), "--no-renders"];
    if let Some(path) = &lpips {
        args.extend(["--lpips", path.to_str().unwrap()]);
    }
    let out = tadgs(&args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let evaluated = summary(&run);
    for key in ["psnr", "ssim", "masked_psnr", "masked_ssim", "gaussians"] {
        assert_eq!(
            trained[key], evaluated[key],
            "{key} differs after reloading"
        );
    }

    // `--split train` scores the 15 training cameras × 6 frames into train-split/.
    let out = tadgs(&[
        "-q",
        "eval",
        run.to_str().unwrap(),
        "--split",
        "train",
        "--no-renders",
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let on_train = summary(&run.join("train-split"));
    assert_eq!(on_train["views"].as_u64(), Some(90));
    assert!(on_train["psnr"].as_f64().is_some());
}

/// `masks` saves the mask of every held-out view as a PNG (for the synthetic scene, its exact
/// masks: all 6 frames of camera 5) and reports how many views have one.
#[test]
fn masks_command_writes_one_png_per_view() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let masks = dir.path().join("masks");
    let out = tadgs(&[
        "-q",
        "masks",
        scene.to_str().unwrap(),
        "--output",
        masks.to_str().unwrap(),
    ]);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("6 of 6 held-out views have a dynamic mask"),
        "{stdout}"
    );
    for frame in 0..6 {
        assert!(masks.join(format!("cam05_frame{frame:04}.png")).is_file());
    }
}

/// A missing scene file and a missing model fail with exit code 1 and one line naming the file.
#[test]
fn bad_input_fails_with_one_line_naming_the_file() {
    let out = tadgs(&["train", "no/such/scene.ron"]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("no/such/scene.ron"), "{stderr}");
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");

    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    std::fs::copy(&scene, dir.path().join("scene.ron")).unwrap();
    let out = tadgs(&["eval", dir.path().to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("model.safetensors"), "{stderr}");
}

/// Property: `train --until 15` (a stop between densification steps, with a checkpoint
/// written every 7 iterations on the way) followed by `train --resume` ends with the same
/// parameters and the same held-out scores as one uninterrupted `train`; the resumed run
/// writes the report with the whole run's history.
#[test]
fn interrupted_and_resumed_training_matches_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let scene = scene.to_str().unwrap();
    let straight = dir.path().join("straight");
    let resumed = dir.path().join("resumed");
    let (straight_s, resumed_s) = (straight.to_str().unwrap(), resumed.to_str().unwrap());
    run_ok(&["-q", "train", scene, "--output", straight_s, "--no-renders"]);

    let stdout = run_ok(&[
        "-q",
        "train",
        scene,
        "--output",
        resumed_s,
        "--until",
        "15",
        "--checkpoint-every",
        "7",
    ]);
    assert!(
        stdout.contains("stopped after iteration 15 of 40"),
        "{stdout}"
    );
    assert!(!resumed.join("model.safetensors").exists());
    let state = std::fs::read_to_string(resumed.join("checkpoint/state.ron")).unwrap();
    assert!(state.contains("iteration: 15"), "{state}");
    run_ok(&["-q", "train", "--resume", resumed_s, "--no-renders"]);

    let a = tadgs::io::model::Model::load(&straight.join("model.safetensors")).unwrap();
    let b = tadgs::io::model::Model::load(&resumed.join("model.safetensors")).unwrap();
    assert_eq!(a.gaussians.len(), b.gaussians.len());
    assert!(
        a.gaussians == b.gaussians,
        "parameters differ after resuming"
    );
    let (sa, sb) = (summary(&straight), summary(&resumed));
    for key in ["psnr", "ssim", "masked_psnr", "gaussians"] {
        assert_eq!(sa[key], sb[key], "{key}");
    }

    let checkpoint = tadgs::io::checkpoint::Checkpoint::load(&resumed.join("checkpoint")).unwrap();
    assert_eq!(checkpoint.state.iteration, 40);
    let iterations: Vec<u32> = checkpoint.log.steps.iter().map(|s| s.iteration).collect();
    assert_eq!(iterations, (1..=40).collect::<Vec<_>>());
    let page = std::fs::read_to_string(resumed.join("report/index.html")).unwrap();
    for image in [
        "loss.png",
        "psnr.png",
        "gaussians.png",
        "lifespans.png",
        "view_0.png",
    ] {
        assert!(page.contains(image), "{image} not on the page");
        let png = image::open(resumed.join("report").join(image)).expect("a readable PNG");
        assert!(png.width() > 0);
    }

    // Resuming a finished run has nothing to do and says so.
    let out = tadgs(&["-q", "train", "--resume", resumed_s]);
    assert_eq!(out.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&out.stderr).contains("already at iteration 40"));
}

/// Property: `export` writes per-frame PLYs that read back as splat files with the run's SH
/// degree and the 4D model with its frame count; `render` draws that model from a RON camera
/// into a PNG of the camera's size, writes PNG frames where no ffmpeg is found, and an MP4
/// where it is; `info` describes the run.
#[test]
fn export_render_and_info_on_a_trained_run() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let run = dir.path().join("run");
    let run_s = run.to_str().unwrap();
    run_ok(&[
        "-q",
        "train",
        scene.to_str().unwrap(),
        "--output",
        run_s,
        "--iterations",
        "12",
        "--no-renders",
        "--no-report",
    ]);
    let model = tadgs::io::model::Model::load(&run.join("model.safetensors")).unwrap();

    let frames = dir.path().join("frames");
    run_ok(&[
        "-q",
        "export",
        run_s,
        "--frames",
        "0,5",
        "-o",
        frames.to_str().unwrap(),
    ]);
    for name in ["frame_0000.ply", "frame_0005.ply"] {
        let cloud = tadgs::io::ply::read_splat_ply(&frames.join(name)).unwrap();
        assert_eq!(cloud.sh_degree, model.sh_degree);
        assert!(!cloud.splats.is_empty() && cloud.splats.len() <= model.gaussians.len());
    }
    let four_d = dir.path().join("model_4d.safetensors");
    run_ok(&[
        "-q",
        "export",
        run_s,
        "--format",
        "4d",
        "-o",
        four_d.to_str().unwrap(),
    ]);
    let exported = tadgs::io::model::Model::load(&four_d).unwrap();
    assert_eq!(exported.frame_count, Some(6));
    assert!(exported.gaussians == model.gaussians);

    // Exports that would overwrite one another, or write the wrong kind of file, are refused
    // before anything is written.
    let refused = dir.path().join("refused");
    let refused_s = refused.to_str().unwrap();
    for (args, says) in [
        (
            &["--times", "0.33333,0.3333"][..],
            "time_0.3333.ply would be written twice",
        ),
        (
            &["--frames", "0,0,0"][..],
            "frame_0000.ply would be written twice",
        ),
        (
            &["--frames", "1", "--min-opacity", "NaN"][..],
            "--min-opacity",
        ),
        (
            &["--frames", "1", "--min-opacity", "2"][..],
            "--min-opacity",
        ),
    ] {
        let mut full = vec!["-q", "export", run_s, "-o", refused_s];
        full.extend(args);
        let stderr = run_fails(&full);
        assert!(stderr.contains(says), "{args:?}: {stderr}");
    }
    // Sizes from input are checked before anything that large is allocated.
    for (sets, says) in [
        (&["data.width=100000"][..], "16384"),
        (
            &["data.width=16384", "data.height=16384"][..],
            "memory available",
        ),
    ] {
        let mut full = vec!["-q", "train", scene.to_str().unwrap(), "-o", refused_s];
        for set in sets {
            full.extend(["--set", set]);
        }
        let stderr = run_fails(&full);
        assert!(stderr.contains(says), "{sets:?}: {stderr}");
    }
    let out = tadgs(&[
        "-q",
        "render",
        run_s,
        "--size",
        "100000x100000",
        "-o",
        refused_s,
    ]);
    assert_eq!(out.status.code(), Some(2), "a clap usage error");
    assert!(String::from_utf8_lossy(&out.stderr).contains("16384"));
    let stderr = run_fails(&[
        "-q",
        "render",
        run_s,
        "--frames",
        "99999999999",
        "-o",
        refused_s,
    ]);
    assert!(stderr.contains("--frames"), "{stderr}");
    let stderr = run_fails(&["-q", "render", run_s, "--up", "0,0,0", "-o", refused_s]);
    assert!(stderr.contains("not a direction"), "{stderr}");
    let jpg = dir.path().join("x.jpg");
    let stderr = run_fails(&[
        "-q",
        "render",
        run_s,
        "--frames",
        "1",
        "-o",
        jpg.to_str().unwrap(),
    ]);
    assert!(stderr.contains(".png, .mp4 or a folder"), "{stderr}");
    assert!(!jpg.exists());
    let stderr = run_fails(&["-q", "export", run_s, "--format", "4d", "-o", "m.ply"]);
    assert!(stderr.contains("*.safetensors"), "{stderr}");
    assert!(!refused.exists() && !Path::new("m.ply").exists());

    let camera = dir.path().join("camera.ron");
    std::fs::write(
        &camera,
        "(width: 40, height: 30, fx: 40.0, fy: 40.0, cx: 20.0, cy: 15.0,\n\
         world_to_camera: [[1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, 0.5], [0.0, 0.0, -1.0, 4.0], [0.0, 0.0, 0.0, 1.0]])",
    )
    .unwrap();
    let png = dir.path().join("one.png");
    run_ok(&[
        "-q",
        "render",
        four_d.to_str().unwrap(),
        "--camera",
        camera.to_str().unwrap(),
        "--time",
        "0.5",
        "-o",
        png.to_str().unwrap(),
    ]);
    let image = image::open(&png).unwrap();
    assert_eq!((image.width(), image.height()), (40, 30));

    // Without ffmpeg on PATH an .mp4 request falls back to PNG frames in a folder.
    let video = dir.path().join("orbit.mp4");
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args([
            "-q",
            "render",
            run_s,
            "--frames",
            "3",
            "-o",
            video.to_str().unwrap(),
        ])
        .env("PATH", "")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for k in 0..3 {
        assert!(dir.path().join(format!("orbit/frame_{k:04}.png")).is_file());
    }
    if tadgs::io::video::ffmpeg_available() {
        run_ok(&[
            "-q",
            "render",
            run_s,
            "--heldout",
            "-o",
            video.to_str().unwrap(),
        ]);
        let bytes = std::fs::read(&video).unwrap();
        assert_eq!(&bytes[4..8], b"ftyp", "an MP4 file");
    } else {
        eprintln!("ffmpeg not installed: MP4 output not checked");
    }

    let stdout = run_ok(&["info", run_s]);
    assert!(
        stdout.contains(&format!("Gaussians        {}", model.gaussians.len())),
        "{stdout}"
    );
    assert!(
        stdout.contains("checkpoint       iteration 12 of 12"),
        "{stdout}"
    );
}

/// Property: Ctrl-C (SIGINT) during training stops after the current iteration with a
/// checkpoint of that iteration and an error that says how to continue; the stopped run
/// renders from its checkpoint and `--resume` finishes it.
#[test]
fn ctrl_c_writes_a_checkpoint_and_stops() {
    use std::io::{BufRead, BufReader};
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let run = dir.path().join("run");
    let mut child = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args([
            "train",
            scene.to_str().unwrap(),
            "--output",
            run.to_str().unwrap(),
        ])
        .args(["--iterations", "2000", "--checkpoint-every", "0"])
        .env("RUST_LOG", "info")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut stderr = BufReader::new(child.stderr.take().unwrap());
    let mut text = String::new();
    // Training has started once the first progress line is logged (every 5 %: 100 iterations).
    loop {
        let mut line = String::new();
        assert!(
            stderr.read_line(&mut line).unwrap() > 0,
            "ended early: {text}"
        );
        text.push_str(&line);
        if line.contains("iteration 100/2000") {
            break;
        }
    }
    let status = Command::new("kill")
        .args(["-INT", &child.id().to_string()])
        .status()
        .unwrap();
    assert!(status.success());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stderr, &mut rest).unwrap();
    let code = child.wait().unwrap().code();
    assert_eq!(code, Some(130), "{rest}");
    assert!(rest.contains("stopped after iteration"), "{rest}");
    assert!(!rest.contains("error:"), "{rest}");
    assert!(
        !rest.contains('\u{1b}'),
        "no colour codes in a pipe: {rest}"
    );
    assert!(rest.contains("--resume"), "{rest}");
    let checkpoint = tadgs::io::checkpoint::Checkpoint::load(&run.join("checkpoint")).unwrap();
    let stopped = checkpoint.state.iteration;
    assert!((100..2000).contains(&stopped), "stopped at {stopped}");
    assert!(
        rest.contains(&format!("stopped after iteration {stopped}:")),
        "{rest}"
    );
    assert_eq!(checkpoint.log.steps.len(), stopped as usize);
    assert!(!run.join("model.safetensors").exists());

    // The unfinished run renders from its checkpoint.
    let png = dir.path().join("mid.png");
    run_ok(&[
        "-q",
        "render",
        run.to_str().unwrap(),
        "--frames",
        "1",
        "-o",
        png.to_str().unwrap(),
    ]);
    assert!(png.is_file());
}

/// Property: a run trained with `--backend gpu` saves, checkpoints and exports what the GPU
/// trained (the resident state is read back first), and is evaluated and rendered with it:
/// - its held-out PSNR is within 0.3 dB of the same run on the CPU backend, and `eval` of the
///   saved run reproduces it to 1e-4 dB (the forward pass has no atomics);
/// - a stop at `--until 15` writes a checkpoint holding non-zero Adam moments (zero if the GPU
///   state were not read back: the CPU stages never ran), from which `--resume` finishes
///   within 0.3 dB of the uninterrupted GPU run;
/// - `export --format 4d` writes exactly the saved parameters, and `render` draws the run.
#[test]
fn gpu_trained_run_saves_evaluates_resumes_and_exports() {
    if gpu::open_or_skip(|| tadgs::gpu::GpuContext::new(true)).is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let scene = scene.to_str().unwrap();
    let path = |name: &str| dir.path().join(name).to_str().unwrap().to_owned();
    let (cpu, straight, resumed) = (path("cpu"), path("gpu"), path("gpu-resumed"));
    // 37 iterations and a stop at 15: neither is a densification step (every 10), whose
    // read-back would hide a missing one before saving.
    let quiet = ["--no-renders", "--no-report", "--iterations", "37"];
    run_ok(&[&["-q", "train", scene, "--output", &cpu][..], &quiet].concat());
    let train_on_gpu = |output: &str, options: &[&str]| {
        let args = ["-q", "train", scene, "--backend", "gpu", "--output", output];
        run_ok(&[&args[..], options].concat())
    };
    train_on_gpu(&straight, &quiet);
    let psnr = |run: &str| summary(Path::new(run))["psnr"].as_f64().expect("PSNR");
    let (on_cpu, on_gpu) = (psnr(&cpu), psnr(&straight));
    eprintln!("held-out PSNR: CPU {on_cpu:.3} dB, GPU {on_gpu:.3} dB");
    assert!(
        (on_cpu - on_gpu).abs() <= 0.3,
        "CPU {on_cpu} vs GPU {on_gpu}"
    );
    let scene_file = std::fs::read_to_string(Path::new(&straight).join("scene.ron")).unwrap();
    assert!(scene_file.contains("backend: Gpu"), "{scene_file}");

    run_ok(&["-q", "eval", &straight, "--no-renders"]);
    let evaluated = psnr(&straight);
    assert!(
        (evaluated - on_gpu).abs() <= 1e-4,
        "eval {evaluated} vs train {on_gpu}"
    );

    train_on_gpu(
        &resumed,
        &[
            "--iterations",
            "37",
            "--until",
            "15",
            "--checkpoint-every",
            "7",
        ],
    );
    let checkpoint =
        tadgs::io::checkpoint::Checkpoint::load(&Path::new(&resumed).join("checkpoint")).unwrap();
    assert_eq!(checkpoint.state.iteration, 15);
    let moved = checkpoint
        .gaussians
        .iter()
        .filter(|g| g.m.position.values().iter().any(|m| *m != 0.0))
        .count();
    assert!(
        moved * 2 > checkpoint.gaussians.len(),
        "{moved} of {} Gaussians have Adam moments",
        checkpoint.gaussians.len()
    );
    run_ok(&[&["-q", "train", "--resume", &resumed][..], &quiet].concat());
    let after_resume = psnr(&resumed);
    assert!(
        (after_resume - on_gpu).abs() <= 0.3,
        "resumed {after_resume} vs straight {on_gpu}"
    );

    let model =
        tadgs::io::model::Model::load(&Path::new(&straight).join("model.safetensors")).unwrap();
    let four_d = path("model_4d.safetensors");
    run_ok(&["-q", "export", &straight, "--format", "4d", "-o", &four_d]);
    let exported = tadgs::io::model::Model::load(Path::new(&four_d)).unwrap();
    assert!(
        exported.gaussians == model.gaussians,
        "export equals the saved model"
    );
    let png = path("gpu.png");
    run_ok(&["-q", "render", &straight, "--frames", "1", "-o", &png]);
    assert!(image::open(&png).unwrap().width() > 0);
}

/// A temporary folder holding the tiny scene, the scene's path, and a run folder path in it.
fn tiny_run() -> (tempfile::TempDir, String, std::path::PathBuf) {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path()).to_str().unwrap().to_owned();
    let run = dir.path().join("run");
    (dir, scene, run)
}

/// `tadgs -q train SCENE -o RUN EXTRA..`, which must succeed.
fn train_tiny(scene: &str, run: &Path, extra: &[&str]) {
    let mut args = vec!["-q", "train", scene, "-o", run.to_str().unwrap()];
    args.extend(extra);
    run_ok(&args);
}

/// `--backend gpu` on a machine without a desktop session (no XDG_RUNTIME_DIR) prints nothing
/// from the Vulkan driver's Wayland probe: Mesa's lavapipe printed "XDG_RUNTIME_DIR is invalid
/// or not set in the environment" twice per run.
#[test]
fn gpu_run_without_a_desktop_session_prints_no_driver_noise() {
    if gpu::open_or_skip(|| tadgs::gpu::GpuContext::new(true)).is_none() {
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let run = dir.path().join("run");
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["-q", "train", scene.to_str().unwrap(), "--backend", "gpu"])
        .args(["--iterations", "2", "--no-renders", "--no-report"])
        .args(["--output", run.to_str().unwrap()])
        .env_remove("XDG_RUNTIME_DIR")
        .output()
        .expect("the tadgs binary runs");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    assert!(!stderr.contains("XDG_RUNTIME_DIR"), "{stderr}");
}

/// A new run never lands on another one: `train` into a folder holding an unfinished run is
/// refused (naming the checkpoint's iteration and the ways out) and leaves the checkpoint
/// untouched; the same over a finished run; `--force` replaces the run; `--resume` into its
/// own folder goes on.
#[test]
fn training_into_a_folder_with_a_run_is_refused_unless_forced() {
    let (_dir, scene, run) = tiny_run();
    let scene = scene.as_str();
    let run_arg = run.to_str().unwrap();
    let iteration = || {
        tadgs::io::checkpoint::Checkpoint::load(&run.join("checkpoint"))
            .unwrap()
            .state
            .iteration
    };
    run_ok(&["-q", "train", scene, "-o", run_arg, "--until", "20"]);
    let stderr = run_fails(&["-q", "train", scene, "-o", run_arg, "--until", "10"]);
    assert!(
        stderr.contains("an unfinished run (checkpoint at iteration 20 of 40)")
            && stderr.contains("--resume")
            && stderr.contains("--force"),
        "{stderr}"
    );
    assert_eq!(iteration(), 20);
    run_ok(&[
        "-q",
        "train",
        "--resume",
        run_arg,
        "--no-report",
        "--no-renders",
    ]);
    assert_eq!(iteration(), 40);
    let stderr = run_fails(&["-q", "train", scene, "-o", run_arg]);
    assert!(stderr.contains("a finished run"), "{stderr}");
    run_ok(&[
        "-q", "train", scene, "-o", run_arg, "--force", "--until", "10",
    ]);
    assert_eq!(iteration(), 10);
    assert!(
        !run.join("model.safetensors").exists() && !run.join("metrics.json").exists(),
        "--force removes the old run's model and metrics"
    );
}

/// While one process holds a run folder (an OS lock on its lock file), `train` and `eval`
/// into it fail with a clear error; once released, they work.
#[test]
fn a_locked_run_folder_is_refused() {
    let (_dir, scene, run) = tiny_run();
    let run_arg = run.to_str().unwrap();
    std::fs::create_dir(&run).unwrap();
    let lock = std::fs::File::create(run.join(".tadgs.lock")).unwrap();
    lock.lock().unwrap();
    let stderr = run_fails(&["-q", "train", &scene, "-o", run_arg]);
    assert!(
        stderr.contains("in use by another tadgs process"),
        "{stderr}"
    );
    assert!(!run.join("scene.ron").exists(), "nothing written");
    drop(lock);
    run_ok(&["-q", "train", &scene, "-o", run_arg, "--no-report"]);
}

/// `eval` of a run whose scene no longer matches its model (other frame count, other
/// deformation settings) fails naming the difference and leaves the metrics as they were.
#[test]
fn eval_refuses_a_model_of_another_scene() {
    let (_dir, scene, run) = tiny_run();
    let run_arg = run.to_str().unwrap();
    run_ok(&["-q", "train", &scene, "-o", run_arg, "--no-report"]);
    let metrics = std::fs::read(run.join("metrics.json")).unwrap();
    let stderr = run_fails(&["-q", "eval", run_arg, "--set", "data.frames=4"]);
    assert!(
        stderr.contains("trained on 6 frames, the scene's data has 4"),
        "{stderr}"
    );
    let stderr = run_fails(&["-q", "eval", run_arg, "--set", "model.tow.enabled=false"]);
    assert!(stderr.contains("deformation settings"), "{stderr}");
    assert_eq!(std::fs::read(run.join("metrics.json")).unwrap(), metrics);
}

/// Mistyped evaluation inputs stop `train` before it loads data or writes anything: a
/// missing LPIPS file, a mask "folder" that is a file, a flow threshold that is not a positive
/// number; `masks` accepts -o like the other commands.
#[test]
fn evaluation_inputs_are_checked_before_training() {
    let (dir, scene, run) = tiny_run();
    let scene = scene.as_str();
    let run_s = run.to_str().unwrap();
    let file = dir.path().join("tiny.ron");
    let file_s = file.to_str().unwrap();
    for (args, says) in [
        (&["--lpips", "no/such/alex.safetensors"][..], "no such file"),
        (&["--masks", file_s][..], "not a folder"),
        (&["--flow-threshold", "-1"][..], "--flow-threshold"),
        (&["--flow-threshold", "NaN"][..], "--flow-threshold"),
    ] {
        let mut full = vec!["-q", "train", scene, "-o", run_s];
        full.extend(args);
        let stderr = run_fails(&full);
        assert!(stderr.contains(says), "{args:?}: {stderr}");
        assert!(!run.exists(), "{args:?}: nothing written");
    }
    let masks = dir.path().join("masks");
    run_ok(&["-q", "masks", scene, "-o", masks.to_str().unwrap()]);
    assert!(masks.join("masks.ron").is_file());
}

/// An edit to a run's scene.ron is not silently dropped by `--resume`: it is refused with the
/// line that changed and the way to give the change; a resume with `--iterations` rewrites
/// scene.ron to match its checkpoint, so the next resume goes on.
#[test]
fn resume_refuses_an_edited_scene_file() {
    let (_dir, scene, run) = tiny_run();
    let run_s = run.to_str().unwrap();
    run_ok(&["-q", "train", &scene, "-o", run_s, "--until", "10"]);
    let scene_ron = run.join("scene.ron");
    let original = std::fs::read_to_string(&scene_ron).unwrap();
    assert!(original.contains("iterations: 40,"));
    std::fs::write(
        &scene_ron,
        original.replace("iterations: 40,", "iterations: 60,"),
    )
    .unwrap();
    let stderr = run_fails(&["-q", "train", "--resume", run_s]);
    assert!(
        stderr.contains("`iterations: 40,` → `iterations: 60,`") && stderr.contains("--set"),
        "{stderr}"
    );
    std::fs::write(&scene_ron, &original).unwrap();
    run_ok(&[
        "-q",
        "train",
        "--resume",
        run_s,
        "--iterations",
        "50",
        "--until",
        "20",
    ]);
    assert!(
        std::fs::read_to_string(&scene_ron)
            .unwrap()
            .contains("iterations: 50,")
    );
    run_ok(&[
        "-q",
        "train",
        "--resume",
        run_s,
        "--no-report",
        "--no-renders",
    ]);
    assert!(run.join("model.safetensors").is_file());
}

/// One clear line for common slips: a path that does not exist, an output folder that is a
/// file, and `eval` of a run that has not finished (pointing to --resume).
#[test]
fn common_slips_get_one_clear_line() {
    let (dir, scene, run) = tiny_run();
    let stderr = run_fails(&["-q", "render", "no/such/run"]);
    assert!(
        stderr.contains("no/such/run: no such file or folder"),
        "{stderr}"
    );
    let file = dir.path().join("a-file");
    std::fs::write(&file, "").unwrap();
    let stderr = run_fails(&["-q", "train", &scene, "-o", file.to_str().unwrap()]);
    assert!(stderr.contains("is a file, not a folder"), "{stderr}");
    train_tiny(&scene, &run, &["--until", "5"]);
    let stderr = run_fails(&["-q", "eval", run.to_str().unwrap()]);
    assert!(
        stderr.contains("unfinished run") && stderr.contains("--resume"),
        "{stderr}"
    );
    assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
}
