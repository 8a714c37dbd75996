//! Photo-consistency carving, the fallback for data without masks: voxels whose colours agree
//! across the views that see them.

use std::time::Instant;

use glam::Vec3;
use rand::Rng;
use rayon::prelude::*;

use super::grid::VoxelGrid;
use super::{
    CarveError, CarveSettings, CarveView, checked_views, colour_views, mean_and_spread,
    search_region,
};
use crate::data::Dataset;
use crate::init::InitPoint;

/// Whether a voxel at `centre` looks the same from every view that sees it, comparing the mean
/// colours of footprints of `radius`; returns its mean colour if so.
fn consistent_colour(
    views: &[CarveView],
    centre: Vec3,
    radius: f32,
    settings: &CarveSettings,
) -> Option<Vec3> {
    let mut seen = 0usize;
    let (mut sum, mut sum_sq) = (Vec3::ZERO, Vec3::ZERO);
    for view in views {
        let Some((u, v, z)) = view.project(centre) else {
            continue;
        };
        let c = view.mean_colour(view.footprint(u, v, z, radius));
        sum += c;
        sum_sq += c * c;
        seen += 1;
    }
    if seen < settings.min_views {
        return None;
    }
    let (mean, spread) = mean_and_spread(sum, sum_sq, seen);
    (spread <= settings.colour_tolerance).then_some(mean)
}

/// The photo-consistent voxels at `frame`: seen by at least `min_views` training views whose
/// mean colours under the voxel's footprint agree within `colour_tolerance`.
///
/// Approximate: a single pass without visibility reasoning, so a voxel hidden from some views
/// by another surface is judged by the occluder's colour too (carving away parts of concave or
/// occluded surfaces), and empty space that only ever sees uniform colour (a plain wall or sky
/// behind it from every side) survives. Use masks where a dataset has them.
pub fn photo_consistent_hull(
    dataset: &Dataset,
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let views = checked_views(dataset, frame, settings, colour_views)?;
    photo_consistent_hull_of(&views, frame, settings)
}

fn photo_consistent_hull_of(
    views: &[CarveView],
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let start = Instant::now();
    let (min, max) = search_region(views, settings.region_scale);
    let radius = 0.5 * VoxelGrid::covering(min, max, settings.resolution).voxel_size;
    let grid = VoxelGrid::carve(min, max, settings.resolution, |c| {
        consistent_colour(views, c, radius, settings).is_some()
    });
    let kept = grid.occupied_count();
    tracing::info!(
        frame,
        views = views.len(),
        kept,
        dims = ?grid.dims,
        seconds = start.elapsed().as_secs_f32(),
        "carved photo-consistent voxels"
    );
    if kept == 0 {
        return Err(CarveError::NoConsistentVoxels {
            frame,
            tolerance: settings.colour_tolerance,
            min_views: settings.min_views,
        });
    }
    Ok(grid)
}

/// `count` points in photo-consistent voxels at `frame` (see [`photo_consistent_hull`] for what
/// "approximate" means), coloured by the mean over the views that see them. For datasets
/// without masks.
pub fn carve_photo_consistent(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let views = checked_views(dataset, frame, settings, colour_views)?;
    let grid = photo_consistent_hull_of(&views, frame, settings)?;
    let positions = grid.sample_points(count, settings.surface_preference, rng);
    Ok(positions
        .into_par_iter()
        .map(|position| {
            let mut sum = Vec3::ZERO;
            let mut n = 0u32;
            for view in &views {
                if let Some((u, v, _)) = view.project(position) {
                    sum += view.colour(u, v);
                    n += 1;
                }
            }
            let color = if n == 0 {
                [0.5; 3]
            } else {
                (sum / n as f32).to_array()
            };
            InitPoint { position, color }
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::carve::initial_points;
    use crate::init::carve::testing::*;

    /// Photo-consistency carving (no masks) keeps every voxel well inside the sphere, and the
    /// red points it samples are on the sphere.
    #[test]
    fn photo_consistency_keeps_the_sphere() {
        let mut scene = sphere_scene();
        for view in &mut scene.dataset.train {
            view.foreground = None;
        }
        let settings = test_settings();
        let grid = photo_consistent_hull(&scene.dataset, 0, &settings).unwrap();
        let mut inside = 0;
        for i in 0..grid.len() {
            if grid.voxel_center(i).distance(scene.centre) < scene.radius - 1.5 * grid.voxel_size {
                assert!(grid.occupied[i], "voxel at {} carved", grid.voxel_center(i));
                inside += 1;
            }
        }
        assert!(inside > 0);
        let points = initial_points(&scene.dataset, 0, 2000, &settings, &mut rng()).unwrap();
        assert_eq!(points.len(), 2000);
        let red: Vec<_> = points
            .iter()
            .filter(|p| p.color[0] > 0.7 && p.color[1] < 0.3)
            .collect();
        assert!(!red.is_empty());
        for p in red {
            assert!(p.position.distance(scene.centre) < scene.radius + 2.0 * grid.voxel_size);
        }
    }
}
