//! Reader for D-NeRF synthetic scenes (Blender/NeRF-synthetic layout with a `time` field).
//!
//! `transforms_{train,val,test}.json` hold `camera_angle_x` (horizontal field of view) and
//! `frames`, each with `file_path` (`./train/r_000`, `.png` implied), `time` in [0, 1] and
//! `transform_matrix`, a camera-to-world matrix in the Blender/OpenGL convention (x right,
//! y up, looking along −z). The capture is monocular: every image has its own camera.

use std::path::{Path, PathBuf};

use glam::{DMat4, DVec4};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::error::{check_downscale, open_image, read_text};
use super::settings::{self, check_background, check_downscale_factor};
use super::{Camera, DataError, Dataset, Matte, View};
use crate::io::image::box_filter;
use crate::scene::FieldError;

/// Where and how to read a D-NeRF scene (a scene-file entry).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct DNerfSource {
    /// Scene folder holding `transforms_*.json` and the `train/`, `val/`, `test/` images.
    pub path: String,
    /// Colour (linear RGB in [0, 1]) that the RGBA images are composited over; D-NeRF uses
    /// white.
    #[serde(default = "settings::white")]
    pub background: [f32; 3],
    /// Integer downscale of the 800×800 images (box filter on RGBA, then composite). D-NeRF
    /// trains at half resolution, hence the default 2.
    #[serde(default = "two")]
    pub downscale: u32,
    /// Which split gives the held-out views: `"test"` (the standard one) or `"val"`.
    #[serde(default = "test_split")]
    pub test_split: String,
}

impl DNerfSource {
    /// Checks the settings (not the files): downscale, split name and background colour.
    pub fn check(&self) -> Result<(), FieldError> {
        check_downscale_factor(self.downscale)?;
        if self.test_split != "test" && self.test_split != "val" {
            return Err(FieldError::new(
                "test_split",
                format!("must be \"test\" or \"val\", found {:?}", self.test_split),
            ));
        }
        check_background(&self.background)
    }

    /// A source with D-NeRF's defaults: white background, half resolution, `test` split.
    pub fn new(path: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            background: settings::white(),
            downscale: two(),
            test_split: test_split(),
        }
    }
}

fn two() -> u32 {
    2
}

fn test_split() -> String {
    "test".into()
}

/// A transforms file as written; keys optional so that a missing one is named in the error.
#[derive(Deserialize)]
struct RawTransforms {
    camera_angle_x: Option<f64>,
    frames: Option<Vec<RawFrame>>,
}

#[derive(Deserialize)]
struct RawFrame {
    file_path: Option<String>,
    time: Option<f64>,
    transform_matrix: Option<Vec<Vec<f64>>>,
}

/// One validated frame of a transforms file.
struct Frame {
    image_path: PathBuf,
    time: f64,
    /// OpenCV world-to-camera.
    world_to_camera: DMat4,
}

/// Reads a D-NeRF scene: training views from `train`, held-out views from the chosen split,
/// one camera per image, foreground from alpha.
pub fn load(source: &DNerfSource) -> Result<Dataset, DataError> {
    let root = PathBuf::from(&source.path);
    source.check().map_err(|e| DataError::setting(&root, e))?;
    let (train_angle, mut train_frames) = read_transforms(&root, "train")?;
    let (test_angle, test_frames) = read_transforms(&root, &source.test_split)?;
    if train_frames.is_empty() {
        return Err(DataError::field(
            &root.join("transforms_train.json"),
            "frames",
            "no training frames",
        ));
    }
    // Frame indices follow time order; the stable sort keeps file order among equal times.
    train_frames.sort_by(|a, b| a.time.total_cmp(&b.time));
    let frame_count = train_frames.len();

    let jobs: Vec<(bool, usize, f64, &Frame)> = train_frames
        .iter()
        .enumerate()
        .map(|(index, frame)| (true, index, train_angle, frame))
        .chain(test_frames.iter().map(|frame| {
            let index = (frame.time * (frame_count - 1) as f64).round() as usize;
            (false, index, test_angle, frame)
        }))
        .collect();

    let loaded: Vec<(bool, Camera, View)> = jobs
        .par_iter()
        .enumerate()
        .map(|(camera_index, &(is_train, frame_index, angle, frame))| {
            let rgba = open_image(&frame.image_path)?.into_rgba8();
            check_downscale(&frame.image_path, rgba.dimensions(), source.downscale)?;
            let (image, foreground, matte) =
                composite_downscaled(&rgba, source.downscale, source.background);
            let (width, height) = image.dimensions();
            let focal = (0.5 * f64::from(width) / (0.5 * angle).tan()) as f32;
            let camera = Camera {
                width,
                height,
                fx: focal,
                fy: focal,
                cx: 0.5 * width as f32,
                cy: 0.5 * height as f32,
                world_to_camera: frame.world_to_camera.as_mat4(),
            };
            let view = View {
                camera: camera_index,
                frame: frame_index,
                time: frame.time as f32,
                image: image.into(),
                dynamic_mask: None,
                foreground: Some(foreground),
                // Only training recomposites the truth.
                matte: is_train.then_some(matte),
            };
            Ok((is_train, camera, view))
        })
        .collect::<Result<_, DataError>>()?;

    let mut dataset = Dataset {
        frame_count,
        ..Dataset::default()
    };
    for (is_train, camera, view) in loaded {
        dataset.cameras.push(camera);
        if is_train {
            dataset.train.push(view);
        } else {
            dataset.test.push(view);
        }
    }
    Ok(dataset)
}

/// Parses and validates `transforms_<split>.json`: the field of view and the frames.
fn read_transforms(root: &Path, split: &str) -> Result<(f64, Vec<Frame>), DataError> {
    let path = root.join(format!("transforms_{split}.json"));
    let text = read_text(&path)?;
    let raw: RawTransforms = serde_json::from_str(&text)
        .map_err(|e| DataError::format(&path, format!("invalid JSON: {e}")))?;
    let angle = raw
        .camera_angle_x
        .ok_or_else(|| DataError::field(&path, "camera_angle_x", "missing"))?;
    if !(angle.is_finite() && angle > 0.0 && angle < std::f64::consts::PI) {
        return Err(DataError::field(
            &path,
            "camera_angle_x",
            format!("field of view must be in (0, π) radians, found {angle}"),
        ));
    }
    let raw_frames = raw
        .frames
        .ok_or_else(|| DataError::field(&path, "frames", "missing"))?;
    let mut frames = Vec::with_capacity(raw_frames.len());
    for (i, frame) in raw_frames.into_iter().enumerate() {
        let field = |key: &str| format!("frames[{i}].{key}");
        let file_path = frame
            .file_path
            .ok_or_else(|| DataError::field(&path, field("file_path"), "missing"))?;
        let time = frame
            .time
            .ok_or_else(|| DataError::field(&path, field("time"), "missing"))?;
        if !(0.0..=1.0).contains(&time) {
            return Err(DataError::field(
                &path,
                field("time"),
                format!("must be in [0, 1], found {time}"),
            ));
        }
        let matrix = frame
            .transform_matrix
            .ok_or_else(|| DataError::field(&path, field("transform_matrix"), "missing"))?;
        let camera_to_world = super::panoptic::parse_rigid(&matrix)
            .map_err(|message| DataError::field(&path, field("transform_matrix"), message))?;
        let image_path = image_path(root, &file_path);
        if !image_path.is_file() {
            return Err(DataError::field(
                &path,
                field("file_path"),
                format!("image {} does not exist", image_path.display()),
            ));
        }
        frames.push(Frame {
            image_path,
            time,
            world_to_camera: blender_to_opencv_w2c(camera_to_world),
        });
    }
    Ok((angle, frames))
}

/// The image of a `file_path` entry: relative to the scene folder, `.png` added when the
/// entry has no extension (as in the D-NeRF files).
pub(crate) fn image_path(root: &Path, file_path: &str) -> PathBuf {
    let relative = file_path.strip_prefix("./").unwrap_or(file_path);
    let path = root.join(relative);
    if path.extension().is_some() {
        path
    } else {
        path.with_extension("png")
    }
}

/// Converts a Blender/OpenGL camera-to-world (y up, looking along −z) to an OpenCV
/// world-to-camera (y down, looking along +z): flip the camera's y and z axes, then invert.
pub(crate) fn blender_to_opencv_w2c(camera_to_world: DMat4) -> DMat4 {
    let flip = DMat4::from_diagonal(DVec4::new(1.0, -1.0, -1.0, 1.0));
    let opencv_c2w = camera_to_world * flip;
    // Rigid inverse: [Rᵀ | −Rᵀt], exact where a general inverse would round.
    let rotation_t = glam::DMat3::from_mat4(opencv_c2w).transpose();
    let translation = -(rotation_t * opencv_c2w.w_axis.truncate());
    DMat4::from_cols(
        rotation_t.x_axis.extend(0.0),
        rotation_t.y_axis.extend(0.0),
        rotation_t.z_axis.extend(0.0),
        translation.extend(1.0),
    )
}

/// Box-filters the RGBA image by `factor` (straight alpha, as D-NeRF's area resize does),
/// composites it over `background` and returns the 8-bit RGB image, the alpha > 0.5 mask and
/// the matte (the filtered alpha with `background`).
pub(crate) fn composite_downscaled(
    rgba: &image::RgbaImage,
    factor: u32,
    background: [f32; 3],
) -> (image::RgbImage, Vec<bool>, Matte) {
    let norm = 1.0 / (255.0 * (factor * factor) as f32);
    let pixels = (rgba.width() / factor) as usize * (rgba.height() / factor) as usize;
    let mut foreground = Vec::with_capacity(pixels);
    let mut coverage = Vec::with_capacity(pixels);
    let image = box_filter(rgba, factor, |sum, out| {
        let alpha = sum[3] as f32 * norm;
        for c in 0..3 {
            let value = sum[c] as f32 * norm * alpha + background[c] * (1.0 - alpha);
            out[c] = (value.clamp(0.0, 1.0) * 255.0).round() as u8;
        }
        foreground.push(alpha > 0.5);
        coverage.push((alpha * 255.0).round() as u8);
    });
    let matte = Matte {
        alpha: coverage,
        background,
    };
    (image, foreground, matte)
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::DVec3;

    /// A Blender camera at `eye` whose −z axis looks at the origin, with world up +Z.
    fn blender_look_at_origin(eye: DVec3) -> DMat4 {
        let back = eye.normalize(); // camera +z points away from the target
        let right = DVec3::Z.cross(back).normalize();
        let up = back.cross(right);
        DMat4::from_cols(
            right.extend(0.0),
            up.extend(0.0),
            back.extend(0.0),
            eye.extend(1.0),
        )
    }

    #[test]
    fn blender_camera_looks_along_opencv_z() {
        let eye = DVec3::new(1.0, -3.0, 2.5);
        let w2c = blender_to_opencv_w2c(blender_look_at_origin(eye));
        // The origin is straight ahead, at the camera's distance.
        let origin = w2c.transform_point3(DVec3::ZERO);
        assert!(origin.x.abs() < 1e-12 && origin.y.abs() < 1e-12);
        assert!((origin.z - eye.length()).abs() < 1e-12);
        // World up (+Z) appears towards the top of the image (−y in OpenCV).
        let above = w2c.transform_point3(DVec3::Z * 0.1);
        assert!(above.y < 0.0);
        // The camera centre maps to the camera origin.
        assert!(w2c.transform_point3(eye).length() < 1e-12);
        assert!((w2c.inverse().transform_point3(DVec3::ZERO) - eye).length() < 1e-12);
    }

    #[test]
    fn composite_over_background_and_alpha_mask() {
        let mut rgba = image::RgbaImage::new(4, 2);
        // Left block: opaque red; right block: transparent (its colour must not leak).
        for y in 0..2 {
            for x in 0..2 {
                rgba.put_pixel(x, y, image::Rgba([255, 0, 0, 255]));
                rgba.put_pixel(x + 2, y, image::Rgba([0, 255, 0, 0]));
            }
        }
        let (image, mask, matte) = composite_downscaled(&rgba, 2, [1.0, 1.0, 1.0]);
        assert_eq!(image.dimensions(), (2, 1));
        assert_eq!(image.get_pixel(0, 0).0, [255, 0, 0]);
        assert_eq!(image.get_pixel(1, 0).0, [255, 255, 255]);
        assert_eq!(mask, vec![true, false]);
        assert_eq!(matte.alpha, vec![255, 0]);
        assert_eq!(matte.background, [1.0; 3]);
        let (black, _, _) = composite_downscaled(&rgba, 1, [0.0; 3]);
        assert_eq!(black.get_pixel(3, 1).0, [0, 0, 0]);
        // A half-covered block: alpha 0.5 in the matte, the mask says background.
        rgba.put_pixel(0, 0, image::Rgba([255, 0, 0, 0]));
        rgba.put_pixel(1, 0, image::Rgba([255, 0, 0, 0]));
        let (_, mask, matte) = composite_downscaled(&rgba, 2, [1.0; 3]);
        assert_eq!(mask, vec![false, false]);
        assert_eq!(matte.alpha, vec![128, 0]);
    }

    #[test]
    fn image_path_adds_png() {
        let root = Path::new("/scene");
        assert_eq!(
            image_path(root, "./train/r_000"),
            Path::new("/scene/train/r_000.png")
        );
        assert_eq!(
            image_path(root, "test/r_001.png"),
            Path::new("/scene/test/r_001.png")
        );
    }
}
