//! Splat PLY files in the standard 3DGS layout: writing and reading back, the exact header,
//! importing static splats made elsewhere (SH degree 0 and 3), and per-frame export of a 4D
//! model that renders like the model itself.

use std::path::Path;
use std::sync::Arc;

use glam::Vec3;
use tadgs::data::{Camera, Dataset};
use tadgs::io::image::Image;
use tadgs::io::model::Model;
use tadgs::io::ply::{SplatCloud, StaticSplat, read_splat_ply, snapshot, write_splat_ply};
use tadgs::model::sh::{C0, SH_COEFFS};
use tadgs::resources::Settings;
use tadgs::train::Trainer;

/// `n` splats with distinct values in every field up to SH degree `degree`.
fn cloud(n: usize, degree: u32) -> SplatCloud {
    let coeffs = (degree as usize + 1).pow(2);
    let splats = (0..n)
        .map(|i| {
            let f = i as f32;
            let mut sh = [[0.0; 3]; SH_COEFFS];
            for (k, c) in sh.iter_mut().enumerate().take(coeffs) {
                *c = [0.01 * k as f32 + f, -0.02 * k as f32, 0.5 + 0.1 * f];
            }
            StaticSplat {
                mean: [f, -2.0 * f, 0.25 + f],
                sh,
                opacity_logit: -1.5 + f,
                log_scale: [-3.0, -2.5 - f, -4.0],
                rotation: [0.9, 0.1 * f, -0.2, 0.3],
            }
        })
        .collect();
    SplatCloud {
        sh_degree: degree,
        splats,
    }
}

/// The header lines of a PLY file and the length of the header in bytes.
fn header(path: &Path) -> (Vec<String>, usize) {
    let bytes = std::fs::read(path).unwrap();
    let end = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .expect("header ends")
        + 11;
    let text = String::from_utf8(bytes[..end].to_vec()).unwrap();
    (text.lines().map(String::from).collect(), end)
}

/// Property: every value written is read back bit for bit, at each SH degree 0–3.
#[test]
fn ply_round_trip_keeps_every_value() {
    let dir = tempfile::tempdir().unwrap();
    for degree in 0..=3 {
        let path = dir.path().join(format!("d{degree}.ply"));
        let written = cloud(7, degree);
        write_splat_ply(&path, &written).unwrap();
        let read = read_splat_ply(&path).unwrap();
        assert_eq!(read, written, "degree {degree}");
    }
}

/// Property: the header is exactly the standard 3DGS one (binary little endian, one vertex
/// element, float properties x y z nx ny nz f_dc_0..2 f_rest_0..44 opacity scale_0..2
/// rot_0..3 in that order) and the body is 62 floats per splat, normals zero, f_rest
/// channel-major.
#[test]
fn ply_header_is_the_standard_layout() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("splats.ply");
    let written = cloud(3, 3);
    write_splat_ply(&path, &written).unwrap();
    let (lines, length) = header(&path);
    let mut expected = vec![
        "ply".to_string(),
        "format binary_little_endian 1.0".into(),
        "element vertex 3".into(),
    ];
    let mut names: Vec<String> = vec!["x", "y", "z", "nx", "ny", "nz"]
        .into_iter()
        .map(String::from)
        .collect();
    names.extend(["f_dc_0", "f_dc_1", "f_dc_2"].map(String::from));
    names.extend((0..45).map(|i| format!("f_rest_{i}")));
    names.push("opacity".into());
    names.extend(["scale_0", "scale_1", "scale_2"].map(String::from));
    names.extend(["rot_0", "rot_1", "rot_2", "rot_3"].map(String::from));
    expected.extend(names.iter().map(|n| format!("property float {n}")));
    expected.push("end_header".into());
    assert_eq!(lines, expected);

    let bytes = std::fs::read(&path).unwrap();
    assert_eq!(bytes.len(), length + 3 * 62 * 4);
    let value = |splat: usize, property: usize| {
        let at = length + (splat * 62 + property) * 4;
        f32::from_le_bytes(bytes[at..at + 4].try_into().unwrap())
    };
    let s = &written.splats[2];
    assert_eq!(value(2, 0), s.mean[0]);
    assert_eq!([value(2, 3), value(2, 4), value(2, 5)], [0.0; 3]);
    assert_eq!(value(2, 6), s.sh[0][0]);
    // f_rest_15 is the first green coefficient above band 0: sh[1][1].
    assert_eq!(value(2, 9 + 15), s.sh[1][1]);
    // f_rest_44 is the last blue coefficient: sh[15][2].
    assert_eq!(value(2, 9 + 44), s.sh[15][2]);
    assert_eq!(value(2, 54), s.opacity_logit);
    assert_eq!(value(2, 55 + 1), s.log_scale[1]);
    assert_eq!(value(2, 58), s.rotation[0]);
}

/// A one-camera dataset looking down +z from the origin, 32×32.
fn camera() -> Camera {
    Camera::look_at(
        Vec3::ZERO,
        Vec3::new(0.0, 0.0, 1.0),
        Vec3::NEG_Y,
        32,
        32,
        1.0,
    )
}

fn render(model: &Model, time: f32) -> Image {
    let scene = model.scene("test", [0.0; 3]);
    let dataset = Dataset {
        cameras: vec![camera()],
        frame_count: model.frame_count.unwrap_or(1),
        ..Dataset::default()
    };
    let mut trainer = Trainer::from_model(&scene, Arc::new(dataset), model);
    trainer.render(&camera(), time).image
}

/// Property: an ASCII PLY at SH degree 0 as other tools write it (double-typed properties in
/// another order, no normals, an extra property) imports as time-invariant Gaussians: the
/// values land in the right fields, and the render is the same at t = 0 and t = 1 and shows
/// the DC colour where the Gaussian is opaque.
#[test]
fn static_import_at_sh_degree_0() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("static.ply");
    let dc = [0.8, -0.4, 0.1];
    let text = format!(
        "ply\nformat ascii 1.0\ncomment made elsewhere\nelement vertex 1\n\
         property double opacity\nproperty double x\nproperty double y\nproperty double z\n\
         property double rot_0\nproperty double rot_1\nproperty double rot_2\nproperty double rot_3\n\
         property double scale_0\nproperty double scale_1\nproperty double scale_2\n\
         property double f_dc_0\nproperty double f_dc_1\nproperty double f_dc_2\n\
         property uchar segment\nend_header\n\
         8.0 0.0 0.0 3.0 2.0 0.0 0.0 0.0 0.0 0.0 0.0 {} {} {} 7\n",
        dc[0], dc[1], dc[2]
    );
    std::fs::write(&path, text).unwrap();
    let cloud = read_splat_ply(&path).unwrap();
    assert_eq!(cloud.sh_degree, 0);
    let s = cloud.splats[0];
    assert_eq!(s.mean, [0.0, 0.0, 3.0]);
    assert_eq!(s.opacity_logit, 8.0);
    assert_eq!(s.rotation, [2.0, 0.0, 0.0, 0.0]);
    assert_eq!(s.sh[0], dc);

    let model = cloud.into_static_model();
    let (early, late) = (render(&model, 0.0), render(&model, 1.0));
    assert_eq!(early, late, "a static model renders the same at every time");
    // Centre pixel: colour C0·dc + 0.5 (clamped at 0) times alpha 0.99 (the 3DGS cap).
    let centre = early.get(16, 16);
    for c in 0..3 {
        let expected = (C0 * dc[c] + 0.5).max(0.0) * 0.99;
        assert!(
            (centre[c] - expected).abs() < 0.01,
            "channel {c}: {} vs {expected}",
            centre[c]
        );
    }
}

/// Property: a binary PLY at SH degree 3 with the standard header, written byte by byte here,
/// imports with every coefficient in place (f_rest channel-major) and degree 3.
#[test]
fn static_import_at_sh_degree_3() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("degree3.ply");
    let mut text = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 2\n");
    let mut names: Vec<String> = [
        "x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2",
    ]
    .map(String::from)
    .into();
    names.extend((0..45).map(|i| format!("f_rest_{i}")));
    names.extend(
        [
            "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3",
        ]
        .map(String::from),
    );
    for name in &names {
        text.push_str(&format!("property float {name}\n"));
    }
    text.push_str("end_header\n");
    let mut bytes = text.into_bytes();
    for splat in 0..2 {
        for property in 0..names.len() {
            let value = 100.0 * splat as f32 + property as f32;
            bytes.extend_from_slice(&value.to_le_bytes());
        }
    }
    std::fs::write(&path, bytes).unwrap();
    let cloud = read_splat_ply(&path).unwrap();
    assert_eq!(cloud.sh_degree, 3);
    let s = cloud.splats[1];
    assert_eq!(s.mean, [100.0, 101.0, 102.0]);
    assert_eq!(s.sh[0], [106.0, 107.0, 108.0]);
    for k in 1..16 {
        for c in 0..3 {
            // f_rest_{c·15 + k − 1} is property 9 + c·15 + k − 1.
            assert_eq!(
                s.sh[k][c],
                100.0 + (9 + c * 15 + k - 1) as f32,
                "sh[{k}][{c}]"
            );
        }
    }
    assert_eq!(s.opacity_logit, 154.0);
    assert_eq!(s.log_scale, [155.0, 156.0, 157.0]);
    assert_eq!(s.rotation, [158.0, 159.0, 160.0, 161.0]);
    let model = cloud.into_static_model();
    assert_eq!(model.sh_degree, 3);
    assert_eq!(model.gaussians[1].sh(), s.sh);
}

/// Property: files that are not splat files are refused with the file and the problem named.
#[test]
fn non_splat_ply_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points.ply");
    std::fs::write(
        &path,
        "ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
         property float z\nend_header\n0 0 0\n",
    )
    .unwrap();
    let error = read_splat_ply(&path).unwrap_err().to_string();
    assert!(
        error.contains("points.ply") && error.contains("f_dc_0"),
        "{error}"
    );

    // Ten f_rest values match no SH degree.
    let mut cloud_path_text = String::from("ply\nformat ascii 1.0\nelement vertex 0\n");
    for name in ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"] {
        cloud_path_text.push_str(&format!("property float {name}\n"));
    }
    for name in (0..3)
        .map(|i| format!("scale_{i}"))
        .chain((0..4).map(|i| format!("rot_{i}")))
    {
        cloud_path_text.push_str(&format!("property float {name}\n"));
    }
    for i in 0..10 {
        cloud_path_text.push_str(&format!("property float f_rest_{i}\n"));
    }
    cloud_path_text.push_str("end_header\n");
    let path = dir.path().join("odd.ply");
    std::fs::write(&path, cloud_path_text).unwrap();
    let error = read_splat_ply(&path).unwrap_err().to_string();
    assert!(
        error.contains("odd.ply") && error.contains("10 `f_rest_*`"),
        "{error}"
    );
}

/// Property: a 4D model exported at time t, read back and rendered as a static model gives
/// the image of the 4D model rendered at t (motion, rotation, scale and temporal opacity are
/// evaluated at t; colours stay view-dependent), and Gaussians faded out at t are left out.
#[test]
fn frame_export_renders_like_the_model_at_that_time() {
    let mut gaussians = Vec::new();
    for i in 0..40 {
        let f = i as f32;
        let mut g = tadgs::components::GaussianParams::default();
        g.position.mean = [
            0.15 * (f % 7.0) - 0.45,
            0.12 * (f % 5.0) - 0.25,
            3.0 + 0.05 * f,
        ];
        g.fourier.cos[0] = [0.1, -0.05, 0.0];
        g.fourier.sin[1] = [0.0, 0.08, 0.02];
        g.fourier.phase[0] = 0.3;
        g.temporal.center = if i % 2 == 0 { 0.2 } else { 0.9 };
        g.temporal.scale = [3.0, 0.0];
        g.opacity.logit = 1.0;
        g.rotation.c0 = [1.0, 0.1, 0.0, 0.2];
        g.rotation.c1 = [0.0, 0.5, 0.3, 0.0];
        g.scale.d0 = [-2.5, -2.8, -3.0];
        g.scale.d1 = [0.4, 0.0, -0.3];
        g.color.dc = [0.5, -0.2, 0.3 - 0.02 * f];
        g.color_rest.sh[1] = [0.1, 0.05, -0.1];
        gaussians.push(g);
    }
    let model = Model {
        gaussians,
        sh_degree: 1,
        frame_count: Some(30),
        config: Some(tadgs::scene::ModelConfig::default()),
        time_windows: None,
        shared_motion: None,
    };
    let settings = Settings::new(&model.scene("test", [0.0; 3]), 30, 1.0);
    let time = 0.3;
    let frame = snapshot(&model, &settings, time, 1.0 / 255.0);
    // Gaussians centred at 0.9 are nearly invisible at 0.3 with ψ = e³: left out.
    assert!(
        frame.splats.len() < 40 && frame.splats.len() >= 20,
        "{}",
        frame.splats.len()
    );
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("frame.ply");
    write_splat_ply(&path, &frame).unwrap();
    let imported = read_splat_ply(&path).unwrap().into_static_model();
    let (a, b) = (render(&model, time), render(&imported, 0.0));
    let max_diff = a
        .data
        .iter()
        .zip(&b.data)
        .flat_map(|(p, q)| (0..3).map(move |c| (p[c] - q[c]).abs()))
        .fold(0.0f32, f32::max);
    assert!(a.data.iter().any(|p| p[0] > 0.1), "the model is in view");
    assert!(max_diff < 2e-3, "renders differ by up to {max_diff}");
}
