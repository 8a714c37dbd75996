//! LPIPS (AlexNet) against the reference values in `shared/data/lpips/reference.ron`.

use std::path::Path;
use std::time::Instant;

use serde::Deserialize;
use tadgs::io::image::Image;
use tadgs::metrics::lpips::*;

mod common;
use common::data_dir;

fn load_net(data: &Path) -> Lpips {
    Lpips::load(&data.join("lpips/alex.safetensors")).expect("load LPIPS weights")
}

/// One line of `reference.ron`.
#[derive(Debug, Deserialize)]
struct Case {
    a: String,
    b: String,
    lpips: f32,
    tol: f32,
    /// A RON list (RON reads `[f32; 5]` as a tuple, so a Vec is used and its length checked).
    layers: Vec<f32>,
}

/// RGB8 buffer (width, height, pixels) for the synthetic generators.
struct Rgb8 {
    w: usize,
    h: usize,
    px: Vec<[u8; 3]>,
}

impl Rgb8 {
    fn to_image(&self) -> Image {
        Image {
            width: self.w,
            height: self.h,
            data: self
                .px
                .iter()
                .map(|p| p.map(|v| v as f32 / 255.0))
                .collect(),
        }
    }
}

/// `gradient(w, h)` from the README: R = 255x/(w-1), G = 255y/(h-1), B = 128 (integer division).
fn gradient(w: usize, h: usize) -> Rgb8 {
    let mut px = Vec::with_capacity(w * h);
    for y in 0..h {
        for x in 0..w {
            px.push([(255 * x / (w - 1)) as u8, (255 * y / (h - 1)) as u8, 128]);
        }
    }
    Rgb8 { w, h, px }
}

/// `checker(img, cell, amp)`: ±amp on all channels by checkerboard parity, clamped to 0..=255.
fn checker(img: &Rgb8, cell: usize, amp: i32) -> Rgb8 {
    let mut px = img.px.clone();
    for y in 0..img.h {
        for x in 0..img.w {
            let d = if (x / cell + y / cell).is_multiple_of(2) {
                amp
            } else {
                -amp
            };
            let p = &mut px[y * img.w + x];
            *p = p.map(|v| (v as i32 + d).clamp(0, 255) as u8);
        }
    }
    Rgb8 {
        w: img.w,
        h: img.h,
        px,
    }
}

/// Parses `key=value` as a number.
fn arg(part: &str, key: &str) -> usize {
    let (k, v) = part
        .trim()
        .split_once('=')
        .unwrap_or_else(|| panic!("bad argument `{part}`"));
    assert_eq!(k.trim(), key, "unexpected argument `{part}`");
    v.trim()
        .parse()
        .unwrap_or_else(|_| panic!("bad number in `{part}`"))
}

/// Builds a `synthetic:` spec (`gradient(w=..,h=..)` or `checker(gradient(..),cell=..,amp=..)`).
fn synthetic(spec: &str) -> Rgb8 {
    if let Some(inner) = spec
        .strip_prefix("checker(")
        .and_then(|s| s.strip_suffix(')'))
    {
        let close = inner.find(')').expect("checker: inner gradient") + 1;
        let base = synthetic(&inner[..close]);
        let rest: Vec<&str> = inner[close..].trim_start_matches(',').split(',').collect();
        assert_eq!(rest.len(), 2, "checker needs cell and amp: {spec}");
        return checker(&base, arg(rest[0], "cell"), arg(rest[1], "amp") as i32);
    }
    if let Some(inner) = spec
        .strip_prefix("gradient(")
        .and_then(|s| s.strip_suffix(')'))
    {
        let parts: Vec<&str> = inner.split(',').collect();
        assert_eq!(parts.len(), 2, "gradient needs w and h: {spec}");
        return gradient(arg(parts[0], "w"), arg(parts[1], "h"));
    }
    panic!("unknown synthetic image `{spec}`");
}

fn input(data: &Path, name: &str) -> Image {
    match name.strip_prefix("synthetic:") {
        Some(spec) => synthetic(spec).to_image(),
        None => Image::load(&data.join(name)).unwrap_or_else(|e| panic!("{e}")),
    }
}

#[test]
fn synthetic_generators_match_readme_examples() {
    let g = gradient(64, 64);
    assert_eq!(g.px[1], [4, 0, 128]);
    let c = checker(&g, 8, 32);
    assert_eq!(c.px[8], [0, 0, 96]);
    let s = synthetic("checker(gradient(w=100,h=72),cell=5,amp=48)");
    assert_eq!((s.w, s.h), (100, 72));
}

#[test]
fn matches_reference_values() {
    let Some(data) = data_dir() else { return };
    let net = load_net(&data);
    let text = std::fs::read_to_string(data.join("lpips/reference.ron")).expect("reference.ron");
    let cases: Vec<Case> = ron::from_str(&text).expect("parse reference.ron");
    assert!(cases.len() >= 7, "expected at least 7 reference cases");
    let mut failures = Vec::new();
    for case in &cases {
        assert_eq!(
            case.layers.len(),
            5,
            "{} vs {}: five layers",
            case.a,
            case.b
        );
        let (a, b) = (input(&data, &case.a), input(&data, &case.b));
        let t = Instant::now();
        let layers = net.layer_distances(&a, &b).expect("lpips");
        let secs = t.elapsed().as_secs_f64();
        let total: f32 = layers.iter().sum();
        println!(
            "{} vs {} ({}x{}): lpips {total:.6} (ref {:.6}, diff {:.2e}) layers {layers:?} in {secs:.3} s",
            case.a,
            case.b,
            a.width,
            a.height,
            case.lpips,
            (total - case.lpips).abs()
        );
        if (total - case.lpips).abs() > case.tol {
            failures.push(format!(
                "{} vs {}: lpips {total} vs {}",
                case.a, case.b, case.lpips
            ));
        }
        for (l, (&got, &want)) in layers.iter().zip(&case.layers).enumerate() {
            if (got - want).abs() > case.tol {
                failures.push(format!(
                    "{} vs {}: layer {l} {got} vs {want}",
                    case.a, case.b
                ));
            }
        }
        let d = net.distance(&a, &b).expect("lpips");
        assert!(
            (d - total).abs() <= 1e-6,
            "distance {d} != sum of layers {total}"
        );
    }
    assert!(failures.is_empty(), "mismatches:\n{}", failures.join("\n"));
}

#[test]
fn identical_is_zero_and_symmetric() {
    let Some(data) = data_dir() else { return };
    let net = load_net(&data);
    let a = synthetic("gradient(w=64,h=48)").to_image();
    let b = synthetic("checker(gradient(w=64,h=48),cell=4,amp=40)").to_image();
    assert_eq!(net.distance(&a, &a).unwrap(), 0.0);
    assert_eq!(net.layer_distances(&b, &b).unwrap(), [0.0; 5]);
    let ab = net.distance(&a, &b).unwrap();
    let ba = net.distance(&b, &a).unwrap();
    assert!(ab > 0.0);
    assert!((ab - ba).abs() <= 1e-6 * ab.max(1.0), "{ab} vs {ba}");
}

#[test]
fn errors_are_descriptive() {
    let missing = Path::new("/nonexistent/dir/alex.safetensors");
    let err = Lpips::load(missing).unwrap_err();
    assert!(matches!(err, LpipsError::Read { .. }), "{err:?}");
    assert!(
        err.to_string()
            .contains("/nonexistent/dir/alex.safetensors"),
        "{err}"
    );

    let dir = tempfile::tempdir().unwrap();
    let junk = dir.path().join("junk.safetensors");
    std::fs::write(&junk, b"definitely not safetensors").unwrap();
    let err = Lpips::load(&junk).unwrap_err();
    assert!(matches!(err, LpipsError::Format { .. }), "{err:?}");
    assert!(err.to_string().contains("junk.safetensors"), "{err}");

    let Some(data) = data_dir() else { return };
    let net = load_net(&data);
    let a = Image::filled(64, 64, [0.5; 3]);
    let b = Image::filled(64, 48, [0.5; 3]);
    let err = net.distance(&a, &b).unwrap_err();
    assert!(matches!(err, LpipsError::SizeMismatch { .. }), "{err:?}");
    assert!(err.to_string().contains("64x64 vs 64x48"), "{err}");
    let tiny = Image::filled(20, 20, [0.5; 3]);
    let err = net.distance(&tiny, &tiny).unwrap_err();
    assert!(matches!(err, LpipsError::TooSmall { .. }), "{err:?}");
    let edge = Image::filled(MIN_SIZE, MIN_SIZE, [0.5; 3]);
    assert_eq!(net.distance(&edge, &edge).unwrap(), 0.0);
}

#[test]
fn wrong_tensors_are_reported() {
    // A file holding only a mis-shaped `features.conv0.weight`, then one with nothing useful.
    let dir = tempfile::tempdir().unwrap();
    let bad_shape = dir.path().join("bad_shape.safetensors");
    let write = |path: &Path, name: &str, shape: Vec<usize>| {
        let n: usize = shape.iter().product();
        let bytes = vec![0u8; 4 * n];
        let view =
            safetensors::tensor::TensorView::new(safetensors::Dtype::F32, shape, &bytes).unwrap();
        safetensors::serialize_to_file([(name, view)], None, path).unwrap();
    };
    write(&bad_shape, "features.conv0.weight", vec![64, 3, 11]);
    let err = Lpips::load(&bad_shape).unwrap_err();
    assert!(matches!(err, LpipsError::Shape { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains("bad_shape.safetensors"), "{msg}");
    assert!(msg.contains("features.conv0.weight"), "{msg}");
    assert!(msg.contains("[64, 3, 11, 11]"), "{msg}");

    let other = dir.path().join("other.safetensors");
    write(&other, "something.else", vec![2]);
    let err = Lpips::load(&other).unwrap_err();
    assert!(matches!(err, LpipsError::MissingTensor { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(msg.contains("other.safetensors"), "{msg}");
    assert!(msg.contains("features.conv0.weight"), "{msg}");
}
