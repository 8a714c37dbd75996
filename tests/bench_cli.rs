//! `tadgs bench` prints one stage table per requested (Gaussians, size) pair, on the CPU or the
//! GPU backend, and rejects a malformed size with one clear line; with `--scene` or
//! `--checkpoint` it times a real scene's iteration at its own population, SH degree and
//! iteration.

use std::process::Command;

#[path = "common/gpu.rs"]
mod gpu;

/// The table `tadgs bench ARGS` prints, after checking that it succeeded.
fn bench(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .arg("bench")
        .args(args)
        .output()
        .expect("the tadgs binary runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn bench_prints_a_table_per_configuration() {
    let text = bench(&[
        "--gaussians",
        "500,1000",
        "--size",
        "64x36",
        "--repeats",
        "1",
    ]);
    for stage in [
        "deform",
        "densification statistics",
        "  blend",
        "  raster backward",
        "training iteration",
        "render at a new time",
    ] {
        let rows = text
            .lines()
            .filter(|l| l.starts_with(&format!("{stage} ")))
            .count();
        assert_eq!(rows, 2, "stage {stage:?} in:\n{text}");
    }
    assert!(text.contains("64 × 36, 500 Gaussians") && text.contains("64 × 36, 1000 Gaussians"));
    assert!(text.contains("memory per Gaussian"));
    assert_eq!(text.matches("Gaussian-pixel pairs: ").count(), 2, "{text}");
    assert!(text.contains("CPU ns per pair: blend "), "{text}");
}

#[test]
fn bench_rejects_a_bad_size() {
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["bench", "--size", "640by360"])
        .output()
        .expect("the tadgs binary runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--size 640by360: expected WxH"), "{err}");
}

/// `tadgs bench --backend gpu` times the GPU-resident stages and names the adapter.
#[test]
fn bench_times_the_gpu_resident_stages() {
    if gpu::open_or_skip(|| tadgs::gpu::GpuContext::new(true)).is_none() {
        return;
    }
    let gpu_args = ["--backend", "gpu", "--gaussians", "500", "--size", "64x36"];
    let text = bench(&[&gpu_args[..], &["--repeats", "1"]].concat());
    for stage in [
        "GPU deform … blend, image back",
        "GPU backward + gradient check",
        "GPU adam",
        "training iteration",
        "render at a new time",
    ] {
        assert!(
            text.lines().any(|l| l.starts_with(&format!("{stage} "))),
            "stage {stage:?} in:\n{text}"
        );
    }
    assert!(
        text.contains("Gpu backend") && text.contains("GPU: "),
        "{text}"
    );
}

/// `--kernels` adds each GPU stage's device time per kernel: the blending kernels appear under
/// their stages, every time is finite and not negative, and a stage's kernels take no longer
/// than the stage's wall time. The backward is the float-atomic kernel where the adapter
/// offers float atomics, the portable per-tile sums and their reduction otherwise.
#[test]
fn bench_kernels_times_each_gpu_kernel() {
    let Some(gpu) = gpu::open_or_skip(|| tadgs::gpu::GpuContext::new(true)) else {
        return;
    };
    let atomics = gpu
        .device
        .features()
        .contains(wgpu::Features::SHADER_FLOAT32_ATOMIC | wgpu::Features::SUBGROUP);
    let kernels = kernel_table(&[]);
    let backward = |name: &str| kernels.contains(&(BACKWARD_STAGE, name.to_string()));
    assert_eq!(
        backward("raster_backward_atomic/backward"),
        atomics,
        "{kernels:?}"
    );
    assert_eq!(
        backward("raster_backward_tiles/backward"),
        !atomics,
        "{kernels:?}"
    );
}

/// `--set train.gpu_float_atomics=false` times the portable backward (per-tile sums and their
/// reduction) even where the adapter offers float atomics, and says so under the table.
#[test]
fn bench_kernels_time_the_portable_backward_when_asked() {
    if gpu::open_or_skip(|| tadgs::gpu::GpuContext::new(false)).is_none() {
        return;
    }
    let kernels = kernel_table(&["--set", "train.gpu_float_atomics=false"]);
    for name in ["raster_backward_tiles/backward", "raster_reduce/reduce"] {
        assert!(
            kernels.contains(&(BACKWARD_STAGE, name.to_string())),
            "{name} in {kernels:?}"
        );
    }
    assert!(
        !kernels
            .iter()
            .any(|(_, k)| k.starts_with("raster_backward_atomic")),
        "{kernels:?}"
    );
}

const FORWARD_STAGE: &str = "GPU deform … blend, image back";
const BACKWARD_STAGE: &str = "GPU backward + gradient check";

/// The (stage, kernel) rows of `tadgs bench --backend gpu --kernels EXTRA` on a small scene,
/// after checking the table's common properties (see
/// [`bench_kernels_times_each_gpu_kernel`]) and that the GPU line names the backward's
/// summation as the kernels do.
fn kernel_table(extra: &[&str]) -> Vec<(&'static str, String)> {
    let args = [
        "--backend",
        "gpu",
        "--kernels",
        "--gaussians",
        "500",
        "--size",
        "64x36",
        "--repeats",
        "2",
    ];
    let text = bench(&[&args[..], extra].concat());
    let table = text
        .split("GPU kernels (device time from timestamp queries")
        .nth(1)
        .unwrap_or_else(|| panic!("a kernel table in:\n{text}"));
    let stage_ms = |stage: &str| -> f64 {
        let line = text
            .lines()
            .find(|l| l.starts_with(&format!("{stage} ")))
            .unwrap_or_else(|| panic!("stage {stage:?} in:\n{text}"));
        line[stage.len()..]
            .split_whitespace()
            .next()
            .unwrap()
            .parse()
            .unwrap()
    };
    let mut sums = [0.0f64; 2];
    let mut kernels = Vec::new();
    for line in table.lines().skip(2).filter(|l| !l.trim().is_empty()) {
        let stage = [
            FORWARD_STAGE,
            BACKWARD_STAGE,
            "GPU adam",
            "GPU densification statistics",
        ]
        .into_iter()
        .find(|s| line.starts_with(s))
        .unwrap_or_else(|| panic!("a stage name starts {line:?}"));
        let fields: Vec<&str> = line[stage.len()..].split_whitespace().collect();
        let ms: f64 = fields[2].parse().unwrap();
        assert!(ms.is_finite() && ms >= 0.0, "{line}");
        if stage == FORWARD_STAGE {
            sums[0] += ms;
        } else if stage == BACKWARD_STAGE {
            sums[1] += ms;
        }
        kernels.push((stage, fields[0].to_string()));
    }
    assert!(
        kernels.contains(&(FORWARD_STAGE, "raster_forward/forward".to_string())),
        "{table}"
    );
    assert!(
        kernels
            .iter()
            .any(|(s, k)| *s == BACKWARD_STAGE && k.starts_with("raster_backward")),
        "{table}"
    );
    assert!(kernels.iter().any(|(s, _)| *s == "GPU adam"), "{table}");
    // Medians against means: allow a little for the spread of two repeats.
    assert!(sums[0] <= 1.5 * stage_ms(FORWARD_STAGE) + 1.0, "{text}");
    assert!(sums[1] <= 1.5 * stage_ms(BACKWARD_STAGE) + 1.0, "{text}");
    let atomic_kernel = kernels
        .iter()
        .any(|(_, k)| k.starts_with("raster_backward_atomic"));
    let summation = if atomic_kernel {
        "backward with float atomics"
    } else {
        "backward with per-tile sums"
    };
    assert!(text.contains(summation), "{summation:?} in:\n{text}");
    kernels
}

/// `--kernels` times GPU kernels only: with the CPU backend it is refused.
#[test]
fn bench_kernels_needs_the_gpu_backend() {
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args([
            "bench",
            "--kernels",
            "--gaussians",
            "100",
            "--size",
            "32x32",
        ])
        .output()
        .expect("the tadgs binary runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--kernels times the GPU kernels: give --backend gpu"),
        "{err}"
    );
}

fn demo_scene() -> String {
    format!("{}/scenes/demo.ron", env!("CARGO_MANIFEST_DIR"))
}

/// `--scene` times the scene's own initial population (the demo over 6 frames: anchors at
/// frames 0 and 5, 1 000 points each) at iteration 0 and SH degree 0.
#[test]
fn bench_times_a_scene_at_its_initial_population() {
    let scene = demo_scene();
    let text = bench(&[
        "--scene",
        &scene,
        "--set",
        "data.frames=6",
        "--repeats",
        "1",
    ]);
    for stage in [
        "deform",
        "  blend",
        "training iteration",
        "render at a new time",
    ] {
        assert!(
            text.lines().any(|l| l.starts_with(&format!("{stage} "))),
            "stage {stage:?} in:\n{text}"
        );
    }
    assert!(text.contains("160 × 120, 2000 Gaussians"), "{text}");
    assert!(
        text.contains("scene `demo`, initial population at iteration 0, SH degree 0"),
        "{text}"
    );
}

/// `--checkpoint` times the run where it stopped: its iteration and its SH degree, raised by
/// the schedule from 0 (every 100 iterations here).
#[test]
fn bench_times_a_checkpoint_where_the_run_stopped() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("run");
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["-q", "train", &demo_scene(), "--set", "data.frames=6"])
        .args([
            "--set",
            "train.sh_increase_interval=100",
            "--iterations",
            "300",
        ])
        .args(["--until", "250", "--output"])
        .arg(&run)
        .output()
        .expect("the tadgs binary runs");
    assert!(
        out.status.code() == Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text = bench(&["--checkpoint", run.to_str().unwrap(), "--repeats", "1"]);
    assert!(text.contains("at iteration 250, SH degree 2"), "{text}");
}

/// `--set` without a scene changes the benchmark scene's settings, checked as for `train`: an
/// unknown key is refused with one line naming it.
#[test]
fn bench_set_changes_the_benchmark_scene() {
    let out = Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["bench", "--set", "train.no_such_setting=1"])
        .output()
        .expect("the tadgs binary runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("train.no_such_setting"), "{err}");
}
