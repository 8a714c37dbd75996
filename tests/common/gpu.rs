//! Shared by the GPU tests: opens the GPU rasterizer, or skips (fails under CI=true).

use tadgs::gpu::{GpuError, GpuRasterizer};

/// A GPU rasterizer from `open` on the default adapter (Mesa's lavapipe where there is no
/// GPU), or None after printing why; under `CI=true` a missing adapter is a failure, so CI
/// never passes by skipping.
pub fn gpu_rasterizer(
    open: impl FnOnce() -> Result<GpuRasterizer, GpuError>,
) -> Option<GpuRasterizer> {
    match open() {
        Ok(gpu) => Some(gpu),
        Err(e) => {
            if std::env::var("CI").is_ok_and(|v| v == "true") {
                panic!("{e}; CI=true requires a GPU adapter");
            }
            eprintln!("skipping: {e}");
            None
        }
    }
}
