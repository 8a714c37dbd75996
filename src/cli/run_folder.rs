//! Who may write a run folder: one tadgs process at a time (an OS file lock, which a crash
//! releases), and a new run never lands on top of another one.

use std::fs::{File, OpenOptions, TryLockError};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use tadgs::io::checkpoint::Checkpoint;

use super::create_dir;

/// The lock file inside a run folder. Its content is irrelevant; the lock is on the open file.
pub const LOCK_FILE: &str = ".tadgs.lock";

/// Everything a run writes into its folder (what `--force` removes). Not `masks/`: dynamic
/// masks depend on the data only, are slow to compute, and may be passed in with `--masks`.
const RUN_OUTPUTS: &[&str] = &[
    "scene.ron",
    "model.safetensors",
    "metrics.json",
    "metrics.csv",
    "heldout",
    "checkpoint",
    "report",
    "train-split",
];

/// Holds a run folder for this process until dropped.
#[derive(Debug)]
pub struct RunLock {
    _file: File,
}

impl RunLock {
    /// Creates `dir` if needed and locks it, or fails when another process holds it.
    pub fn acquire(dir: &Path) -> Result<Self> {
        create_dir(dir)?;
        let path = dir.join(LOCK_FILE);
        let file = OpenOptions::new()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .with_context(|| format!("opening {}", path.display()))?;
        match file.try_lock() {
            Ok(()) => {}
            Err(TryLockError::WouldBlock) => bail!(
                "{} is in use by another tadgs process (train or eval); wait until it ends, \
                 or write to another folder with -o DIR",
                dir.display()
            ),
            // Some file systems (e.g. a few network mounts) have no locks: go on without one.
            Err(TryLockError::Error(e)) => tracing::warn!(
                "could not lock {} ({e}); make sure no other tadgs process writes there",
                dir.display()
            ),
        }
        Ok(Self { _file: file })
    }
}

/// What an existing run in `dir` is, in words, or None when `dir` holds no run.
pub fn existing_run(dir: &Path) -> Option<String> {
    if dir.join("model.safetensors").is_file() {
        return Some("a finished run".into());
    }
    let checkpoint = dir.join("checkpoint");
    if checkpoint.is_dir() {
        return Some(match Checkpoint::load_state(&checkpoint) {
            Ok(state) => format!(
                "an unfinished run (checkpoint at iteration {} of {})",
                state.iteration, state.scene.train.iterations
            ),
            Err(_) => "an unfinished run (its checkpoint does not load)".into(),
        });
    }
    RUN_OUTPUTS
        .iter()
        .any(|name| dir.join(name).exists())
        .then(|| "the files of an earlier run".into())
}

/// Fails when `dir` holds a run, with the ways out; with `force`, says it will be replaced.
pub fn refuse_existing_run(dir: &Path, force: bool) -> Result<()> {
    let Some(what) = existing_run(dir) else {
        return Ok(());
    };
    if force {
        tracing::warn!(
            "--force: {} holds {what}; it will be replaced",
            dir.display()
        );
        return Ok(());
    }
    bail!(
        "{} already holds {what}. Continue it with `tadgs train --resume {}`, write to another \
         folder with -o DIR, or replace it with --force",
        dir.display(),
        dir.display()
    )
}

/// Removes an earlier run's outputs from `dir`.
pub fn remove_run_outputs(dir: &Path) -> Result<()> {
    for name in RUN_OUTPUTS {
        let path = dir.join(name);
        let removed = if path.is_dir() {
            std::fs::remove_dir_all(&path)
        } else if path.exists() {
            std::fs::remove_file(&path)
        } else {
            continue;
        };
        removed.with_context(|| format!("removing {}", path.display()))?;
    }
    Ok(())
}

/// Whether two paths name the same folder (both exist and resolve to one place).
pub fn same_folder(a: &Path, b: &Path) -> bool {
    let resolve = |p: &Path| -> Option<PathBuf> { p.canonicalize().ok() };
    matches!((resolve(a), resolve(b)), (Some(x), Some(y)) if x == y)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second lock on a folder fails while the first is held, and succeeds once it is dropped.
    #[test]
    fn second_lock_fails_until_the_first_is_released() {
        let dir = tempfile::tempdir().unwrap();
        let first = RunLock::acquire(dir.path()).unwrap();
        let err = RunLock::acquire(dir.path()).unwrap_err().to_string();
        assert!(err.contains("in use by another tadgs process"), "{err}");
        drop(first);
        RunLock::acquire(dir.path()).unwrap();
    }

    /// An empty folder, or one with only the lock file and masks, holds no run; any run output
    /// counts, and removing the outputs keeps the masks and anything else the user put there.
    #[test]
    fn run_outputs_are_found_and_removed() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(existing_run(dir.path()), None);
        std::fs::write(dir.path().join(LOCK_FILE), "").unwrap();
        std::fs::create_dir(dir.path().join("masks")).unwrap();
        assert_eq!(existing_run(dir.path()), None);
        std::fs::write(dir.path().join("metrics.json"), "{}").unwrap();
        std::fs::write(dir.path().join("notes.txt"), "mine").unwrap();
        assert!(existing_run(dir.path()).is_some());
        std::fs::write(dir.path().join("model.safetensors"), "").unwrap();
        assert_eq!(existing_run(dir.path()).as_deref(), Some("a finished run"));
        remove_run_outputs(dir.path()).unwrap();
        assert!(dir.path().join("masks").is_dir());
        assert!(dir.path().join("notes.txt").is_file());
        assert!(!dir.path().join("metrics.json").exists());
        assert!(!dir.path().join("model.safetensors").exists());
        assert_eq!(existing_run(dir.path()), None);
        std::fs::write(dir.path().join("scene.ron"), "()").unwrap();
        let err = refuse_existing_run(dir.path(), false)
            .unwrap_err()
            .to_string();
        assert!(err.contains("--resume") && err.contains("--force"), "{err}");
        refuse_existing_run(dir.path(), true).unwrap();
    }
}
