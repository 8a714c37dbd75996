//! Scene files: parsing with defaults, and errors that point at the file, line and field.

mod mutate;

use std::path::Path;

use proptest::prelude::*;
use tadgs::scene::load::{apply_overrides, set_override, validate};
use tadgs::scene::*;

/// The body of the synthetic data source used by every test scene (one line, so that
/// line numbers in the tests stay easy to read off).
const SYNTHETIC: &str = "frames: 4, width: 16, height: 12, \
    cameras: (count: 3, radius: 3.0, height: 1.0, target: (0.0, 0.0, 0.0), fov_x_degrees: 50.0), \
    held_out: [2], background: (0.0, 0.0, 0.0), \
    objects: [(shape: Sphere(radius: 0.5), texture: Solid((1.0, 0.0, 0.0)), \
    path: [(time: 0.0, position: (0.0, 0.0, 0.0)), (time: 1.0, position: (1.0, 0.0, 0.0))])]";

/// The data section used by every test scene, in the canonical newtype-variant form.
fn data() -> String {
    format!("Synthetic(({SYNTHETIC}))")
}

/// A scene with only the required fields.
fn minimal() -> String {
    let data = data();
    format!("(\n    name: \"minimal\",\n    data: {data},\n)\n")
}

/// A scene with the given sections spliced in after the required fields (one field per
/// line, so line numbers in the tests are easy to read off: `extra` starts on line 4).
fn scene_with(extra: &str) -> String {
    let data = data();
    format!("(\n    name: \"t\",\n    data: {data},\n{extra}\n)\n")
}

fn minimal_config() -> SceneConfig {
    parse_scene(&minimal(), "minimal.ron").expect("minimal scene parses")
}

#[track_caller]
fn expect_syntax(result: Result<SceneConfig, SceneError>) -> (usize, usize, String) {
    match result {
        Err(SceneError::Syntax {
            path,
            line,
            column,
            message,
        }) => {
            assert_eq!(path, "scene.ron");
            (line, column, message)
        }
        other => panic!("expected a syntax error, got {other:?}"),
    }
}

#[track_caller]
fn expect_invalid(result: Result<SceneConfig, SceneError>) -> (Option<usize>, String, String) {
    match result {
        Err(SceneError::Invalid {
            path,
            line,
            field,
            message,
        }) => {
            assert_eq!(path, "scene.ron");
            (line, field, message)
        }
        other => panic!("expected an invalid-value error, got {other:?}"),
    }
}

// ---------------------------------------------------------------------------------------
// Parsing
// ---------------------------------------------------------------------------------------

/// Property: a scene with only `name` and `data` parses and every section takes the
/// SPEC defaults.
#[test]
fn minimal_scene_fills_in_defaults() {
    let c = minimal_config();
    assert_eq!(c.name, "minimal");
    assert_eq!(c.init, InitConfig::default());
    assert_eq!(c.model, ModelConfig::default());
    assert_eq!(c.densify, DensifyConfig::default());
    assert_eq!(c.train, TrainConfig::default());
    assert_eq!(c.output, "runs/out");
    assert!(validate(&c).is_ok());
}

/// Property: a fully written scene (comments, attributes, enums, options, integers for
/// floats) parses to exactly the values written; omitted sections keep their defaults.
#[test]
fn full_scene_parses_every_kind_of_value() {
    let data = data();
    let text = format!(
        r#"// A comment before the scene.
#![enable(implicit_some)]
(
    name: "full",
    data: {data},
    init: (anchor_spacing: 10, points_per_anchor: 500, opacity: 0.2, lifespan_half_frames: 12.5),
    model: (
        sh_degree: 1,
        opacity: Asymmetric,
        phase: PerFrequency,
        scale_motion: false,
        tow: (enabled: true, window_frames: 40, rho: 0.7), /* integers are fine for floats */
    ),
    densify: (
        vad: true,
        vad_min_opacity: 0.05,
        tat: true,
        tat_form: Implementation(beta: 0.5, alpha: 2.0),
        grad_threshold: 3e-4,
        percent_dense: 0.01,
        interval: 100,
        from_iter: 500,
        until_iter: 15000,
        opacity_reset_interval: 3000,
        prune_opacity: 0.005,
        prune_big: true,
        max_gaussians: 200000,
    ),
    output: "runs/full",
)
"#
    );
    let c = parse_scene(&text, "full.ron").unwrap();
    assert_eq!(c.init.points_per_anchor, 500);
    assert_eq!(c.model.opacity, OpacityModel::Asymmetric);
    assert_eq!(c.model.phase, PhaseModel::PerFrequency);
    assert_eq!(c.model.tow.window_frames, 40.0);
    assert_eq!(c.densify.vad_min_opacity, Some(0.05));
    assert_eq!(
        c.densify.tat_form,
        TatForm::Implementation {
            beta: 0.5,
            alpha: 2.0
        }
    );
    assert_eq!(c.densify.max_gaussians, 200_000);
    assert_eq!(c.output, "runs/full");
    assert_eq!(c.train, TrainConfig::default());
}

/// Property: options may be written explicitly as `Some(x)` as well as bare.
#[test]
fn explicit_some_is_accepted() {
    let text = scene_with(
        "    densify: (vad: true, vad_min_opacity: Some(0.1), tat: true, \
         tat_form: Paper(beta: 0.3, alpha: 1.0), grad_threshold: 2e-4, percent_dense: 0.01, \
         interval: 200, from_iter: 500, until_iter: 17000, opacity_reset_interval: 3000, \
         prune_opacity: 0.005, prune_big: false, max_gaussians: 1000),",
    );
    let c = parse_scene(&text, "scene.ron").unwrap();
    assert_eq!(c.densify.vad_min_opacity, Some(0.1));
}

// ---------------------------------------------------------------------------------------
// Syntax errors: file, line, column
// ---------------------------------------------------------------------------------------

/// Property: a RON syntax error on line 3 is reported at line 3 with a column, and the
/// message starts with `path:line:column:`.
#[test]
fn syntax_error_reports_line_and_column() {
    let text = format!("(\n    name: \"t\",\n    data {},\n)\n", data());
    let err = parse_scene(&text, "scene.ron").unwrap_err();
    let shown = err.to_string();
    let (line, column, _) = expect_syntax(Err(err));
    assert_eq!(line, 3);
    assert_eq!(
        column, 10,
        "the column of the unexpected token after `data`"
    );
    assert!(shown.starts_with("scene.ron:3:10: "), "{shown}");
}

/// Property: an unknown top-level field (`densfy`) is reported at its own line, and the
/// message names it.
#[test]
fn unknown_top_level_field_reports_line_and_name() {
    let text = scene_with("    densfy: (),");
    let (line, column, message) = expect_syntax(parse_scene(&text, "scene.ron"));
    assert_eq!(line, 4);
    assert_eq!(column, 5);
    assert!(message.contains("densfy"), "{message}");
}

/// Property: an unknown nested field (`grad_treshold` inside `densify`) is reported at
/// its own line, and the message names it.
#[test]
fn unknown_nested_field_reports_line_and_name() {
    let text =
        scene_with("    densify: (\n        vad: true,\n        grad_treshold: 1e-4,\n    ),");
    let (line, _, message) = expect_syntax(parse_scene(&text, "scene.ron"));
    assert_eq!(line, 6);
    assert!(message.contains("grad_treshold"), "{message}");
}

/// Property: a value of the wrong type is reported at the value's line.
#[test]
fn wrong_type_reports_line() {
    let text = scene_with("    output: 12,");
    let (line, _, _) = expect_syntax(parse_scene(&text, "scene.ron"));
    assert_eq!(line, 4);
}

/// Property: a missing required field is a syntax error that names the field.
#[test]
fn missing_required_field_is_named() {
    let text = "(\n    name: \"t\",\n)\n";
    let (_, _, message) = expect_syntax(parse_scene(text, "scene.ron"));
    assert!(message.contains("data"), "{message}");
}

/// Property: an unknown enum variant is reported at its line with its name.
#[test]
fn unknown_variant_reports_line_and_name() {
    let text = scene_with(
        "    model: (\n        sh_degree: 3,\n        opacity: Gaussian,\n        phase: PerGaussian,\n        scale_motion: true,\n        tow: (enabled: true, window_frames: 50, rho: 0.75),\n    ),",
    );
    let (line, _, message) = expect_syntax(parse_scene(&text, "scene.ron"));
    assert_eq!(line, 6);
    assert!(message.contains("Gaussian"), "{message}");
}

// ---------------------------------------------------------------------------------------
// Out-of-range values: file, line, field
// ---------------------------------------------------------------------------------------

/// A `model` section with every field given and the `tow` line on line 9.
fn model_section(sh_degree: &str, rho: &str) -> String {
    format!(
        "    model: (\n        sh_degree: {sh_degree},\n        opacity: Rbf,\n        phase: PerGaussian,\n        scale_motion: true,\n        tow: (\n            enabled: true,\n            window_frames: 50,\n            rho: {rho},\n        ),\n    ),"
    )
}

/// Property: `rho: 1.5` is rejected, naming `model.tow.rho` and the line of `rho`.
#[test]
fn rho_out_of_range_reports_field_and_line() {
    let text = scene_with(&model_section("3", "1.5"));
    let err = parse_scene(&text, "scene.ron").unwrap_err();
    let shown = err.to_string();
    let (line, field, message) = expect_invalid(Err(err));
    assert_eq!(field, "model.tow.rho");
    assert_eq!(line, Some(12));
    assert!(message.contains("1.5"), "{message}");
    assert!(
        shown.starts_with("scene.ron:12: invalid value for `model.tow.rho`"),
        "{shown}"
    );
}

/// Property: `sh_degree: 7` is rejected, naming `model.sh_degree` and its line.
#[test]
fn sh_degree_out_of_range_reports_field_and_line() {
    let text = scene_with(&model_section("7", "0.75"));
    let (line, field, _) = expect_invalid(parse_scene(&text, "scene.ron"));
    assert_eq!(field, "model.sh_degree");
    assert_eq!(line, Some(5));
}

/// A `train` section with every field given and `iterations` on line 5.
fn train_section(iterations: &str, lambda_dssim: &str) -> String {
    let lr = "(position: 2.6e-4, position_final: 2.6e-6, fourier_cos_sin: 0.35, \
              fourier_phase: 0.07, temporal_scale: 0.01, opacity: 0.05, rotation: 1e-3, \
              rotation_velocity: 1e-4, scale: 1.5e-3, scale_velocity: 1.5e-4, sh_dc: 2.5e-3, \
              sh_rest_divisor: 20.0)";
    format!(
        "    train: (\n        iterations: {iterations},\n        seed: 1,\n        background: (0.0, 0.0, 0.0),\n        lambda_dssim: {lambda_dssim},\n        sh_increase_interval: 1000,\n        lr: {lr},\n        backend: Cpu,\n        eval_interval: 0,\n    ),"
    )
}

/// Property: `iterations: 0` is rejected, naming `train.iterations` and its line.
#[test]
fn zero_iterations_reports_field_and_line() {
    let text = scene_with(&train_section("0", "0.2"));
    let (line, field, _) = expect_invalid(parse_scene(&text, "scene.ron"));
    assert_eq!(field, "train.iterations");
    assert_eq!(line, Some(5));
}

/// Property: non-finite floats are rejected (`lambda_dssim: NaN`).
#[test]
fn nan_is_rejected() {
    let text = scene_with(&train_section("100", "NaN"));
    let (line, field, message) = expect_invalid(parse_scene(&text, "scene.ron"));
    assert_eq!(field, "train.lambda_dssim");
    assert_eq!(line, Some(8));
    assert!(message.contains("finite"), "{message}");
}

/// Property: a constraint broken against a defaulted field (`from_iter` after the default
/// `until_iter`) is reported at the line of the field that is written.
#[test]
fn cross_field_constraint_points_at_written_field() {
    let text = scene_with(
        "    densify: (\n        vad: true,\n        vad_min_opacity: None,\n        tat: true,\n        tat_form: Paper(beta: 0.3, alpha: 1.0),\n        grad_threshold: 2e-4,\n        percent_dense: 0.01,\n        interval: 200,\n        from_iter: 20000,\n        until_iter: 17000,\n        opacity_reset_interval: 3000,\n        prune_opacity: 0.005,\n        prune_big: false,\n        max_gaussians: 1000,\n    ),",
    );
    let (line, field, _) = expect_invalid(parse_scene(&text, "scene.ron"));
    assert_eq!(field, "densify.from_iter");
    assert_eq!(line, Some(12));
}

/// Property: out-of-range values inside enum variants are named by their dotted path.
#[test]
fn tat_form_alpha_must_be_positive() {
    let mut c = minimal_config();
    c.densify.tat_form = TatForm::Paper {
        beta: 0.3,
        alpha: 0.0,
    };
    let field = validate(&c).unwrap_err().path;
    assert_eq!(field, "densify.tat_form.alpha");
    c.densify.tat_form = TatForm::Implementation {
        beta: 1.5,
        alpha: 1.0,
    };
    let field = validate(&c).unwrap_err().path;
    assert_eq!(field, "densify.tat_form.beta");
}

/// Property: a sample of the remaining range checks each reject a bad value by name.
#[test]
fn validate_names_each_bad_field() {
    type Edit = fn(&mut SceneConfig);
    let cases: &[(&str, Edit)] = &[
        ("train.lambda_dssim", |c| c.train.lambda_dssim = 1.5),
        ("name", |c| c.name = " ".into()),
        ("output", |c| c.output = String::new()),
        ("train.lr.scale", |c| c.train.lr.scale = -1.0),
        ("train.lr.opacity", |c| c.train.lr.opacity = f32::INFINITY),
        // Learning rates that can only diverge (1e30 trained to positions at ±7e28).
        ("train.lr.position", |c| c.train.lr.position = 1e30),
        ("train.lr.sh_dc", |c| c.train.lr.sh_dc = 2.0),
        ("train.lr.fourier_phase", |c| c.train.lr.fourier_phase = 1e3),
        ("train.lr.position_final", |c| {
            c.train.lr.position_final = 1.0
        }),
        ("train.background", |c| c.train.background = [0.0, 2.0, 0.0]),
        ("model.tow.window_frames", |c| {
            c.model.tow.window_frames = 0.0
        }),
        ("densify.grad_threshold", |c| c.densify.grad_threshold = 0.0),
        ("densify.interval", |c| c.densify.interval = 0),
        ("densify.prune_opacity", |c| c.densify.prune_opacity = 1.0),
        ("densify.percent_dense", |c| c.densify.percent_dense = -0.1),
        ("densify.vad_min_opacity", |c| {
            c.densify.vad_min_opacity = Some(1.0)
        }),
        ("densify.max_gaussians", |c| c.densify.max_gaussians = 0),
        ("densify.at_cap.max_opacity", |c| {
            c.densify.at_cap = CapPolicy::Replace { max_opacity: 0.0 }
        }),
        ("init.anchor_spacing", |c| c.init.anchor_spacing = 0),
        ("init.points_per_anchor", |c| c.init.points_per_anchor = 0),
        ("init.opacity", |c| c.init.opacity = 1.0),
        ("init.lifespan_half_frames", |c| {
            c.init.lifespan_half_frames = f32::NAN
        }),
        ("train.coarse_downscale", |c| c.train.coarse_downscale = 0),
        ("train.coarse_until", |c| c.train.coarse_downscale = 2),
        ("init.background_lifespan_half_frames", |c| {
            c.init.background_lifespan_half_frames = Some(0.0)
        }),
        ("train.lr.temporal_center", |c| {
            c.train.lr.temporal_center = -1e-3
        }),
        // Learnt centres are refused on the GPU backend, which warps times with the CPU's.
        ("train.lr.temporal_center", |c| {
            c.train.lr.temporal_center = 1e-3;
            c.train.backend = tadgs::scene::BackendKind::Gpu;
        }),
        // The GPU backend's Adam steps every Gaussian.
        ("train.visible_adam", |c| {
            c.train.visible_adam = true;
            c.train.backend = tadgs::scene::BackendKind::Gpu;
        }),
        ("train.deferred_adam", |c| {
            c.train.deferred_adam = true;
            c.train.backend = tadgs::scene::BackendKind::Gpu;
        }),
        // Fused Adam does without the gradient components that the regulariser and the
        // shared motion read.
        ("train.fused_adam", |c| {
            c.train.fused_adam = true;
            c.train.motion_smoothness.weight = 0.1;
        }),
        ("model.shared_motion", |c| {
            c.train.fused_adam = true;
            c.model.shared_motion = Some(tadgs::scene::SharedMotionConfig { bases: 3, knots: 4 });
        }),
        // Two ways of skipping unseen Gaussians at once.
        ("train.deferred_adam", |c| {
            c.train.deferred_adam = true;
            c.train.visible_adam = true;
        }),
        ("train.motion_smoothness.weight", |c| {
            c.train.motion_smoothness.weight = -0.1
        }),
        ("train.motion_smoothness.neighbours", |c| {
            c.train.motion_smoothness.weight = 0.1;
            c.train.motion_smoothness.neighbours = 0;
        }),
        // The regulariser reads the motion parameters on the CPU.
        ("train.motion_smoothness.weight", |c| {
            c.train.motion_smoothness.weight = 0.1;
            c.train.backend = tadgs::scene::BackendKind::Gpu;
        }),
        ("model.shared_motion.bases", |c| {
            c.model.shared_motion = Some(tadgs::scene::SharedMotionConfig { bases: 0, knots: 8 })
        }),
        ("model.shared_motion.bases", |c| {
            c.model.shared_motion = Some(tadgs::scene::SharedMotionConfig {
                bases: 17,
                knots: 8,
            })
        }),
        ("model.shared_motion.knots", |c| {
            c.model.shared_motion = Some(tadgs::scene::SharedMotionConfig { bases: 8, knots: 1 })
        }),
        // The shared motion runs on the CPU backend only.
        ("model.shared_motion", |c| {
            c.model.shared_motion = Some(tadgs::scene::SharedMotionConfig { bases: 8, knots: 8 });
            c.train.backend = tadgs::scene::BackendKind::Gpu;
        }),
        ("train.lr.motion_bases", |c| c.train.lr.motion_bases = -1e-4),
        ("train.lr.motion_weights", |c| {
            c.train.lr.motion_weights = f32::NAN
        }),
    ];
    for (expected, edit) in cases {
        let mut c = minimal_config();
        edit(&mut c);
        let field = validate(&c).expect_err(expected).path;
        assert_eq!(&field, expected);
    }
}

/// Property: the data source's own check runs; its failure is reported under `data`,
/// at the line of the offending field inside the data section.
#[test]
fn data_source_validation_reports_data_and_inner_line() {
    let text = "(\n    name: \"t\",\n    data: Synthetic((\n        frames: 4,\n        width: 16,\n        height: 12,\n        cameras: (\n            count: 3,\n            radius: -3.0,\n            height: 1.0,\n            target: (0.0, 0.0, 0.0),\n            fov_x_degrees: 50.0,\n        ),\n        held_out: [2],\n        background: (0.0, 0.0, 0.0),\n        objects: [],\n    )),\n)\n";
    let (line, field, message) = expect_invalid(parse_scene(text, "scene.ron"));
    assert_eq!(field, "data");
    assert!(message.contains("cameras.radius"), "{message}");
    assert_eq!(line, Some(9));

    // A message naming a list element is located at that element.
    let text = text.replace("radius: -3.0", "radius: 3.0").replace(
        "held_out: [2]",
        "held_out: [\n            1,\n            7,\n        ]",
    );
    let (line, field, message) = expect_invalid(parse_scene(&text, "scene.ron"));
    assert_eq!(field, "data");
    assert!(message.contains("held_out[1]"), "{message}");
    assert_eq!(line, Some(16));
}

/// Property: newtype variants may also be written without the inner parentheses
/// throughout a file (`Synthetic(frames: 4, ...)`, `Solid(1.0, 0.0, 0.0)`), and an error
/// elsewhere in such a file is still reported at its own line rather than at the data
/// section.
#[test]
fn unwrapped_newtype_variants_are_accepted() {
    let unwrapped = SYNTHETIC.replace("Solid((1.0, 0.0, 0.0))", "Solid(1.0, 0.0, 0.0)");
    assert_ne!(unwrapped, SYNTHETIC);
    let text = format!("(\n    name: \"minimal\",\n    data: Synthetic({unwrapped}),\n)\n");
    assert_eq!(parse_scene(&text, "scene.ron").unwrap(), minimal_config());

    let text =
        format!("(\n    name: \"t\",\n    data: Synthetic({unwrapped}),\n    densfy: (),\n)\n");
    let (line, _, message) = expect_syntax(parse_scene(&text, "scene.ron"));
    assert_eq!(line, 4);
    assert!(message.contains("densfy"), "{message}");
}

// ---------------------------------------------------------------------------------------
// Overrides
// ---------------------------------------------------------------------------------------

/// Property: overrides reach top-level, nested and doubly nested fields, enums, options
/// and array elements, and change nothing else.
#[test]
fn set_override_sets_nested_fields() {
    let mut c = minimal_config();
    set_override(&mut c, "train.iterations", "3000").unwrap();
    set_override(&mut c, "densify.vad", "false").unwrap();
    set_override(&mut c, "model.tow.rho", "0.7").unwrap();
    set_override(&mut c, "output", "\"runs/x\"").unwrap();
    assert_eq!(c.train.iterations, 3000);
    assert!(!c.densify.vad);
    assert_eq!(c.model.tow.rho, 0.7);
    assert_eq!(c.output, "runs/x");

    set_override(&mut c, "output", "runs/unquoted").unwrap();
    assert_eq!(c.output, "runs/unquoted");
    set_override(&mut c, "model.opacity", "Asymmetric").unwrap();
    assert_eq!(c.model.opacity, OpacityModel::Asymmetric);
    set_override(
        &mut c,
        "densify.tat_form",
        "Implementation(beta: 0.5, alpha: 2)",
    )
    .unwrap();
    set_override(&mut c, "densify.tat_form.alpha", "3.0").unwrap();
    assert_eq!(
        c.densify.tat_form,
        TatForm::Implementation {
            beta: 0.5,
            alpha: 3.0
        }
    );
    set_override(&mut c, "densify.vad_min_opacity", "0.1").unwrap();
    assert_eq!(c.densify.vad_min_opacity, Some(0.1));
    set_override(&mut c, "train.background.1", "0.5").unwrap();
    assert_eq!(c.train.background, [0.0, 0.5, 0.0]);
    set_override(&mut c, "model.shared_motion", "Some((bases: 8, knots: 8))").unwrap();
    set_override(&mut c, "model.shared_motion.knots", "12").unwrap();
    assert_eq!(
        c.model.shared_motion,
        Some(tadgs::scene::SharedMotionConfig {
            bases: 8,
            knots: 12
        })
    );
    set_override(&mut c, "model.shared_motion", "(bases: 2, knots: 3)").unwrap();
    assert_eq!(c.model.shared_motion.map(|s| s.bases), Some(2));
    set_override(&mut c, "model.shared_motion", "None").unwrap();
    assert_eq!(c.model.shared_motion, None);
    set_override(
        &mut c,
        "model.tow",
        "(enabled: false, window_frames: 10, rho: 0.5)",
    )
    .unwrap();
    assert!(!c.model.tow.enabled);
    set_override(&mut c, "data.width", "32").unwrap();
    set_override(&mut c, "data.objects.0.spin", "1.5").unwrap();
    let DataSource::Synthetic(scene) = &c.data else {
        panic!("the demo scene is synthetic");
    };
    assert_eq!((scene.width, scene.objects[0].spin), (32, 1.5));

    // Untouched fields keep their exact values through the RON round trip.
    let d = minimal_config();
    assert_eq!(c.train.lr, d.train.lr);
    assert_eq!(c.init, d.init);
    assert_eq!(c.densify.grad_threshold, d.densify.grad_threshold);

    // Optional fields that default to None are overridable too.
    set_override(
        &mut c,
        "init.background_lifespan_half_frames",
        "Some(150.0)",
    )
    .unwrap();
    assert_eq!(c.init.background_lifespan_half_frames, Some(150.0));
    let mut panoptic = SceneConfig::new(
        "p",
        DataSource::Panoptic(tadgs::data::panoptic::PanopticSource {
            path: "capture".into(),
            frames: None,
            frame_stride: 1,
            foreground_masks: true,
            downscale: 1,
            validation_cameras: None,
            cache_mb: None,
        }),
    );
    set_override(&mut panoptic, "data.validation_cameras", "Some([5, 22])").unwrap();
    set_override(&mut panoptic, "data.cache_mb", "Some(512)").unwrap();
    let DataSource::Panoptic(source) = &panoptic.data else {
        panic!("the scene is a Panoptic capture");
    };
    assert_eq!(source.validation_cameras, Some(vec![5, 22]));
    assert_eq!(source.cache_mb, Some(512.0));
}

/// Property: an unknown key is rejected with an error naming the key (and, for a typo
/// inside a section, listing that section's fields); the config is left unchanged.
#[test]
fn set_override_rejects_unknown_keys() {
    let mut c = minimal_config();
    let before = c.clone();
    let err = set_override(&mut c, "densify.grad_treshold", "1e-4").unwrap_err();
    let shown = err.to_string();
    assert!(matches!(&err, SceneError::Override { key, .. } if key == "densify.grad_treshold"));
    assert!(shown.contains("densify.grad_treshold"), "{shown}");
    assert!(
        shown.contains("grad_threshold"),
        "lists the known fields: {shown}"
    );

    let err = set_override(&mut c, "trian.iterations", "10").unwrap_err();
    assert!(err.to_string().contains("trian"), "{err}");
    let err = set_override(&mut c, "train.iterations.x", "10").unwrap_err();
    assert!(err.to_string().contains("train.iterations"), "{err}");
    assert!(set_override(&mut c, "", "1").is_err());
    let err = set_override(&mut c, "data.frames", "1").unwrap_err();
    assert!(err.to_string().contains("frames"), "{err}");
    assert_eq!(c, before);
}

/// Property: a value of the wrong type or malformed RON is rejected clearly and leaves
/// the config unchanged.
#[test]
fn set_override_rejects_wrong_types() {
    let mut c = minimal_config();
    let before = c.clone();
    for (key, value) in [
        ("train.iterations", "true"),
        ("train.iterations", "-5"),
        ("densify.vad", "1"),
        ("model.opacity", "Gaussian"),
        ("model.tow", "(rho: 0.5"),
        ("model.tow.rho", "0.5, enabled: false"),
    ] {
        let err = set_override(&mut c, key, value).unwrap_err();
        let shown = err.to_string();
        assert!(shown.contains(key), "{shown}");
        assert!(matches!(err, SceneError::Override { .. }), "{shown}");
    }
    assert_eq!(c, before);
}

/// Property: an override producing an out-of-range value is rejected by validation,
/// naming the field; the config is left unchanged.
#[test]
fn set_override_validates() {
    let mut c = minimal_config();
    let err = set_override(&mut c, "model.tow.rho", "1.5").unwrap_err();
    assert!(err.to_string().contains("model.tow.rho"), "{err}");
    assert_eq!(c.model.tow.rho, 0.75);
}

/// Property: `apply_overrides` takes `key=value` strings and validates only the final
/// result, so orders with an inconsistent intermediate state work.
#[test]
fn apply_overrides_validates_at_the_end() {
    let mut c = minimal_config();
    apply_overrides(
        &mut c,
        &[
            "densify.until_iter=300",
            "densify.from_iter = 100",
            "output=a b",
        ],
    )
    .unwrap();
    assert_eq!((c.densify.from_iter, c.densify.until_iter), (100, 300));
    assert_eq!(c.output, "a b");
    let err =
        apply_overrides(&mut c, &["model.sh_degree=2", "densify.from_iter=1000"]).unwrap_err();
    assert!(
        matches!(&err, SceneError::Override { key, .. } if key == "densify.from_iter"),
        "the failure is attributed to the override that caused it: {err}"
    );
    assert!(apply_overrides(&mut c, &["no_equals_sign"]).is_err());
    assert_eq!(c.densify.from_iter, 100);
}

// ---------------------------------------------------------------------------------------
// Files
// ---------------------------------------------------------------------------------------

/// Property: a missing file gives the Io error, and its message names the path.
#[test]
fn missing_file_is_io_error_with_path() {
    let path = std::path::Path::new("/nonexistent/dir/scene.ron");
    let err = load_scene(path).unwrap_err();
    assert!(matches!(&err, SceneError::Io { path, .. } if path == "/nonexistent/dir/scene.ron"));
    let shown = err.to_string();
    assert!(
        shown.starts_with("cannot read scene file /nonexistent/dir/scene.ron: "),
        "{shown}"
    );
}

/// Property: `load_scene` reads a file from disk, and its errors name that file.
#[test]
fn load_scene_reads_file_and_names_it_in_errors() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.ron");
    std::fs::write(&good, minimal()).unwrap();
    assert_eq!(load_scene(&good).unwrap(), minimal_config());

    let bad = dir.path().join("bad.ron");
    std::fs::write(&bad, scene_with("    densfy: (),")).unwrap();
    let shown = load_scene(&bad).unwrap_err().to_string();
    assert!(
        shown.starts_with(&format!("{}:4:5: ", bad.display())),
        "{shown}"
    );
}

/// Property: the shipped demo scene loads and validates, and overrides reach fields
/// nested in its options and lists (`data.floor` is `Some((...))`).
#[test]
fn demo_scene_loads_and_takes_overrides() {
    let path = std::path::Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/scenes/demo.ron"));
    let mut c = load_scene(path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(c.name, "demo");
    apply_overrides(
        &mut c,
        &[
            "data.floor.half_size=3.0",
            "data.objects.1.spin=0.5",
            "train.iterations=10",
        ],
    )
    .unwrap();
    let DataSource::Synthetic(scene) = &c.data else {
        panic!("the demo scene is synthetic");
    };
    assert_eq!(scene.floor.as_ref().map(|f| f.half_size), Some(3.0));
    assert_eq!(scene.objects[1].spin, 0.5);
    assert_eq!(c.train.iterations, 10);
}

// ---------------------------------------------------------------------------------------
// Malformed-input corpus
// ---------------------------------------------------------------------------------------

/// Property: each malformed text below is a syntax error at the stated line that names
/// the problem (never a panic, never a default silently used).
#[test]
fn malformed_scene_corpus_syntax() {
    let cases: &[(&str, String, usize, &str)] = &[
        (
            "negative iterations",
            scene_with("    train: (iterations: -5),"),
            4,
            "",
        ),
        (
            "integer too large",
            scene_with("    train: (iterations: 99999999999),"),
            4,
            "",
        ),
        (
            "the Fourier term count K is not a setting",
            scene_with("    model: (fourier_terms: 0),"),
            4,
            "fourier_terms",
        ),
        (
            "duplicate field",
            scene_with("    train: (seed: 1, seed: 2),"),
            4,
            "seed",
        ),
        (
            "unclosed parenthesis (truncated file)",
            minimal().trim_end().trim_end_matches(')').to_string(),
            3, // the last line: where the text ends
            "",
        ),
        ("empty file", String::new(), 1, ""),
        (
            "string where a number belongs",
            scene_with("    model: (tow: (rho: \"high\")),"),
            4,
            "",
        ),
    ];
    for (name, text, line, needle) in cases {
        let (found, _, message) = expect_syntax(parse_scene(text, "scene.ron"));
        assert_eq!(found, *line, "case `{name}`: {message}");
        assert!(message.contains(needle), "case `{name}`: {message}");
    }
}

/// Property: each out-of-range value below is rejected, naming its dotted field and the
/// line it is written on.
#[test]
fn malformed_scene_corpus_ranges() {
    let cases: &[(&str, &str)] = &[
        ("model.tow.rho", "    model: (tow: (rho: 0.0)),"),
        ("model.tow.rho", "    model: (tow: (rho: 1.0)),"),
        ("model.tow.rho", "    model: (tow: (rho: -0.25)),"),
        (
            "model.tow.window_frames",
            "    model: (tow: (window_frames: -50.0)),",
        ),
        ("train.lambda_dssim", "    train: (lambda_dssim: -0.1),"),
        (
            "densify.tat_form.beta",
            "    densify: (tat_form: Implementation(beta: 1.5, alpha: 0.8)),",
        ),
        (
            "densify.tat_form.beta",
            "    densify: (tat_form: Paper(beta: -1.0, alpha: 1.0)),",
        ),
        ("init.opacity", "    init: (opacity: 0.0),"),
    ];
    for (field, section) in cases {
        let (line, found, message) = expect_invalid(parse_scene(&scene_with(section), "scene.ron"));
        assert_eq!(&found, field, "{section}: {message}");
        assert_eq!(line, Some(4), "{section}: {message}");
    }
}

/// Property: a scene file that is not UTF-8 is an I/O error naming the file.
#[test]
fn non_utf8_scene_file_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("binary.ron");
    std::fs::write(&path, b"(name: \"\xff\xfe\")").unwrap();
    let error = load_scene(&path).unwrap_err();
    assert!(matches!(error, SceneError::Io { .. }), "{error:?}");
    assert!(error.to_string().contains("binary.ron"), "{error}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// Property: the demo scene's text with random damage (or random bytes) never panics
    /// the parser, and every error it gives names the file.
    #[test]
    fn damaged_scene_text_never_panics(
        bytes in mutate::damaged(include_bytes!("../scenes/demo.ron").to_vec())
    ) {
        let text = String::from_utf8_lossy(&bytes);
        if let Err(error) = parse_scene(&text, "scene.ron") {
            prop_assert!(error.to_string().starts_with("scene.ron"), "{}", error);
        }
    }
}

/// A scene file's relative data path is found beside the file when it exists there (so the
/// scene works from any working directory), else stays relative to the working directory;
/// `absolute_paths` (what a run's scene.ron holds) makes it absolute; a UTF-8 byte-order mark
/// at the start of the file is accepted.
#[test]
fn relative_paths_resolve_beside_the_scene_file() {
    let dir = tempfile::tempdir().unwrap();
    let scenes = dir.path().join("scenes");
    std::fs::create_dir_all(scenes.join("mutant")).unwrap();
    let scene = |path: &str| {
        format!("\u{feff}(name: \"d\", data: DNerf((path: \"{path}\")), output: \"runs/d\")")
    };
    let file = scenes.join("beside.ron");
    std::fs::write(&file, scene("mutant")).unwrap();
    let config = load_scene(&file).unwrap();
    let DataSource::DNerf(source) = &config.data else {
        panic!("a D-NeRF scene")
    };
    assert_eq!(Path::new(&source.path), scenes.join("mutant"));

    std::fs::write(&file, scene("elsewhere/mutant")).unwrap();
    let mut config = load_scene(&file).unwrap();
    let DataSource::DNerf(source) = &config.data else {
        panic!("a D-NeRF scene")
    };
    assert_eq!(source.path, "elsewhere/mutant");
    config.absolute_paths();
    let DataSource::DNerf(source) = &config.data else {
        panic!("a D-NeRF scene")
    };
    assert_eq!(
        Path::new(&source.path),
        std::env::current_dir().unwrap().join("elsewhere/mutant")
    );
}

/// Numbers a scene file may hold that break arithmetic: huge, tiny, zero, negative, not finite.
fn extreme_number() -> impl Strategy<Value = f32> {
    prop_oneof![
        1 => Just(0.0f32),
        1 => Just(-1.0),
        1 => Just(1e20),
        1 => Just(-1e20),
        1 => Just(1e-30),
        1 => Just(f32::NAN),
        1 => Just(f32::INFINITY),
        1 => Just(f32::MAX),
        // Ordinary values most of the time, so that many cases get past validation.
        24 => 0.5f32..4.0,
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(128))]

    /// Property: a synthetic scene with extreme camera and object numbers either is refused
    /// (by validation, data generation or initialisation, as an error) or trains a step;
    /// nothing on the way panics. (A camera ring of radius 1e20 once panicked in
    /// initialisation.)
    #[test]
    fn extreme_scene_numbers_are_errors_not_panics(
        radius in extreme_number(),
        height in extreme_number(),
        target in extreme_number(),
        fov in extreme_number(),
        size in extreme_number(),
        position in extreme_number(),
    ) {
        let mut synthetic = tadgs::data::synthetic::demo_scene();
        (synthetic.frames, synthetic.width, synthetic.height, synthetic.supersample) = (3, 8, 6, 1);
        synthetic.cameras.count = 3;
        synthetic.held_out = vec![2];
        synthetic.cameras.radius = radius;
        synthetic.cameras.height = height;
        synthetic.cameras.target = [target, 0.0, 0.0];
        synthetic.cameras.fov_x_degrees = fov;
        synthetic.objects.truncate(1);
        synthetic.objects[0].shape = tadgs::data::synthetic::Shape::Sphere { radius: size };
        synthetic.objects[0].path[0].position = [position, 0.0, 0.0];
        let mut config = SceneConfig::new("extreme", DataSource::Synthetic(synthetic));
        config.init.points_per_anchor = 20;
        config.train.iterations = 2;
        if validate(&config).is_err() {
            return Ok(());
        }
        let Ok(dataset) = tadgs::data::load(&config.data) else {
            return Ok(());
        };
        let Ok(mut trainer) = tadgs::train::Trainer::try_new(&config, std::sync::Arc::new(dataset))
        else {
            return Ok(());
        };
        trainer.step();
    }
}
