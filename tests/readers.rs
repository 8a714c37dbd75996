//! Dataset readers: the real Panoptic and D-NeRF data read with the documented conventions,
//! and malformed files rejected with errors that name the file and the problem.

mod common;
mod mutate;

use std::path::Path;
use std::time::Instant;

use glam::{Mat4, Vec3};
use proptest::test_runner::{Config, TestRunner};
use serde_json::{Value, json};
use tadgs::data::dnerf::{self, DNerfSource};
use tadgs::data::panoptic::{self, PanopticSource};
use tadgs::data::{Camera, DataError};

/// Point that every Panoptic optical axis passes near (data README).
const RIG_FOCUS: Vec3 = Vec3::new(-0.02, -1.31, -0.02);

fn panoptic_dir() -> Option<String> {
    common::data_dir().map(|d| d.join("panoptic_basketball").to_string_lossy().into_owned())
}

fn dnerf_dir() -> Option<String> {
    common::data_dir().map(|d| d.join("dnerf_mutant").to_string_lossy().into_owned())
}

/// The full Panoptic capture reads as 27 training cameras × 150 frames and the 4 standard
/// held-out cameras, all 640×360, every camera seeing the rig focus point in front of it and
/// inside its image, with foreground masks on training views only.
#[test]
fn panoptic_full_dataset_matches_the_documented_layout() {
    let Some(dir) = panoptic_dir() else { return };
    let start = Instant::now();
    let data = panoptic::load(&PanopticSource::new(dir)).unwrap();
    println!(
        "panoptic: {} train + {} test views loaded in {:.2} s ({:.2} GB)",
        data.train.len(),
        data.test.len(),
        start.elapsed().as_secs_f64(),
        data.memory_bytes() as f64 / 1e9
    );

    let train_cameras: Vec<usize> = (1..=9).chain(11..=14).chain(16..=29).collect();
    assert_eq!(data.cameras.len(), 31);
    assert_eq!(data.frame_count, 150);
    assert_eq!(data.train_cameras(), train_cameras);
    assert_eq!(data.test_cameras(), vec![0, 10, 15, 30]);
    assert_eq!(data.train.len(), 27 * 150);
    assert_eq!(data.test.len(), 4 * 150);

    for (id, camera) in data.cameras.iter().enumerate() {
        assert_eq!((camera.width, camera.height), (640, 360), "camera {id}");
        let (u, v, z) = camera.project(RIG_FOCUS);
        assert!(z > 2.0, "camera {id}: focus point at depth {z}");
        assert!(
            (0.0..640.0).contains(&u) && (0.0..360.0).contains(&v),
            "camera {id}: focus point projects to ({u}, {v})"
        );
    }
    for view in data.train.iter().chain(&data.test) {
        assert_eq!(view.image.dimensions(), (640, 360));
        assert_eq!(view.time, data.frame_time(view.frame));
        assert!(view.dynamic_mask.is_none());
    }
    assert!(
        data.train
            .iter()
            .all(|v| v.foreground.as_ref().is_some_and(|m| m.len() == 640 * 360))
    );
    assert!(data.test.iter().all(|v| v.foreground.is_none()));

    let first = data
        .train
        .iter()
        .find(|v| v.camera == 1 && v.frame == 0)
        .unwrap();
    let mask = first.foreground.as_ref().unwrap();
    let fraction = mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64;
    assert!(
        (0.05..0.20).contains(&fraction),
        "foreground fraction {fraction}"
    );
    let last = data.test_view(30, 149).unwrap();
    assert_eq!(last.time, 1.0);
}

/// `frames: Some(3)` keeps the first three timesteps, renumbered with times 0, ½, 1.
#[test]
fn panoptic_frames_limits_timesteps() {
    let Some(dir) = panoptic_dir() else { return };
    let source = PanopticSource {
        frames: Some(3),
        ..PanopticSource::new(dir)
    };
    let data = panoptic::load(&source).unwrap();
    assert_eq!(data.frame_count, 3);
    assert_eq!(data.train.len(), 27 * 3);
    assert_eq!(data.test.len(), 4 * 3);
    let mut times: Vec<f32> = data.train.iter().map(|v| v.time).collect();
    times.dedup();
    assert_eq!(times, vec![0.0, 0.5, 1.0]);
}

/// `frame_stride` picks every k-th timestep: frame 1 of a stride-50 load is recording frame 50.
#[test]
fn panoptic_stride_picks_every_kth_timestep() {
    let Some(dir) = panoptic_dir() else { return };
    let source = PanopticSource {
        frames: Some(2),
        frame_stride: 50,
        foreground_masks: false,
        ..PanopticSource::new(dir.clone())
    };
    let data = panoptic::load(&source).unwrap();
    assert_eq!(data.frame_count, 2);
    assert!(data.train.iter().all(|v| v.foreground.is_none()));
    let view = data
        .train
        .iter()
        .find(|v| v.camera == 5 && v.frame == 1)
        .unwrap();
    let expected = image::open(Path::new(&dir).join("ims/5/000050.jpg"))
        .unwrap()
        .to_rgb8();
    assert!(*view.image.pixels().unwrap() == expected);
}

/// Downscaling by 2 halves image, mask and intrinsics together: the focus point lands at
/// half its full-resolution pixel position.
#[test]
fn panoptic_downscale_scales_intrinsics_with_images() {
    let Some(dir) = panoptic_dir() else { return };
    let full = panoptic::load(&PanopticSource {
        frames: Some(1),
        ..PanopticSource::new(dir.clone())
    })
    .unwrap();
    let half = panoptic::load(&PanopticSource {
        frames: Some(1),
        downscale: 2,
        ..PanopticSource::new(dir)
    })
    .unwrap();
    for (a, b) in full.cameras.iter().zip(&half.cameras) {
        assert_eq!((b.width, b.height), (320, 180));
        let (u, v, _) = a.project(RIG_FOCUS);
        let (uh, vh, _) = b.project(RIG_FOCUS);
        assert!((u / 2.0 - uh).abs() < 1e-3 && (v / 2.0 - vh).abs() < 1e-3);
    }
    for view in &half.train {
        assert_eq!(view.image.dimensions(), (320, 180));
        assert_eq!(view.foreground.as_ref().unwrap().len(), 320 * 180);
    }
}

/// The D-NeRF mutant reads as 150 training and 20 test views at 400×400 (half resolution),
/// every camera 4.031 from the origin and looking straight at it, times as in the files.
#[test]
fn dnerf_mutant_matches_the_documented_layout() {
    let Some(dir) = dnerf_dir() else { return };
    let start = Instant::now();
    let data = dnerf::load(&DNerfSource::new(dir.clone())).unwrap();
    println!(
        "d-nerf: {} train + {} test views loaded in {:.2} s",
        data.train.len(),
        data.test.len(),
        start.elapsed().as_secs_f64()
    );
    assert_eq!(data.train.len(), 150);
    assert_eq!(data.test.len(), 20);
    assert_eq!(data.frame_count, 150);
    assert_eq!(data.cameras.len(), 170);

    let expected_focal = 0.5 * 400.0 / (0.5f32 * 0.691_111_2).tan();
    for (i, camera) in data.cameras.iter().enumerate() {
        assert_eq!((camera.width, camera.height), (400, 400));
        assert!((camera.fx - expected_focal).abs() < 1e-2 && camera.fx == camera.fy);
        let distance = camera.center().length();
        assert!(
            (distance - 4.031).abs() < 0.01,
            "camera {i}: distance {distance}"
        );
        let (u, v, z) = camera.project(Vec3::ZERO);
        assert!(z > 0.0, "camera {i}: origin behind");
        assert!(
            (u - 200.0).abs() < 1.0 && (v - 200.0).abs() < 1.0,
            "camera {i}: ({u}, {v})"
        );
    }

    let times = |split: &str| -> Vec<f32> {
        let text =
            std::fs::read_to_string(Path::new(&dir).join(format!("transforms_{split}.json")))
                .unwrap();
        let json: Value = serde_json::from_str(&text).unwrap();
        json["frames"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["time"].as_f64().unwrap() as f32)
            .collect()
    };
    let train_times = times("train");
    for (index, view) in data.train.iter().enumerate() {
        assert_eq!(view.frame, index);
        assert_eq!(view.time, train_times[index]);
    }
    for (view, time) in data.test.iter().zip(times("test")) {
        assert_eq!(view.time, time);
        assert_eq!(view.frame, (time * 149.0).round() as usize);
    }
    for view in data.train.iter().chain(&data.test) {
        assert_eq!(view.image.dimensions(), (400, 400));
        let mask = view.foreground.as_ref().unwrap();
        let fraction = mask.iter().filter(|&&m| m).count() as f64 / mask.len() as f64;
        assert!(
            (0.01..0.9).contains(&fraction),
            "foreground fraction {fraction}"
        );
        // The corner is empty background, composited onto white.
        assert_eq!(
            view.image.pixels().unwrap().get_pixel(0, 0).0,
            [255, 255, 255]
        );
    }
}

// ---------------------------------------------------------------------------------------------
// Synthetic Panoptic datasets

const W: u32 = 8;
const H: u32 = 6;
const TRAIN_IDS: [u64; 2] = [4, 9];
const TEST_IDS: [u64; 1] = [6];
const STEPS: usize = 2;

fn synthetic_camera(id: u64) -> Camera {
    let angle = id as f32;
    let eye = Vec3::new(3.0 * angle.cos(), -1.0, 3.0 * angle.sin());
    let mut camera = Camera::look_at(eye, Vec3::ZERO, -Vec3::Y, W, H, 1.0);
    camera.fx += id as f32; // distinct intrinsics per camera
    camera.cy += 0.25;
    camera
}

fn rows(m: Mat4) -> Value {
    json!(m.transpose().to_cols_array_2d())
}

fn intrinsics(c: &Camera) -> Value {
    json!([[c.fx, 0.0, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]])
}

fn meta(ids: &[u64]) -> Value {
    let per_step = |f: &dyn Fn(u64, usize) -> Value| -> Value {
        (0..STEPS)
            .map(|t| ids.iter().map(|&id| f(id, t)).collect::<Value>())
            .collect()
    };
    json!({
        "w": W,
        "h": H,
        "k": per_step(&|id, _| intrinsics(&synthetic_camera(id))),
        "w2c": per_step(&|id, _| rows(synthetic_camera(id).world_to_camera)),
        "fn": per_step(&|id, t| json!(format!("{id}/{t:06}.png"))),
        "cam_id": per_step(&|id, _| json!(id)),
    })
}

fn write_json(path: &Path, value: &Value) {
    std::fs::write(path, serde_json::to_string_pretty(value).unwrap()).unwrap();
}

/// Saves a `width × height` image of `pixel(x, y)` at `path`, creating its folder.
fn save_image<P>(path: &Path, width: u32, height: u32, pixel: impl Fn(u32, u32) -> P)
where
    P: image::Pixel<Subpixel = u8> + image::PixelWithColorType,
{
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image::ImageBuffer::from_fn(width, height, pixel)
        .save(path)
        .unwrap();
}

fn write_image(path: &Path, width: u32, height: u32, seed: u8) {
    save_image(path, width, height, |x, y| {
        image::Rgb([seed, x as u8 * 20, y as u8 * 30])
    });
}

/// Writes a valid synthetic Panoptic dataset (train cams 4 and 9, test cam 6, two
/// timesteps, 8×6 images, a foreground mask for camera 4 only) and returns its folder.
fn synthetic_panoptic() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    write_json(&root.join("train_meta.json"), &meta(&TRAIN_IDS));
    write_json(&root.join("test_meta.json"), &meta(&TEST_IDS));
    for id in TRAIN_IDS.iter().chain(&TEST_IDS) {
        for t in 0..STEPS {
            write_image(
                &root.join(format!("ims/{id}/{t:06}.png")),
                W,
                H,
                (*id as u8) * 10 + t as u8,
            );
        }
    }
    for t in 0..STEPS {
        save_image(&root.join(format!("seg/4/{t:06}.png")), W, H, |x, _| {
            image::Luma([if x < 2 { 255 } else { 0 }])
        });
    }
    dir
}

fn source(dir: &tempfile::TempDir) -> PanopticSource {
    PanopticSource::new(dir.path().to_string_lossy().into_owned())
}

/// A small valid synthetic dataset loads with one camera per id in increasing id order,
/// intrinsics and extrinsics as written, and masks where a `seg/` file exists.
#[test]
fn synthetic_panoptic_loads_cameras_views_and_masks() {
    let dir = synthetic_panoptic();
    let data = panoptic::load(&source(&dir)).unwrap();
    assert_eq!(data.cameras.len(), 3);
    assert_eq!(data.frame_count, STEPS);
    // Ids 4, 6, 9 → indices 0, 1, 2.
    for (index, id) in [4u64, 6, 9].into_iter().enumerate() {
        let expected = synthetic_camera(id);
        let camera = data.cameras[index];
        assert_eq!((camera.width, camera.height), (W, H));
        assert!((camera.fx - expected.fx).abs() < 1e-4 && (camera.cy - expected.cy).abs() < 1e-4);
        assert!(
            camera
                .world_to_camera
                .abs_diff_eq(expected.world_to_camera, 1e-5)
        );
    }
    assert_eq!(data.train_cameras(), vec![0, 2]);
    assert_eq!(data.test_cameras(), vec![1]);
    assert_eq!(data.train.len(), 4);
    assert_eq!(data.test.len(), 2);
    let view = data
        .train
        .iter()
        .find(|v| v.camera == 2 && v.frame == 1)
        .unwrap();
    assert_eq!(view.time, 1.0);
    assert_eq!(view.image.pixels().unwrap().get_pixel(3, 2).0, [91, 60, 60]);
    assert!(view.foreground.is_none(), "camera 9 has no mask file");
    let masked = data.train.iter().find(|v| v.camera == 0).unwrap();
    let mask = masked.foreground.as_ref().unwrap();
    assert_eq!(mask.iter().filter(|&&m| m).count(), 2 * H as usize);
    assert!(mask[0] && mask[1] && !mask[2]);

    let no_masks = panoptic::load(&PanopticSource {
        foreground_masks: false,
        ..source(&dir)
    })
    .unwrap();
    assert!(no_masks.train.iter().all(|v| v.foreground.is_none()));
}

/// `validation_cameras` turns those training cameras into the evaluation set (without their
/// foreground masks) and leaves the capture's own held-out cameras out entirely; a camera that
/// is not a training camera is an error naming it.
#[test]
fn panoptic_validation_split_replaces_the_held_out_cameras() {
    let dir = synthetic_panoptic();
    let data = panoptic::load(&PanopticSource {
        validation_cameras: Some(vec![4]),
        ..source(&dir)
    })
    .unwrap();
    assert_eq!(data.train_cameras(), vec![2], "only camera 9 trains");
    assert_eq!(data.test_cameras(), vec![0], "camera 4 validates");
    assert_eq!((data.train.len(), data.test.len()), (2, 2));
    assert!(data.test.iter().all(|v| v.foreground.is_none()));
    assert!(
        data.test.iter().all(|v| v.camera != 1),
        "held-out camera 6 is not loaded"
    );

    let error = panoptic::load(&PanopticSource {
        validation_cameras: Some(vec![6]),
        ..source(&dir)
    })
    .expect_err("a held-out camera cannot validate");
    assert!(error.to_string().contains("validation camera 6"), "{error}");
    let empty = PanopticSource {
        validation_cameras: Some(vec![]),
        ..source(&dir)
    };
    assert_eq!(empty.check().unwrap_err().path, "validation_cameras");
}

/// Loads a synthetic dataset after `defect` edited it, expecting an error whose message
/// contains every one of `expected`.
fn expect_panoptic_error(defect: impl FnOnce(&Path), expected: &[&str]) -> DataError {
    let dir = synthetic_panoptic();
    defect(dir.path());
    let error = panoptic::load(&source(&dir)).expect_err("defective dataset must be rejected");
    let message = error.to_string();
    for part in expected {
        assert!(
            message.contains(part),
            "error `{message}` does not mention `{part}`"
        );
    }
    error
}

fn edit_train_meta(root: &Path, edit: impl FnOnce(&mut Value)) {
    let mut value = meta(&TRAIN_IDS);
    edit(&mut value);
    write_json(&root.join("train_meta.json"), &value);
}

/// A meta file without `k` is rejected, naming the file and the key.
#[test]
fn panoptic_missing_key_is_named() {
    expect_panoptic_error(
        |root| edit_train_meta(root, |m| drop(m.as_object_mut().unwrap().remove("k"))),
        &["train_meta.json", "`k`", "missing"],
    );
}

/// A 2×3 intrinsics matrix is rejected, naming the entry and the expected shape.
#[test]
fn panoptic_intrinsics_shape_is_checked() {
    expect_panoptic_error(
        |root| {
            edit_train_meta(root, |m| {
                m["k"][0][1] = json!([[500.0, 0.0, 4.0], [0.0, 500.0, 3.0]])
            })
        },
        &["train_meta.json", "`k[0][1]`", "3x3"],
    );
}

/// A w2c whose last row is not [0,0,0,1] is rejected.
#[test]
fn panoptic_w2c_last_row_is_checked() {
    expect_panoptic_error(
        |root| edit_train_meta(root, |m| m["w2c"][1][0][3] = json!([0.0, 0.0, 1.0, 1.0])),
        &["train_meta.json", "`w2c[1][0]`", "last row"],
    );
}

/// A w2c whose rotation block is scaled is rejected (it would silently distort geometry).
#[test]
fn panoptic_w2c_rotation_is_checked() {
    expect_panoptic_error(
        |root| {
            edit_train_meta(root, |m| {
                for r in 0..3 {
                    for c in 0..3 {
                        let v = m["w2c"][0][1][r][c].as_f64().unwrap();
                        m["w2c"][0][1][r][c] = json!(v * 1.1);
                    }
                }
            })
        },
        &["train_meta.json", "`w2c[0][1]`", "orthonormal"],
    );
}

/// An `fn` list shorter than `cam_id` in a timestep is rejected.
#[test]
fn panoptic_list_lengths_must_agree() {
    expect_panoptic_error(
        |root| edit_train_meta(root, |m| drop(m["fn"][0].as_array_mut().unwrap().pop())),
        &["train_meta.json", "`fn[0]`", "has 1"],
    );
}

/// Train and test meta files with different numbers of timesteps are rejected.
#[test]
fn panoptic_timestep_counts_must_agree() {
    expect_panoptic_error(
        |root| {
            let mut value = meta(&TEST_IDS);
            for key in ["k", "w2c", "fn", "cam_id"] {
                value[key].as_array_mut().unwrap().pop();
            }
            write_json(&root.join("test_meta.json"), &value);
        },
        &["train_meta.json has 2 timesteps", "test_meta.json has 1"],
    );
}

/// A referenced image that does not exist is named, with the meta entry pointing at it.
#[test]
fn panoptic_missing_image_is_named() {
    expect_panoptic_error(
        |root| std::fs::remove_file(root.join("ims/9/000001.png")).unwrap(),
        &[
            "train_meta.json",
            "`fn[1][1]`",
            "9/000001.png",
            "does not exist",
        ],
    );
}

/// An image whose size differs from the meta file's `w`×`h` is rejected as a size error.
#[test]
fn panoptic_wrong_image_size_is_rejected() {
    let error = expect_panoptic_error(
        |root| write_image(&root.join("ims/6/000000.png"), 5, 5, 0),
        &["6/000000.png", "5×5", "8×6"],
    );
    assert!(matches!(error, DataError::Size { .. }));
}

/// A JSON syntax error names the file, line and column.
#[test]
fn panoptic_json_syntax_error_has_position() {
    expect_panoptic_error(
        |root| std::fs::write(root.join("test_meta.json"), "{\"w\": 8,\n  \"h\": 6,,\n}").unwrap(),
        &["test_meta.json", "line 2", "column"],
    );
}

/// A camera whose matrices change between timesteps is rejected: the model has a static rig.
#[test]
fn panoptic_moving_camera_is_rejected() {
    expect_panoptic_error(
        |root| edit_train_meta(root, |m| m["k"][1][0][0][0] = json!(123.0)),
        &["train_meta.json", "`k[1][0]`", "static"],
    );
}

/// Bad source settings are rejected before reading anything.
#[test]
fn panoptic_source_settings_are_checked() {
    let dir = synthetic_panoptic();
    for (bad, field) in [
        (
            PanopticSource {
                frame_stride: 0,
                ..source(&dir)
            },
            "frame_stride",
        ),
        (
            PanopticSource {
                frames: Some(0),
                ..source(&dir)
            },
            "frames",
        ),
        (
            PanopticSource {
                downscale: 0,
                ..source(&dir)
            },
            "downscale",
        ),
    ] {
        let message = panoptic::load(&bad).unwrap_err().to_string();
        assert!(message.contains(field), "{message}");
    }
}

// ---------------------------------------------------------------------------------------------
// Synthetic D-NeRF scenes

/// A Blender camera-to-world at `eye` looking at the origin with +Z up (rows).
fn blender_pose(eye: Vec3) -> Value {
    let back = eye.normalize();
    let right = Vec3::Z.cross(back).normalize();
    let up = back.cross(right);
    let m = Mat4::from_cols(
        right.extend(0.0),
        up.extend(0.0),
        back.extend(0.0),
        eye.extend(1.0),
    );
    rows(m)
}

fn transforms(split: &str, times: &[f64]) -> Value {
    let frames: Vec<Value> = times
        .iter()
        .enumerate()
        .map(|(i, &time)| {
            let angle = i as f32;
            json!({
                "file_path": format!("./{split}/r_{i:03}"),
                "rotation": 0.1,
                "time": time,
                "transform_matrix": blender_pose(Vec3::new(2.0 * angle.cos(), 2.0 * angle.sin(), 1.0)),
            })
        })
        .collect();
    json!({ "camera_angle_x": 0.8, "frames": frames })
}

/// Writes a valid D-NeRF scene: 3 train frames (times 0, ½, 1 in shuffled order), 2 test
/// frames, 8×8 RGBA images with an opaque red left half and a transparent right half.
fn synthetic_dnerf() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    for (split, times) in [("train", &[0.5, 0.0, 1.0][..]), ("test", &[0.25, 1.0][..])] {
        write_json(
            &root.join(format!("transforms_{split}.json")),
            &transforms(split, times),
        );
        for i in 0..times.len() {
            save_image(&root.join(format!("{split}/r_{i:03}.png")), 8, 8, |x, _| {
                if x < 4 {
                    image::Rgba([255, 0, 0, 255])
                } else {
                    image::Rgba([0, 0, 255, 0])
                }
            });
        }
    }
    dir
}

fn dnerf_source(dir: &tempfile::TempDir) -> DNerfSource {
    DNerfSource::new(dir.path().to_string_lossy().into_owned())
}

/// A small valid D-NeRF scene loads: train views sorted by time, test frames rounded to the
/// nearest training frame, images composited over the background, masks from alpha.
#[test]
fn synthetic_dnerf_loads_in_time_order() {
    let dir = synthetic_dnerf();
    let data = dnerf::load(&DNerfSource {
        background: [0.0, 1.0, 0.0],
        ..dnerf_source(&dir)
    })
    .unwrap();
    assert_eq!(data.frame_count, 3);
    assert_eq!(data.cameras.len(), 5);
    let frames: Vec<(usize, f32)> = data.train.iter().map(|v| (v.frame, v.time)).collect();
    assert_eq!(frames, vec![(0, 0.0), (1, 0.5), (2, 1.0)]);
    let test: Vec<(usize, f32)> = data.test.iter().map(|v| (v.frame, v.time)).collect();
    assert_eq!(test, vec![(1, 0.25), (2, 1.0)]);
    // Train view 0 (time 0) is file r_001, whose camera sits at angle 1.
    let camera = data.cameras[data.train[0].camera];
    let eye = Vec3::new(2.0 * 1f32.cos(), 2.0 * 1f32.sin(), 1.0);
    assert!((camera.center() - eye).length() < 1e-5);
    assert_eq!((camera.width, camera.height), (4, 4));
    assert!((camera.fx - 2.0 / 0.4f32.tan()).abs() < 1e-4);
    let (u, v, z) = camera.project(Vec3::ZERO);
    assert!((u - 2.0).abs() < 1e-4 && (v - 2.0).abs() < 1e-4 && z > 0.0);
    for view in data.train.iter().chain(&data.test) {
        assert_eq!(view.image.pixels().unwrap().get_pixel(0, 0).0, [255, 0, 0]);
        assert_eq!(view.image.pixels().unwrap().get_pixel(3, 3).0, [0, 255, 0]);
        let mask = view.foreground.as_ref().unwrap();
        assert_eq!(mask, &[true, true, false, false].repeat(4));
    }
}

fn expect_dnerf_error(defect: impl FnOnce(&Path), expected: &[&str]) {
    let dir = synthetic_dnerf();
    defect(dir.path());
    let message = dnerf::load(&dnerf_source(&dir))
        .expect_err("defective scene must be rejected")
        .to_string();
    for part in expected {
        assert!(
            message.contains(part),
            "error `{message}` does not mention `{part}`"
        );
    }
}

fn edit_transforms(root: &Path, split: &str, edit: impl FnOnce(&mut Value)) {
    let path = root.join(format!("transforms_{split}.json"));
    let mut value: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut value);
    write_json(&path, &value);
}

/// A transforms file without `camera_angle_x` is rejected, naming the file and key.
#[test]
fn dnerf_missing_camera_angle_is_named() {
    expect_dnerf_error(
        |root| {
            edit_transforms(root, "train", |t| {
                drop(t.as_object_mut().unwrap().remove("camera_angle_x"))
            })
        },
        &["transforms_train.json", "`camera_angle_x`", "missing"],
    );
}

/// A 3×4 `transform_matrix` is rejected, naming the frame.
#[test]
fn dnerf_transform_matrix_shape_is_checked() {
    expect_dnerf_error(
        |root| {
            edit_transforms(root, "test", |t| {
                drop(
                    t["frames"][1]["transform_matrix"]
                        .as_array_mut()
                        .unwrap()
                        .pop(),
                )
            })
        },
        &[
            "transforms_test.json",
            "`frames[1].transform_matrix`",
            "4x4",
        ],
    );
}

/// A camera far beyond the f32 working range (translated by 1e20, in a D-NeRF file or by a
/// synthetic scene's ring radius) is an error naming the camera and the limit, not a panic
/// during initialisation.
#[test]
fn cameras_beyond_the_working_range_are_rejected() {
    let dir = synthetic_dnerf();
    edit_transforms(dir.path(), "train", |t| {
        t["frames"][2]["transform_matrix"][0][3] = json!(1e20)
    });
    let source = tadgs::scene::DataSource::DNerf(dnerf_source(&dir));
    let message = tadgs::data::load(&source).unwrap_err().to_string();
    for part in ["camera 2", "1e6", "recentre"] {
        assert!(
            message.contains(part),
            "`{message}` does not mention `{part}`"
        );
    }
    let mut demo = tadgs::data::synthetic::demo_scene();
    demo.cameras.radius = 1e20;
    let message = tadgs::data::load(&tadgs::scene::DataSource::Synthetic(demo))
        .unwrap_err()
        .to_string();
    assert!(message.contains("1e6"), "{message}");
}

/// A frame whose image is missing is rejected, naming the image.
#[test]
fn dnerf_missing_image_is_named() {
    expect_dnerf_error(
        |root| std::fs::remove_file(root.join("train/r_002.png")).unwrap(),
        &[
            "transforms_train.json",
            "`frames[2].file_path`",
            "r_002.png",
            "does not exist",
        ],
    );
}

/// A time outside [0, 1] is rejected.
#[test]
fn dnerf_time_range_is_checked() {
    expect_dnerf_error(
        |root| edit_transforms(root, "train", |t| t["frames"][0]["time"] = json!(1.5)),
        &["transforms_train.json", "`frames[0].time`", "[0, 1]"],
    );
}

/// A JSON syntax error names the file, line and column.
#[test]
fn dnerf_json_syntax_error_has_position() {
    expect_dnerf_error(
        |root| std::fs::write(root.join("transforms_train.json"), "{\n \"frames\": [}\n").unwrap(),
        &["transforms_train.json", "line 2", "column"],
    );
}

/// An unknown held-out split is rejected instead of silently evaluating on nothing.
#[test]
fn dnerf_test_split_is_checked() {
    let dir = synthetic_dnerf();
    let message = dnerf::load(&DNerfSource {
        test_split: "train".into(),
        ..dnerf_source(&dir)
    })
    .unwrap_err()
    .to_string();
    assert!(message.contains("test_split"), "{message}");
}

// ---------------------------------------------------------------------------------------------
// Malformed-input corpus: more defects of each kind, each one rejected with an error that
// names the file and the problem (never a panic).

/// A file of bytes that no image decoder accepts.
fn write_garbage(path: &Path) {
    std::fs::write(path, b"\x89PNG\r\n\x1a\n this is not really a PNG").unwrap();
}

/// A textured 8×6 JPEG cut after two thirds of its bytes.
fn write_truncated_jpeg(path: &Path) {
    let img = image::RgbImage::from_fn(W, H, |x, y| {
        image::Rgb([(x * 30) as u8, (y * 40) as u8, 99])
    });
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Jpeg).unwrap();
    let bytes = bytes.into_inner();
    std::fs::write(path, &bytes[..bytes.len() * 2 / 3]).unwrap();
}

type Defect = fn(&Path);

/// Panoptic: every defect below is rejected, and the error names the file (or entry) and
/// what is wrong with it.
#[test]
fn panoptic_malformed_corpus() {
    let cases: &[(&str, Defect, &[&str])] = &[
        (
            "corrupt image bytes",
            |root| write_garbage(&root.join("ims/6/000001.png")),
            &["cannot decode image", "6/000001.png"],
        ),
        (
            "truncated JPEG (the decoder alone would fill the rest with grey)",
            |root| write_truncated_jpeg(&root.join("ims/6/000001.png")),
            &["truncated JPEG", "6/000001.png"],
        ),
        (
            "corrupt mask bytes",
            |root| write_garbage(&root.join("seg/4/000000.png")),
            &["cannot decode image", "seg/4/000000.png"],
        ),
        (
            "mask of the wrong size",
            |root| {
                save_image(&root.join("seg/4/000001.png"), 4, 4, |_, _| {
                    image::Luma([255u8])
                })
            },
            &["seg/4/000001.png", "4×4", "8×6"],
        ),
        (
            "wrong value type",
            |root| edit_train_meta(root, |m| m["w"] = json!("eight")),
            &["train_meta.json", "invalid JSON", "line"],
        ),
        (
            "w2c of the wrong size",
            |root| edit_train_meta(root, |m| drop(m["w2c"][0][0].as_array_mut().unwrap().pop())),
            &["train_meta.json", "`w2c[0][0]`", "4x4"],
        ),
        (
            "zero focal length",
            |root| edit_train_meta(root, |m| m["k"][0][0][0][0] = json!(0.0)),
            &["train_meta.json", "`k[0][0]`", "focal"],
        ),
        (
            "zero image width",
            |root| edit_train_meta(root, |m| m["w"] = json!(0)),
            &["train_meta.json", "`w`", "positive"],
        ),
        (
            "a camera twice in one timestep",
            |root| edit_train_meta(root, |m| m["cam_id"][1][1] = json!(4)),
            &["train_meta.json", "`cam_id[1]`", "appears twice"],
        ),
        (
            "no timesteps",
            |root| {
                for name in ["train_meta.json", "test_meta.json"] {
                    let empty = json!({"w": W, "h": H, "k": [], "w2c": [], "fn": [], "cam_id": []});
                    write_json(&root.join(name), &empty);
                }
            },
            &["train_meta.json", "no timesteps"],
        ),
        (
            "missing meta file",
            |root| std::fs::remove_file(root.join("test_meta.json")).unwrap(),
            &["cannot read", "test_meta.json"],
        ),
        (
            "meta file that is not an object",
            |root| std::fs::write(root.join("train_meta.json"), "[1, 2, 3]").unwrap(),
            &["train_meta.json", "invalid JSON"],
        ),
        (
            "timestep lists of different lengths",
            |root| edit_train_meta(root, |m| drop(m["cam_id"].as_array_mut().unwrap().pop())),
            &["train_meta.json", "`cam_id`", "timesteps"],
        ),
    ];
    for (name, defect, expected) in cases {
        eprintln!("case: {name}");
        expect_panoptic_error(defect, expected);
    }
}

/// Panoptic: asking for more frames than the sequence has is an error naming both counts,
/// not a silently shorter sequence.
#[test]
fn panoptic_more_frames_than_the_sequence_is_rejected() {
    let dir = synthetic_panoptic();
    let message = panoptic::load(&PanopticSource {
        frames: Some(100),
        ..source(&dir)
    })
    .unwrap_err()
    .to_string();
    assert!(message.contains("asks for 100 frames"), "{message}");
}

/// Panoptic: a downscale that leaves no pixel of the image is refused, naming the setting
/// and the image size (rather than making 0×0 cameras).
#[test]
fn panoptic_downscale_larger_than_images_is_rejected() {
    let dir = synthetic_panoptic();
    let message = panoptic::load(&PanopticSource {
        downscale: 16,
        ..source(&dir)
    })
    .unwrap_err()
    .to_string();
    for part in ["train_meta.json", "downscale", "8×6"] {
        assert!(
            message.contains(part),
            "`{message}` does not mention `{part}`"
        );
    }
}

/// D-NeRF: every defect below is rejected, and the error names the file (or frame) and
/// what is wrong with it.
#[test]
fn dnerf_malformed_corpus() {
    let cases: &[(&str, Defect, &[&str])] = &[
        (
            "corrupt image bytes",
            |root| write_garbage(&root.join("test/r_001.png")),
            &["cannot decode image", "r_001.png"],
        ),
        (
            "image smaller than the downscale",
            |root| {
                save_image(&root.join("train/r_000.png"), 1, 1, |_, _| {
                    image::Rgba([0u8, 0, 0, 255])
                })
            },
            &["r_000.png", "1×1", "downscale by 2"],
        ),
        (
            "missing frames",
            |root| {
                edit_transforms(root, "train", |t| {
                    drop(t.as_object_mut().unwrap().remove("frames"))
                })
            },
            &["transforms_train.json", "`frames`", "missing"],
        ),
        (
            "frame without time",
            |root| {
                edit_transforms(root, "test", |t| {
                    drop(t["frames"][0].as_object_mut().unwrap().remove("time"))
                })
            },
            &["transforms_test.json", "`frames[0].time`", "missing"],
        ),
        (
            "field of view out of range",
            |root| edit_transforms(root, "train", |t| t["camera_angle_x"] = json!(4.0)),
            &["transforms_train.json", "`camera_angle_x`", "(0, π)"],
        ),
        (
            "scaled transform matrix",
            |root| {
                edit_transforms(root, "train", |t| {
                    t["frames"][1]["transform_matrix"][0][0] = json!(3.0)
                })
            },
            &[
                "transforms_train.json",
                "`frames[1].transform_matrix`",
                "orthonormal",
            ],
        ),
        (
            "no training frames",
            |root| edit_transforms(root, "train", |t| t["frames"] = json!([])),
            &["transforms_train.json", "no training frames"],
        ),
        (
            "missing transforms file",
            |root| std::fs::remove_file(root.join("transforms_test.json")).unwrap(),
            &["cannot read", "transforms_test.json"],
        ),
        (
            "wrong value type",
            |root| edit_transforms(root, "train", |t| t["frames"][0]["time"] = json!("noon")),
            &["transforms_train.json", "invalid JSON"],
        ),
    ];
    for (name, defect, expected) in cases {
        eprintln!("case: {name}");
        expect_dnerf_error(defect, expected);
    }
}

/// Runs `load` on a valid dataset whose file `name` is replaced by damaged versions of
/// itself (or random bytes), 64 times: it must never panic, and an error must name a file
/// of the dataset folder.
fn fuzz_file<T>(dir: &tempfile::TempDir, name: &str, load: impl Fn() -> Result<T, DataError>) {
    let path = dir.path().join(name);
    let valid = std::fs::read(&path).unwrap();
    let folder = dir.path().to_string_lossy().into_owned();
    let mut runner = TestRunner::new(Config::with_cases(64));
    runner
        .run(&mutate::damaged(valid), |bytes| {
            std::fs::write(&path, &bytes).unwrap();
            if let Err(error) = load() {
                let message = error.to_string();
                assert!(message.contains(&folder), "{message}");
            }
            Ok(())
        })
        .unwrap();
}

/// Damaged `train_meta.json` files never panic the Panoptic reader.
#[test]
fn damaged_panoptic_meta_never_panics() {
    let dir = synthetic_panoptic();
    fuzz_file(&dir, "train_meta.json", || panoptic::load(&source(&dir)));
}

/// Damaged `transforms_train.json` files never panic the D-NeRF reader.
#[test]
fn damaged_dnerf_transforms_never_panic() {
    let dir = synthetic_dnerf();
    fuzz_file(&dir, "transforms_train.json", || {
        dnerf::load(&dnerf_source(&dir))
    });
}

/// Damaged PNG images never panic the Panoptic reader.
#[test]
fn damaged_panoptic_image_never_panics() {
    let dir = synthetic_panoptic();
    fuzz_file(&dir, "ims/4/000000.png", || panoptic::load(&source(&dir)));
}

/// With `init.background_lifespan_half_frames`, the carved background points of a real capture
/// start with that lifespan and the hull points with `lifespan_half_frames`: on two Panoptic
/// frames (one anchor each), exactly the background share of each anchor's points gets the
/// long temporal scale (its ψ smaller, i.e. a longer life, than the hull points').
#[test]
fn panoptic_background_points_get_their_own_lifespan() {
    use tadgs::components::Temporal;
    use tadgs::scene::{DataSource, SceneConfig};
    let Some(dir) = panoptic_dir() else { return };
    let mut scene = SceneConfig::new(
        "background-lifespan",
        DataSource::Panoptic(PanopticSource {
            frames: Some(2),
            downscale: 4,
            ..PanopticSource::new(dir)
        }),
    );
    scene.init.anchor_spacing = 1;
    scene.init.points_per_anchor = 1000;
    scene.init.background_lifespan_half_frames = Some(150.0);
    let dataset = std::sync::Arc::new(tadgs::data::load(&scene.data).unwrap());
    let mut trainer = tadgs::train::Trainer::try_new(&scene, dataset).unwrap();
    let world = &mut trainer.world;
    let scales: Vec<f32> = world
        .query::<&Temporal>()
        .iter(world)
        .map(|t| t.scale[0])
        .collect();
    assert_eq!(scales.len(), 2000);
    let long = scales.iter().fold(f32::INFINITY, |a, &b| a.min(b));
    let short = scales.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b));
    assert!(long < short, "background log ψ {long} vs hull {short}");
    let background = scales.iter().filter(|&&s| s == long).count();
    let hull = scales.iter().filter(|&&s| s == short).count();
    assert_eq!(background + hull, 2000, "only the two initial lifespans");
    // The carve settings' foreground fraction is one half; background points fall short of
    // their half only where too few are photo-consistent.
    assert!(
        (200..=1000).contains(&background),
        "{background} background points"
    );
}
