//! The nerfstudio reader (`transforms.json`): a small capture written here reads back with
//! its cameras, frames and split; malformed files are refused naming the file and the field;
//! the synthetic demo written out in this layout reads back unchanged.

#[path = "common/round_trip.rs"]
mod round_trip;

use std::path::Path;

use glam::{DMat4, DVec4, Mat4};
use serde_json::{Value, json};
use tadgs::data::nerfstudio::{self, NerfstudioHeldOut, NerfstudioSource};
use tadgs::data::{Camera, DataError, Dataset};

use round_trip::{assert_same_dataset, assert_trains_alike};

/// An OpenGL camera-to-world matrix (rows) for an OpenCV world-to-camera.
fn gl_c2w_rows(world_to_camera: Mat4) -> Vec<Vec<f64>> {
    let w2c = world_to_camera.as_dmat4();
    let flip = DMat4::from_diagonal(DVec4::new(1.0, -1.0, -1.0, 1.0));
    let c2w = w2c.inverse() * flip;
    let m = c2w.transpose().to_cols_array_2d();
    m.iter().map(|row| row.to_vec()).collect()
}

/// A camera at `x` on a circle of radius 4, looking at the origin.
fn camera(angle: f32) -> Camera {
    let eye = glam::Vec3::new(4.0 * angle.cos(), 1.0, 4.0 * angle.sin());
    Camera::look_at(eye, glam::Vec3::ZERO, glam::Vec3::Y, 8, 6, 1.0)
}

fn write_png(path: &Path, width: u32, height: u32, seed: u8) {
    let img = image::RgbImage::from_fn(width, height, |x, y| {
        image::Rgb([seed.wrapping_mul(40), x as u8 * 20, y as u8 * 30])
    });
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    img.save(path).unwrap();
}

/// A dynamic capture of 2 cameras × 3 times (8×6 px), intrinsics at the top level.
fn small_capture(dir: &Path) -> Value {
    let mut frames = Vec::new();
    for c in 0..2 {
        for t in 0..3 {
            let name = format!("images/c{c}_t{t}.png");
            write_png(&dir.join(&name), 8, 6, (c * 3 + t) as u8);
            frames.push(json!({
                "file_path": name,
                "transform_matrix": gl_c2w_rows(camera(c as f32).world_to_camera),
                "time": t as f64 / 2.0,
            }));
        }
    }
    json!({
        "camera_model": "OPENCV",
        "fl_x": 7.0, "fl_y": 7.5, "cx": 4.0, "cy": 3.0, "w": 8, "h": 6,
        "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": frames,
    })
}

fn write_json(dir: &Path, value: &Value) {
    std::fs::write(
        dir.join("transforms.json"),
        serde_json::to_string_pretty(value).unwrap(),
    )
    .unwrap();
}

fn load(dir: &Path) -> Result<Dataset, DataError> {
    nerfstudio::load(&NerfstudioSource::new(dir.to_string_lossy()))
}

/// A valid capture reads as one camera per distinct pose (two), one frame per distinct time
/// (three), the intrinsics and poses as written (OpenGL → OpenCV), images byte for byte, and
/// nerfstudio's fraction split (6 images: ceil(5.4) = 6 train, none held out); explicit
/// `train_filenames`/`test_filenames` lists override it.
#[test]
fn valid_capture_reads_back_cameras_frames_and_split() {
    let dir = tempfile::tempdir().unwrap();
    let mut meta = small_capture(dir.path());
    write_json(dir.path(), &meta);
    let data = load(dir.path()).unwrap();
    assert_eq!(data.cameras.len(), 2);
    assert_eq!(data.frame_count, 3);
    assert_eq!(data.train.len(), 6);
    assert!(data.test.is_empty());
    for (c, cam) in data.cameras.iter().enumerate() {
        let expected = camera(c as f32);
        assert_eq!((cam.width, cam.height), (8, 6));
        assert_eq!((cam.fx, cam.fy, cam.cx, cam.cy), (7.0, 7.5, 4.0, 3.0));
        let diff = (cam.world_to_camera - expected.world_to_camera)
            .to_cols_array()
            .iter()
            .fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(diff < 1e-5, "camera {c}: pose differs by {diff}");
    }
    for view in &data.train {
        assert_eq!(view.time, view.frame as f32 / 2.0);
        let name = format!("images/c{}_t{}.png", view.camera, view.frame);
        let expected = image::open(dir.path().join(name)).unwrap().to_rgb8();
        assert!(view.image == expected);
        assert!(view.foreground.is_none());
    }

    // Explicit lists: camera 1 at t = 0.5 held out.
    meta["train_filenames"] = json!([
        "images/c0_t0.png",
        "images/c0_t1.png",
        "images/c0_t2.png",
        "images/c1_t0.png",
        "images/c1_t2.png"
    ]);
    meta["test_filenames"] = json!(["images/c1_t1.png"]);
    write_json(dir.path(), &meta);
    let data = load(dir.path()).unwrap();
    assert_eq!(data.train.len(), 5);
    assert_eq!(data.test.len(), 1);
    assert_eq!((data.test[0].camera, data.test[0].frame), (1, 1));
    assert_eq!(data.test[0].time, 0.5);

    // The transforms file itself may be named, and the fraction rule chosen over the lists.
    let data = nerfstudio::load(&NerfstudioSource {
        held_out: NerfstudioHeldOut::Fraction(0.5),
        ..NerfstudioSource::new(dir.path().join("transforms.json").to_string_lossy())
    })
    .unwrap();
    // n = 6, k = 3: linspace(0, 5, 3) = 0, 2.5, 5 → 0, 2, 5 in sorted path order.
    assert_eq!(data.train.len(), 3);
    assert_eq!(data.test.len(), 3);
}

/// A static capture (no `time`), per-frame intrinsics, `camera_angle_x` in place of `fl_x`,
/// no `w`/`h` (the image's size), and `downscale: 2`: one frame at time 0, a camera per
/// image, the focal from the field of view, intrinsics halved with the image.
#[test]
fn static_capture_with_field_of_view_and_downscale() {
    let dir = tempfile::tempdir().unwrap();
    let frames: Vec<Value> = (0..3)
        .map(|i| {
            let name = format!("im{i}.png");
            write_png(&dir.path().join(&name), 8, 6, i as u8);
            json!({
                "file_path": name,
                "transform_matrix": gl_c2w_rows(camera(i as f32).world_to_camera),
                "camera_angle_x": 1.0,
            })
        })
        .collect();
    write_json(dir.path(), &json!({ "frames": frames }));
    let data = nerfstudio::load(&NerfstudioSource {
        downscale: 2,
        held_out: NerfstudioHeldOut::TrainOnAll,
        ..NerfstudioSource::new(dir.path().to_string_lossy())
    })
    .unwrap();
    assert_eq!(data.frame_count, 1);
    assert_eq!(data.cameras.len(), 3);
    let focal = (0.5 * 8.0 / 0.5f64.tan()) as f32 / 2.0;
    for cam in &data.cameras {
        assert_eq!((cam.width, cam.height), (4, 3));
        assert!((cam.fx - focal).abs() < 1e-5 && (cam.fy - focal).abs() < 1e-5);
        assert_eq!((cam.cx, cam.cy), (2.0, 1.5));
    }
    assert!(data.train.iter().all(|v| v.frame == 0 && v.time == 0.0));
}

/// Every malformed capture is refused with one message that names the transforms file (or
/// the image at fault) and the offending field, with the frame index where the field is in
/// a frame: missing file, bad JSON (with line and column), NaN, missing keys, wrong matrix
/// shape, a non-rigid matrix, a missing image, an image of another size than `w`×`h`,
/// distortion, a fisheye model, a time outside [0, 1] or missing on one frame, an unknown
/// split file name and a missing point cloud.
#[test]
fn malformed_captures_name_the_file_and_field() {
    type Edit = fn(&mut Value, &Path) -> Option<String>;
    let cases: Vec<(&str, Edit, &[&str])> = vec![
        (
            "missing frames",
            |m, _| {
                m.as_object_mut().unwrap().remove("frames");
                None
            },
            &["transforms.json", "`frames`", "missing"],
        ),
        (
            "missing file_path",
            |m, _| {
                m["frames"][2].as_object_mut().unwrap().remove("file_path");
                None
            },
            &["transforms.json", "frames[2].file_path", "missing"],
        ),
        (
            "missing transform_matrix",
            |m, _| {
                m["frames"][4]
                    .as_object_mut()
                    .unwrap()
                    .remove("transform_matrix");
                None
            },
            &["transforms.json", "frames[4].transform_matrix", "missing"],
        ),
        (
            "3×4 matrix",
            |m, _| {
                m["frames"][1]["transform_matrix"]
                    .as_array_mut()
                    .unwrap()
                    .pop();
                None
            },
            &["transforms.json", "frames[1].transform_matrix", "4x4"],
        ),
        (
            "scaled rotation",
            |m, _| {
                m["frames"][3]["transform_matrix"][0][0] = json!(3.0);
                None
            },
            &[
                "transforms.json",
                "frames[3].transform_matrix",
                "orthonormal",
            ],
        ),
        (
            "no focal length",
            |m, _| {
                m.as_object_mut().unwrap().remove("fl_x");
                None
            },
            &["transforms.json", "frames[0].fl_x", "missing"],
        ),
        (
            "negative focal",
            |m, _| {
                m["frames"][5]["fl_y"] = json!(-2.0);
                None
            },
            &["transforms.json", "frames[5].fl_y", "positive"],
        ),
        (
            "distortion",
            |m, _| {
                m["k1"] = json!(0.02);
                None
            },
            &["transforms.json", "`k1`", "OPENCV", "undistort"],
        ),
        (
            "per-frame distortion_params",
            |m, _| {
                m["frames"][2]["distortion_params"] = json!([0.0, 0.0, 0.0, 0.0, 0.01, 0.0]);
                None
            },
            &[
                "transforms.json",
                "frames[2].distortion_params[4]",
                "undistort",
            ],
        ),
        (
            "fisheye",
            |m, _| {
                m["camera_model"] = json!("OPENCV_FISHEYE");
                None
            },
            &[
                "transforms.json",
                "camera_model",
                "OPENCV_FISHEYE",
                "pinhole",
            ],
        ),
        (
            "time out of range",
            |m, _| {
                m["frames"][1]["time"] = json!(1.5);
                None
            },
            &["transforms.json", "frames[1].time", "[0, 1]"],
        ),
        (
            "time on some frames only",
            |m, _| {
                m["frames"][3].as_object_mut().unwrap().remove("time");
                None
            },
            &["transforms.json", "frames[3].time", "missing"],
        ),
        (
            "missing image",
            |m, dir| {
                std::fs::remove_file(dir.join("images/c1_t1.png")).unwrap();
                let _ = m;
                None
            },
            &[
                "transforms.json",
                "frames[4].file_path",
                "c1_t1.png",
                "does not exist",
            ],
        ),
        (
            "image of another size",
            |m, _| {
                m["frames"][0]["w"] = json!(10);
                None
            },
            &["c0_t0.png", "8×6", "10×6"],
        ),
        (
            "fractional width",
            |m, _| {
                m["w"] = json!(7.5);
                None
            },
            &["transforms.json", "`w`", "whole number"],
        ),
        (
            "unknown split name",
            |m, _| {
                m["train_filenames"] = json!(["images/c0_t0.png"]);
                m["test_filenames"] = json!(["images/nope.png"]);
                None
            },
            &["transforms.json", "test_filenames[0]", "nope.png"],
        ),
        (
            "missing point cloud",
            |m, _| {
                m["ply_file_path"] = json!("sparse_pc.ply");
                None
            },
            &["transforms.json", "ply_file_path", "sparse_pc.ply"],
        ),
        (
            "wrong type",
            |_, _| Some(r#"{"frames": [{"file_path": 3}]}"#.into()),
            &["transforms.json", "invalid JSON", "line 1 column"],
        ),
        (
            "syntax error",
            |_, _| Some("{\n  \"frames\": [\n    {\"file_path\": \"a.png\",,}\n  ]\n}".into()),
            &["transforms.json", "invalid JSON", "line 3 column"],
        ),
        (
            "NaN",
            |_, _| {
                Some("{\"fl_x\": 5, \"frames\": [{\"file_path\": \"a.png\", \"transform_matrix\": [[NaN, 0, 0, 0]]}]}".into())
            },
            &["transforms.json", "invalid JSON", "non-finite"],
        ),
    ];
    assert!(cases.len() >= 8);
    for (name, edit, expected) in cases {
        let dir = tempfile::tempdir().unwrap();
        let mut meta = small_capture(dir.path());
        match edit(&mut meta, dir.path()) {
            Some(text) => std::fs::write(dir.path().join("transforms.json"), text).unwrap(),
            None => write_json(dir.path(), &meta),
        }
        let error = load(dir.path()).expect_err(name).to_string();
        assert!(!error.contains('\n'), "{name}: not one line: {error}");
        for part in expected {
            assert!(error.contains(part), "{name}: {error:?} lacks {part:?}");
        }
    }

    // A folder without transforms.json, and a path that does not exist.
    let dir = tempfile::tempdir().unwrap();
    let error = load(dir.path()).unwrap_err().to_string();
    assert!(error.contains("transforms.json") && error.contains("no transforms.json"));
    let error = load(&dir.path().join("absent")).unwrap_err().to_string();
    assert!(
        error.contains("absent") && error.contains("no such file"),
        "{error}"
    );
}

/// The synthetic demo (fewer frames, for speed) written out as a nerfstudio capture — a PNG
/// and a frame entry per view, intrinsics per frame, per-frame time, its split as
/// `train_filenames`/`test_filenames` — reads back as the same cameras (intrinsics and poses
/// to 1e-5), the same frames and times, and identical images, and trains to the same held-out
/// PSNR within 0.2 dB.
#[test]
fn demo_scene_round_trips_through_the_nerfstudio_layout() {
    let mut scene = tadgs::data::synthetic::demo_scene();
    scene.frames = 6;
    let original = scene.build().unwrap();
    let dir = tempfile::tempdir().unwrap();
    write_capture(&original, dir.path());

    let read = load(dir.path()).unwrap();
    assert_same_dataset(&original, &read);
    assert_trains_alike(&original, &read);
}

/// Writes `dataset` as a nerfstudio capture in `dir`.
fn write_capture(dataset: &Dataset, dir: &Path) {
    let mut frames = Vec::new();
    let mut lists = (Vec::new(), Vec::new());
    for (is_train, views) in [(true, &dataset.train), (false, &dataset.test)] {
        for view in views {
            let name = format!("images/c{:03}_f{:04}.png", view.camera, view.frame);
            std::fs::create_dir_all(dir.join("images")).unwrap();
            view.image.pixels().unwrap().save(dir.join(&name)).unwrap();
            let cam = dataset.cameras[view.camera];
            frames.push(json!({
                "file_path": name,
                "transform_matrix": gl_c2w_rows(cam.world_to_camera),
                "time": view.time,
                "fl_x": cam.fx, "fl_y": cam.fy, "cx": cam.cx, "cy": cam.cy,
                "w": cam.width, "h": cam.height,
            }));
            if is_train {
                lists.0.push(name);
            } else {
                lists.1.push(name);
            }
        }
    }
    write_json(
        dir,
        &json!({
            "camera_model": "PINHOLE",
            "frames": frames,
            "train_filenames": lists.0,
            "test_filenames": lists.1,
        }),
    );
}

/// The fraction split is nerfstudio's `get_train_eval_split_fraction`: NumPy's
/// `linspace(0, n − 1, ceil(f·n), dtype=int)` trains (values worked out by hand), the rest is
/// held out.
#[test]
fn fraction_split_matches_nerfstudio() {
    // n = 10: k = 9, step 9/8: 0, 1.125, 2.25, 3.375, 4.5, 5.625, 6.75, 7.875, 9.
    let (train, held) = nerfstudio::fraction_split(10, 0.9);
    assert_eq!(train, vec![0, 1, 2, 3, 4, 5, 6, 7, 9]);
    assert_eq!(held, vec![8]);
    // n = 20: k = 18, step 19/17: 8.94 → 8, then 10.06 → 10; 17.88 → 17, then 19.
    let (train, held) = nerfstudio::fraction_split(20, 0.9);
    assert_eq!(train.len(), 18);
    assert_eq!(held, vec![9, 18]);
    assert_eq!(nerfstudio::fraction_split(1, 0.9), (vec![0], vec![]));
    assert_eq!(
        nerfstudio::fraction_split(5, 1.0),
        ((0..5).collect(), vec![])
    );
}

/// `scenes/nerfstudio.ron` parses as a nerfstudio source, and an out-of-range setting is
/// reported under its `data.` path.
#[test]
fn scene_file_names_a_nerfstudio_source() {
    use tadgs::scene::{DataSource, load_scene, parse_scene};
    let path = Path::new(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/scenes/nerfstudio.ron"
    ));
    let config = load_scene(path).unwrap();
    let DataSource::Nerfstudio(source) = &config.data else {
        panic!("scenes/nerfstudio.ron is not a nerfstudio scene");
    };
    assert_eq!(source.held_out, NerfstudioHeldOut::Auto);
    assert_eq!(source.downscale, 2);
    let error = parse_scene(
        r#"(name: "n", data: Nerfstudio((path: "x", held_out: Fraction(1.5))))"#,
        "bad.ron",
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("bad.ron") && error.contains("data.held_out"),
        "{error}"
    );
}
