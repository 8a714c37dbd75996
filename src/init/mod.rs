//! Initial Gaussians: points per anchor frame, scaled by their nearest-neighbour distances.
//!
//! The points are random ([`random_points_in_view`]), carved from the images ([`carve`]), or
//! a point cloud (the dataset's, or a file read by [`crate::data::pointcloud`]).

pub mod carve;

use glam::Vec3;
use rand::Rng;
use rayon::prelude::*;

use self::carve::{CarveError, CarvedPoints};
use crate::data::{Camera, Dataset};
use crate::scene::{InitConfig, InitMethod};

/// A coloured point of an initial point cloud.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InitPoint {
    /// Position in world coordinates (the dataset's units).
    pub position: Vec3,
    /// RGB colour, nominally in [0, 1] (8-bit sources are divided by 255).
    pub color: [f32; 3],
}

/// Scene extent as in 3DGS: 1.1 × the largest distance of a camera centre from their mean.
pub fn scene_extent(cameras: &[Camera]) -> f32 {
    let centres: Vec<Vec3> = cameras.iter().map(Camera::center).collect();
    let mean = centres.iter().copied().sum::<Vec3>() / centres.len().max(1) as f32;
    let radius = centres.iter().map(|c| c.distance(mean)).fold(0.0, f32::max);
    1.1 * radius.max(1e-3)
}

/// The point nearest (least squares) to every camera's optical axis: where the rig looks.
pub fn rig_focus(cameras: &[Camera]) -> Vec3 {
    let mut a = glam::Mat3::ZERO;
    let mut b = Vec3::ZERO;
    for cam in cameras {
        let dir = cam.rotation().transpose() * Vec3::Z;
        // Projector onto the plane orthogonal to the axis.
        let p = glam::Mat3::IDENTITY - glam::Mat3::from_cols(dir * dir.x, dir * dir.y, dir * dir.z);
        a += p;
        b += p * cam.center();
    }
    if a.determinant().abs() < 1e-6 {
        return cameras.iter().map(Camera::center).sum::<Vec3>() / cameras.len().max(1) as f32;
    }
    a.inverse() * b
}

/// Whether `point` is in front of `cam` and projects inside its image.
pub fn in_view(cam: &Camera, point: Vec3) -> bool {
    let (u, v, z) = cam.project(point);
    z > 0.01 && u >= 0.0 && v >= 0.0 && u < cam.width as f32 && v < cam.height as f32
}

/// `count` random points, uniform in the region seen by at least half of `cameras`, with
/// random colours. The region is searched in a cube around the rig's focus point whose
/// half-size is the mean camera distance (rejection sampling; gives up after 1000 tries per point).
pub fn random_points_in_view(
    cameras: &[Camera],
    count: usize,
    rng: &mut impl Rng,
) -> Vec<InitPoint> {
    let focus = rig_focus(cameras);
    let half = cameras
        .iter()
        .map(|c| c.center().distance(focus))
        .sum::<f32>()
        / cameras.len().max(1) as f32;
    let needed = cameras.len().div_ceil(2);
    let mut points = Vec::with_capacity(count);
    let mut tries = 0usize;
    while points.len() < count && tries < count * 1000 {
        tries += 1;
        let p = focus
            + Vec3::new(
                rng.random_range(-half..half),
                rng.random_range(-half..half),
                rng.random_range(-half..half),
            );
        if cameras.iter().filter(|c| in_view(c, p)).count() >= needed {
            points.push(InitPoint {
                position: p,
                color: [rng.random(), rng.random(), rng.random()],
            });
        }
    }
    points
}

/// Root mean squared distance to the 3 nearest neighbours of every point (3DGS's initial scale).
///
/// Brute force, parallel over points: O(n²), fine for the per-anchor clouds of a few thousand
/// points used here.
pub fn nearest_neighbour_scales(points: &[Vec3]) -> Vec<f32> {
    points
        .par_iter()
        .enumerate()
        .map(|(i, p)| {
            let mut best = [f32::INFINITY; 3];
            for (j, q) in points.iter().enumerate() {
                if i == j {
                    continue;
                }
                let d = p.distance_squared(*q);
                if d < best[2] {
                    best[2] = d;
                    best.sort_by(f32::total_cmp);
                }
            }
            let found: Vec<f32> = best.into_iter().filter(|d| d.is_finite()).collect();
            if found.is_empty() {
                0.01
            } else {
                (found.iter().sum::<f32>() / found.len() as f32)
                    .sqrt()
                    .max(1e-7)
            }
        })
        .collect()
}

/// Anchor frames: every `spacing` frames from 0, plus the last frame.
pub fn anchor_frames(frame_count: usize, spacing: usize) -> Vec<usize> {
    let mut anchors: Vec<usize> = (0..frame_count).step_by(spacing.max(1)).collect();
    if frame_count > 0 && anchors.last() != Some(&(frame_count - 1)) {
        anchors.push(frame_count - 1);
    }
    anchors
}

/// The initial points of one anchor frame by the scene's method (not a point-cloud file);
/// only carving against foreground masks tells background points apart.
pub(crate) fn anchor_points(
    dataset: &Dataset,
    frame: usize,
    init: &InitConfig,
    rng: &mut rand_chacha::ChaCha8Rng,
) -> Result<CarvedPoints, CarveError> {
    let count = init.points_per_anchor;
    let random = |rng: &mut rand_chacha::ChaCha8Rng| {
        CarvedPoints::undivided(random_points_in_view(&dataset.training_rig(), count, rng))
    };
    match init.method {
        InitMethod::Random => Ok(random(rng)),
        InitMethod::Carve => carve::carved_points(dataset, frame, count, &init.carve, rng),
        InitMethod::Auto if carve::has_masks(dataset, frame) => {
            match carve::carved_points(dataset, frame, count, &init.carve, rng) {
                Ok(points) => Ok(points),
                Err(error) => {
                    tracing::warn!("anchor frame {frame}: {error}; using random points instead");
                    Ok(random(rng))
                }
            }
        }
        InitMethod::Auto => {
            if let Some((source, points)) = dataset.nearest_frame_points(frame) {
                if source != frame {
                    tracing::warn!(
                        "anchor frame {frame} has no point cloud of its own; using frame {source}'s"
                    );
                }
                return Ok(CarvedPoints::undivided(points.to_vec()));
            }
            Ok(match dataset.points.clone() {
                Some(points) => CarvedPoints::undivided(points),
                None => random(rng),
            })
        }
        InitMethod::PointCloud(_) => unreachable!("point-cloud files are read once by the caller"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn anchors_every_spacing_plus_last() {
        assert_eq!(anchor_frames(60, 20), vec![0, 20, 40, 59]);
        assert_eq!(anchor_frames(41, 20), vec![0, 20, 40]);
    }

    #[test]
    fn neighbour_scale_of_a_unit_grid_is_one() {
        let pts: Vec<Vec3> = (0..27)
            .map(|i| Vec3::new((i % 3) as f32, ((i / 3) % 3) as f32, (i / 9) as f32))
            .collect();
        let s = nearest_neighbour_scales(&pts);
        assert!((s[13] - 1.0).abs() < 1e-6); // the centre point has 6 neighbours at distance 1
    }

    #[test]
    fn random_points_are_seen_by_most_cameras() {
        let cams: Vec<Camera> = (0..8)
            .map(|i| {
                let a = i as f32 * std::f32::consts::TAU / 8.0;
                Camera::look_at(
                    Vec3::new(4.0 * a.cos(), 1.0, 4.0 * a.sin()),
                    Vec3::ZERO,
                    Vec3::Y,
                    64,
                    48,
                    1.0,
                )
            })
            .collect();
        assert!(rig_focus(&cams).length() < 1e-3);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let pts = random_points_in_view(&cams, 200, &mut rng);
        assert_eq!(pts.len(), 200);
        for p in pts {
            assert!(cams.iter().filter(|c| in_view(c, p.position)).count() >= 4);
        }
    }
}
