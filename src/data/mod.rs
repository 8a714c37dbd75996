//! Cameras, multi-view video datasets and their readers.

pub mod camera;
pub mod colmap;
pub mod colmap_video;
pub mod dnerf;
pub mod error;
pub mod n3dv;
pub mod nerfstudio;
pub mod panoptic;
pub mod pointcloud;
mod settings;
pub mod stream;
pub mod synthetic;
pub mod undistort;

pub use camera::Camera;
pub use error::DataError;
pub use stream::{FrameCache, ViewImage};

use crate::io::image::Image;

/// One observed image: which camera saw it, at which frame and normalised time.
///
/// Images are kept as 8-bit RGB (a quarter of the memory of [`Image`]): a 27-camera,
/// 150-frame capture at 640×360 fits in 2.8 GB. Larger captures are streamed from disk
/// through a bounded cache (`data.cache_mb`, see [`stream`]). Masks are `width × height`
/// booleans in row-major order.
#[derive(Clone, Debug)]
pub struct View {
    /// Index into [`Dataset::cameras`].
    pub camera: usize,
    /// Frame index in `0..frame_count`.
    pub frame: usize,
    /// Normalised time in [0, 1] (usually `frame / (T − 1)`; readers with their own time
    /// stamps, such as D-NeRF, give them exactly).
    pub time: f32,
    /// The image, of its camera's size: in memory or read from disk on demand.
    pub image: ViewImage,
    /// Dynamic-region mask for the masked metrics (true = dynamic), where known.
    pub dynamic_mask: Option<Vec<bool>>,
    /// Foreground segmentation (true = foreground), where the dataset ships one; used by
    /// the visual-hull initialiser.
    pub foreground: Option<Vec<bool>>,
    /// The image's alpha and the colour it was composited over, for training views of
    /// datasets of RGBA images (D-NeRF, Blender-style nerfstudio scenes): lets training
    /// recomposite the truth over another background (`train.random_background`).
    pub matte: Option<Matte>,
}

/// Coverage of an image composited over a uniform colour: `alpha` per pixel (0–255,
/// row-major, the image's size) and the `background` colour the image was blended over.
#[derive(Clone, Debug, PartialEq)]
pub struct Matte {
    /// Straight alpha of each pixel, 0 (background only) to 255 (opaque).
    pub alpha: Vec<u8>,
    /// The colour the 8-bit image was composited over.
    pub background: [f32; 3],
}

impl Matte {
    /// Moves `image` (the view's image over [`Matte::background`]) onto `over`: each pixel
    /// gains (over − background)·(1 − alpha).
    pub fn recomposite(&self, image: &mut Image, over: [f32; 3]) {
        debug_assert_eq!(image.data.len(), self.alpha.len());
        let shift = std::array::from_fn::<f32, 3, _>(|c| over[c] - self.background[c]);
        for (pixel, &alpha) in image.data.iter_mut().zip(&self.alpha) {
            let uncovered = 1.0 - f32::from(alpha) / 255.0;
            for c in 0..3 {
                pixel[c] += shift[c] * uncovered;
            }
        }
    }

    /// The matte of the view box-filtered by `factor` (the image is `width × height`), as
    /// [`crate::io::image::box_downscale`] filters the image.
    pub fn downscaled(&self, width: u32, height: u32, factor: u32) -> Matte {
        let alpha = image::GrayImage::from_raw(width, height, self.alpha.clone())
            .expect("a matte has its view's size");
        Matte {
            alpha: crate::io::image::box_downscale(&alpha, factor).into_raw(),
            background: self.background,
        }
    }
}

impl View {
    /// The image as `f32` RGB in [0, 1] (the 8-bit values divided by 255, not linearised).
    /// Fails only for a streamed view whose file can no longer be read.
    pub fn to_image(&self) -> Result<Image, DataError> {
        Ok(Image::from_rgb8(&*self.image.pixels()?))
    }

    /// Writes the image into `out` as `f32` RGB, reusing its allocation. Fails only for a
    /// streamed view whose file can no longer be read.
    pub fn copy_image_into(&self, out: &mut Image) -> Result<(), DataError> {
        out.copy_from_rgb8(&*self.image.pixels()?);
        Ok(())
    }
}

/// A multi-view video held in memory: training and held-out views with their cameras.
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    /// Every camera of the capture, training and held-out; [`View::camera`] indexes it.
    pub cameras: Vec<Camera>,
    /// Number of frames T of the sequence (the model's time base: λ = window / T).
    pub frame_count: usize,
    /// Views to train on, in a fixed order (sampling shuffles indices into this list).
    pub train: Vec<View>,
    /// Held-out views for evaluation.
    pub test: Vec<View>,
    /// An initial point cloud shipped with the dataset, if any.
    pub points: Option<Vec<crate::init::InitPoint>>,
    /// Point clouds of single frames (a COLMAP reconstruction per anchor frame), in increasing
    /// frame order; where there are any, each anchor frame starts from the nearest frame's
    /// cloud instead of [`Dataset::points`] (see [`Dataset::nearest_frame_points`]).
    pub frame_points: Vec<(usize, Vec<crate::init::InitPoint>)>,
    /// The temporal segment the views were restricted to ([`Dataset::restrict_to_segment`]).
    pub segment: Option<crate::scene::Segment>,
}

impl Dataset {
    /// Normalised time of a frame: `frame / (T − 1)` in [0, 1].
    pub fn frame_time(&self, frame: usize) -> f32 {
        frame_time(frame, self.frame_count)
    }

    /// A one-camera dataset that sees `image` at every one of `frame_count` frames (for tests,
    /// benches and examples).
    pub fn single_camera(camera: Camera, frame_count: usize, image: &Image) -> Self {
        let rgb = ViewImage::from(image.to_rgb8());
        let train = (0..frame_count)
            .map(|frame| View {
                camera: 0,
                frame,
                time: frame_time(frame, frame_count),
                image: rgb.clone(),
                dynamic_mask: None,
                foreground: None,
                matte: None,
            })
            .collect();
        Self {
            cameras: vec![camera],
            frame_count,
            train,
            ..Self::default()
        }
    }

    /// Keeps only the training and held-out views of the segment's frames. Frame numbers,
    /// times and [`Dataset::frame_count`] stay those of the whole sequence, so a model trained
    /// on the segment lives in the sequence's time.
    pub fn restrict_to_segment(&mut self, segment: crate::scene::Segment) -> Result<(), String> {
        if segment.last_frame >= self.frame_count {
            return Err(format!(
                "the segment ends at frame {}, but the sequence has {} frames (0 to {})",
                segment.last_frame,
                self.frame_count,
                self.frame_count.saturating_sub(1)
            ));
        }
        let frames = segment.first_frame..=segment.last_frame;
        self.train.retain(|view| frames.contains(&view.frame));
        self.test.retain(|view| frames.contains(&view.frame));
        if self.train.is_empty() {
            return Err(format!(
                "no training view lies in the segment's frames {} to {}",
                segment.first_frame, segment.last_frame
            ));
        }
        self.segment = Some(segment);
        Ok(())
    }

    /// The anchor frames that get initial points: every `spacing`-th frame and the last
    /// ([`crate::init::anchor_frames`]); in a segment, those inside it plus its first and last
    /// frames, so the segment's ends are covered as well as a whole run's.
    pub fn anchor_frames(&self, spacing: usize) -> Vec<usize> {
        let all = crate::init::anchor_frames(self.frame_count, spacing);
        let Some(segment) = self.segment else {
            return all;
        };
        let frames = segment.first_frame..=segment.last_frame;
        let mut anchors: Vec<usize> = all.into_iter().filter(|f| frames.contains(f)).collect();
        anchors.extend([segment.first_frame, segment.last_frame]);
        anchors.sort_unstable();
        anchors.dedup();
        anchors
    }

    /// The per-frame point cloud nearest in time to `frame` (the earlier one on a tie), with
    /// the frame it belongs to; `None` when the dataset has no per-frame clouds.
    pub fn nearest_frame_points(&self, frame: usize) -> Option<(usize, &[crate::init::InitPoint])> {
        self.frame_points
            .iter()
            .min_by_key(|(f, _)| f.abs_diff(frame))
            .map(|(f, points)| (*f, points.as_slice()))
    }

    /// Adds `camera`'s views at frames 0, 1, … from `images` (at most `frame_count` of them)
    /// to the held-out views when `held_out`, otherwise to the training views.
    pub(crate) fn push_camera_frames(
        &mut self,
        camera: usize,
        images: Vec<impl Into<ViewImage>>,
        held_out: bool,
    ) {
        let frame_count = self.frame_count;
        let views = images
            .into_iter()
            .take(frame_count)
            .enumerate()
            .map(|(frame, image)| View {
                camera,
                frame,
                time: frame_time(frame, frame_count),
                image: image.into(),
                dynamic_mask: None,
                foreground: None,
                matte: None,
            });
        if held_out {
            self.test.extend(views);
        } else {
            self.train.extend(views);
        }
    }

    /// Distinct camera indices of the training views, in increasing order.
    pub fn train_cameras(&self) -> Vec<usize> {
        distinct_cameras(&self.train)
    }

    /// The training views (images box-filtered, masks sampled at block centres) and every
    /// camera at a resolution `factor` times lower, without the held-out views: what a
    /// coarse-to-fine run trains on first.
    pub fn downscaled_training_views(&self, factor: u32) -> Dataset {
        use rayon::prelude::*;
        let cameras: Vec<Camera> = self.cameras.iter().map(|c| c.downscaled(factor)).collect();
        let train = self
            .train
            .par_iter()
            .map(|view| {
                let (width, height) = view.image.dimensions();
                let size = (width / factor, height / factor);
                let mask = |m: &Option<Vec<bool>>| {
                    m.as_ref()
                        .map(|m| panoptic::downscale_mask(m, width, height, factor))
                };
                View {
                    camera: view.camera,
                    frame: view.frame,
                    time: view.time,
                    image: view.image.map(size, move |image| {
                        crate::io::image::box_downscale(image, factor)
                    }),
                    dynamic_mask: mask(&view.dynamic_mask),
                    foreground: mask(&view.foreground),
                    matte: view
                        .matte
                        .as_ref()
                        .map(|m| m.downscaled(width, height, factor)),
                }
            })
            .collect();
        Dataset {
            cameras,
            frame_count: self.frame_count,
            train,
            test: Vec::new(),
            points: self.points.clone(),
            frame_points: self.frame_points.clone(),
            segment: self.segment,
        }
    }

    /// The cameras of the training views, in increasing index order.
    pub fn training_rig(&self) -> Vec<Camera> {
        self.train_cameras()
            .iter()
            .map(|&c| self.cameras[c])
            .collect()
    }

    /// The cameras that place and size the scene (its extent and centre): the training rig,
    /// or every camera of a dataset without training views (a render-only dataset). Held-out
    /// cameras must not influence training, not even through the extent.
    pub fn scene_rig(&self) -> Vec<Camera> {
        let rig = self.training_rig();
        if rig.is_empty() {
            self.cameras.clone()
        } else {
            rig
        }
    }

    /// Distinct camera indices of the held-out views, in increasing order.
    pub fn test_cameras(&self) -> Vec<usize> {
        distinct_cameras(&self.test)
    }

    /// The held-out view of `camera` at `frame`, if there is one.
    pub fn test_view(&self, camera: usize, frame: usize) -> Option<&View> {
        self.test
            .iter()
            .find(|v| v.camera == camera && v.frame == frame)
    }

    /// Bytes of image, mask and matte data the views hold themselves (streamed images count in
    /// their cache instead: see [`Dataset::cache`]).
    pub fn memory_bytes(&self) -> usize {
        self.train
            .iter()
            .chain(&self.test)
            .map(|v| {
                v.image.resident_bytes()
                    + v.dynamic_mask.as_ref().map_or(0, Vec::len)
                    + v.foreground.as_ref().map_or(0, Vec::len)
                    + v.matte.as_ref().map_or(0, |m| m.alpha.len())
            })
            .sum()
    }

    /// The cache streamed views are read through, if any view is streamed (readers use one
    /// cache per dataset).
    pub fn cache(&self) -> Option<&std::sync::Arc<FrameCache>> {
        self.train
            .iter()
            .chain(&self.test)
            .find_map(|v| v.image.cache())
    }
}

/// Reads (or, for a synthetic scene, renders) the dataset a scene file names.
pub fn load(source: &crate::scene::DataSource) -> Result<Dataset, DataError> {
    use crate::scene::DataSource;
    let (dataset, path) = match source {
        DataSource::Synthetic(scene) => {
            let path = "synthetic scene";
            let dataset = scene
                .build()
                .map_err(|message| DataError::dataset(std::path::Path::new(path), message))?;
            (dataset, path)
        }
        DataSource::Panoptic(source) => (panoptic::load(source)?, source.path.as_str()),
        DataSource::DNerf(source) => (dnerf::load(source)?, source.path.as_str()),
        DataSource::N3dv(source) => (n3dv::load(source)?, source.path.as_str()),
        DataSource::Nerfstudio(source) => (nerfstudio::load(source)?, source.path.as_str()),
        DataSource::ColmapFrames(source) => {
            (colmap_video::load_frames(source)?, source.path.as_str())
        }
        DataSource::ColmapRig(source) => (colmap_video::load_rig(source)?, source.path.as_str()),
    };
    check_camera_positions(&dataset.cameras)
        .map_err(|message| DataError::dataset(std::path::Path::new(path), message))?;
    Ok(dataset)
}

/// The largest image side, in pixels, that tadgs reads, renders or generates (that of the
/// largest textures GPUs commonly support); larger sizes from input are refused before any
/// allocation.
pub const MAX_IMAGE_SIDE: u32 = 16384;

/// The most frames a sequence may have (model metadata, exports, renders).
pub const MAX_FRAMES: usize = 1_000_000;

/// How far from the origin a camera may be, in scene units. Positions are `f32`: at 1e6 a
/// step of the position learning rate (≈1e-6 of the scene extent) is below their precision,
/// and far beyond it sizes overflow. Recentre and rescale scenes beyond it.
pub const MAX_CAMERA_DISTANCE: f32 = 1e6;

/// Every camera centre is finite and within [`MAX_CAMERA_DISTANCE`] of the origin.
pub fn check_camera_positions(cameras: &[Camera]) -> Result<(), String> {
    for (index, camera) in cameras.iter().enumerate() {
        let centre = camera.center();
        let distance = centre.length();
        if !(distance <= MAX_CAMERA_DISTANCE) {
            return Err(format!(
                "camera {index} is at ({:.3e}, {:.3e}, {:.3e}), farther than {MAX_CAMERA_DISTANCE:.0e} \
                 from the origin (or not finite): recentre and rescale the scene",
                centre.x, centre.y, centre.z
            ));
        }
    }
    Ok(())
}

/// Normalised time of `frame` in a `frame_count`-frame sequence: `frame / (T − 1)`.
pub fn frame_time(frame: usize, frame_count: usize) -> f32 {
    if frame_count <= 1 {
        0.0
    } else {
        frame as f32 / (frame_count - 1) as f32
    }
}

fn distinct_cameras(views: &[View]) -> Vec<usize> {
    let mut cameras: Vec<usize> = views.iter().map(|v| v.camera).collect();
    cameras.sort_unstable();
    cameras.dedup();
    cameras
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Recompositing moves uncovered pixels to the new colour (to 1e-6), leaves covered ones
    /// exactly as they are and blends a half-covered one halfway: the image a renderer would draw
    /// over the new colour.
    #[test]
    fn recomposite_replaces_the_background_by_coverage() {
        let white = [1.0; 3];
        let red = [0.9, 0.1, 0.2];
        let over = [0.2, 0.4, 0.6];
        let half = 128.0 / 255.0;
        let blend =
            |back: [f32; 3]| std::array::from_fn(|c| half * red[c] + (1.0 - half) * back[c]);
        let mut image = Image {
            width: 3,
            height: 1,
            data: vec![white, red, blend(white)],
        };
        let matte = Matte {
            alpha: vec![0, 255, 128],
            background: white,
        };
        matte.recomposite(&mut image, over);
        assert_eq!(image.data[1], red);
        let expected: [f32; 3] = blend(over);
        for c in 0..3 {
            assert!(
                (image.data[0][c] - over[c]).abs() < 1e-6,
                "uncovered, channel {c}"
            );
            assert!(
                (image.data[2][c] - expected[c]).abs() < 1e-6,
                "half, channel {c}"
            );
        }
    }

    /// The downscaled matte is the block mean of the alpha, rounded, like the image's box
    /// filter: a 4×2 matte at factor 2 gives 2×1.
    #[test]
    fn downscaled_matte_averages_blocks() {
        let matte = Matte {
            alpha: vec![0, 255, 255, 255, 0, 0, 255, 255],
            background: [0.0; 3],
        };
        let half = matte.downscaled(4, 2, 2);
        assert_eq!(half.alpha, vec![64, 255]);
        assert_eq!(half.background, [0.0; 3]);
    }
}
