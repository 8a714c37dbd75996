//! Shared by the integration tests that run the `tadgs` binary on a tiny demo scene.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use tadgs::scene::{DataSource, load_scene};

/// Runs the `tadgs` binary with `args` (its log limited to warnings) and returns its output.
pub fn tadgs(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("the tadgs binary runs")
}

/// Runs `tadgs args`, which must succeed, and returns its stdout.
pub fn run_ok(args: &[&str]) -> String {
    let out = tadgs(args);
    assert!(
        out.status.success(),
        "{args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// Runs `tadgs args`, which must fail with exit code 1, and returns its stderr.
pub fn run_fails(args: &[&str]) -> String {
    let out = tadgs(args);
    assert_eq!(out.status.code(), Some(1), "{args:?} should fail");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// The demo scene shrunk to 6 frames of `width × height` (anchors every 3 frames with
/// `points` initial points each) and `iterations` iterations, densified every
/// `densify_every` from iteration `densify_every`; written to `dir/tiny.ron`.
pub fn tiny_demo_scene(
    dir: &Path,
    (width, height): (u32, u32),
    points: usize,
    iterations: u32,
    densify_every: u32,
) -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut config = load_scene(&root.join("scenes/demo.ron")).expect("demo scene loads");
    let DataSource::Synthetic(synthetic) = &mut config.data else {
        panic!("the demo is synthetic");
    };
    (synthetic.frames, synthetic.width, synthetic.height) = (6, width, height);
    synthetic.supersample = 1;
    config.init.points_per_anchor = points;
    config.init.anchor_spacing = 3;
    config.train.iterations = iterations;
    config.densify.from_iter = densify_every;
    config.densify.interval = densify_every;
    let path = dir.join("tiny.ron");
    let text = ron::ser::to_string_pretty(&config, ron::ser::PrettyConfig::default()).unwrap();
    std::fs::write(&path, text).unwrap();
    path
}
