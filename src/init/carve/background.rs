//! Background points: outside the visual hull, in the region most masked views see, preferring
//! photo-consistent ones.

use glam::Vec3;
use rand::Rng;
use rayon::prelude::*;

use super::grid::VoxelGrid;
use super::{
    CANDIDATE_BATCH, CarveError, CarveSettings, CarveView, checked_views, masked_views,
    mean_and_spread, search_region,
};
use crate::data::Dataset;
use crate::init::InitPoint;

/// Rejection sampling of background candidates gives up after this many draws per wanted one.
const CANDIDATE_TRIES: usize = 200;

/// A background candidate: position, mean colour over the views that see it as background, and
/// how much those colours disagree.
struct Candidate {
    position: Vec3,
    colour: Vec3,
    spread: f32,
}

fn background_candidate(
    views: &[CarveView],
    position: Vec3,
    settings: &CarveSettings,
    needed: usize,
) -> Option<Candidate> {
    let (mut seen, mut foreground) = (0usize, 0usize);
    let (mut sum, mut sum_sq) = (Vec3::ZERO, Vec3::ZERO);
    // Most rejected candidates lie outside the common view volume: stop once too many views
    // have missed them.
    let allowed_misses = views.len().saturating_sub(needed);
    for (index, view) in views.iter().enumerate() {
        let Some((u, v, _)) = view.project(position) else {
            if index + 1 - seen > allowed_misses {
                return None;
            }
            continue;
        };
        seen += 1;
        if view.is_foreground(u, v) {
            foreground += 1;
        } else {
            let c = view.colour(u, v);
            sum += c;
            sum_sq += c * c;
        }
    }
    let background = seen - foreground;
    let outside_hull = (foreground as f32) < settings.agreement * seen as f32;
    if seen < needed || !outside_hull || background < settings.min_views.min(seen) {
        return None;
    }
    let (colour, spread) = mean_and_spread(sum, sum_sq, background);
    Some(Candidate {
        position,
        colour,
        spread,
    })
}

/// Bounding box of the part of the search region seen by at least `needed` views (found on a
/// coarse grid, padded by a cell): rejection sampling there wastes far fewer draws.
fn common_view_bounds(
    views: &[CarveView],
    region_scale: f32,
    needed: usize,
) -> Option<(Vec3, Vec3)> {
    let (region_min, region_max) = search_region(views, region_scale);
    let seen_enough = |p: Vec3| views.iter().filter(|v| v.project(p).is_some()).count() >= needed;
    let coarse = VoxelGrid::carve(region_min, region_max, 24, seen_enough);
    let (lo, hi) = coarse.occupied_bounds()?;
    let margin = Vec3::splat(coarse.voxel_size);
    Some(((lo - margin).max(region_min), (hi + margin).min(region_max)))
}

/// `count` points of the static background at `frame`: random points in the region seen by at
/// least half of the masked views (and `min_views`), outside the visual hull (seen as foreground
/// by fewer than `agreement` of them), coloured by the mean of their background projections.
/// Of `background_oversample` candidates per point the most photo-consistent are kept, which
/// favours points near real surfaces. May return fewer points when the region is hard to hit.
pub fn background_points(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let views = checked_views(dataset, frame, settings, masked_views)?;
    Ok(background_points_of(&views, count, settings, rng))
}

pub(super) fn background_points_of(
    views: &[CarveView],
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Vec<InitPoint> {
    if count == 0 {
        return Vec::new();
    }
    let fraction_needed = (settings.background_view_fraction * views.len() as f32).ceil() as usize;
    let needed = settings.min_views.max(fraction_needed);
    let Some((lo, hi)) = common_view_bounds(views, settings.region_scale, needed) else {
        tracing::warn!(
            needed,
            "no region is seen by enough cameras for background points"
        );
        return Vec::new();
    };
    let wanted = count * settings.background_oversample.max(1);
    let mut candidates: Vec<Candidate> = Vec::with_capacity(wanted);
    let mut draws = 0usize;
    while candidates.len() < wanted && draws < wanted * CANDIDATE_TRIES {
        let batch: Vec<Vec3> = (0..CANDIDATE_BATCH)
            .map(|_| lo + Vec3::new(rng.random(), rng.random(), rng.random()) * (hi - lo))
            .collect();
        draws += batch.len();
        candidates.par_extend(
            batch
                .into_par_iter()
                .filter_map(|p| background_candidate(views, p, settings, needed)),
        );
    }
    candidates.sort_by(|a, b| a.spread.total_cmp(&b.spread));
    candidates.truncate(count);
    if candidates.len() < count {
        tracing::warn!(
            found = candidates.len(),
            count,
            draws,
            "few random points fall in the background seen by most cameras"
        );
    }
    candidates
        .into_iter()
        .map(|c| InitPoint {
            position: c.position,
            color: c.colour.to_array(),
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::carve::testing::*;

    /// Background points avoid the sphere and take the background's grey.
    #[test]
    fn background_points_avoid_the_sphere() {
        let scene = sphere_scene();
        let points =
            background_points(&scene.dataset, 0, 300, &test_settings(), &mut rng()).unwrap();
        assert_eq!(points.len(), 300);
        for p in points {
            assert!(p.position.distance(scene.centre) > scene.radius);
            for c in p.color {
                assert!((c - 128.0 / 255.0).abs() < 0.02, "{:?}", p.color);
            }
        }
    }
}
