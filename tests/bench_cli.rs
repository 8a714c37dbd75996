//! `tadgs bench` prints one stage table per requested (Gaussians, size) pair, on the CPU or the
//! GPU backend, and rejects a malformed size with one clear line.

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
