//! The report's plots, drawn by plotters into RGB buffers and saved as PNG.

use std::ops::Range;
use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf32;
use plotters::prelude::*;

use super::{ReportError, TrainingLog};
use crate::io::image::Image;

const SIZE: (u32, u32) = (960, 360);
const FONT: &str = "sans-serif";
type DrawResult = Result<(), Box<dyn std::error::Error>>;

/// Registers the embedded DejaVu Sans as plotters' "sans-serif" (once per process).
fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        // DejaVu Sans is a valid TrueType font: registration cannot fail on it.
        let _ = plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular());
    });
}

/// Draws with `draw` onto a white `SIZE` canvas and saves it as a PNG at `path`.
fn save_plot(
    path: &Path,
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> DrawResult,
) -> Result<(), ReportError> {
    register_font();
    let (w, h) = SIZE;
    let mut buffer = vec![255u8; (w * h * 3) as usize];
    let result = (|| -> DrawResult {
        let root = BitMapBackend::with_buffer(&mut buffer, SIZE).into_drawing_area();
        root.fill(&WHITE)?;
        draw(&root)?;
        root.present()?;
        Ok(())
    })();
    result.map_err(|e| ReportError::Plot {
        path: path.to_path_buf(),
        message: e.to_string(),
    })?;
    let rgb = image::RgbImage::from_raw(w, h, buffer).expect("buffer of the canvas size");
    Image::from_rgb8(&rgb).save_png(path)?;
    Ok(())
}

/// Moving average over a window of 5 % of the points (1 to 200).
fn smooth(points: &[(f32, f32)]) -> Vec<(f32, f32)> {
    let window = (points.len() / 20).clamp(1, 200);
    let mut sum = 0.0;
    let mut out = Vec::with_capacity(points.len());
    for (i, &(x, y)) in points.iter().enumerate() {
        sum += y;
        if i >= window {
            sum -= points[i - window].1;
        }
        out.push((x, sum / (i + 1).min(window) as f32));
    }
    out
}

/// (min, max) of `values` widened by 5 % (and to a non-empty range).
fn range(values: impl Iterator<Item = f32>) -> (f32, f32) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    if lo > hi {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-3);
    (lo - pad, hi + pad)
}

fn x_range(log: &TrainingLog) -> Range<f32> {
    let last = log.steps.last().map_or(1, |s| s.iteration);
    0.0..last.max(1) as f32
}

type Chart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf32, RangedCoordf32>>;

/// Tick label with as many decimals as a range of `span` needs.
fn tick(value: f32, span: f32) -> String {
    let decimals = (1.0 - span.max(1e-6).log10().floor()).clamp(0.0, 4.0) as usize;
    format!("{value:.decimals$}")
}

/// A titled chart over `x` × `y` with labelled axes and a light grid.
fn chart<'a, 'b>(
    root: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    title: &str,
    (x, y): (Range<f32>, Range<f32>),
    (x_desc, y_desc): (&str, &str),
) -> Result<Chart<'a, 'b>, Box<dyn std::error::Error>> {
    let (x_span, y_span) = (x.end - x.start, y.end - y.start);
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 22))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x, y)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style((FONT, 14))
        .x_label_formatter(&|v| tick(*v, x_span))
        .y_label_formatter(&|v| tick(*v, y_span))
        .light_line_style(RGBColor(238, 238, 238))
        .draw()?;
    Ok(chart)
}

/// The legend of the chart's labelled series.
fn legend<'a, 'b: 'a>(chart: &mut Chart<'a, 'b>, position: SeriesLabelPosition) -> DrawResult {
    chart
        .configure_series_labels()
        .position(position)
        .label_font((FONT, 14))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()?;
    Ok(())
}

/// A line series and its legend entry.
fn line(
    chart: &mut Chart<'_, '_>,
    points: Vec<(f32, f32)>,
    color: RGBColor,
    width: u32,
    label: &str,
) -> DrawResult {
    chart
        .draw_series(LineSeries::new(points, color.stroke_width(width)))?
        .label(label)
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    Ok(())
}

/// Training loss per iteration and its moving average.
pub fn loss(path: &Path, log: &TrainingLog) -> Result<(), ReportError> {
    let raw: Vec<(f32, f32)> = log
        .steps
        .iter()
        .map(|s| (s.iteration as f32, s.loss))
        .collect();
    let (lo, hi) = range(raw.iter().map(|p| p.1));
    save_plot(path, |root| {
        let axes = (x_range(log), lo..hi);
        let mut chart = chart(root, "Training loss", axes, ("iteration", "loss"))?;
        line(
            &mut chart,
            raw.clone(),
            RGBColor(180, 200, 230),
            1,
            "per iteration",
        )?;
        line(
            &mut chart,
            smooth(&raw),
            RGBColor(20, 70, 160),
            2,
            "moving average",
        )?;
        legend(&mut chart, SeriesLabelPosition::UpperRight)
    })
}

/// Training-view PSNR (moving average) and held-out PSNR over iterations.
pub fn psnr(path: &Path, log: &TrainingLog) -> Result<(), ReportError> {
    let train: Vec<(f32, f32)> = log
        .steps
        .iter()
        .filter(|s| s.psnr.is_finite())
        .map(|s| (s.iteration as f32, s.psnr))
        .collect();
    let train = smooth(&train);
    let heldout: Vec<(f32, f32)> = log
        .heldout
        .iter()
        .map(|h| (h.iteration as f32, h.psnr))
        .collect();
    let (lo, hi) = range(train.iter().chain(&heldout).map(|p| p.1));
    save_plot(path, |root| {
        let axes = (x_range(log), lo..hi);
        let mut chart = chart(root, "PSNR", axes, ("iteration", "PSNR (dB)"))?;
        line(
            &mut chart,
            train,
            RGBColor(20, 70, 160),
            2,
            "training views (moving average)",
        )?;
        if !heldout.is_empty() {
            let red = RGBColor(200, 40, 30);
            line(&mut chart, heldout.clone(), red, 1, "held-out views")?;
            chart.draw_series(heldout.iter().map(|&p| Circle::new(p, 4, red.filled())))?;
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight)
    })
}

/// Gaussian count over iterations with the densification steps as dashed vertical lines.
pub fn gaussians(path: &Path, log: &TrainingLog) -> Result<(), ReportError> {
    let counts: Vec<(f32, f32)> = log
        .steps
        .iter()
        .map(|s| (s.iteration as f32, s.gaussians as f32))
        .collect();
    let (_, hi) = range(counts.iter().map(|p| p.1));
    save_plot(path, |root| {
        let axes = (x_range(log), 0.0..hi);
        let mut chart = chart(root, "Gaussians", axes, ("iteration", "Gaussians"))?;
        let orange = RGBColor(230, 120, 30);
        for event in &log.densify {
            let x = event.iteration as f32;
            let style = orange.stroke_width(1);
            chart.draw_series(DashedLineSeries::new([(x, 0.0), (x, hi)], 4, 4, style))?;
        }
        line(&mut chart, counts, RGBColor(30, 120, 60), 2, "Gaussians")?;
        if !log.densify.is_empty() {
            chart
                .draw_series(std::iter::empty::<Circle<(f32, f32), u32>>())?
                .label(format!("densification steps ({})", log.densify.len()))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], orange.stroke_width(1))
                });
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight)
    })
}

/// Held-out PSNR and M-PSNR per frame, with the anchor frames as dashed vertical lines.
pub fn by_frame(
    path: &Path,
    frames: &[super::FrameScores],
    anchors: &[usize],
) -> Result<(), ReportError> {
    let psnr: Vec<(f32, f32)> = frames.iter().map(|f| (f.frame as f32, f.psnr)).collect();
    let masked: Vec<(f32, f32)> = frames
        .iter()
        .filter_map(|f| Some((f.frame as f32, f.masked_psnr?)))
        .collect();
    let (lo, hi) = range(psnr.iter().chain(&masked).map(|p| p.1));
    let last = frames.last().map_or(1, |f| f.frame.max(1)) as f32;
    save_plot(path, |root| {
        let axes = (0.0..last, lo..hi);
        let title = "Held-out scores per frame";
        let mut chart = chart(root, title, axes, ("frame", "dB"))?;
        let orange = RGBColor(230, 120, 30);
        for &anchor in anchors {
            let x = anchor as f32;
            let style = orange.stroke_width(2);
            chart.draw_series(DashedLineSeries::new([(x, lo), (x, hi)], 6, 4, style))?;
        }
        if !anchors.is_empty() {
            chart
                .draw_series(std::iter::empty::<Circle<(f32, f32), u32>>())?
                .label(format!("anchor frames ({})", anchors.len()))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], orange.stroke_width(2))
                });
        }
        line(&mut chart, psnr, RGBColor(20, 70, 160), 2, "PSNR")?;
        if !masked.is_empty() {
            line(
                &mut chart,
                masked,
                RGBColor(200, 40, 30),
                2,
                "M-PSNR (dynamic pixels)",
            )?;
        }
        legend(&mut chart, SeriesLabelPosition::LowerRight)
    })
}

/// Histogram of normalised lifespans in 20 bins over [0, 1].
pub fn lifespans(path: &Path, lifespans: &[f32]) -> Result<(), ReportError> {
    const BINS: usize = 20;
    let mut counts = [0u32; BINS];
    for &l in lifespans {
        let bin = ((l.clamp(0.0, 1.0) * BINS as f32) as usize).min(BINS - 1);
        counts[bin] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1).max(1) as f32 * 1.05;
    save_plot(path, |root| {
        let title = format!("Temporal lifespans of {} Gaussians", lifespans.len());
        let axes = (0.0..1.0, 0.0..top);
        let mut chart = chart(root, &title, axes, ("normalised lifespan ψ̄", "Gaussians"))?;
        let blue = RGBColor(60, 110, 190);
        let width = 1.0 / BINS as f32;
        chart.draw_series(counts.iter().enumerate().map(|(i, &c)| {
            let x0 = i as f32 * width;
            Rectangle::new(
                [(x0 + 0.002, 0.0), (x0 + width - 0.002, c as f32)],
                blue.filled(),
            )
        }))?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Text drawn with the embedded font puts dark pixels on a white canvas (no system font
    /// needed); an unregistered font family would draw nothing.
    #[test]
    fn embedded_font_draws_text() {
        register_font();
        let mut buffer = vec![255u8; 200 * 60 * 3];
        {
            let root = BitMapBackend::with_buffer(&mut buffer, (200, 60)).into_drawing_area();
            root.draw_text(
                "PSNR 24.1 dB",
                &(FONT, 24).into_font().color(&BLACK),
                (5, 15),
            )
            .unwrap();
            root.present().unwrap();
        }
        let dark = buffer.chunks(3).filter(|p| p[0] < 128).count();
        assert!(dark > 100, "only {dark} dark pixels");
    }

    /// The moving average of a constant is that constant, and it follows a step with a lag.
    #[test]
    fn moving_average() {
        let points: Vec<(f32, f32)> = (0..300)
            .map(|i| (i as f32, if i < 150 { 1.0 } else { 3.0 }))
            .collect();
        let s = smooth(&points);
        assert_eq!(s[10].1, 1.0);
        assert_eq!(s[299].1, 3.0);
        assert!(s[151].1 > 1.0 && s[151].1 < 3.0);
    }
}
