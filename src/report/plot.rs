//! The report's plots, drawn by plotters into RGB buffers and saved as PNG.

use std::path::Path;
use std::sync::Once;

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
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, plotters::coord::Shift>) -> DrawResult,
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

/// Moving average over a window of about 1 % of the points (at least 1).
fn smooth(points: &[(f32, f32)]) -> Vec<(f32, f32)> {
    let window = (points.len() / 100).max(1);
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

fn x_range(log: &TrainingLog) -> std::ops::Range<f32> {
    let last = log.steps.last().map_or(1, |s| s.iteration);
    0.0..last.max(1) as f32
}

/// A line series and its legend entry.
fn line<'a, DB: DrawingBackend + 'a>(
    chart: &mut ChartContext<
        'a,
        DB,
        Cartesian2d<plotters::coord::types::RangedCoordf32, plotters::coord::types::RangedCoordf32>,
    >,
    points: Vec<(f32, f32)>,
    color: RGBColor,
    width: u32,
    label: &str,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
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
        let mut chart = ChartBuilder::on(root)
            .caption("Training loss", (FONT, 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x_range(log), lo..hi)?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("loss")
            .label_style((FONT, 14))
            .draw()?;
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
        chart
            .configure_series_labels()
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
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
        let mut chart = ChartBuilder::on(root)
            .caption("PSNR", (FONT, 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(x_range(log), lo..hi)?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("PSNR (dB)")
            .label_style((FONT, 14))
            .draw()?;
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
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
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
        let mut chart = ChartBuilder::on(root)
            .caption("Gaussians", (FONT, 22))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(x_range(log), 0.0..hi)?;
        chart
            .configure_mesh()
            .x_desc("iteration")
            .y_desc("Gaussians")
            .label_style((FONT, 14))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        let grey = RGBColor(150, 150, 150);
        for event in &log.densify {
            let x = event.iteration as f32;
            chart.draw_series(DashedLineSeries::new(
                [(x, 0.0), (x, hi)],
                4,
                4,
                grey.stroke_width(1),
            ))?;
        }
        line(&mut chart, counts, RGBColor(30, 120, 60), 2, "Gaussians")?;
        if !log.densify.is_empty() {
            chart
                .draw_series(std::iter::empty::<Circle<(f32, f32), u32>>())?
                .label(format!("densification steps ({})", log.densify.len()))
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], grey.stroke_width(1))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .label_font((FONT, 14))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()?;
        Ok(())
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
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!("Temporal lifespans of {} Gaussians", lifespans.len()),
                (FONT, 22),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(0.0f32..1.0f32, 0.0..top)?;
        chart
            .configure_mesh()
            .x_desc("normalised lifespan ψ̄")
            .y_desc("Gaussians")
            .label_style((FONT, 14))
            .y_label_formatter(&|v| format!("{v:.0}"))
            .draw()?;
        let blue = RGBColor(60, 110, 190);
        chart.draw_series(counts.iter().enumerate().map(|(i, &c)| {
            let x0 = i as f32 / BINS as f32;
            Rectangle::new(
                [
                    (x0 + 0.002, 0.0),
                    (x0 + 1.0 / BINS as f32 - 0.002, c as f32),
                ],
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
