//! Initial point clouds from the images themselves: a visual hull carved from foreground
//! masks, background points outside it, and a photo-consistency fallback for unmasked data.
//!
//! Random initial points waste the first thousands of iterations on moving Gaussians to the
//! subject; carving puts them there from the start and gives them the observed colours.
//!
//! All carving works on a regular grid of cubic voxels. A voxel votes with its centre: every
//! view into which the centre projects (in front of the camera, inside the image) looks at the
//! pixels whose centres lie in a square footprint around it. For the visual hull the square
//! bounds the voxel's bounding sphere, so voxels bigger than a pixel do not miss thin parts and
//! the hull stays an over-approximation; photo-consistency uses the inscribed sphere, so as
//! not to mix in colours of neighbouring surfaces.

mod background;
mod grid;
mod hull;
mod photo;
#[cfg(test)]
mod testing;

pub use background::background_points;
pub use grid::VoxelGrid;
pub use hull::{carve_from_masks, visual_hull};
pub use photo::{carve_photo_consistent, photo_consistent_hull};

use std::sync::Arc;

use glam::Vec3;
use image::RgbImage;
use rand::Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use self::background::background_points_of;
use self::grid::SummedArea;
use self::hull::{sample_hull, visual_hull_of};
use super::{InitPoint, rig_focus};
use crate::data::{Camera, Dataset, View};

/// Points closer to a camera than this (along its axis) are not seen by it.
const MIN_DEPTH: f32 = 1e-3;

/// The fine grid may not exceed this many voxels per side (memory: one byte per voxel).
const MAX_RESOLUTION: u32 = 512;

/// Background candidates are drawn in batches of this size and tested in parallel.
const CANDIDATE_BATCH: usize = 4096;

/// How to carve the initial point cloud of an anchor frame (a `carve: (...)` block in scene
/// files; omitted fields take their defaults).
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
#[serde(default, deny_unknown_fields)]
pub struct CarveSettings {
    /// Voxels along the longest side of the grid. The hull is first carved at this resolution
    /// (at most 64) over the whole region the cameras see, then at this one over the bounding
    /// box of what survived: on Panoptic frame 0 (two players, 4 m apart) 96 gives 4.4 cm voxels.
    pub resolution: u32,
    /// Fraction of the views that see a voxel which must see it as foreground for it to be
    /// kept. Below 1 tolerates a few bad masks (a player cut off by a segmentation error).
    pub agreement: f32,
    /// A voxel (or background point) seen by fewer masked views than this is dropped: a region
    /// seen by one or two cameras is a cone, not a shape.
    pub min_views: usize,
    /// Share of the points of [`initial_points`] taken from the hull; the rest are background.
    pub foreground_fraction: f32,
    /// Photo-consistency: the largest standard deviation (RGB in [0, 1], averaged over the
    /// channels) of a voxel's colours across the views that see it for it to be kept.
    pub colour_tolerance: f32,
    /// Share of hull points placed in surface voxels (those with an empty neighbour): Gaussians
    /// only need to model what the cameras see, so the interior gets few.
    pub surface_preference: f32,
    /// Half-size of the search region (a cube around the rig's focus) in units of the mean
    /// camera distance from the focus. Raise it when the subject is near or beyond the cameras.
    pub region_scale: f32,
    /// Colour hull points only from views in which they lie on the hull's visible surface
    /// (tested against a depth map of the hull per view); otherwise the far side of a player
    /// takes the colour of the near side.
    pub occlusion: bool,
    /// Background points are the most photo-consistent of this many candidates per point, which
    /// pulls them towards real surfaces (floor, walls) rather than empty space.
    pub background_oversample: usize,
    /// A background candidate must be seen by at least this fraction of the masked views (and
    /// by `min_views`). Lower it where the background is a wall around the rig (a dome with
    /// the cameras on it), whose points only the cameras opposite can see.
    pub background_view_fraction: f32,
}

impl Default for CarveSettings {
    fn default() -> Self {
        Self {
            resolution: 96,
            agreement: 0.9,
            min_views: 4,
            foreground_fraction: 0.5,
            colour_tolerance: 0.08,
            surface_preference: 0.8,
            region_scale: 1.0,
            occlusion: true,
            background_oversample: 4,
            background_view_fraction: 0.5,
        }
    }
}

impl CarveSettings {
    /// Checks the ranges, so that bad scene files fail with a message instead of odd clouds.
    pub fn validate(&self) -> Result<(), CarveError> {
        let invalid = |message: String| Err(CarveError::InvalidSettings(message));
        if !(2..=MAX_RESOLUTION).contains(&self.resolution) {
            return invalid(format!(
                "resolution {} is outside 2..={MAX_RESOLUTION}",
                self.resolution
            ));
        }
        if !(self.agreement > 0.0 && self.agreement <= 1.0) {
            return invalid(format!("agreement {} is outside (0, 1]", self.agreement));
        }
        if self.min_views == 0 {
            return invalid("min_views must be at least 1".into());
        }
        for (name, value) in [
            ("foreground_fraction", self.foreground_fraction),
            ("surface_preference", self.surface_preference),
            ("background_view_fraction", self.background_view_fraction),
        ] {
            if !(0.0..=1.0).contains(&value) {
                return invalid(format!("{name} {value} is outside [0, 1]"));
            }
        }
        if !(self.colour_tolerance > 0.0 && self.colour_tolerance.is_finite()) {
            return invalid(format!(
                "colour_tolerance {} must be positive",
                self.colour_tolerance
            ));
        }
        if !(self.region_scale > 0.0 && self.region_scale.is_finite()) {
            return invalid(format!(
                "region_scale {} must be positive",
                self.region_scale
            ));
        }
        Ok(())
    }
}

/// Why no point cloud could be carved.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum CarveError {
    /// The dataset has no training view at the frame.
    #[error("frame {frame} has no training views")]
    NoViews {
        /// Frame index (not normalised time).
        frame: usize,
    },
    /// No training view at the frame has a usable foreground mask.
    #[error(
        "no training view at frame {frame} has a foreground mask of its camera's size; \
         use photo-consistency carving or random points instead"
    )]
    NoMasks {
        /// Frame index.
        frame: usize,
    },
    /// Too few views to carve anything meaningful (a monocular dataset, or a tiny subset).
    #[error(
        "frame {frame} has {found} usable views, but carving needs at least min_views = {needed}"
    )]
    TooFewViews {
        /// Frame index.
        frame: usize,
        /// Usable views at the frame (with a mask of the camera's size, for mask carving).
        found: usize,
        /// [`CarveSettings::min_views`].
        needed: usize,
    },
    /// Every voxel was carved away.
    #[error(
        "the visual hull at frame {frame} is empty: no voxel of {voxels} was foreground in at \
         least {agreement} of the (at least {min_views}) masked views that see it, among {views} \
         views; the masks disagree with the cameras (wrong poses, masks of another frame or \
         camera) or the search region misses the subject (raise region_scale)"
    )]
    EmptyHull {
        /// Frame index.
        frame: usize,
        /// Masked views used for carving.
        views: usize,
        /// Voxels tested in the grid that came out empty (the coarse grid, or the fine one).
        voxels: usize,
        /// [`CarveSettings::agreement`].
        agreement: f32,
        /// [`CarveSettings::min_views`].
        min_views: usize,
    },
    /// Photo-consistency carving kept nothing.
    #[error(
        "no voxel at frame {frame} is seen by at least {min_views} views with colours within \
         {tolerance} of each other; raise colour_tolerance or lower min_views"
    )]
    NoConsistentVoxels {
        /// Frame index.
        frame: usize,
        /// [`CarveSettings::colour_tolerance`].
        tolerance: f32,
        /// [`CarveSettings::min_views`].
        min_views: usize,
    },
    /// A setting is out of range.
    #[error("invalid carve settings: {0}")]
    InvalidSettings(String),
}

/// Inclusive pixel rectangle (x0, y0, x1, y1).
type PixelRect = (usize, usize, usize, usize);

/// A training view prepared for carving.
struct CarveView<'a> {
    camera: &'a Camera,
    eye: Vec3,
    image: Arc<RgbImage>,
    mask: Option<&'a [bool]>,
    /// Foreground pixel counts, for "any foreground under this footprint".
    mask_sums: Option<SummedArea<1>>,
    /// Colour sums, for the mean colour under a footprint (photo-consistency only).
    colour_sums: Option<SummedArea<3>>,
}

impl CarveView<'_> {
    fn width(&self) -> usize {
        self.camera.width as usize
    }

    /// Pixel coordinates of `point` when it lies in front of the camera and inside the image.
    fn project(&self, point: Vec3) -> Option<(f32, f32, f32)> {
        let (u, v, z) = self.camera.project(point);
        // Written so that NaN fails every comparison.
        let inside = z > MIN_DEPTH
            && u >= 0.0
            && v >= 0.0
            && u < self.camera.width as f32
            && v < self.camera.height as f32;
        inside.then_some((u, v, z))
    }

    /// The pixels whose centres lie in the square around (u, v) that bounds a sphere of
    /// `radius` at depth `z`; at least the pixel containing (u, v).
    fn footprint(&self, u: f32, v: f32, z: f32, radius: f32) -> PixelRect {
        let r = radius * self.camera.fx.max(self.camera.fy) / z;
        // Pixel i has its centre at i + 0.5.
        let span = |c: f32, size: u32| {
            let last = size as usize - 1;
            let first = (c - r - 0.5).ceil().max(0.0) as usize;
            let end = ((c + r - 0.5).floor().max(0.0) as usize).min(last);
            if first > end {
                let own = (c as usize).min(last);
                (own, own)
            } else {
                (first, end)
            }
        };
        let (x0, x1) = span(u, self.camera.width);
        let (y0, y1) = span(v, self.camera.height);
        (x0, y0, x1, y1)
    }

    fn pixel_index(&self, u: f32, v: f32) -> usize {
        v as usize * self.width() + u as usize
    }

    fn is_foreground(&self, u: f32, v: f32) -> bool {
        self.mask.is_some_and(|m| m[self.pixel_index(u, v)])
    }

    fn any_foreground(&self, rect: PixelRect) -> bool {
        let (x0, y0, x1, y1) = rect;
        self.mask_sums
            .as_ref()
            .is_some_and(|s| s.sum(x0, y0, x1, y1)[0] > 0)
    }

    fn colour(&self, u: f32, v: f32) -> Vec3 {
        let p = self.image.get_pixel(u as u32, v as u32).0;
        Vec3::new(p[0] as f32, p[1] as f32, p[2] as f32) / 255.0
    }

    fn mean_colour(&self, rect: PixelRect) -> Vec3 {
        let (x0, y0, x1, y1) = rect;
        let Some(sums) = &self.colour_sums else {
            return Vec3::ZERO;
        };
        let s = sums.sum(x0, y0, x1, y1);
        let area = ((x1 - x0 + 1) * (y1 - y0 + 1)) as f32;
        Vec3::new(s[0] as f32, s[1] as f32, s[2] as f32) / (255.0 * area)
    }
}

/// Training views at `frame` with a foreground mask of their camera's size (others are skipped
/// with a warning).
fn masked_views(dataset: &Dataset, frame: usize) -> Result<Vec<CarveView<'_>>, CarveError> {
    let views = views_at(dataset, frame, |view, camera| {
        let mask = view.foreground.as_deref()?;
        let (w, h) = (camera.width as usize, camera.height as usize);
        if mask.len() != w * h || view.image.dimensions() != (camera.width, camera.height) {
            tracing::warn!(
                camera = view.camera,
                frame,
                "mask or image does not match its camera's size; not carving with it"
            );
            return None;
        }
        let sums = SummedArea::new(w, h, |x, y| [u32::from(mask[y * w + x])]);
        Some(CarveView {
            camera,
            eye: camera.center(),
            image: readable_pixels(view)?,
            mask: Some(mask),
            mask_sums: Some(sums),
            colour_sums: None,
        })
    })?;
    if views.is_empty() {
        return Err(CarveError::NoMasks { frame });
    }
    Ok(views)
}

/// All training views at `frame` with colour prefix sums (for photo-consistency).
fn colour_views(dataset: &Dataset, frame: usize) -> Result<Vec<CarveView<'_>>, CarveError> {
    views_at(dataset, frame, |view, camera| {
        if view.image.dimensions() != (camera.width, camera.height) {
            tracing::warn!(
                camera = view.camera,
                frame,
                "image does not match its camera's size"
            );
            return None;
        }
        let image = readable_pixels(view)?;
        let sums = SummedArea::new(camera.width as usize, camera.height as usize, |x, y| {
            image.get_pixel(x as u32, y as u32).0.map(u32::from)
        });
        Some(CarveView {
            camera,
            eye: camera.center(),
            image,
            mask: None,
            mask_sums: None,
            colour_sums: Some(sums),
        })
    })
}

/// The training views at `frame` (with their cameras) that `make` turns into carving views,
/// built in parallel; `make` returns `None` for a view it cannot use.
/// A view's pixels, or `None` with a warning when a streamed view's file cannot be read
/// (training reports the error when it reaches that view).
fn readable_pixels(view: &View) -> Option<Arc<RgbImage>> {
    view.image
        .pixels()
        .inspect_err(|e| {
            tracing::warn!(
                camera = view.camera,
                frame = view.frame,
                "{e}; not carving with it"
            )
        })
        .ok()
}

fn views_at<'a>(
    dataset: &'a Dataset,
    frame: usize,
    make: impl Fn(&'a View, &'a Camera) -> Option<CarveView<'a>> + Sync,
) -> Result<Vec<CarveView<'a>>, CarveError> {
    let at_frame: Vec<&View> = dataset.train.iter().filter(|v| v.frame == frame).collect();
    if at_frame.is_empty() {
        return Err(CarveError::NoViews { frame });
    }
    Ok(at_frame
        .par_iter()
        .filter_map(|view| make(view, dataset.cameras.get(view.camera)?))
        .collect())
}

/// What the public entry points share: validates `settings`, collects the views of `frame`
/// with `collect` ([`masked_views`] or [`colour_views`]) and checks that at least `min_views`
/// of them are usable.
fn checked_views<'a>(
    dataset: &'a Dataset,
    frame: usize,
    settings: &CarveSettings,
    collect: fn(&'a Dataset, usize) -> Result<Vec<CarveView<'a>>, CarveError>,
) -> Result<Vec<CarveView<'a>>, CarveError> {
    settings.validate()?;
    let views = collect(dataset, frame)?;
    if views.len() < settings.min_views {
        return Err(CarveError::TooFewViews {
            frame,
            found: views.len(),
            needed: settings.min_views,
        });
    }
    Ok(views)
}

/// The cube the cameras look at: around the rig's focus, half-size `region_scale` × the mean
/// camera distance from it.
fn search_region(views: &[CarveView], region_scale: f32) -> (Vec3, Vec3) {
    let cameras: Vec<Camera> = views.iter().map(|v| *v.camera).collect();
    let focus = rig_focus(&cameras);
    let mean_distance =
        views.iter().map(|v| v.eye.distance(focus)).sum::<f32>() / views.len().max(1) as f32;
    let half = Vec3::splat(region_scale * mean_distance.max(1e-3));
    (focus - half, focus + half)
}

/// Mean and standard deviation (averaged over channels) of colours given as sum and sum of
/// squares over `n` samples.
fn mean_and_spread(sum: Vec3, sum_sq: Vec3, n: usize) -> (Vec3, f32) {
    let mean = sum / n as f32;
    let variance = (sum_sq / n as f32 - mean * mean).max(Vec3::ZERO);
    (mean, (variance.element_sum() / 3.0).sqrt())
}

/// Whether any training view at `frame` carries a foreground mask.
pub fn has_masks(dataset: &Dataset, frame: usize) -> bool {
    dataset
        .train
        .iter()
        .any(|v| v.frame == frame && v.foreground.is_some())
}

/// The initial point cloud of anchor `frame`: with masks, `foreground_fraction` of `count` from
/// the visual hull and the rest from the background (topped up from the hull when the
/// background is hard to hit); without masks, all from photo-consistency carving. On an error
/// the caller can fall back to [`super::random_points_in_view`].
pub fn initial_points(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<Vec<InitPoint>, CarveError> {
    let mut carved = carved_points(dataset, frame, count, settings, rng)?;
    carved.foreground.append(&mut carved.background);
    Ok(carved.foreground)
}

/// [`initial_points`] kept apart: the points on the visual hull and the background points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CarvedPoints {
    /// On the visual hull of the masks (the moving foreground), or every point of a
    /// photo-consistency carving (which does not tell foreground from background).
    pub foreground: Vec<InitPoint>,
    /// Photo-consistent points outside the hull: the static background.
    pub background: Vec<InitPoint>,
}

impl CarvedPoints {
    /// Points whose source does not tell foreground from background (random points, a point
    /// cloud, a photo-consistency carving): all counted as foreground.
    pub fn undivided(points: Vec<InitPoint>) -> Self {
        Self {
            foreground: points,
            background: Vec::new(),
        }
    }
}

/// The points of [`initial_points`], the hull's and the background's apart.
pub fn carved_points(
    dataset: &Dataset,
    frame: usize,
    count: usize,
    settings: &CarveSettings,
    rng: &mut impl Rng,
) -> Result<CarvedPoints, CarveError> {
    settings.validate()?;
    if !has_masks(dataset, frame) {
        tracing::info!(frame, "no foreground masks; carving by photo-consistency");
        let points = carve_photo_consistent(dataset, frame, count, settings, rng)?;
        return Ok(CarvedPoints::undivided(points));
    }
    let views = checked_views(dataset, frame, settings, masked_views)?;
    let grid = visual_hull_of(&views, frame, settings)?;
    let foreground_count =
        ((count as f32 * settings.foreground_fraction).round() as usize).min(count);
    let mut foreground = sample_hull(&views, &grid, foreground_count, settings, &mut *rng);
    let background = background_points_of(&views, count - foreground_count, settings, &mut *rng);
    let shortfall = count - foreground_count - background.len();
    foreground.extend(sample_hull(&views, &grid, shortfall, settings, rng));
    Ok(CarvedPoints {
        foreground,
        background,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::init::carve::testing::*;

    /// `initial_points` splits the count between hull and background by `foreground_fraction`.
    #[test]
    fn initial_points_mix_hull_and_background() {
        let scene = sphere_scene();
        let settings = CarveSettings {
            foreground_fraction: 0.25,
            ..test_settings()
        };
        let points = initial_points(&scene.dataset, 0, 400, &settings, &mut rng()).unwrap();
        assert_eq!(points.len(), 400);
        // Hull points are red, background points grey.
        let red = points.iter().filter(|p| p.color[0] > 0.8).count();
        assert_eq!(red, 100);
    }

    /// `carved_points` keeps the two kinds apart: every hull point is red (on the sphere),
    /// every background point grey (outside it), and together they are `initial_points`.
    #[test]
    fn carved_points_keep_hull_and_background_apart() {
        let scene = sphere_scene();
        let settings = CarveSettings {
            foreground_fraction: 0.25,
            ..test_settings()
        };
        let carved = carved_points(&scene.dataset, 0, 400, &settings, &mut rng()).unwrap();
        assert_eq!(
            (carved.foreground.len(), carved.background.len()),
            (100, 300)
        );
        assert!(carved.foreground.iter().all(|p| p.color[0] > 0.8));
        assert!(carved.background.iter().all(|p| p.color[0] < 0.6));
        for p in &carved.background {
            assert!(p.position.distance(scene.centre) > scene.radius);
        }
        let mut all = initial_points(&scene.dataset, 0, 400, &settings, &mut rng()).unwrap();
        let mut joined = [carved.foreground, carved.background].concat();
        let key = |p: &InitPoint| p.position.to_array().map(f32::to_bits);
        all.sort_by_key(key);
        joined.sort_by_key(key);
        assert_eq!(all, joined);
    }

    /// The same seed gives the same cloud.
    #[test]
    fn carving_is_deterministic() {
        let scene = sphere_scene();
        let a = initial_points(&scene.dataset, 0, 200, &test_settings(), &mut rng()).unwrap();
        let b = initial_points(&scene.dataset, 0, 200, &test_settings(), &mut rng()).unwrap();
        assert_eq!(a, b);
    }

    /// Without masks, mask carving says so; a frame without views and too few views are errors too.
    #[test]
    fn missing_masks_and_views_are_errors() {
        let mut scene = sphere_scene();
        let settings = test_settings();
        assert_eq!(
            carve_from_masks(&scene.dataset, 5, 10, &settings, &mut rng()),
            Err(CarveError::NoViews { frame: 5 })
        );
        let few = CarveSettings {
            min_views: 11,
            ..test_settings()
        };
        assert!(matches!(
            visual_hull(&scene.dataset, 0, &few),
            Err(CarveError::TooFewViews {
                found: 10,
                needed: 11,
                ..
            })
        ));
        for view in &mut scene.dataset.train {
            view.foreground = None;
        }
        assert_eq!(
            carve_from_masks(&scene.dataset, 0, 10, &settings, &mut rng()),
            Err(CarveError::NoMasks { frame: 0 })
        );
        assert_eq!(
            background_points(&scene.dataset, 0, 10, &settings, &mut rng()),
            Err(CarveError::NoMasks { frame: 0 })
        );
    }

    /// Out-of-range settings are rejected rather than carving nonsense.
    #[test]
    fn bad_settings_are_rejected() {
        let scene = sphere_scene();
        for bad in [
            CarveSettings {
                resolution: 0,
                ..test_settings()
            },
            CarveSettings {
                agreement: 0.0,
                ..test_settings()
            },
            CarveSettings {
                min_views: 0,
                ..test_settings()
            },
            CarveSettings {
                foreground_fraction: 1.5,
                ..test_settings()
            },
            CarveSettings {
                colour_tolerance: f32::NAN,
                ..test_settings()
            },
        ] {
            assert!(matches!(
                initial_points(&scene.dataset, 0, 10, &bad, &mut rng()),
                Err(CarveError::InvalidSettings(_))
            ));
        }
    }

    /// Settings survive a RON round trip, omitted fields default and unknown ones are refused.
    #[test]
    fn settings_read_from_ron() {
        let settings = CarveSettings {
            resolution: 64,
            occlusion: false,
            ..CarveSettings::default()
        };
        let text = ron::to_string(&settings).unwrap();
        assert_eq!(ron::from_str::<CarveSettings>(&text).unwrap(), settings);
        let partial: CarveSettings = ron::from_str("(agreement: 0.8)").unwrap();
        assert_eq!(partial.agreement, 0.8);
        assert_eq!(partial.resolution, CarveSettings::default().resolution);
        assert!(ron::from_str::<CarveSettings>("(resolutoin: 8)").is_err());
    }
}
