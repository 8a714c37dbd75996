//! Malformed model files (`model.safetensors`): truncated, foreign or mismatched files are
//! refused with an error that names the file and the problem, never a panic. (Scene, dataset
//! and point-cloud corpora live next to their readers' tests: scene_errors.rs, readers.rs,
//! formats.rs.)

mod mutate;

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::{Dtype, TensorView};
use tadgs::components::GaussianParams;
use tadgs::io::model::{MODEL_FORMAT, MODEL_VERSION, Model};

/// Widths (f32 fields per Gaussian) of the model's tensors, in file order.
const TENSORS: [(&str, usize); 7] = [
    ("position", 3),
    ("fourier", 28),
    ("temporal", 3),
    ("opacity", 1),
    ("rotation", 8),
    ("scale", 6),
    ("color", 48),
];

/// A valid three-Gaussian model file's bytes.
fn valid_model_bytes(dir: &Path) -> Vec<u8> {
    let path = dir.join("valid.safetensors");
    let model = Model {
        gaussians: vec![GaussianParams::default(); 3],
        sh_degree: 1,
        frame_count: None,
        config: None,
        time_windows: None,
        shared_motion: None,
    };
    model.save(&path).unwrap();
    std::fs::read(path).unwrap()
}

/// A safetensors file with the given tensors (name, dtype, shape, bytes) and metadata.
fn safetensors_file(
    tensors: &[(&str, Dtype, Vec<usize>, Vec<u8>)],
    meta: &[(&str, &str)],
) -> Vec<u8> {
    let views: Vec<(&str, TensorView<'_>)> = tensors
        .iter()
        .map(|(name, dtype, shape, bytes)| {
            (
                *name,
                TensorView::new(*dtype, shape.clone(), bytes).unwrap(),
            )
        })
        .collect();
    let metadata: HashMap<String, String> = meta
        .iter()
        .map(|(k, v)| (k.to_string(), v.to_string()))
        .collect();
    safetensors::serialize(views, Some(metadata)).unwrap()
}

/// The model's tensors for `rows` Gaussians, every value `value`, with `edit` applied to the
/// list (to drop, retype or reshape one).
fn model_file(
    rows: usize,
    value: f32,
    meta: &[(&str, &str)],
    edit: impl FnOnce(&mut Vec<(&'static str, Dtype, Vec<usize>, Vec<u8>)>),
) -> Vec<u8> {
    let mut tensors: Vec<_> = TENSORS
        .iter()
        .map(|&(name, width)| {
            let bytes = value.to_le_bytes().repeat(rows * width);
            (name, Dtype::F32, vec![rows, width], bytes)
        })
        .collect();
    edit(&mut tensors);
    safetensors_file(&tensors, meta)
}

const META: [(&str, &str); 3] = [
    ("format", MODEL_FORMAT),
    ("version", MODEL_VERSION),
    ("sh_degree", "2"),
];

/// The bytes of every malformed case: (name, bytes, words the error must contain).
fn corpus(dir: &Path) -> Vec<(&'static str, Vec<u8>, Vec<&'static str>)> {
    let valid = valid_model_bytes(dir);
    let header_len = u64::from_le_bytes(valid[..8].try_into().unwrap()) as usize;
    let valid_file = |tensors_edit: fn(&mut Vec<(&'static str, Dtype, Vec<usize>, Vec<u8>)>)| {
        model_file(3, 0.5, &META, tensors_edit)
    };
    vec![
        ("empty file", Vec::new(), vec!["not a valid safetensors"]),
        (
            "only the header length",
            valid[..8].to_vec(),
            vec!["not a valid safetensors"],
        ),
        (
            "cut inside the header",
            valid[..8 + header_len / 2].to_vec(),
            vec!["not a valid safetensors"],
        ),
        (
            "cut inside the data",
            valid[..valid.len() - 100].to_vec(),
            vec!["not a valid safetensors"],
        ),
        (
            "header length larger than the file",
            [&u64::MAX.to_le_bytes()[..], &valid[8..]].concat(),
            vec!["not a valid safetensors"],
        ),
        (
            "header that is not JSON",
            [&16u64.to_le_bytes()[..], b"this is not json"].concat(),
            vec!["not a valid safetensors"],
        ),
        (
            "not a tadgs model (foreign metadata)",
            model_file(3, 0.5, &[("format", "pt")], |_| {}),
            vec!["metadata `format`"],
        ),
        (
            "a newer layout version",
            model_file(
                3,
                0.5,
                &[
                    ("format", MODEL_FORMAT),
                    ("version", "99"),
                    ("sh_degree", "1"),
                ],
                |_| {},
            ),
            vec!["metadata `version`", "99"],
        ),
        (
            "SH degree out of range",
            model_file(
                3,
                0.5,
                &[
                    ("format", MODEL_FORMAT),
                    ("version", MODEL_VERSION),
                    ("sh_degree", "7"),
                ],
                |_| {},
            ),
            vec!["sh_degree", "0..=3"],
        ),
        (
            "a frame count no sequence has (exports of every frame would never end)",
            model_file(
                3,
                0.5,
                &[
                    ("format", MODEL_FORMAT),
                    ("version", MODEL_VERSION),
                    ("sh_degree", "0"),
                    ("frame_count", "99999999999999"),
                ],
                |_| {},
            ),
            vec!["frame_count", "1000000"],
        ),
        (
            "a tensor missing",
            valid_file(|t| drop(t.pop())),
            vec!["`color`", "missing"],
        ),
        (
            "a tensor of the wrong dtype",
            valid_file(|t| {
                t[3].1 = Dtype::F64;
                t[3].2 = vec![3, 1];
                t[3].3 = vec![0; 3 * 8];
            }),
            vec!["`opacity`", "F64"],
        ),
        (
            "tensors of different lengths",
            valid_file(|t| {
                t[4].2 = vec![2, 8];
                t[4].3.truncate(2 * 8 * 4);
            }),
            vec!["`rotation`", "[2, 8]", "[3, 8]"],
        ),
        (
            "a tensor of the wrong width",
            valid_file(|t| {
                t[0].2 = vec![3, 4];
                t[0].3 = vec![0; 3 * 4 * 4];
            }),
            vec!["`position`", "[3, 4]"],
        ),
        (
            "a one-dimensional tensor",
            valid_file(|t| t[2].2 = vec![9]),
            vec!["`temporal`", "[9]"],
        ),
        (
            "NaN parameters",
            model_file(3, f32::NAN, &META, |_| {}),
            vec!["`position`", "NaN"],
        ),
    ]
}

/// Every malformed model file is refused with an error naming the file and containing the
/// words that say what is wrong; a missing file names the file too.
#[test]
fn malformed_model_files_are_named_errors() {
    let dir = tempfile::tempdir().unwrap();
    let cases = corpus(dir.path());
    assert!(cases.len() >= 15);
    for (index, (name, bytes, needles)) in cases.into_iter().enumerate() {
        let file = format!("case{index}.safetensors");
        let path = dir.path().join(&file);
        std::fs::write(&path, &bytes).unwrap();
        let message = match Model::load(&path) {
            Ok(_) => panic!("case `{name}` was accepted"),
            Err(error) => error.to_string(),
        };
        assert!(message.contains(&file), "case `{name}`: {message}");
        for needle in needles {
            assert!(
                message.contains(needle),
                "case `{name}` lacks `{needle}`: {message}"
            );
        }
    }
    let missing = dir.path().join("absent.safetensors");
    let message = Model::load(&missing).unwrap_err().to_string();
    assert!(message.contains("absent.safetensors") && message.contains("cannot read"));
}

/// The test's own builder makes files the reader accepts, so the cases above fail for the
/// defect each one adds and not for a mistake in the builder.
#[test]
fn corpus_builder_makes_valid_models() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("built.safetensors");
    std::fs::write(&path, model_file(3, 0.5, &META, |_| {})).unwrap();
    let model = Model::load(&path).unwrap();
    assert_eq!((model.gaussians.len(), model.sh_degree), (3, 2));
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(128))]

    /// Damaged model files (or random bytes) never panic the reader; an error names the file.
    #[test]
    fn damaged_model_files_never_panic(bytes in mutate::damaged(model_file(4, 0.25, &META, |_| {}))) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("damaged.safetensors");
        std::fs::write(&path, &bytes).unwrap();
        if let Err(error) = Model::load(&path) {
            proptest::prop_assert!(error.to_string().contains("damaged.safetensors"), "{}", error);
        }
    }
}
