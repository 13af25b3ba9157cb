//! # odocal-report — pictures of a calibration a person can judge
//!
//! A calibration is deployed by a person who has to decide whether the new
//! parameters are better than the old ones. [`render_html`] writes one
//! self-contained HTML page (inline SVG, no scripts, no network fetches):
//!
//! 1. the verdict and its reasons, then the parameter table (θ_0,
//!    calibrated, 1σ or "held", truth when known) and the method's own
//!    account of the fit (EIV: noise model, σ widening, result);
//! 2. Ē_p of θ_0 and of the calibrated θ (and of the truth);
//! 3. the drive as a map: the reference, and dead reckoning with θ_0 and
//!    with the calibrated θ on a few validation segments;
//! 4. E_p,s per validation segment for θ_0 and the calibrated θ;
//! 5. the spread of the step-1 estimates θ_B,I (3-step method);
//! 6. residual time series: the one-step heading residual and the
//!    dead-reckoning position error along the validation segments;
//! 7. the warnings.
//!
//! [`plots`] holds the small SVG figure kit that the experiment figures use
//! too (plotters with its SVG backend only).
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use odocal::{drive::segment, sim, Theta};
//! use odocal_report::{render_html, ParamRow, ReportInput};
//! let out = sim::simulate(&sim::SimOptions { length_km: 2.0, ..sim::SimOptions::paper(3) })?;
//! let segs = segment::validation_segments(&out.drive, &Default::default())?;
//! let truth = out.sidecar.theta_true;
//! let input = ReportInput {
//!     params: ParamRow::theta_rows(&Theta::PAPER_INITIAL, &truth, None, Some(&truth)),
//!     ..ReportInput::new("demo", &out.drive, &segs, Theta::PAPER_INITIAL, truth)
//! };
//! let html = render_html(&input)?;
//! assert!(html.contains("<section id=\"map\">") && html.contains("<svg"));
//! # Ok(()) }
//! ```

pub mod plots;

use std::fmt::Write as _;

use odocal::assess::position_error::segment_position_error;
use odocal::drive::segment::{Segment, SegmentData};
use odocal::model::{step, Theta, THETA_NAMES};
use odocal::Drive;

use crate::plots::{figure_svg, Panel, Series};

/// Errors of the report renderer.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// A figure could not be drawn.
    #[error("report figure: {0}")]
    Draw(String),
    /// Writing the report failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// The input cannot be shown (no validation segments, say).
    #[error("report: {0}")]
    Input(String),
}

/// The renderer's result type.
pub type Result<T, E = ReportError> = std::result::Result<T, E>;

/// One row of the parameter table.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamRow {
    /// Parameter name (`c_e`, …).
    pub name: String,
    /// Display unit (`m`, `mm`, `mm/(m/s²)`, `rad`, …).
    pub unit: String,
    /// SI value × `scale` = value in the display unit.
    pub scale: f64,
    /// Initial value, SI.
    pub initial: f64,
    /// Calibrated value, SI.
    pub calibrated: f64,
    /// 1σ, SI; `None` when the parameter was held.
    pub sigma: Option<f64>,
    /// The truth, SI, when known.
    pub truth: Option<f64>,
}

impl ParamRow {
    /// Rows for the four θ entries in their usual display units (c_d in mm,
    /// d in mm per m/s²). `sigma[i] = None` marks a held parameter.
    pub fn theta_rows(
        initial: &Theta,
        calibrated: &Theta,
        sigma: Option<[Option<f64>; 4]>,
        truth: Option<&Theta>,
    ) -> Vec<ParamRow> {
        let units = [("m", 1.0), ("mm", 1e3), ("m", 1.0), ("mm/(m/s²)", 1e3)];
        (0..4)
            .map(|i| ParamRow {
                name: THETA_NAMES[i].to_string(),
                unit: units[i].0.to_string(),
                scale: units[i].1,
                initial: initial.to_array()[i],
                calibrated: calibrated.to_array()[i],
                sigma: sigma.and_then(|s| s[i]),
                truth: truth.map(|t| t.to_array()[i]),
            })
            .collect()
    }
}

impl ParamRow {
    /// Rows for the reference extrinsics (lever arm in m, heading offset in
    /// mrad); held entries have no σ.
    pub fn extrinsics_rows(x: &odocal::ExtrinsicsEstimate) -> Vec<ParamRow> {
        let (init, val, sd) = (x.initial.to_array(), x.value.to_array(), x.std_dev.to_array());
        odocal::Param::EXTRINSICS
            .into_iter()
            .enumerate()
            .map(|(i, p)| {
                let (unit, scale) = if i == 2 { ("mrad", 1e3) } else { ("m", 1.0) };
                ParamRow {
                    name: p.name().to_string(),
                    unit: unit.to_string(),
                    scale,
                    initial: init[i],
                    calibrated: val[i],
                    sigma: x.free.contains(p).then_some(sd[i]),
                    truth: None,
                }
            })
            .collect()
    }
}

/// Everything the HTML report shows. Build with [`ReportInput::new`] and
/// fill in what is known.
#[derive(Debug, Clone)]
pub struct ReportInput<'a> {
    /// Page title (the input file, usually).
    pub title: String,
    /// Key–value lines shown under the title: method, odocal version, date, input…
    pub provenance: Vec<(String, String)>,
    /// The verdict (`accepted`, `doubtful`, `rejected`) and its reasons.
    pub verdict: Option<(String, Vec<String>)>,
    /// The parameter table.
    pub params: Vec<ParamRow>,
    /// The drive.
    pub drive: &'a Drive,
    /// The validation segments.
    pub validation_segments: &'a [Segment],
    /// The initial θ_0.
    pub theta0: Theta,
    /// The calibrated θ.
    pub theta: Theta,
    /// The true θ, when known (simulated drives).
    pub truth: Option<Theta>,
    /// Step-1 estimates θ_B,I with their Ē_p (3-step method); empty otherwise.
    pub batches: Vec<(Theta, f64)>,
    /// Warnings, one per line.
    pub warnings: Vec<String>,
    /// The method's own account of the fit, one line each (for EIV: the
    /// filter, the noise model at the start and as estimated, how far the
    /// estimated noise levels widened θ's σ, and whether the result is the
    /// EIV estimate or the batch G-N fallback). Shown as text under the
    /// parameter table; the section is left out when empty.
    pub method_details: Vec<String>,
    /// How many validation segments the map shows (default 4).
    pub map_segments: usize,
}

impl<'a> ReportInput<'a> {
    /// The minimal input: a title, the drive and its validation segments, θ_0
    /// and the calibrated θ.
    pub fn new(
        title: impl Into<String>,
        drive: &'a Drive,
        validation_segments: &'a [Segment],
        theta0: Theta,
        theta: Theta,
    ) -> Self {
        ReportInput {
            title: title.into(),
            provenance: Vec::new(),
            verdict: None,
            params: ParamRow::theta_rows(&theta0, &theta, None, None),
            drive,
            validation_segments,
            theta0,
            theta,
            truth: None,
            batches: Vec::new(),
            warnings: Vec::new(),
            method_details: Vec::new(),
            map_segments: 4,
        }
    }
}

/// Escapes text for HTML.
fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            c => o.push(c),
        }
    }
    o
}

/// Dead reckoning of one segment from its reference start pose: (x, y) per sample.
fn dead_reckoning(seg: &SegmentData<'_>, theta: &Theta) -> Vec<(f64, f64)> {
    let mut x = seg.reference(0);
    let mut out = Vec::with_capacity(seg.steps() + 1);
    out.push((x[0], x[1]));
    for k in 0..seg.steps() {
        x = step(&x, &seg.input(k), theta, seg.sample_time_s);
        out.push((x[0], x[1]));
    }
    out
}

/// Thins a polyline to at most `max` points (keeps the last).
fn thin(points: Vec<(f64, f64)>, max: usize) -> Vec<(f64, f64)> {
    if points.len() <= max || max < 2 {
        return points;
    }
    let stride = points.len().div_ceil(max - 1);
    let last = points.last().copied();
    let mut out: Vec<(f64, f64)> = points.into_iter().step_by(stride).collect();
    if let Some(l) = last {
        if out.last() != Some(&l) {
            out.push(l);
        }
    }
    out
}

/// Renders the self-contained HTML report.
///
/// # Errors
/// [`ReportError::Input`] without validation segments; [`ReportError::Draw`]
/// when a figure fails.
pub fn render_html(r: &ReportInput<'_>) -> Result<String> {
    let drive = r.drive;
    if r.validation_segments.is_empty() {
        return Err(ReportError::Input("no validation segments to show".into()));
    }
    let segs: Vec<SegmentData<'_>> = r.validation_segments.iter().map(|s| SegmentData::new(drive, s)).collect();
    let e0: Vec<f64> = segs.iter().map(|s| segment_position_error(s, &r.theta0)).collect();
    let e1: Vec<f64> = segs.iter().map(|s| segment_position_error(s, &r.theta)).collect();
    let et: Option<Vec<f64>> = r.truth.map(|t| segs.iter().map(|s| segment_position_error(s, &t)).collect());
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;

    let mut h = String::new();
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\"/>\n<title>odocal — {}</title>\n<style>\n{}\n</style>\n</head>\n<body>\n",
        esc(&r.title),
        CSS
    );
    let _ = writeln!(h, "<h1>odocal calibration — {}</h1>", esc(&r.title));
    if !r.provenance.is_empty() {
        h.push_str("<p class=\"prov\">");
        let items: Vec<String> = r.provenance.iter().map(|(k, v)| format!("{}: <b>{}</b>", esc(k), esc(v))).collect();
        h.push_str(&items.join(" · "));
        h.push_str("</p>\n");
    }

    // 1. Verdict and parameters.
    h.push_str("<section id=\"verdict\">\n<h2>Verdict</h2>\n");
    match &r.verdict {
        Some((level, reasons)) => {
            let _ = writeln!(h, "<p class=\"verdict {0}\">{0}</p>", esc(level));
            if !reasons.is_empty() {
                h.push_str("<ul>\n");
                for reason in reasons {
                    let _ = writeln!(h, "<li>{}</li>", esc(reason));
                }
                h.push_str("</ul>\n");
            }
        }
        None => h.push_str("<p class=\"verdict none\">no verdict given</p>\n"),
    }
    h.push_str("</section>\n<section id=\"parameters\">\n<h2>Parameters</h2>\n<table>\n<tr><th>parameter</th><th>unit</th><th>initial</th><th>calibrated</th><th>± 1σ</th>");
    let has_truth = r.params.iter().any(|p| p.truth.is_some());
    if has_truth {
        h.push_str("<th>truth</th><th>error</th>");
    }
    h.push_str("</tr>\n");
    for p in &r.params {
        let f = |v: f64| format!("{:.6}", v * p.scale);
        let sigma = p.sigma.map(f).unwrap_or_else(|| "held".into());
        let _ = write!(
            h,
            "<tr><td>{}</td><td>{}</td><td>{}</td><td><b>{}</b></td><td>{}</td>",
            esc(&p.name),
            esc(&p.unit),
            f(p.initial),
            f(p.calibrated),
            sigma
        );
        if has_truth {
            match p.truth {
                Some(t) => {
                    let _ = write!(h, "<td>{}</td><td>{:+.6}</td>", f(t), (p.calibrated - t) * p.scale);
                }
                None => h.push_str("<td></td><td></td>"),
            }
        }
        h.push_str("</tr>\n");
    }
    h.push_str("</table>\n</section>\n");
    if !r.method_details.is_empty() {
        h.push_str("<section id=\"method\">\n<h2>Method details</h2>\n<pre>");
        for line in &r.method_details {
            let _ = writeln!(h, "{}", esc(line));
        }
        h.push_str("</pre>\n</section>\n");
    }

    // 2. Ē_p.
    h.push_str("<section id=\"validation\">\n<h2>Validation: mean position error Ē_p</h2>\n<table>\n");
    let _ = writeln!(h, "<tr><th>θ</th><th>Ē_p (m)</th><th>segments</th></tr>");
    let _ = writeln!(h, "<tr><td>θ_0 (initial)</td><td>{:.3}</td><td>{}</td></tr>", mean(&e0), e0.len());
    let _ = writeln!(h, "<tr><td>calibrated</td><td><b>{:.3}</b></td><td>{}</td></tr>", mean(&e1), e1.len());
    if let Some(et) = &et {
        let _ = writeln!(h, "<tr><td>truth</td><td>{:.3}</td><td>{}</td></tr>", mean(et), et.len());
    }
    let better = e1.iter().zip(&e0).filter(|(a, b)| a < b).count();
    let _ = writeln!(
        h,
        "</table>\n<p>The calibrated θ dead-reckons better than θ_0 on {better} of {} validation segments.</p>",
        e0.len()
    );
    // 4. per segment (drawn here, next to the numbers).
    let idx = |v: &[f64]| v.iter().enumerate().map(|(i, &e)| (i as f64, e)).collect::<Vec<_>>();
    let mut series =
        vec![Series::points("θ_0", idx(&e0), plots::ORANGE), Series::points("calibrated", idx(&e1), plots::BLUE)];
    if let Some(et) = &et {
        series.push(Series::points("truth", idx(et), plots::GREEN));
    }
    let panel = Panel {
        title: "E_p,s per validation segment".into(),
        x_label: "validation segment".into(),
        y_label: "E_p,s (m)".into(),
        series,
        y_range: plots::robust_range(&[e0.clone(), e1.clone()].concat(), &[0.0]),
        ..Default::default()
    };
    h.push_str(&figure_svg("Dead-reckoning error per validation segment", (900, 380), (1, 1), &[panel])?);
    h.push_str("</section>\n");

    // 3. Map.
    h.push_str("<section id=\"map\">\n<h2>The drive</h2>\n");
    let mut map_series = Vec::new();
    for p in drive.parts() {
        let pts: Vec<(f64, f64)> = (p.start..p.end).map(|i| (drive.px()[i], drive.py()[i])).collect();
        map_series.push(Series::line(
            if map_series.is_empty() { "reference" } else { "" },
            thin(pts, 4000),
            plots::GREY,
        ));
    }
    // The segments shown: the ones where θ_0 was worst, up to map_segments.
    let mut order: Vec<usize> = (0..segs.len()).collect();
    order.sort_by(|&a, &b| e0[b].total_cmp(&e0[a]));
    order.truncate(r.map_segments.max(1));
    order.sort_unstable();
    for (j, &i) in order.iter().enumerate() {
        let first = j == 0;
        map_series.push(Series::line(
            if first { "dead reckoning θ_0" } else { "" },
            thin(dead_reckoning(&segs[i], &r.theta0), 1500),
            plots::ORANGE,
        ));
        map_series.push(Series::line(
            if first { "dead reckoning calibrated" } else { "" },
            thin(dead_reckoning(&segs[i], &r.theta), 1500),
            plots::BLUE,
        ));
    }
    let map = Panel {
        title: format!("reference and dead reckoning on the {} validation segments where θ_0 is worst", order.len()),
        x_label: "x (m)".into(),
        y_label: "y (m)".into(),
        series: map_series,
        equal_aspect: true,
        ..Default::default()
    };
    h.push_str(&figure_svg("Map", (900, 700), (1, 1), &[map])?);
    let _ = writeln!(
        h,
        "<p>Segments shown (start time, s): {}.</p>\n</section>",
        order
            .iter()
            .map(|&i| format!("{:.1}", drive.t()[r.validation_segments[i].start]))
            .collect::<Vec<_>>()
            .join(", ")
    );

    // 5. Step-1 spread.
    if !r.batches.is_empty() {
        h.push_str("<section id=\"batches\">\n<h2>Step-1 estimates θ_B,I</h2>\n");
        let units = [("c_e (m)", 1.0), ("c_d (mm)", 1e3), ("t_r (m)", 1.0), ("d (mm/(m/s²))", 1e3)];
        let panels: Vec<Panel> = (0..4)
            .map(|i| {
                let pts: Vec<(f64, f64)> = r.batches.iter().map(|(t, e)| (*e, t.to_array()[i] * units[i].1)).collect();
                let ys: Vec<f64> = pts.iter().map(|p| p.1).collect();
                let mut hlines = vec![plots::HLine {
                    name: "calibrated".into(),
                    y: r.theta.to_array()[i] * units[i].1,
                    color: plots::RED,
                }];
                if let Some(t) = r.truth {
                    hlines.push(plots::HLine {
                        name: "truth".into(),
                        y: t.to_array()[i] * units[i].1,
                        color: plots::GREEN,
                    });
                }
                let always: Vec<f64> = hlines.iter().map(|l| l.y).collect();
                Panel {
                    title: units[i].0.split(' ').next().unwrap_or("").to_string(),
                    x_label: "Ē_p of the batch estimate (m)".into(),
                    y_label: units[i].0.into(),
                    y_range: plots::robust_range(&ys, &always),
                    series: vec![Series::points("θ_B,I", pts, plots::BLUE)],
                    hlines,
                    ..Default::default()
                }
            })
            .collect();
        h.push_str(&figure_svg("Spread of the step-1 batch estimates", (900, 640), (2, 2), &panels)?);
        h.push_str("</section>\n");
    }

    // 6. Residuals.
    h.push_str("<section id=\"residuals\">\n<h2>Residuals</h2>\n");
    let ts = drive.sample_time_s();
    let mut heading = Vec::new();
    let mut heading0 = Vec::new();
    for p in drive.parts() {
        for i in p.start..p.end.saturating_sub(1) {
            let x = drive.pose(i);
            let u = drive.input(i);
            let r1 = drive.psi()[i + 1] - step(&x, &u, &r.theta, ts)[2];
            let r0 = drive.psi()[i + 1] - step(&x, &u, &r.theta0, ts)[2];
            heading.push((drive.t()[i], r1 / ts));
            heading0.push((drive.t()[i], r0 / ts));
        }
    }
    // Means over 5 s make a systematic yaw-rate error visible above the wheel noise.
    let smooth = |v: &[(f64, f64)]| -> Vec<(f64, f64)> {
        let w = ((5.0 / ts).round() as usize).max(1);
        v.chunks(w).map(|c| (c[0].0, c.iter().map(|p| p.1).sum::<f64>() / c.len() as f64)).collect()
    };
    let (hs, hs0) = (smooth(&heading), smooth(&heading0));
    let ys: Vec<f64> = hs.iter().chain(&hs0).map(|p| p.1).collect();
    let p1 = Panel {
        title: "yaw-rate residual: reference − model one step ahead (5 s means)".into(),
        x_label: "t (s)".into(),
        y_label: "rad/s".into(),
        y_range: plots::robust_range(&ys, &[0.0]),
        series: vec![Series::line("θ_0", hs0, plots::ORANGE), Series::line("calibrated", hs, plots::BLUE)],
        ..Default::default()
    };
    let mut pos_series = Vec::new();
    let mut ys = Vec::new();
    for (j, (s, seg)) in r.validation_segments.iter().zip(&segs).enumerate() {
        let (a, b) = (dead_reckoning(seg, &r.theta0), dead_reckoning(seg, &r.theta));
        let err_of = |d: &[(f64, f64)]| -> Vec<(f64, f64)> {
            d.iter()
                .enumerate()
                .map(|(k, p)| (drive.t()[s.start + k], (seg.px[k] - p.0).hypot(seg.py[k] - p.1)))
                .collect()
        };
        let (e_a, e_b) = (err_of(&a), err_of(&b));
        ys.extend(e_a.iter().chain(&e_b).map(|p| p.1));
        pos_series.push(Series::line(if j == 0 { "θ_0" } else { "" }, thin(e_a, 200), plots::ORANGE));
        pos_series.push(Series::line(if j == 0 { "calibrated" } else { "" }, thin(e_b, 200), plots::BLUE));
    }
    let p2 = Panel {
        title: "dead-reckoning position error along each validation segment".into(),
        x_label: "t (s)".into(),
        y_label: "m".into(),
        y_range: Some((0.0, 1.05 * ys.iter().copied().filter(|v| v.is_finite()).fold(1e-3, f64::max))),
        series: pos_series,
        ..Default::default()
    };
    h.push_str(&figure_svg("Residuals over the drive", (900, 640), (2, 1), &[p1, p2])?);
    h.push_str("</section>\n");

    // 7. Warnings.
    h.push_str("<section id=\"warnings\">\n<h2>Warnings</h2>\n");
    if r.warnings.is_empty() {
        h.push_str("<p>none</p>\n");
    } else {
        h.push_str("<ul>\n");
        for w in &r.warnings {
            let _ = writeln!(h, "<li>{}</li>", esc(w));
        }
        h.push_str("</ul>\n");
    }
    h.push_str("</section>\n</body>\n</html>\n");
    Ok(h)
}

/// Renders the report and writes it to `path`.
///
/// # Errors
/// As [`render_html`], and [`ReportError::Io`].
pub fn write_html(path: &std::path::Path, r: &ReportInput<'_>) -> Result<()> {
    let html = render_html(r)?;
    std::fs::write(path, html).map_err(|source| ReportError::Io { path: path.to_path_buf(), source })
}

const CSS: &str = "body{font-family:sans-serif;max-width:960px;margin:2em auto;color:#222;line-height:1.4}\
h1{font-size:1.5em}h2{font-size:1.2em;border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}\
table{border-collapse:collapse;margin:.5em 0}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:right}\
td:first-child,th:first-child{text-align:left}.prov{color:#555;font-size:.9em}\
.verdict{display:inline-block;padding:.3em .9em;border-radius:.3em;font-weight:bold;font-size:1.2em;text-transform:uppercase}\
.accepted{background:#d4f4dd;color:#0a5c2b}.doubtful{background:#fff2cc;color:#7a5a00}.rejected{background:#fadbd8;color:#8a1c12}\
.none{background:#eee;color:#555}svg{max-width:100%;height:auto;display:block;margin:.5em 0}\
pre{white-space:pre-wrap;font-size:.85em;background:#f7f7f7;padding:.5em}";

#[cfg(test)]
mod tests {
    use super::*;
    use odocal::{drive::segment, sim};

    fn parse_all(xml: &str) {
        let mut r = quick_xml::Reader::from_str(xml);
        loop {
            match r.read_event() {
                Ok(quick_xml::events::Event::Eof) => break,
                Ok(_) => {}
                Err(e) => panic!("not well-formed at {}: {e}", r.buffer_position()),
            }
        }
    }

    #[test]
    fn report_is_well_formed_and_complete() {
        let out = sim::simulate(&sim::SimOptions { length_km: 2.0, ..sim::SimOptions::paper(5) }).expect("sim");
        let segs = segment::validation_segments(&out.drive, &Default::default()).expect("segments");
        let truth = out.sidecar.theta_true;
        let th0 = Theta::PAPER_INITIAL;
        let input = ReportInput {
            params: ParamRow::theta_rows(&th0, &truth, Some([Some(1e-4), None, Some(1e-3), Some(1e-5)]), Some(&truth)),
            verdict: Some(("accepted".into(), vec!["Ē_p 10 m < θ_0's 28 m <&>".into()])),
            truth: Some(truth),
            batches: vec![(th0, 20.0), (truth, 10.0)],
            warnings: vec!["a <warning>".into()],
            method_details: vec!["EIV: 1 window(s)".into(), "  noise, estimated: σ_white <1 %>".into()],
            ..ReportInput::new("sim <2 km>", &out.drive, &segs, th0, truth)
        };
        let html = render_html(&input).expect("render");
        assert!(
            html.contains("<pre>EIV: 1 window(s)\n  noise, estimated: σ_white &lt;1 %&gt;\n</pre>"),
            "method details"
        );
        let plain = render_html(&ReportInput { method_details: Vec::new(), ..input.clone() }).expect("render");
        assert!(!plain.contains("<section id=\"method\">"), "no details, no section");
        for id in ["verdict", "parameters", "method", "validation", "map", "batches", "residuals", "warnings"] {
            assert!(html.contains(&format!("<section id=\"{id}\">")), "section {id}");
        }
        assert!(html.contains("<td>held</td>"));
        assert!(html.contains("&lt;warning&gt;") && !html.contains("<warning>"));
        assert!(!html.contains("<script"), "no scripts");
        assert!(!html.contains("src=\"http") && !html.contains("href=\"http"), "no network fetches");
        // Well-formed as XML (the page is XHTML-compatible), SVGs included.
        let body = html.trim_start_matches("<!DOCTYPE html>\n");
        parse_all(body);
        assert!(html.matches("<svg").count() >= 4);
    }

    #[test]
    fn no_segments_is_an_error() {
        let out = sim::simulate(&sim::SimOptions { length_km: 1.0, ..sim::SimOptions::noise_free(1) }).expect("sim");
        let input = ReportInput::new("x", &out.drive, &[], Theta::PAPER_INITIAL, Theta::PAPER_INITIAL);
        assert!(matches!(render_html(&input), Err(ReportError::Input(_))));
    }
}
