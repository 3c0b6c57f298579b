//! Plots (plotters): panels of curves, log-log or linear, written as SVG and PNG.
//!
//! Every curve has its colour (eight that stay apart on white and for the common colour
//! blindnesses: Okabe and Ito's set, with black, grey and brown for its yellow and sky
//! blue) and its marker (circle, square, triangle, diamond, cross) by its index, so that
//! two methods never look alike; a dashed curve (a prediction) is drawn before the solid
//! ones, thinner and without markers, so that measurements lie on top. The legend sits
//! beside the plot, never over the data. Log axes label whole decades, and 2 and 5 times
//! them when the range spans at most three decades, as plain decimals between 0.001 and
//! 10000.
//!
//! Text in PNGs is drawn with DejaVu Sans (the `dejavu` crate), registered once, so that
//! no system font is needed; SVGs name the font family and leave drawing to the viewer.

use crate::io::write_atomically;
use crate::io::Image;
use plotters::coord::ranged1d::{AsRangedCoord, Ranged, ValueFormatter};
use plotters::prelude::*;
use std::path::Path;

/// One curve: a label and its points (x, y).
#[derive(Clone, Debug, Default)]
pub struct Curve {
    /// Legend label.
    pub label: String,
    /// Points (x, y); non-finite ones (and non-positive ones on log axes) are left out.
    pub points: Vec<(f64, f64)>,
    /// Dashed, thin and without markers: a prediction or reference beside measurements.
    pub dashed: bool,
}

/// The colours curves take by index: Okabe and Ito's palette (2008) with black, grey and
/// brown in place of its yellow and sky blue, which fade on white.
const COLOURS: [RGBColor; 8] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
    RGBColor(0, 0, 0),
    RGBColor(110, 110, 110),
    RGBColor(140, 70, 20),
];

fn colour(i: usize) -> RGBColor {
    COLOURS[i % COLOURS.len()]
}

/// Marker shapes by index.
const MARKERS: usize = 5;

/// Runs `$body` with `$m` bound to a function from a position to the marker element of
/// curve `$i` there (radius `$r` pixels, style `$style`): one expansion per shape, since
/// each shape is a type of its own.
macro_rules! with_marker {
    ($i:expr, $r:expr, $style:expr, |$m:ident| $body:expr) => {{
        let (r, style): (i32, ShapeStyle) = ($r, $style);
        match ($i / COLOURS.len() + $i) % MARKERS {
            0 => {
                let $m = |p| EmptyElement::at(p) + Circle::new((0, 0), r, style);
                $body
            }
            1 => {
                let $m = |p| EmptyElement::at(p) + Rectangle::new([(-r, -r), (r, r)], style);
                $body
            }
            2 => {
                let $m = |p| {
                    EmptyElement::at(p)
                        + Polygon::new(vec![(0, -r - 1), (-r - 1, r), (r + 1, r)], style)
                };
                $body
            }
            3 => {
                let $m = |p| {
                    EmptyElement::at(p)
                        + Polygon::new(
                            vec![(0, -r - 1), (r + 1, 0), (0, r + 1), (-r - 1, 0)],
                            style,
                        )
                };
                $body
            }
            _ => {
                let s = style.stroke_width(2);
                let $m = |p| {
                    EmptyElement::at(p)
                        + PathElement::new(vec![(-r, -r), (r, r)], s)
                        + PathElement::new(vec![(-r, r), (r, -r)], s)
                };
                $body
            }
        }
    }};
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
    // Each panel is as wide as asked plus its legend beside it.
    let legend = panels.iter().map(legend_width).max().unwrap_or(0);
    let size = (
        (panel_size.0 + legend) * cols as u32,
        panel_size.1 * rows as u32,
    );
    let svg_path = stem.with_extension("svg");
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        draw_all(&root, panels, rows, cols, legend)?;
        root.present().map_err(|e| e.to_string())?;
    }
    write_atomically(&svg_path, |w| w.write_all(svg.as_bytes()))
        .map_err(|e| format!("{}: {e}", svg_path.display()))?;
    let mut image = Image::new(size.0, size.1);
    {
        let root = BitMapBackend::with_buffer(&mut image.rgb, size).into_drawing_area();
        draw_all(&root, panels, rows, cols, legend)?;
        root.present().map_err(|e| e.to_string())?;
    }
    let png_path = stem.with_extension("png");
    write_atomically(&png_path, |w| crate::io::write_png(w, &image))
        .map_err(|e| format!("{}: {e}", png_path.display()))
}

/// The width of a panel's legend (pixels): as long as its longest label needs.
fn legend_width(panel: &Panel) -> u32 {
    let font = ("sans-serif", 11).into_font();
    let longest = panel
        .curves
        .iter()
        .map(|(_, c)| {
            // Measured with the registered font; about 6 pixels a character if not.
            font.box_size(&c.label)
                .map_or(6 * c.label.chars().count() as u32, |(w, _)| w)
        })
        .max();
    longest.map_or(0, |w| 48 + w)
}

fn draw_all<DB: DrawingBackend>(
    root: &DrawingArea<DB, plotters::coord::Shift>,
    panels: &[Panel],
    rows: usize,
    cols: usize,
    legend_w: u32,
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
        let width = area.dim_in_pixel().0;
        let (plot, legend) = area.split_horizontally(width.saturating_sub(legend_w));
        if log {
            let plain = |v: &f64| plain(*v);
            draw_panel(
                &plot,
                panel,
                (xs.0..xs.1).log_scale().with_key_points(log_ticks(xs)),
                (ys.0..ys.1).log_scale().with_key_points(log_ticks(ys)),
                &plain,
            )?;
        } else {
            draw_panel(&plot, panel, xs.0..xs.1, ys.0..ys.1, &linear_tick)?;
        }
        draw_legend(&legend, panel)?;
    }
    Ok(())
}

/// The ticks of a log axis over `(lo, hi)`: whole decades, and 2 and 5 times them when
/// the range spans at most three decades (every digit when that leaves fewer than two,
/// the two ends when even that does).
fn log_ticks((lo, hi): (f64, f64)) -> Vec<f64> {
    let (first, last) = (lo.log10().floor() as i32, hi.log10().ceil() as i32);
    let ticks = |mantissas: &[f64]| -> Vec<f64> {
        (first..=last)
            .flat_map(|e| mantissas.iter().map(move |m| m * 10f64.powi(e)))
            .filter(|v| (lo..=hi).contains(v))
            .collect()
    };
    let decades = (hi / lo).log10();
    let mut t = if decades > 3.0 {
        ticks(&[1.0])
    } else {
        ticks(&[1.0, 2.0, 5.0])
    };
    if t.len() < 2 {
        t = ticks(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0]);
    }
    if t.len() < 2 {
        // Within one digit step: the ends, to two significant digits, inside the range.
        let step = |v: f64| 10f64.powi(v.log10().floor() as i32 - 1);
        t = vec![
            (lo / step(lo)).ceil() * step(lo),
            (hi / step(hi)).floor() * step(hi),
        ];
    }
    t
}

/// `v` as a plain decimal between 0.001 and 10000, else in exponent form (`2e-5`).
fn plain(v: f64) -> String {
    if (1e-3..1e4).contains(&v.abs()) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

/// A linear-axis tick label: [`crate::io::human`].
fn linear_tick(v: &f64) -> String {
    // Ticks stepped from a range's start land a rounding error off zero (-2.8e-17).
    if v.abs() < 1e-12 {
        return "0".into();
    }
    crate::io::human(*v)
}

/// The panel's curves: dashed ones first (thin, no markers), then the others with their
/// markers on top.
fn draw_panel<DB, X, Y>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    panel: &Panel,
    x: X,
    y: Y,
    tick: &dyn Fn(&f64) -> String,
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
    // Log axes bring their own ticks (`log_ticks`); no finer grid lines.
    chart
        .configure_mesh()
        .x_desc(panel.x_label.as_str())
        .y_desc(panel.y_label.as_str())
        .x_labels(if log { 40 } else { 8 })
        .y_labels(if log { 40 } else { 8 })
        .light_line_style(WHITE)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick)
        .draw()
        .map_err(|e| e.to_string())?;
    let mut order: Vec<&(usize, Curve)> = panel.curves.iter().collect();
    order.sort_by_key(|(_, c)| !c.dashed);
    for (index, curve) in order {
        let pts: Vec<(f64, f64)> = curve
            .points
            .iter()
            .copied()
            .filter(|(x, y)| x.is_finite() && y.is_finite() && (!log || (*x > 0.0 && *y > 0.0)))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let c = colour(*index);
        if curve.dashed {
            chart
                .draw_series(DashedLineSeries::new(pts, 6, 4, c.stroke_width(1)))
                .map_err(|e| e.to_string())?;
            continue;
        }
        chart
            .draw_series(LineSeries::new(pts.clone(), c.stroke_width(2)))
            .map_err(|e| e.to_string())?;
        if log || pts.len() <= 40 {
            with_marker!(*index, 4, c.filled(), |m| {
                chart
                    .draw_series(pts.iter().map(|&p| m(p)))
                    .map_err(|e| e.to_string())?;
            });
        }
    }
    Ok(())
}

/// The legend of `panel` in its own area beside the plot: a sample of each curve's line
/// and marker, and its label, one row each.
fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    panel: &Panel,
) -> Result<(), String> {
    let font = ("sans-serif", 11).into_font().color(&BLACK);
    let e = |e: DrawingAreaErrorKind<DB::ErrorType>| e.to_string();
    for (row, (index, curve)) in panel.curves.iter().enumerate() {
        let y = 44 + 18 * row as i32;
        let c = colour(*index);
        if curve.dashed {
            area.draw(&PathElement::new(vec![(4, y), (11, y)], c.stroke_width(1)))
                .map_err(e)?;
            area.draw(&PathElement::new(vec![(17, y), (26, y)], c.stroke_width(1)))
                .map_err(e)?;
        } else {
            area.draw(&PathElement::new(vec![(4, y), (28, y)], c.stroke_width(2)))
                .map_err(e)?;
            with_marker!(*index, 4, c.filled(), |m| {
                area.draw(&m((16, y))).map_err(e)?;
            });
        }
        area.draw(&Text::new(curve.label.as_str(), (34, y - 6), font.clone()))
            .map_err(e)?;
    }
    Ok(())
}

/// A perceptually ordered dark-to-light colour map (black, purple, red, orange, pale
/// yellow, after matplotlib's "inferno"), `t` in [0, 1].
fn heat(t: f64) -> RGBColor {
    const STOPS: [(f64, [f64; 3]); 5] = [
        (0.0, [0.0, 0.0, 4.0]),
        (0.25, [87.0, 16.0, 110.0]),
        (0.5, [188.0, 55.0, 84.0]),
        (0.75, [249.0, 142.0, 9.0]),
        (1.0, [252.0, 255.0, 164.0]),
    ];
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        0.0
    };
    let k = STOPS.iter().position(|s| s.0 >= t).unwrap_or(4).max(1);
    let ((t0, a), (t1, b)) = (STOPS[k - 1], STOPS[k]);
    let u = (t - t0) / (t1 - t0);
    let c = |i: usize| (a[i] + u * (b[i] - a[i])).round() as u8;
    RGBColor(c(0), c(1), c(2))
}

/// Dynamic range of a spectrogram (dB below its loudest cell).
pub const SPECTROGRAM_RANGE_DB: f64 = 80.0;

/// Writes the spectrogram of `samples` (at `rate` Hz) as a PNG: short-time Fourier
/// transforms (Hann window of 4,096 samples, one per pixel column), magnitude in dB over
/// [`SPECTROGRAM_RANGE_DB`] below the loudest cell, time across and frequency up to a
/// little above the highest component within that range (each pixel row shows the
/// loudest bin it covers, so narrow modal peaks stay visible), with a colour bar.
pub fn write_spectrogram(
    path: &Path,
    samples: &[f64],
    rate: u32,
    title: &str,
) -> Result<(), String> {
    use rustfft::num_complex::Complex;
    register_font();
    let rate_f = rate as f64;
    let (w, h) = (900u32, 460u32);
    // One transform per pixel column of the plot area (the width less the axis labels,
    // margins and the colour bar).
    let cols = 900 - 64 - 90 - 16;
    let win = 4096usize;
    let fft = rustfft::FftPlanner::<f64>::new().plan_fft_forward(win);
    let hann: Vec<f64> = (0..win)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / win as f64).cos())
        .collect();
    let duration = samples.len() as f64 / rate_f;
    let bins = win / 2 + 1;
    let mut power = vec![0.0f64; cols * bins];
    let mut buf = vec![Complex::new(0.0, 0.0); win];
    for c in 0..cols {
        let centre = ((c as f64 + 0.5) / cols as f64 * samples.len() as f64) as isize;
        for (i, z) in buf.iter_mut().enumerate() {
            let k = centre - (win / 2) as isize + i as isize;
            let x = if k >= 0 && (k as usize) < samples.len() {
                samples[k as usize]
            } else {
                0.0
            };
            *z = Complex::new(x * hann[i], 0.0);
        }
        fft.process(&mut buf);
        for b in 0..bins {
            power[c * bins + b] = buf[b].norm_sqr();
        }
    }
    let db = |p: f64| 10.0 * p.max(1e-300).log10();
    let top = power.iter().fold(0.0f64, |a, &b| a.max(b));
    let top_db = db(top);
    let floor_db = top_db - SPECTROGRAM_RANGE_DB;
    // The highest bin within range, plus 15%, rounded up to a nice number of Hz.
    let highest = (0..bins)
        .rev()
        .find(|&b| (0..cols).any(|c| db(power[c * bins + b]) > floor_db + 10.0))
        .unwrap_or(bins - 1);
    let f_hi = (highest as f64 * rate_f / win as f64 * 1.15).max(100.0);
    let step = 10f64.powf(f_hi.log10().floor()) / 2.0;
    let f_max = ((f_hi / step).ceil() * step).min(rate_f / 2.0);
    let mut image = Image::new(w, h);
    {
        let root = BitMapBackend::with_buffer(&mut image.rgb, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let (main, bar) = root.split_horizontally(w - 90);
        let mut chart = ChartBuilder::on(&main)
            .caption(title, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(0.0..duration.max(1e-9), 0.0..f_max / 1000.0)
            .map_err(|e| e.to_string())?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("time (s)")
            .y_desc("frequency (kHz)")
            .label_style(("sans-serif", 12))
            .axis_desc_style(("sans-serif", 13))
            .x_label_formatter(&linear_tick)
            .y_label_formatter(&linear_tick)
            .draw()
            .map_err(|e| e.to_string())?;
        let (px, py) = chart.plotting_area().get_pixel_range();
        let (pw, ph) = ((px.end - px.start) as usize, (py.end - py.start) as usize);
        for x in 0..pw {
            let c = (x * cols / pw.max(1)).min(cols - 1);
            for y in 0..ph {
                // Row y covers frequencies [f0, f1) (top row: the highest).
                let f1 = f_max * (ph - y) as f64 / ph as f64;
                let f0 = f_max * (ph - y - 1) as f64 / ph as f64;
                let b0 = ((f0 * win as f64 / rate_f).round() as usize).min(bins - 1);
                let b1 = ((f1 * win as f64 / rate_f).round() as usize).clamp(b0 + 1, bins);
                let p = power[c * bins + b0..c * bins + b1]
                    .iter()
                    .fold(0.0f64, |a, &b| a.max(b));
                let t = (db(p) - floor_db) / SPECTROGRAM_RANGE_DB;
                root.draw_pixel((px.start + x as i32, py.start + y as i32), &heat(t))
                    .map_err(|e| e.to_string())?;
            }
        }
        // The colour bar: dB below the loudest cell.
        let mut bar_chart = ChartBuilder::on(&bar)
            .margin_top(38)
            .margin_bottom(48)
            .margin_right(8)
            .y_label_area_size(44)
            .build_cartesian_2d(0.0..1.0, -SPECTROGRAM_RANGE_DB..0.0)
            .map_err(|e| e.to_string())?;
        bar_chart
            .configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc("dB")
            .y_labels(5)
            .y_label_style(("sans-serif", 12))
            .axis_desc_style(("sans-serif", 13))
            .y_label_formatter(&linear_tick)
            .draw()
            .map_err(|e| e.to_string())?;
        let n = 160;
        bar_chart
            .draw_series((0..n).map(|k| {
                let lo = -SPECTROGRAM_RANGE_DB + SPECTROGRAM_RANGE_DB * k as f64 / n as f64;
                let hi = lo + SPECTROGRAM_RANGE_DB / n as f64;
                Rectangle::new([(0.0, lo), (1.0, hi)], heat(k as f64 / n as f64).filled())
            }))
            .map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    write_atomically(path, |w| crate::io::write_png(w, &image))
        .map_err(|e| format!("{}: {e}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn log_ticks_are_decades_or_1_2_5_and_plain_decimals() {
        assert_eq!(log_ticks((0.004, 0.12)), vec![0.005, 0.01, 0.02, 0.05, 0.1]);
        assert_eq!(log_ticks((1e-9, 1e-1)).len(), 9);
        // Less than one decade still gets at least two ticks.
        let narrow = log_ticks((0.212, 0.287));
        assert_eq!(narrow.len(), 2);
        assert!((narrow[0] - 0.22).abs() < 1e-12 && (narrow[1] - 0.28).abs() < 1e-12);
        assert_eq!(log_ticks((2.0, 9.5)), vec![2.0, 5.0]);
        assert_eq!(plain(0.005), "0.005");
        assert_eq!(plain(20.0), "20");
        assert_eq!(plain(1e-5), "1e-5");
        assert_eq!(linear_tick(&0.25), "0.25");
        assert_eq!(linear_tick(&1500.0), "1500");
    }
}
