//! N3DV (Neural 3D Video, "DyNeRF") multi-view videos in the LLFF layout.
//!
//! A scene folder holds `poses_bounds.npy` — float64, N × 17: per camera a row-major 3 × 5
//! matrix `[R | c | hwf]` (camera-to-world rotation with columns *down, right, backwards*,
//! camera centre, and image height, width, focal length) followed by near/far bounds — and
//! one set of frames per camera, the i-th camera (in natural name order) matching the i-th
//! pose row. Frames are taken from the first of these that exists for a camera `camXX`:
//!
//! 1. `<path>/frames/camXX/*.png` (or `.jpg`) — e.g. extracted once with
//!    `ffmpeg -i camXX.mp4 <path>/frames/camXX/%06d.png`;
//! 2. `<path>/camXX/images/*.png` (or `.jpg`);
//! 3. `<path>/camXX.mp4`, decoded at load time with the system `ffmpeg` and `ffprobe`.
//!
//! Frame files are ordered by the number in their name; a gap in the numbering is an error,
//! since it would shift every later frame in time.
//!
//! The `hwf` column is read as the intrinsics at `w × h` pixels and rescaled to the size of
//! the frames actually found (N3DV's `hwf` is given for 1352 × 1014 while its videos are
//! 2704 × 2028), then divided by `downscale`; the principal point is the image centre.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use glam::{DMat3, DVec3, Mat4};
use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::error::{
    check_downscale, check_image_size, image_dimensions, read_rgb8, require_folder,
};
use super::settings::{check_cache_mb, check_downscale_factor};
use super::{Camera, DataError, Dataset, FrameCache, ViewImage, stream};
use crate::io::image::{box_downscale, box_downscale_owned};
use crate::scene::FieldError;

/// Where and how to read an N3DV scene (the `n3dv` source of a RON scene file).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct N3dvSource {
    /// Scene folder holding `poses_bounds.npy` and the videos or frame folders.
    pub path: String,
    /// Use only the first `frames` frames of every camera (all, when absent).
    #[serde(default)]
    pub frames: Option<usize>,
    /// Integer factor to shrink frames by (box filter). The default 2 gives the paper's
    /// protocol: N3DV's 2704 × 2028 videos are trained and evaluated at 1352 × 1014.
    #[serde(default = "default_downscale")]
    pub downscale: u32,
    /// Cameras held out for evaluation, as indices into the pose rows. The default `[0]`
    /// holds out `cam00`, the centre camera, as in the N3DV benchmark.
    #[serde(default = "default_test_cameras")]
    pub test_cameras: Vec<usize>,
    /// Stream the frames from disk through a cache of this many megabytes instead of decoding
    /// them all up front (frame folders only; see `tadgs::data::stream`). `None` (the default)
    /// loads them all unless they would take more than half the available memory.
    #[serde(default)]
    pub cache_mb: Option<f64>,
}

fn default_downscale() -> u32 {
    2
}

fn default_test_cameras() -> Vec<usize> {
    vec![0]
}

impl N3dvSource {
    /// Checks the settings (not the files): downscale, frame count, held-out cameras.
    pub fn check(&self) -> Result<(), FieldError> {
        check_downscale_factor(self.downscale)?;
        if self.frames == Some(0) {
            return Err(FieldError::new("frames", "must be at least 1 when given"));
        }
        if self.test_cameras.is_empty() {
            return Err(FieldError::new(
                "test_cameras",
                "hold out at least one camera",
            ));
        }
        check_cache_mb(self.cache_mb)
    }

    /// A source for the scene at `path` with the benchmark's defaults.
    pub fn new(path: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            frames: None,
            downscale: default_downscale(),
            test_cameras: default_test_cameras(),
            cache_mb: None,
        }
    }
}

/// Name of the pose file inside a scene folder.
pub const POSES_FILE: &str = "poses_bounds.npy";

/// Values per pose row: a 3 × 5 matrix and the near/far bounds.
const ROW_LENGTH: usize = 17;

/// One row of `poses_bounds.npy`, still in LLFF's convention.
#[derive(Clone, Copy, Debug)]
struct LlffPose {
    /// Row-major 3 × 5 `[R | c | hwf]`.
    matrix: [[f64; 5]; 3],
}

/// Where one camera's frames come from.
#[derive(Clone, Debug)]
pub(crate) enum FrameSource {
    Folder(PathBuf),
    Video(PathBuf),
}

impl FrameSource {
    fn path(&self) -> &Path {
        match self {
            Self::Folder(p) | Self::Video(p) => p,
        }
    }
}

/// A camera's frames after loading: their size before downscaling, and the images.
pub(crate) struct LoadedFrames {
    /// The frame folder or video they came from (for errors).
    path: PathBuf,
    full_size: (u32, u32),
    pub(crate) images: Vec<ViewImage>,
}

/// A check and transformation of each full-size frame before it is downscaled, given the file
/// (or video) it came from: undistortion for a calibrated rig, nothing for N3DV.
type PrepareFrame<'a> = dyn Fn(&Path, RgbImage) -> Result<RgbImage, DataError> + Sync + 'a;

/// Loads an N3DV scene: one [`Camera`] per pose row, every camera × frame as a
/// [`View`](super::View); views of `test_cameras` go to [`Dataset::test`], the rest to
/// [`Dataset::train`].
pub fn load(source: &N3dvSource) -> Result<Dataset, DataError> {
    let root = Path::new(&source.path);
    let poses_path = root.join(POSES_FILE);
    source.check().map_err(|e| DataError::setting(root, e))?;
    let poses = read_poses(&poses_path)?;
    for &test in &source.test_cameras {
        if test >= poses.len() {
            return Err(DataError::field(
                root,
                "test_cameras",
                format!(
                    "camera {test} does not exist: {} has {} poses (cameras 0 to {})",
                    poses_path.display(),
                    poses.len(),
                    poses.len() - 1
                ),
            ));
        }
    }
    if (0..poses.len()).all(|c| source.test_cameras.contains(&c)) {
        return Err(DataError::field(
            root,
            "test_cameras",
            "every camera is held out: no camera is left to train on",
        ));
    }

    let sources = find_frame_sources(root)?;
    if sources.len() != poses.len() {
        let names: Vec<&str> = sources.iter().map(|(name, _)| name.as_str()).collect();
        return Err(DataError::dataset(
            &poses_path,
            format!(
                "{} camera poses, but {} cameras found in {} ({names:?}); give one video \
                 camXX.mp4, one folder frames/camXX/ or one folder camXX/images/ per pose row",
                poses.len(),
                sources.len(),
                root.display()
            ),
        ));
    }

    let listings = folder_listings(&sources, source.frames)?;
    let (per_camera, frame_count) = match streaming_cache(listings.as_deref(), source) {
        Some(cache) => {
            let Some(listings) = listings else {
                let video = sources
                    .iter()
                    .find_map(|(_, frames)| match frames {
                        FrameSource::Video(video) => Some(video),
                        FrameSource::Folder(_) => None,
                    })
                    .expect("a camera without a frame folder has a video");
                return Err(DataError::dataset(
                    video,
                    "videos cannot be streamed from disk: extract the frames once \
                     (ffmpeg -i camXX.mp4 frames/camXX/%06d.png), or leave data.cache_mb \
                     unset and load the frames into memory",
                ));
            };
            let per_camera = sources
                .iter()
                .zip(listings)
                .map(|((_, frames), (files, full_size))| {
                    stream_frame_folder(frames.path(), files, full_size, source.downscale, &cache)
                })
                .collect::<Result<Vec<_>, _>>()?;
            check_frame_counts(root, per_camera, source.frames)?
        }
        None => load_cameras(
            root,
            sources.iter().map(|(_, frames)| frames),
            source.frames,
            source.downscale,
            &|_, _, image| Ok(image),
        )?,
    };

    let mut cameras = Vec::with_capacity(poses.len());
    for (index, (pose, frames)) in poses.iter().zip(&per_camera).enumerate() {
        cameras.push(pose_to_camera(
            &poses_path,
            index,
            pose,
            frames.full_size,
            source.downscale,
            sources[index].1.path(),
        )?);
    }

    let mut dataset = Dataset {
        cameras,
        frame_count,
        ..Dataset::default()
    };
    for (camera, frames) in per_camera.into_iter().enumerate() {
        let held_out = source.test_cameras.contains(&camera);
        dataset.push_camera_frames(camera, frames.images, held_out);
    }
    Ok(dataset)
}

/// Reads and checks `poses_bounds.npy`: float64, shape N × 17.
fn read_poses(path: &Path) -> Result<Vec<LlffPose>, DataError> {
    let file = std::fs::File::open(path).map_err(|e| DataError::io(path, e))?;
    let npy = npyz::NpyFile::new(std::io::BufReader::new(file))
        .map_err(|e| DataError::format(path, format!("not a valid NumPy .npy file: {e}")))?;
    let dtype = npy.dtype();
    let is_float64 = matches!(
        &dtype,
        npyz::DType::Plain(t) if t.type_char() == npyz::TypeChar::Float && t.size_field() == 8
    );
    if !is_float64 {
        return Err(DataError::field(
            path,
            "dtype",
            format!("expected float64 ('<f8'), found {}", dtype.descr()),
        ));
    }
    let shape = npy.shape().to_vec();
    if shape.len() != 2 || shape[1] != ROW_LENGTH as u64 || shape[0] == 0 {
        return Err(DataError::field(
            path,
            "shape",
            format!(
                "expected N×{ROW_LENGTH} (per camera a 3×5 [R|t|hwf] pose and near/far bounds, \
                 N ≥ 1), found {shape:?}"
            ),
        ));
    }
    let rows = shape[0] as usize;
    let fortran = npy.order() == npyz::Order::Fortran;
    let values: Vec<f64> = npy
        .into_vec()
        .map_err(|e| DataError::format(path, format!("truncated or unreadable array data: {e}")))?;
    let at = |row: usize, column: usize| {
        if fortran {
            values[column * rows + row]
        } else {
            values[row * ROW_LENGTH + column]
        }
    };
    let mut poses = Vec::with_capacity(rows);
    for row in 0..rows {
        let mut matrix = [[0.0; 5]; 3];
        for (r, matrix_row) in matrix.iter_mut().enumerate() {
            for (c, value) in matrix_row.iter_mut().enumerate() {
                *value = at(row, r * 5 + c);
            }
        }
        if matrix.iter().flatten().any(|v| !v.is_finite()) {
            return Err(DataError::field(
                path,
                format!("row {row}"),
                "pose has non-finite values",
            ));
        }
        poses.push(LlffPose { matrix });
    }
    Ok(poses)
}

/// Builds the OpenCV camera of pose row `index`, for frames of `full_size` before downscaling.
fn pose_to_camera(
    poses_path: &Path,
    index: usize,
    pose: &LlffPose,
    full_size: (u32, u32),
    downscale: u32,
    frames_path: &Path,
) -> Result<Camera, DataError> {
    let m = &pose.matrix;
    let column = |c: usize| DVec3::new(m[0][c], m[1][c], m[2][c]);
    // LLFF camera axes (in world coordinates) are [down, right, backwards]; OpenCV's are
    // [right, down, forwards].
    let (down, right, backwards, centre) = (column(0), column(1), column(2), column(3));
    let camera_to_world = DMat3::from_cols(right, down, -backwards);
    let orthonormal_error = (camera_to_world.transpose() * camera_to_world - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |worst, v| worst.max(v.abs()));
    if orthonormal_error > 1e-3 || camera_to_world.determinant() < 0.0 {
        return Err(DataError::field(
            poses_path,
            format!("row {index}"),
            "the 3×3 rotation [down, right, backwards] is not a proper rotation",
        ));
    }
    let rotation = camera_to_world.transpose();
    let translation = -(rotation * centre);
    let world_to_camera = Mat4::from_cols(
        rotation.x_axis.as_vec3().extend(0.0),
        rotation.y_axis.as_vec3().extend(0.0),
        rotation.z_axis.as_vec3().extend(0.0),
        translation.as_vec3().extend(1.0),
    );

    let [pose_height, pose_width, focal] = [m[0][4], m[1][4], m[2][4]];
    if pose_height <= 0.0 || pose_width <= 0.0 || focal <= 0.0 {
        return Err(DataError::field(
            poses_path,
            format!("row {index} hwf"),
            format!(
                "height, width and focal must be positive, found {pose_height}, {pose_width}, {focal}"
            ),
        ));
    }
    let (full_width, full_height) = full_size;
    let scale_x = f64::from(full_width) / pose_width;
    let scale_y = f64::from(full_height) / pose_height;
    if (scale_x / scale_y - 1.0).abs() > 0.01 {
        tracing::warn!(
            "{}: frames are {full_width}×{full_height} but {} row {index} says {pose_width}×{pose_height}: \
             different aspect ratios, focal lengths rescaled per axis",
            frames_path.display(),
            poses_path.display()
        );
    }
    let width = full_width / downscale;
    let height = full_height / downscale;
    let downscale = f64::from(downscale);
    Ok(Camera {
        width,
        height,
        fx: (focal * scale_x / downscale) as f32,
        fy: (focal * scale_y / downscale) as f32,
        cx: 0.5 * width as f32,
        cy: 0.5 * height as f32,
        world_to_camera,
    })
}

// ---------------------------------------------------------------------------------------
// Finding and loading frames
// ---------------------------------------------------------------------------------------

/// Cameras found under `root`, in natural name order, each with where its frames come from.
fn find_frame_sources(root: &Path) -> Result<Vec<(String, FrameSource)>, DataError> {
    require_folder(root)?;
    let mut names: Vec<String> = Vec::new();
    let mut add = |name: String| {
        if !names.contains(&name) {
            names.push(name);
        }
    };
    for entry in list_dir(root)? {
        let file_name = entry_name(&entry);
        if !file_name.starts_with("cam") {
            continue;
        }
        if entry.is_dir() && entry.join("images").is_dir() {
            add(file_name);
        } else if let Some(stem) = file_name.strip_suffix(".mp4") {
            add(stem.to_owned());
        }
    }
    let frames_dir = root.join("frames");
    if frames_dir.is_dir() {
        for entry in list_dir(&frames_dir)? {
            let file_name = entry_name(&entry);
            if file_name.starts_with("cam") && entry.is_dir() {
                add(file_name);
            }
        }
    }
    names.sort_by_cached_key(|name| natural_key(name));

    Ok(names
        .into_iter()
        .map(|name| {
            let extracted = frames_dir.join(&name);
            let images = root.join(&name).join("images");
            let video = root.join(format!("{name}.mp4"));
            let source = if has_frames(&extracted) || (extracted.is_dir() && !video.is_file()) {
                FrameSource::Folder(extracted)
            } else if has_frames(&images) || (images.is_dir() && !video.is_file()) {
                FrameSource::Folder(images)
            } else {
                FrameSource::Video(video)
            };
            (name, source)
        })
        .collect())
}

pub(crate) fn list_dir(dir: &Path) -> Result<Vec<PathBuf>, DataError> {
    let entries = std::fs::read_dir(dir).map_err(|e| DataError::io(dir, e))?;
    entries
        .map(|entry| entry.map(|e| e.path()).map_err(|e| DataError::io(dir, e)))
        .collect()
}

pub(crate) fn entry_name(path: &Path) -> String {
    path.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default()
}

/// Sort key that orders `cam2` before `cam10` and `9.png` before `10.png`.
pub(crate) fn natural_key(name: &str) -> (String, Option<u64>, String) {
    let stem = name.split('.').next().unwrap_or(name);
    let digits_start = stem.trim_end_matches(|c: char| c.is_ascii_digit()).len();
    let number = stem[digits_start..].parse().ok();
    (stem[..digits_start].to_owned(), number, name.to_owned())
}

fn is_frame_file(path: &Path) -> bool {
    path.is_file()
        && path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
}

fn has_frames(dir: &Path) -> bool {
    std::fs::read_dir(dir)
        .is_ok_and(|mut entries| entries.any(|e| e.is_ok_and(|e| is_frame_file(&e.path()))))
}

/// Loads each camera's frames with [`load_frames`] (`prepare` is also given the camera's
/// index), checks that every camera has the `limit` frames asked for, and returns them with the
/// number of frames all cameras have: the shortest camera's, with a warning when they differ.
pub(crate) fn load_cameras<'a>(
    root: &Path,
    sources: impl IntoIterator<Item = &'a FrameSource>,
    limit: Option<usize>,
    downscale: u32,
    prepare: &(dyn Fn(usize, &Path, RgbImage) -> Result<RgbImage, DataError> + Sync),
) -> Result<(Vec<LoadedFrames>, usize), DataError> {
    let mut per_camera = Vec::new();
    for (camera, frame_source) in sources.into_iter().enumerate() {
        per_camera.push(load_frames(
            frame_source,
            limit,
            downscale,
            &|path, image| prepare(camera, path, image),
        )?);
    }
    check_frame_counts(root, per_camera, limit)
}

/// Checks that every camera has the `limit` frames asked for and returns the cameras' frames
/// with the number all of them have: the shortest camera's, with a warning when they differ.
fn check_frame_counts(
    root: &Path,
    per_camera: Vec<LoadedFrames>,
    limit: Option<usize>,
) -> Result<(Vec<LoadedFrames>, usize), DataError> {
    for frames in &per_camera {
        if let Some(wanted) = limit
            && frames.images.len() < wanted
        {
            return Err(DataError::dataset(
                &frames.path,
                format!(
                    "has {} frames, but `frames` asks for {wanted}",
                    frames.images.len()
                ),
            ));
        }
    }
    let frame_count = per_camera.iter().map(|f| f.images.len()).min().unwrap_or(0);
    let longest = per_camera.iter().map(|f| f.images.len()).max().unwrap_or(0);
    if frame_count != longest {
        tracing::warn!(
            "{}: cameras have between {frame_count} and {longest} frames; using the first {frame_count}",
            root.display()
        );
    }
    Ok((per_camera, frame_count))
}

/// Reads up to `limit` frames of one camera, each passed through `prepare` at full size and
/// then downscaled.
fn load_frames(
    source: &FrameSource,
    limit: Option<usize>,
    downscale: u32,
    prepare: &PrepareFrame,
) -> Result<LoadedFrames, DataError> {
    match source {
        FrameSource::Folder(dir) => load_frame_folder(dir, limit, downscale, prepare),
        FrameSource::Video(video) => decode_video(video, limit, downscale, prepare),
    }
}

/// Frame files of a folder, in numeric order, checked for gaps in their numbering.
fn list_frame_files(dir: &Path) -> Result<Vec<PathBuf>, DataError> {
    let mut files: Vec<PathBuf> = list_dir(dir)?
        .into_iter()
        .filter(|p| is_frame_file(p))
        .collect();
    files.sort_by_cached_key(|p| natural_key(&entry_name(p)));
    if files.is_empty() {
        return Err(DataError::dataset(
            dir,
            "no frames (*.png or *.jpg) in this folder",
        ));
    }
    let numbers: Option<Vec<u64>> = files
        .iter()
        .map(|p| p.file_stem()?.to_str()?.parse().ok())
        .collect();
    if let Some(numbers) = numbers {
        for (pair, files) in numbers.windows(2).zip(files.windows(2)) {
            if pair[1] != pair[0] + 1 {
                return Err(DataError::dataset(
                    dir,
                    format!(
                        "frames are missing between {} and {} (frame numbers must be consecutive)",
                        entry_name(&files[0]),
                        entry_name(&files[1])
                    ),
                ));
            }
        }
    }
    Ok(files)
}

fn load_frame_folder(
    dir: &Path,
    limit: Option<usize>,
    downscale: u32,
    prepare: &PrepareFrame,
) -> Result<LoadedFrames, DataError> {
    let mut files = list_frame_files(dir)?;
    if let Some(limit) = limit {
        files.truncate(limit);
    }
    let first = read_rgb8(&files[0], None)?;
    let full_size = first.dimensions();
    check_downscale(&files[0], full_size, downscale)?;
    let mut images = vec![ViewImage::from(box_downscale(
        &prepare(&files[0], first)?,
        downscale,
    ))];
    let rest: Vec<ViewImage> = files[1..]
        .par_iter()
        .map(|file| {
            let image = prepare(file, read_rgb8(file, Some(full_size))?)?;
            Ok(box_downscale(&image, downscale).into())
        })
        .collect::<Result<_, DataError>>()?;
    images.extend(rest);
    Ok(LoadedFrames {
        path: dir.to_path_buf(),
        full_size,
        images,
    })
}

/// The frame files of a folder up to `limit`, and their full size (the first frame's).
fn frame_files(dir: &Path, limit: Option<usize>) -> Result<(Vec<PathBuf>, (u32, u32)), DataError> {
    let mut files = list_frame_files(dir)?;
    if let Some(limit) = limit {
        files.truncate(limit);
    }
    let full_size = image_dimensions(&files[0])?;
    Ok((files, full_size))
}

/// Every camera's frame files (at most `limit`) and first-frame size, when every camera is a
/// frame folder; `None` when a camera has a video.
fn folder_listings(
    sources: &[(String, FrameSource)],
    limit: Option<usize>,
) -> Result<Option<Vec<FrameListing>>, DataError> {
    let listings = sources
        .iter()
        .map(|(_, frames)| match frames {
            FrameSource::Folder(dir) => frame_files(dir, limit).map(Some),
            FrameSource::Video(_) => Ok(None),
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(listings.into_iter().collect())
}

/// A camera's frame files and the full size of its first frame.
type FrameListing = (Vec<PathBuf>, (u32, u32));

/// The cache to stream the frames through (`data.cache_mb`, or the decoded frames would take
/// more than half the available memory), or `None` to load them. Only frame folders
/// (`listings`) are measured up front; a scene with videos is loaded unless `cache_mb` is
/// given.
fn streaming_cache(
    listings: Option<&[FrameListing]>,
    source: &N3dvSource,
) -> Option<std::sync::Arc<FrameCache>> {
    let Some(listings) = listings else {
        return source.cache_mb.and_then(|mb| stream::plan(Some(mb), 0));
    };
    let d = source.downscale;
    let total_bytes = listings
        .iter()
        .map(|(files, (width, height))| {
            files.len() as u64 * 3 * u64::from(width / d) * u64::from(height / d)
        })
        .sum();
    stream::plan(source.cache_mb, total_bytes)
}

/// A camera's frame folder as streamed views: each frame's size is checked from its header
/// now and the pixels decoded when training or evaluation needs them.
fn stream_frame_folder(
    dir: &Path,
    files: Vec<PathBuf>,
    full_size: (u32, u32),
    downscale: u32,
    cache: &std::sync::Arc<FrameCache>,
) -> Result<LoadedFrames, DataError> {
    check_downscale(&files[0], full_size, downscale)?;
    let size = (full_size.0 / downscale, full_size.1 / downscale);
    let images = files
        .par_iter()
        .map(|file| {
            check_image_size(file, full_size)?;
            let path = file.clone();
            Ok(ViewImage::streamed(file, size, cache, move || {
                Ok(box_downscale_owned(
                    read_rgb8(&path, Some(full_size))?,
                    downscale,
                ))
            }))
        })
        .collect::<Result<_, DataError>>()?;
    Ok(LoadedFrames {
        path: dir.to_path_buf(),
        full_size,
        images,
    })
}

// ---------------------------------------------------------------------------------------
// Video decoding through the system ffmpeg
// ---------------------------------------------------------------------------------------

/// The error for a camera that has only a video when ffmpeg cannot be run.
fn ffmpeg_missing(video: &Path, tool: &str, error: &std::io::Error) -> DataError {
    let camera = video
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let frames_dir = video.with_file_name("frames").join(camera);
    DataError::dataset(
        video,
        format!(
            "cannot run `{tool}` ({error}) to decode this video: install FFmpeg (e.g. \
             `apt-get install ffmpeg`, `brew install ffmpeg`) or extract the frames beforehand \
             to {}/000000.png, 000001.png, ...",
            frames_dir.display()
        ),
    )
}

/// Width and height of the first video stream, from `ffprobe`.
fn probe_video_size(video: &Path) -> Result<(u32, u32), DataError> {
    let output = Command::new("ffprobe")
        .args([
            "-v",
            "error",
            "-select_streams",
            "v:0",
            "-show_entries",
            "stream=width,height",
        ])
        .args(["-of", "csv=p=0:s=x"])
        .arg(video)
        .stdin(Stdio::null())
        .output()
        .map_err(|e| ffmpeg_missing(video, "ffprobe", &e))?;
    let text = String::from_utf8_lossy(&output.stdout);
    let parsed = text.trim().lines().next().and_then(|line| {
        let (w, h) = line.split_once('x')?;
        Some((w.trim().parse::<u32>().ok()?, h.trim().parse::<u32>().ok()?))
    });
    match parsed {
        Some((w, h)) if output.status.success() && w > 0 && h > 0 => Ok((w, h)),
        _ => Err(DataError::format(
            video,
            format!(
                "ffprobe found no video stream: {}",
                String::from_utf8_lossy(&output.stderr).trim()
            ),
        )),
    }
}

/// Decodes up to `limit` frames as raw RGB through an ffmpeg pipe (no temporary files),
/// downscaling each frame as it arrives so full-resolution frames are never all in memory.
fn decode_video(
    video: &Path,
    limit: Option<usize>,
    downscale: u32,
    prepare: &PrepareFrame,
) -> Result<LoadedFrames, DataError> {
    if !video.is_file() {
        return Err(DataError::dataset(
            video,
            "no such video, and no frame folder for this camera",
        ));
    }
    let full_size = probe_video_size(video)?;
    check_downscale(video, full_size, downscale)?;
    let mut command = Command::new("ffmpeg");
    command
        .args(["-v", "error", "-nostdin", "-noautorotate", "-i"])
        .arg(video);
    if let Some(limit) = limit {
        command.args(["-frames:v", &limit.to_string()]);
    }
    command
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24", "pipe:1"])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    let mut child = command
        .spawn()
        .map_err(|e| ffmpeg_missing(video, "ffmpeg", &e))?;
    let mut stdout = child.stdout.take().expect("stdout was piped");
    let mut stderr = child.stderr.take().expect("stderr was piped");
    // Drain stderr on its own thread so a chatty ffmpeg cannot block on a full pipe.
    let stderr_thread = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });

    let (width, height) = full_size;
    let frame_bytes = width as usize * height as usize * 3;
    let mut buffer = vec![0u8; frame_bytes];
    let mut images = Vec::new();
    let mut read_error = None;
    let mut prepare_error = None;
    loop {
        match fill(&mut stdout, &mut buffer) {
            Ok(0) => break,
            Ok(n) if n == frame_bytes => {
                let frame = RgbImage::from_raw(
                    width,
                    height,
                    std::mem::replace(&mut buffer, vec![0; frame_bytes]),
                )
                .expect("buffer holds exactly one frame");
                match prepare(video, frame) {
                    Ok(frame) => images.push(box_downscale(&frame, downscale).into()),
                    Err(error) => {
                        prepare_error = Some(error);
                        break;
                    }
                }
            }
            Ok(n) => {
                read_error = Some(format!(
                    "ffmpeg output ended inside frame {} ({n} of {frame_bytes} bytes)",
                    images.len()
                ));
                break;
            }
            Err(e) => {
                read_error = Some(format!("reading ffmpeg output: {e}"));
                break;
            }
        }
    }
    drop(stdout);
    if let Some(error) = prepare_error {
        let _ = child.kill();
        let _ = child.wait();
        let _ = stderr_thread.join();
        return Err(error);
    }
    let status = child.wait().map_err(|e| DataError::io(video, e))?;
    let stderr_text = stderr_thread.join().unwrap_or_default();
    if !status.success() || read_error.is_some() {
        return Err(DataError::format(
            video,
            format!(
                "ffmpeg could not decode the video ({status}){}: {}",
                read_error.map(|e| format!(", {e}")).unwrap_or_default(),
                stderr_text.trim()
            ),
        ));
    }
    if images.is_empty() {
        return Err(DataError::format(video, "the video has no frames"));
    }
    Ok(LoadedFrames {
        path: video.to_path_buf(),
        full_size,
        images,
    })
}

/// Reads until `buffer` is full or the stream ends; returns the bytes read.
fn fill(reader: &mut impl Read, buffer: &mut [u8]) -> std::io::Result<usize> {
    let mut filled = 0;
    while filled < buffer.len() {
        match reader.read(&mut buffer[filled..]) {
            Ok(0) => break,
            Ok(n) => filled += n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(e),
        }
    }
    Ok(filled)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn natural_order_puts_cam2_before_cam10() {
        let mut names = vec!["cam10", "cam2", "cam01", "frame.png", "10.png", "9.png"];
        names.sort_by_key(|n| natural_key(n));
        assert_eq!(
            names,
            ["9.png", "10.png", "cam01", "cam2", "cam10", "frame.png"]
        );
    }
}
