//! Error-against-time plots (log-log, one line per method), as PNG and SVG, via `plotters`.
//! Text is drawn with DejaVu Sans embedded in the binary, so no system fonts are needed.

use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;

use crate::atomic::{atomic_write, encode_png_rgb8};
use crate::error::{EvalError, Result};
use crate::metrics::Metric;
use crate::sweep::SweepSeries;

/// Size of the plots, pixels (the SVG uses the same units).
pub const PLOT_SIZE: (u32, u32) = (900, 600);

static FONT: Once = Once::new();

fn register_font() {
    FONT.call_once(|| {
        // DejaVu Sans is a valid TrueType font; registration cannot fail for it.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

/// Writes the error-against-time plot of `series` in `metric` to `png_path` and `svg_path`.
/// Points with non-positive or missing values are left out (log axes).
pub fn plot_error_vs_time(
    series: &[SweepSeries],
    metric: Metric,
    title: &str,
    png_path: &Path,
    svg_path: &Path,
) -> Result<()> {
    plot_series(
        series,
        metric,
        (title, "time per frame (ms)"),
        png_path,
        svg_path,
    )
}

/// [`plot_error_vs_time`] with another quantity on the x axis (the points' `time_ms` field
/// holds it; `x_desc` names it), e.g. the frame number of a sequence.
pub fn plot_series(
    series: &[SweepSeries],
    metric: Metric,
    (title, x_desc): (&str, &str),
    png_path: &Path,
    svg_path: &Path,
) -> Result<()> {
    register_font();
    let curves: Vec<(&str, Vec<(f64, f64)>)> = series
        .iter()
        .map(|s| (s.method.as_str(), s.curve(metric)))
        .filter(|(_, c)| !c.is_empty())
        .collect();
    if curves.is_empty() {
        return Err(EvalError::NotEnoughData(format!(
            "no positive {} values to plot",
            metric.label()
        )));
    }
    let (w, h) = PLOT_SIZE;

    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (w, h)).into_drawing_area();
        draw(&root, &curves, metric, (title, x_desc)).map_err(|reason| EvalError::Draw {
            path: svg_path.to_path_buf(),
            reason,
        })?;
    }
    atomic_write(svg_path, svg.as_bytes())?;

    let mut rgb = vec![255u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
        draw(&root, &curves, metric, (title, x_desc)).map_err(|reason| EvalError::Draw {
            path: png_path.to_path_buf(),
            reason,
        })?;
    }
    atomic_write(
        png_path,
        &encode_png_rgb8(png_path, w as usize, h as usize, &rgb)?,
    )
}

/// Axis range covering `values` with a margin of a quarter decade on each side (log axes).
fn log_range(values: impl Iterator<Item = f64>) -> std::ops::Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    let margin = 10f64.powf(0.25);
    lo / margin..hi * margin
}

fn draw<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    curves: &[(&str, Vec<(f64, f64)>)],
    metric: Metric,
    (title, x_desc): (&str, &str),
) -> std::result::Result<(), String> {
    let e = |err: DrawingAreaErrorKind<DB::ErrorType>| err.to_string();
    root.fill(&WHITE).map_err(e)?;
    let x_range = log_range(curves.iter().flat_map(|(_, c)| c.iter().map(|p| p.0)));
    let y_range = log_range(curves.iter().flat_map(|(_, c)| c.iter().map(|p| p.1)));
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 24))
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(80)
        .build_cartesian_2d(x_range.log_scale(), y_range.log_scale())
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(metric.label())
        .x_label_formatter(&|v| format_tick(*v))
        .y_label_formatter(&|v| format_tick(*v))
        .light_line_style(TRANSPARENT)
        .label_style(("sans-serif", 14))
        .axis_desc_style(("sans-serif", 16))
        .draw()
        .map_err(e)?;
    for (i, (method, curve)) in curves.iter().enumerate() {
        let c = colorous::TABLEAU10[i % colorous::TABLEAU10.len()];
        let color = RGBColor(c.r, c.g, c.b);
        chart
            .draw_series(LineSeries::new(
                curve.iter().copied(),
                color.stroke_width(2),
            ))
            .map_err(e)?
            .label(*method)
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        chart
            .draw_series(curve.iter().map(|&p| Circle::new(p, 4, color.filled())))
            .map_err(e)?;
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(e)?;
    root.present().map_err(e)
}

/// Label of a log-axis tick: only the mantissas 1, 2 and 5 are labelled (plotters puts a tick
/// at every integer mantissa, and neighbours such as 90 and 100 would print over each other);
/// the other ticks keep their grid line without text.
fn format_tick(v: f64) -> String {
    let mantissa = v.abs() / 10f64.powf(v.abs().log10().floor());
    if ![1.0, 2.0, 5.0].iter().any(|m| (mantissa - m).abs() < 1e-6) {
        return String::new();
    }
    if (1e-2..1e4).contains(&v.abs()) {
        format!("{}", (v * 1e3).round() / 1e3)
    } else {
        format!("{v:.0e}")
    }
}

#[cfg(test)]
mod tests {
    use super::format_tick;

    #[test]
    fn log_ticks_are_labelled_at_1_2_5_only() {
        let labels: Vec<String> = [
            10.0, 20.0, 30.0, 50.0, 90.0, 100.0, 200.0, 0.02, 0.07, 5e-5, 3e-5, 1e4,
        ]
        .iter()
        .map(|&v| format_tick(v))
        .collect();
        assert_eq!(
            labels,
            [
                "10", "20", "", "50", "", "100", "200", "0.02", "", "5e-5", "", "1e4"
            ]
        );
    }
}
