//! COLMAP-calibrated videos: per-frame `colmap_<frame>/` folders (`ColmapFrames`) and a rig
//! model with per-camera frame folders (`ColmapRig`). Small layouts written here read back
//! with their cameras, frames, split and per-anchor points; malformed ones are refused naming
//! the file and the field; the synthetic demo round-trips through both layouts; distorted
//! cameras are undistorted exactly as COLMAP's models say.

#[path = "common/round_trip.rs"]
mod round_trip;

use std::path::Path;
use std::sync::Arc;

use glam::{DMat3, DQuat, Mat4, Vec3};
use image::RgbImage;
use tadgs::components::{Position, Temporal};
use tadgs::data::colmap_video::{self, ColmapSource};
use tadgs::data::undistort::{Distortion, Undistortion};
use tadgs::data::{Camera, DataError, Dataset};

use round_trip::{assert_same_dataset, assert_trains_alike, camera_difference};

// ---------------------------------------------------------------------------------------
// Writing COLMAP models (text and binary, as COLMAP does)
// ---------------------------------------------------------------------------------------

/// COLMAP's camera model names in the order of their binary ids (any other name is written as
/// the unknown id 99).
const MODEL_IDS: [&str; 7] = [
    "SIMPLE_PINHOLE",
    "PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
    "OPENCV_FISHEYE",
    "FULL_OPENCV",
];

/// A sparse model: per registered image its name, camera model, parameters and
/// world-to-camera pose (each image has its own camera, id = index + 1), and the 3D points.
#[derive(Clone)]
struct Model {
    images: Vec<ModelImage>,
    points: Vec<([f64; 3], [u8; 3])>,
}

#[derive(Clone)]
struct ModelImage {
    name: String,
    model: &'static str,
    size: (u32, u32),
    params: Vec<f64>,
    pose: Mat4,
}

impl ModelImage {
    /// A PINHOLE image of `camera` named `name`.
    fn pinhole(name: impl Into<String>, camera: &Camera) -> Self {
        Self {
            name: name.into(),
            model: "PINHOLE",
            size: (camera.width, camera.height),
            params: [camera.fx, camera.fy, camera.cx, camera.cy]
                .map(f64::from)
                .to_vec(),
            pose: camera.world_to_camera,
        }
    }

    /// COLMAP's quaternion (w, x, y, z) and translation of the pose.
    fn qvec_tvec(&self) -> ([f64; 4], [f64; 3]) {
        let m = self.pose.as_dmat4();
        let q = DQuat::from_mat3(&DMat3::from_mat4(m)).normalize();
        ([q.w, q.x, q.y, q.z], m.w_axis.truncate().to_array())
    }
}

/// A model of `cameras` named `cam00`, `cam01`, … with `points`.
fn rig_model(cameras: &[Camera], points: Vec<([f64; 3], [u8; 3])>) -> Model {
    let images = cameras
        .iter()
        .enumerate()
        .map(|(i, c)| ModelImage::pinhole(format!("cam{i:02}.png"), c))
        .collect();
    Model { images, points }
}

fn joined(values: &[f64]) -> String {
    values
        .iter()
        .map(f64::to_string)
        .collect::<Vec<_>>()
        .join(" ")
}

fn write_text_model(dir: &Path, model: &Model) {
    std::fs::create_dir_all(dir).unwrap();
    let mut cameras = String::from("# Camera list with one line of data per camera:\n");
    let mut images = String::from("# Image list with two lines of data per image:\n");
    for (i, image) in model.images.iter().enumerate() {
        let id = i + 1;
        let (width, height) = image.size;
        cameras += &format!(
            "{id} {} {width} {height} {}\n",
            image.model,
            joined(&image.params)
        );
        let (q, t) = image.qvec_tvec();
        images += &format!("{id} {} {} {id} {}\n\n", joined(&q), joined(&t), image.name);
    }
    let mut points = String::from("# 3D point list\n");
    for (i, (xyz, [r, g, b])) in model.points.iter().enumerate() {
        points += &format!("{} {} {r} {g} {b} 0.5\n", i + 1, joined(xyz));
    }
    std::fs::write(dir.join("cameras.txt"), cameras).unwrap();
    std::fs::write(dir.join("images.txt"), images).unwrap();
    std::fs::write(dir.join("points3D.txt"), points).unwrap();
}

/// Little-endian bytes of COLMAP's binary files.
#[derive(Default)]
struct Bytes(Vec<u8>);

impl Bytes {
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend(v.to_le_bytes());
        self
    }
    fn f64s(&mut self, values: &[f64]) -> &mut Self {
        values.iter().for_each(|v| self.0.extend(v.to_le_bytes()));
        self
    }
}

fn write_binary_model(dir: &Path, model: &Model) {
    std::fs::create_dir_all(dir).unwrap();
    let (mut cameras, mut images, mut points) =
        (Bytes::default(), Bytes::default(), Bytes::default());
    cameras.u64(model.images.len() as u64);
    images.u64(model.images.len() as u64);
    for (i, image) in model.images.iter().enumerate() {
        let id = i as u32 + 1;
        let model_id = MODEL_IDS
            .iter()
            .position(|m| *m == image.model)
            .unwrap_or(99) as u32;
        cameras.u32(id).u32(model_id);
        cameras.u64(image.size.0.into()).u64(image.size.1.into());
        cameras.f64s(&image.params);
        let (q, t) = image.qvec_tvec();
        images.u32(id).f64s(&q).f64s(&t).u32(id);
        images.0.extend(image.name.as_bytes());
        images.0.push(0);
        images.u64(0);
    }
    points.u64(model.points.len() as u64);
    for (i, (xyz, rgb)) in model.points.iter().enumerate() {
        points.u64(i as u64 + 1).f64s(xyz);
        points.0.extend(rgb);
        points.f64s(&[0.5]).u64(0);
    }
    std::fs::write(dir.join("cameras.bin"), cameras.0).unwrap();
    std::fs::write(dir.join("images.bin"), images.0).unwrap();
    std::fs::write(dir.join("points3D.bin"), points.0).unwrap();
}

// ---------------------------------------------------------------------------------------
// Small layouts: 3 cameras (cam00 … cam02) of 8×6 px, 4 frames
// ---------------------------------------------------------------------------------------

const CAMERAS: usize = 3;
const FRAMES: usize = 4;

/// A camera on a circle of radius 4, looking at the origin.
fn camera(index: usize) -> Camera {
    let angle = index as f32 * 0.7;
    let eye = Vec3::new(4.0 * angle.cos(), 1.0, 4.0 * angle.sin());
    let mut camera = Camera::look_at(eye, Vec3::ZERO, Vec3::Y, 8, 6, 1.0);
    camera.fy = camera.fx * 1.05;
    camera.cx = 4.25;
    camera
}

fn cameras() -> Vec<Camera> {
    (0..CAMERAS).map(camera).collect()
}

/// The image camera `c` sees at frame `f`.
fn image(c: usize, f: usize, (width, height): (u32, u32)) -> RgbImage {
    RgbImage::from_fn(width, height, |x, y| {
        image::Rgb([(c * 60 + f * 10) as u8, x as u8 * 20, y as u8 * 30])
    })
}

fn save(path: &Path, image: &RgbImage) {
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    image.save(path).unwrap();
}

/// The points of frame `f`'s model: `f + 3` of them, distinct per frame.
fn points(f: usize) -> Vec<([f64; 3], [u8; 3])> {
    (0..f + 3)
        .map(|i| {
            (
                [i as f64 * 0.25, f as f64, -0.5],
                [10 * i as u8, 200, f as u8],
            )
        })
        .collect()
}

/// `colmap_0` … `colmap_3` with images, a text model in `colmap_0` and a binary one in
/// `colmap_2`.
fn write_frames_layout(dir: &Path) {
    for f in 0..FRAMES {
        for c in 0..CAMERAS {
            let path = dir.join(format!("colmap_{f}/images/cam{c:02}.png"));
            save(&path, &image(c, f, (8, 6)));
        }
    }
    write_text_model(
        &dir.join("colmap_0/sparse/0"),
        &rig_model(&cameras(), points(0)),
    );
    write_binary_model(
        &dir.join("colmap_2/sparse/0"),
        &rig_model(&cameras(), points(2)),
    );
}

/// A binary model in `sparse/0` and `frames/camXX/00000f.png`.
fn write_rig_layout(dir: &Path) {
    write_binary_model(&dir.join("sparse/0"), &rig_model(&cameras(), points(0)));
    for c in 0..CAMERAS {
        for f in 0..FRAMES {
            let path = dir.join(format!("frames/cam{c:02}/{f:06}.png"));
            save(&path, &image(c, f, (8, 6)));
        }
    }
}

fn source(dir: &Path) -> ColmapSource {
    ColmapSource::new(dir.to_string_lossy())
}

/// The small layout's cameras, frames, split (cam00 held out) and images read back.
fn check_small(data: &Dataset) {
    assert_eq!(data.cameras.len(), CAMERAS);
    assert_eq!(data.frame_count, FRAMES);
    for (c, cam) in data.cameras.iter().enumerate() {
        let diff = camera_difference(cam, &camera(c));
        assert!(diff < 1e-5, "camera {c} differs by {diff}");
    }
    assert_eq!(data.test_cameras(), vec![0]);
    assert_eq!(data.train.len(), (CAMERAS - 1) * FRAMES);
    assert_eq!(data.test.len(), FRAMES);
    for view in data.train.iter().chain(&data.test) {
        assert_eq!(view.time, view.frame as f32 / (FRAMES - 1) as f32);
        assert!(view.image == image(view.camera, view.frame, (8, 6)));
    }
}

fn assert_points(found: &[tadgs::init::InitPoint], expected: &[([f64; 3], [u8; 3])]) {
    assert_eq!(found.len(), expected.len());
    for (p, (xyz, rgb)) in found.iter().zip(expected) {
        assert!(
            p.position
                .abs_diff_eq(Vec3::from_array(xyz.map(|v| v as f32)), 1e-6)
        );
        assert_eq!(p.color, rgb.map(|c| f32::from(c) / 255.0));
    }
}

/// Per-frame folders read back as 3 cameras × 4 frames with cam00 held out, and the points of
/// frames 0 and 2 (text and binary models) as those frames' clouds, a dense cloud where there
/// is one; `frames` limits the sequence and its clouds, `downscale` halves images and
/// intrinsics.
#[test]
fn per_frame_folders_read_back_cameras_frames_and_anchor_points() {
    let dir = tempfile::tempdir().unwrap();
    write_frames_layout(dir.path());
    let data = colmap_video::load_frames(&source(dir.path())).unwrap();
    check_small(&data);
    assert!(data.points.is_none());
    let frames: Vec<usize> = data.frame_points.iter().map(|(f, _)| *f).collect();
    assert_eq!(frames, [0, 2]);
    assert_points(&data.frame_points[0].1, &points(0));
    assert_points(&data.frame_points[1].1, &points(2));
    assert_eq!(data.nearest_frame_points(1).unwrap().0, 0);
    assert_eq!(data.nearest_frame_points(3).unwrap().0, 2);

    // A dense cloud left by the authors' `--pointcloud dense` replaces that frame's points.
    let dense = vec![tadgs::init::InitPoint {
        position: Vec3::new(0.5, -1.0, 2.0),
        color: [1.0, 0.0, 0.0],
    }];
    let ply = dir
        .path()
        .join("colmap_2/dense/workspace/fused_downsample.ply");
    std::fs::create_dir_all(ply.parent().unwrap()).unwrap();
    tadgs::data::pointcloud::write_point_cloud_ply(&ply, &dense).unwrap();
    let data = colmap_video::load_frames(&source(dir.path())).unwrap();
    assert_eq!(data.frame_points[1], (2, dense));

    let data = colmap_video::load_frames(&ColmapSource {
        frames: Some(2),
        downscale: 2,
        test_cameras: vec!["cam02".into()],
        ..source(dir.path())
    })
    .unwrap();
    assert_eq!(data.frame_count, 2);
    assert_eq!(data.test_cameras(), vec![2]);
    assert_eq!(data.frame_points.len(), 1);
    let expected = camera(1).downscaled(2);
    assert!(camera_difference(&data.cameras[1], &expected) < 1e-5);
    assert_eq!(data.train[0].image.dimensions(), (4, 3));
}

/// `init.method: Auto` starts each anchor frame from the nearest frame's COLMAP points: with
/// anchors 0, 2 and 3, frames 0 and 2 their own clouds and frame 3 that of frame 2.
#[test]
fn anchor_frames_start_from_their_frame_points() {
    use tadgs::scene::{DataSource, SceneConfig};
    let dir = tempfile::tempdir().unwrap();
    write_frames_layout(dir.path());
    let source = source(dir.path());
    let data = colmap_video::load_frames(&source).unwrap();
    let mut scene = SceneConfig::new("colmap", DataSource::ColmapFrames(source));
    scene.init.anchor_spacing = 2;
    let mut trainer = tadgs::train::Trainer::new(&scene, Arc::new(data));
    let mut query = trainer.world.query::<(&Position, &Temporal)>();
    for (frame, cloud) in [(0, 0), (2, 2), (3, 2)] {
        let time = frame as f32 / (FRAMES - 1) as f32;
        let mut found: Vec<[f32; 3]> = query
            .iter(&trainer.world)
            .filter(|(_, t)| (t.center - time).abs() < 1e-6)
            .map(|(p, _)| p.mean)
            .collect();
        found.sort_by(|a, b| a[0].total_cmp(&b[0]));
        let expected: Vec<[f32; 3]> = points(cloud)
            .iter()
            .map(|(xyz, _)| xyz.map(|v| v as f32))
            .collect();
        assert_eq!(found, expected, "anchor frame {frame}");
    }
    assert_eq!(trainer.gaussian_count(), 3 + 5 + 5);
}

/// A rig model with frame folders reads back the same way, the model's points as the cloud
/// of every anchor; a camera without a folder is read from `<camera>.mp4` when ffmpeg is
/// there.
#[test]
fn rig_model_with_frame_folders_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    write_rig_layout(dir.path());
    let data = colmap_video::load_rig(&source(dir.path())).unwrap();
    check_small(&data);
    assert!(data.frame_points.is_empty());
    assert_points(data.points.as_ref().unwrap(), &points(0));

    // Images named in folders (`cam01/000000.png`) name their camera by the folder.
    let mut model = rig_model(&cameras(), points(0));
    for (i, image) in model.images.iter_mut().enumerate() {
        image.name = format!("cam{i:02}/000000.png");
    }
    write_binary_model(&dir.path().join("sparse/0"), &model);
    check_small(&colmap_video::load_rig(&source(dir.path())).unwrap());
    assert_eq!(colmap_video::camera_name("cam07/000000.png"), "cam07");
    assert_eq!(colmap_video::camera_name("cam07.jpg"), "cam07");
}

// ---------------------------------------------------------------------------------------
// Malformed layouts
// ---------------------------------------------------------------------------------------

/// Each case edits a valid layout (files and settings); loading must fail with one line
/// holding every expected part.
type Case = (
    &'static str,
    fn(&Path, &mut ColmapSource),
    &'static [&'static str],
);

fn check_cases(
    cases: Vec<Case>,
    write: fn(&Path),
    load: fn(&ColmapSource) -> Result<Dataset, DataError>,
) {
    assert!(cases.len() >= 8);
    for (name, edit, expected) in cases {
        let dir = tempfile::tempdir().unwrap();
        write(dir.path());
        let mut source = source(dir.path());
        edit(dir.path(), &mut source);
        let error = load(&source).expect_err(name).to_string();
        assert!(!error.contains('\n'), "{name}: not one line: {error}");
        for part in expected {
            assert!(error.contains(part), "{name}: {error:?} lacks {part:?}");
        }
    }
}

/// Replaces line `line` (1-based) of a text file.
fn replace_line(path: &Path, line: usize, text: &str) {
    let content = std::fs::read_to_string(path).unwrap();
    let mut lines: Vec<&str> = content.lines().collect();
    lines[line - 1] = text;
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

fn remove(path: &Path) {
    if path.is_dir() {
        std::fs::remove_dir_all(path).unwrap();
    } else {
        std::fs::remove_file(path).unwrap();
    }
}

/// A model of the small rig at `frame` (binary, in `colmap_<frame>/sparse/0`) after `edit`.
fn rewrite_frame_model(dir: &Path, frame: usize, edit: fn(&mut Model)) {
    let mut model = rig_model(&cameras(), points(frame));
    edit(&mut model);
    write_binary_model(&dir.join(format!("colmap_{frame}/sparse/0")), &model);
}

/// Per-frame folders that are missing, out of order, without a model, without an image,
/// with a camera missing, added or moved in one frame's model, with an unknown or fisheye
/// camera model, a malformed number, an image of the wrong size, a truncated binary file, an
/// unknown held-out camera, or fewer frames than asked for.
#[test]
fn malformed_per_frame_folders_name_the_file_and_field() {
    let cases: Vec<Case> = vec![
        (
            "missing folder",
            |dir, s| s.path = dir.join("absent").to_string_lossy().into(),
            &["absent", "no such folder"],
        ),
        (
            "no frame folders",
            |dir, s| {
                std::fs::create_dir(dir.join("empty")).unwrap();
                s.path = dir.join("empty").to_string_lossy().into();
            },
            &["empty", "no frame folders colmap_<frame>"],
        ),
        (
            "gap in the frames",
            |dir, _| remove(&dir.join("colmap_1")),
            &["colmap_0 and colmap_2", "not consecutive"],
        ),
        (
            "no model",
            |dir, _| {
                remove(&dir.join("colmap_0/sparse"));
                remove(&dir.join("colmap_2/sparse"));
            },
            &["none of the 4 frame folders", "sparse/0/cameras.bin"],
        ),
        (
            "missing image",
            |dir, _| remove(&dir.join("colmap_3/images/cam01.png")),
            &["colmap_3/images/cam01.png", "no such file"],
        ),
        (
            "camera missing in one frame",
            |dir, _| rewrite_frame_model(dir, 2, |m| drop(m.images.remove(1))),
            &[
                "colmap_2/sparse/0/images.bin",
                "colmap_0/sparse/0/images.txt",
                "camera `cam01`",
                "not registered",
            ],
        ),
        (
            "extra camera in one frame",
            |dir, _| {
                rewrite_frame_model(dir, 2, |m| {
                    m.images.push(ModelImage::pinhole("cam03.png", &camera(3)))
                })
            },
            &["colmap_2", "camera `cam03` is not in", "colmap_0"],
        ),
        (
            "poses differ between frames",
            |dir, _| rewrite_frame_model(dir, 2, |m| m.images[2].pose = camera(5).world_to_camera),
            &[
                "colmap_2/sparse/0/images.bin",
                "colmap_0/sparse/0/images.txt",
                "camera `cam02`",
                "static rig",
            ],
        ),
        (
            "size differs between frames",
            |dir, _| rewrite_frame_model(dir, 2, |m| m.images[0].size = (10, 6)),
            &[
                "colmap_2",
                "camera `cam00` is 10×6 px here but 8×6 px",
                "colmap_0",
            ],
        ),
        (
            "unknown camera model",
            |dir, _| {
                replace_line(
                    &dir.join("colmap_0/sparse/0/cameras.txt"),
                    3,
                    "2 FANCY 8 6 7 4 3",
                )
            },
            &[
                "colmap_0/sparse/0/cameras.txt",
                "line 3",
                "unknown camera model `FANCY`",
            ],
        ),
        (
            "fisheye refused",
            |dir, _| {
                let line = "1 OPENCV_FISHEYE 8 6 7 7 4 3 0.1 0 0 0";
                replace_line(&dir.join("colmap_0/sparse/0/cameras.txt"), 2, line)
            },
            &[
                "cameras.txt",
                "line 2",
                "OPENCV_FISHEYE",
                "image_undistorter",
            ],
        ),
        (
            "bad number",
            |dir, _| {
                let line = "1 one 0 0 0 0 0 5 1 cam00.png";
                replace_line(&dir.join("colmap_0/sparse/0/images.txt"), 2, line)
            },
            &["images.txt", "line 2", "QW QX QY QZ", "`one`"],
        ),
        (
            "image of another size",
            |dir, _| {
                save(
                    &dir.join("colmap_1/images/cam02.png"),
                    &image(2, 1, (10, 6)),
                )
            },
            &["colmap_1/images/cam02.png", "10×6", "8×6"],
        ),
        (
            "truncated binary model",
            |dir, _| {
                let path = dir.join("colmap_2/sparse/0/images.bin");
                let bytes = std::fs::read(&path).unwrap();
                std::fs::write(&path, &bytes[..bytes.len() - 9]).unwrap();
            },
            &["colmap_2/sparse/0/images.bin", "truncated", "image 3 of 3"],
        ),
        (
            "unknown held-out camera",
            |_, s| s.test_cameras = vec!["cam00".into(), "cam07".into()],
            &["test_cameras[1]", "`cam07`", "cam00, cam01, cam02"],
        ),
        (
            "more frames than there are",
            |_, s| s.frames = Some(9),
            &[
                "`frames`",
                "asks for 9",
                "4 frame folders (colmap_0 to colmap_3)",
            ],
        ),
    ];
    check_cases(cases, write_frames_layout, colmap_video::load_frames);
}

/// A rig whose folder, model, frame folder or frames are missing, whose frames skip a number
/// or have the wrong size, whose model is corrupt (unknown or fisheye camera model, non-finite
/// point, zero quaternion, two images of one camera), or whose settings name an unknown
/// camera, hold every camera out or ask for more frames than there are.
#[test]
fn malformed_rigs_name_the_file_and_field() {
    fn set_camera_model(dir: &Path, model: &'static str, params: &[f64]) {
        let mut m = rig_model(&cameras(), points(0));
        m.images[1].model = model;
        m.images[1].params = params.to_vec();
        write_binary_model(&dir.join("sparse/0"), &m);
    }
    let cases: Vec<Case> = vec![
        (
            "missing folder",
            |dir, s| s.path = dir.join("absent").to_string_lossy().into(),
            &["absent", "no such folder"],
        ),
        (
            "no model",
            |dir, _| remove(&dir.join("sparse")),
            &["no COLMAP model of the rig", "sparse/0/cameras.bin"],
        ),
        (
            "missing frame folder",
            |dir, _| remove(&dir.join("frames/cam01")),
            &["frames/cam01", "no frames for camera `cam01`", "cam01.mp4"],
        ),
        (
            "empty frame folder",
            |dir, _| {
                remove(&dir.join("frames/cam02"));
                std::fs::create_dir(dir.join("frames/cam02")).unwrap();
            },
            &["frames/cam02", "no frames (*.png or *.jpg)"],
        ),
        (
            "gap in the frames",
            |dir, _| remove(&dir.join("frames/cam00/000001.png")),
            &["frames/cam00", "missing between 000000.png and 000002.png"],
        ),
        (
            "one frame of another size",
            |dir, _| save(&dir.join("frames/cam01/000002.png"), &image(1, 2, (10, 6))),
            &["frames/cam01/000002.png", "10×6", "8×6"],
        ),
        (
            "frames of another size than the camera",
            |dir, _| {
                for f in 0..FRAMES {
                    save(
                        &dir.join(format!("frames/cam02/{f:06}.png")),
                        &image(2, f, (8, 7)),
                    );
                }
            },
            &["frames/cam02/000000.png", "8×7", "its camera is 8×6"],
        ),
        (
            "unknown camera model",
            |dir, _| set_camera_model(dir, "FANCY", &[7.0, 7.0, 4.0, 3.0]),
            &["cameras.bin", "camera 2 of 3", "unknown camera model id 99"],
        ),
        (
            "fisheye refused",
            |dir, _| {
                set_camera_model(
                    dir,
                    "OPENCV_FISHEYE",
                    &[7.0, 7.0, 4.0, 3.0, 0.1, 0.0, 0.0, 0.0],
                )
            },
            &[
                "cameras.bin",
                "camera 2 of 3",
                "OPENCV_FISHEYE",
                "image_undistorter",
            ],
        ),
        (
            "non-finite point",
            |dir, _| {
                let mut points = points(0);
                points[1].0[2] = f64::NAN;
                write_binary_model(&dir.join("sparse/0"), &rig_model(&cameras(), points));
            },
            &["points3D.bin", "point 2 of 3", "non-finite position"],
        ),
        (
            "zero quaternion",
            |dir, _| {
                // The first image's quaternion: after the count (8 bytes) and its id (4).
                let path = dir.join("sparse/0/images.bin");
                let mut bytes = std::fs::read(&path).unwrap();
                bytes[12..44].fill(0);
                std::fs::write(&path, bytes).unwrap();
            },
            &[
                "images.bin",
                "image 1 of 3",
                "zero or non-finite quaternion",
            ],
        ),
        (
            "two images of one camera",
            |dir, _| {
                let mut m = rig_model(&cameras(), points(0));
                m.images[2].name = "cam00.jpg".into();
                write_binary_model(&dir.join("sparse/0"), &m);
            },
            &[
                "images.bin",
                "`cam00.jpg` and `cam00.png` are both camera `cam00`",
            ],
        ),
        (
            "unknown held-out camera",
            |_, s| s.test_cameras = vec!["left".into()],
            &["test_cameras[0]", "`left`", "cam00, cam01, cam02"],
        ),
        (
            "every camera held out",
            |_, s| s.test_cameras = vec!["cam00".into(), "cam01".into(), "cam02".into()],
            &["`test_cameras`", "every camera is held out"],
        ),
        (
            "more frames than there are",
            |_, s| s.frames = Some(9),
            &["frames/cam00", "has 4 frames", "`frames` asks for 9"],
        ),
        (
            "bad setting",
            |_, s| s.background = [0.0, 2.0, 0.0],
            &["`background`", "channel 1 is 2"],
        ),
    ];
    check_cases(cases, write_rig_layout, colmap_video::load_rig);
}

// ---------------------------------------------------------------------------------------
// The demo through both layouts
// ---------------------------------------------------------------------------------------

/// The demo scene with 6 frames, and its camera names (`cam05` is held out).
fn demo() -> (Dataset, Vec<ModelImage>) {
    let mut scene = tadgs::data::synthetic::demo_scene();
    scene.frames = 6;
    let data = scene.build().unwrap();
    let images = data
        .cameras
        .iter()
        .enumerate()
        .map(|(i, c)| ModelImage::pinhole(format!("cam{i:02}.png"), c))
        .collect();
    (data, images)
}

/// The demo written as per-frame folders (a text model at frame 0, a binary one at frame 3)
/// and as a rig (binary model, frame folders) reads back unchanged, and trains to the same
/// held-out PSNR within 0.2 dB.
#[test]
fn demo_scene_round_trips_through_both_layouts() {
    let (original, images) = demo();
    let model = Model {
        images,
        points: points(0),
    };
    let frames_dir = tempfile::tempdir().unwrap();
    let rig_dir = tempfile::tempdir().unwrap();
    for view in original.train.iter().chain(&original.test) {
        let (c, f) = (view.camera, view.frame);
        save(
            &frames_dir
                .path()
                .join(format!("colmap_{f}/images/cam{c:02}.png")),
            &view.image.pixels().unwrap(),
        );
        save(
            &rig_dir.path().join(format!("frames/cam{c:02}/{f:06}.png")),
            &view.image.pixels().unwrap(),
        );
    }
    write_text_model(&frames_dir.path().join("colmap_0/sparse/0"), &model);
    write_binary_model(&frames_dir.path().join("colmap_3/sparse/0"), &model);
    write_binary_model(&rig_dir.path().join("sparse/0"), &model);
    let held_out = ColmapSource {
        test_cameras: vec!["cam05".into()],
        ..source(frames_dir.path())
    };
    let frames = colmap_video::load_frames(&held_out).unwrap();
    assert_same_dataset(&original, &frames);
    assert_trains_alike(&original, &frames);
    let held_out = ColmapSource {
        path: rig_dir.path().to_string_lossy().into(),
        ..held_out
    };
    let rig = colmap_video::load_rig(&held_out).unwrap();
    assert_same_dataset(&original, &rig);
    assert_trains_alike(&original, &rig);
}

// ---------------------------------------------------------------------------------------
// Undistortion
// ---------------------------------------------------------------------------------------

fn close(found: (f64, f64), expected: (f64, f64)) -> bool {
    (found.0 - expected.0).abs() < 1e-12 && (found.1 - expected.1).abs() < 1e-12
}

/// COLMAP's forward models, checked against values worked out by hand, and the pixel an
/// output pixel samples: OPENCV at (0.3, −0.2) with k1 0.1, k2 0.01, p1 0.001, p2 0.002:
/// r² = 0.13, radial 0.013169, du = 0.0039507 − 0.00012 + 0.00062 = 0.0044507,
/// dv = −0.0026338 − 0.00024 + 0.00021 = −0.0026638.
#[test]
fn distortion_models_match_hand_computed_values() {
    let opencv = Distortion::from_colmap("OPENCV", &[0.1, 0.01, 0.001, 0.002]);
    assert!(close(opencv.distort(0.3, -0.2), (0.3044507, -0.2026638)));
    // SIMPLE_RADIAL k = −0.2 at (0.5, 0.5): r² = 0.5, factor 1 − 0.1.
    let simple = Distortion::from_colmap("SIMPLE_RADIAL", &[-0.2]);
    assert!(close(simple.distort(0.5, 0.5), (0.45, 0.45)));
    // RADIAL k1 = 0.1, k2 = 0.05 at (0.2, 0.1): r² = 0.05, radial 0.005 + 0.000125.
    let radial = Distortion::from_colmap("RADIAL", &[0.1, 0.05]);
    assert!(close(radial.distort(0.2, 0.1), (0.201025, 0.1005125)));
    // FULL_OPENCV with k4 … k6 zero is OPENCV plus k3·r⁶.
    let full = Distortion::from_colmap(
        "FULL_OPENCV",
        &[0.1, 0.01, 0.001, 0.002, 0.0, 0.0, 0.0, 0.0],
    );
    assert!(close(full.distort(0.3, -0.2), (0.3044507, -0.2026638)));
    assert!(Distortion::from_colmap("OPENCV", &[0.0; 4]).is_identity());
    assert!(!opencv.is_identity());

    // Pixel (470, 160) of a 640×480 camera (fx 500, fy 400, cx 320.5, cy 240.5) has its
    // centre at (0.3, −0.2) and samples the distorted image at fx·0.3044507 + cx, …
    let camera = Camera {
        width: 640,
        height: 480,
        fx: 500.0,
        fy: 400.0,
        cx: 320.5,
        cy: 240.5,
        world_to_camera: Mat4::IDENTITY,
    };
    let [x, y] = Undistortion::new(&opencv, &camera).source(470, 160);
    assert!(
        (x - 472.72535).abs() < 1e-3 && (y - 159.43448).abs() < 1e-3,
        "{x}, {y}"
    );
}

/// Inverse of the forward model by Newton's method with a finite-difference Jacobian (for
/// making distorted test images).
fn undistort_point(distortion: &Distortion, (ud, vd): (f64, f64)) -> (f64, f64) {
    const H: f64 = 1e-7;
    let (mut u, mut v) = (ud, vd);
    for _ in 0..30 {
        let (fu, fv) = distortion.distort(u, v);
        let (ru, rv) = (fu - ud, fv - vd);
        let (du_u, dv_u) = distortion.distort(u + H, v);
        let (du_v, dv_v) = distortion.distort(u, v + H);
        let [a, b, c, e] = [du_u - fu, du_v - fu, dv_u - fv, dv_v - fv].map(|d| d / H);
        let det = a * e - b * c;
        u -= (e * ru - b * rv) / det;
        v -= (a * rv - c * ru) / det;
    }
    (u, v)
}

/// Darkness-weighted centre of the line in row `y` near column `near`.
fn line_centre(image: &RgbImage, y: u32, near: f32) -> f32 {
    let (mut sum, mut weight) = (0.0, 0.0);
    let lo = (near - 8.0).max(0.0) as u32;
    let hi = ((near + 8.0) as u32).min(image.width() - 1);
    for x in lo..=hi {
        let w = 255.0 - f32::from(image.get_pixel(x, y).0[0]);
        sum += w * (x as f32 + 0.5);
        weight += w;
    }
    sum / weight
}

/// A straight vertical line seen through a barrel-distorted OPENCV lens bows by pixels; after
/// undistortion it is straight again, within 0.5 px of where the pinhole camera puts it on
/// every row.
#[test]
fn undistortion_straightens_a_distorted_line() {
    let distortion = Distortion::from_colmap("OPENCV", &[-0.25, 0.05, 0.001, -0.001]);
    let camera = Camera {
        width: 200,
        height: 150,
        fx: 120.0,
        fy: 125.0,
        cx: 100.0,
        cy: 75.0,
        world_to_camera: Mat4::IDENTITY,
    };
    let line_x = 40.0f64;
    let [fx, fy, cx, cy] = [camera.fx, camera.fy, camera.cx, camera.cy].map(f64::from);
    // What the distorted lens records: each pixel looks up the pinhole image of the line.
    let distorted = RgbImage::from_fn(camera.width, camera.height, |x, y| {
        let ud = (f64::from(x) + 0.5 - cx) / fx;
        let vd = (f64::from(y) + 0.5 - cy) / fy;
        let (u, _) = undistort_point(&distortion, (ud, vd));
        let d = (fx * u + cx - line_x) / 1.5;
        let v = (255.0 - 220.0 * (-d * d).exp()).round() as u8;
        image::Rgb([v, v, v])
    });
    let bow: Vec<f32> = (0..camera.height)
        .map(|y| {
            let darkest = (0..camera.width)
                .min_by_key(|&x| distorted.get_pixel(x, y).0[0])
                .unwrap();
            line_centre(&distorted, y, darkest as f32)
        })
        .collect();
    let spread =
        bow.iter().cloned().fold(f32::MIN, f32::max) - bow.iter().cloned().fold(f32::MAX, f32::min);
    assert!(
        spread > 3.0,
        "the distorted line should bow, spread {spread}"
    );

    let straight = Undistortion::new(&distortion, &camera).apply(&distorted, [255; 3]);
    for y in 0..camera.height {
        let centre = line_centre(&straight, y, line_x as f32);
        assert!(
            (centre - line_x as f32).abs() < 0.5,
            "row {y}: line at {centre}, expected {line_x}"
        );
    }
}

/// A rig with an OPENCV camera is undistorted at load time: its views are the undistortion of
/// the frames written, and pixels outside the distorted image (a pincushion lens) get the
/// source's background; the other cameras' images are untouched.
#[test]
fn distorted_rig_cameras_are_undistorted_when_read() {
    let dir = tempfile::tempdir().unwrap();
    write_rig_layout(dir.path());
    let mut model = rig_model(&cameras(), points(0));
    let cam = camera(1);
    let coefficients = [0.6, 0.1, 0.0, 0.0];
    model.images[1].model = "OPENCV";
    model.images[1].params = [cam.fx, cam.fy, cam.cx, cam.cy]
        .map(f64::from)
        .into_iter()
        .chain(coefficients)
        .collect();
    write_binary_model(&dir.path().join("sparse/0"), &model);
    let data = colmap_video::load_rig(&ColmapSource {
        background: [1.0, 0.0, 0.0],
        ..source(dir.path())
    })
    .unwrap();
    let undistortion = Undistortion::new(&Distortion::from_colmap("OPENCV", &coefficients), &cam);
    for view in &data.train {
        let written = image(view.camera, view.frame, (8, 6));
        if view.camera == 1 {
            assert!(view.image == undistortion.apply(&written, [255, 0, 0]));
            assert_eq!(view.image.pixels().unwrap().get_pixel(0, 0).0, [255, 0, 0]);
            assert!(view.image != written);
        } else {
            assert!(view.image == written);
        }
    }
}

// ---------------------------------------------------------------------------------------
// Scene files
// ---------------------------------------------------------------------------------------

/// `scenes/colmap_frames.ron` and `scenes/colmap_rig.ron` parse as their sources; a bad
/// setting is reported under its `data.` path.
#[test]
fn scene_files_name_the_colmap_sources() {
    use tadgs::scene::{DataSource, load_scene, parse_scene};
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenes");
    let config = load_scene(&scenes.join("colmap_frames.ron")).unwrap();
    let DataSource::ColmapFrames(source) = &config.data else {
        panic!("scenes/colmap_frames.ron is not a ColmapFrames scene");
    };
    assert_eq!(source.test_cameras, ["cam00"]);
    assert_eq!(source.downscale, 1);
    let config = load_scene(&scenes.join("colmap_rig.ron")).unwrap();
    assert!(matches!(config.data, DataSource::ColmapRig(_)));
    for variant in ["ColmapFrames", "ColmapRig"] {
        let text = format!(r#"(name: "c", data: {variant}((path: "x", downscale: 0)))"#);
        let error = parse_scene(&text, "bad.ron").unwrap_err().to_string();
        assert!(
            error.contains("bad.ron") && error.contains("data.downscale"),
            "{error}"
        );
        // Defaults: cam00 held out, full size.
        let text = format!(r#"(name: "c", data: {variant}((path: "x")))"#);
        let config = parse_scene(&text, "ok.ron").unwrap();
        let (DataSource::ColmapFrames(source) | DataSource::ColmapRig(source)) = config.data else {
            panic!("{variant}");
        };
        assert_eq!(source, ColmapSource::new("x"));
    }
}

/// `tadgs info --data` summarises a per-frame COLMAP scene: cameras, split, frames and the
/// per-frame clouds.
#[test]
fn info_describes_a_per_frame_scene() {
    let dir = tempfile::tempdir().unwrap();
    write_frames_layout(dir.path());
    let scene = dir.path().join("scene.ron");
    let text = format!(
        r#"(name: "c", data: ColmapFrames((path: "{}")))"#,
        dir.path().display()
    );
    std::fs::write(&scene, text).unwrap();
    let output = std::process::Command::new(env!("CARGO_BIN_EXE_tadgs"))
        .args(["info", "--data"])
        .arg(&scene)
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&output.stdout);
    assert!(
        output.status.success(),
        "{stdout}{}",
        String::from_utf8_lossy(&output.stderr)
    );
    for part in [
        "cameras 3 (train [1, 2], held out [0])",
        "frames 4, training views 8, held-out views 4",
        "initial points 8 in per-frame clouds at frames [0, 2]",
    ] {
        assert!(stdout.contains(part), "{stdout:?} lacks {part:?}");
    }
}
