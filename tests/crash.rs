//! Crash safety: a training run killed with SIGKILL at several points (some inside checkpoint
//! writes) always leaves a checkpoint that is complete and loadable, or none; resuming after
//! each kill finishes with exactly the model of an uninterrupted run.

#![cfg(unix)]

mod tiny;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use tadgs::io::checkpoint::Checkpoint;
use tadgs::scene::load_scene;

/// The demo at 64×48, 6 frames, 150 iterations with densification, a checkpoint every 3
/// iterations (so kills often land inside a write).
fn scene_file(dir: &Path) -> PathBuf {
    let (mut config, _) = tiny::tiny_demo(64, 48, 300);
    config.train.iterations = 150;
    config.train.checkpoint_interval = 3;
    config.densify.from_iter = 20;
    config.densify.interval = 20;
    config.densify.until_iter = 120;
    config.densify.opacity_reset_interval = 0;
    let path = dir.join("scene.ron");
    let text = ron::ser::to_string_pretty(&config, Default::default()).unwrap();
    std::fs::write(&path, text).unwrap();
    path
}

fn tadgs(args: &[&str]) -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_tadgs"));
    command
        .args(["-q"])
        .args(args)
        .args(["--no-report", "--no-renders"])
        .env("RUST_LOG", "error")
        .stdout(Stdio::null())
        .stderr(Stdio::null());
    command
}

/// Starts the run, or resumes it when a checkpoint (or the fallback of an interrupted swap)
/// exists.
fn start(scene: &Path, run: &Path) -> std::process::Child {
    let checkpoint = run.join("checkpoint");
    let resumable = checkpoint.exists() || run.join("checkpoint.old").exists();
    let mut command = if resumable {
        tadgs(&["train", "--resume", run.to_str().unwrap()])
    } else {
        tadgs(&[
            "train",
            scene.to_str().unwrap(),
            "--output",
            run.to_str().unwrap(),
        ])
    };
    command.spawn().expect("tadgs starts")
}

/// The iteration of the checkpoint on disk, if one is there; panics if one is there but
/// cannot be loaded.
fn checkpoint_iteration(run: &Path) -> Option<u32> {
    let dir = run.join("checkpoint");
    if !dir.exists() && !run.join("checkpoint.old").exists() {
        return None;
    }
    match Checkpoint::load(&dir) {
        Ok(checkpoint) => Some(checkpoint.state.iteration),
        Err(error) => panic!("a checkpoint on disk does not load: {error}"),
    }
}

#[test]
fn killed_runs_keep_a_loadable_checkpoint_and_resume_to_the_same_model() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene_file(dir.path());

    let reference = dir.path().join("reference");
    let status = tadgs(&[
        "train",
        scene.to_str().unwrap(),
        "--output",
        reference.to_str().unwrap(),
    ])
    .status()
    .unwrap();
    assert!(status.success(), "the uninterrupted run finishes");

    let run = dir.path().join("killed");
    let mut kills = 0;
    let mut seen = Vec::new();
    // Kill after waiting for progress past each of these iterations plus a short, varying
    // delay, so some kills land between checkpoints and some inside a write.
    for (round, wait_for) in [6u32, 30, 60, 90, 120].into_iter().enumerate() {
        let mut child = start(&scene, &run);
        let deadline = Instant::now() + Duration::from_secs(120);
        let mut finished = false;
        // While the child runs, a read may race with its folder swap: errors only mean "not yet".
        let progress = |run: &Path| Checkpoint::load(&run.join("checkpoint")).ok();
        while progress(&run).is_none_or(|c| c.state.iteration < wait_for) {
            if child.try_wait().unwrap().is_some() {
                finished = true;
                break;
            }
            assert!(Instant::now() < deadline, "no progress in round {round}");
            std::thread::sleep(Duration::from_millis(2));
        }
        if finished {
            break;
        }
        std::thread::sleep(Duration::from_millis(7 * round as u64));
        child.kill().unwrap(); // SIGKILL
        child.wait().unwrap();
        kills += 1;
        let iteration = checkpoint_iteration(&run).expect("a checkpoint survives the kill");
        seen.push(iteration);
    }
    assert!(
        kills >= 3,
        "the run was killed {kills} times (checkpoints at {seen:?})"
    );
    assert!(
        seen.windows(2).all(|w| w[0] <= w[1]),
        "checkpoints never go back: {seen:?}"
    );

    let status = start(&scene, &run).wait().unwrap();
    assert!(status.success(), "the resumed run finishes");
    let model = |run: &Path| tadgs::io::model::Model::load(&run.join("model.safetensors")).unwrap();
    let (expected, resumed) = (model(&reference), model(&run));
    assert_eq!(
        expected.gaussians.len(),
        resumed.gaussians.len(),
        "kills at {seen:?}"
    );
    assert!(
        expected.gaussians == resumed.gaussians,
        "the resumed parameters differ from the uninterrupted run's (kills at checkpoints {seen:?})"
    );
}

/// The states a crash inside `Checkpoint::save` can leave: a stale `.partial` folder is
/// replaced by the next save, and with the folder renamed away to `.old` (a crash between the
/// two renames) loading falls back to `.old`, with the same iteration.
#[test]
fn every_intermediate_state_of_a_checkpoint_write_loads() {
    use std::sync::Arc;
    use tadgs::report::TrainingLog;
    use tadgs::train::Trainer;

    let dir = tempfile::tempdir().unwrap();
    let scene = load_scene(&scene_file(dir.path())).unwrap();
    let dataset = Arc::new(tadgs::data::load(&scene.data).unwrap());
    let mut trainer = Trainer::new(&scene, dataset);
    let folder = dir.path().join("checkpoint");
    for _ in 0..4 {
        trainer.step();
    }
    // A crash while writing the first checkpoint's files left a partial folder behind.
    std::fs::create_dir_all(dir.path().join("checkpoint.partial")).unwrap();
    std::fs::write(dir.path().join("checkpoint.partial/state.ron"), "(trunc").unwrap();
    trainer
        .checkpoint(&scene, &TrainingLog::default())
        .save(&folder)
        .unwrap();
    assert_eq!(Checkpoint::load(&folder).unwrap().state.iteration, 4);
    assert!(!dir.path().join("checkpoint.partial").exists());

    trainer.step();
    trainer
        .checkpoint(&scene, &TrainingLog::default())
        .save(&folder)
        .unwrap();
    assert_eq!(Checkpoint::load(&folder).unwrap().state.iteration, 5);
    assert!(!dir.path().join("checkpoint.old").exists());

    // A crash between the two renames: only `.old` is there.
    std::fs::rename(&folder, dir.path().join("checkpoint.old")).unwrap();
    assert_eq!(Checkpoint::load(&folder).unwrap().state.iteration, 5);
    // The next save puts a complete folder back and removes `.old`.
    trainer.step();
    trainer
        .checkpoint(&scene, &TrainingLog::default())
        .save(&folder)
        .unwrap();
    assert_eq!(Checkpoint::load(&folder).unwrap().state.iteration, 6);
    assert!(!dir.path().join("checkpoint.old").exists());
}
