//! Shared by the GPU tests: opens a GPU stage, or skips (fails under CI=true).

use tadgs::gpu::{GpuError, GpuRasterizer};

/// A GPU rasterizer from `open` on the default adapter (Mesa's lavapipe where there is no
/// GPU), or None after printing why; under `CI=true` a missing adapter is a failure, so CI
/// never passes by skipping.
pub fn gpu_rasterizer(
    open: impl FnOnce() -> Result<GpuRasterizer, GpuError>,
) -> Option<GpuRasterizer> {
    open_or_skip(open)
}

/// Any GPU stage from `open`, or None after printing why a GPU could not be opened; under
/// `CI=true` that is a failure, as in [`gpu_rasterizer`].
pub fn open_or_skip<T>(open: impl FnOnce() -> Result<T, GpuError>) -> Option<T> {
    match open() {
        Ok(stage) => Some(stage),
        Err(e) => {
            if std::env::var("CI").is_ok_and(|v| v == "true") {
                panic!("{e}; CI=true requires a GPU adapter");
            }
            eprintln!("skipping: {e}");
            None
        }
    }
}
