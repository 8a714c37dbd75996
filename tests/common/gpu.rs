//! Shared by the GPU tests: opens the GPU rasterizer or a bare context, or skips (fails under
//! CI=true).

#![allow(dead_code)]

use tadgs::gpu::{GpuContext, GpuError, GpuRasterizer};

/// The result of `open` on the default adapter (Mesa's lavapipe where there is no GPU), or None
/// after printing why; under `CI=true` a missing adapter is a failure, so CI never passes by
/// skipping.
pub fn open_or_skip<T>(open: impl FnOnce() -> Result<T, GpuError>) -> Option<T> {
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

/// A GPU rasterizer from `open` (see [`open_or_skip`]).
pub fn gpu_rasterizer(
    open: impl FnOnce() -> Result<GpuRasterizer, GpuError>,
) -> Option<GpuRasterizer> {
    open_or_skip(open)
}

/// A device on the default adapter without optional features (see [`open_or_skip`]): what
/// the portable kernels must work with.
pub fn gpu_context() -> Option<GpuContext> {
    let gpu = open_or_skip(|| GpuContext::new(false))?;
    eprintln!("adapter: {}", gpu.describe());
    Some(gpu)
}
