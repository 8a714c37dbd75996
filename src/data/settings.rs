//! Serde defaults and setting checks that several data sources share.

use crate::scene::FieldError;

/// Serde default 1 (`downscale`: full resolution).
pub(crate) fn one() -> u32 {
    1
}

/// Serde default white background.
pub(crate) fn white() -> [f32; 3] {
    [1.0; 3]
}

/// Checks a `downscale` setting: an integer factor of at least 1.
pub(crate) fn check_downscale_factor(downscale: u32) -> Result<(), FieldError> {
    if downscale == 0 {
        return Err(FieldError::new("downscale", "must be at least 1"));
    }
    Ok(())
}

/// Checks a `background` setting: every channel finite and in [0, 1].
pub(crate) fn check_background(background: &[f32; 3]) -> Result<(), FieldError> {
    for (i, &c) in background.iter().enumerate() {
        if !(c.is_finite() && (0.0..=1.0).contains(&c)) {
            return Err(FieldError::new(
                "background",
                format!("channel {i} is {c}, outside [0, 1]"),
            ));
        }
    }
    Ok(())
}

/// Checks a `cache_mb` setting: a finite, positive number of megabytes, or `None`.
pub(crate) fn check_cache_mb(cache_mb: Option<f64>) -> Result<(), FieldError> {
    match cache_mb {
        Some(mb) if !(mb.is_finite() && mb > 0.0) => Err(FieldError::new(
            "cache_mb",
            format!("must be a positive number of megabytes, or None; found {mb}"),
        )),
        _ => Ok(()),
    }
}
