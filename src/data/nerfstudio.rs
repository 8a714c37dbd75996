//! Reader for nerfstudio captures (`transforms.json`, as written by `ns-process-data`).
//!
//! The file holds `frames`, each with `file_path` (relative to the file's folder) and
//! `transform_matrix`, a 4×4 camera-to-world matrix in the OpenGL/Blender convention (x right,
//! y up, looking along −z; the same conversion as [`super::dnerf`]). The pinhole intrinsics
//! `fl_x`, `fl_y`, `cx`, `cy` (pixels, pixel centres at +0.5 as in COLMAP) and the image size
//! `w`, `h` are given at the top level, for every frame, or per frame (a frame's own value
//! wins). `fl_x` may instead come from `camera_angle_x` (horizontal field of view, radians),
//! `fl_y` defaults to `fl_x`, and `w`, `h` default to the image's own size.
//!
//! Only undistorted pinhole images are read: a `camera_model` other than the perspective ones
//! (`PINHOLE`, `SIMPLE_PINHOLE`, `SIMPLE_RADIAL`, `RADIAL`, `OPENCV`), or any non-zero
//! distortion coefficient (`k1`…`k4`, `p1`, `p2`, `distortion_params`), is refused.
//!
//! Dynamic captures give each frame a `time` in [0, 1]; without one the capture is static (one
//! frame, time 0). Images with the same intrinsics and the same `transform_matrix` are one
//! camera seen at several times; each distinct training time is a frame, in increasing order
//! (a monocular sequence, where every image has its own pose and time, reads as one camera per
//! image, like D-NeRF).
//!
//! Held-out views: the file's `train_filenames` / `test_filenames` (or `val_filenames`) lists
//! where it has them, otherwise nerfstudio's default "fraction" split: the frames sorted by
//! image path, `ceil(0.9 N)` of them evenly spaced from the first to the last train and the
//! rest are held out. `ply_file_path` names an initial point cloud (in the same world frame as
//! the poses), used by `init.method: Auto` when the views have no foreground masks.
//! `applied_transform` and `applied_scale` (how the file's frame relates to the original
//! COLMAP reconstruction) are ignored: poses and points are used as written, without
//! nerfstudio's own re-orientation and rescaling.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::DMat4;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::dnerf::{blender_to_opencv_w2c, composite_downscaled, image_path};
use super::error::{check_downscale, open_image, read_text};
use super::panoptic::parse_rigid;
use super::settings::{self, check_background, check_downscale_factor};
use super::{Camera, DataError, Dataset, Matte, View};
use crate::io::image::box_downscale;
use crate::scene::FieldError;

/// nerfstudio's default `train_split_fraction`.
pub const DEFAULT_TRAIN_FRACTION: f64 = 0.9;

/// Which views are held out for evaluation.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub enum NerfstudioHeldOut {
    /// The file's own lists where it has them (`train_filenames` trains, `test_filenames`
    /// or, without it, `val_filenames` is held out), otherwise `Fraction(0.9)`.
    Auto,
    /// nerfstudio's "fraction" split: of the N frames sorted by image path, `ceil(f·N)`
    /// evenly spaced ones (indices `floor(k·(N−1)/(ceil(f·N)−1))`, first and last included)
    /// train and the others are held out. The file's lists, if any, are ignored.
    Fraction(f64),
    /// The file's lists: `train_filenames` trains, `<name>_filenames` (`"val"` or `"test"`)
    /// is held out; an error when the file lacks either.
    Lists(String),
    /// Every frame trains; nothing is held out.
    TrainOnAll,
}

/// Where and how to read a nerfstudio capture (a scene-file entry).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct NerfstudioSource {
    /// The folder holding `transforms.json`, or the transforms file itself (any name).
    pub path: String,
    /// Integer downscale of the images (1 = full resolution): box filter, intrinsics scaled
    /// to match, a size not divisible by it rounded down.
    #[serde(default = "settings::one")]
    pub downscale: u32,
    /// Which views are held out.
    #[serde(default = "auto")]
    pub held_out: NerfstudioHeldOut,
    /// Colour (linear RGB in [0, 1]) that RGBA images are composited over; their alpha also
    /// gives the view a foreground mask (unless every pixel is opaque).
    #[serde(default = "settings::white")]
    pub background: [f32; 3],
}

fn auto() -> NerfstudioHeldOut {
    NerfstudioHeldOut::Auto
}

impl NerfstudioSource {
    /// A source for the capture at `path` with the defaults: full resolution, automatic
    /// split, white background.
    pub fn new(path: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            downscale: settings::one(),
            held_out: auto(),
            background: settings::white(),
        }
    }

    /// Checks the settings (not the files): downscale, split and background colour.
    pub fn check(&self) -> Result<(), FieldError> {
        check_downscale_factor(self.downscale)?;
        match &self.held_out {
            NerfstudioHeldOut::Fraction(f) if !(*f > 0.0 && *f <= 1.0) => {
                return Err(FieldError::new(
                    "held_out",
                    format!("Fraction must be in (0, 1], found {f}"),
                ));
            }
            NerfstudioHeldOut::Lists(name) if name != "val" && name != "test" => {
                return Err(FieldError::new(
                    "held_out",
                    format!("Lists must name \"val\" or \"test\", found {name:?}"),
                ));
            }
            _ => {}
        }
        check_background(&self.background)
    }

    /// The transforms file and the folder its paths are relative to.
    pub fn files(&self) -> (PathBuf, PathBuf) {
        let path = PathBuf::from(&self.path);
        if path.is_dir() {
            (path.join("transforms.json"), path)
        } else {
            let root = path.parent().map(Path::to_path_buf).unwrap_or_default();
            (path, root)
        }
    }
}

/// Intrinsics and distortion keys, allowed at the top level and in every frame.
#[derive(Deserialize, Default)]
struct RawIntrinsics {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
    camera_angle_x: Option<f64>,
    camera_model: Option<String>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
    distortion_params: Option<Vec<f64>>,
}

/// Reads one key of a [`RawIntrinsics`].
type Getter = fn(&RawIntrinsics) -> Option<f64>;

/// A transforms file as written; keys optional so that a missing one is named in the error.
#[derive(Deserialize)]
struct RawTransforms {
    frames: Option<Vec<RawFrame>>,
    ply_file_path: Option<String>,
    train_filenames: Option<Vec<String>>,
    val_filenames: Option<Vec<String>>,
    test_filenames: Option<Vec<String>>,
    #[serde(flatten)]
    intrinsics: RawIntrinsics,
}

#[derive(Deserialize)]
struct RawFrame {
    file_path: Option<String>,
    transform_matrix: Option<Vec<Vec<f64>>>,
    time: Option<f64>,
    #[serde(flatten)]
    intrinsics: RawIntrinsics,
}

/// Pinhole intrinsics of one frame at full resolution; the size where the file gives it.
#[derive(Clone, Copy)]
struct Intrinsics {
    /// Horizontal focal length in pixels, or the horizontal field of view it follows from.
    fx: Focal,
    /// Vertical focal length; `None` is `fx`.
    fy: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    size: Option<(u32, u32)>,
}

/// A focal length as given: in pixels, or as `camera_angle_x` (radians) of the image width.
#[derive(Clone, Copy)]
enum Focal {
    Pixels(f64),
    Angle(f64),
}

/// One validated frame.
struct Frame {
    image_path: PathBuf,
    time: Option<f64>,
    intrinsics: Intrinsics,
    /// OpenCV world-to-camera.
    world_to_camera: DMat4,
}

/// Camera models whose projection is a pinhole once the distortion coefficients are zero.
const PERSPECTIVE_MODELS: [&str; 5] = [
    "PINHOLE",
    "SIMPLE_PINHOLE",
    "SIMPLE_RADIAL",
    "RADIAL",
    "OPENCV",
];

/// Reads a nerfstudio capture: cameras grouped by identical pose and intrinsics, frames by
/// distinct time, the split of [`NerfstudioSource::held_out`], and the `ply_file_path` cloud.
pub fn load(source: &NerfstudioSource) -> Result<Dataset, DataError> {
    let (file, root) = source.files();
    source
        .check()
        .map_err(|e| DataError::setting(Path::new(&source.path), e))?;
    if !file.is_file() {
        let what = if Path::new(&source.path).is_dir() {
            "no transforms.json in the folder named by data.path"
        } else {
            "no such file or folder"
        };
        return Err(DataError::io(
            &file,
            std::io::Error::new(std::io::ErrorKind::NotFound, what),
        ));
    }
    let text = read_text(&file)?;
    let raw: RawTransforms =
        serde_json::from_str(&text).map_err(|e| json_error(&file, &text, &e))?;
    let mut frames = read_frames(&file, &root, &raw)?;
    // nerfstudio sorts the frames by image path before splitting.
    frames.sort_by(|a, b| a.image_path.cmp(&b.image_path));
    let (train, test) = split(&file, &root, &raw, &frames, &source.held_out)?;
    if train.is_empty() {
        return Err(DataError::field(&file, "frames", "no training frames"));
    }

    // Frames are the distinct training times, in increasing order.
    let mut times: Vec<f64> = train
        .iter()
        .map(|&i| frames[i].time.unwrap_or(0.0))
        .collect();
    times.sort_by(f64::total_cmp);
    times.dedup();
    let frame_of = |time: f64| {
        times
            .iter()
            .enumerate()
            .min_by(|a, b| (a.1 - time).abs().total_cmp(&(b.1 - time).abs()))
            .map_or(0, |(i, _)| i)
    };

    // In sorted path order, so that camera indices follow the first image of each camera.
    let mut jobs: Vec<(usize, bool)> = train
        .iter()
        .map(|&i| (i, true))
        .chain(test.iter().map(|&i| (i, false)))
        .collect();
    jobs.sort_unstable();
    let jobs: Vec<(bool, &Frame)> = jobs.iter().map(|&(i, t)| (t, &frames[i])).collect();
    let loaded: Vec<(bool, Camera, View)> = jobs
        .par_iter()
        .map(|&(is_train, frame)| {
            let (camera, image, foreground, matte) = read_view(frame, source)?;
            let time = frame.time.unwrap_or(0.0);
            let view = View {
                camera: 0,
                frame: frame_of(time),
                time: time as f32,
                image: image.into(),
                dynamic_mask: None,
                foreground,
                // Only training recomposites the truth.
                matte: matte.filter(|_| is_train),
            };
            Ok((is_train, camera, view))
        })
        .collect::<Result<_, DataError>>()?;

    let mut dataset = Dataset {
        frame_count: times.len(),
        ..Dataset::default()
    };
    // One camera per distinct (intrinsics, pose), in order of first appearance.
    let mut camera_index: HashMap<Vec<u32>, usize> = HashMap::new();
    for (is_train, camera, mut view) in loaded {
        let key = camera_key(&camera);
        view.camera = *camera_index.entry(key).or_insert_with(|| {
            dataset.cameras.push(camera);
            dataset.cameras.len() - 1
        });
        if is_train {
            dataset.train.push(view);
        } else {
            dataset.test.push(view);
        }
    }
    if let Some(ply) = &raw.ply_file_path {
        let path = root.join(ply.strip_prefix("./").unwrap_or(ply));
        if !path.is_file() {
            return Err(DataError::field(
                &file,
                "ply_file_path",
                format!("point cloud {} does not exist", path.display()),
            ));
        }
        dataset.points = Some(super::pointcloud::read_point_cloud(&path)?);
    }
    Ok(dataset)
}

/// The bits of a camera's intrinsics and pose: equal keys are the same camera.
fn camera_key(camera: &Camera) -> Vec<u32> {
    let mut key = vec![camera.width, camera.height];
    key.extend(
        [camera.fx, camera.fy, camera.cx, camera.cy]
            .into_iter()
            .chain(camera.world_to_camera.to_cols_array())
            .map(f32::to_bits),
    );
    key
}

/// One frame's camera, its image and, for RGBA images with transparency, the alpha > 0.5
/// foreground mask and the matte.
type ViewParts = (Camera, image::RgbImage, Option<Vec<bool>>, Option<Matte>);

/// Reads one frame's image and makes its camera, both downscaled.
fn read_view(frame: &Frame, source: &NerfstudioSource) -> Result<ViewParts, DataError> {
    let path = &frame.image_path;
    let decoded = open_image(path)?;
    let found = (decoded.width(), decoded.height());
    let intrinsics = frame.intrinsics;
    if let Some((width, height)) = intrinsics.size
        && (width, height) != found
    {
        return Err(DataError::Size {
            path: path.clone(),
            width,
            height,
            found_width: found.0,
            found_height: found.1,
        });
    }
    check_downscale(path, found, source.downscale)?;
    let (image, foreground, matte) = if decoded.color().has_alpha() {
        let (image, mask, matte) =
            composite_downscaled(&decoded.into_rgba8(), source.downscale, source.background);
        // An opaque alpha channel says nothing about what is foreground or background.
        let mask = (!mask.iter().all(|&m| m)).then_some(mask);
        let matte = (!matte.alpha.iter().all(|&a| a == 255)).then_some(matte);
        (image, mask, matte)
    } else {
        (
            box_downscale(&decoded.into_rgb8(), source.downscale),
            None,
            None,
        )
    };
    let (width, height) = found;
    let fx = match intrinsics.fx {
        Focal::Pixels(fx) => fx,
        Focal::Angle(angle) => 0.5 * f64::from(width) / (0.5 * angle).tan(),
    };
    let camera = Camera {
        width,
        height,
        fx: fx as f32,
        fy: intrinsics.fy.unwrap_or(fx) as f32,
        cx: intrinsics.cx.unwrap_or(0.5 * f64::from(width)) as f32,
        cy: intrinsics.cy.unwrap_or(0.5 * f64::from(height)) as f32,
        world_to_camera: frame.world_to_camera.as_mat4(),
    }
    .downscaled(source.downscale);
    Ok((camera, image, foreground, matte))
}

/// A JSON error naming the file, line and column, with a hint where the value is NaN or
/// Infinity (which Python's `json.dump` writes but JSON does not allow).
fn json_error(file: &Path, text: &str, error: &serde_json::Error) -> DataError {
    let at = text
        .lines()
        .nth(error.line().saturating_sub(1))
        .and_then(|line| line.get(error.column().saturating_sub(1)..))
        .unwrap_or("");
    let at = at.trim_start_matches(['-', ' ']);
    let hint = if ["NaN", "Infinity", "nan", "inf"]
        .iter()
        .any(|t| at.starts_with(t))
    {
        " (a non-finite number: NaN and Infinity are not JSON, and a pose or intrinsic must be finite)"
    } else {
        ""
    };
    DataError::format(file, format!("invalid JSON: {error}{hint}"))
}

/// Validates every frame of the file (keys, matrix, intrinsics, distortion, time, image).
fn read_frames(file: &Path, root: &Path, raw: &RawTransforms) -> Result<Vec<Frame>, DataError> {
    let top = &raw.intrinsics;
    let raw_frames = raw
        .frames
        .as_ref()
        .ok_or_else(|| DataError::field(file, "frames", "missing"))?;
    if raw_frames.is_empty() {
        return Err(DataError::field(file, "frames", "is empty"));
    }
    let with_time = raw_frames.iter().filter(|f| f.time.is_some()).count();
    let mut frames = Vec::with_capacity(raw_frames.len());
    for (i, frame) in raw_frames.iter().enumerate() {
        let field = |key: &str| format!("frames[{i}].{key}");
        let file_path = frame
            .file_path
            .as_ref()
            .ok_or_else(|| DataError::field(file, field("file_path"), "missing"))?;
        let matrix = frame
            .transform_matrix
            .as_ref()
            .ok_or_else(|| DataError::field(file, field("transform_matrix"), "missing"))?;
        let camera_to_world = parse_rigid(matrix)
            .map_err(|message| DataError::field(file, field("transform_matrix"), message))?;
        let time = match frame.time {
            Some(t) if !(0.0..=1.0).contains(&t) => {
                return Err(DataError::field(
                    file,
                    field("time"),
                    format!("must be in [0, 1], found {t}"),
                ));
            }
            None if with_time > 0 => {
                return Err(DataError::field(
                    file,
                    field("time"),
                    format!(
                        "missing, while {with_time} other frames have one: give every frame a \
                         time, or none for a static capture"
                    ),
                ));
            }
            t => t,
        };
        let intrinsics = read_intrinsics(file, i, &frame.intrinsics, top)?;
        let image_path = image_path(root, file_path);
        if !image_path.is_file() {
            return Err(DataError::field(
                file,
                field("file_path"),
                format!("image {} does not exist", image_path.display()),
            ));
        }
        frames.push(Frame {
            image_path,
            time,
            intrinsics,
            world_to_camera: blender_to_opencv_w2c(camera_to_world),
        });
    }
    Ok(frames)
}

/// The intrinsics of frame `i`: its own keys, else the top-level ones; checks the camera
/// model and that there is no distortion.
fn read_intrinsics(
    file: &Path,
    i: usize,
    own: &RawIntrinsics,
    top: &RawIntrinsics,
) -> Result<Intrinsics, DataError> {
    // The field as the error names it: in the frame, or at the top level.
    let field = |key: &str, in_frame: bool| {
        if in_frame {
            format!("frames[{i}].{key}")
        } else {
            key.to_string()
        }
    };
    let pick = |key: &str, get: Getter| -> Option<(f64, String)> {
        get(own)
            .map(|v| (v, field(key, true)))
            .or_else(|| get(top).map(|v| (v, field(key, false))))
    };
    let model = own
        .camera_model
        .as_ref()
        .map(|m| (m, field("camera_model", true)))
        .or_else(|| {
            top.camera_model
                .as_ref()
                .map(|m| (m, field("camera_model", false)))
        });
    let model_name = model.as_ref().map_or("PINHOLE", |(m, _)| m.as_str());
    if let Some((model, at)) = &model
        && !PERSPECTIVE_MODELS.contains(&model.as_str())
    {
        return Err(DataError::field(
            file,
            at.clone(),
            format!(
                "camera model {model:?} is not a pinhole projection; tadgs reads pinhole \
                 images only (models {}): undistort the images into a pinhole camera first",
                PERSPECTIVE_MODELS.join(", ")
            ),
        ));
    }
    let coefficients: [(&str, Getter); 6] = [
        ("k1", |r| r.k1),
        ("k2", |r| r.k2),
        ("k3", |r| r.k3),
        ("k4", |r| r.k4),
        ("p1", |r| r.p1),
        ("p2", |r| r.p2),
    ];
    let distortion_error = |at: String, value: f64| {
        DataError::field(
            file,
            at,
            format!(
                "camera model {model_name} has distortion ({value}); tadgs renders undistorted \
                 pinhole cameras only and does not treat a distorted image as one: undistort the \
                 images first (e.g. COLMAP image_undistorter) and write PINHOLE intrinsics with \
                 zero distortion"
            ),
        )
    };
    for (key, get) in coefficients {
        if let Some((value, at)) = pick(key, get)
            && value != 0.0
        {
            return Err(distortion_error(at, value));
        }
    }
    let params = own
        .distortion_params
        .as_ref()
        .map(|p| (p, field("distortion_params", true)))
        .or_else(|| {
            top.distortion_params
                .as_ref()
                .map(|p| (p, field("distortion_params", false)))
        });
    if let Some((params, at)) = params
        && let Some((k, &value)) = params.iter().enumerate().find(|(_, v)| **v != 0.0)
    {
        return Err(distortion_error(format!("{at}[{k}]"), value));
    }

    let size = |key: &str, get: Getter| match pick(key, get) {
        None => Ok(None),
        Some((v, _)) if v.fract() == 0.0 && v >= 1.0 && v <= f64::from(super::MAX_IMAGE_SIDE) => {
            Ok(Some(v as u32))
        }
        Some((v, at)) => Err(DataError::field(
            file,
            at,
            format!(
                "must be a whole number of pixels in 1..={}, found {v}",
                super::MAX_IMAGE_SIDE
            ),
        )),
    };
    let width = size("w", |r| r.w)?;
    let height = size("h", |r| r.h)?;
    let size = match (width, height) {
        (Some(w), Some(h)) => Some((w, h)),
        (None, None) => None,
        (Some(_), None) => {
            return Err(DataError::field(
                file,
                field("h", true),
                "missing (w is given)",
            ));
        }
        (None, Some(_)) => {
            return Err(DataError::field(
                file,
                field("w", true),
                "missing (h is given)",
            ));
        }
    };
    let positive = |value: f64, at: &str| {
        if value.is_finite() && value > 0.0 {
            Ok(value)
        } else {
            Err(DataError::field(
                file,
                at.to_string(),
                format!("focal length must be positive, found {value}"),
            ))
        }
    };
    let fx = match pick("fl_x", |r| r.fl_x) {
        Some((v, at)) => Focal::Pixels(positive(v, &at)?),
        None => match pick("camera_angle_x", |r| r.camera_angle_x) {
            Some((angle, at)) => {
                if !(angle.is_finite() && angle > 0.0 && angle < std::f64::consts::PI) {
                    return Err(DataError::field(
                        file,
                        at,
                        format!("field of view must be in (0, π) radians, found {angle}"),
                    ));
                }
                Focal::Angle(angle)
            }
            None => {
                return Err(DataError::field(
                    file,
                    field("fl_x", true),
                    "missing (neither in the frame nor at the top level, and no camera_angle_x)",
                ));
            }
        },
    };
    let fy = match pick("fl_y", |r| r.fl_y) {
        Some((v, at)) => Some(positive(v, &at)?),
        None => None,
    };
    let centre = |key: &str, get: Getter| match pick(key, get) {
        Some((v, at)) if !v.is_finite() => Err(DataError::field(
            file,
            at,
            format!("must be finite, found {v}"),
        )),
        other => Ok(other.map(|(v, _)| v)),
    };
    Ok(Intrinsics {
        fx,
        fy,
        cx: centre("cx", |r| r.cx)?,
        cy: centre("cy", |r| r.cy)?,
        size,
    })
}

/// Training and held-out frame indices (into the sorted `frames`).
fn split(
    file: &Path,
    root: &Path,
    raw: &RawTransforms,
    frames: &[Frame],
    held_out: &NerfstudioHeldOut,
) -> Result<(Vec<usize>, Vec<usize>), DataError> {
    let has_lists = raw.train_filenames.is_some()
        || raw.val_filenames.is_some()
        || raw.test_filenames.is_some();
    let lists = |name: &str| -> Result<(Vec<usize>, Vec<usize>), DataError> {
        let held = match name {
            "val" => &raw.val_filenames,
            _ => &raw.test_filenames,
        };
        let key = format!("{name}_filenames");
        let train = raw.train_filenames.as_ref().ok_or_else(|| {
            DataError::field(
                file,
                "train_filenames",
                "missing (the file lists other splits)",
            )
        })?;
        let held = held.as_ref().ok_or_else(|| {
            DataError::field(file, key.clone(), "missing (held_out asks for this list)")
        })?;
        Ok((
            list_indices(file, root, frames, "train_filenames", train)?,
            list_indices(file, root, frames, &key, held)?,
        ))
    };
    match held_out {
        NerfstudioHeldOut::TrainOnAll => Ok(((0..frames.len()).collect(), Vec::new())),
        NerfstudioHeldOut::Fraction(f) => Ok(fraction_split(frames.len(), *f)),
        NerfstudioHeldOut::Lists(name) => lists(name),
        NerfstudioHeldOut::Auto if has_lists => lists(if raw.test_filenames.is_some() {
            "test"
        } else {
            "val"
        }),
        NerfstudioHeldOut::Auto => Ok(fraction_split(frames.len(), DEFAULT_TRAIN_FRACTION)),
    }
}

/// The frames a `<split>_filenames` list names (paths relative to the file's folder).
fn list_indices(
    file: &Path,
    root: &Path,
    frames: &[Frame],
    key: &str,
    names: &[String],
) -> Result<Vec<usize>, DataError> {
    let by_path: HashMap<&Path, usize> = frames
        .iter()
        .enumerate()
        .map(|(i, f)| (f.image_path.as_path(), i))
        .collect();
    let mut indices = Vec::with_capacity(names.len());
    for (k, name) in names.iter().enumerate() {
        let path = image_path(root, name);
        let index = by_path.get(path.as_path()).ok_or_else(|| {
            DataError::field(
                file,
                format!("{key}[{k}]"),
                format!("{name:?} is not the file_path of any frame"),
            )
        })?;
        indices.push(*index);
    }
    indices.sort_unstable();
    indices.dedup();
    Ok(indices)
}

/// nerfstudio's `get_train_eval_split_fraction`: `ceil(fraction·n)` training indices evenly
/// spaced over `0..n` (NumPy's `linspace(0, n − 1, k, dtype=int)`, which truncates), the others
/// held out.
pub fn fraction_split(n: usize, fraction: f64) -> (Vec<usize>, Vec<usize>) {
    let k = ((n as f64 * fraction).ceil() as usize).min(n);
    let train: Vec<usize> = match k {
        0 => Vec::new(),
        1 => vec![0],
        _ => {
            let step = (n - 1) as f64 / (k - 1) as f64;
            // linspace computes start + i·step and pins the last value to the stop exactly.
            (0..k)
                .map(|i| {
                    if i == k - 1 {
                        n - 1
                    } else {
                        (i as f64 * step) as usize
                    }
                })
                .collect()
        }
    };
    let held = (0..n).filter(|i| train.binary_search(i).is_err()).collect();
    (train, held)
}
