//! Built-in synthetic scenes: analytic coloured objects moving along keyframed paths,
//! seen by a ring of cameras and rendered to ground-truth images by a small ray caster,
//! together with exact dynamic-region masks.
//!
//! The ray caster is deliberately independent of the splatting renderer: it uses only the
//! [`Camera`] model (its pose and intrinsics), so the ground truth cannot inherit the
//! rasteriser's mistakes.
//!
//! Conventions: world up is +Y; normalised time runs over [0, 1] and frame `f` of `T` is
//! at `f / (T − 1)`; colours are linear RGB in [0, 1].
//!
//! The scene schema and its validation live here; the ray caster in `raycast`; the built-in
//! demo scene in `demo`.

use std::f32::consts::PI;

use glam::Vec3;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::data::{Camera, Dataset, View};
use crate::io::image::Image;
use crate::scene::{Check, FieldError, fail};

mod demo;
mod raycast;

pub use demo::demo_scene;

/// Largest supported `supersample`.
const MAX_SUPERSAMPLE: u32 = 8;

fn default_supersample() -> u32 {
    2
}

/// A synthetic multi-view video: a ring of cameras around analytic objects on an optional floor.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SyntheticScene {
    /// Number of video frames (at least 2); frame `f` is at normalised time `f / (frames − 1)`.
    pub frames: usize,
    /// Image width in pixels.
    pub width: u32,
    /// Image height in pixels.
    pub height: u32,
    /// Where the cameras are.
    pub cameras: CameraRing,
    /// Camera indices held out for evaluation; the others are used for training.
    pub held_out: Vec<usize>,
    /// Colour of rays that hit nothing.
    pub background: [f32; 3],
    /// Optional floor square.
    #[serde(default)]
    pub floor: Option<Floor>,
    /// The objects, static or moving.
    pub objects: Vec<SceneObject>,
    /// Anti-aliasing: `s × s` rays per pixel on a regular grid, averaged (default 2).
    #[serde(default = "default_supersample")]
    pub supersample: u32,
    /// Give every view a foreground mask (the pixels that show an object, not the floor or
    /// the sky), like the `seg/` masks of a Panoptic capture, so that `init.method: Auto`
    /// carves the objects' visual hull at every anchor frame instead of scattering random
    /// points (default false).
    #[serde(default)]
    pub foreground_masks: bool,
}

/// Cameras evenly spaced on a horizontal circle, all looking at a common target.
///
/// Camera `i` sits at angle `2π·i / count` (camera 0 on the +Z side of the target, increasing
/// towards +X), `radius` away from the target horizontally and `height` above it.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CameraRing {
    /// Number of cameras (at least 2).
    pub count: usize,
    /// Horizontal distance of every camera from the target.
    pub radius: f32,
    /// Height of the camera centres above the target (negative: below it).
    pub height: f32,
    /// World point every camera looks at.
    pub target: [f32; 3],
    /// Horizontal field of view in degrees, in (0, 180).
    pub fov_x_degrees: f32,
}

/// A horizontal floor square centred on the world Y axis.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Floor {
    /// Height of the floor plane.
    pub y: f32,
    /// Half the side of the square: it covers `|x| ≤ half_size`, `|z| ≤ half_size`.
    pub half_size: f32,
    /// Surface pattern, evaluated in world coordinates relative to `(0, y, 0)`.
    pub texture: Texture,
}

/// The geometry of an object, centred on its local origin.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum Shape {
    /// A ball.
    Sphere {
        /// Radius, positive.
        radius: f32,
    },
    /// An axis-aligned (in the local frame) box.
    Box {
        /// Half the side lengths along local X, Y and Z, all positive.
        half_extents: [f32; 3],
    },
}

/// A surface pattern, evaluated in the surface's local frame so that it moves with the object.
///
/// Pattern edges are slightly softened (a few pixels wide at demo resolution), and further
/// anti-aliased by supersampling.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub enum Texture {
    /// One colour everywhere.
    Solid([f32; 3]),
    /// A checkerboard of `a` and `b` with `cells` cells per unit length: a 3D solid checker on
    /// spheres, the 2D checker of the face plane on box faces and the floor.
    Checker {
        /// Colour of the cells on one side of the board (including the cell at the +,+ corner
        /// of the origin).
        a: [f32; 3],
        /// Colour of the other cells.
        b: [f32; 3],
        /// Cells per unit length, positive.
        cells: f32,
    },
    /// Alternating sectors of `a` and `b` around the local Y axis: vertical stripes on the
    /// sides of an object (pie slices on its top and bottom), so spin is visible.
    Stripes {
        /// Colour of the first stripe of each pair.
        a: [f32; 3],
        /// Colour of the second stripe of each pair.
        b: [f32; 3],
        /// Number of `a`/`b` stripe pairs around the axis; a positive whole number so the
        /// pattern closes up.
        count: f32,
    },
}

/// One keyframe of an object's path.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Keyframe {
    /// Normalised time in [0, 1] (times outside are allowed but never rendered).
    pub time: f32,
    /// World position of the object's centre at that time.
    pub position: [f32; 3],
}

/// An analytic object: a shape with a texture, moving along a path and possibly spinning.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SceneObject {
    /// Geometry.
    pub shape: Shape,
    /// Surface pattern in the object's local frame.
    pub texture: Texture,
    /// Keyframes of the centre position, strictly increasing in time. The position is
    /// interpolated with a Catmull-Rom (cubic Hermite) spline through the keyframes — linear
    /// for two keyframes — and held constant before the first and after the last keyframe;
    /// a single keyframe makes the object static.
    pub path: Vec<Keyframe>,
    /// Spin about the local Y axis in radians per unit of normalised time (the rotation angle
    /// at time `t` is `spin · t`).
    #[serde(default)]
    pub spin: f32,
    /// Normalised time window `(start, end)`, inclusive, in which the object exists;
    /// `None`: always.
    #[serde(default)]
    pub visible: Option<(f32, f32)>,
}

impl SceneObject {
    /// Centre position at normalised time `t` (see [`SceneObject::path`]); the origin for an
    /// empty path.
    pub fn position_at(&self, t: f32) -> Vec3 {
        let path = &self.path;
        let Some(first) = path.first() else {
            return Vec3::ZERO;
        };
        let last = &path[path.len() - 1];
        if path.len() == 1 || t.is_nan() || t <= first.time {
            return Vec3::from(first.position);
        }
        if t >= last.time {
            return Vec3::from(last.position);
        }
        // Segment i: path[i].time <= t < path[i + 1].time (clamped, should the path be unsorted).
        let i = path
            .partition_point(|k| k.time <= t)
            .clamp(1, path.len() - 1)
            - 1;
        let (k0, k1) = (&path[i], &path[i + 1]);
        let h = k1.time - k0.time;
        let s = (t - k0.time) / h;
        let (p0, p1) = (Vec3::from(k0.position), Vec3::from(k1.position));
        let (m0, m1) = (self.tangent(i), self.tangent(i + 1));
        let (s2, s3) = (s * s, s * s * s);
        p0 * (2.0 * s3 - 3.0 * s2 + 1.0)
            + m0 * (h * (s3 - 2.0 * s2 + s))
            + p1 * (3.0 * s2 - 2.0 * s3)
            + m1 * (h * (s3 - s2))
    }

    /// Velocity of the spline at keyframe `k`: central difference inside, one-sided at the ends.
    fn tangent(&self, k: usize) -> Vec3 {
        let path = &self.path;
        let a = &path[k.saturating_sub(1)];
        let b = &path[(k + 1).min(path.len() - 1)];
        (Vec3::from(b.position) - Vec3::from(a.position)) / (b.time - a.time)
    }

    /// Whether the object exists at normalised time `t`.
    pub fn exists_at(&self, t: f32) -> bool {
        self.visible
            .is_none_or(|(start, end)| start <= t && t <= end)
    }

    /// Whether the object's pixels can change over [0, 1]: it moves (two keyframes at different
    /// positions), spins, or exists for only part of [0, 1].
    pub fn is_dynamic(&self) -> bool {
        let moves = self.path.windows(2).any(|w| w[0].position != w[1].position);
        let partial = self
            .visible
            .is_some_and(|(start, end)| start > 0.0 || end < 1.0);
        moves || self.spin != 0.0 || partial
    }
}

impl SyntheticScene {
    /// Checks every field; the error names the offending one (e.g. `cameras.radius`).
    pub fn validate(&self) -> Result<(), FieldError> {
        if self.frames < 2 {
            return fail("frames", format!("must be at least 2, got {}", self.frames));
        }
        for (field, side) in [("width", self.width), ("height", self.height)] {
            if !(1..=super::MAX_IMAGE_SIDE).contains(&side) {
                return fail(
                    field,
                    format!(
                        "must be between 1 and {} pixels, got {side}",
                        super::MAX_IMAGE_SIDE
                    ),
                );
            }
        }
        if !(1..=MAX_SUPERSAMPLE).contains(&self.supersample) {
            return fail(
                "supersample",
                format!(
                    "must be between 1 and {MAX_SUPERSAMPLE}, got {}",
                    self.supersample
                ),
            );
        }
        let ring = &self.cameras;
        if ring.count < 2 {
            return fail(
                "cameras.count",
                format!("must be at least 2, got {}", ring.count),
            );
        }
        positive("cameras.radius", ring.radius)?;
        finite("cameras.height", ring.height)?;
        finite_vec("cameras.target", ring.target)?;
        if !(ring.fov_x_degrees > 0.0 && ring.fov_x_degrees < 180.0) {
            return fail(
                "cameras.fov_x_degrees",
                format!("must be in (0, 180), got {}", ring.fov_x_degrees),
            );
        }
        for (i, &c) in self.held_out.iter().enumerate() {
            if c >= ring.count {
                return fail(
                    &format!("held_out[{i}]"),
                    format!(
                        "= {c} is not a camera index (cameras.count = {})",
                        ring.count
                    ),
                );
            }
            if self.held_out[..i].contains(&c) {
                return fail("held_out", format!("lists camera {c} twice"));
            }
        }
        if self.held_out.len() >= ring.count {
            return fail("held_out", "must leave at least one camera for training");
        }
        colour("background", self.background)?;
        if let Some(floor) = &self.floor {
            finite("floor.y", floor.y)?;
            positive("floor.half_size", floor.half_size)?;
            validate_texture("floor.texture", &floor.texture)?;
        }
        for (i, object) in self.objects.iter().enumerate() {
            validate_object(&format!("objects[{i}]"), object)?;
        }
        Ok(())
    }

    /// The cameras of the ring (see [`CameraRing`]), each `width × height`.
    pub fn cameras(&self) -> Vec<Camera> {
        let ring = &self.cameras;
        let target = Vec3::from(ring.target);
        (0..ring.count)
            .map(|i| {
                let angle = 2.0 * PI * i as f32 / ring.count as f32;
                let eye = target
                    + Vec3::new(
                        ring.radius * angle.sin(),
                        ring.height,
                        ring.radius * angle.cos(),
                    );
                Camera::look_at(
                    eye,
                    target,
                    Vec3::Y,
                    self.width,
                    self.height,
                    ring.fov_x_degrees.to_radians(),
                )
            })
            .collect()
    }

    /// Whether object `object` is dynamic (see [`SceneObject::is_dynamic`]).
    ///
    /// # Panics
    /// If `object` is not an index into [`SyntheticScene::objects`].
    pub fn is_dynamic(&self, object: usize) -> bool {
        self.objects[object].is_dynamic()
    }
    /// Renders every camera × frame (frame `f` at time `f / (frames − 1)`) in parallel.
    ///
    /// Training cameras are all but [`SyntheticScene::held_out`], in increasing order; test
    /// cameras are `held_out` in the order given. Dynamic masks are always present.
    pub fn build(&self) -> Result<Dataset, String> {
        self.validate().map_err(|e| e.to_string())?;
        let cameras = self.cameras();
        let frames = self.frames;
        // RGB f32 and two mask bytes (dynamic, object) per pixel of every view, checked
        // before any is allocated.
        let bytes = (cameras.len() * frames) as u64
            * u64::from(self.width)
            * u64::from(self.height)
            * (12 + 2);
        if let Some(available) = crate::budget::available_memory().filter(|&a| bytes > a) {
            return Err(format!(
                "{} cameras × {frames} frames at {}×{} need {:.1} GB of images, more than the \
                 {:.1} GB of memory available: lower width, height, frames or cameras.count",
                cameras.len(),
                self.width,
                self.height,
                bytes as f64 / 1e9,
                available as f64 / 1e9
            ));
        }
        let rendered: Vec<(Image, Vec<bool>, Vec<bool>)> = (0..cameras.len() * frames)
            .into_par_iter()
            .map(|k| {
                let (camera, frame) = (k / frames, k % frames);
                self.render_with_objects(&cameras[camera], frame as f32 / (frames - 1) as f32)
            })
            .collect();
        let mut dataset = Dataset {
            cameras,
            frame_count: frames,
            ..Dataset::default()
        };
        for (k, (image, mask, objects)) in rendered.into_iter().enumerate() {
            let (camera, frame) = (k / frames, k % frames);
            let view = View {
                camera,
                frame,
                time: dataset.frame_time(frame),
                image: image.to_rgb8().into(),
                dynamic_mask: Some(mask),
                foreground: self.foreground_masks.then_some(objects),
                matte: None,
            };
            if self.held_out.contains(&camera) {
                dataset.test.push(view);
            } else {
                dataset.train.push(view);
            }
        }
        // Held-out views in the order `held_out` lists their cameras.
        let order = |v: &View| self.held_out.iter().position(|&c| c == v.camera);
        dataset.test.sort_by_key(|v| (order(v), v.frame));
        Ok(dataset)
    }
}

fn finite(field: &str, value: f32) -> Check {
    if value.is_finite() {
        Ok(())
    } else {
        fail(field, format!("must be finite, got {value}"))
    }
}

fn positive(field: &str, value: f32) -> Check {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        fail(field, format!("must be positive and finite, got {value}"))
    }
}

fn finite_vec(field: &str, value: [f32; 3]) -> Check {
    if value.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        fail(field, format!("must be finite, got {value:?}"))
    }
}

fn colour(field: &str, value: [f32; 3]) -> Check {
    if value.iter().all(|v| (0.0..=1.0).contains(v)) {
        Ok(())
    } else {
        fail(
            field,
            format!("must be a colour with channels in [0, 1], got {value:?}"),
        )
    }
}

fn validate_texture(field: &str, texture: &Texture) -> Check {
    match texture {
        Texture::Solid(c) => colour(field, *c),
        Texture::Checker { a, b, cells } => {
            colour(&format!("{field}.a"), *a)?;
            colour(&format!("{field}.b"), *b)?;
            positive(&format!("{field}.cells"), *cells)
        }
        Texture::Stripes { a, b, count } => {
            colour(&format!("{field}.a"), *a)?;
            colour(&format!("{field}.b"), *b)?;
            positive(&format!("{field}.count"), *count)?;
            if count.fract() != 0.0 {
                return fail(
                    &format!("{field}.count"),
                    format!("must be a whole number so the stripes close up, got {count}"),
                );
            }
            Ok(())
        }
    }
}

fn validate_object(field: &str, object: &SceneObject) -> Check {
    match &object.shape {
        Shape::Sphere { radius } => positive(&format!("{field}.shape.radius"), *radius)?,
        Shape::Box { half_extents } => {
            for h in half_extents {
                positive(&format!("{field}.shape.half_extents"), *h)?;
            }
        }
    }
    validate_texture(&format!("{field}.texture"), &object.texture)?;
    if object.path.is_empty() {
        return fail(&format!("{field}.path"), "must have at least one keyframe");
    }
    for (k, key) in object.path.iter().enumerate() {
        finite(&format!("{field}.path[{k}].time"), key.time)?;
        finite_vec(&format!("{field}.path[{k}].position"), key.position)?;
        if k > 0 && key.time <= object.path[k - 1].time {
            return fail(
                &format!("{field}.path[{k}].time"),
                format!(
                    "= {} must be greater than the previous keyframe's {} \
                     (keyframes must be sorted in time)",
                    key.time,
                    object.path[k - 1].time
                ),
            );
        }
    }
    finite(&format!("{field}.spin"), object.spin)?;
    if let Some((start, end)) = object.visible
        && !(start.is_finite() && end.is_finite() && start < end)
    {
        return fail(
            &format!("{field}.visible"),
            format!("must be a finite window (start, end) with start < end, got ({start}, {end})"),
        );
    }
    Ok(())
}
#[cfg(test)]
mod tests;
