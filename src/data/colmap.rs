//! COLMAP sparse models: cameras, registered images and 3D points, text or binary.
//!
//! [`read_model`] looks in a folder for `cameras`, `images` and `points3D` with the extension
//! `.bin` (preferred, as COLMAP writes by default) or `.txt`; when the folder has neither it
//! also tries `sparse/0` and `sparse` below it. Poses in COLMAP are world-to-camera in the
//! OpenCV convention already, so they are used as they are.
//!
//! Perspective models are read with their lens distortion: SIMPLE_PINHOLE and PINHOLE have
//! none; SIMPLE_RADIAL, RADIAL, OPENCV and FULL_OPENCV keep their coefficients in
//! [`ColmapCamera::distortion`], and the dataset readers undistort their images with
//! [`super::undistort`] (a posed [`ColmapImage::camera`] is the pinhole part alone). Fisheye
//! models are refused (undistort the images first with `colmap image_undistorter`).

use std::path::{Path, PathBuf};
use std::str::FromStr;

use glam::{DMat3, DQuat, DVec3, Mat4};

use super::error::read_text;
use super::undistort::Distortion;
use super::{Camera, DataError};
use crate::init::InitPoint;

/// An intrinsic camera of a COLMAP model (shared by the images taken with it).
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapCamera {
    /// COLMAP's `CAMERA_ID`.
    pub id: u32,
    /// COLMAP's model name, e.g. `PINHOLE`.
    pub model: &'static str,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Horizontal focal length in pixels (the single `f` of SIMPLE_* and RADIAL models).
    pub fx: f32,
    /// Vertical focal length in pixels (equal to `fx` for single-focal models).
    pub fy: f32,
    /// Principal point x in pixels (COLMAP's convention: pixel centres at +0.5, as in
    /// [`Camera`]).
    pub cx: f32,
    /// Principal point y in pixels.
    pub cy: f32,
    /// The lens distortion of the model's remaining parameters ([`Distortion::None`] for
    /// SIMPLE_PINHOLE and PINHOLE).
    pub distortion: Distortion,
}

/// A registered image: its file name and the posed camera that took it.
#[derive(Clone, Debug, PartialEq)]
pub struct ColmapImage {
    /// COLMAP's `IMAGE_ID`.
    pub id: u32,
    /// Image file name relative to the image folder of the reconstruction.
    pub name: String,
    /// Id of its [`ColmapCamera`].
    pub camera_id: u32,
    /// Pinhole intrinsics of its camera (without the distortion) with this image's pose.
    pub camera: Camera,
}

/// A sparse reconstruction.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ColmapModel {
    /// Cameras sorted by id.
    pub cameras: Vec<ColmapCamera>,
    /// Images sorted by name (COLMAP's own order depends on registration order).
    pub images: Vec<ColmapImage>,
    /// The 3D points, with colours in [0, 1].
    pub points: Vec<InitPoint>,
}

/// A COLMAP camera model: its id in binary files, name in text files, parameter count.
struct CameraModel {
    id: i32,
    name: &'static str,
    param_count: usize,
    /// How fx, fy, cx, cy are read from the parameters; `None` for non-pinhole models.
    layout: Option<IntrinsicsLayout>,
}

#[derive(Clone, Copy)]
enum IntrinsicsLayout {
    /// `f, cx, cy, ...`
    SingleFocal,
    /// `fx, fy, cx, cy, ...`
    TwoFocals,
}

/// Every model COLMAP defines (src/colmap/sensor/models.h), so that a file using one we do
/// not support is told apart from a corrupt file.
const CAMERA_MODELS: [CameraModel; 12] = [
    model(0, "SIMPLE_PINHOLE", 3, Some(IntrinsicsLayout::SingleFocal)),
    model(1, "PINHOLE", 4, Some(IntrinsicsLayout::TwoFocals)),
    model(2, "SIMPLE_RADIAL", 4, Some(IntrinsicsLayout::SingleFocal)),
    model(3, "RADIAL", 5, Some(IntrinsicsLayout::SingleFocal)),
    model(4, "OPENCV", 8, Some(IntrinsicsLayout::TwoFocals)),
    model(5, "OPENCV_FISHEYE", 8, None),
    model(6, "FULL_OPENCV", 12, Some(IntrinsicsLayout::TwoFocals)),
    model(7, "FOV", 5, None),
    model(8, "SIMPLE_RADIAL_FISHEYE", 4, None),
    model(9, "RADIAL_FISHEYE", 5, None),
    model(10, "THIN_PRISM_FISHEYE", 12, None),
    model(11, "RAD_TAN_THIN_PRISM_FISHEYE", 16, None),
];

const fn model(
    id: i32,
    name: &'static str,
    param_count: usize,
    layout: Option<IntrinsicsLayout>,
) -> CameraModel {
    CameraModel {
        id,
        name,
        param_count,
        layout,
    }
}

/// Reads a sparse model from `dir` (or `dir/sparse/0`, `dir/sparse`), binary or text.
pub fn read_model(dir: &Path) -> Result<ColmapModel, DataError> {
    match find_model(dir) {
        Some((folder, extension)) => read_model_files(&folder, extension),
        None => Err(DataError::dataset(
            dir,
            "no COLMAP model: expected cameras.bin + images.bin + points3D.bin (or the .txt \
             versions) in this folder, in sparse/0 or in sparse",
        )),
    }
}

/// The folder of the sparse model in `dir` (`dir` itself, `dir/sparse/0` or `dir/sparse`, the
/// first that holds `cameras` and `images`) and its files' extension, `bin` (preferred, as
/// COLMAP writes by default) or `txt`.
pub fn find_model(dir: &Path) -> Option<(PathBuf, &'static str)> {
    let candidates = [dir.to_path_buf(), dir.join("sparse/0"), dir.join("sparse")];
    candidates.into_iter().find_map(|folder| {
        ["bin", "txt"].into_iter().find_map(|extension| {
            let cameras = folder.join(format!("cameras.{extension}"));
            let images = folder.join(format!("images.{extension}"));
            (cameras.is_file() && images.is_file()).then(|| (folder.clone(), extension))
        })
    })
}

/// Reads the model whose files are in `folder` with `extension` (see [`find_model`]).
pub fn read_model_files(folder: &Path, extension: &str) -> Result<ColmapModel, DataError> {
    let binary = extension == "bin";
    let cameras_path = folder.join(format!("cameras.{extension}"));
    let images_path = folder.join(format!("images.{extension}"));
    let points_path = folder.join(format!("points3D.{extension}"));

    let mut cameras = if binary {
        read_cameras_bin(&cameras_path)?
    } else {
        read_cameras_text(&cameras_path)?
    };
    cameras.sort_by_key(|c| c.id);
    if let Some(pair) = cameras.windows(2).find(|pair| pair[0].id == pair[1].id) {
        return Err(DataError::format(
            &cameras_path,
            format!("camera id {} appears twice", pair[0].id),
        ));
    }

    let posed = if binary {
        read_images_bin(&images_path)?
    } else {
        read_images_text(&images_path)?
    };
    let mut images = Vec::with_capacity(posed.len());
    for image in posed {
        let Ok(index) = cameras.binary_search_by_key(&image.camera_id, |c| c.id) else {
            return Err(DataError::format(
                &images_path,
                format!(
                    "{}: image `{}` uses camera id {}, which {} does not define",
                    image.place,
                    image.name,
                    image.camera_id,
                    cameras_path.display()
                ),
            ));
        };
        images.push(ColmapImage {
            id: image.id,
            name: image.name,
            camera_id: image.camera_id,
            camera: posed_camera(&cameras[index], image.world_to_camera),
        });
    }
    images.sort_by(|a, b| a.name.cmp(&b.name));

    let points = if points_path.is_file() {
        read_points3d(&points_path)?
    } else {
        tracing::warn!(
            "{}: not found; the COLMAP model has no points",
            points_path.display()
        );
        Vec::new()
    };
    Ok(ColmapModel {
        cameras,
        images,
        points,
    })
}

/// Reads COLMAP 3D points, `points3D.txt` or `points3D.bin` by extension; colours /255.
pub fn read_points3d(path: &Path) -> Result<Vec<InitPoint>, DataError> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("bin") => read_points_bin(path),
        Some("txt") => read_points_text(path),
        _ => Err(DataError::format(
            path,
            "COLMAP points must be points3D.txt or points3D.bin",
        )),
    }
}

fn posed_camera(intrinsics: &ColmapCamera, world_to_camera: Mat4) -> Camera {
    Camera {
        width: intrinsics.width,
        height: intrinsics.height,
        fx: intrinsics.fx,
        fy: intrinsics.fy,
        cx: intrinsics.cx,
        cy: intrinsics.cy,
        world_to_camera,
    }
}

/// A COLMAP camera from its model, size and parameter list; `place` says where it was read.
fn build_camera(
    path: &Path,
    place: &str,
    id: u32,
    model: &CameraModel,
    width: u64,
    height: u64,
    params: &[f64],
) -> Result<ColmapCamera, DataError> {
    let at = |message: String| DataError::format(path, format!("{place}: {message}"));
    let Some(layout) = model.layout else {
        return Err(at(format!(
            "camera {id} uses the fisheye model {}, which tadgs does not undistort; undistort \
             the images first (`colmap image_undistorter`) and use the PINHOLE model it writes",
            model.name
        )));
    };
    let (width, height) = match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) if w > 0 && h > 0 => (w, h),
        _ => return Err(at(format!("camera {id} has invalid size {width}×{height}"))),
    };
    if params.iter().any(|p| !p.is_finite()) {
        return Err(at(format!(
            "camera {id} has non-finite parameters {params:?}"
        )));
    }
    let (fx, fy, cx, cy, distortion) = match layout {
        IntrinsicsLayout::SingleFocal => (params[0], params[0], params[1], params[2], &params[3..]),
        IntrinsicsLayout::TwoFocals => (params[0], params[1], params[2], params[3], &params[4..]),
    };
    if fx <= 0.0 || fy <= 0.0 {
        return Err(at(format!(
            "camera {id} has non-positive focal length {fx}, {fy}"
        )));
    }
    Ok(ColmapCamera {
        id,
        model: model.name,
        width,
        height,
        fx: fx as f32,
        fy: fy as f32,
        cx: cx as f32,
        cy: cy as f32,
        distortion: Distortion::from_colmap(model.name, distortion),
    })
}

/// World-to-camera from COLMAP's quaternion (w, x, y, z) and translation, computed in f64.
fn pose_matrix(qvec: [f64; 4], tvec: [f64; 3]) -> Option<Mat4> {
    let [w, x, y, z] = qvec;
    let q = DQuat::from_xyzw(x, y, z, w);
    let norm = q.length();
    if !norm.is_finite() || norm < 1e-12 || tvec.iter().any(|t| !t.is_finite()) {
        return None;
    }
    let rotation = DMat3::from_quat(q / norm);
    let translation = DVec3::from_array(tvec);
    Some(Mat4::from_cols(
        rotation.x_axis.as_vec3().extend(0.0),
        rotation.y_axis.as_vec3().extend(0.0),
        rotation.z_axis.as_vec3().extend(0.0),
        translation.as_vec3().extend(1.0),
    ))
}

/// An image record before its camera is attached; `place` locates it for later errors.
struct PosedImage {
    id: u32,
    name: String,
    camera_id: u32,
    world_to_camera: Mat4,
    place: String,
}

// ---------------------------------------------------------------------------------------
// Text files
// ---------------------------------------------------------------------------------------

/// The whitespace-separated fields of one line of a text model, for parsing with errors
/// that name the file and line.
struct TextRecord<'a> {
    path: &'a Path,
    line: usize,
    fields: Vec<&'a str>,
}

impl<'a> TextRecord<'a> {
    fn new(path: &'a Path, line: usize, text: &'a str) -> Self {
        Self {
            path,
            line,
            fields: text.split_whitespace().collect(),
        }
    }

    fn error(&self, message: impl std::fmt::Display) -> DataError {
        DataError::format(self.path, format!("line {}: {message}", self.line))
    }

    /// Fails unless there are at least `count` fields; `layout` names them for the message.
    fn require(&self, count: usize, layout: &str) -> Result<(), DataError> {
        if self.fields.len() < count {
            return Err(self.error(format!(
                "expected at least {count} fields ({layout}), found {}",
                self.fields.len()
            )));
        }
        Ok(())
    }

    fn parse<T: FromStr>(&self, index: usize, name: &str) -> Result<T, DataError> {
        let text = self.fields[index];
        text.parse().map_err(|_| {
            self.error(format!(
                "field {} ({name}) is `{text}`, not a valid {}",
                index + 1,
                std::any::type_name::<T>()
            ))
        })
    }

    fn parse_array<const N: usize>(&self, first: usize, name: &str) -> Result<[f64; N], DataError> {
        let mut values = [0.0; N];
        for (i, value) in values.iter_mut().enumerate() {
            *value = self.parse(first + i, name)?;
        }
        Ok(values)
    }
}

/// Numbered lines that are neither blank nor `#` comments.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines()
        .enumerate()
        .map(|(i, line)| (i + 1, line.trim()))
        .filter(|(_, line)| !line.is_empty() && !line.starts_with('#'))
}

fn read_cameras_text(path: &Path) -> Result<Vec<ColmapCamera>, DataError> {
    let text = read_text(path)?;
    let mut cameras = Vec::new();
    for (line, content) in data_lines(&text) {
        let record = TextRecord::new(path, line, content);
        record.require(4, "CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]")?;
        let id: u32 = record.parse(0, "CAMERA_ID")?;
        let name = record.fields[1];
        let Some(model) = CAMERA_MODELS.iter().find(|m| m.name == name) else {
            let known: Vec<&str> = CAMERA_MODELS.iter().map(|m| m.name).collect();
            return Err(record.error(format!(
                "unknown camera model `{name}` (COLMAP models: {})",
                known.join(", ")
            )));
        };
        let params = &record.fields[4..];
        if params.len() != model.param_count {
            return Err(record.error(format!(
                "camera model {} takes {} parameters, found {}",
                model.name,
                model.param_count,
                params.len()
            )));
        }
        let params = (0..params.len())
            .map(|i| record.parse::<f64>(4 + i, "PARAMS"))
            .collect::<Result<Vec<_>, _>>()?;
        cameras.push(build_camera(
            path,
            &format!("line {line}"),
            id,
            model,
            record.parse(2, "WIDTH")?,
            record.parse(3, "HEIGHT")?,
            &params,
        )?);
    }
    Ok(cameras)
}

fn read_images_text(path: &Path) -> Result<Vec<PosedImage>, DataError> {
    const LAYOUT: &str = "IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME";
    let text = read_text(path)?;
    let mut images = Vec::new();
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, line)| (i + 1, line.trim()));
    while let Some((line, content)) = lines.next() {
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let record = TextRecord::new(path, line, content);
        record.require(10, LAYOUT)?;
        let qvec = record.parse_array::<4>(1, "QW QX QY QZ")?;
        let tvec = record.parse_array::<3>(5, "TX TY TZ")?;
        let world_to_camera = pose_matrix(qvec, tvec).ok_or_else(|| {
            record.error("pose has a zero or non-finite quaternion or translation")
        })?;
        images.push(PosedImage {
            id: record.parse(0, "IMAGE_ID")?,
            name: record.fields[9..].join(" "),
            camera_id: record.parse(8, "CAMERA_ID")?,
            world_to_camera,
            place: format!("line {line}"),
        });
        // Every image line is followed by its 2D points (possibly an empty line): skip it.
        lines.next();
    }
    Ok(images)
}

fn read_points_text(path: &Path) -> Result<Vec<InitPoint>, DataError> {
    let text = read_text(path)?;
    let mut points = Vec::new();
    for (line, content) in data_lines(&text) {
        let record = TextRecord::new(path, line, content);
        record.require(8, "POINT3D_ID X Y Z R G B ERROR TRACK[]")?;
        let [x, y, z] = record.parse_array::<3>(1, "X Y Z")?;
        let position = DVec3::new(x, y, z).as_vec3();
        if !position.is_finite() {
            return Err(record.error(format!("non-finite position {position}")));
        }
        let mut color = [0.0; 3];
        for (channel, value) in color.iter_mut().enumerate() {
            *value = f32::from(record.parse::<u8>(4 + channel, "R G B")?) / 255.0;
        }
        points.push(InitPoint { position, color });
    }
    Ok(points)
}

// ---------------------------------------------------------------------------------------
// Binary files (little-endian, as COLMAP writes them)
// ---------------------------------------------------------------------------------------

/// A cursor over a binary model file whose errors name the byte offset and the record.
struct BinaryCursor<'a> {
    path: &'a Path,
    bytes: &'a [u8],
    offset: usize,
    /// Where the field read last (or being read) starts: errors point at it.
    field_start: usize,
    /// What is being read, e.g. `point`, and which one: for error messages.
    record_kind: &'static str,
    record_index: u64,
    record_count: u64,
}

impl<'a> BinaryCursor<'a> {
    fn new(path: &'a Path, bytes: &'a [u8], record_kind: &'static str) -> Self {
        Self {
            path,
            bytes,
            offset: 0,
            field_start: 0,
            record_kind,
            record_index: 0,
            record_count: 0,
        }
    }

    fn error(&self, message: impl std::fmt::Display) -> DataError {
        DataError::format(
            self.path,
            format!(
                "byte offset {}, {} {} of {}: {message}",
                self.field_start,
                self.record_kind,
                self.record_index + 1,
                self.record_count
            ),
        )
    }

    fn take(&mut self, count: usize, field: &str) -> Result<&'a [u8], DataError> {
        self.field_start = self.offset;
        let remaining = self.bytes.len() - self.offset;
        if remaining < count {
            return Err(self.error(format!(
                "file truncated: `{field}` needs {count} bytes, only {remaining} left"
            )));
        }
        let slice = &self.bytes[self.offset..self.offset + count];
        self.offset += count;
        Ok(slice)
    }

    fn array<const N: usize>(&mut self, field: &str) -> Result<[u8; N], DataError> {
        let slice = self.take(N, field)?;
        let mut out = [0; N];
        out.copy_from_slice(slice);
        Ok(out)
    }

    fn u8(&mut self, field: &str) -> Result<u8, DataError> {
        Ok(self.array::<1>(field)?[0])
    }

    fn u32(&mut self, field: &str) -> Result<u32, DataError> {
        self.array(field).map(u32::from_le_bytes)
    }

    fn i32(&mut self, field: &str) -> Result<i32, DataError> {
        self.array(field).map(i32::from_le_bytes)
    }

    fn u64(&mut self, field: &str) -> Result<u64, DataError> {
        self.array(field).map(u64::from_le_bytes)
    }

    fn f64(&mut self, field: &str) -> Result<f64, DataError> {
        self.array(field).map(f64::from_le_bytes)
    }

    fn f64s<const N: usize>(&mut self, field: &str) -> Result<[f64; N], DataError> {
        let mut values = [0.0; N];
        for value in &mut values {
            *value = self.f64(field)?;
        }
        Ok(values)
    }

    /// Skips `count` items of `item_size` bytes (2D points, tracks).
    fn skip(&mut self, count: u64, item_size: usize, field: &str) -> Result<(), DataError> {
        let bytes = usize::try_from(count)
            .ok()
            .and_then(|c| c.checked_mul(item_size))
            .ok_or_else(|| self.error(format!("`{field}` count {count} is impossibly large")))?;
        self.take(bytes, field).map(|_| ())
    }

    /// Reads the leading record count, and a capacity for it that the file size can back
    /// (so that a corrupt count cannot request a huge allocation).
    fn record_count(&mut self, min_record_size: usize) -> Result<usize, DataError> {
        let count = self.u64("record count")?;
        self.record_count = count;
        let possible = (self.bytes.len() - self.offset) / min_record_size.max(1);
        Ok(usize::try_from(count).unwrap_or(usize::MAX).min(possible))
    }

    fn start_record(&mut self, index: u64) {
        self.record_index = index;
    }

    fn finish(&self) -> Result<(), DataError> {
        if self.offset != self.bytes.len() {
            return Err(DataError::format(
                self.path,
                format!(
                    "{} unexpected trailing bytes after the last {} (byte offset {})",
                    self.bytes.len() - self.offset,
                    self.record_kind,
                    self.offset
                ),
            ));
        }
        Ok(())
    }
}

fn read_bytes(path: &Path) -> Result<Vec<u8>, DataError> {
    std::fs::read(path).map_err(|e| DataError::io(path, e))
}

/// Reads a COLMAP binary file of `record_kind` records: a record count, then the records,
/// parsed one at a time by `read` (given the cursor at the record's start and its index), then
/// nothing more. `min_record_size` bounds the preallocation by what the file can hold.
fn read_records<T>(
    path: &Path,
    record_kind: &'static str,
    min_record_size: usize,
    mut read: impl FnMut(&mut BinaryCursor, u64) -> Result<T, DataError>,
) -> Result<Vec<T>, DataError> {
    let bytes = read_bytes(path)?;
    let mut cursor = BinaryCursor::new(path, &bytes, record_kind);
    let capacity = cursor.record_count(min_record_size)?;
    let mut records = Vec::with_capacity(capacity);
    for index in 0..cursor.record_count {
        cursor.start_record(index);
        records.push(read(&mut cursor, index)?);
    }
    cursor.finish()?;
    Ok(records)
}

fn read_cameras_bin(path: &Path) -> Result<Vec<ColmapCamera>, DataError> {
    read_records(path, "camera", 4 + 4 + 8 + 8 + 3 * 8, |cursor, index| {
        let record_start = cursor.offset;
        let id = cursor.u32("camera_id")?;
        let model_id = cursor.i32("model_id")?;
        let Some(model) = CAMERA_MODELS.iter().find(|m| m.id == model_id) else {
            return Err(cursor.error(format!(
                "unknown camera model id {model_id} (COLMAP defines 0 to {})",
                CAMERA_MODELS.len() - 1
            )));
        };
        let width = cursor.u64("width")?;
        let height = cursor.u64("height")?;
        let mut params = vec![0.0; model.param_count];
        for value in &mut params {
            *value = cursor.f64("params")?;
        }
        let place = format!(
            "byte offset {record_start}, camera {} of {}",
            index + 1,
            cursor.record_count
        );
        build_camera(path, &place, id, model, width, height, &params)
    })
}

fn read_images_bin(path: &Path) -> Result<Vec<PosedImage>, DataError> {
    read_records(path, "image", 4 + 7 * 8 + 4 + 1 + 8, |cursor, index| {
        let record_start = cursor.offset;
        let id = cursor.u32("image_id")?;
        let qvec = cursor.f64s::<4>("qvec")?;
        let tvec = cursor.f64s::<3>("tvec")?;
        let camera_id = cursor.u32("camera_id")?;
        let mut name_bytes = Vec::new();
        loop {
            match cursor.u8("name (NUL-terminated)")? {
                0 => break,
                byte => name_bytes.push(byte),
            }
        }
        let name = String::from_utf8(name_bytes)
            .map_err(|_| cursor.error("image name is not valid UTF-8"))?;
        let point_count = cursor.u64("num_points2D")?;
        cursor.skip(point_count, 8 + 8 + 8, "points2D")?;
        let world_to_camera = pose_matrix(qvec, tvec).ok_or_else(|| {
            cursor.error("pose has a zero or non-finite quaternion or translation")
        })?;
        Ok(PosedImage {
            id,
            name,
            camera_id,
            world_to_camera,
            place: format!(
                "byte offset {record_start}, image {} of {}",
                index + 1,
                cursor.record_count
            ),
        })
    })
}

fn read_points_bin(path: &Path) -> Result<Vec<InitPoint>, DataError> {
    read_records(path, "point", 8 + 3 * 8 + 3 + 8 + 8, |cursor, _| {
        let _id = cursor.u64("point3D_id")?;
        let xyz = cursor.f64s::<3>("xyz")?;
        let rgb = cursor.array::<3>("rgb")?;
        let _error = cursor.f64("error")?;
        let track_length = cursor.u64("track_length")?;
        cursor.skip(track_length, 4 + 4, "track")?;
        let position = DVec3::from_array(xyz).as_vec3();
        if !position.is_finite() {
            return Err(cursor.error(format!("non-finite position {position}")));
        }
        Ok(InitPoint {
            position,
            color: rgb.map(|c| f32::from(c) / 255.0),
        })
    })
}
