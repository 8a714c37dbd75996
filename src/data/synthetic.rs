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

use std::f32::consts::PI;

use glam::{Mat3, Vec3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::data::{Camera, Dataset, View};
use crate::io::image::Image;
use crate::scene::{Check, FieldError, fail};

/// Ambient share of the shading: a surface facing away from the light keeps this much of its
/// texture colour.
const AMBIENT: f32 = 0.55;
/// Diffuse share of the shading (`AMBIENT + DIFFUSE = 1`, so colours never exceed the texture's).
const DIFFUSE: f32 = 0.45;
/// Direction towards the (infinitely distant) light, before normalisation: from above, a little
/// to the side, so the faces of a box get three different brightnesses.
const LIGHT: Vec3 = Vec3::new(0.45, 1.0, 0.3);
/// Steepness of the pattern edges: `clamp(k·sin θ, −1, 1)` makes a transition about `2/k`
/// radians of phase wide — crisp, but not a step a smooth model could never fit.
const EDGE_SHARPNESS: f32 = 5.0;
/// Hits closer than this along a ray are ignored (no self-intersection at the ray origin).
const RAY_EPSILON: f32 = 1e-4;
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

/// An object placed at one instant and seen from one ray origin: the quantities the ray caster
/// needs, computed once per image.
struct Placed<'a> {
    object: &'a SceneObject,
    center: Vec3,
    /// Local-to-world rotation (spin about Y).
    to_world: Mat3,
    /// World-to-local rotation.
    to_local: Mat3,
    /// Ray origin relative to the centre, in world axes.
    offset: Vec3,
    /// Ray origin in the local frame.
    local_origin: Vec3,
    /// `|offset|² − R²` for the bounding sphere of radius R (the sphere itself for a ball).
    bound_c: f32,
    dynamic: bool,
}

impl Placed<'_> {
    /// Nearest ray parameter beyond [`RAY_EPSILON`] where the ray (from the origin the object
    /// was placed for, along unit `dir`) meets the object.
    fn hit(&self, dir: Vec3) -> Option<f32> {
        // Bounding sphere first: exact for a ball, a cheap rejection for a box.
        let b = self.offset.dot(dir);
        let disc = b * b - self.bound_c;
        if disc < 0.0 {
            return None;
        }
        match &self.object.shape {
            Shape::Sphere { .. } => {
                let root = disc.sqrt();
                [-b - root, -b + root]
                    .into_iter()
                    .find(|&t| t > RAY_EPSILON)
            }
            Shape::Box { half_extents } => hit_box(
                Vec3::from(*half_extents),
                self.local_origin,
                self.to_local * dir,
            ),
        }
    }
}

/// What one ray of the ray caster sees.
struct RayHit {
    colour: Vec3,
    /// The surface belongs to a dynamic object.
    dynamic: bool,
    /// The surface belongs to an object (not the floor; the sky is no surface).
    object: bool,
}

/// What a ray hit first.
#[derive(Clone, Copy)]
enum Target {
    Floor,
    Object(usize),
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

    /// Ray-casts the scene at normalised time `t` through `camera` (at the camera's own size).
    ///
    /// Returns the image and its exact dynamic mask (row-major, like the image): a pixel is
    /// dynamic when, for any of its `supersample²` rays, the first surface hit belongs to a
    /// dynamic object. The scene should be valid (see [`SyntheticScene::validate`]).
    pub fn render(&self, camera: &Camera, t: f32) -> (Image, Vec<bool>) {
        let (image, dynamic, _) = self.render_with_objects(camera, t);
        (image, dynamic)
    }

    /// [`SyntheticScene::render`], plus the object mask: a pixel is set when any of its rays
    /// first hits an object (not the floor or the sky).
    pub fn render_with_objects(&self, camera: &Camera, t: f32) -> (Image, Vec<bool>, Vec<bool>) {
        let origin = camera.center();
        let placed: Vec<Placed> = self
            .objects
            .iter()
            .filter(|o| o.exists_at(t))
            .map(|object| {
                let center = object.position_at(t);
                let to_world = Mat3::from_rotation_y(object.spin * t);
                let to_local = to_world.transpose();
                let offset = origin - center;
                let bound = match &object.shape {
                    Shape::Sphere { radius } => *radius,
                    Shape::Box { half_extents } => Vec3::from(*half_extents).length(),
                };
                Placed {
                    object,
                    center,
                    to_world,
                    to_local,
                    offset,
                    local_origin: to_local * offset,
                    bound_c: offset.length_squared() - bound * bound,
                    dynamic: object.is_dynamic(),
                }
            })
            .collect();
        let (width, height) = (camera.width as usize, camera.height as usize);
        let s = self.supersample.max(1);
        let step = 1.0 / s as f32;
        let weight = step * step;
        let camera_to_world = camera.rotation().transpose();
        let light = LIGHT.normalize();
        let mut data = Vec::with_capacity(width * height);
        let mut mask = Vec::with_capacity(width * height);
        let mut objects = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let mut sum = Vec3::ZERO;
                let mut dynamic = false;
                let mut object = false;
                for j in 0..s {
                    let v = y as f32 + (j as f32 + 0.5) * step;
                    for i in 0..s {
                        let u = x as f32 + (i as f32 + 0.5) * step;
                        let camera_dir = Vec3::new(
                            (u - camera.cx) / camera.fx,
                            (v - camera.cy) / camera.fy,
                            1.0,
                        );
                        let dir = (camera_to_world * camera_dir).normalize();
                        let hit = self.trace(&placed, origin, dir, light);
                        sum += hit.colour;
                        dynamic |= hit.dynamic;
                        object |= hit.object;
                    }
                }
                data.push((sum * weight).clamp(Vec3::ZERO, Vec3::ONE).to_array());
                mask.push(dynamic);
                objects.push(object);
            }
        }
        (
            Image {
                width,
                height,
                data,
            },
            mask,
            objects,
        )
    }

    /// What one ray sees.
    fn trace(&self, placed: &[Placed], origin: Vec3, dir: Vec3, light: Vec3) -> RayHit {
        let mut nearest = f32::INFINITY;
        let mut target = None;
        if let Some(floor) = &self.floor
            && let Some(t) = hit_floor(floor, origin, dir)
        {
            nearest = t;
            target = Some(Target::Floor);
        }
        for (k, p) in placed.iter().enumerate() {
            if let Some(t) = p.hit(dir)
                && t < nearest
            {
                nearest = t;
                target = Some(Target::Object(k));
            }
        }
        let Some(target) = target else {
            return RayHit {
                colour: Vec3::from(self.background),
                dynamic: false,
                object: false,
            };
        };
        let point = origin + nearest * dir;
        let (albedo, normal, dynamic) = match target {
            Target::Floor => {
                let floor = self.floor.as_ref().expect("the floor was hit");
                let local = point - Vec3::new(0.0, floor.y, 0.0);
                (
                    texture_colour(&floor.texture, local, Some(1)),
                    Vec3::Y,
                    false,
                )
            }
            Target::Object(k) => {
                let p = &placed[k];
                let local = p.to_local * (point - p.center);
                let (local_normal, face_axis) = match &p.object.shape {
                    Shape::Sphere { .. } => (local.normalize(), None),
                    Shape::Box { half_extents } => {
                        let ratio = (local / Vec3::from(*half_extents)).abs();
                        let axis = if ratio.x >= ratio.y && ratio.x >= ratio.z {
                            0
                        } else if ratio.y >= ratio.z {
                            1
                        } else {
                            2
                        };
                        let mut n = Vec3::ZERO;
                        n[axis] = local[axis].signum();
                        (n, Some(axis))
                    }
                };
                let colour = texture_colour(&p.object.texture, local, face_axis);
                (colour, p.to_world * local_normal, p.dynamic)
            }
        };
        // Shade the side facing the ray (floor seen from below, camera inside a box).
        let normal = if normal.dot(dir) > 0.0 {
            -normal
        } else {
            normal
        };
        let shade = AMBIENT + DIFFUSE * normal.dot(light).max(0.0);
        RayHit {
            colour: albedo * shade,
            dynamic,
            object: matches!(target, Target::Object(_)),
        }
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
                image: image.to_rgb8(),
                dynamic_mask: Some(mask),
                foreground: self.foreground_masks.then_some(objects),
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

/// Nearest ray parameter beyond [`RAY_EPSILON`] where the ray meets the floor square.
fn hit_floor(floor: &Floor, origin: Vec3, dir: Vec3) -> Option<f32> {
    if dir.y.abs() < 1e-9 {
        return None;
    }
    let t = (floor.y - origin.y) / dir.y;
    if t <= RAY_EPSILON {
        return None;
    }
    let p = origin + t * dir;
    (p.x.abs() <= floor.half_size && p.z.abs() <= floor.half_size).then_some(t)
}

/// Nearest ray parameter beyond [`RAY_EPSILON`] where a ray, given in the box's local frame,
/// meets the surface of the box `[-half, half]` (slab method).
fn hit_box(half: Vec3, origin: Vec3, dir: Vec3) -> Option<f32> {
    let mut near = f32::NEG_INFINITY;
    let mut far = f32::INFINITY;
    for axis in 0..3 {
        let (o, d, h) = (origin[axis], dir[axis], half[axis]);
        if d.abs() < 1e-12 {
            if o.abs() > h {
                return None;
            }
            continue;
        }
        let (t0, t1) = ((-h - o) / d, (h - o) / d);
        near = near.max(t0.min(t1));
        far = far.min(t0.max(t1));
    }
    if near > far || far <= RAY_EPSILON {
        return None;
    }
    Some(if near > RAY_EPSILON { near } else { far })
}

/// `clamp(k·x, −1, 1)`: a sign with softened edges.
fn soft_sign(x: f32) -> f32 {
    (EDGE_SHARPNESS * x).clamp(-1.0, 1.0)
}

/// Texture colour at local point `p`; `face_axis` is the normal axis of a flat face (left out of
/// the checker), `None` on curved surfaces.
fn texture_colour(texture: &Texture, p: Vec3, face_axis: Option<usize>) -> Vec3 {
    let (a, b, w) = match texture {
        Texture::Solid(c) => return Vec3::from(*c),
        Texture::Checker { a, b, cells } => {
            let w = (0..3)
                .filter(|&axis| Some(axis) != face_axis)
                .map(|axis| soft_sign((PI * cells * p[axis]).sin()))
                .product::<f32>();
            (a, b, w)
        }
        Texture::Stripes { a, b, count } => (a, b, soft_sign((count * p.z.atan2(p.x)).sin())),
    };
    Vec3::from(*b).lerp(Vec3::from(*a), 0.5 + 0.5 * w)
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

/// The built-in demo: 60 frames from 16 cameras (camera 5 held out) at 160 × 120, a checkered
/// floor, two static objects (a checkered box and a striped sphere), a sphere bouncing across
/// the scene, a striped box spinning once in place, and a cube that slides across the middle
/// while it exists, from t = 0.3 to t = 0.7.
pub fn demo_scene() -> SyntheticScene {
    let key = |time: f32, position: [f32; 3]| Keyframe { time, position };
    SyntheticScene {
        frames: 60,
        width: 160,
        height: 120,
        cameras: CameraRing {
            count: 16,
            radius: 4.0,
            height: 1.5,
            target: [0.0, 0.35, 0.0],
            fov_x_degrees: 50.0,
        },
        held_out: vec![5],
        background: [0.62, 0.72, 0.85],
        floor: Some(Floor {
            y: 0.0,
            half_size: 2.5,
            texture: Texture::Checker {
                a: [0.78, 0.76, 0.70],
                b: [0.42, 0.45, 0.50],
                cells: 1.0,
            },
        }),
        objects: vec![
            // Static checkered box.
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.35, 0.35, 0.35],
                },
                texture: Texture::Checker {
                    a: [0.85, 0.30, 0.25],
                    b: [0.95, 0.88, 0.72],
                    cells: 2.5,
                },
                path: vec![key(0.0, [-0.8, 0.35, -0.6])],
                spin: 0.0,
                visible: None,
            },
            // Static striped sphere.
            SceneObject {
                shape: Shape::Sphere { radius: 0.4 },
                texture: Texture::Stripes {
                    a: [0.20, 0.35, 0.80],
                    b: [0.90, 0.92, 0.95],
                    count: 4.0,
                },
                path: vec![key(0.0, [0.8, 0.4, -0.5])],
                spin: 0.0,
                visible: None,
            },
            // Sphere bouncing across the front, from left to right.
            SceneObject {
                shape: Shape::Sphere { radius: 0.28 },
                texture: Texture::Checker {
                    a: [0.95, 0.80, 0.15],
                    b: [0.85, 0.35, 0.10],
                    cells: 3.0,
                },
                path: vec![
                    key(0.0, [-1.0, 0.28, 0.7]),
                    key(0.25, [-0.5, 0.85, 0.7]),
                    key(0.5, [0.0, 0.28, 0.7]),
                    key(0.75, [0.5, 0.85, 0.7]),
                    key(1.0, [1.0, 0.28, 0.7]),
                ],
                spin: 0.0,
                visible: None,
            },
            // Striped box spinning one full turn in place.
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.28, 0.45, 0.28],
                },
                texture: Texture::Stripes {
                    a: [0.55, 0.25, 0.70],
                    b: [0.95, 0.95, 0.90],
                    count: 3.0,
                },
                path: vec![key(0.0, [0.0, 0.45, -1.0])],
                spin: 2.0 * PI,
                visible: None,
            },
            // Cube that appears at t = 0.3, slides across the middle and disappears at t = 0.7.
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.2, 0.2, 0.2],
                },
                texture: Texture::Solid([0.15, 0.75, 0.70]),
                path: vec![key(0.3, [0.9, 0.2, 0.15]), key(0.7, [-0.9, 0.2, 0.15])],
                spin: 0.0,
                visible: Some((0.3, 0.7)),
            },
        ],
        supersample: 2,
        foreground_masks: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A scene with no floor and the given objects, seen by a default ring.
    fn scene_with(objects: Vec<SceneObject>) -> SyntheticScene {
        SyntheticScene {
            frames: 5,
            width: 96,
            height: 80,
            cameras: CameraRing {
                count: 4,
                radius: 5.0,
                height: 0.0,
                target: [0.0; 3],
                fov_x_degrees: 40.0,
            },
            held_out: vec![1],
            background: [0.0, 0.0, 0.0],
            floor: None,
            objects,
            supersample: 2,
            foreground_masks: false,
        }
    }

    fn sphere(radius: f32, colour: [f32; 3], path: Vec<Keyframe>) -> SceneObject {
        SceneObject {
            shape: Shape::Sphere { radius },
            texture: Texture::Solid(colour),
            path,
            spin: 0.0,
            visible: None,
        }
    }

    fn at(position: [f32; 3]) -> Vec<Keyframe> {
        vec![Keyframe {
            time: 0.0,
            position,
        }]
    }

    fn pixel_of(camera: &Camera, world: Vec3) -> usize {
        let (u, v, z) = camera.project(world);
        assert!(
            z > 0.0 && u >= 0.0 && v >= 0.0,
            "point in front of the camera"
        );
        let (x, y) = (u as usize, v as usize);
        assert!(x < camera.width as usize && y < camera.height as usize);
        y * camera.width as usize + x
    }

    #[test]
    fn ray_directions_match_the_camera_model() {
        let scene = demo_scene();
        for camera in scene.cameras() {
            let r = camera.rotation().transpose();
            for (u, v) in [(0.25, 0.25), (80.0, 60.0), (159.75, 3.5)] {
                let dir = (r * Vec3::new(
                    (u - camera.cx) / camera.fx,
                    (v - camera.cy) / camera.fy,
                    1.0,
                ))
                .normalize();
                assert!((dir - camera.ray_direction(u, v)).length() < 1e-5);
            }
        }
    }

    #[test]
    fn ring_cameras_look_at_the_target_from_the_ring() {
        let scene = demo_scene();
        let ring = &scene.cameras;
        let target = Vec3::from(ring.target);
        let cameras = scene.cameras();
        assert_eq!(cameras.len(), ring.count);
        for camera in &cameras {
            let offset = camera.center() - target;
            assert!((offset.y - ring.height).abs() < 1e-4);
            assert!((Vec3::new(offset.x, 0.0, offset.z).length() - ring.radius).abs() < 1e-4);
            let (u, v, _) = camera.project(target);
            assert!((u - 80.0).abs() < 1e-3 && (v - 60.0).abs() < 1e-3);
            assert_eq!((camera.width, camera.height), (160, 120));
        }
        // Evenly spaced: neighbouring centres are all the same distance apart.
        let gap =
            |i: usize| (cameras[i].center() - cameras[(i + 1) % cameras.len()].center()).length();
        for i in 1..cameras.len() {
            assert!((gap(i) - gap(0)).abs() < 1e-4);
        }
    }

    #[test]
    fn sphere_ahead_covers_its_disk_with_its_colour() {
        let colour = [0.8, 0.4, 0.2];
        let (radius, distance) = (0.8, 5.0);
        let scene = scene_with(vec![sphere(radius, colour, at([0.0; 3]))]);
        let camera = Camera::look_at(
            Vec3::new(0.0, 0.0, distance),
            Vec3::ZERO,
            Vec3::Y,
            96,
            80,
            0.7,
        );
        let (image, mask) = scene.render(&camera, 0.0);
        assert_eq!((image.width, image.height), (96, 80));
        assert!(mask.iter().all(|&m| !m), "a static sphere is not dynamic");

        // Silhouette: a disk of angular radius asin(r / d) around the principal point.
        let disk = camera.fx * (radius / distance).asin().tan();
        for y in 0..80 {
            for x in 0..96 {
                let p = image.get(x, y);
                let lit = p.iter().any(|&c| c > 0.0);
                let d = ((x as f32 + 0.5 - camera.cx).powi(2)
                    + (y as f32 + 0.5 - camera.cy).powi(2))
                .sqrt();
                if d < disk - 1.0 {
                    assert!(lit, "pixel ({x}, {y}) inside the disk is background");
                } else if d > disk + 1.0 {
                    assert_eq!(p, [0.0; 3], "pixel ({x}, {y}) outside the disk is drawn");
                }
            }
        }
        // With one ray per pixel, the drawn pixels are those whose centre ray hits the sphere.
        let mut single = scene.clone();
        single.supersample = 1;
        let covered = single
            .render(&camera, 0.0)
            .0
            .data
            .iter()
            .filter(|p| p[0] > 0.0)
            .count() as f32;
        let area = PI * disk * disk;
        assert!(
            (covered - area).abs() < 0.02 * area,
            "covered {covered} pixels, expected about {area}"
        );

        // Centre: the normal faces the camera, the colour is the shaded texture colour.
        let normal = Vec3::Z;
        let shade = AMBIENT + DIFFUSE * normal.dot(LIGHT.normalize()).max(0.0);
        let centre = image.get(48, 40);
        for c in 0..3 {
            assert!(
                (centre[c] - colour[c] * shade).abs() < 0.01,
                "{centre:?} vs {colour:?} · {shade}"
            );
        }
    }

    #[test]
    fn static_objects_are_not_dynamic_and_moving_ones_are() {
        let mut floor_scene = scene_with(vec![
            sphere(0.5, [0.2, 0.8, 0.2], at([-1.0, 0.0, 0.0])),
            sphere(
                0.5,
                [0.8, 0.2, 0.2],
                vec![
                    Keyframe {
                        time: 0.0,
                        position: [1.0, -0.3, 0.0],
                    },
                    Keyframe {
                        time: 1.0,
                        position: [1.0, 0.3, 0.0],
                    },
                ],
            ),
            SceneObject {
                shape: Shape::Box {
                    half_extents: [0.3, 0.3, 0.3],
                },
                texture: Texture::Stripes {
                    a: [1.0; 3],
                    b: [0.2; 3],
                    count: 2.0,
                },
                path: at([0.0, 1.0, 0.0]),
                spin: 1.0,
                visible: None,
            },
        ]);
        floor_scene.floor = Some(Floor {
            y: -1.0,
            half_size: 3.0,
            texture: Texture::Solid([0.5; 3]),
        });
        assert!(!floor_scene.is_dynamic(0));
        assert!(floor_scene.is_dynamic(1));
        assert!(floor_scene.is_dynamic(2));
        let camera = Camera::look_at(Vec3::new(0.0, 0.5, 5.0), Vec3::ZERO, Vec3::Y, 96, 80, 1.0);
        let (image, mask, objects) = floor_scene.render_with_objects(&camera, 0.5);
        let still = pixel_of(&camera, Vec3::new(-1.0, 0.0, 0.0));
        let moving = pixel_of(&camera, floor_scene.objects[1].position_at(0.5));
        let spinning = pixel_of(&camera, Vec3::new(0.0, 1.0, 0.0));
        let floor = pixel_of(&camera, Vec3::new(0.0, -1.0, 2.0));
        assert!(!mask[still] && mask[moving] && mask[spinning] && !mask[floor]);
        assert!(!mask[0], "background corner");
        // The object mask (foreground for carving) holds every object, static or not, and
        // neither the floor nor the sky.
        assert!(objects[still] && objects[moving] && objects[spinning]);
        assert!(!objects[floor] && !objects[0]);
        assert!(
            image.data[moving][0] > 0.3 && image.data[moving][1] < 0.2,
            "the moving sphere is drawn there"
        );
        // Every dynamic pixel shows one of the dynamic objects' textures: none is the static green.
        for (pixel, &m) in image.data.iter().zip(&mask) {
            if m {
                assert!(pixel[1] <= pixel[0] + 1e-6, "{pixel:?} is marked dynamic");
            }
        }
        // The moving sphere really moves: its centre pixel at t = 0 is elsewhere.
        assert_ne!(
            pixel_of(&camera, floor_scene.objects[1].position_at(0.0)),
            moving
        );
    }

    #[test]
    fn visibility_window_hides_the_object_outside_it() {
        let mut object = sphere(0.6, [0.9, 0.9, 0.1], at([0.0; 3]));
        object.visible = Some((0.3, 0.7));
        let scene = scene_with(vec![object]);
        assert!(scene.is_dynamic(0));
        let camera = scene.cameras()[0];
        let centre = pixel_of(&camera, Vec3::ZERO);
        for (t, shown) in [
            (0.0, false),
            (0.29, false),
            (0.3, true),
            (0.5, true),
            (0.7, true),
            (0.71, false),
            (1.0, false),
        ] {
            let (image, mask) = scene.render(&camera, t);
            assert_eq!(image.data[centre][0] > 0.3, shown, "t = {t}");
            assert_eq!(mask[centre], shown, "t = {t}");
            if !shown {
                assert!(image.data.iter().all(|p| *p == [0.0; 3]) && mask.iter().all(|&m| !m));
            }
        }
        // A window covering all of [0, 1] does not make a static object dynamic.
        let mut always = scene.clone();
        always.objects[0].visible = Some((0.0, 1.0));
        assert!(!always.is_dynamic(0));
    }

    #[test]
    fn spinning_texture_moves_with_the_object() {
        let object = SceneObject {
            shape: Shape::Sphere { radius: 1.0 },
            texture: Texture::Stripes {
                a: [1.0, 0.0, 0.0],
                b: [0.0, 0.0, 1.0],
                count: 3.0,
            },
            path: at([0.0; 3]),
            spin: PI / 3.0, // half a stripe pair per unit time: colours swap
            visible: None,
        };
        let scene = scene_with(vec![object]);
        let camera = scene.cameras()[0];
        let (before, _) = scene.render(&camera, 0.0);
        let (after, mask) = scene.render(&camera, 1.0);
        let probe = pixel_of(&camera, Vec3::new(0.55, 0.0, 0.8));
        let (b, a) = (before.data[probe], after.data[probe]);
        assert!(
            (b[0] > b[2]) != (a[0] > a[2]),
            "stripe colour swaps: {b:?} → {a:?}"
        );
        assert!(mask[probe]);
    }

    #[test]
    fn path_interpolation() {
        let object = SceneObject {
            shape: Shape::Sphere { radius: 0.1 },
            texture: Texture::Solid([1.0; 3]),
            path: vec![
                Keyframe {
                    time: 0.2,
                    position: [0.0, 0.0, 0.0],
                },
                Keyframe {
                    time: 0.5,
                    position: [3.0, 1.0, 0.0],
                },
                Keyframe {
                    time: 0.6,
                    position: [4.0, 0.0, 2.0],
                },
            ],
            spin: 0.0,
            visible: None,
        };
        for key in &object.path {
            assert!((object.position_at(key.time) - Vec3::from(key.position)).length() < 1e-5);
        }
        assert_eq!(object.position_at(0.0), Vec3::ZERO);
        assert_eq!(object.position_at(f32::NAN), Vec3::ZERO);
        assert_eq!(object.position_at(1.0), Vec3::new(4.0, 0.0, 2.0));
        // Continuous across keyframes.
        let e = 1e-4;
        assert!((object.position_at(0.5 - e) - object.position_at(0.5 + e)).length() < 1e-2);
        // Two keyframes: linear.
        let linear = SceneObject {
            path: object.path[..2].to_vec(),
            ..object.clone()
        };
        assert!((linear.position_at(0.35) - Vec3::new(1.5, 0.5, 0.0)).length() < 1e-5);
        assert!(object.is_dynamic());
        let still = SceneObject {
            path: object.path[..1].to_vec(),
            ..object
        };
        assert!(!still.is_dynamic());
    }

    #[test]
    fn validate_names_the_offending_field() {
        assert_eq!(demo_scene().validate(), Ok(()));
        type Edit = fn(&mut SyntheticScene);
        let cases: &[(&str, Edit)] = &[
            ("frames", |s| s.frames = 1),
            ("width", |s| s.width = 0),
            ("height", |s| s.height = 0),
            ("supersample", |s| s.supersample = 0),
            ("cameras.count", |s| s.cameras.count = 1),
            ("cameras.radius", |s| s.cameras.radius = 0.0),
            ("cameras.fov_x_degrees", |s| s.cameras.fov_x_degrees = 180.0),
            ("cameras.target", |s| s.cameras.target[1] = f32::NAN),
            ("held_out[1]", |s| s.held_out = vec![2, 16]),
            ("held_out", |s| s.held_out = vec![3, 3]),
            ("held_out", |s| s.held_out = (0..16).collect()),
            ("background", |s| s.background = [1.2, 0.0, 0.0]),
            ("floor.half_size", |s| {
                s.floor.as_mut().unwrap().half_size = -1.0
            }),
            ("floor.texture.cells", |s| {
                s.floor.as_mut().unwrap().texture = Texture::Checker {
                    a: [0.0; 3],
                    b: [1.0; 3],
                    cells: 0.0,
                }
            }),
            ("objects[1].shape.radius", |s| {
                s.objects[1].shape = Shape::Sphere { radius: 0.0 }
            }),
            ("objects[0].shape.half_extents", |s| {
                s.objects[0].shape = Shape::Box {
                    half_extents: [0.1, -0.1, 0.1],
                }
            }),
            ("objects[2].texture.a", |s| {
                s.objects[2].texture = Texture::Checker {
                    a: [2.0; 3],
                    b: [0.0; 3],
                    cells: 1.0,
                }
            }),
            ("objects[3].texture.count", |s| {
                s.objects[3].texture = Texture::Stripes {
                    a: [1.0; 3],
                    b: [0.0; 3],
                    count: 2.5,
                }
            }),
            ("objects[4].texture", |s| {
                s.objects[4].texture = Texture::Solid([-0.1, 0.0, 0.0])
            }),
            ("objects[2].path[2].time", |s| {
                s.objects[2].path[2].time = 0.1
            }),
            ("objects[2].path[1].time", |s| {
                s.objects[2].path[1].time = 0.0
            }),
            ("objects[0].path", |s| s.objects[0].path.clear()),
            ("objects[0].path[0].position", |s| {
                s.objects[0].path[0].position[0] = f32::INFINITY
            }),
            ("objects[3].spin", |s| s.objects[3].spin = f32::NAN),
            ("objects[4].visible", |s| {
                s.objects[4].visible = Some((0.7, 0.3))
            }),
        ];
        for (field, edit) in cases {
            let mut scene = demo_scene();
            edit(&mut scene);
            let error = scene.validate().expect_err(field);
            assert_eq!(&error.path, field, "{error}");
            assert_eq!(scene.build().map(|_| ()), Err(error.to_string()));
        }
    }

    #[test]
    fn build_renders_every_camera_and_frame() {
        let mut scene = demo_scene();
        scene.frames = 3;
        scene.width = 32;
        scene.height = 24;
        scene.supersample = 1;
        let dataset = scene.build().expect("valid scene");
        assert_eq!(dataset.frame_count, 3);
        assert_eq!(dataset.cameras.len(), 16);
        assert_eq!(
            dataset.train_cameras(),
            (0..16).filter(|&c| c != 5).collect::<Vec<_>>()
        );
        assert_eq!(dataset.test_cameras(), vec![5]);
        assert_eq!(dataset.train.len(), 15 * 3);
        assert_eq!(dataset.test.len(), 3);
        for view in dataset.train.iter().chain(&dataset.test) {
            assert_eq!(view.image.dimensions(), (32, 24));
            let mask = view.dynamic_mask.as_ref().expect("masks");
            assert_eq!(mask.len(), 32 * 24);
            assert_eq!(view.time, dataset.frame_time(view.frame));
            // The same as rendering that view alone (quantised to 8 bits).
            let alone = scene.render(&dataset.cameras[view.camera], view.time);
            assert_eq!((&alone.0.to_rgb8(), &alone.1), (&view.image, mask));
        }
    }

    #[test]
    fn demo_scene_round_trips_through_ron() {
        let scene = demo_scene();
        let text = ron::ser::to_string_pretty(&scene, ron::ser::PrettyConfig::default())
            .expect("serialises");
        let back: SyntheticScene = ron::from_str(&text).expect("deserialises");
        assert_eq!(back, scene);
        // Defaults and unknown fields.
        let minimal = text.replace("supersample: 2,", "");
        assert_ne!(minimal, text);
        assert_eq!(
            ron::from_str::<SyntheticScene>(&minimal).expect("default supersample"),
            scene
        );
        let typo = text.replace("supersample:", "super_sample:");
        assert!(ron::from_str::<SyntheticScene>(&typo).is_err());
    }

    #[test]
    fn demo_objects_stay_in_every_view_and_move_everywhere() {
        let scene = demo_scene();
        assert_eq!(
            (0..scene.objects.len())
                .map(|i| scene.is_dynamic(i))
                .collect::<Vec<_>>(),
            [false, false, true, true, true]
        );
        let cameras = scene.cameras();
        // Every object's bounding sphere projects inside every image, at every frame, with a margin.
        let directions: Vec<Vec3> = (-1..=1)
            .flat_map(|x| {
                (-1..=1).flat_map(move |y| {
                    (-1..=1).map(move |z| Vec3::new(x as f32, y as f32, z as f32))
                })
            })
            .filter(|d| *d != Vec3::ZERO)
            .map(|d| d.normalize())
            .collect();
        for object in &scene.objects {
            let bound = match &object.shape {
                Shape::Sphere { radius } => *radius,
                Shape::Box { half_extents } => Vec3::from(*half_extents).length(),
            };
            for f in 0..scene.frames {
                let center = object.position_at(f as f32 / (scene.frames - 1) as f32);
                for camera in &cameras {
                    for d in &directions {
                        let (u, v, z) = camera.project(center + bound * *d);
                        assert!(z > 0.5, "in front");
                        assert!(
                            u > 4.0 && u < 156.0 && v > 4.0 && v < 116.0,
                            "({u}, {v}) at frame {f}"
                        );
                    }
                }
            }
        }
        // At low resolution, every view of every frame has dynamic pixels, and colours stay in range.
        let mut small = scene.clone();
        small.width = 80;
        small.height = 60;
        small.supersample = 1;
        let dataset = small.build().expect("valid");
        for view in dataset.train.iter().chain(&dataset.test) {
            let mask = view.dynamic_mask.as_ref().unwrap();
            assert!(mask.iter().filter(|&&m| m).count() > 20);
        }
    }

    /// Writes demo frames to /tmp for a visual check:
    /// `cargo test --lib data::synthetic -- --ignored --nocapture`.
    #[test]
    #[ignore]
    fn write_demo_frames() {
        let scene = demo_scene();
        let start = std::time::Instant::now();
        let dataset = scene.build().expect("valid");
        println!("demo build: {:.2} s", start.elapsed().as_secs_f64());
        let (w, h) = (scene.width as usize, scene.height as usize);
        let view_of = |c: usize, f: usize| {
            dataset
                .train
                .iter()
                .chain(&dataset.test)
                .find(|v| v.camera == c && v.frame == f)
                .expect("every camera and frame is rendered")
        };
        view_of(0, 30)
            .to_image()
            .save_png(std::path::Path::new("/tmp/demo_frame.png"))
            .expect("writes");
        // A contact sheet: cameras 0, 2, 4, 6 down, frames 0, 20, 30, 40, 59 across, and the
        // masks of camera 0 underneath.
        let frames = [0, 20, 30, 40, 59];
        let rows = [0, 2, 4, 6];
        let mut sheet = Image::filled(w * frames.len(), h * (rows.len() + 1), [0.0; 3]);
        for (col, &f) in frames.iter().enumerate() {
            for (row, &c) in rows.iter().enumerate() {
                let image = view_of(c, f).to_image();
                for y in 0..h {
                    for x in 0..w {
                        sheet.data[(row * h + y) * sheet.width + col * w + x] = image.get(x, y);
                    }
                }
            }
            let mask = view_of(0, f).dynamic_mask.as_ref().expect("masks");
            for y in 0..h {
                for x in 0..w {
                    let v = if mask[y * w + x] { 1.0 } else { 0.0 };
                    sheet.data[(rows.len() * h + y) * sheet.width + col * w + x] = [v; 3];
                }
            }
        }
        sheet
            .save_png(std::path::Path::new("/tmp/demo_sheet.png"))
            .expect("writes");
        let text = ron::ser::to_string_pretty(&scene, ron::ser::PrettyConfig::default()).unwrap();
        std::fs::write("/tmp/demo_scene.ron", text).expect("writes");
    }
}
