//! The run report: an HTML page with PNG plots written at the end of training.
//!
//! `index.html` shows the run's figures, then `loss.png` (training loss over iterations),
//! `psnr.png` (training-view PSNR, smoothed, and held-out PSNR), `gaussians.png` (Gaussian
//! count with the densification steps marked), `lifespans.png` (histogram of the normalised
//! temporal lifespans ψ̄), `frames.png` (held-out PSNR and M-PSNR per frame, anchor frames
//! marked) and, for a few held-out views, `view_N.png`: render | ground truth |
//! error heat-map. Plots are drawn with plotters into RGB buffers; their text uses the
//! DejaVu Sans font embedded in the binary, so no system font is needed.

mod log;
mod plot;

pub use log::{DensifyRecord, HeldoutRecord, StepRecord, TrainingLog};

use std::path::{Path, PathBuf};

use crate::io::image::{Image, ImageError};

/// The report could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// plotters could not draw a plot.
    #[error("drawing {}: {message}", path.display())]
    Plot {
        /// The PNG being drawn.
        path: PathBuf,
        /// plotters' message.
        message: String,
    },
    /// A PNG (a plot or a held-out view strip) could not be saved; the error names the file.
    #[error(transparent)]
    Image(#[from] ImageError),
    /// The report folder could not be created or `index.html` written.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The folder or file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// A held-out view shown in the report.
pub struct ReportView {
    /// Caption, e.g. "camera 5, frame 12: PSNR 24.1 dB".
    pub caption: String,
    /// The rendered view.
    pub render: Image,
    /// The ground-truth image, of the same size.
    pub ground_truth: Image,
}

/// Held-out scores of one frame, averaged over the held-out cameras.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameScores {
    /// Frame index.
    pub frame: usize,
    /// Mean PSNR of the frame's held-out views.
    pub psnr: f32,
    /// Mean M-PSNR of those of its views that have a dynamic mask (`None`: none has).
    pub masked_psnr: Option<f32>,
}

impl FrameScores {
    /// Per-frame means of `(frame, PSNR, M-PSNR)` view scores, in increasing frame order.
    pub fn per_frame(views: impl IntoIterator<Item = (usize, f32, Option<f32>)>) -> Vec<Self> {
        let mut sums = std::collections::BTreeMap::<usize, (f32, u32, f32, u32)>::new();
        for (frame, psnr, masked) in views {
            let sum = sums.entry(frame).or_default();
            sum.0 += psnr;
            sum.1 += 1;
            if let Some(m) = masked.filter(|m| m.is_finite()) {
                sum.2 += m;
                sum.3 += 1;
            }
        }
        sums.into_iter()
            .map(|(frame, (psnr, n, masked, m))| Self {
                frame,
                psnr: psnr / n as f32,
                masked_psnr: (m > 0).then(|| masked / m as f32),
            })
            .collect()
    }
}

/// What the report shows.
pub struct Report<'a> {
    /// Page title and heading (HTML-escaped when written).
    pub title: String,
    /// Figures of the run as (name, value) rows.
    pub figures: Vec<(String, String)>,
    /// The run's history, plotted.
    pub log: &'a TrainingLog,
    /// Normalised lifespan ψ̄ of every Gaussian at the end of training.
    pub lifespans: Vec<f32>,
    /// Held-out views shown as render | ground truth | error strips.
    pub views: Vec<ReportView>,
    /// Held-out scores per frame (empty: no plot).
    pub frames: Vec<FrameScores>,
    /// The anchor frames the Gaussians were initialised at, marked on the per-frame plot.
    pub anchor_frames: Vec<usize>,
}

/// Mean absolute error (over channels) that maps to the top of the heat-map colour scale.
pub const HEATMAP_MAX_ERROR: f32 = 0.25;

impl Report<'_> {
    /// Writes `index.html` and its PNGs into `dir` (created if needed); returns the page's path.
    pub fn write(&self, dir: &Path) -> Result<PathBuf, ReportError> {
        std::fs::create_dir_all(dir).map_err(|source| ReportError::Write {
            path: dir.to_path_buf(),
            source,
        })?;
        let mut sections = Vec::new();
        let log = self.log;
        if !log.steps.is_empty() {
            plot::loss(&dir.join("loss.png"), log)?;
            sections.push(figure(
                "loss.png",
                "Training loss (0.8·L1 + 0.2·D-SSIM) per iteration, with its moving average.",
            ));
            plot::psnr(&dir.join("psnr.png"), log)?;
            sections.push(figure(
                "psnr.png",
                "PSNR of each iteration's render against its training view (moving average) \
                 and of the held-out views where they were evaluated.",
            ));
            plot::gaussians(&dir.join("gaussians.png"), log)?;
            sections.push(figure(
                "gaussians.png",
                "Number of Gaussians; orange dashed lines mark densification steps.",
            ));
        }
        if !self.lifespans.is_empty() {
            plot::lifespans(&dir.join("lifespans.png"), &self.lifespans)?;
            sections.push(figure(
                "lifespans.png",
                "Normalised temporal lifespan ψ̄ of the final Gaussians: the fraction of the \
                 sequence in which σ(t)/σˢ > 0.2.",
            ));
        }
        if self.frames.len() > 1 {
            plot::by_frame(&dir.join("frames.png"), &self.frames, &self.anchor_frames)?;
            sections.push(figure(
                "frames.png",
                "Held-out PSNR and M-PSNR per frame (mean over the held-out cameras); orange \
                 dashed lines mark the anchor frames the Gaussians started at. Scores that dip \
                 half-way between anchors mean the Gaussians' lifespans do not cover the gap.",
            ));
        }
        for (index, view) in self.views.iter().enumerate() {
            let name = format!("view_{index}.png");
            view_strip(view).save_png(&dir.join(&name))?;
            sections.push(figure_wide(
                &name,
                &format!(
                    "{}. Render | ground truth | error (mean absolute error per pixel, black = 0, \
                     yellow ≥ {HEATMAP_MAX_ERROR}).",
                    view.caption
                ),
            ));
        }
        let rows: String = self
            .figures
            .iter()
            .map(|(k, v)| format!("<tr><th>{}</th><td>{}</td></tr>\n", escape(k), escape(v)))
            .collect();
        let html = format!(
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
             <title>{title}</title>\n<style>\n\
             body {{ font-family: sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }}\n\
             table {{ border-collapse: collapse; margin-bottom: 1.5em; }}\n\
             th, td {{ text-align: left; padding: 0.2em 1em 0.2em 0; border-bottom: 1px solid #ddd; }}\n\
             figure {{ margin: 0 0 2em 0; }}\n img {{ max-width: 100%; }}\n\
             img.view {{ width: 100%; image-rendering: pixelated; }}\n\
             figcaption {{ color: #555; }}\n</style>\n</head>\n<body>\n<h1>{title}</h1>\n\
             <table>\n{rows}</table>\n{sections}\n</body>\n</html>\n",
            title = escape(&self.title),
            sections = sections.join("\n"),
        );
        let path = dir.join("index.html");
        crate::io::write_atomic(&path, html.as_bytes()).map_err(|source| ReportError::Write {
            path: path.clone(),
            source,
        })?;
        Ok(path)
    }
}

fn figure(image: &str, caption: &str) -> String {
    format!(
        "<figure><img src=\"{image}\" alt=\"{image}\"><figcaption>{}</figcaption></figure>",
        escape(caption)
    )
}

/// A figure stretched to the page width (small renders are enlarged, pixels kept sharp).
fn figure_wide(image: &str, caption: &str) -> String {
    format!(
        "<figure><img class=\"view\" src=\"{image}\" alt=\"{image}\"><figcaption>{}</figcaption></figure>",
        escape(caption)
    )
}

/// Text safe to put in HTML.
fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Render, ground truth and error heat-map side by side.
pub fn view_strip(view: &ReportView) -> Image {
    let error = error_heatmap(&view.render, &view.ground_truth);
    let parts = [&view.render, &view.ground_truth, &error];
    let width = parts.iter().map(|p| p.width).sum();
    let height = parts.iter().map(|p| p.height).max().unwrap_or(0);
    let mut out = Image::filled(width, height, [1.0; 3]);
    let mut left = 0;
    for part in parts {
        for y in 0..part.height {
            let row = &part.data[y * part.width..(y + 1) * part.width];
            out.data[y * width + left..y * width + left + part.width].copy_from_slice(row);
        }
        left += part.width;
    }
    out
}

/// Per-pixel mean absolute error as a black → red → yellow heat-map, full scale at
/// [`HEATMAP_MAX_ERROR`]. Images of different sizes give the error over their overlap.
pub fn error_heatmap(render: &Image, ground_truth: &Image) -> Image {
    let (width, height) = (
        render.width.min(ground_truth.width),
        render.height.min(ground_truth.height),
    );
    let mut out = Image::filled(width, height, [0.0; 3]);
    for y in 0..height {
        for x in 0..width {
            let (a, b) = (render.get(x, y), ground_truth.get(x, y));
            let error = (0..3).map(|c| (a[c] - b[c]).abs()).sum::<f32>() / 3.0;
            out.data[y * width + x] = heat((error / HEATMAP_MAX_ERROR).clamp(0.0, 1.0));
        }
    }
    out
}

/// Colour of `v` in [0, 1]: black, dark red, orange, yellow.
fn heat(v: f32) -> [f32; 3] {
    const STOPS: [[f32; 3]; 4] = [
        [0.0, 0.0, 0.0],
        [0.55, 0.05, 0.1],
        [0.95, 0.45, 0.05],
        [1.0, 1.0, 0.3],
    ];
    let t = v * (STOPS.len() - 1) as f32;
    let i = (t.floor() as usize).min(STOPS.len() - 2);
    let f = t - i as f32;
    std::array::from_fn(|c| STOPS[i][c] * (1.0 - f) + STOPS[i + 1][c] * f)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Views are averaged per frame, in frame order; M-PSNR only over the views that have
    /// one (a frame with none has none).
    #[test]
    fn frame_scores_average_each_frame() {
        let frames = FrameScores::per_frame([
            (3, 20.0, Some(10.0)),
            (1, 30.0, None),
            (3, 24.0, None),
            (3, 22.0, Some(14.0)),
            (1, 32.0, None),
        ]);
        assert_eq!(
            frames,
            [
                FrameScores {
                    frame: 1,
                    psnr: 31.0,
                    masked_psnr: None
                },
                FrameScores {
                    frame: 3,
                    psnr: 22.0,
                    masked_psnr: Some(12.0)
                },
            ]
        );
    }

    /// The report with per-frame scores writes `frames.png` and shows it on the page.
    #[test]
    fn report_plots_scores_per_frame() {
        let dir = tempfile::tempdir().unwrap();
        let log = TrainingLog::default();
        let report = Report {
            title: "t".into(),
            figures: Vec::new(),
            log: &log,
            lifespans: Vec::new(),
            views: Vec::new(),
            frames: FrameScores::per_frame(
                (0..40).map(|f| (f, 25.0 + (f % 20) as f32 * 0.1, Some(20.0))),
            ),
            anchor_frames: vec![0, 20, 39],
        };
        let page = std::fs::read_to_string(report.write(dir.path()).unwrap()).unwrap();
        assert!(page.contains("frames.png"));
        let image = image::open(dir.path().join("frames.png")).unwrap();
        assert!(image.width() > 100 && image.height() > 100);
    }

    /// The heat-map is black where render and truth agree and yellow at full-scale error.
    #[test]
    fn heatmap_scale_ends() {
        let a = Image::filled(2, 1, [0.5; 3]);
        let mut b = a.clone();
        b.data[1] = [0.5 + HEATMAP_MAX_ERROR; 3];
        let map = error_heatmap(&a, &b);
        assert_eq!(map.data[0], [0.0; 3]);
        assert_eq!(map.data[1], [1.0, 1.0, 0.3]);
    }
}
