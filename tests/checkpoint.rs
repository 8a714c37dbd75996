//! Checkpoints: a run stopped, saved to disk, loaded and continued ends exactly where the same
//! run without a stop ends; damaged or mismatched checkpoints are refused with the file named.

mod tiny;

use std::sync::Arc;

use tadgs::data::Dataset;
use tadgs::io::checkpoint::{Checkpoint, LOG_FILE, STATE_FILE, TENSORS_FILE};
use tadgs::report::{StepRecord, TrainingLog};
use tadgs::scene::{CloneTime, SceneConfig, SharedMotionConfig};
use tadgs::train::Trainer;

fn log_of(trainer: &mut Trainer, log: &mut TrainingLog) {
    let state = trainer.state();
    log.steps.push(StepRecord {
        iteration: state.iteration,
        loss: state.loss.total,
        psnr: trainer.last_view_psnr(),
        gaussians: trainer.gaussian_count() as u32,
    });
}

/// Property: training 36 iterations straight and training 17, writing a checkpoint, loading it
/// into a new trainer and training the remaining 19 give bit-identical parameters, Adam
/// moments, densification statistics and counters, and the same RNG position. The stop lies
/// between two densification steps, with statistics accumulated and the epoch's view order
/// half used, so each of them matters.
///
/// Checked with and without per-camera exposure compensation, whose corrections and Adam
/// moments must survive the stop too, and with clones centred at their gradient's time, which
/// reads the statistics' time offsets, and with hard views drawn twice per epoch, whose
/// per-view losses must survive the stop, and with deferred Adam, whose Gaussians left behind
/// at the stop must keep how far behind they are (also with fused Adam, whose Gaussians are
/// restored without gradient components), and with shared motion bases, whose values
/// and moments and the Gaussians' weights and their moments must survive the stop.
#[test]
fn resumed_run_matches_uninterrupted_run() {
    let (config, dataset) = tiny::tiny_densifying_demo();
    check_resume(&config, &dataset, 17);
    let mut config = config;
    config.train.deferred_adam = true;
    check_resume(&config, &dataset, 17);
    config.train.fused_adam = true;
    check_resume(&config, &dataset, 17);
    config.train.fused_adam = false;
    config.train.deferred_adam = false;
    config.train.camera_exposure = true;
    check_resume(&config, &dataset, 17);
    config.densify.clone_time = CloneTime::Gradient;
    check_resume(&config, &dataset, 17);
    config.model.shared_motion = Some(SharedMotionConfig { bases: 3, knots: 4 });
    check_resume(&config, &dataset, 17);
    config.model.shared_motion = None;
    // Stop inside the second epoch, the first one to hold repeated views.
    let views = dataset.train.len() as u32;
    config.train.repeat_hard_views = 0.5;
    config.train.iterations = views + 30;
    check_resume(
        &config,
        &dataset,
        views + 5 + u32::from((views + 5).is_multiple_of(10)),
    );
}

fn check_resume(config: &SceneConfig, dataset: &Arc<Dataset>, stop: u32) {
    let config = config.clone();
    let total = config.train.iterations;

    let mut straight = Trainer::new(&config, dataset.clone());
    let mut straight_log = TrainingLog::default();
    for _ in 0..total {
        straight.step();
        log_of(&mut straight, &mut straight_log);
    }

    let dir = tempfile::tempdir().unwrap();
    let mut first = Trainer::new(&config, dataset.clone());
    let mut log = TrainingLog::default();
    for _ in 0..stop {
        first.step();
        log_of(&mut first, &mut log);
    }
    let saved = first.checkpoint(&config, &log);
    assert!(
        saved.gaussians.iter().any(|g| g.accum.count > 0),
        "the stop should fall where statistics are being accumulated"
    );
    if config.train.deferred_adam {
        assert!(
            saved
                .gaussians
                .iter()
                .any(|g| g.clock < stop && g.m != Default::default()),
            "some Gaussian with momentum should be left behind at the stop"
        );
    }
    if let Some(exposures) = &saved.state.camera_exposures {
        assert!(
            exposures
                .cameras
                .iter()
                .any(|c| c.steps > 0 && c.m != [0.0; 6]),
            "the exposure corrections should have been trained before the stop"
        );
    }
    if let Some(shared) = &saved.shared_motion {
        assert!(
            shared.m.iter().flatten().any(|&m| m != 0.0)
                && saved
                    .gaussians
                    .iter()
                    .any(|g| g.motion_adam.m().w[0] != 0.0),
            "the shared motion should have been trained before the stop"
        );
    }
    saved.save(dir.path()).unwrap();
    drop(first);

    let loaded = Checkpoint::load(dir.path()).unwrap();
    assert_eq!(loaded.state, saved.state);
    assert_eq!(loaded.gaussians, saved.gaussians);
    let kept = |c: &Checkpoint| {
        c.shared_motion
            .as_ref()
            .map(|s| (s.bases.clone(), s.m.clone(), s.v.clone()))
    };
    assert_eq!(
        kept(&loaded),
        kept(&saved),
        "shared motion bases or moments"
    );
    assert_eq!(loaded.log, log);
    let mut resumed = Trainer::from_checkpoint(&loaded, dataset.clone()).unwrap();
    let mut log = loaded.log.clone();
    for _ in stop..total {
        resumed.step();
        log_of(&mut resumed, &mut log);
    }

    let a = straight.checkpoint(&config, &straight_log);
    let b = resumed.checkpoint(&config, &log);
    assert_eq!(a.state.iteration, total);
    let densified = a.state.last_densify.0;
    assert!(
        densified > stop,
        "a densification step should follow the stop (last at {densified})"
    );
    if config.train.repeat_hard_views > 0.0 {
        assert!(
            saved.state.view_losses.iter().any(Option::is_some),
            "the views' losses should have been recorded before the stop"
        );
        assert!(
            a.state.view_order.len() > dataset.train.len(),
            "an epoch with repeated hard views should have been drawn"
        );
    }
    assert_eq!(a.state, b.state, "counters, view order or RNG differ");
    assert_eq!(
        a.shared_motion, b.shared_motion,
        "the shared motion differs"
    );
    assert_eq!(a.gaussians.len(), b.gaussians.len());
    for (i, (x, y)) in a.gaussians.iter().zip(&b.gaussians).enumerate() {
        assert_eq!(x, y, "Gaussian {i} differs");
    }
    assert_eq!(straight_log, log, "the training history differs");
}

/// Trains `steps` iterations and saves a checkpoint into `dir`; returns the Gaussian count.
fn saved_checkpoint(dir: &std::path::Path, steps: u32) -> usize {
    let (config, dataset) = tiny::tiny_densifying_demo();
    let mut trainer = Trainer::new(&config, dataset);
    for _ in 0..steps {
        trainer.step();
    }
    trainer
        .checkpoint(&config, &TrainingLog::default())
        .save(dir)
        .unwrap();
    trainer.gaussian_count()
}

/// A checkpoint written before `densify.clone_time` has no `grad_accum_offset` tensor: it
/// loads, with every time offset at 0 and everything else as saved.
#[test]
fn checkpoint_without_time_offsets_loads_with_zero_offsets() {
    let dir = tempfile::tempdir().unwrap();
    saved_checkpoint(dir.path(), 17);
    let saved = Checkpoint::load(dir.path()).unwrap();
    assert!(
        saved
            .gaussians
            .iter()
            .any(|g| g.accum.weighted_offset != 0.0),
        "the offsets should have been accumulated before the stop"
    );
    let path = dir.path().join(TENSORS_FILE);
    let bytes = std::fs::read(&path).unwrap();
    let (_, header) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let tensors = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let kept: Vec<_> = tensors
        .tensors()
        .into_iter()
        .filter(|(name, _)| name != "grad_accum_offset")
        .collect();
    assert_eq!(kept.len() + 1, tensors.len(), "the offsets were saved");
    safetensors::serialize_to_file(kept, header.metadata().clone(), &path).unwrap();
    let old = Checkpoint::load(dir.path()).unwrap();
    assert_eq!(old.state, saved.state);
    assert_eq!(old.gaussians.len(), saved.gaussians.len());
    for (a, b) in old.gaussians.iter().zip(&saved.gaussians) {
        assert_eq!(a.accum.weighted_offset, 0.0);
        let mut b = b.clone();
        b.accum.weighted_offset = 0.0;
        assert_eq!(*a, b);
    }
}

/// Property: a truncated tensor file is an error naming that file, not a panic.
#[test]
fn truncated_checkpoint_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    saved_checkpoint(dir.path(), 3);
    let path = dir.path().join(TENSORS_FILE);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let error = Checkpoint::load(dir.path()).unwrap_err().to_string();
    assert!(error.contains(TENSORS_FILE), "{error}");
}

/// Property: files from different iterations (a state file from another checkpoint) are
/// refused, naming the file that disagrees with state.ron.
#[test]
fn mismatched_checkpoint_files_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    saved_checkpoint(dir.path(), 3);
    let other = tempfile::tempdir().unwrap();
    let n = saved_checkpoint(other.path(), 5);
    std::fs::copy(other.path().join(STATE_FILE), dir.path().join(STATE_FILE)).unwrap();
    let error = Checkpoint::load(dir.path()).unwrap_err().to_string();
    assert!(error.contains(LOG_FILE), "{error}");
    assert!(error.contains("iteration 5"), "{error}");

    // Same iteration in every file, but the tensors hold another number of Gaussians.
    std::fs::copy(other.path().join(LOG_FILE), dir.path().join(LOG_FILE)).unwrap();
    let text = std::fs::read_to_string(dir.path().join(STATE_FILE)).unwrap();
    let text = text.replace(&format!("gaussians: {n}"), &format!("gaussians: {}", n + 1));
    std::fs::write(dir.path().join(STATE_FILE), text).unwrap();
    std::fs::copy(
        other.path().join(TENSORS_FILE),
        dir.path().join(TENSORS_FILE),
    )
    .unwrap();
    let error = Checkpoint::load(dir.path()).unwrap_err().to_string();
    assert!(error.contains(TENSORS_FILE), "{error}");

    // A missing file is named too.
    std::fs::remove_file(dir.path().join(TENSORS_FILE)).unwrap();
    let error = Checkpoint::load(dir.path()).unwrap_err().to_string();
    assert!(error.contains(TENSORS_FILE), "{error}");
}
