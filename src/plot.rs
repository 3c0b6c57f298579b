//! Plots (plotters): panels of curves, log-log or linear, written as SVG and PNG.
//!
//! Text in PNGs is drawn with DejaVu Sans (the `dejavu` crate), registered once, so that
//! no system font is needed; SVGs name the font family and leave drawing to the viewer.

use crate::io::write_atomically;
use crate::io::Image;
use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;
use std::path::Path;

/// One curve: a label and its points (x, y).
#[derive(Clone, Debug)]
pub struct Curve {
    /// Legend label.
    pub label: String,
    /// Points (x, y); non-finite ones (and non-positive ones on log axes) are left out.
    pub points: Vec<(f64, f64)>,
}

/// Axis scales of a panel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scale {
    /// Both axes logarithmic.
    LogLog,
    /// Both axes linear.
    Linear,
}

/// One panel: a title, axis labels and curves.
#[derive(Clone, Debug)]
pub struct Panel {
    /// Title.
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// Axis scales.
    pub scale: Scale,
    /// Curves with their colour index (a method keeps its colour across panels when it
    /// keeps its index).
    pub curves: Vec<(usize, Curve)>,
}

fn register_font() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // The bytes are a valid TrueType font shipped by the crate.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

fn bounds(values: impl Iterator<Item = f64>, log: bool) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite() && (!log || *v > 0.0))
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    match (lo <= hi, log) {
        (false, true) => (1e-3, 1.0),
        (false, false) => (0.0, 1.0),
        (true, true) => (lo / 2.0, hi * 2.0),
        (true, false) => {
            let pad = 0.05 * (hi - lo).max(1e-12 * hi.abs().max(1.0));
            (lo - pad, hi + pad)
        }
    }
}

/// Draws `panels` in a grid of `cols` columns as `stem.svg` and `stem.png`.
pub fn write_panels(
    stem: &Path,
    panels: &[Panel],
    cols: usize,
    panel_size: (u32, u32),
) -> Result<(), String> {
    register_font();
    let rows = panels.len().div_ceil(cols.max(1)).max(1);
    let size = (panel_size.0 * cols as u32, panel_size.1 * rows as u32);
    let svg_path = stem.with_extension("svg");
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        draw_all(&root, panels, rows, cols)?;
        root.present().map_err(|e| e.to_string())?;
    }
    write_atomically(&svg_path, |w| w.write_all(svg.as_bytes()))
        .map_err(|e| format!("{}: {e}", svg_path.display()))?;
    let mut image = Image::new(size.0, size.1);
    {
        let root = BitMapBackend::with_buffer(&mut image.rgb, size).into_drawing_area();
        draw_all(&root, panels, rows, cols)?;
        root.present().map_err(|e| e.to_string())?;
    }
    let png_path = stem.with_extension("png");
    write_atomically(&png_path, |w| crate::io::write_png(w, &image))
        .map_err(|e| format!("{}: {e}", png_path.display()))
}

fn draw_all<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    panels: &[Panel],
    rows: usize,
    cols: usize,
) -> Result<(), String> {
    root.fill(&WHITE).map_err(|e| e.to_string())?;
    for (area, panel) in root.split_evenly((rows, cols)).iter().zip(panels) {
        let log = panel.scale == Scale::LogLog;
        let pts = |f: fn(&(f64, f64)) -> f64| {
            bounds(
                panel
                    .curves
                    .iter()
                    .flat_map(move |(_, c)| c.points.iter().map(f)),
                log,
            )
        };
        let (xs, ys) = (pts(|p| p.0), pts(|p| p.1));
        if log {
            draw_panel(
                area,
                panel,
                (xs.0..xs.1).log_scale(),
                (ys.0..ys.1).log_scale(),
                |v| format!("{v:.0e}"),
            )?;
        } else {
            draw_panel(area, panel, xs.0..xs.1, ys.0..ys.1, linear_tick)?;
        }
    }
    Ok(())
}

/// A linear-axis tick label: up to 4 significant digits without trailing zeros, in
/// exponent form when very large or small.
fn linear_tick(v: &f64) -> String {
    let a = v.abs();
    if a == 0.0 {
        return "0".into();
    }
    if !(1e-3..1e5).contains(&a) {
        return format!("{v:.2e}");
    }
    let decimals = (3 - a.log10().floor() as i32).clamp(0, 6) as usize;
    let s = format!("{v:.decimals$}");
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        s
    }
}

fn draw_panel<DB, X, Y>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    panel: &Panel,
    x: X,
    y: Y,
    label: fn(&f64) -> String,
) -> Result<(), String>
where
    DB: DrawingBackend,
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let log = panel.scale == Scale::LogLog;
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 16))
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(64)
        .build_cartesian_2d(x, y)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .x_label_formatter(&label)
        .y_label_formatter(&label)
        .draw()
        .map_err(|e| e.to_string())?;
    for (colour, curve) in &panel.curves {
        let pts: Vec<(f64, f64)> = curve
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite() && (!log || (*x > 0.0 && *y > 0.0)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let colour = *colour;
        chart
            .draw_series(LineSeries::new(
                pts.clone(),
                Palette99::pick(colour).stroke_width(2),
            ))
            .map_err(|e| e.to_string())?
            .label(curve.label.as_str())
            .legend(move |(x, y)| {
                PathElement::new(
                    vec![(x, y), (x + 16, y)],
                    Palette99::pick(colour).stroke_width(2),
                )
            });
        if log || pts.len() <= 40 {
            chart
                .draw_series(
                    pts.iter()
                        .map(|&p| Circle::new(p, 3, Palette99::pick(colour).filled())),
                )
                .map_err(|e| e.to_string())?;
        }
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 11))
        .position(if log {
            SeriesLabelPosition::LowerLeft
        } else {
            SeriesLabelPosition::UpperRight
        })
        .draw()
        .map_err(|e| e.to_string())
}
