//! Dataset file formats: N3DV (LLFF poses + frames or videos), COLMAP sparse models and PLY
//! point clouds, read from tiny files the tests write by hand, and their errors on bad input.

#[path = "common/llff.rs"]
mod llff;
mod mutate;

use std::path::{Path, PathBuf};
use std::process::Command;

use glam::{Quat, Vec3};
use tadgs::data::DataError;
use tadgs::data::colmap::{self, ColmapModel};
use tadgs::data::n3dv::{self, N3dvSource};
use tadgs::data::pointcloud::{read_point_cloud, write_point_cloud_ply};
use tadgs::init::InitPoint;

use llff::{llff_row, write_npy, write_poses};

// ---------------------------------------------------------------------------------------
// Helpers
// ---------------------------------------------------------------------------------------

/// Frame `f` of camera `c`: a flat colour that encodes both, so views can be traced back.
fn frame_color(camera: usize, frame: usize) -> [u8; 3] {
    [10 + 60 * camera as u8, 5 + 70 * frame as u8, 100]
}

fn write_frames(dir: &Path, camera: usize, count: usize, width: u32, height: u32, digits: usize) {
    std::fs::create_dir_all(dir).unwrap();
    for frame in 0..count {
        let image =
            image::RgbImage::from_pixel(width, height, image::Rgb(frame_color(camera, frame)));
        image
            .save(dir.join(format!("{frame:0digits$}.png")))
            .unwrap();
    }
}

const WIDTH: u32 = 12;
const HEIGHT: u32 = 8;
const FOCAL: f64 = 10.0;
const FRAMES: usize = 3;
const HWF: [f64; 3] = [HEIGHT as f64, WIDTH as f64, FOCAL];

/// The three hand-worked LLFF poses of the tiny scene:
/// 0. OpenCV's identity (at the origin, looking along +z, image x = world x, y = world y);
/// 1. LLFF's identity (down = world x, right = world y, backwards = world z) at (1, 2, 3);
/// 2. at (−5, 0, 0) looking along +x, with world −y down and world +z to the right.
fn tiny_poses() -> Vec<[f64; 17]> {
    vec![
        llff_row(
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 0.0, -1.0],
            [0.0; 3],
            HWF,
        ),
        llff_row(
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 2.0, 3.0],
            HWF,
        ),
        llff_row(
            [0.0, -1.0, 0.0],
            [0.0, 0.0, 1.0],
            [-1.0, 0.0, 0.0],
            [-5.0, 0.0, 0.0],
            HWF,
        ),
    ]
}

/// A 3-camera, 3-frame N3DV scene using both accepted folder layouts:
/// `frames/cam00`, `frames/cam01` and `cam02/images`.
fn write_tiny_n3dv(root: &Path) {
    write_poses(&root.join("poses_bounds.npy"), &tiny_poses());
    write_frames(&root.join("frames/cam00"), 0, FRAMES, WIDTH, HEIGHT, 6);
    write_frames(&root.join("frames/cam01"), 1, FRAMES, WIDTH, HEIGHT, 6);
    write_frames(&root.join("cam02/images"), 2, FRAMES, WIDTH, HEIGHT, 4);
}

fn source(root: &Path, downscale: u32) -> N3dvSource {
    N3dvSource {
        downscale,
        ..N3dvSource::new(root.to_string_lossy())
    }
}

fn assert_close(found: (f32, f32), expected: (f32, f32)) {
    assert!(
        (found.0 - expected.0).abs() < 1e-4 && (found.1 - expected.1).abs() < 1e-4,
        "projected to {found:?}, expected {expected:?}"
    );
}

/// The error's message, checked to name `file` (by its file name) and to contain `needles`.
fn assert_error_mentions(error: &DataError, file: &str, needles: &[&str]) {
    let message = error.to_string();
    assert!(
        message.contains(file),
        "error does not name {file}: {message}"
    );
    assert!(!message.contains('\n'), "error is not one line: {message}");
    for needle in needles {
        assert!(
            message.contains(needle),
            "error lacks `{needle}`: {message}"
        );
    }
}

fn ffmpeg_available() -> bool {
    let runs = |tool: &str| {
        Command::new(tool)
            .arg("-version")
            .output()
            .is_ok_and(|o| o.status.success())
    };
    runs("ffmpeg") && runs("ffprobe")
}

// ---------------------------------------------------------------------------------------
// N3DV
// ---------------------------------------------------------------------------------------

/// LLFF poses become OpenCV cameras: each hand-worked pose projects known world points to
/// the pixels worked out by hand, and intrinsics come from `hwf` with the principal point
/// at the image centre.
#[test]
fn n3dv_llff_poses_become_opencv_cameras() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let dataset = n3dv::load(&source(dir.path(), 1)).unwrap();
    assert_eq!(dataset.cameras.len(), 3);
    for camera in &dataset.cameras {
        assert_eq!((camera.width, camera.height), (WIDTH, HEIGHT));
        assert_eq!(
            (camera.fx, camera.fy, camera.cx, camera.cy),
            (10.0, 10.0, 6.0, 4.0)
        );
    }

    // Camera 0 is OpenCV's identity: (x, y, z) ↦ (cx + f·x/z, cy + f·y/z).
    let cam0 = &dataset.cameras[0];
    let (u, v, depth) = cam0.project(Vec3::new(0.6, -0.4, 5.0));
    assert_close((u, v), (7.2, 3.2));
    assert!((depth - 5.0).abs() < 1e-5);

    // Camera 1 (LLFF identity at (1, 2, 3)): right = world +y, down = world +x, forward =
    // world −z. Two metres ahead and half a metre to the right lands right of centre.
    let cam1 = &dataset.cameras[1];
    assert!((cam1.center() - Vec3::new(1.0, 2.0, 3.0)).length() < 1e-5);
    let (u, v, depth) = cam1.project(Vec3::new(1.0, 2.5, 1.0));
    assert_close((u, v), (6.0 + 10.0 * 0.25, 4.0));
    assert!((depth - 2.0).abs() < 1e-5);
    // ... and 0.3 along world +x is 0.3 down in the image.
    let (u, v, _) = cam1.project(Vec3::new(1.3, 2.0, 1.0));
    assert_close((u, v), (6.0, 4.0 + 10.0 * 0.15));

    // Camera 2 looks along +x from (−5, 0, 0), with world +z to the right and +y up.
    let cam2 = &dataset.cameras[2];
    let (u, v, depth) = cam2.project(Vec3::ZERO);
    assert_close((u, v), (6.0, 4.0));
    assert!((depth - 5.0).abs() < 1e-5);
    let (u, v, _) = cam2.project(Vec3::new(0.0, 1.0, 0.5));
    assert_close((u, v), (7.0, 2.0));
}

/// Camera 0 is held out by default: test views are cam00's frames, training views are the
/// other cameras' frames, each with its own image and normalised time frame / (T − 1).
#[test]
fn n3dv_holds_out_camera_zero_and_keeps_frame_order() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let dataset = n3dv::load(&source(dir.path(), 1)).unwrap();
    assert_eq!(dataset.frame_count, FRAMES);
    assert_eq!(dataset.test_cameras(), vec![0]);
    assert_eq!(dataset.train_cameras(), vec![1, 2]);
    assert_eq!(dataset.test.len(), FRAMES);
    assert_eq!(dataset.train.len(), 2 * FRAMES);
    for view in dataset.train.iter().chain(&dataset.test) {
        assert_eq!(view.image.dimensions(), (WIDTH, HEIGHT));
        assert_eq!(
            view.image.pixels().unwrap().get_pixel(3, 2).0,
            frame_color(view.camera, view.frame)
        );
        assert!((view.time - view.frame as f32 / (FRAMES - 1) as f32).abs() < 1e-6);
    }
    assert!(dataset.test_view(0, 2).is_some());

    // `frames` keeps the first frames only, and time is renormalised to them.
    let limited = n3dv::load(&N3dvSource {
        frames: Some(2),
        test_cameras: vec![2],
        ..source(dir.path(), 1)
    })
    .unwrap();
    assert_eq!(limited.frame_count, 2);
    assert_eq!(limited.test_cameras(), vec![2]);
    assert_eq!(limited.train_cameras(), vec![0, 1]);
    assert_eq!(
        limited.train.iter().map(|v| v.time).fold(0.0, f32::max),
        1.0
    );
}

/// `downscale: 2` halves the image size, the focal lengths and the principal point, and
/// averages the pixels (a flat frame stays the same colour).
#[test]
fn n3dv_downscale_halves_size_and_focal() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let dataset = n3dv::load(&source(dir.path(), 2)).unwrap();
    for camera in &dataset.cameras {
        assert_eq!((camera.width, camera.height), (WIDTH / 2, HEIGHT / 2));
        assert_eq!(
            (camera.fx, camera.fy, camera.cx, camera.cy),
            (5.0, 5.0, 3.0, 2.0)
        );
    }
    let view = &dataset.train[0];
    assert_eq!(view.image.dimensions(), (WIDTH / 2, HEIGHT / 2));
    assert_eq!(
        view.image.pixels().unwrap().get_pixel(1, 1).0,
        frame_color(view.camera, view.frame)
    );
    // The projection of a point scales with the image: half the offset from the centre.
    let (u, v, _) = dataset.cameras[0].project(Vec3::new(0.6, -0.4, 5.0));
    assert_close((u, v), (3.6, 1.6));
}

/// Scene files may give only `path`: the paper's protocol (half resolution, cam00 held out,
/// all frames) is the default, and unknown fields are refused.
#[test]
fn n3dv_source_defaults_in_ron() {
    let parsed: N3dvSource = ron::from_str(r#"(path: "data/coffee_martini")"#).unwrap();
    assert_eq!(parsed, N3dvSource::new("data/coffee_martini"));
    assert_eq!(
        (parsed.downscale, parsed.test_cameras, parsed.frames),
        (2, vec![0], None)
    );
    assert!(ron::from_str::<N3dvSource>(r#"(path: "x", downscal: 1)"#).is_err());
}

/// Videos `camXX.mp4` are decoded with the system ffmpeg into the same views as frame
/// folders would give (colours within video-compression error).
#[test]
fn n3dv_reads_mp4_videos_with_ffmpeg() {
    if !ffmpeg_available() {
        println!("skipped: ffmpeg/ffprobe not on PATH (install ffmpeg to run this test)");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    // Even sizes, as 4:2:0 video needs.
    let (width, height) = (16u32, 12u32);
    let hwf = [height as f64, width as f64, FOCAL];
    let mut poses = tiny_poses();
    for row in &mut poses {
        row[4] = hwf[0];
        row[9] = hwf[1];
        row[14] = hwf[2];
    }
    write_poses(&root.join("poses_bounds.npy"), &poses);
    for camera in 0..3 {
        let staging = root.join(format!("staging{camera}"));
        write_frames(&staging, camera, FRAMES, width, height, 6);
        let status = Command::new("ffmpeg")
            .args(["-v", "error", "-y", "-framerate", "10", "-i"])
            .arg(staging.join("%06d.png"))
            .args(["-c:v", "mpeg4", "-q:v", "1", "-pix_fmt", "yuv420p"])
            .arg(root.join(format!("cam{camera:02}.mp4")))
            .status()
            .unwrap();
        assert!(status.success(), "ffmpeg could not encode the test video");
        std::fs::remove_dir_all(&staging).unwrap();
    }

    let dataset = n3dv::load(&source(root, 2)).unwrap();
    assert_eq!(dataset.frame_count, FRAMES);
    assert_eq!(dataset.test_cameras(), vec![0]);
    assert_eq!(dataset.train.len(), 2 * FRAMES);
    let camera = &dataset.cameras[1];
    assert_eq!((camera.width, camera.height), (8, 6));
    assert_eq!((camera.fx, camera.cx, camera.cy), (5.0, 4.0, 3.0));
    for view in dataset.train.iter().chain(&dataset.test) {
        let expected = frame_color(view.camera, view.frame);
        let found = view.image.pixels().unwrap().get_pixel(4, 3).0;
        for (f, e) in found.iter().zip(expected) {
            assert!(
                f.abs_diff(e) <= 12,
                "camera {} frame {}: {found:?} vs {expected:?}",
                view.camera,
                view.frame
            );
        }
    }

    let limited = n3dv::load(&N3dvSource {
        frames: Some(2),
        ..source(root, 1)
    })
    .unwrap();
    assert_eq!(limited.frame_count, 2);
    assert_eq!(limited.train[0].image.dimensions(), (width, height));
}

/// A pose file of the wrong shape is refused with the file, the shape found and the one
/// expected.
#[test]
fn n3dv_rejects_npy_with_wrong_shape() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let data: Vec<u8> = (0..45).flat_map(|i| f64::from(i).to_le_bytes()).collect();
    write_npy(&dir.path().join("poses_bounds.npy"), "<f8", &[3, 15], &data);
    let error = n3dv::load(&source(dir.path(), 1)).unwrap_err();
    assert_error_mentions(&error, "poses_bounds.npy", &["shape", "[3, 15]", "N×17"]);
}

/// A float32 pose file is refused, naming the dtype found and the one expected.
#[test]
fn n3dv_rejects_float32_npy() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let data: Vec<u8> = (0..51).flat_map(|i| (i as f32).to_le_bytes()).collect();
    write_npy(&dir.path().join("poses_bounds.npy"), "<f4", &[3, 17], &data);
    let error = n3dv::load(&source(dir.path(), 1)).unwrap_err();
    assert_error_mentions(&error, "poses_bounds.npy", &["dtype", "float64", "<f4"]);
}

/// A pose row whose camera has neither frames nor a video is an error that names the pose
/// file, both counts and the layouts that would have worked.
#[test]
fn n3dv_rejects_missing_camera_folder() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    std::fs::remove_dir_all(dir.path().join("cam02")).unwrap();
    let error = n3dv::load(&source(dir.path(), 1)).unwrap_err();
    assert_error_mentions(
        &error,
        "poses_bounds.npy",
        &[
            "3 camera poses",
            "2 cameras found",
            "camXX.mp4",
            "frames/camXX",
        ],
    );
}

/// Without ffmpeg and without frames, a video-only camera gets an error saying what to
/// install or which layout to provide. (Runs only where ffmpeg is absent.)
#[test]
fn n3dv_without_ffmpeg_says_what_to_do() {
    if ffmpeg_available() {
        println!("skipped: ffmpeg is installed, so videos decode");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    std::fs::remove_dir_all(dir.path().join("cam02")).unwrap();
    std::fs::write(dir.path().join("cam02.mp4"), b"not really a video").unwrap();
    let error = n3dv::load(&source(dir.path(), 1)).unwrap_err();
    assert_error_mentions(
        &error,
        "cam02.mp4",
        &["install FFmpeg", "frames/cam02/000000.png"],
    );
}

/// A frame whose size differs from the camera's other frames is an error naming that frame
/// file and both sizes.
#[test]
fn n3dv_rejects_frames_of_different_sizes() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let odd = dir.path().join("frames/cam01/000002.png");
    image::RgbImage::new(WIDTH + 2, HEIGHT).save(&odd).unwrap();
    let error = n3dv::load(&source(dir.path(), 1)).unwrap_err();
    assert_error_mentions(&error, "cam01/000002.png", &["14×8", "12×8"]);
}

/// Frame folders streamed through a cache (`cache_mb`) read as the same views, cameras and
/// pixels as loaded ones, at full size and downscaled; nothing is decoded until a view's
/// pixels are asked for, and the streamed dataset holds no image bytes itself.
#[test]
fn n3dv_streamed_frame_folders_match_loaded_ones() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    for downscale in [1, 2] {
        let loaded = n3dv::load(&source(dir.path(), downscale)).unwrap();
        let streamed = n3dv::load(&N3dvSource {
            cache_mb: Some(0.001),
            ..source(dir.path(), downscale)
        })
        .unwrap();
        let cache = streamed.cache().expect("streamed").clone();
        assert_eq!(cache.stats().misses + cache.stats().prefetched, 0);
        assert_eq!(streamed.memory_bytes(), 0);
        assert_eq!(loaded.cameras, streamed.cameras);
        let views =
            |d: &tadgs::data::Dataset| d.train.iter().chain(&d.test).cloned().collect::<Vec<_>>();
        for (a, b) in views(&loaded).iter().zip(&views(&streamed)) {
            assert_eq!((a.camera, a.frame, a.time), (b.camera, b.frame, b.time));
            assert!(a.image == b.image, "camera {} frame {}", a.camera, a.frame);
        }
        assert!(cache.stats().peak_bytes <= 1000);
    }
}

/// A frame of the wrong size is refused when a streamed dataset is read (from the file's
/// header), not later in training, naming the file and both sizes.
#[test]
fn n3dv_streamed_frame_of_wrong_size_is_refused_at_load() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let odd = dir.path().join("frames/cam01/000002.png");
    image::RgbImage::new(WIDTH + 2, HEIGHT).save(&odd).unwrap();
    let error = n3dv::load(&N3dvSource {
        cache_mb: Some(1.0),
        ..source(dir.path(), 1)
    })
    .unwrap_err();
    assert_error_mentions(&error, "cam01/000002.png", &["14×8", "12×8"]);
}

/// A non-positive or non-finite `cache_mb` is a setting error naming the field.
#[test]
fn n3dv_cache_mb_must_be_positive() {
    for bad in [0.0, -5.0, f64::NAN] {
        let error = N3dvSource {
            cache_mb: Some(bad),
            ..N3dvSource::new("x")
        }
        .check()
        .unwrap_err();
        assert!(error.to_string().contains("cache_mb"), "{error}");
    }
}

/// A gap in a camera's frame numbering (it would shift every later frame in time) is an
/// error naming the folder and the frames around the gap.
#[test]
fn n3dv_rejects_missing_frames() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    std::fs::remove_file(dir.path().join("cam02/images/0001.png")).unwrap();
    let error = n3dv::load(&source(dir.path(), 1)).unwrap_err();
    assert_error_mentions(&error, "cam02/images", &["missing", "0000.png", "0002.png"]);
}

/// Asking for more frames than a camera has is an error naming that camera's frames.
#[test]
fn n3dv_rejects_too_few_frames() {
    let dir = tempfile::tempdir().unwrap();
    write_tiny_n3dv(dir.path());
    let error = n3dv::load(&N3dvSource {
        frames: Some(5),
        ..source(dir.path(), 1)
    })
    .unwrap_err();
    assert_error_mentions(&error, "frames/cam00", &["has 3 frames", "asks for 5"]);
}

// ---------------------------------------------------------------------------------------
// COLMAP
// ---------------------------------------------------------------------------------------

struct TestCamera {
    id: u32,
    model_id: i32,
    model: &'static str,
    width: u64,
    height: u64,
    params: Vec<f64>,
}

struct TestImage {
    id: u32,
    qvec: [f64; 4],
    tvec: [f64; 3],
    camera_id: u32,
    name: &'static str,
}

struct TestPoint {
    xyz: [f64; 3],
    rgb: [u8; 3],
}

fn test_cameras() -> Vec<TestCamera> {
    vec![
        TestCamera {
            id: 1,
            model_id: 1,
            model: "PINHOLE",
            width: 640,
            height: 480,
            params: vec![500.0, 510.0, 320.5, 240.25],
        },
        TestCamera {
            id: 7,
            model_id: 2,
            model: "SIMPLE_RADIAL",
            width: 800,
            height: 600,
            params: vec![700.0, 400.0, 300.0, 0.01],
        },
    ]
}

fn test_images() -> Vec<TestImage> {
    let half = 15f64.to_radians();
    vec![
        TestImage {
            id: 1,
            qvec: [half.cos(), 0.0, half.sin(), 0.0],
            tvec: [0.1, -0.2, 3.0],
            camera_id: 7,
            name: "b.png",
        },
        TestImage {
            id: 2,
            qvec: [1.0, 0.0, 0.0, 0.0],
            tvec: [0.0, 0.0, 5.0],
            camera_id: 1,
            name: "a.png",
        },
    ]
}

fn test_points() -> Vec<TestPoint> {
    (0..5)
        .map(|i| TestPoint {
            xyz: [
                i as f64 * 0.5 - 1.0,
                0.25 * i as f64,
                1.0 / (i as f64 + 1.0),
            ],
            rgb: [i as u8 * 50, 255 - i as u8 * 30, 7],
        })
        .collect()
}

fn write_text_model(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    let mut cameras = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    for c in test_cameras() {
        let params: Vec<String> = c.params.iter().map(|p| format!("{p:.17}")).collect();
        cameras += &format!(
            "{} {} {} {} {}\n",
            c.id,
            c.model,
            c.width,
            c.height,
            params.join(" ")
        );
    }
    std::fs::write(dir.join("cameras.txt"), cameras).unwrap();

    let mut images = String::from("# Image list with two lines of data per image:\n");
    for (index, i) in test_images().iter().enumerate() {
        let [qw, qx, qy, qz] = i.qvec;
        let [tx, ty, tz] = i.tvec;
        images += &format!(
            "{} {qw:.17} {qx:.17} {qy:.17} {qz:.17} {tx} {ty} {tz} {} {}\n",
            i.id, i.camera_id, i.name
        );
        // The first image has 2D points, the second an empty points line.
        images += if index == 0 {
            "10.5 20.5 1 30.0 40.0 -1\n"
        } else {
            "\n"
        };
    }
    std::fs::write(dir.join("images.txt"), images).unwrap();

    let mut points = String::from("# 3D point list\n");
    for (id, p) in test_points().iter().enumerate() {
        let [x, y, z] = p.xyz;
        let [r, g, b] = p.rgb;
        points += &format!(
            "{} {x:.17} {y:.17} {z:.17} {r} {g} {b} 0.5 1 0 2 0\n",
            id + 1
        );
    }
    std::fs::write(dir.join("points3D.txt"), points).unwrap();
}

fn push_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn push_u64(out: &mut Vec<u8>, v: u64) {
    out.extend_from_slice(&v.to_le_bytes());
}
fn push_f64s(out: &mut Vec<u8>, values: &[f64]) {
    for v in values {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

fn cameras_bin(cameras: &[TestCamera]) -> Vec<u8> {
    let mut out = Vec::new();
    push_u64(&mut out, cameras.len() as u64);
    for c in cameras {
        push_u32(&mut out, c.id);
        out.extend_from_slice(&c.model_id.to_le_bytes());
        push_u64(&mut out, c.width);
        push_u64(&mut out, c.height);
        push_f64s(&mut out, &c.params);
    }
    out
}

fn points_bin(points: &[TestPoint]) -> Vec<u8> {
    let mut out = Vec::new();
    push_u64(&mut out, points.len() as u64);
    for (id, p) in points.iter().enumerate() {
        push_u64(&mut out, id as u64 + 1);
        push_f64s(&mut out, &p.xyz);
        out.extend_from_slice(&p.rgb);
        push_f64s(&mut out, &[0.5]);
        push_u64(&mut out, 2); // track length
        for (image, point2d) in [(1u32, 0u32), (2, 0)] {
            push_u32(&mut out, image);
            push_u32(&mut out, point2d);
        }
    }
    out
}

fn write_binary_model(dir: &Path) {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::write(dir.join("cameras.bin"), cameras_bin(&test_cameras())).unwrap();

    let mut images = Vec::new();
    let list = test_images();
    push_u64(&mut images, list.len() as u64);
    for (index, i) in list.iter().enumerate() {
        push_u32(&mut images, i.id);
        push_f64s(&mut images, &i.qvec);
        push_f64s(&mut images, &i.tvec);
        push_u32(&mut images, i.camera_id);
        images.extend_from_slice(i.name.as_bytes());
        images.push(0);
        let point_count = if index == 0 { 2 } else { 0 };
        push_u64(&mut images, point_count);
        for _ in 0..point_count {
            push_f64s(&mut images, &[10.5, 20.5]);
            images.extend_from_slice(&(-1i64).to_le_bytes());
        }
    }
    std::fs::write(dir.join("images.bin"), images).unwrap();
    std::fs::write(dir.join("points3D.bin"), points_bin(&test_points())).unwrap();
}

/// Checks a model read back against the data the test wrote.
fn check_model(model: &ColmapModel) {
    assert_eq!(model.cameras.len(), 2);
    let pinhole = &model.cameras[0];
    assert_eq!(
        (pinhole.id, pinhole.model, pinhole.width, pinhole.height),
        (1, "PINHOLE", 640, 480)
    );
    assert_eq!(
        (pinhole.fx, pinhole.fy, pinhole.cx, pinhole.cy),
        (500.0, 510.0, 320.5, 240.25)
    );
    let radial = &model.cameras[1];
    assert_eq!((radial.id, radial.model), (7, "SIMPLE_RADIAL"));
    assert_eq!(
        (radial.fx, radial.fy, radial.cx, radial.cy),
        (700.0, 700.0, 400.0, 300.0)
    );

    // Images come sorted by name and carry their camera's intrinsics.
    let names: Vec<&str> = model.images.iter().map(|i| i.name.as_str()).collect();
    assert_eq!(names, ["a.png", "b.png"]);
    let a = &model.images[0];
    assert_eq!(
        (a.id, a.camera_id, a.camera.width, a.camera.fx),
        (2, 1, 640, 500.0)
    );
    let (u, v, depth) = a.camera.project(Vec3::ZERO);
    assert!((u - 320.5).abs() < 1e-4 && (v - 240.25).abs() < 1e-4 && (depth - 5.0).abs() < 1e-5);
    let b = &model.images[1];
    assert_eq!(
        (b.camera_id, b.camera.width, b.camera.height),
        (7, 800, 600)
    );
    let expected_rotation = glam::Mat3::from_quat(Quat::from_rotation_y(30f32.to_radians()));
    assert!(b.camera.rotation().abs_diff_eq(expected_rotation, 1e-6));
    assert!(
        b.camera
            .translation()
            .abs_diff_eq(Vec3::new(0.1, -0.2, 3.0), 1e-6)
    );

    assert_eq!(model.points.len(), 5);
    for (found, expected) in model.points.iter().zip(test_points()) {
        assert!(
            found
                .position
                .abs_diff_eq(Vec3::from_array(expected.xyz.map(|v| v as f32)), 1e-6)
        );
        let rgb = expected.rgb.map(|c| f32::from(c) / 255.0);
        for (f, e) in found.color.iter().zip(rgb) {
            assert!((f - e).abs() < 1e-6);
        }
    }
}

/// The text and binary forms of the same model read to the same cameras, poses and points
/// (within 1e-6), and both match what was written.
#[test]
fn colmap_text_and_binary_models_agree() {
    let dir = tempfile::tempdir().unwrap();
    let text_dir = dir.path().join("text");
    let binary_dir = dir.path().join("binary/sparse/0");
    write_text_model(&text_dir);
    write_binary_model(&binary_dir);
    let text = colmap::read_model(&text_dir).unwrap();
    // The binary model is found below the scene folder, in sparse/0.
    let binary = colmap::read_model(&dir.path().join("binary")).unwrap();
    check_model(&text);
    check_model(&binary);
    assert_eq!(text.cameras, binary.cameras);
    for (t, b) in text.images.iter().zip(&binary.images) {
        assert_eq!(t.name, b.name);
        assert!(
            t.camera
                .world_to_camera
                .abs_diff_eq(b.camera.world_to_camera, 1e-6)
        );
    }
    for (t, b) in text.points.iter().zip(&binary.points) {
        assert!(t.position.abs_diff_eq(b.position, 1e-6));
        assert_eq!(t.color, b.color);
    }
    // The point-cloud reader dispatches to the same COLMAP readers by extension.
    assert_eq!(
        read_point_cloud(&binary_dir.join("points3D.bin")).unwrap(),
        binary.points
    );
    assert_eq!(
        read_point_cloud(&text_dir.join("points3D.txt")).unwrap(),
        text.points
    );
}

/// Writes a valid text model to `dir`, replaces its `file` with `contents` and checks that
/// reading the model fails with an error naming `file` and containing `needles`.
fn assert_text_model_rejects(dir: &Path, file: &str, contents: &str, needles: &[&str]) {
    write_text_model(dir);
    std::fs::write(dir.join(file), contents).unwrap();
    let error = colmap::read_model(dir).unwrap_err();
    assert_error_mentions(&error, file, needles);
}

/// An unknown camera model is an error naming the file and the line (text) or the record
/// and byte offset (binary).
#[test]
fn colmap_rejects_unknown_camera_model() {
    let dir = tempfile::tempdir().unwrap();
    assert_text_model_rejects(
        dir.path(),
        "cameras.txt",
        "# cameras\n1 FANCY_LENS 640 480 500 320 240\n",
        &["line 2", "unknown camera model `FANCY_LENS`"],
    );

    let mut cameras = test_cameras();
    cameras[1].model_id = 42;
    write_binary_model(&dir.path().join("bin"));
    std::fs::write(dir.path().join("bin/cameras.bin"), cameras_bin(&cameras)).unwrap();
    let error = colmap::read_model(&dir.path().join("bin")).unwrap_err();
    assert_error_mentions(
        &error,
        "cameras.bin",
        &[
            "unknown camera model id 42",
            "camera 2 of 2",
            "byte offset 68",
        ],
    );
}

/// A camera line with the wrong number of parameters for its model is an error naming the
/// file, line, model and both counts.
#[test]
fn colmap_rejects_wrong_parameter_count() {
    let dir = tempfile::tempdir().unwrap();
    assert_text_model_rejects(
        dir.path(),
        "cameras.txt",
        "1 PINHOLE 640 480 500 320 240\n",
        &["line 1", "PINHOLE takes 4 parameters, found 3"],
    );
}

/// A fisheye camera is refused (its distortion cannot be dropped) with advice to undistort.
#[test]
fn colmap_rejects_fisheye_models() {
    let dir = tempfile::tempdir().unwrap();
    assert_text_model_rejects(
        dir.path(),
        "cameras.txt",
        "1 OPENCV_FISHEYE 640 480 500 500 320 240 0 0 0 0\n",
        &["line 1", "OPENCV_FISHEYE", "image_undistorter"],
    );
}

/// A truncated points3D.bin is an error naming the file, the point and the byte offset
/// where data ran out.
#[test]
fn colmap_rejects_truncated_points_bin() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points3D.bin");
    let mut bytes = points_bin(&test_points());
    bytes.truncate(bytes.len() - 10);
    std::fs::write(&path, &bytes).unwrap();
    let error = colmap::read_points3d(&path).unwrap_err();
    assert_error_mentions(
        &error,
        "points3D.bin",
        &["truncated", "point 5 of 5", "byte offset"],
    );
}

/// A text line with too few fields is an error naming the file, the line and the layout
/// expected.
#[test]
fn colmap_rejects_short_text_line() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("points3D.txt");
    std::fs::write(&path, "# points\n1 0.0 0.0 1.0 255 0 0 0.1\n2 0.5 0.5\n").unwrap();
    let error = colmap::read_points3d(&path).unwrap_err();
    assert_error_mentions(
        &error,
        "points3D.txt",
        &["line 3", "expected at least 8 fields", "found 3"],
    );

    assert_text_model_rejects(
        dir.path(),
        "images.txt",
        "1 1 0 0 0 0 0 5 1\n\n",
        &["line 1", "expected at least 10 fields"],
    );
}

// ---------------------------------------------------------------------------------------
// PLY
// ---------------------------------------------------------------------------------------

fn sample_points() -> Vec<InitPoint> {
    (0..20)
        .map(|i| InitPoint {
            position: Vec3::new(i as f32 * 0.1 - 1.0, (i * i) as f32 * 0.01, -0.5 * i as f32),
            color: [i as f32 / 19.0, 1.0 - i as f32 / 19.0, 0.25],
        })
        .collect()
}

fn write(dir: &Path, name: &str, contents: &[u8]) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, contents).unwrap();
    path
}

/// A cloud written as binary PLY reads back with the same positions and colours
/// (to 8-bit precision), and no temporary file is left behind.
#[test]
fn ply_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cloud.ply");
    let points = sample_points();
    write_point_cloud_ply(&path, &points).unwrap();
    let read = read_point_cloud(&path).unwrap();
    assert_eq!(read.len(), points.len());
    for (r, p) in read.iter().zip(&points) {
        assert_eq!(r.position, p.position);
        for (a, b) in r.color.iter().zip(p.color) {
            assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
        }
    }
    let entries: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(entries.len(), 1, "only cloud.ply should remain");
}

/// ASCII PLY with float colours (taken as 0–1), double positions, extra properties and a
/// face element after the vertices reads correctly.
#[test]
fn ply_ascii_with_float_colours() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        dir.path(),
        "ascii.ply",
        b"ply\nformat ascii 1.0\ncomment hand written\nelement vertex 2\n\
          property double x\nproperty double y\nproperty double z\nproperty float nx\n\
          property float red\nproperty float green\nproperty float blue\n\
          element face 1\nproperty list uchar int vertex_indices\nend_header\n\
          1.5 -2 3 0 0.25 0.5 1\n0 0 0 1 1 0 0\n3 0 1 0\n",
    );
    let points = read_point_cloud(&path).unwrap();
    assert_eq!(points.len(), 2);
    assert_eq!(points[0].position, Vec3::new(1.5, -2.0, 3.0));
    assert_eq!(points[0].color, [0.25, 0.5, 1.0]);
    assert_eq!(points[1].color, [1.0, 0.0, 0.0]);
}

/// Points of a PLY without colours get 0.5 grey.
#[test]
fn ply_without_colours_is_grey() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        dir.path(),
        "plain.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\n\
          property float z\nend_header\n1 2 3\n",
    );
    let points = read_point_cloud(&path).unwrap();
    assert_eq!(
        points,
        vec![InitPoint {
            position: Vec3::new(1.0, 2.0, 3.0),
            color: [0.5; 3]
        }]
    );
}

/// A malformed header is an error naming the file and the header.
#[test]
fn ply_rejects_bad_header() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(
        dir.path(),
        "bad_header.ply",
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty floot x\nend_header\n",
    );
    let error = read_point_cloud(&path).unwrap_err();
    assert_error_mentions(&error, "bad_header.ply", &["invalid PLY header"]);

    let path = write(
        dir.path(),
        "no_z.ply",
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n",
    );
    let error = read_point_cloud(&path).unwrap_err();
    assert_error_mentions(&error, "no_z.ply", &["vertex.z", "missing"]);
}

/// A body shorter than its header declares (binary or ascii) is an error naming the file
/// and the element.
#[test]
fn ply_rejects_truncated_body() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("short.ply");
    write_point_cloud_ply(&path, &sample_points()).unwrap();
    let mut bytes = std::fs::read(&path).unwrap();
    bytes.truncate(bytes.len() - 7);
    std::fs::write(&path, &bytes).unwrap();
    let error = read_point_cloud(&path).unwrap_err();
    assert_error_mentions(
        &error,
        "short.ply",
        &["truncated", "`vertex`", "20 declared"],
    );

    let path = write(
        dir.path(),
        "short_ascii.ply",
        b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
          property float z\nend_header\n1 2 3\n4 5 6\n",
    );
    let error = read_point_cloud(&path).unwrap_err();
    assert_error_mentions(
        &error,
        "short_ascii.ply",
        &["truncated", "`vertex`", "3 declared"],
    );
}

/// Unsupported point-cloud formats are refused by name rather than guessed at.
#[test]
fn point_cloud_rejects_unsupported_formats() {
    let dir = tempfile::tempdir().unwrap();
    let path = write(dir.path(), "cloud.npz", b"PK");
    let error = read_point_cloud(&path).unwrap_err();
    assert_error_mentions(&error, "cloud.npz", &["not supported", "PLY"]);
    let path = write(dir.path(), "cloud.xyz", b"1 2 3");
    let error = read_point_cloud(&path).unwrap_err();
    assert_error_mentions(&error, "cloud.xyz", &["unknown point cloud format"]);
}

/// PLY malformed-input corpus: each file below is refused with an error naming the file and
/// the problem (header, element, vertex), never a panic and never an empty cloud.
#[test]
fn ply_malformed_corpus() {
    let header = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
                  property float z\n";
    let binary = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n\
                  property float y\nproperty float z\nend_header\n";
    let nan_vertex: Vec<u8> = [1.0f32, f32::NAN, 2.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    let cases: Vec<(&str, Vec<u8>, &[&str])> = vec![
        ("empty file", Vec::new(), &["invalid PLY header"]),
        (
            "misspelt property type (the parser's own message spans lines)",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty floot x\nend_header\n1\n".to_vec(),
            &["invalid PLY header", "Line 4", "property floot x"],
        ),
        (
            "no magic line",
            b"format ascii 1.0\nelement vertex 1\nend_header\n".to_vec(),
            &["invalid PLY header"],
        ),
        (
            "header without end_header",
            header.as_bytes().to_vec(),
            &["invalid PLY header"],
        ),
        (
            "unknown format",
            b"ply\nformat utf8 1.0\nelement vertex 0\nend_header\n".to_vec(),
            &["invalid PLY header"],
        ),
        (
            "no vertex element",
            b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int i\nend_header\n"
                .to_vec(),
            &["no `vertex` element"],
        ),
        (
            "only some colour channels",
            format!("{header}property uchar red\nend_header\n1 2 3 4\n5 6 7 8\n").into_bytes(),
            &["vertex.red/green/blue", "all three or none"],
        ),
        (
            "non-numeric value",
            format!("{header}end_header\n1 2 3\n4 five 6\n").into_bytes(),
            &["malformed PLY body", "`vertex`"],
        ),
        (
            "non-finite position",
            [binary.as_bytes(), &nan_vertex].concat(),
            &["vertex 0", "non-finite"],
        ),
        (
            "huge declared count, tiny body",
            b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n\
             property float x\nproperty float y\nproperty float z\nend_header\n\0\0\0\0"
                .to_vec(),
            &["truncated", "`vertex`", "4000000000 declared"],
        ),
    ];
    let dir = tempfile::tempdir().unwrap();
    for (index, (name, contents, needles)) in cases.iter().enumerate() {
        let file = format!("case{index}.ply");
        let path = write(dir.path(), &file, contents);
        match read_point_cloud(&path) {
            Ok(points) => panic!("case `{name}` was accepted with {} points", points.len()),
            Err(error) => assert_error_mentions(&error, &file, needles),
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(128))]

    /// Damaged binary and ascii PLY files (or random bytes) never panic the reader, and an
    /// error always names the file.
    #[test]
    fn damaged_ply_never_panics(
        binary in mutate::damaged(sample_ply_bytes()),
        ascii in mutate::damaged(ASCII_PLY.to_vec()),
    ) {
        let dir = tempfile::tempdir().unwrap();
        for (name, bytes) in [("binary.ply", binary), ("ascii.ply", ascii)] {
            let path = write(dir.path(), name, &bytes);
            if let Err(error) = read_point_cloud(&path) {
                proptest::prop_assert!(error.to_string().contains(name), "{}", error);
            }
        }
    }
}

/// An ascii PLY with colours, normals and a face element.
const ASCII_PLY: &[u8] = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\n\
    property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n\
    property uchar blue\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n\
    1 2 3 255 0 0\n-1 0.5 2e1 0 128 255\n3 0 1 0\n";

/// The sample cloud as binary PLY bytes.
fn sample_ply_bytes() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sample.ply");
    write_point_cloud_ply(&path, &sample_points()).unwrap();
    std::fs::read(path).unwrap()
}
