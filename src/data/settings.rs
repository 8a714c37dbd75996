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
