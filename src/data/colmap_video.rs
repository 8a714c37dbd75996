//! Multi-view videos calibrated with COLMAP, in two layouts: the `ColmapFrames` and `ColmapRig`
//! sources of a scene file (both set up by a [`ColmapSource`]).
//!
//! **Per-frame folders** ([`load_frames`]), as the preprocessing of SpacetimeGaussians and of
//! the TAD-GS authors (`pre_n3d.py`) writes an N3DV scene:
//!
//! ```text
//! <path>/colmap_0/images/cam00.png … cam20.png
//! <path>/colmap_0/sparse/0/{cameras,images,points3D}.bin    (or .txt)
//! <path>/colmap_1/images/cam00.png …                         (no model: COLMAP did not run here)
//! …
//! <path>/colmap_20/sparse/0/…                                (every 20th frame and the last)
//! ```
//!
//! Frame k is the k-th `colmap_<n>` folder in numeric order (the numbers must be consecutive);
//! its images are `colmap_<n>/images/<image name>`. The cameras, their intrinsics and poses
//! are those of the first frame with a model (`sparse/0`, `sparse`, or the model files in the
//! frame folder; the authors' `manual/` models are not read). Every other model must register
//! the same cameras with the same poses and sizes, since the trainer assumes a static rig: a
//! camera missing or moved is an error naming both frames; intrinsics that differ are only
//! warned about (the first frame's are used). The points of every model — or the dense cloud
//! `dense/workspace/fused_downsample.ply` where the authors' dense preprocessing wrote one —
//! initialise that frame's anchor ([`Dataset::frame_points`]), as in the paper.
//!
//! **A rig model with frame folders** ([`load_rig`]): one model of the static rig in
//! `<path>/sparse/0/` (or `<path>/sparse/`, or `<path>` itself) registering one image per
//! camera, and each camera's frames in `<path>/frames/<camera>/<index>.png` (or `.jpg`,
//! numbered consecutively, as N3DV's frame folders) or, without that folder, the video
//! `<path>/<camera>.mp4` decoded by the system `ffmpeg`. The model's points initialise every
//! anchor frame.
//!
//! In both layouts a camera is named after its image ([`camera_name`]: `cam00.png` is camera
//! `cam00`, `cam00/000000.png` too), cameras are ordered by name (`cam2` before `cam10`), and
//! `test_cameras` names the held-out ones: by default `cam00`, N3DV's centre camera, which the
//! authors hold out. Distorted perspective cameras (SIMPLE_RADIAL, RADIAL, OPENCV,
//! FULL_OPENCV) are undistorted once at load time onto the pinhole camera with the same
//! intrinsics ([`super::undistort`]); fisheye models are refused.

use std::path::{Path, PathBuf};

use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::colmap::{self, ColmapImage};
use super::error::{check_downscale, read_rgb8, require_folder};
use super::n3dv::{self, FrameSource};
use super::settings::{self, check_background, check_downscale_factor};
use super::undistort::{Distortion, Undistortion};
use super::{Camera, DataError, Dataset};
use crate::init::InitPoint;
use crate::io::image::box_downscale;
use crate::scene::FieldError;

/// Where and how to read a COLMAP-calibrated video (the `ColmapFrames` and `ColmapRig`
/// sources of a scene file).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ColmapSource {
    /// The scene folder: the one holding `colmap_<frame>/` folders (`ColmapFrames`), or the
    /// rig's model and `frames/` (`ColmapRig`).
    pub path: String,
    /// Use only the first `frames` frames (all, when absent).
    #[serde(default)]
    pub frames: Option<usize>,
    /// Integer factor to shrink images by (box filter, intrinsics scaled to match). The
    /// default 1 keeps the images as they are: the authors' N3DV preprocessing has already
    /// halved them to 1352 × 1014.
    #[serde(default = "settings::one")]
    pub downscale: u32,
    /// Names of the held-out cameras ([`camera_name`] of their images); `[]` holds none out.
    /// The default `["cam00"]` is the N3DV benchmark's.
    #[serde(default = "default_test_cameras")]
    pub test_cameras: Vec<String>,
    /// Colour (RGB in [0, 1]) of the pixels that undistortion finds no source for.
    #[serde(default = "black")]
    pub background: [f32; 3],
}

fn default_test_cameras() -> Vec<String> {
    vec!["cam00".into()]
}

fn black() -> [f32; 3] {
    [0.0; 3]
}

impl ColmapSource {
    /// A source for the scene at `path` with the defaults: every frame, full size, `cam00`
    /// held out, black background.
    pub fn new(path: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            frames: None,
            downscale: settings::one(),
            test_cameras: default_test_cameras(),
            background: black(),
        }
    }

    /// Checks the settings (not the files): frame count, downscale, background colour.
    pub fn check(&self) -> Result<(), FieldError> {
        check_downscale_factor(self.downscale)?;
        if self.frames == Some(0) {
            return Err(FieldError::new("frames", "must be at least 1 when given"));
        }
        check_background(&self.background)
    }

    /// The scene folder, after the settings and the folder itself are checked.
    fn root(&self) -> Result<&Path, DataError> {
        let root = Path::new(&self.path);
        self.check().map_err(|e| DataError::setting(root, e))?;
        require_folder(root)?;
        Ok(root)
    }
}

/// The name of the camera that took the COLMAP image `image_name`: the folder the image is in,
/// where it is in one (`cam00/000000.png` → `cam00`), otherwise the name without its extension
/// (`cam00.png` → `cam00`).
pub fn camera_name(image_name: &str) -> String {
    let path = Path::new(image_name);
    let folder = path.parent().and_then(Path::file_name);
    folder.or_else(|| path.file_stem()).map_or_else(
        || image_name.to_owned(),
        |n| n.to_string_lossy().into_owned(),
    )
}

/// Largest difference of a rotation entry, and of the translation or an intrinsic relative to
/// its size (at least 1), for two models of one camera to count as the same.
const POSE_TOLERANCE: f32 = 1e-4;

/// Reads per-frame COLMAP folders `colmap_<frame>/` (see the module documentation).
pub fn load_frames(source: &ColmapSource) -> Result<Dataset, DataError> {
    let root = source.root()?;
    let folders = frame_folders(root, source.frames)?;
    let mut reference: Option<Rig> = None;
    let mut frame_points = Vec::new();
    for (frame, folder) in folders.iter().enumerate() {
        let Some(mut rig) = read_rig(folder)? else {
            continue;
        };
        let points = frame_cloud(folder, std::mem::take(&mut rig.points))?;
        if points.is_empty() {
            tracing::warn!(
                "{}: the model has no points; frame {frame} has no point cloud of its own",
                rig.images_path.display()
            );
        } else {
            frame_points.push((frame, points));
        }
        match &reference {
            Some(reference) => check_same_rig(reference, &rig)?,
            None => reference = Some(rig),
        }
    }
    let rig = reference.ok_or_else(|| {
        DataError::dataset(
            root,
            format!(
                "none of the {} frame folders has a COLMAP model: expected \
                 colmap_<frame>/sparse/0/cameras.bin, images.bin, points3D.bin (or .txt) in at \
                 least one of them",
                folders.len()
            ),
        )
    })?;
    let held_out = held_out_cameras(root, &rig, &source.test_cameras)?;
    let preparations = rig.preparations(source)?;

    // Camera-major, so that each camera's frames come out together and in order.
    let frame_count = folders.len();
    let jobs: Vec<(usize, &Path)> = (0..rig.len())
        .flat_map(|camera| folders.iter().map(move |f| (camera, f.as_path())))
        .collect();
    let images: Vec<RgbImage> = jobs
        .par_iter()
        .map(|&(camera, folder)| {
            let path = folder.join("images").join(&rig.images[camera].name);
            let image = preparations[camera].prepare(&path, read_rgb8(&path, None)?)?;
            Ok(box_downscale(&image, source.downscale))
        })
        .collect::<Result<_, DataError>>()?;

    let mut dataset = rig.dataset(frame_count, source.downscale);
    let mut images = images.into_iter();
    for (camera, held_out) in held_out.into_iter().enumerate() {
        let frames = images.by_ref().take(frame_count).collect();
        dataset.push_camera_frames(camera, frames, held_out);
    }
    dataset.frame_points = frame_points;
    Ok(dataset)
}

/// Reads a rig's COLMAP model and per-camera frame folders or videos (see the module
/// documentation).
pub fn load_rig(source: &ColmapSource) -> Result<Dataset, DataError> {
    let root = source.root()?;
    let mut rig = read_rig(root)?.ok_or_else(|| {
        DataError::dataset(
            root,
            "no COLMAP model of the rig: expected sparse/0/cameras.bin, images.bin and \
             points3D.bin (or .txt), or the same in sparse/ or in this folder",
        )
    })?;
    let held_out = held_out_cameras(root, &rig, &source.test_cameras)?;
    let preparations = rig.preparations(source)?;
    let sources = rig
        .names
        .iter()
        .map(|name| rig_frame_source(root, name))
        .collect::<Result<Vec<_>, _>>()?;
    let (per_camera, frame_count) = n3dv::load_cameras(
        root,
        &sources,
        source.frames,
        source.downscale,
        &|camera, path, image| preparations[camera].prepare(path, image),
    )?;
    let mut dataset = rig.dataset(frame_count, source.downscale);
    for (camera, (frames, held_out)) in per_camera.into_iter().zip(held_out).enumerate() {
        dataset.push_camera_frames(camera, frames.images, held_out);
    }
    let points = std::mem::take(&mut rig.points);
    dataset.points = (!points.is_empty()).then_some(points);
    Ok(dataset)
}

/// The cameras of one COLMAP model as a static rig: one per registered image, ordered by name.
struct Rig {
    /// The model's images file, named in errors.
    images_path: PathBuf,
    /// Camera names ([`camera_name`]), in rig order.
    names: Vec<String>,
    /// The registered images (pinhole camera and pose), in rig order.
    images: Vec<ColmapImage>,
    /// The lens distortion of each image's camera, in rig order.
    distortions: Vec<Distortion>,
    /// The model's 3D points.
    points: Vec<InitPoint>,
}

/// Reads the COLMAP model in `dir` (or its `sparse/0`, `sparse`) as a rig; `None` when there
/// is no model there.
fn read_rig(dir: &Path) -> Result<Option<Rig>, DataError> {
    let Some((folder, extension)) = colmap::find_model(dir) else {
        return Ok(None);
    };
    let model = colmap::read_model_files(&folder, extension)?;
    let images_path = folder.join(format!("images.{extension}"));
    if model.images.is_empty() {
        return Err(DataError::dataset(&images_path, "no registered images"));
    }
    let mut entries: Vec<(String, ColmapImage, Distortion)> = model
        .images
        .into_iter()
        .map(|image| {
            let distortion = model
                .cameras
                .iter()
                .find(|c| c.id == image.camera_id)
                .map_or(Distortion::None, |c| c.distortion);
            (camera_name(&image.name), image, distortion)
        })
        .collect();
    entries.sort_by_cached_key(|(name, ..)| n3dv::natural_key(name));
    if let Some(pair) = entries.windows(2).find(|pair| pair[0].0 == pair[1].0) {
        return Err(DataError::dataset(
            &images_path,
            format!(
                "images `{}` and `{}` are both camera `{}`: a rig's model registers one image \
                 per camera",
                pair[0].1.name, pair[1].1.name, pair[0].0
            ),
        ));
    }
    let mut rig = Rig {
        images_path,
        names: Vec::with_capacity(entries.len()),
        images: Vec::with_capacity(entries.len()),
        distortions: Vec::with_capacity(entries.len()),
        points: model.points,
    };
    for (name, image, distortion) in entries {
        rig.names.push(name);
        rig.images.push(image);
        rig.distortions.push(distortion);
    }
    Ok(Some(rig))
}

impl Rig {
    fn len(&self) -> usize {
        self.names.len()
    }

    /// A dataset of the rig's cameras, downscaled, with `frame_count` frames and no views yet.
    fn dataset(&self, frame_count: usize, downscale: u32) -> Dataset {
        Dataset {
            cameras: self
                .images
                .iter()
                .map(|image| image.camera.downscaled(downscale))
                .collect(),
            frame_count,
            ..Dataset::default()
        }
    }

    /// How each camera's images are checked and undistorted, in rig order.
    fn preparations(&self, source: &ColmapSource) -> Result<Vec<Preparation>, DataError> {
        let background = source.background.map(|c| (c * 255.0).round() as u8);
        self.images
            .iter()
            .zip(&self.distortions)
            .map(|(image, distortion)| {
                let camera = image.camera;
                let size = (camera.width, camera.height);
                check_downscale(&self.images_path, size, source.downscale)?;
                Ok(Preparation {
                    size,
                    undistortion: (!distortion.is_identity())
                        .then(|| Undistortion::new(distortion, &camera)),
                    background,
                })
            })
            .collect()
    }
}

/// How one camera's full-size images become views: their size checked against the camera,
/// undistorted where its model is distorted.
struct Preparation {
    size: (u32, u32),
    undistortion: Option<Undistortion>,
    background: [u8; 3],
}

impl Preparation {
    fn prepare(&self, path: &Path, image: RgbImage) -> Result<RgbImage, DataError> {
        let (found_width, found_height) = image.dimensions();
        if (found_width, found_height) != self.size {
            return Err(DataError::Size {
                path: path.to_path_buf(),
                width: self.size.0,
                height: self.size.1,
                found_width,
                found_height,
            });
        }
        Ok(match &self.undistortion {
            Some(undistortion) => undistortion.apply(&image, self.background),
            None => image,
        })
    }
}

/// Checks that `other`, a later frame's model, registers the same cameras as `reference` with
/// the same sizes and poses; intrinsics that differ are only warned about.
fn check_same_rig(reference: &Rig, other: &Rig) -> Result<(), DataError> {
    let ours = reference.images_path.display();
    let error = |message: String| DataError::dataset(&other.images_path, message);
    for (k, (name, image)) in reference.names.iter().zip(&reference.images).enumerate() {
        let Some(index) = other.names.iter().position(|n| n == name) else {
            return Err(error(format!(
                "camera `{name}` (image {}) of {ours} is not registered in this model: every \
                 frame's model must hold the whole rig",
                image.name
            )));
        };
        let (a, b) = (&image.camera, &other.images[index].camera);
        if (a.width, a.height) != (b.width, b.height) {
            return Err(error(format!(
                "camera `{name}` is {}×{} px here but {}×{} px in {ours}",
                b.width, b.height, a.width, a.height
            )));
        }
        let rotation = (a.rotation() - b.rotation())
            .to_cols_array()
            .iter()
            .fold(0.0f32, |worst, v| worst.max(v.abs()));
        let translation = (a.translation() - b.translation()).length();
        if rotation > POSE_TOLERANCE
            || translation > POSE_TOLERANCE * a.translation().length().max(1.0)
        {
            return Err(error(format!(
                "camera `{name}` is posed differently than in {ours} (rotation entries differ \
                 by up to {rotation:.2e}, the translation by {translation:.2e}): tadgs assumes a \
                 static rig, one pose per camera for the whole sequence"
            )));
        }
        let intrinsics = |c: &Camera| [c.fx, c.fy, c.cx, c.cy];
        let differs = intrinsics(a)
            .iter()
            .zip(intrinsics(b))
            .any(|(x, y)| (x - y).abs() > POSE_TOLERANCE * x.abs().max(1.0));
        if differs || reference.distortions[k] != other.distortions[index] {
            tracing::warn!(
                "{}: camera `{name}` has other intrinsics than in {ours}; using those of {ours}",
                other.images_path.display()
            );
        }
    }
    if let Some(extra) = other.names.iter().find(|n| !reference.names.contains(n)) {
        return Err(error(format!(
            "camera `{extra}` is not in {ours}: every frame's model must hold the same rig"
        )));
    }
    Ok(())
}

/// Which cameras of the rig are held out, by the names in `test_cameras`.
fn held_out_cameras(
    root: &Path,
    rig: &Rig,
    test_cameras: &[String],
) -> Result<Vec<bool>, DataError> {
    for (i, name) in test_cameras.iter().enumerate() {
        if !rig.names.contains(name) {
            return Err(DataError::field(
                root,
                format!("test_cameras[{i}]"),
                format!(
                    "camera `{name}` is not in {} (its cameras: {}); name cameras of the \
                     model, or give [] to hold none out",
                    rig.images_path.display(),
                    rig.names.join(", ")
                ),
            ));
        }
    }
    let held_out: Vec<bool> = rig.names.iter().map(|n| test_cameras.contains(n)).collect();
    if held_out.iter().all(|&h| h) {
        return Err(DataError::field(
            root,
            "test_cameras",
            "every camera is held out: no camera is left to train on",
        ));
    }
    Ok(held_out)
}

/// The `colmap_<n>` folders under `root` in numeric order, checked for gaps, the first
/// `limit` of them.
fn frame_folders(root: &Path, limit: Option<usize>) -> Result<Vec<PathBuf>, DataError> {
    let mut numbered: Vec<(u64, PathBuf)> = n3dv::list_dir(root)?
        .into_iter()
        .filter(|path| path.is_dir())
        .filter_map(|path| {
            let number = n3dv::entry_name(&path)
                .strip_prefix("colmap_")?
                .parse()
                .ok()?;
            Some((number, path))
        })
        .collect();
    numbered.sort();
    if numbered.is_empty() {
        return Err(DataError::dataset(
            root,
            "no frame folders colmap_<frame> (colmap_0, colmap_1, …) in this folder",
        ));
    }
    for pair in numbered.windows(2) {
        if pair[1].0 != pair[0].0 + 1 {
            return Err(DataError::dataset(
                root,
                format!(
                    "frame folders {} and {} are not consecutive (frame numbers must follow \
                     each other without gaps)",
                    n3dv::entry_name(&pair[0].1),
                    n3dv::entry_name(&pair[1].1)
                ),
            ));
        }
    }
    if let Some(limit) = limit {
        if numbered.len() < limit {
            return Err(DataError::field(
                root,
                "frames",
                format!(
                    "asks for {limit} frames, but there are {} frame folders ({} to {})",
                    numbered.len(),
                    n3dv::entry_name(&numbered[0].1),
                    n3dv::entry_name(&numbered[numbered.len() - 1].1)
                ),
            ));
        }
        numbered.truncate(limit);
    }
    Ok(numbered.into_iter().map(|(_, path)| path).collect())
}

/// The initial points of a frame with a model: its dense cloud where the dense preprocessing
/// left one, otherwise the model's sparse `points`.
fn frame_cloud(folder: &Path, points: Vec<InitPoint>) -> Result<Vec<InitPoint>, DataError> {
    let dense = folder.join("dense/workspace/fused_downsample.ply");
    if dense.is_file() {
        super::pointcloud::read_point_cloud(&dense)
    } else {
        Ok(points)
    }
}

/// Where the rig camera `name` has its frames: `frames/<name>/`, else `<name>.mp4`.
fn rig_frame_source(root: &Path, name: &str) -> Result<FrameSource, DataError> {
    let folder = root.join("frames").join(name);
    let video = root.join(format!("{name}.mp4"));
    if folder.is_dir() {
        Ok(FrameSource::Folder(folder))
    } else if video.is_file() {
        Ok(FrameSource::Video(video))
    } else {
        Err(DataError::dataset(
            &folder,
            format!(
                "no frames for camera `{name}`: neither this folder nor the video {} exists",
                video.display()
            ),
        ))
    }
}
