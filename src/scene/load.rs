//! Loading, validating and overriding scene files.
//!
//! Scene files are RON documents deserialised into [`SceneConfig`]. Every failure is
//! reported with the file it came from and, wherever the source text allows, the line
//! (and column) of the offending text:
//!
//! * syntax errors, unknown fields, missing fields and wrong types come from the RON
//!   parser with its position ([`SceneError::Syntax`]);
//! * values that parse but are out of range are found by [`validate`] (a [`FieldError`])
//!   and located in the source text by a structural scan of the RON document
//!   ([`locate_field`], [`SceneError::Invalid`]).
//!
//! Two RON extensions are accepted without a `#![enable(...)]` attribute:
//! `implicit_some` (write `vad_min_opacity: 0.1` instead of `Some(0.1)`; the explicit
//! form still works) and, as a fallback when the canonical form fails,
//! `unwrap_variant_newtypes` (write `data: Synthetic(width: 64, ...)` instead of the
//! canonical `Synthetic((width: 64, ...))`). RON applies the latter to every newtype
//! variant in the file, so a file must use one style throughout (`Solid(1.0, 0.0, 0.0)`
//! with the unwrapped style, `Solid((1.0, 0.0, 0.0))` with the canonical one).
//!
//! Command-line overrides such as `train.iterations=3000` or `model.tow.rho=0.7` are
//! applied by [`set_override`] / [`apply_overrides`]: the configuration is written out as
//! RON, the value at the dotted path is replaced by the override's RON text and the
//! result is parsed back with the real types, so every field — nested structs, enums,
//! options, arrays — is reachable without per-field code.

use std::path::Path;

use ron::extensions::Extensions;

use super::field_error::{Check, FieldError, fail};
use super::outline::{self, locate_field};
use super::types::{BackendKind, CapPolicy, DataSource, SceneConfig, TatForm};
use crate::model::shared_motion::MAX_MOTION_BASES;

/// The most knots `model.shared_motion.knots` may have (far more than any sequence has frames
/// to constrain them).
pub const MAX_MOTION_KNOTS: u32 = 100_000;

/// Everything that can go wrong while loading a scene file or applying an override.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    /// The file could not be read.
    #[error("cannot read scene file {path}: {source}")]
    Io {
        /// The path as given.
        path: String,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// The text is not a valid scene: RON syntax, unknown or missing field, wrong type.
    #[error("{path}:{line}:{column}: {message}")]
    Syntax {
        /// The path as given.
        path: String,
        /// 1-based line of the error.
        line: usize,
        /// 1-based column (in characters) of the error.
        column: usize,
        /// The parser's description of the problem.
        message: String,
    },
    /// The scene parsed but a value is out of range (found by [`validate`]).
    #[error("{path}{}: invalid value for `{field}`: {message}", line_suffix(.line))]
    Invalid {
        /// The path as given.
        path: String,
        /// 1-based line of the field in the file; when the field itself is absent (its
        /// default is used) the line of its closest enclosing section that is present.
        /// `None` when neither appears in the text.
        line: Option<usize>,
        /// Dotted field path, e.g. `densify.grad_threshold`.
        field: String,
        /// What is wrong with the value.
        message: String,
    },
    /// A command-line override could not be applied: unknown key, malformed value, a
    /// value of the wrong type, or a value that fails validation.
    #[error("invalid override `{key}`: {message}")]
    Override {
        /// The dotted key as given, e.g. `model.tow.rho`.
        key: String,
        /// What is wrong.
        message: String,
    },
}

fn line_suffix(line: &Option<usize>) -> String {
    match line {
        Some(line) => format!(":{line}"),
        None => String::new(),
    }
}

impl SceneError {
    /// The 1-based line the error points at, if it has one.
    pub fn line(&self) -> Option<usize> {
        match self {
            SceneError::Syntax { line, .. } => Some(*line),
            SceneError::Invalid { line, .. } => *line,
            SceneError::Io { .. } | SceneError::Override { .. } => None,
        }
    }
}

/// Reads, parses and validates the scene file at `path`.
///
/// Errors name the path as given.
pub fn load_scene(path: &Path) -> Result<SceneConfig, SceneError> {
    let shown = path.display().to_string();
    let text = std::fs::read_to_string(path).map_err(|source| SceneError::Io {
        path: shown.clone(),
        source,
    })?;
    // Editors on some systems start UTF-8 files with a byte-order mark.
    let text = text.strip_prefix('\u{feff}').unwrap_or(&text);
    let mut config = parse_scene(text, &shown)?;
    resolve_beside(&mut config, path.parent().unwrap_or(Path::new("")));
    Ok(config)
}

/// Relative paths in a scene file are looked up beside the file first, so a scene works from
/// any working directory; where nothing exists there, they stay relative to the working
/// directory (how the shipped scenes, run from the repository root, name `../shared/data`).
fn resolve_beside(config: &mut SceneConfig, folder: &Path) {
    for path in config.paths_mut() {
        if Path::new(path.as_str()).is_relative() {
            let beside = folder.join(path.as_str());
            if beside.exists() {
                *path = beside.to_string_lossy().into_owned();
            }
        }
    }
}

/// Parses and validates a scene from RON text; `path` is only used in error messages.
pub fn parse_scene(text: &str, path: &str) -> Result<SceneConfig, SceneError> {
    let config = deserialize(text).map_err(|e| {
        let (line, column) = skip_blanks(text, e.span.start.line, e.span.start.col);
        SceneError::Syntax {
            path: path.to_string(),
            line,
            column,
            message: e.code.to_string(),
        }
    })?;
    validate(&config).map_err(|error| SceneError::Invalid {
        path: path.to_string(),
        line: locate_field(text, error.points_at()),
        field: error.path,
        message: error.message,
    })?;
    Ok(config)
}

/// The parser reports some errors at the blank before the offending token; move such a
/// position onto the token when it is on the same line.
fn skip_blanks(text: &str, line: usize, column: usize) -> (usize, usize) {
    let Some(line_text) = text.lines().nth(line.wrapping_sub(1)) else {
        return (line, column);
    };
    let rest = line_text.chars().skip(column.saturating_sub(1));
    let blanks = rest.clone().take_while(|c| *c == ' ' || *c == '\t').count();
    if rest.clone().nth(blanks).is_some() {
        (line, column + blanks)
    } else {
        (line, column)
    }
}

fn ron_options(extra: Extensions) -> ron::Options {
    ron::Options::default().with_default_extension(Extensions::IMPLICIT_SOME | extra)
}

/// Deserialises with the canonical newtype-variant form first and the unwrapped form as
/// a fallback; when both fail, the error that got further into the text is the
/// informative one.
fn deserialize(text: &str) -> Result<SceneConfig, ron::error::SpannedError> {
    match ron_options(Extensions::empty()).from_str(text) {
        Ok(config) => Ok(config),
        Err(first) => match ron_options(Extensions::UNWRAP_VARIANT_NEWTYPES).from_str(text) {
            Ok(config) => Ok(config),
            Err(second) if second.span.start > first.span.start => Err(second),
            Err(_) => Err(first),
        },
    }
}

// ---------------------------------------------------------------------------------------
// Validation
// ---------------------------------------------------------------------------------------

fn finite(field: &str, v: f32) -> Check {
    if v.is_finite() {
        Ok(())
    } else {
        fail(field, format!("{v} is not a finite number"))
    }
}

/// `v` finite and within `lo..hi`, each bound inclusive or exclusive as flagged.
fn in_range(field: &str, v: f32, lo: f32, lo_incl: bool, hi: f32, hi_incl: bool) -> Check {
    finite(field, v)?;
    let above = if lo_incl { v >= lo } else { v > lo };
    let below = if hi_incl { v <= hi } else { v < hi };
    if above && below {
        Ok(())
    } else {
        let open = if lo_incl { '[' } else { '(' };
        let close = if hi_incl { ']' } else { ')' };
        fail(field, format!("{v} is outside {open}{lo}, {hi}{close}"))
    }
}

fn at_least(field: &str, v: f32, lo: f32) -> Check {
    finite(field, v)?;
    if v >= lo {
        Ok(())
    } else {
        fail(field, format!("{v} must be at least {lo}"))
    }
}

fn positive(field: &str, v: f32) -> Check {
    finite(field, v)?;
    if v > 0.0 {
        Ok(())
    } else {
        fail(field, format!("{v} must be greater than 0"))
    }
}

fn nonzero<T: PartialEq + Default>(field: &str, v: T) -> Check {
    if v != T::default() {
        Ok(())
    } else {
        fail(field, "must be greater than 0")
    }
}

/// Checks every range constraint of a scene; on failure names the first offending field
/// (e.g. `densify.grad_threshold`) and what is wrong with it.
///
/// Checked: `train.iterations > 0`; `lambda_dssim` in [0, 1]; every learning rate finite
/// and ≥ 0 (`sh_rest_divisor` > 0) with `position_final ≤ position`; background channels
/// in [0, 1]; `near_plane > 0`; `model.sh_degree ≤ 3`; `model.motion_period > 0`;
/// `tow.window_frames > 0`, `tow.rho` in (0, 1); `model.shared_motion` with `bases` in 1..=16,
/// `knots` in 2..=[`MAX_MOTION_KNOTS`] and the CPU backend; `train.lr.temporal_center` 0 with the GPU
/// backend; `train.motion_smoothness.weight ≥ 0`, and above 0 only on the CPU backend with
/// `neighbours` and `rebuild_interval` above 0; `train.fused_adam` without motion smoothness or
/// shared motion;
/// TAT `Paper` β ≥ 0, α > 0 and `Implementation` β in [0, 1], α > 0;
/// `grad_threshold > 0`; `percent_dense > 0`; `interval > 0`; `from_iter ≤ until_iter`;
/// `prune_opacity` in [0, 1); `vad_min_opacity` in [0, 1) if set; `max_gaussians ≥ 1`;
/// `at_cap: Replace` `max_opacity` in (0, 1);
/// `init.anchor_spacing ≥ 1`, `points_per_anchor ≥ 1`, `opacity` in (0, 1),
/// `lifespan_half_frames > 0`; and the data source's own check (`data.<field>`; a synthetic
/// scene's errors are reported under `data` as a whole, pointing at the field inside it).
/// Non-finite floats are rejected wherever a float is checked.
pub fn validate(config: &SceneConfig) -> Result<(), FieldError> {
    if config.name.trim().is_empty() {
        return fail(
            "name",
            "is empty: name the scene (it titles the report and logs)",
        );
    }
    if config.output.trim().is_empty() {
        return fail(
            "output",
            "is empty: give the run folder (an empty one would write into the working directory)",
        );
    }
    if let Some(segment) = &config.segment
        && segment.first_frame > segment.last_frame
    {
        return fail(
            "segment",
            format!(
                "first_frame {} is after last_frame {}",
                segment.first_frame, segment.last_frame
            ),
        );
    }
    // train
    let t = &config.train;
    nonzero("train.iterations", t.iterations)?;
    in_range("train.lambda_dssim", t.lambda_dssim, 0.0, true, 1.0, true)?;
    in_range(
        "train.repeat_hard_views",
        t.repeat_hard_views,
        0.0,
        true,
        1.0,
        true,
    )?;
    positive("train.near_plane", t.near_plane)?;
    nonzero("train.coarse_downscale", t.coarse_downscale)?;
    if t.coarse_downscale > 1 && t.coarse_until == 0 {
        return fail(
            "train.coarse_until",
            "is 0, so no iteration would use train.coarse_downscale: give the last coarse \
             iteration, or set coarse_downscale to 1",
        );
    }
    for (i, &c) in t.background.iter().enumerate() {
        if !(c.is_finite() && (0.0..=1.0).contains(&c)) {
            return fail(
                "train.background",
                format!("channel {i} is {c}, outside [0, 1]"),
            );
        }
    }
    let lr = &t.lr;
    let rates = [
        ("position", lr.position),
        ("position_final", lr.position_final),
        ("fourier_cos_sin", lr.fourier_cos_sin),
        ("fourier_phase", lr.fourier_phase),
        ("temporal_scale", lr.temporal_scale),
        ("temporal_center", lr.temporal_center),
        ("opacity", lr.opacity),
        ("rotation", lr.rotation),
        ("rotation_velocity", lr.rotation_velocity),
        ("scale", lr.scale),
        ("scale_velocity", lr.scale_velocity),
        ("sh_dc", lr.sh_dc),
        ("exposure", lr.exposure),
        ("motion_bases", lr.motion_bases),
        ("motion_weights", lr.motion_weights),
    ];
    // Adam moves a parameter by about its learning rate per step: above 1 (a whole unit of
    // logit, log-scale or colour, or 1 × the extent for positions, every iteration) training
    // only diverges. The Fourier rates are fractions of the position rate.
    for (name, v) in rates {
        let most = if name.starts_with("fourier") {
            100.0
        } else {
            1.0
        };
        in_range(&format!("train.lr.{name}"), v, 0.0, true, most, true)?;
    }
    positive("train.lr.sh_rest_divisor", lr.sh_rest_divisor)?;
    if lr.temporal_center > 0.0 && t.backend == BackendKind::Gpu {
        return fail(
            "train.lr.temporal_center",
            format!(
                "is {}, but learnt temporal centres need `train.backend: Cpu`: the GPU backend \
                 warps each view's times with the centres the CPU holds",
                lr.temporal_center
            ),
        );
    }
    let smooth = &t.motion_smoothness;
    at_least("train.motion_smoothness.weight", smooth.weight, 0.0)?;
    if smooth.weight > 0.0 {
        nonzero("train.motion_smoothness.neighbours", smooth.neighbours)?;
        nonzero(
            "train.motion_smoothness.rebuild_interval",
            smooth.rebuild_interval,
        )?;
        if t.backend == BackendKind::Gpu {
            return fail(
                "train.motion_smoothness.weight",
                format!(
                    "is {}, but the motion-smoothness regulariser runs on the CPU backend only: \
                     use `train.backend: Cpu` or `weight: 0`",
                    smooth.weight
                ),
            );
        }
    }
    // Both options skip Gaussians in the CPU optimiser only.
    for (name, on) in [
        ("visible_adam", t.visible_adam),
        ("deferred_adam", t.deferred_adam),
    ] {
        if on && t.backend == BackendKind::Gpu {
            return fail(
                &format!("train.{name}"),
                format!(
                    "is true, but the GPU backend's Adam steps every Gaussian: use \
                     `train.backend: Cpu` or `{name}: false`"
                ),
            );
        }
    }
    if t.deferred_adam && t.visible_adam {
        return fail(
            "train.deferred_adam",
            "is true, and so is train.visible_adam: choose one (deferred Adam also steps only \
             the Gaussians that received a gradient)"
                .to_string(),
        );
    }
    if t.fused_adam && smooth.weight > 0.0 {
        return fail(
            "train.fused_adam",
            "is true, but the motion-smoothness regulariser adds to the gradient components a \
             fused Adam does without: set `train.motion_smoothness.weight: 0` or `fused_adam: \
             false`"
                .to_string(),
        );
    }
    if lr.position_final > lr.position {
        return fail(
            "train.lr.position_final",
            format!(
                "{} is larger than train.lr.position ({})",
                lr.position_final, lr.position
            ),
        );
    }

    // model
    let m = &config.model;
    if m.sh_degree > 3 {
        return fail("model.sh_degree", format!("{} is above 3", m.sh_degree));
    }
    positive("model.motion_period", m.motion_period)?;
    positive("model.tow.window_frames", m.tow.window_frames)?;
    in_range("model.tow.rho", m.tow.rho, 0.0, false, 1.0, false)?;
    if let Some(shared) = m.shared_motion {
        let most = MAX_MOTION_BASES as u32;
        if !(1..=most).contains(&shared.bases) {
            return fail(
                "model.shared_motion.bases",
                format!("{} is outside 1 to {most}", shared.bases),
            );
        }
        if !(2..=MAX_MOTION_KNOTS).contains(&shared.knots) {
            return fail(
                "model.shared_motion.knots",
                format!(
                    "{} is outside 2 to {MAX_MOTION_KNOTS}: a piecewise-linear trajectory \
                     needs a knot at each end of the sequence",
                    shared.knots
                ),
            );
        }
        if t.backend == BackendKind::Gpu {
            return fail(
                "model.shared_motion",
                "is set, but the shared motion bases run on the CPU backend only: use \
                 `train.backend: Cpu` or `shared_motion: None`",
            );
        }
        if t.fused_adam {
            return fail(
                "model.shared_motion",
                "is set, but the shared motion's gradient is read from the gradient components \
                 that `train.fused_adam` does without: use `fused_adam: false` or \
                 `shared_motion: None`",
            );
        }
    }

    // densify
    let d = &config.densify;
    match d.tat_form {
        TatForm::Paper { beta, alpha } => {
            at_least("densify.tat_form.beta", beta, 0.0)?;
            positive("densify.tat_form.alpha", alpha)?;
        }
        TatForm::Implementation { beta, alpha } => {
            in_range("densify.tat_form.beta", beta, 0.0, true, 1.0, true)?;
            positive("densify.tat_form.alpha", alpha)?;
        }
    }
    positive("densify.grad_threshold", d.grad_threshold)?;
    positive("densify.percent_dense", d.percent_dense)?;
    nonzero("densify.interval", d.interval)?;
    if d.from_iter > d.until_iter {
        return fail(
            "densify.from_iter",
            format!(
                "{} is after densify.until_iter ({})",
                d.from_iter, d.until_iter
            ),
        );
    }
    in_range(
        "densify.prune_opacity",
        d.prune_opacity,
        0.0,
        true,
        1.0,
        false,
    )?;
    if let Some(v) = d.vad_min_opacity {
        in_range("densify.vad_min_opacity", v, 0.0, true, 1.0, false)?;
    }
    nonzero("densify.max_gaussians", d.max_gaussians)?;
    if let CapPolicy::Replace { max_opacity } = d.at_cap {
        in_range(
            "densify.at_cap.max_opacity",
            max_opacity,
            0.0,
            false,
            1.0,
            false,
        )?;
    }

    // init
    let i = &config.init;
    nonzero("init.anchor_spacing", i.anchor_spacing)?;
    nonzero("init.points_per_anchor", i.points_per_anchor)?;
    in_range("init.opacity", i.opacity, 0.0, false, 1.0, false)?;
    positive("init.lifespan_half_frames", i.lifespan_half_frames)?;
    if let Some(frames) = i.background_lifespan_half_frames {
        positive("init.background_lifespan_half_frames", frames)?;
    }
    if let Err(error) = i.carve.validate() {
        return fail("init.carve", error.to_string());
    }
    if let crate::scene::InitMethod::PointCloud(path) = &i.method
        && path.is_empty()
    {
        return fail("init.method", "PointCloud needs a file path");
    }

    // data
    match &config.data {
        DataSource::Synthetic(scene) => scene.validate().map_err(|e| e.reported_under("data")),
        DataSource::Panoptic(p) => p.check().map_err(|e| e.within("data")),
        DataSource::N3dv(n) => n.check().map_err(|e| e.within("data")),
        DataSource::DNerf(d) => d.check().map_err(|e| e.within("data")),
        DataSource::Nerfstudio(n) => n.check().map_err(|e| e.within("data")),
        DataSource::ColmapFrames(c) | DataSource::ColmapRig(c) => {
            c.check().map_err(|e| e.within("data"))
        }
    }
}

// ---------------------------------------------------------------------------------------
// Overrides
// ---------------------------------------------------------------------------------------

/// Sets the field at a dotted `key` (e.g. `train.iterations`, `densify.vad`,
/// `model.tow.rho`, `densify.tat_form`, `train.background.0`) to `value`, written as RON
/// (`3000`, `false`, `0.7`, `Implementation(beta: 0.5, alpha: 2.0)`, `"runs/x"`), then
/// validates the whole configuration.
///
/// String fields also accept an unquoted value (`output=runs/x`). Option fields accept
/// the bare inner value. On any error `config` is left unchanged; the error names the
/// key: an unknown key lists the fields available at that level, a value of the wrong
/// type quotes the parser's complaint. Because every call validates, overrides whose
/// intermediate state would be inconsistent (e.g. moving `densify.until_iter` below
/// `densify.from_iter` before lowering the latter) should go through
/// [`apply_overrides`], which validates once at the end.
pub fn set_override(config: &mut SceneConfig, key: &str, value: &str) -> Result<(), SceneError> {
    let updated = replaced(config, key, value)?;
    check_overridden(&updated, &[key])?;
    *config = updated;
    Ok(())
}

/// Applies `key=value` overrides in order (see [`set_override`] for the syntax), then
/// validates once. On any error `config` is left unchanged.
pub fn apply_overrides<S: AsRef<str>>(
    config: &mut SceneConfig,
    overrides: &[S],
) -> Result<(), SceneError> {
    let mut updated = config.clone();
    let mut keys = Vec::new();
    for arg in overrides {
        let arg = arg.as_ref();
        let (key, value) = arg.split_once('=').ok_or_else(|| SceneError::Override {
            key: arg.to_string(),
            message: "expected `key=value`".to_string(),
        })?;
        updated = replaced(&updated, key.trim(), value)?;
        keys.push(key.trim());
    }
    check_overridden(&updated, &keys)?;
    *config = updated;
    Ok(())
}

/// Validates an overridden configuration. A failure is attributed to the override whose
/// key overlaps the failing field (the last such), else to all of `keys`.
fn check_overridden(config: &SceneConfig, keys: &[&str]) -> Result<(), SceneError> {
    validate(config).map_err(|error| {
        let field = &error.path;
        let overlaps = |key: &&&str| {
            let within = |outer: &str, inner: &str| {
                inner == outer || inner.starts_with(&format!("{outer}."))
            };
            within(key, field) || within(field, key)
        };
        let key = match keys.iter().rev().find(overlaps) {
            Some(key) => key.to_string(),
            None => keys.join(", "),
        };
        SceneError::Override {
            key,
            message: format!("invalid value for `{field}`: {}", error.message),
        }
    })
}

/// `config` with the value at `key` replaced by the RON text `value` (type-checked by
/// deserialisation, not validated).
fn replaced(config: &SceneConfig, key: &str, value: &str) -> Result<SceneConfig, SceneError> {
    let err = |message: String| SceneError::Override {
        key: key.to_string(),
        message,
    };
    if key.is_empty() || key.split('.').any(str::is_empty) {
        return Err(err(
            "the key must be a dotted field path such as `train.iterations`".into(),
        ));
    }
    let text = ron::ser::to_string_pretty(config, ron::ser::PrettyConfig::default())
        .map_err(|e| err(format!("cannot serialise the configuration: {e}")))?;
    let root = outline::parse_document(&text)
        .ok_or_else(|| err("cannot scan the serialised configuration".into()))?;

    // Walk the dotted path.
    let mut node = &root;
    let mut walked = String::new();
    for segment in key.split('.') {
        let next = match segment.parse::<usize>() {
            Ok(index) => node.item(index),
            Err(_) => node.field(segment).map(|f| &f.value),
        };
        node = match next {
            Some(next) => next,
            None => {
                let known = node.field_names();
                let place = if walked.is_empty() {
                    "the scene".to_string()
                } else {
                    format!("`{walked}`")
                };
                return Err(err(if known.is_empty() {
                    format!("unknown key: {place} has no field `{segment}`")
                } else {
                    format!(
                        "unknown key: {place} has no field `{segment}` (fields: {})",
                        known.join(", ")
                    )
                }));
            }
        };
        if !walked.is_empty() {
            walked.push('.');
        }
        walked.push_str(segment);
    }

    // The replacement text: one well-formed RON value.
    let value = value.trim();
    let target_is_string = text[node.start..].starts_with('"');
    let replacement =
        if target_is_string && outline::parse_single(value).is_none_or(|v| !v.is_string(value)) {
            quote(value)
        } else if outline::parse_single(value).is_some() {
            value.to_string()
        } else {
            return Err(err(format!("`{value}` is not a single RON value")));
        };

    let spliced = format!(
        "{}{}{}",
        &text[..node.start],
        replacement,
        &text[node.end..]
    );
    deserialize(&spliced).map_err(|e| err(format!("cannot use `{value}` here: {}", e.code)))
}

fn quote(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\t' => out.push_str("\\t"),
            '\r' => out.push_str("\\r"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}
