//! File input and output: images, trained models, checkpoints, splat PLY files and videos.

pub mod camera_path;
pub mod checkpoint;
pub mod image;
pub mod model;
pub mod ply;
pub mod video;

use std::io::Write;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` so that the file is either complete or absent: the bytes go to a
/// hidden temporary file beside it, are flushed to disk, then renamed over `path`. The
/// temporary file is removed when any step fails.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let temp = temporary_beside(path);
    let result = (|| {
        let mut file = std::fs::File::create(&temp)?;
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&temp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&temp);
    }
    result
}

/// `.<name>.<pid>.tmp` in the same folder as `path` (same file system, so the rename is atomic;
/// the process id keeps two writers of one file apart).
fn temporary_beside(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "file".to_owned());
    path.with_file_name(format!(".{name}.{}.tmp", std::process::id()))
}
