//! A visual hull carved from foreground masks, and points sampled in it.

use std::time::Instant;

use glam::Vec3;
use rand::Rng;
use rayon::prelude::*;

use super::grid::{VoxelGrid, VoxelPools};
use super::{
    CANDIDATE_BATCH, CarveError, CarveSettings, CarveView, checked_views, masked_views,
    search_region,
};
use crate::data::Dataset;
use crate::init::InitPoint;

/// Hull points are drawn at most this many times per point before filtering is given up.
const HULL_TRIES: usize = 20;

/// Whether a voxel of bounding-sphere `radius` at `centre` belongs to the visual hull (with
/// radius 0: whether the point does, judged on the pixels it falls in).
fn in_visual_hull(
    views: &[CarveView],
    centre: Vec3,
    radius: f32,
    settings: &CarveSettings,
) -> bool {
    // Once this many views see background, agreement cannot be reached however many of the
    // rest see the voxel: most of the search region is rejected after a few views.
    let background_limit = (1.0 - settings.agreement) * views.len() as f32 + 1e-4;
    let mut seen = 0usize;
    let mut foreground = 0usize;
    for view in views {
        let Some((u, v, z)) = view.project(centre) else {
            continue;
        };
        seen += 1;
        if view.any_foreground(view.footprint(u, v, z, radius)) {
            foreground += 1;
        } else if (seen - foreground) as f32 > background_limit {
            return false;
        }
    }
    // The small slack keeps "9 of 10 at agreement 0.9" from failing on rounding.
    seen >= settings.min_views && foreground as f32 >= settings.agreement * seen as f32 - 1e-4
}

/// The visual hull at `frame`: voxels seen as foreground by at least `agreement` of the masked
/// training views that see them.
///
/// Carved twice: coarsely over the whole search region (conservative, since a voxel's whole
/// footprint is tested), then at `resolution` over the bounding box of what survived, so the
/// voxels are spent on the subject rather than on empty space.
pub fn visual_hull(
    dataset: &Dataset,
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let views = checked_views(dataset, frame, settings, masked_views)?;
    visual_hull_of(&views, frame, settings)
}

pub(super) fn visual_hull_of(
    views: &[CarveView],
    frame: usize,
    settings: &CarveSettings,
) -> Result<VoxelGrid, CarveError> {
    let start = Instant::now();
    let (region_min, region_max) = search_region(views, settings.region_scale);
    let carve = |min: Vec3, max: Vec3, resolution: u32| {
        let probe = VoxelGrid::covering(min, max, resolution);
        let radius = 0.5 * 3f32.sqrt() * probe.voxel_size;
        VoxelGrid::carve(min, max, resolution, |c| {
            in_visual_hull(views, c, radius, settings)
        })
    };
    let coarse = carve(region_min, region_max, settings.resolution.min(64));
    let empty_hull = |voxels: usize| CarveError::EmptyHull {
        frame,
        views: views.len(),
        voxels,
        agreement: settings.agreement,
        min_views: settings.min_views,
    };
    let Some((lo, hi)) = coarse.occupied_bounds() else {
        return Err(empty_hull(coarse.len()));
    };
    let margin = Vec3::splat(coarse.voxel_size);
    let fine = carve(
        (lo - margin).max(region_min),
        (hi + margin).min(region_max),
        settings.resolution,
    );
    let kept = fine.occupied_count();
    tracing::info!(
        frame,
        views = views.len(),
        coarse_kept = coarse.occupied_count(),
        kept,
        dims = ?fine.dims,
        voxel_size = fine.voxel_size,
        seconds = start.elapsed().as_secs_f32(),
        "carved visual hull"
    );
    if kept == 0 {
        return Err(empty_hull(fine.len()));
    }
    Ok(fine)
}

/// Per view, the camera depth of the nearest hull surface at each pixel (infinity where the
/// hull is not seen): splats of the surface voxels' footprints, for O(1) occlusion tests.
fn hull_depth_maps(views: &[CarveView], grid: &VoxelGrid) -> Vec<Vec<f32>> {
    let surface: Vec<usize> = (0..grid.len()).filter(|&i| grid.is_surface(i)).collect();
    let radius = 0.5 * 3f32.sqrt() * grid.voxel_size;
    views
        .par_iter()
        .map(|view| {
            let width = view.width();
            let mut depth = vec![f32::INFINITY; width * view.camera.height as usize];
            for &voxel in &surface {
                let Some((u, v, z)) = view.project(grid.voxel_center(voxel)) else {
                    continue;
                };
                let (x0, y0, x1, y1) = view.footprint(u, v, z, radius);
                for y in y0..=y1 {
                    for d in &mut depth[y * width + x0..=y * width + x1] {
                        *d = d.min(z);
                    }
                }
            }
            depth
        })
        .collect()
}

/// Colour of a hull point: its mean pixel colour over the views in which it is foreground and
/// (given depth maps) not hidden behind the hull's nearer surface. Falls back to ignoring
/// occlusion, then to every view that sees it.
fn hull_point_colour(
    views: &[CarveView],
    depth_maps: Option<&[Vec<f32>]>,
    depth_slack: f32,
    point: Vec3,
) -> [f32; 3] {
    let mean_over = |accept: &dyn Fn(usize, f32, f32, f32) -> bool| {
        let mut sum = Vec3::ZERO;
        let mut n = 0u32;
        for (index, view) in views.iter().enumerate() {
            if let Some((u, v, z)) = view.project(point)
                && accept(index, u, v, z)
            {
                sum += view.colour(u, v);
                n += 1;
            }
        }
        (n > 0).then(|| (sum / n as f32).to_array())
    };
    let foreground = |index: usize, u: f32, v: f32| views[index].is_foreground(u, v);
    let visible = |index: usize, u: f32, v: f32, z: f32| {
        depth_maps.is_some_and(|maps| {
            foreground(index, u, v)
                && z <= maps[index][views[index].pixel_index(u, v)] + depth_slack
        })
    };
    depth_maps
        .and_then(|_| mean_over(&visible))
        .or_else(|| mean_over(&|index, u, v, _| foreground(index, u, v)))
        .or_else(|| mean_over(&|_, _, _, _| true))
        .unwrap_or([0.5; 3])
}

/// `count` points in hull voxels that also pass the hull test themselves, pixel-exactly (the
/// voxel test is conservative by up to two voxels, which on a limb is a lot). Gives up
/// filtering after `HULL_TRIES` draws per point and fills up with unfiltered ones.
fn sample_inside_silhouettes(
    views: &[CarveView],
    grid: &VoxelGrid,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Vec<Vec3> {
    let pools = VoxelPools::new(grid);
    let mut positions = Vec::with_capacity(count);
    let mut draws = 0usize;
    while positions.len() < count && draws < count * HULL_TRIES {
        let batch = (count - positions.len()).clamp(256, CANDIDATE_BATCH);
        let candidates = pools.sample(grid, batch, settings.surface_preference, &mut *rng);
        draws += candidates.len();
        let passed: Vec<Vec3> = candidates
            .into_par_iter()
            .filter(|p| in_visual_hull(views, *p, 0.0, settings))
            .collect();
        positions.extend(passed.into_iter().take(count - positions.len()));
    }
    if positions.len() < count {
        tracing::warn!(
            passed = positions.len(),
            count,
            draws,
            "few points in hull voxels pass the pixel-exact silhouette test; filling up unfiltered"
        );
        let missing = count - positions.len();
        positions.extend(pools.sample(grid, missing, settings.surface_preference, rng));
    }
    positions
}

pub(super) fn sample_hull(
    views: &[CarveView],
    grid: &VoxelGrid,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Vec<InitPoint> {
    if count == 0 {
        return Vec::new();
    }
    let positions = sample_inside_silhouettes(views, grid, count, settings, rng);
    let depth_maps = settings.occlusion.then(|| hull_depth_maps(views, grid));
    // A point may lie anywhere in its surface voxel, behind the splatted centre depth, and
    // neighbouring surface voxels overlap it at grazing angles.
    let depth_slack = 2.0 * grid.voxel_size;
    positions
        .into_par_iter()
        .map(|position| InitPoint {
            position,
            color: hull_point_colour(views, depth_maps.as_deref(), depth_slack, position),
        })
        .collect()
}

/// `count` points in the visual hull at `frame` (see [`visual_hull`]), mostly on its surface,
/// coloured by the views that see them as foreground.
///
/// Points are jittered in hull voxels and kept only where they pass the hull test themselves on
/// the pixels they project to, which undoes the voxel test's conservative margin.
pub fn carve_from_masks(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let views = checked_views(dataset, frame, settings, masked_views)?;
    let grid = visual_hull_of(&views, frame, settings)?;
    Ok(sample_hull(&views, &grid, count, settings, rng))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::carve::initial_points;
    use crate::init::carve::testing::*;

    /// Hull points lie within r + 1.5 voxels + 1 pixel (the masks' quantisation) of the sphere's
    /// centre and reach out to the sphere in all six axis directions (the hull neither grows
    /// nor loses a side).
    #[test]
    fn hull_points_hug_the_sphere() {
        let scene = sphere_scene();
        let settings = test_settings();
        let grid = visual_hull(&scene.dataset, 0, &settings).unwrap();
        let points = carve_from_masks(&scene.dataset, 0, 4000, &settings, &mut rng()).unwrap();
        assert_eq!(points.len(), 4000);
        let camera = &scene.dataset.cameras[0];
        let pixel = (camera.center().distance(scene.centre) - scene.radius) / camera.fx;
        let limit = scene.radius + 1.5 * grid.voxel_size + pixel;
        let mut reach_pos = Vec3::splat(f32::MIN);
        let mut reach_neg = Vec3::splat(f32::MIN);
        for p in &points {
            let offset = p.position - scene.centre;
            assert!(
                offset.length() <= limit,
                "{offset} is {} from the centre",
                offset.length()
            );
            reach_pos = reach_pos.max(offset);
            reach_neg = reach_neg.max(-offset);
        }
        for reach in [reach_pos, reach_neg] {
            assert!(reach.min_element() > 0.85 * scene.radius, "reach {reach}");
        }
    }

    /// The visual hull over-approximates: its volume is at least the sphere's and at most twice it.
    #[test]
    fn hull_volume_bounds_the_sphere() {
        let scene = sphere_scene();
        let grid = visual_hull(&scene.dataset, 0, &test_settings()).unwrap();
        let sphere = 4.0 / 3.0 * std::f32::consts::PI * scene.radius.powi(3);
        let volume = grid.volume();
        assert!(
            volume >= sphere && volume <= 2.0 * sphere,
            "hull {volume} vs sphere {sphere}"
        );
        assert!(grid.contains(scene.centre));
        let (lo, hi) = grid.occupied_bounds().unwrap();
        let tolerance = Vec3::splat(scene.radius * 0.15 + grid.voxel_size);
        assert!(
            ((lo - (scene.centre - scene.radius)).abs())
                .cmple(tolerance)
                .all(),
            "{lo}"
        );
        assert!(
            ((hi - (scene.centre + scene.radius)).abs())
                .cmple(tolerance)
                .all(),
            "{hi}"
        );
    }

    /// Hull points take the colour of the sphere (red), not of the background.
    #[test]
    fn hull_points_are_red() {
        let scene = sphere_scene();
        for occlusion in [true, false] {
            let settings = CarveSettings {
                occlusion,
                ..test_settings()
            };
            let points = carve_from_masks(&scene.dataset, 0, 500, &settings, &mut rng()).unwrap();
            for p in points {
                let [r, g, b] = p.color;
                assert!(r > 0.8 && g < 0.2 && b < 0.2, "{:?}", p.color);
            }
        }
    }

    /// With agreement 0.9, one blank mask out of ten does not carve the sphere away.
    #[test]
    fn one_bad_mask_is_tolerated() {
        let mut scene = sphere_scene();
        scene.dataset.train[3].foreground = Some(vec![false; (WIDTH * HEIGHT) as usize]);
        let grid = visual_hull(&scene.dataset, 0, &test_settings()).unwrap();
        let sphere = 4.0 / 3.0 * std::f32::consts::PI * scene.radius.powi(3);
        assert!(grid.volume() >= sphere);
        let strict = CarveSettings {
            agreement: 1.0,
            ..test_settings()
        };
        assert!(matches!(
            visual_hull(&scene.dataset, 0, &strict),
            Err(CarveError::EmptyHull { .. })
        ));
    }

    /// Masks that show nothing empty the hull, and the error says why.
    #[test]
    fn blank_masks_give_an_empty_hull_error() {
        let mut scene = sphere_scene();
        for view in &mut scene.dataset.train {
            view.foreground = Some(vec![false; (WIDTH * HEIGHT) as usize]);
        }
        let err = visual_hull(&scene.dataset, 0, &test_settings()).unwrap_err();
        assert!(matches!(
            err,
            CarveError::EmptyHull {
                frame: 0,
                views: 10,
                ..
            }
        ));
        assert!(err.to_string().contains("masks disagree with the cameras"));
    }

    /// On the Panoptic capture (when present) frame 0 carves to a non-empty hull inside the rig,
    /// and every initial point gets a colour; prints sizes and timings. Ignored: it decodes
    /// 31 JPEGs and 27 masks.
    #[test]
    #[ignore]
    fn panoptic_hull_report() {
        use crate::data::panoptic::{PanopticSource, load};
        let root = std::env::var("TADGS_DATA")
            .map(std::path::PathBuf::from)
            .unwrap_or_else(|_| {
                std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data")
            });
        let path = root.join("panoptic_basketball");
        if !path.exists() {
            println!("skipping: {} not found", path.display());
            return;
        }
        let source = PanopticSource {
            frames: Some(1),
            ..PanopticSource::new(path.to_string_lossy())
        };
        let start = Instant::now();
        let dataset = load(&source).unwrap();
        println!(
            "loaded {} train views in {:.2} s",
            dataset.train.len(),
            start.elapsed().as_secs_f32()
        );
        for resolution in [64, 96, 128] {
            let settings = CarveSettings {
                resolution,
                ..CarveSettings::default()
            };
            let start = Instant::now();
            let grid = visual_hull(&dataset, 0, &settings).unwrap();
            let hull_seconds = start.elapsed().as_secs_f32();
            let (lo, hi) = grid.occupied_bounds().unwrap();
            println!(
                "resolution {resolution}: grid {:?}, voxel {:.4}, kept {} ({:.3} m³), bounds {lo:.2}..{hi:.2}, {hull_seconds:.3} s",
                grid.dims,
                grid.voxel_size,
                grid.occupied_count(),
                grid.volume()
            );
            // Silhouette agreement: how much of each mask the hull's projection covers, and how
            // much of the projection is foreground.
            let views = masked_views(&dataset, 0).unwrap();
            let depth_maps = hull_depth_maps(&views, &grid);
            let (mut recall, mut precision) = (Vec::new(), Vec::new());
            for (view, depth) in views.iter().zip(&depth_maps) {
                let mask = view.mask.unwrap();
                let both = mask
                    .iter()
                    .zip(depth)
                    .filter(|(m, d)| **m && d.is_finite())
                    .count();
                recall.push(both as f32 / mask.iter().filter(|m| **m).count().max(1) as f32);
                precision.push(
                    both as f32 / depth.iter().filter(|d| d.is_finite()).count().max(1) as f32,
                );
            }
            let summary = |v: &[f32]| {
                let mean = v.iter().sum::<f32>() / v.len() as f32;
                (mean, v.iter().copied().fold(1.0, f32::min))
            };
            println!(
                "  mask recall (mean, min) {:.3?}, precision {:.3?}",
                summary(&recall),
                summary(&precision)
            );
            let start = Instant::now();
            let points = initial_points(&dataset, 0, 100_000, &settings, &mut rng()).unwrap();
            println!(
                "  initial_points(100000): {} points in {:.3} s",
                points.len(),
                start.elapsed().as_secs_f32()
            );
            assert_eq!(points.len(), 100_000);
            // Of the hull points (the first half), the share of (point, view) pairs on the mask,
            // and of the background points, the share off it.
            let on_mask = |points: &[InitPoint]| {
                let (mut on, mut pairs) = (0usize, 0usize);
                for p in points {
                    for view in &views {
                        if let Some((u, v, _)) = view.project(p.position) {
                            pairs += 1;
                            on += usize::from(view.is_foreground(u, v));
                        }
                    }
                }
                on as f32 / pairs as f32
            };
            println!(
                "  (point, view) pairs on the mask: hull points {:.3}, background points {:.3}",
                on_mask(&points[..50_000]),
                on_mask(&points[50_000..])
            );
            assert!(
                points
                    .iter()
                    .all(|p| p.position.is_finite()
                        && p.color.iter().all(|c| (0.0..=1.0).contains(c)))
            );
        }
    }
}
