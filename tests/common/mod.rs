//! Shared by the integration tests that use the real data in `../shared/data`.

use std::path::PathBuf;

/// The shared test data folder: `TADGS_DATA`, or `../shared/data` beside the crate.
///
/// Returns None (after printing why) when it is missing, so the calling test can skip; under
/// `CI=true` a missing folder is a failure instead, so CI never passes by skipping.
pub fn data_dir() -> Option<PathBuf> {
    let dir = std::env::var_os("TADGS_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if dir.is_dir() {
        return Some(dir);
    }
    let message = format!("test data not found at {} (set TADGS_DATA)", dir.display());
    if std::env::var("CI").is_ok_and(|v| v == "true") {
        panic!("{message}; CI=true requires it");
    }
    eprintln!("skipping: {message}");
    None
}
