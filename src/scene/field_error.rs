//! The one error type for a setting that is out of range, shared by the scene checks
//! ([`validate`](super::validate)) and the data sources' own checks, so that every loader
//! knows which field to name and where to point without reading it back out of a message.

/// A setting whose value is invalid: the dotted path of the field and what is wrong.
///
/// Shown as `{path} {message}` (`cameras.count must be at least 2, got 1`). A scene file
/// reports it as [`SceneError::Invalid`](super::SceneError::Invalid) at the line of the
/// field, a data reader as a [`DataError::Field`](crate::data::DataError::Field).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("{path} {message}")]
pub struct FieldError {
    /// Dotted path of the field the error is reported under, with list indices where
    /// they matter: `densify.grad_threshold`, `held_out[1]`, `data.validation_cameras`.
    pub path: String,
    /// What is wrong with the value.
    pub message: String,
    /// The value at fault, when deeper than `path` (see [`FieldError::reported_under`]).
    at: Option<String>,
}

impl FieldError {
    /// The field at `path` is invalid because of `message`.
    pub fn new(path: impl Into<String>, message: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            message: message.into(),
            at: None,
        }
    }

    /// The same error for a section checked on its own and placed at `parent` in a scene:
    /// a data source's `frames` becomes `data.frames`.
    pub fn within(self, parent: &str) -> Self {
        Self {
            path: format!("{parent}.{}", self.path),
            message: self.message,
            at: self.at.map(|at| format!("{parent}.{at}")),
        }
    }

    /// This error reported under `parent` as a whole, its own path leading the message
    /// (`data`: `cameras.radius must be …`), while [`FieldError::points_at`] still names the
    /// field itself. A synthetic scene's errors are reported this way.
    pub fn reported_under(self, parent: &str) -> Self {
        let at = format!("{parent}.{}", self.points_at());
        Self {
            path: parent.to_string(),
            message: self.to_string(),
            at: Some(at),
        }
    }

    /// Dotted path of the value at fault: the place to point at in a file. It is `path`
    /// unless the error is [reported under](FieldError::reported_under) an enclosing field.
    pub fn points_at(&self) -> &str {
        self.at.as_deref().unwrap_or(&self.path)
    }
}

/// The outcome of one check.
pub(crate) type Check = Result<(), FieldError>;

/// Fails a check: shorthand for the many early returns in the validators.
pub(crate) fn fail(path: &str, message: impl Into<String>) -> Check {
    Err(FieldError::new(path, message))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nesting_keeps_the_field_at_fault() {
        let inner = FieldError::new("cameras.radius", "must be positive and finite, got -3");
        assert_eq!(
            inner.to_string(),
            "cameras.radius must be positive and finite, got -3"
        );
        let within = inner.clone().within("data");
        assert_eq!(within.path, "data.cameras.radius");
        assert_eq!(within.points_at(), "data.cameras.radius");
        let under = inner.reported_under("data");
        assert_eq!(under.path, "data");
        assert_eq!(
            under.message,
            "cameras.radius must be positive and finite, got -3"
        );
        assert_eq!(under.points_at(), "data.cameras.radius");
    }
}
