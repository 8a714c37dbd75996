//! End-to-end runs of the `tadgs` binary on a tiny synthetic scene: train writes a model and
//! the metrics table, `eval` reproduces it from the saved model, `masks` writes PNGs, and bad
//! input fails with one clear line.

mod common;

use std::path::Path;
use std::process::{Command, Output};

use tadgs::scene::{DataSource, load_scene};

fn tadgs(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("the tadgs binary runs")
}

/// The demo scene shrunk to 6 frames at 48×36 and 40 iterations, written to `dir`.
fn tiny_scene(dir: &Path) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut config = load_scene(&root.join("scenes/demo.ron")).expect("demo scene loads");
    let DataSource::Synthetic(synthetic) = &mut config.data else {
        panic!("the demo is synthetic");
    };
    synthetic.frames = 6;
    synthetic.width = 48;
    synthetic.height = 36;
    synthetic.supersample = 1;
    config.init.points_per_anchor = 200;
    config.init.anchor_spacing = 3;
    config.train.iterations = 40;
    config.densify.from_iter = 10;
    config.densify.interval = 10;
    let path = dir.join("tiny.ron");
    let text = ron::ser::to_string_pretty(&config, ron::ser::PrettyConfig::default()).unwrap();
    std::fs::write(&path, text).unwrap();
    path
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
