//! Reader for the Dynamic3DGaussians layout of CMU Panoptic captures.
//!
//! A dataset folder holds `train_meta.json` and `test_meta.json` (keys `w`, `h`, and per
//! timestep `t` and view `i`: `k[t][i]` 3×3 intrinsics, `w2c[t][i]` 4×4 OpenCV
//! world-to-camera, `fn[t][i]` image path under `ims/`, `cam_id[t][i]`), the JPEGs under
//! `ims/`, and optionally foreground masks under `seg/` (same path, `.png`).
//!
//! Cameras are static, so one [`Camera`] is made per distinct `cam_id`; its index in
//! [`Dataset::cameras`] is the id's rank among all ids (train and test) in increasing order.
//! For Panoptic the ids are `0..=30`, so `dataset.cameras[cam_id]` is that camera.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::{DMat3, DMat4};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::error::{
    check_downscale, check_image_size, read_mask, read_rgb8, read_text, require_folder,
};
use super::settings::{self, check_cache_mb, check_downscale_factor};
use super::{Camera, DataError, Dataset, View, ViewImage, frame_time, stream};
use crate::io::image::box_downscale_owned;
use crate::scene::FieldError;

/// Where and how to read a Dynamic3DGaussians / CMU Panoptic dataset (a scene-file entry).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PanopticSource {
    /// Dataset folder holding `train_meta.json`, `test_meta.json`, `ims/` and maybe `seg/`.
    pub path: String,
    /// Number of timesteps to keep (counted after `frame_stride`); `None` keeps all. Short
    /// sequences make quick experiments and tests.
    #[serde(default)]
    pub frames: Option<usize>,
    /// Keep every k-th timestep of the recording (1 = all), starting at the first; the kept
    /// timesteps are renumbered `0..T`, so time stays `frame / (T − 1)`.
    #[serde(default = "one_usize")]
    pub frame_stride: usize,
    /// Load the `seg/` foreground masks of the training views where they exist (test views
    /// never get one: the masks are for initialisation, not evaluation).
    #[serde(default = "yes")]
    pub foreground_masks: bool,
    /// Integer downscale of images and masks (1 = full resolution). Images are box-filtered
    /// (area average), masks sampled nearest, intrinsics scaled to match; a size not
    /// divisible by it is rounded down, dropping the last pixels on the right and bottom.
    #[serde(default = "settings::one")]
    pub downscale: u32,
    /// Training camera ids to hold out as a validation split: their views become the
    /// evaluation set and the capture's own held-out cameras (`test_meta.json`) are not loaded
    /// at all. For choosing settings without looking at the held-out cameras; `None` (the
    /// default) is the standard split.
    #[serde(default)]
    pub validation_cameras: Option<Vec<u64>>,
    /// Stream the images from disk through a cache of this many megabytes instead of
    /// decoding them all up front (see `tadgs::data::stream`). `None` (the default) loads them
    /// all unless they would take more than half the available memory.
    #[serde(default)]
    pub cache_mb: Option<f64>,
}

impl PanopticSource {
    /// Checks the settings (not the files): stride, frame count and downscale.
    pub fn check(&self) -> Result<(), FieldError> {
        if self.frame_stride == 0 {
            return Err(FieldError::new("frame_stride", "must be at least 1"));
        }
        if self.frames == Some(0) {
            return Err(FieldError::new(
                "frames",
                "must be at least 1, or None for all",
            ));
        }
        check_downscale_factor(self.downscale)?;
        check_cache_mb(self.cache_mb)?;
        if self.validation_cameras.as_ref().is_some_and(Vec::is_empty) {
            return Err(FieldError::new(
                "validation_cameras",
                "must name at least one training camera, or be None",
            ));
        }
        Ok(())
    }

    /// A source for the whole dataset at `path`, at full resolution, with masks.
    pub fn new(path: impl Into<String>) -> Self {
        Self {
            path: path.into(),
            frames: None,
            frame_stride: 1,
            foreground_masks: true,
            downscale: 1,
            validation_cameras: None,
            cache_mb: None,
        }
    }
}

fn one_usize() -> usize {
    1
}

fn yes() -> bool {
    true
}

/// `train_meta.json` / `test_meta.json` as written; every key optional so that a missing one
/// is reported by name rather than by serde's position.
#[derive(Deserialize)]
struct RawMeta {
    w: Option<u32>,
    h: Option<u32>,
    k: Option<Vec<Vec<Vec<Vec<f64>>>>>,
    w2c: Option<Vec<Vec<Vec<Vec<f64>>>>>,
    #[serde(rename = "fn")]
    file_names: Option<Vec<Vec<String>>>,
    cam_id: Option<Vec<Vec<u64>>>,
}

/// One view of a meta file after validation.
struct MetaView {
    cam_id: u64,
    intrinsics: DMat3,
    world_to_camera: DMat4,
    /// Path relative to `ims/`.
    file_name: String,
    /// Index path of this entry in the meta file, for error messages (`[t][i]`).
    index: (usize, usize),
}

/// A validated meta file: image size and views per timestep.
struct Meta {
    path: PathBuf,
    width: u32,
    height: u32,
    timesteps: Vec<Vec<MetaView>>,
}

/// Reads a Panoptic dataset: cameras, training views (with foreground masks) and held-out
/// views, images decoded in parallel.
pub fn load(source: &PanopticSource) -> Result<Dataset, DataError> {
    let root = PathBuf::from(&source.path);
    check_source(source, &root)?;
    let train = read_meta(&root.join("train_meta.json"))?;
    let test = read_meta(&root.join("test_meta.json"))?;
    if train.timesteps.len() != test.timesteps.len() {
        return Err(DataError::dataset(
            &root,
            format!(
                "train_meta.json has {} timesteps but test_meta.json has {}; they must agree",
                train.timesteps.len(),
                test.timesteps.len()
            ),
        ));
    }
    if train.timesteps.is_empty() {
        return Err(DataError::field(&train.path, "fn", "no timesteps"));
    }
    for meta in [&train, &test] {
        check_downscale(&meta.path, (meta.width, meta.height), source.downscale)?;
    }

    let kept = kept_timesteps(train.timesteps.len(), source.frame_stride, source.frames);
    if let Some(frames) = source.frames.filter(|&f| f > kept.len()) {
        return Err(DataError::field(
            &train.path,
            "frames",
            format!(
                "data.frames asks for {frames} frames, but the sequence has {} (with \
                 frame_stride {})",
                kept.len(),
                source.frame_stride
            ),
        ));
    }
    let frame_count = kept.len();

    let (cameras, camera_index) = build_cameras(&[&train, &test], source.downscale)?;

    let validation = source.validation_cameras.as_deref();
    if let Some(ids) = validation {
        let train_ids: Vec<u64> = train.timesteps[0].iter().map(|v| v.cam_id).collect();
        if let Some(id) = ids.iter().find(|id| !train_ids.contains(id)) {
            return Err(DataError::field(
                &train.path,
                "cam_id",
                format!("validation camera {id} is not a training camera of this capture"),
            ));
        }
    }
    let metas: &[(&Meta, bool)] = if validation.is_some() {
        &[(&train, true)]
    } else {
        &[(&train, true), (&test, false)]
    };
    let mut jobs = Vec::new();
    for &(meta, from_train_meta) in metas {
        for (frame, &t) in kept.iter().enumerate() {
            for view in &meta.timesteps[t] {
                let is_train =
                    from_train_meta && !validation.is_some_and(|ids| ids.contains(&view.cam_id));
                let image_path = root.join("ims").join(&view.file_name);
                if !image_path.is_file() {
                    return Err(DataError::field(
                        &meta.path,
                        format!("fn[{}][{}]", view.index.0, view.index.1),
                        format!("image {} does not exist", image_path.display()),
                    ));
                }
                let mask_path = (is_train && source.foreground_masks)
                    .then(|| root.join("seg").join(&view.file_name).with_extension("png"))
                    .filter(|p| p.is_file());
                jobs.push(ViewJob {
                    is_train,
                    camera: camera_index[&view.cam_id],
                    frame,
                    image_path,
                    mask_path,
                    size: (meta.width, meta.height),
                });
            }
        }
    }

    let factor = source.downscale;
    let scaled = |(width, height): (u32, u32)| (width / factor, height / factor);
    let total_bytes = jobs
        .iter()
        .map(|job| {
            let (width, height) = scaled(job.size);
            3 * u64::from(width) * u64::from(height)
        })
        .sum();
    let cache = stream::plan(source.cache_mb, total_bytes);
    let decoded: Vec<(bool, View)> = jobs
        .par_iter()
        .map(|job| {
            let decode = {
                let (path, size) = (job.image_path.clone(), job.size);
                move || Ok(box_downscale_owned(read_rgb8(&path, Some(size))?, factor))
            };
            let image = match &cache {
                None => ViewImage::from(decode()?),
                Some(cache) => {
                    check_image_size(&job.image_path, job.size)?;
                    ViewImage::streamed(&job.image_path, scaled(job.size), cache, decode)
                }
            };
            let foreground = match &job.mask_path {
                Some(path) => {
                    let mask = read_mask(path, Some(job.size))?;
                    Some(if factor > 1 {
                        downscale_mask(&mask, job.size.0, job.size.1, factor)
                    } else {
                        mask
                    })
                }
                None => None,
            };
            Ok((
                job.is_train,
                View {
                    camera: job.camera,
                    frame: job.frame,
                    time: frame_time(job.frame, frame_count),
                    image,
                    dynamic_mask: None,
                    foreground,
                    matte: None,
                },
            ))
        })
        .collect::<Result<_, DataError>>()?;

    let mut dataset = Dataset {
        cameras,
        frame_count,
        ..Dataset::default()
    };
    for (is_train, view) in decoded {
        if is_train {
            dataset.train.push(view);
        } else {
            dataset.test.push(view);
        }
    }
    if dataset.train.is_empty() {
        return Err(DataError::dataset(&root, "no training views"));
    }
    Ok(dataset)
}

/// One image (and maybe mask) to decode.
struct ViewJob {
    is_train: bool,
    camera: usize,
    frame: usize,
    image_path: PathBuf,
    mask_path: Option<PathBuf>,
    /// Size the meta file promises, checked before downscaling.
    size: (u32, u32),
}

fn check_source(source: &PanopticSource, root: &Path) -> Result<(), DataError> {
    source.check().map_err(|e| DataError::setting(root, e))?;
    require_folder(root)?;
    Ok(())
}

/// Timesteps of the recording kept: every `stride`-th, at most `frames` of them.
fn kept_timesteps(total: usize, stride: usize, frames: Option<usize>) -> Vec<usize> {
    (0..total)
        .step_by(stride)
        .take(frames.unwrap_or(usize::MAX))
        .collect()
}

/// One camera per distinct id, in increasing id order; checks that a camera's intrinsics and
/// extrinsics are the same wherever it appears (the model assumes a static rig).
fn build_cameras(
    metas: &[&Meta],
    downscale: u32,
) -> Result<(Vec<Camera>, BTreeMap<u64, usize>), DataError> {
    struct First<'a> {
        meta: &'a Meta,
        view: &'a MetaView,
    }
    let mut first: BTreeMap<u64, First> = BTreeMap::new();
    for meta in metas {
        for view in meta.timesteps.iter().flatten() {
            match first.get(&view.cam_id) {
                None => {
                    first.insert(view.cam_id, First { meta, view });
                }
                Some(seen) => {
                    let (t, i) = view.index;
                    let same_size =
                        (seen.meta.width, seen.meta.height) == (meta.width, meta.height);
                    if !same_size
                        || !close(
                            &seen.view.intrinsics.to_cols_array(),
                            &view.intrinsics.to_cols_array(),
                        )
                    {
                        return Err(moving_camera(meta, "k", t, i, view.cam_id, seen));
                    }
                    if !close(
                        &seen.view.world_to_camera.to_cols_array(),
                        &view.world_to_camera.to_cols_array(),
                    ) {
                        return Err(moving_camera(meta, "w2c", t, i, view.cam_id, seen));
                    }
                }
            }
        }
    }
    fn moving_camera(
        meta: &Meta,
        key: &str,
        t: usize,
        i: usize,
        id: u64,
        seen: &First,
    ) -> DataError {
        let (t0, i0) = seen.view.index;
        DataError::field(
            &meta.path,
            format!("{key}[{t}][{i}]"),
            format!(
                "camera {id} differs from its entry [{t0}][{i0}] in {}; cameras must be static",
                seen.meta.path.display()
            ),
        )
    }
    fn close(a: &[f64], b: &[f64]) -> bool {
        a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= 1e-6 * (1.0 + x.abs()))
    }

    let scale = f64::from(downscale);
    let mut cameras = Vec::with_capacity(first.len());
    let mut index = BTreeMap::new();
    for (id, seen) in &first {
        let k = seen.view.intrinsics;
        index.insert(*id, cameras.len());
        cameras.push(Camera {
            width: seen.meta.width / downscale,
            height: seen.meta.height / downscale,
            fx: (k.x_axis.x / scale) as f32,
            fy: (k.y_axis.y / scale) as f32,
            cx: (k.z_axis.x / scale) as f32,
            cy: (k.z_axis.y / scale) as f32,
            world_to_camera: seen.view.world_to_camera.as_mat4(),
        });
    }
    Ok((cameras, index))
}

/// Parses and validates one meta file.
fn read_meta(path: &Path) -> Result<Meta, DataError> {
    let text = read_text(path)?;
    let raw: RawMeta = serde_json::from_str(&text)
        .map_err(|e| DataError::format(path, format!("invalid JSON: {e}")))?;
    let missing = |key: &str| DataError::field(path, key, "missing");
    let width = raw.w.ok_or_else(|| missing("w"))?;
    let height = raw.h.ok_or_else(|| missing("h"))?;
    let k = raw.k.ok_or_else(|| missing("k"))?;
    let w2c = raw.w2c.ok_or_else(|| missing("w2c"))?;
    let file_names = raw.file_names.ok_or_else(|| missing("fn"))?;
    let cam_ids = raw.cam_id.ok_or_else(|| missing("cam_id"))?;
    if width == 0 || height == 0 {
        return Err(DataError::field(
            path,
            if width == 0 { "w" } else { "h" },
            "image size must be positive",
        ));
    }

    let steps = file_names.len();
    for (key, len) in [
        ("k", k.len()),
        ("w2c", w2c.len()),
        ("cam_id", cam_ids.len()),
    ] {
        if len != steps {
            return Err(DataError::field(
                path,
                key,
                format!("has {len} timesteps but `fn` has {steps}"),
            ));
        }
    }

    let mut timesteps = Vec::with_capacity(steps);
    for t in 0..steps {
        let views = file_names[t].len();
        for (key, len) in [
            ("k", k[t].len()),
            ("w2c", w2c[t].len()),
            ("cam_id", cam_ids[t].len()),
        ] {
            if len != views {
                return Err(DataError::field(
                    path,
                    format!("{key}[{t}]"),
                    format!("has {len} entries but `fn[{t}]` has {views}"),
                ));
            }
        }
        let mut step = Vec::with_capacity(views);
        for i in 0..views {
            let intrinsics = parse_intrinsics(&k[t][i])
                .map_err(|message| DataError::field(path, format!("k[{t}][{i}]"), message))?;
            let world_to_camera = parse_rigid(&w2c[t][i])
                .map_err(|message| DataError::field(path, format!("w2c[{t}][{i}]"), message))?;
            step.push(MetaView {
                cam_id: cam_ids[t][i],
                intrinsics,
                world_to_camera,
                file_name: file_names[t][i].clone(),
                index: (t, i),
            });
        }
        // Two views of one camera in a timestep would be two images of one instant.
        let mut ids: Vec<u64> = step.iter().map(|v| v.cam_id).collect();
        ids.sort_unstable();
        if let Some(pair) = ids.windows(2).find(|p| p[0] == p[1]) {
            return Err(DataError::field(
                path,
                format!("cam_id[{t}]"),
                format!("camera {} appears twice", pair[0]),
            ));
        }
        timesteps.push(step);
    }
    Ok(Meta {
        path: path.to_path_buf(),
        width,
        height,
        timesteps,
    })
}

/// Checks a row-major matrix's shape and finiteness and returns its rows.
fn matrix_rows<const N: usize>(rows: &[Vec<f64>]) -> Result<[[f64; N]; N], String> {
    let shape = || {
        let cols: Vec<String> = rows.iter().map(|r| r.len().to_string()).collect();
        format!(
            "expected a {N}x{N} matrix, found {} rows of length [{}]",
            rows.len(),
            cols.join(", ")
        )
    };
    if rows.len() != N || rows.iter().any(|r| r.len() != N) {
        return Err(shape());
    }
    let mut out = [[0.0; N]; N];
    for (r, row) in rows.iter().enumerate() {
        for (c, &value) in row.iter().enumerate() {
            if !value.is_finite() {
                return Err(format!("entry [{r}][{c}] is not finite"));
            }
            out[r][c] = value;
        }
    }
    Ok(out)
}

/// A 3×3 pinhole intrinsics matrix `[[fx,0,cx],[0,fy,cy],[0,0,1]]` (row-major).
pub(crate) fn parse_intrinsics(rows: &[Vec<f64>]) -> Result<DMat3, String> {
    let m = matrix_rows::<3>(rows)?;
    if m[2] != [0.0, 0.0, 1.0] {
        return Err(format!("last row must be [0, 0, 1], found {:?}", m[2]));
    }
    if m[0][0] <= 0.0 || m[1][1] <= 0.0 {
        return Err(format!(
            "focal lengths must be positive, found fx {} fy {}",
            m[0][0], m[1][1]
        ));
    }
    // The camera model has no skew.
    if m[0][1].abs() > 1e-6 * m[0][0] || m[1][0].abs() > 1e-6 * m[1][1] {
        return Err(format!(
            "off-diagonal entries [0][1], [1][0] must be 0, found {} and {}",
            m[0][1], m[1][0]
        ));
    }
    Ok(DMat3::from_cols_array_2d(&m).transpose())
}

/// A 4×4 rigid transform (row-major): last row `[0,0,0,1]`, orthonormal rotation with
/// determinant +1 (tolerance 1e-3).
pub(crate) fn parse_rigid(rows: &[Vec<f64>]) -> Result<DMat4, String> {
    let m = matrix_rows::<4>(rows)?;
    if m[3] != [0.0, 0.0, 0.0, 1.0] {
        return Err(format!("last row must be [0, 0, 0, 1], found {:?}", m[3]));
    }
    let matrix = DMat4::from_cols_array_2d(&m).transpose();
    check_rotation(DMat3::from_mat4(matrix))?;
    Ok(matrix)
}

/// Checks that `r` is a rotation: `RᵀR = I` and `det R = +1` within 1e-3.
pub(crate) fn check_rotation(r: DMat3) -> Result<(), String> {
    let gram = r.transpose() * r;
    let error = (gram - DMat3::IDENTITY)
        .to_cols_array()
        .iter()
        .fold(0.0f64, |acc, v| acc.max(v.abs()));
    if error > 1e-3 {
        return Err(format!(
            "rotation block is not orthonormal (|RᵀR − I| = {error:.2e})"
        ));
    }
    let det = r.determinant();
    if (det - 1.0).abs() > 1e-3 {
        return Err(format!(
            "rotation block has determinant {det:.4}, expected +1"
        ));
    }
    Ok(())
}

/// Nearest-neighbour downscale of a row-major mask by an integer factor (the block centre).
pub(crate) fn downscale_mask(mask: &[bool], width: u32, height: u32, factor: u32) -> Vec<bool> {
    let (w, h, k) = (width as usize, height as usize, factor as usize);
    let (out_w, out_h) = (w / k, h / k);
    let mut out = Vec::with_capacity(out_w * out_h);
    for y in 0..out_h {
        let row = (y * k + k / 2) * w;
        out.extend((0..out_w).map(|x| mask[row + x * k + k / 2]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kept_timesteps_stride_then_count() {
        assert_eq!(kept_timesteps(10, 1, None), (0..10).collect::<Vec<_>>());
        assert_eq!(kept_timesteps(10, 3, None), vec![0, 3, 6, 9]);
        assert_eq!(kept_timesteps(10, 3, Some(2)), vec![0, 3]);
        assert_eq!(kept_timesteps(10, 1, Some(50)).len(), 10);
    }

    #[test]
    fn rigid_rejects_bad_matrices() {
        let id: Vec<Vec<f64>> = (0..4)
            .map(|r| (0..4).map(|c| f64::from(u8::from(r == c))).collect())
            .collect();
        assert!(parse_rigid(&id).is_ok());
        let mut scaled = id.clone();
        scaled[0][0] = 2.0;
        assert!(parse_rigid(&scaled).unwrap_err().contains("orthonormal"));
        let mut mirrored = id.clone();
        mirrored[0][0] = -1.0;
        assert!(parse_rigid(&mirrored).unwrap_err().contains("determinant"));
        let mut last = id.clone();
        last[3][0] = 1.0;
        assert!(parse_rigid(&last).unwrap_err().contains("last row"));
        assert!(parse_rigid(&id[..3]).unwrap_err().contains("4x4"));
    }

    #[test]
    fn rigid_reads_row_major() {
        let rows = vec![
            vec![1.0, 0.0, 0.0, 5.0],
            vec![0.0, 1.0, 0.0, 6.0],
            vec![0.0, 0.0, 1.0, 7.0],
            vec![0.0, 0.0, 0.0, 1.0],
        ];
        let m = parse_rigid(&rows).unwrap();
        assert_eq!(m.w_axis.truncate(), glam::DVec3::new(5.0, 6.0, 7.0));
    }

    #[test]
    fn mask_downscale_takes_block_centres() {
        let mask: Vec<bool> = (0..16).map(|i| i == 5 || i == 15).collect();
        // Block centres are pixels (1,1), (3,1), (1,3), (3,3) = indices 5, 7, 13, 15.
        assert_eq!(
            downscale_mask(&mask, 4, 4, 2),
            vec![true, false, false, true]
        );
    }
}
