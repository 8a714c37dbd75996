//! Temporal segments end to end with the `tadgs` binary on a tiny synthetic scene: the Slurm
//! scripts of a plan, run task by task on this machine, train the segments and merge them; the
//! merged model draws the same pixels as each segment inside it; bad plans and merges fail
//! with one clear line.

#[path = "common/cli.rs"]
mod tiny;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use tadgs::data::Dataset;
use tadgs::io::model::Model;
use tadgs::scene::load_scene;
use tadgs::segment::SegmentPlan;
use tadgs::train::Trainer;
use tiny::{run_fails, run_ok, tiny_demo_scene};

/// `tadgs args`, which must fail with one line on stderr, which it returns.
fn fails_with_one_line(args: &[&str]) -> String {
    let stderr = run_fails(args);
    assert_eq!(stderr.trim().lines().count(), 1, "one line: {stderr}");
    stderr
}

/// A plan of the tiny 6-frame demo in `dir/plan`: 2 segments owning frames 0–2 and 3–5, each
/// trained one frame further (overlap 1).
fn plan(dir: &Path, extra: &[&str]) -> PathBuf {
    let scene = tiny_demo_scene(dir, (48, 36), 200, 40, 10);
    let plan = dir.join("plan");
    let mut args = vec![
        "-q",
        "segment",
        "plan",
        scene.to_str().unwrap(),
        "--segments",
        "2",
        "--overlap",
        "1",
        "-o",
        plan.to_str().unwrap(),
    ];
    args.extend(extra);
    run_ok(&args);
    plan
}

/// The `#SBATCH` directives at the head of a batch script, as (option, value) pairs; panics
/// on a directive sbatch would not parse as `--option[=value]`.
fn sbatch_directives(script: &str) -> Vec<(String, Option<String>)> {
    let mut lines = script.lines();
    assert_eq!(lines.next(), Some("#!/bin/bash"), "a bash script");
    lines
        // sbatch reads directives until the first line that is neither a comment nor blank.
        .take_while(|line| line.starts_with('#') || line.trim().is_empty())
        .filter_map(|line| line.strip_prefix("#SBATCH "))
        .map(|directive| {
            let option = directive
                .strip_prefix("--")
                .unwrap_or_else(|| panic!("not a long option: {directive}"));
            assert!(
                !option.contains(char::is_whitespace),
                "one word: {directive}"
            );
            match option.split_once('=') {
                Some((key, value)) => (key.to_string(), Some(value.to_string())),
                None => (option.to_string(), None),
            }
        })
        .collect()
}

fn directive<'a>(directives: &'a [(String, Option<String>)], key: &str) -> Option<&'a str> {
    directives
        .iter()
        .find(|(k, _)| k == key)
        .and_then(|(_, v)| v.as_deref())
}

/// Runs a generated script with bash as Slurm would, with `env`, and returns its stdout.
fn run_script(script: &Path, env: &[(&str, &str)]) -> String {
    let out = Command::new("bash")
        .arg(script)
        .envs(env.iter().copied())
        .env("TADGS", env!("CARGO_BIN_EXE_tadgs"))
        .env("RUST_LOG", "warn")
        .output()
        .expect("bash runs");
    assert!(
        out.status.success(),
        "{} failed: {}",
        script.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

fn render(model: &Model, dataset: &Arc<Dataset>, scene_file: &Path, time: f32) -> Vec<[f32; 3]> {
    let scene = load_scene(scene_file).unwrap();
    let mut trainer = Trainer::from_model(&scene, dataset.clone(), model);
    let camera = &dataset.cameras[dataset.test[0].camera];
    trainer.render(camera, time).image.data
}

/// Property: the Slurm job array written by `segment plan --slurm` has directives sbatch
/// parses (one array task per segment, the CPUs asked for, requeue), and running each task's
/// script on this machine trains its segment (a second run of a task leaves it as it is); the
/// merge job then writes one model that draws exactly the pixels of segment k's own model at
/// every frame segment k owns outside the cross-fade (by default the overlap), a mix inside
/// it, and an even mix half-way between the frames of the boundary; `export`
/// and `eval` read it, and the GPU backend refuses it.
#[test]
fn slurm_tasks_train_the_segments_and_the_merge_draws_each_segment() {
    let dir = tempfile::tempdir().unwrap();
    let plan_dir = plan(
        dir.path(),
        &[
            "--iterations",
            "30",
            "--slurm",
            "--slurm-cpus",
            "1",
            "--slurm-time",
            "00:10:00",
        ],
    );
    let segment_scene = load_scene(&plan_dir.join("segment-1.ron")).unwrap();
    assert_eq!(segment_scene.train.iterations, 30);
    assert_eq!(
        segment_scene.densify.from_iter, 8,
        "the schedule stretched from 40 to 30"
    );
    let slurm = plan_dir.join("slurm");

    let array = std::fs::read_to_string(slurm.join("segments.sbatch")).unwrap();
    let directives = sbatch_directives(&array);
    assert_eq!(directive(&directives, "array"), Some("0-1"));
    assert_eq!(directive(&directives, "cpus-per-task"), Some("1"));
    assert_eq!(directive(&directives, "time"), Some("00:10:00"));
    assert!(
        directives
            .iter()
            .any(|(k, v)| k == "requeue" && v.is_none())
    );
    let merge = std::fs::read_to_string(slurm.join("merge.sbatch")).unwrap();
    assert!(directive(&sbatch_directives(&merge), "job-name").is_some());
    let submit = std::fs::read_to_string(slurm.join("submit.sh")).unwrap();
    assert!(submit.contains("sbatch --parsable") && submit.contains("--dependency=afterok:"));

    for task in ["0", "1"] {
        run_script(
            &slurm.join("segments.sbatch"),
            &[("SLURM_ARRAY_TASK_ID", task)],
        );
    }
    let again = run_script(
        &slurm.join("segments.sbatch"),
        &[("SLURM_ARRAY_TASK_ID", "0")],
    );
    assert!(again.contains("trained already"), "{again}");
    run_script(&slurm.join("merge.sbatch"), &[]);

    let plan: SegmentPlan =
        ron::from_str(&std::fs::read_to_string(plan_dir.join("plan.ron")).unwrap()).unwrap();
    let merged_run = plan_dir.join("merged");
    let merged = Model::load(&merged_run.join("model.safetensors")).unwrap();
    let segments: Vec<Model> = plan
        .segments
        .iter()
        .map(|s| Model::load(&plan_dir.join(&s.run).join("model.safetensors")).unwrap())
        .collect();
    assert_eq!(
        merged.gaussians.len(),
        segments.iter().map(|m| m.gaussians.len()).sum::<usize>()
    );
    let scene_file = merged_run.join("scene.ron");
    let dataset = Arc::new(tadgs::data::load(&load_scene(&scene_file).unwrap().data).unwrap());
    // The default cross-fade spans the overlap: 3 frames around the boundary at 2.5.
    assert_eq!(plan.fade_frames, 3.0);
    for (segment, model) in plan.segments.iter().zip(&segments) {
        for frame in segment.owned_first..=segment.owned_last {
            let t = dataset.frame_time(frame);
            let whole = render(&merged, &dataset, &scene_file, t);
            let own = render(model, &dataset, &scene_file, t);
            if (frame as f32 - 2.5).abs() >= plan.fade_frames / 2.0 {
                assert_eq!(whole, own, "frame {frame} of {}", segment.run);
            } else {
                assert_ne!(whole, own, "frame {frame} is in the cross-fade");
            }
        }
    }
    // Halfway between frames 2 and 3 both segments draw at half opacity.
    let t = 2.5 / 5.0;
    let mixed = render(&merged, &dataset, &scene_file, t);
    let first = render(&segments[0], &dataset, &scene_file, t);
    assert_ne!(mixed, first);
    assert!(mixed.iter().flatten().all(|v| v.is_finite()));

    // Exported frames keep only the Gaussians their windows show: frame 1 is segment 0's.
    let exported = |run: &Path, name: &str| {
        let file = dir.path().join(name);
        run_ok(&[
            "-q",
            "export",
            run.to_str().unwrap(),
            "--frames",
            "1",
            "-o",
            file.to_str().unwrap(),
        ]);
        tadgs::io::ply::read_splat_ply(&file).unwrap().splats.len()
    };
    assert_eq!(
        exported(&merged_run, "merged.ply"),
        exported(&plan_dir.join("segment-0"), "segment-0.ply")
    );

    // The merged run is a run folder like any other.
    let out = run_ok(&["-q", "eval", merged_run.to_str().unwrap()]);
    assert!(out.contains("PSNR"), "{out}");
    let gpu = fails_with_one_line(&[
        "-q",
        "eval",
        merged_run.to_str().unwrap(),
        "--set",
        "train.backend=Gpu",
    ]);
    assert!(gpu.contains("time windows"), "{gpu}");
}

/// Property: merging refuses, naming the segment and what to do, a segment not trained yet, a
/// segment trained with other settings than the plan's, a plan whose owned ranges overlap, and
/// an output that already holds a model; planning refuses more segments than frames and a
/// fade wider than the overlap allows, and training refuses a segment past the sequence.
#[test]
fn bad_plans_and_merges_fail_with_one_clear_line() {
    let dir = tempfile::tempdir().unwrap();
    let plan_dir = plan(dir.path(), &[]);
    let plan_file = plan_dir.join("plan.ron");
    let plan = plan_file.to_str().unwrap();

    let untrained = fails_with_one_line(&["segment", "merge", plan]);
    assert!(
        untrained.contains("segment 0")
            && untrained.contains("tadgs train")
            && untrained.contains("segment-0.ron"),
        "{untrained}"
    );

    let segment = |k: usize| plan_dir.join(format!("segment-{k}.ron"));
    run_ok(&["-q", "train", segment(0).to_str().unwrap()]);
    run_ok(&[
        "-q",
        "train",
        segment(1).to_str().unwrap(),
        "--set",
        "train.seed=7",
    ]);
    let other = fails_with_one_line(&["segment", "merge", plan]);
    assert!(
        other.contains("segment 1") && other.contains("other settings") && other.contains("seed"),
        "{other}"
    );
    run_ok(&["-q", "train", segment(1).to_str().unwrap(), "--force"]);
    run_ok(&["-q", "segment", "merge", plan]);
    let again = fails_with_one_line(&["segment", "merge", plan]);
    assert!(again.contains("--force"), "{again}");
    let merged = plan_dir.join("merged");
    run_ok(&["-q", "eval", merged.to_str().unwrap()]);
    assert!(merged.join("metrics.json").is_file());
    run_ok(&["-q", "segment", "merge", plan, "--force"]);
    assert!(
        !merged.join("metrics.json").exists(),
        "the replaced model's scores are gone with it"
    );

    let text = std::fs::read_to_string(&plan_file).unwrap();
    std::fs::write(&plan_file, text.replace("owned_first: 3", "owned_first: 2")).unwrap();
    let overlapping = fails_with_one_line(&["segment", "merge", plan]);
    assert!(
        overlapping.contains("without gap or overlap"),
        "{overlapping}"
    );

    let scene = dir.path().join("tiny.ron");
    let scene = scene.to_str().unwrap();
    let out = dir.path().join("other");
    let out = out.to_str().unwrap();
    let many = fails_with_one_line(&["segment", "plan", scene, "--segments", "7", "-o", out]);
    assert!(
        many.contains("cannot split 6 frames into 7 segments"),
        "{many}"
    );
    let fade = fails_with_one_line(&[
        "segment",
        "plan",
        scene,
        "--segments",
        "2",
        "--overlap",
        "1",
        "--fade",
        "5",
        "-o",
        out,
    ]);
    assert!(fade.contains("raise the overlap"), "{fade}");
    let past = fails_with_one_line(&[
        "train",
        scene,
        "--set",
        "segment=Some((first_frame: 4, last_frame: 9))",
        "-o",
        out,
    ]);
    assert!(
        past.contains("the segment ends at frame 9") && past.contains("6 frames"),
        "{past}"
    );
}

/// A virtual environment with Ray in it, under the test's target folder (reused when it
/// already imports Ray); None (after printing why) when Python or Ray cannot be installed,
/// which fails under `CI=true`.
fn ray_python() -> Option<PathBuf> {
    let venv = Path::new(env!("CARGO_TARGET_TMPDIR")).join("ray-venv");
    let python = venv.join("bin/python");
    let imports_ray = |python: &Path| {
        Command::new(python)
            .args(["-c", "import ray"])
            .output()
            .is_ok_and(|out| out.status.success())
    };
    if imports_ray(&python) {
        return Some(python);
    }
    let install = || -> Result<(), String> {
        let run = |program: &Path, args: &[&str]| {
            let out = Command::new(program)
                .args(args)
                .output()
                .map_err(|e| format!("{}: {e}", program.display()))?;
            if out.status.success() {
                Ok(())
            } else {
                let stderr = String::from_utf8_lossy(&out.stderr);
                Err(format!("{} {args:?}: {}", program.display(), stderr.trim()))
            }
        };
        run(
            Path::new("python3"),
            &["-m", "venv", venv.to_str().unwrap()],
        )?;
        run(&python, &["-m", "pip", "install", "--quiet", "ray"])
    };
    match install() {
        Ok(()) => Some(python),
        Err(error) => {
            let message = format!("cannot install Ray into a virtual environment: {error}");
            if std::env::var("CI").is_ok_and(|v| v == "true") {
                panic!("{message}; CI=true requires it");
            }
            eprintln!("skipping: {message}");
            None
        }
    }
}

/// Property: `scripts/ray_segments.py` on a local single-node Ray cluster trains every
/// segment of a plan as a Ray task (two at a time on one CPU each) and merges them: the
/// merged model holds every segment's Gaussians; run again, it trains nothing and merges the
/// same model.
#[test]
fn ray_driver_trains_the_segments_and_merges_them() {
    let Some(python) = ray_python() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_demo_scene(dir.path(), (48, 36), 200, 40, 10);
    let plan_dir = dir.path().join("plan");
    run_ok(&[
        "-q",
        "segment",
        "plan",
        scene.to_str().unwrap(),
        "--segments",
        "3",
        "--overlap",
        "1",
        "-o",
        plan_dir.to_str().unwrap(),
    ]);
    let driver = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/ray_segments.py");
    let run_driver = || {
        let out = Command::new(&python)
            .arg(&driver)
            .arg(&plan_dir)
            .args([
                "--tadgs",
                env!("CARGO_BIN_EXE_tadgs"),
                "--cpus-per-segment",
                "1",
            ])
            // Ray keeps its session files and token under HOME and the temporary folder.
            .env("HOME", dir.path())
            .env("RAY_TMPDIR", dir.path())
            .env("RUST_LOG", "warn")
            .output()
            .expect("python runs");
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        assert!(
            out.status.success(),
            "the Ray driver failed: {stdout}{}",
            String::from_utf8_lossy(&out.stderr)
        );
        stdout
    };
    let first = run_driver();
    for k in 0..3 {
        assert!(first.contains(&format!("segment {k}:")), "{first}");
    }
    let merged_file = plan_dir.join("merged/model.safetensors");
    let merged = Model::load(&merged_file).unwrap();
    let total: usize = (0..3)
        .map(|k| {
            let run = plan_dir.join(format!("segment-{k}/model.safetensors"));
            Model::load(&run).unwrap().gaussians.len()
        })
        .sum();
    assert_eq!(merged.gaussians.len(), total);
    assert_eq!(merged.time_windows.as_ref().map(Vec::len), Some(total));

    let second = run_driver();
    assert_eq!(second.matches("trained already").count(), 3, "{second}");
    let again = Model::load(&merged_file).unwrap();
    assert_eq!(again.gaussians.len(), total);
}
