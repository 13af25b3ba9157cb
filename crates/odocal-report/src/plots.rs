//! Small SVG figures (plotters, SVG backend): a grid of x-y panels, each with
//! titled axes, several series and horizontal reference lines, and a legend
//! (series with an empty name stay out of it).

use std::path::Path;

use plotters::prelude::*;

use crate::{ReportError, Result};

fn anyhow_like(msg: String) -> ReportError {
    ReportError::Draw(msg)
}

/// How a series is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A polyline.
    Line,
    /// Dots.
    Points,
}

/// One named series of a panel.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend entry.
    pub name: String,
    /// Data, (x, y); non-finite points are skipped.
    pub points: Vec<(f64, f64)>,
    /// Line or dots.
    pub kind: Kind,
    /// Colour.
    pub color: RGBColor,
}

impl Series {
    /// A polyline series.
    pub fn line(name: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Series { name: name.into(), points, kind: Kind::Line, color }
    }
    /// A dot series.
    pub fn points(name: impl Into<String>, points: Vec<(f64, f64)>, color: RGBColor) -> Self {
        Series { name: name.into(), points, kind: Kind::Points, color }
    }
}

/// A horizontal reference line across a panel.
#[derive(Debug, Clone)]
pub struct HLine {
    /// Legend entry.
    pub name: String,
    /// Height.
    pub y: f64,
    /// Colour.
    pub color: RGBColor,
}

/// One x-y panel.
#[derive(Debug, Clone, Default)]
pub struct Panel {
    /// Panel caption.
    pub title: String,
    /// x-axis label with unit.
    pub x_label: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// The data.
    pub series: Vec<Series>,
    /// Reference lines.
    pub hlines: Vec<HLine>,
    /// Fixed y range; points outside are left out and counted in the caption.
    pub y_range: Option<(f64, f64)>,
    /// Same scale on both axes (a map).
    pub equal_aspect: bool,
    /// Text at data points `(x, y)` (e.g. numbers naming a map's segments);
    /// those outside the panel are left out.
    pub labels: Vec<(f64, f64, String)>,
}

/// Colours used throughout (colour-blind friendly Okabe-Ito palette): blue.
pub const BLUE: RGBColor = RGBColor(0, 114, 178);
/// Orange.
pub const ORANGE: RGBColor = RGBColor(230, 159, 0);
/// Green.
pub const GREEN: RGBColor = RGBColor(0, 158, 115);
/// Red.
pub const RED: RGBColor = RGBColor(213, 94, 0);
/// Grey.
pub const GREY: RGBColor = RGBColor(90, 90, 90);

/// Widens a degenerate or reversed range and pads it by 5 %.
fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    let (lo, hi) = if hi > lo { (lo, hi) } else { (lo - 0.5 * lo.abs().max(1e-9), hi + 0.5 * hi.abs().max(1e-9)) };
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// A y range holding the central 90 % of `values` (and `always`), padded —
/// for scatter plots where a few wild estimates would hide the rest.
pub fn robust_range(values: &[f64], always: &[f64]) -> Option<(f64, f64)> {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    let (mut lo, mut hi) = (q(0.05), q(0.95));
    for a in always.iter().filter(|a| a.is_finite()) {
        lo = lo.min(*a);
        hi = hi.max(*a);
    }
    let w = (hi - lo).max(1e-12);
    Some((lo - 0.1 * w, hi + 0.1 * w))
}

/// Tick-label formatter with enough decimals for a range of width `w`.
fn decimals(w: f64) -> usize {
    if !(w.is_finite() && w > 0.0) {
        return 3;
    }
    (1.0 - w.log10().floor()).clamp(0.0, 8.0) as usize
}

/// Widens one of the ranges so that a metre is as long on both axes of the
/// plotting area (label areas taken off).
fn equal_aspect<DB: DrawingBackend>(
    area: &DrawingArea<DB, plotters::coord::Shift>,
    (x_lo, x_hi): (f64, f64),
    (y_lo, y_hi): (f64, f64),
) -> (f64, f64, f64, f64) {
    let (w, h) = area.dim_in_pixel();
    let (w, h) = ((w as f64 - 80.0).max(10.0), (h as f64 - 70.0).max(10.0));
    let (sx, sy) = ((x_hi - x_lo) / w, (y_hi - y_lo) / h);
    if sx > sy {
        let mid = (y_lo + y_hi) / 2.0;
        (x_lo, x_hi, mid - sx * h / 2.0, mid + sx * h / 2.0)
    } else {
        let mid = (x_lo + x_hi) / 2.0;
        (mid - sy * w / 2.0, mid + sy * w / 2.0, y_lo, y_hi)
    }
}

fn draw_panel<DB: DrawingBackend>(area: &DrawingArea<DB, plotters::coord::Shift>, p: &Panel) -> Result<()>
where
    DB::ErrorType: 'static,
{
    let finite = |&(x, y): &(f64, f64)| x.is_finite() && y.is_finite();
    let all: Vec<(f64, f64)> = p.series.iter().flat_map(|s| s.points.iter().copied()).filter(finite).collect();
    let (x_lo, x_hi) = padded(
        all.iter().map(|q| q.0).fold(f64::INFINITY, f64::min),
        all.iter().map(|q| q.0).fold(f64::NEG_INFINITY, f64::max),
    );
    let (y_lo, y_hi) = match p.y_range {
        Some(r) => r,
        None => padded(
            all.iter().map(|q| q.1).chain(p.hlines.iter().map(|h| h.y)).fold(f64::INFINITY, f64::min),
            all.iter().map(|q| q.1).chain(p.hlines.iter().map(|h| h.y)).fold(f64::NEG_INFINITY, f64::max),
        ),
    };
    let (x_lo, x_hi, y_lo, y_hi) =
        if p.equal_aspect { equal_aspect(area, (x_lo, x_hi), (y_lo, y_hi)) } else { (x_lo, x_hi, y_lo, y_hi) };
    let inside = |&(x, y): &(f64, f64)| finite(&(x, y)) && y >= y_lo && y <= y_hi;
    let hidden = all.len() - all.iter().filter(|q| inside(q)).count();
    let title = match hidden {
        0 => p.title.clone(),
        1 => format!("{} (1 point off scale)", p.title),
        n => format!("{} ({n} points off scale)", p.title),
    };
    let err = |e: DrawingAreaErrorKind<DB::ErrorType>| anyhow_like(format!("drawing '{}': {e:?}", p.title));
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 18))
        .margin(8)
        .x_label_area_size(38)
        .y_label_area_size(62)
        .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)
        .map_err(err)?;
    let (dx, dy) = (decimals(x_hi - x_lo), decimals(y_hi - y_lo));
    let fx = move |v: &f64| format!("{v:.dx$}");
    let fy = move |v: &f64| format!("{v:.dy$}");
    chart
        .configure_mesh()
        .x_desc(p.x_label.as_str())
        .y_desc(p.y_label.as_str())
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .label_style(("sans-serif", 13))
        .draw()
        .map_err(err)?;
    for h in &p.hlines {
        let c = h.color;
        chart
            .draw_series(LineSeries::new(vec![(x_lo, h.y), (x_hi, h.y)], c.stroke_width(1)))
            .map_err(err)?
            .label(h.name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(1)));
    }
    for s in &p.series {
        let c = s.color;
        let pts: Vec<(f64, f64)> = s.points.iter().copied().filter(inside).collect();
        match s.kind {
            Kind::Line => {
                let drawn = chart.draw_series(LineSeries::new(pts, c.stroke_width(2))).map_err(err)?;
                if !s.name.is_empty() {
                    drawn
                        .label(s.name.as_str())
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], c.stroke_width(2)));
                }
            }
            Kind::Points => {
                let drawn = chart.draw_series(pts.into_iter().map(|q| Circle::new(q, 3, c.filled()))).map_err(err)?;
                if !s.name.is_empty() {
                    drawn.label(s.name.as_str()).legend(move |(x, y)| Circle::new((x + 8, y), 3, c.filled()));
                }
            }
        }
    }
    let shown = p.labels.iter().filter(|(x, y, _)| (x_lo..=x_hi).contains(x) && (y_lo..=y_hi).contains(y));
    chart
        .draw_series(shown.map(|(x, y, text)| {
            Text::new(text.clone(), (*x, *y), ("sans-serif", 20).into_font().style(FontStyle::Bold))
        }))
        .map_err(err)?;
    // The legend goes into the corner that covers the fewest points.
    let in_corner = |left: bool, top: bool| {
        all.iter()
            .filter(|q| inside(q))
            .filter(|&&(x, y)| {
                let fx = (x - x_lo) / (x_hi - x_lo);
                let fy = (y - y_lo) / (y_hi - y_lo);
                (if left { fx < 0.4 } else { fx > 0.6 }) && (if top { fy > 0.6 } else { fy < 0.4 })
            })
            .count()
    };
    let corners = [
        (in_corner(false, true), SeriesLabelPosition::UpperRight),
        (in_corner(true, true), SeriesLabelPosition::UpperLeft),
        (in_corner(false, false), SeriesLabelPosition::LowerRight),
        (in_corner(true, false), SeriesLabelPosition::LowerLeft),
    ];
    let position = corners.into_iter().min_by_key(|c| c.0).map(|c| c.1).unwrap_or(SeriesLabelPosition::UpperRight);
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font(("sans-serif", 13))
        .draw()
        .map_err(err)?;
    Ok(())
}

/// Draws the panels (row-major in a `grid`) under a title on an SVG area;
/// `what` names the figure in errors.
fn draw_figure(
    root: DrawingArea<SVGBackend<'_>, plotters::coord::Shift>,
    what: &str,
    title: &str,
    grid: (usize, usize),
    panels: &[Panel],
) -> Result<()> {
    let err = |e: DrawingAreaErrorKind<std::io::Error>| anyhow_like(format!("{what}: {e:?}"));
    root.fill(&WHITE).map_err(err)?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(err)?;
    for (area, p) in root.split_evenly(grid).iter().zip(panels) {
        draw_panel(area, p)?;
    }
    root.present().map_err(err)
}

/// An SVG figure of `rows × cols` panels (row-major) under a title, as a
/// string (for inline use in HTML).
pub fn figure_svg(title: &str, size: (u32, u32), grid: (usize, usize), panels: &[Panel]) -> Result<String> {
    let mut out = String::new();
    draw_figure(
        SVGBackend::with_string(&mut out, size).into_drawing_area(),
        &format!("'{title}'"),
        title,
        grid,
        panels,
    )?;
    Ok(out)
}

/// Writes an SVG figure of `rows × cols` panels (row-major) under a title,
/// atomically ([`odocal::output::write_text`]).
pub fn figure(path: &Path, title: &str, size: (u32, u32), grid: (usize, usize), panels: &[Panel]) -> Result<()> {
    let mut svg = String::new();
    draw_figure(
        SVGBackend::with_string(&mut svg, size).into_drawing_area(),
        &path.display().to_string(),
        title,
        grid,
        panels,
    )?;
    odocal::output::write_text(path, &svg).map_err(crate::write_error)
}
