//! The evaluation protocol: per-view PSNR, SSIM, LPIPS and the masked M-PSNR / M-SSIM over
//! dynamic pixels, their means, and the dynamic masks themselves.
//!
//! Masks come from, in order: the dataset (exact masks of synthetic scenes), PNG files in a
//! mask folder (written by `tadgs masks` or supplied by the user, named by
//! [`mask_file_name`]), or dense optical flow between frames `t − 5` and `t` of the same test
//! camera ([`flow::dynamic_mask`], threshold [`flow::DEFAULT_FLOW_THRESHOLD`] px). Frames
//! without a mask (0–4, or a camera without earlier frames) are skipped by the masked metrics.

use std::path::{Path, PathBuf};

use serde::Serialize;

use super::flow::{self, MASK_FRAME_GAP};
use super::lpips::{Lpips, LpipsError};
use super::{masked_psnr, masked_ssim, psnr, ssim};
use crate::data::{DataError, Dataset, View};
use crate::io::image::{Image, ImageError};

/// The metrics of one held-out view.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ViewScores {
    /// Index of the view's camera in [`Dataset::cameras`].
    pub camera: usize,
    /// Frame index of the view.
    pub frame: usize,
    /// Normalised time of the view in [0, 1].
    pub time: f32,
    /// PSNR in dB over the whole image (peak 1); infinite for a pixel-exact render.
    pub psnr: f32,
    /// SSIM over the whole image (11×11 Gaussian window, σ = 1.5).
    pub ssim: f32,
    /// LPIPS (AlexNet); None when no LPIPS weights were given.
    pub lpips: Option<f32>,
    /// PSNR over the dynamic pixels; None where the view has no mask or an empty one.
    pub masked_psnr: Option<f32>,
    /// Mean SSIM map over the dynamic pixels.
    pub masked_ssim: Option<f32>,
    /// Fraction of pixels flagged dynamic (None without a mask).
    pub dynamic_fraction: Option<f32>,
}

/// Means over the views (masked means over the views that have a non-empty mask).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ScoreSummary {
    /// Number of views scored.
    pub views: usize,
    /// Mean PSNR in dB over the views with a finite PSNR; None when there is none.
    pub psnr: Option<f32>,
    /// Mean SSIM; None without views.
    pub ssim: Option<f32>,
    /// Mean LPIPS (AlexNet); None when no view has an LPIPS score.
    pub lpips: Option<f32>,
    /// Number of views with a non-empty dynamic mask (those the masked means cover).
    pub masked_views: usize,
    /// Mean M-PSNR in dB over the masked views with a finite M-PSNR.
    pub masked_psnr: Option<f32>,
    /// Mean M-SSIM over the masked views.
    pub masked_ssim: Option<f32>,
}

impl ScoreSummary {
    /// The means of `scores`, each over the finite values it has.
    pub fn of(scores: &[ViewScores]) -> Self {
        Self {
            views: scores.len(),
            psnr: mean(scores.iter().map(|s| s.psnr)),
            ssim: mean(scores.iter().map(|s| s.ssim)),
            lpips: mean(scores.iter().filter_map(|s| s.lpips)),
            masked_views: scores.iter().filter(|s| s.masked_psnr.is_some()).count(),
            masked_psnr: mean(scores.iter().filter_map(|s| s.masked_psnr)),
            masked_ssim: mean(scores.iter().filter_map(|s| s.masked_ssim)),
        }
    }
}

/// Mean of the finite values (None when there are none).
pub fn mean(values: impl Iterator<Item = f32>) -> Option<f32> {
    let (sum, n) = values
        .filter(|v| v.is_finite())
        .fold((0.0f64, 0usize), |(s, n), v| (s + v as f64, n + 1));
    (n > 0).then(|| (sum / n as f64) as f32)
}

/// Scores one render against its ground truth.
pub fn score_view(
    view: &View,
    render: &Image,
    gt: &Image,
    mask: Option<&[bool]>,
    lpips: Option<&Lpips>,
) -> Result<ViewScores, LpipsError> {
    Ok(ViewScores {
        camera: view.camera,
        frame: view.frame,
        time: view.time,
        psnr: psnr(render, gt),
        ssim: ssim(render, gt),
        lpips: lpips.map(|net| net.distance(render, gt)).transpose()?,
        masked_psnr: mask.and_then(|m| masked_psnr(render, gt, m)),
        masked_ssim: mask.and_then(|m| masked_ssim(render, gt, m)),
        dynamic_fraction: mask
            .map(|m| m.iter().filter(|&&d| d).count() as f32 / m.len().max(1) as f32),
    })
}

/// File name of the mask of `camera` at `frame` inside a mask folder.
pub fn mask_file_name(camera: usize, frame: usize) -> String {
    format!("cam{camera:02}_frame{frame:04}.png")
}

/// The flow mask of a held-out view: flow between frame `t − 5` and `t` of the same camera.
/// None for the first five frames (or when the earlier frame is not among the test views).
/// Fails only when a streamed view's file can no longer be read.
pub fn flow_mask(
    dataset: &Dataset,
    view: &View,
    threshold: f32,
) -> Result<Option<Vec<bool>>, DataError> {
    let Some(earlier) = view
        .frame
        .checked_sub(MASK_FRAME_GAP)
        .and_then(|frame| dataset.test_view(view.camera, frame))
    else {
        return Ok(None);
    };
    Ok(Some(flow::dynamic_mask(
        &earlier.to_image()?,
        &view.to_image()?,
        threshold,
    )))
}

/// Where the dynamic masks of the held-out views come from.
#[derive(Clone, Debug, Default)]
pub struct MaskSource {
    /// Folder of mask PNGs ([`mask_file_name`]); read when a file exists there.
    pub folder: Option<PathBuf>,
    /// Compute missing masks by optical flow (and write them to `folder` when given).
    pub compute: bool,
    /// Flow magnitude threshold in pixels.
    pub threshold: f32,
}

/// A mask folder could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum MaskError {
    /// A mask PNG could not be read, or a computed mask could not be written.
    #[error(transparent)]
    Image(#[from] ImageError),
    /// A mask PNG in the folder does not have the size of its view's image.
    #[error("mask {}: {width}×{height} px, but the view is {expected_width}×{expected_height}", path.display())]
    Size {
        /// The mask file.
        path: PathBuf,
        /// Width of the mask in pixels.
        width: usize,
        /// Height of the mask in pixels.
        height: usize,
        /// Width of the view's image in pixels.
        expected_width: usize,
        /// Height of the view's image in pixels.
        expected_height: usize,
    },
    /// The mask folder, or the record of its settings, could not be written (only attempted
    /// when masks are computed).
    #[error("cannot write {}: {source}", path.display())]
    Folder {
        /// The mask folder.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// A held-out view's image could not be read (a streamed view whose file went missing).
    #[error(transparent)]
    Data(#[from] DataError),
}

/// The record of how a mask folder's masks were computed, beside them.
pub const MASK_SETTINGS_FILE: &str = "masks.ron";

/// How computed masks were made (written to [`MASK_SETTINGS_FILE`]).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct MaskSettings {
    /// Flow magnitude threshold in pixels.
    pub flow_threshold: f32,
}

/// Whether the PNGs already in `folder` may be reused with `threshold`: yes when they were
/// made with it, or when nothing records how they were made (masks the user supplied);
/// no when they were made with another threshold. Logs what it decides.
fn reuse_mask_folder(folder: &Path, threshold: f32) -> bool {
    let existing = std::fs::read_dir(folder)
        .map(|entries| {
            entries
                .flatten()
                .filter(|e| e.file_name().to_string_lossy().ends_with(".png"))
                .count()
        })
        .unwrap_or(0);
    if existing == 0 {
        return true;
    }
    let record = std::fs::read_to_string(folder.join(MASK_SETTINGS_FILE))
        .ok()
        .and_then(|text| ron::from_str::<MaskSettings>(&text).ok());
    match record {
        Some(made) if made.flow_threshold != threshold => {
            tracing::info!(
                "the {existing} masks in {} were made with flow threshold {} px; computing them \
                 again with {threshold} px",
                folder.display(),
                made.flow_threshold
            );
            false
        }
        Some(_) => {
            tracing::info!("reusing the {existing} masks in {}", folder.display());
            true
        }
        None => {
            tracing::info!(
                "reusing the {existing} masks in {} (no {MASK_SETTINGS_FILE} records how they \
                 were made)",
                folder.display()
            );
            true
        }
    }
}

/// The dynamic mask of every held-out view (in `dataset.test` order): the dataset's own
/// (exact) mask, else the mask folder's PNG, else optical flow when [`MaskSource::compute`]
/// is set. With `compute`, every mask not read from the folder is written there as a PNG,
/// with the settings in [`MASK_SETTINGS_FILE`]; PNGs recorded there as made with another
/// threshold are computed again. `progress` is called once per view.
pub fn dynamic_masks(
    dataset: &Dataset,
    source: &MaskSource,
    mut progress: impl FnMut(),
) -> Result<Vec<Option<Vec<bool>>>, MaskError> {
    let mut reuse = true;
    if let Some(folder) = source.folder.as_ref().filter(|_| source.compute) {
        std::fs::create_dir_all(folder).map_err(|e| MaskError::Folder {
            path: folder.clone(),
            source: e,
        })?;
        reuse = reuse_mask_folder(folder, source.threshold);
    }
    let mut masks = Vec::with_capacity(dataset.test.len());
    for view in &dataset.test {
        let (width, height) = (view.image.width() as usize, view.image.height() as usize);
        let file = source
            .folder
            .as_ref()
            .map(|f| f.join(mask_file_name(view.camera, view.frame)));
        let from_file = file
            .as_ref()
            .filter(|p| reuse && p.is_file() && view.dynamic_mask.is_none());
        let mask = if let Some(path) = from_file {
            Some(read_mask_png(path, width, height)?)
        } else {
            let mask = match &view.dynamic_mask {
                Some(mask) => Some(mask.clone()),
                None if source.compute => flow_mask(dataset, view, source.threshold)?,
                None => None,
            };
            // Save every mask not read from the folder, so the folder shows what was used.
            if let (Some(mask), Some(path), true) = (&mask, &file, source.compute) {
                flow::mask_to_image(mask, width, height).save_png(path)?;
            }
            mask
        };
        masks.push(mask);
        progress();
    }
    // Recorded once every mask is written, so the record never describes older files.
    if let Some(folder) = source.folder.as_ref().filter(|_| source.compute) {
        let settings = MaskSettings {
            flow_threshold: source.threshold,
        };
        let text = ron::to_string(&settings).expect("mask settings serialise");
        let path = folder.join(MASK_SETTINGS_FILE);
        crate::io::write_atomic(&path, text.as_bytes())
            .map_err(|e| MaskError::Folder { path, source: e })?;
    }
    Ok(masks)
}

fn read_mask_png(path: &Path, width: usize, height: usize) -> Result<Vec<bool>, MaskError> {
    let image = Image::load(path)?;
    if (image.width, image.height) != (width, height) {
        return Err(MaskError::Size {
            path: path.to_path_buf(),
            width: image.width,
            height: image.height,
            expected_width: width,
            expected_height: height,
        });
    }
    Ok(flow::mask_from_image(&image))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::Camera;

    fn view_with(image: &Image, frame: usize) -> View {
        View {
            camera: 0,
            frame,
            time: 0.0,
            image: image.to_rgb8().into(),
            dynamic_mask: None,
            foreground: None,
            matte: None,
        }
    }

    /// A perfect render scores infinite PSNR (reported as such), SSIM 1 and masked SSIM 1;
    /// an empty mask leaves the masked metrics out of the means.
    #[test]
    fn identical_images_score_perfectly() {
        let image = Image {
            width: 16,
            height: 12,
            data: (0..192).map(|i| [(i % 7) as f32 / 7.0, 0.5, 0.2]).collect(),
        };
        let view = view_with(&image, 0);
        let mut mask = vec![false; 192];
        mask[40] = true;
        let scores = score_view(&view, &image, &image, Some(&mask), None).unwrap();
        assert!(scores.psnr.is_infinite());
        assert!((scores.ssim - 1.0).abs() < 1e-6);
        assert!((scores.masked_ssim.unwrap() - 1.0).abs() < 1e-6);
        let empty = score_view(&view, &image, &image, Some(&[false; 192]), None).unwrap();
        assert_eq!(empty.masked_psnr, None);
        let summary = ScoreSummary::of(&[scores, empty]);
        assert_eq!(summary.masked_views, 1);
        assert_eq!(summary.views, 2);
    }

    /// Masks are computed from frame t − 5 of the same camera, saved as PNGs, and read back
    /// identically; frames 0–4 have none.
    #[test]
    fn flow_masks_are_cached_in_the_mask_folder() {
        let (w, h) = (64, 48);
        let frame_with_square = |x0: usize| Image {
            width: w,
            height: h,
            data: (0..w * h)
                .map(|i| {
                    let (x, y) = (i % w, i / w);
                    let inside = (x0..x0 + 12).contains(&x) && (18..30).contains(&y);
                    let texture = 0.3 + 0.1 * ((x * 7 + y * 3) % 5) as f32;
                    if inside {
                        [0.9, 0.2, 0.1]
                    } else {
                        [texture; 3]
                    }
                })
                .collect(),
        };
        let mut dataset = Dataset {
            cameras: vec![Camera::look_at(
                glam::Vec3::new(0.0, 0.0, -3.0),
                glam::Vec3::ZERO,
                glam::Vec3::Y,
                w as u32,
                h as u32,
                1.0,
            )],
            frame_count: 7,
            ..Dataset::default()
        };
        for frame in 0..7 {
            dataset
                .test
                .push(view_with(&frame_with_square(10 + 3 * frame), frame));
        }
        let dir = tempfile::tempdir().unwrap();
        let source = MaskSource {
            folder: Some(dir.path().join("masks")),
            compute: true,
            threshold: flow::DEFAULT_FLOW_THRESHOLD,
        };
        let masks = dynamic_masks(&dataset, &source, || {}).unwrap();
        assert!(masks[..5].iter().all(Option::is_none));
        let mask = masks[5].as_ref().expect("frame 5 has a mask");
        // The square at frame 5 spans x 25..37, y 18..30: its centre is dynamic.
        assert!(mask[24 * w + 31]);
        assert!(!mask[2 * w + 2]);
        let cached = MaskSource {
            compute: false,
            ..source.clone()
        };
        let again = dynamic_masks(&dataset, &cached, || {}).unwrap();
        assert_eq!(masks, again);

        // The folder records its threshold; another threshold computes the masks again
        // instead of reusing them (a huge one flags nothing), and the record follows.
        let record = |dir: &Path| -> MaskSettings {
            ron::from_str(&std::fs::read_to_string(dir.join(MASK_SETTINGS_FILE)).unwrap()).unwrap()
        };
        let folder = dir.path().join("masks");
        assert_eq!(record(&folder).flow_threshold, flow::DEFAULT_FLOW_THRESHOLD);
        let strict = MaskSource {
            threshold: 1000.0,
            ..source.clone()
        };
        let recomputed = dynamic_masks(&dataset, &strict, || {}).unwrap();
        assert!(!recomputed[5].as_ref().unwrap().iter().any(|&d| d));
        assert_eq!(record(&folder).flow_threshold, 1000.0);
        // Without a record (masks the user supplied), the PNGs are reused as they are.
        std::fs::remove_file(folder.join(MASK_SETTINGS_FILE)).unwrap();
        let reused = dynamic_masks(&dataset, &source, || {}).unwrap();
        assert_eq!(reused, recomputed);
    }
}
