//! The ray caster behind [`SyntheticScene::render`]: analytic hits on spheres, boxes and the
//! floor, procedural textures and a fixed directional light.

use std::f32::consts::PI;

use glam::{Mat3, Vec3};

use super::{Floor, SceneObject, Shape, SyntheticScene, Texture};
use crate::data::Camera;
use crate::io::image::Image;

/// Ambient share of the shading: a surface facing away from the light keeps this much of its
/// texture colour.
pub(super) const AMBIENT: f32 = 0.55;
/// Diffuse share of the shading (`AMBIENT + DIFFUSE = 1`, so colours never exceed the texture's).
pub(super) const DIFFUSE: f32 = 0.45;
/// Direction towards the (infinitely distant) light, before normalisation: from above, a little
/// to the side, so the faces of a box get three different brightnesses.
pub(super) const LIGHT: Vec3 = Vec3::new(0.45, 1.0, 0.3);
/// Steepness of the pattern edges: `clamp(k·sin θ, −1, 1)` makes a transition about `2/k`
/// radians of phase wide — crisp, but not a step a smooth model could never fit.
const EDGE_SHARPNESS: f32 = 5.0;
/// Hits closer than this along a ray are ignored (no self-intersection at the ray origin).
const RAY_EPSILON: f32 = 1e-4;
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
