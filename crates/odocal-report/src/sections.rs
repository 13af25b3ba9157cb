//! The sections of the HTML report, each appended to the page in turn.

use std::fmt::Write as _;

use odocal::model::{step, Input, State, THETA_NAMES};
use odocal::segment::SegmentData;

use crate::plots::{self, figure_svg, Panel, Series};
use crate::{dead_reckoning, esc, thin, ReportInput, Result, CSS};

/// E_p,s of each validation segment for θ_0, the calibrated θ and the
/// truth, each with the reference extrinsics the library's validation gives
/// that row, so that their means are the text's and the JSON's Ē_p bit for
/// bit (each segment's [`ReportInput::segment_extrinsics`], the `initial`
/// and `validation` Ē_p): θ with the calibrated extrinsics, θ_0 with those
/// the calibration started from — except that on a validation drive whose
/// heading offset is re-estimated, each of θ and θ_0 takes the one fitted
/// on that drive for it (JSON `validate_on.drives[].extrinsics.value` and
/// `.initial`), so that both are judged at their best heading offset; the
/// truth with the true mount ([`ReportInput::truth_extrinsics`]). The truth does not take θ's
/// extrinsics: an estimated heading offset also absorbs the reference's
/// heading error on this drive, and lending it to the truth would score
/// the truth with part of the calibration's result.
pub(crate) struct SegmentErrors {
    /// θ_0's.
    pub initial: Vec<f64>,
    /// The calibrated θ's.
    pub calibrated: Vec<f64>,
    /// The truth's, when known.
    pub truth: Option<Vec<f64>>,
}

impl SegmentErrors {
    pub fn new(r: &ReportInput<'_>, segs: &[SegmentData<'_>]) -> Self {
        let each = |theta: &odocal::Theta, extrinsics: &dyn Fn(usize) -> odocal::Extrinsics| -> Vec<f64> {
            let error = |(i, s): (usize, &SegmentData<'_>)| odocal::dead_reckoning(s, theta, &extrinsics(i)).0;
            segs.iter().enumerate().map(error).collect()
        };
        SegmentErrors {
            initial: each(&r.theta0, &|i| r.extrinsics_of(i)[0]),
            calibrated: each(&r.theta, &|i| r.extrinsics_of(i)[1]),
            truth: r.truth.map(|t| each(&t, &|_| r.truth_extrinsics)),
        }
    }
}

/// The document head, the title and the provenance line.
pub(crate) fn head(h: &mut String, r: &ReportInput<'_>) {
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
}

/// `items` as an HTML list, escaped (nothing when there are none).
fn list(h: &mut String, items: &[String]) {
    if items.is_empty() {
        return;
    }
    h.push_str("<ul>\n");
    for item in items {
        let _ = writeln!(h, "<li>{}</li>", esc(item));
    }
    h.push_str("</ul>\n");
}

/// Section 1: the verdict and its reasons.
pub(crate) fn verdict(h: &mut String, r: &ReportInput<'_>) {
    h.push_str("<section id=\"verdict\">\n<h2>Verdict</h2>\n");
    match &r.verdict {
        Some((level, reasons)) => {
            let _ = writeln!(h, "<p class=\"verdict {0}\">{0}</p>", esc(level));
            list(h, reasons);
        }
        None => h.push_str("<p class=\"verdict none\">no verdict given</p>\n"),
    }
    h.push_str("</section>\n");
}

/// Section 1: the parameter table, then the method's own account of the fit.
pub(crate) fn parameters(h: &mut String, r: &ReportInput<'_>) {
    let _ = write!(
        h,
        "<section id=\"parameters\">\n<h2>Parameters</h2>\n<table>\n<tr><th>parameter</th><th>unit</th>\
         <th>initial</th><th>calibrated</th><th>{}</th>",
        esc(&r.sigma_label)
    );
    let has_truth = r.params.iter().any(|p| p.truth.is_some());
    if has_truth {
        h.push_str("<th>truth</th><th>error</th>");
    }
    if r.eiv_unused.is_some() {
        h.push_str("<th>EIV (unused)</th>");
    }
    h.push_str("</tr>\n");
    let mut label = &r.sigma_label;
    for p in &r.params {
        // Rows whose σ is of another kind (the reference extrinsics') under a heading of their own.
        if let Some(l) = p.sigma_label.as_ref().filter(|l| *l != label) {
            let _ = writeln!(h, "<tr><th colspan=\"4\">reference extrinsics</th><th>{}</th></tr>", esc(l));
            label = l;
        }
        let f = |v: f64| format!("{:.6}", v * p.scale);
        // "held" only for a parameter that did not move.
        let mut sigma = match p.sigma {
            Some(v) => f(v),
            None if p.calibrated.to_bits() == p.initial.to_bits() => "held".into(),
            None => "–".into(),
        };
        if p.not_observable {
            sigma.push_str(" (not observable)");
        }
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
        if let Some(e) = &r.eiv_unused {
            // θ's rows only (the reference extrinsics have no EIV value).
            match THETA_NAMES.iter().position(|n| *n == p.name) {
                Some(i) => {
                    let _ = write!(h, "<td>{}</td>", f(<[f64; 4]>::from(e)[i]));
                }
                None => h.push_str("<td></td>"),
            }
        }
        h.push_str("</tr>\n");
    }
    h.push_str("</table>\n");
    // The text report's line under its table, with the same words.
    let unobservable: Vec<&str> = r.params.iter().filter(|p| p.not_observable).map(|p| p.name.as_str()).collect();
    if !unobservable.is_empty() {
        let _ = writeln!(
            h,
            "<p class=\"unobservable\"><b>NOT OBSERVABLE from these data (estimates not to be trusted): {}</b></p>",
            esc(&unobservable.join(", "))
        );
    }
    h.push_str("</section>\n");
    if !r.method_details.is_empty() {
        h.push_str("<section id=\"method\">\n<h2>Method details</h2>\n<pre>");
        for line in &r.method_details {
            let _ = writeln!(h, "{}", esc(line));
        }
        h.push_str("</pre>\n</section>\n");
    }
}

/// Sections 2 and 4: Ē_p, and E_p,s per validation segment (drawn here,
/// next to the numbers).
pub(crate) fn validation(h: &mut String, r: &ReportInput<'_>, e: &SegmentErrors) -> Result<()> {
    let (e0, e1) = (&e.initial, &e.calibrated);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    h.push_str("<section id=\"validation\">\n<h2>Validation: mean position error Ē_p</h2>\n");
    if let Some((first, drives)) = r.validation_data.split_first() {
        let _ = writeln!(h, "<p class=\"data\">{}</p>", esc(first));
        list(h, drives);
    }
    h.push_str("<table>\n");
    let _ = writeln!(h, "<tr><th>θ</th><th>Ē_p (m)</th><th>segments</th></tr>");
    let _ = writeln!(h, "<tr><td>θ_0 (initial)</td><td>{:.3}</td><td>{}</td></tr>", mean(e0), e0.len());
    let _ = writeln!(h, "<tr><td>calibrated</td><td><b>{:.3}</b></td><td>{}</td></tr>", mean(e1), e1.len());
    if let Some(et) = &e.truth {
        let _ = writeln!(h, "<tr><td>truth</td><td>{:.3}</td><td>{}</td></tr>", mean(et), et.len());
    }
    let better = e1.iter().zip(e0).filter(|(a, b)| a < b).count();
    let _ = writeln!(
        h,
        "</table>\n<p>The calibrated θ dead-reckons better than θ_0 on {better} of {} validation segments.</p>",
        e0.len()
    );
    let idx = |v: &[f64]| v.iter().enumerate().map(|(i, &e)| ((i + 1) as f64, e)).collect::<Vec<_>>();
    let mut series =
        vec![Series::points("θ_0", idx(e0), plots::ORANGE), Series::points("calibrated", idx(e1), plots::BLUE)];
    if let Some(et) = &e.truth {
        series.push(Series::points("truth", idx(et), plots::GREEN));
    }
    let panel = Panel {
        title: "E_p,s per validation segment".into(),
        x_label: segment_axis_label(r),
        y_label: "E_p,s (m)".into(),
        series,
        y_range: plots::robust_range(&[e0.clone(), e1.clone()].concat(), &[0.0]),
        ..Default::default()
    };
    h.push_str(&figure_svg("Dead-reckoning error per validation segment", (900, 380), (1, 1), &[panel])?);
    h.push_str("</section>\n");
    Ok(())
}

/// Section 3: the drive as a map, the reference and dead reckoning with θ_0
/// and the calibrated θ on the validation segments where θ_0 is worst;
/// each segment shown named by its drive and timed on that drive's clock.
pub(crate) fn map(h: &mut String, r: &ReportInput<'_>, segs: &[SegmentData<'_>], e0: &[f64]) -> Result<()> {
    let drive = r.drive;
    let several = r.drives() > 1;
    let _ = writeln!(h, "<section id=\"map\">\n<h2>{}</h2>", if several { "The drives" } else { "The drive" });
    let mut map_series = Vec::new();
    for p in drive.parts() {
        let pts: Vec<(f64, f64)> = (p.start..p.end).map(|i| (drive.measured().px[i], drive.measured().py[i])).collect();
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
            thin(dead_reckoning(&segs[i], &r.theta0, &r.extrinsics_of(i)[0]), 1500),
            plots::ORANGE,
        ));
        map_series.push(Series::line(
            if first { "dead reckoning calibrated" } else { "" },
            thin(dead_reckoning(&segs[i], &r.theta, &r.extrinsics_of(i)[1]), 1500),
            plots::BLUE,
        ));
    }
    let of = if several { format!(" of {} drives", r.drives()) } else { String::new() };
    // Each segment shown numbered at its start, as the line under the map lists them.
    let labels = order.iter().enumerate().map(|(j, &i)| (segs[i].px[0], segs[i].py[0], format!("{}", j + 1))).collect();
    let map = Panel {
        title: format!(
            "reference and dead reckoning on the {} validation segments{of} where θ_0 is worst",
            order.len()
        ),
        x_label: "x (m)".into(),
        y_label: "y (m)".into(),
        series: map_series,
        equal_aspect: true,
        labels,
        ..Default::default()
    };
    h.push_str(&figure_svg("Map", (900, 700), (1, 1), &[map])?);
    let starts: Vec<usize> = order.iter().map(|&i| r.validation_segments[i].start).collect();
    let _ = writeln!(h, "<p>{}</p>\n</section>", esc(&segments_shown(r, &starts)));
    Ok(())
}

/// The line under the map: the segments shown (first samples `starts`, in
/// time order) by the numbers the map gives them, each with its start time
/// and, with several drives, its drive, timed on that drive's own clock.
fn segments_shown(r: &ReportInput<'_>, starts: &[usize]) -> String {
    let drive = r.drive;
    let several = r.drives() > 1;
    let each: Vec<String> = starts
        .iter()
        .enumerate()
        .map(|(j, &s)| {
            let t = drive.own_time_s(s);
            if several {
                format!("{}: {} at {t:.1} s", j + 1, r.drive_label(r.drive_of(s)))
            } else {
                format!("{}: {t:.1} s", j + 1)
            }
        })
        .collect();
    let what = if several { "drive and start time on that drive's own clock" } else { "start time" };
    format!("Segments shown, numbered on the map ({what}): {}.", each.join("; "))
}

/// The x-axis label of the per-segment errors: the segments are numbered
/// from 1 in time order; with several drives, which numbers are whose.
fn segment_axis_label(r: &ReportInput<'_>) -> String {
    if r.drives() == 1 {
        return "validation segment".into();
    }
    let drive_of: Vec<usize> = r.validation_segments.iter().map(|s| r.drive_of(s.start)).collect();
    let ranges: Vec<String> = (0..r.drives())
        .filter_map(|k| {
            let first = drive_of.iter().position(|&d| d == k)?;
            let last = drive_of.iter().rposition(|&d| d == k)?;
            Some(format!("{} {}–{}", r.drive_label(k), first + 1, last + 1))
        })
        .collect();
    format!("validation segment ({})", ranges.join(", "))
}

/// Section 5: the spread of the step-1 estimates θ_B,I (3-step method);
/// nothing without them.
pub(crate) fn batches(h: &mut String, r: &ReportInput<'_>) -> Result<()> {
    if r.batches.is_empty() {
        return Ok(());
    }
    h.push_str("<section id=\"batches\">\n<h2>Step-1 estimates θ_B,I</h2>\n");
    let units = [("c_e (m)", 1.0), ("c_d (mm)", 1e3), ("t_r (m)", 1.0), ("d (mm/(m/s²))", 1e3)];
    let panels: Vec<Panel> = (0..4)
        .map(|i| {
            let pts: Vec<(f64, f64)> = r.batches.iter().map(|(t, e)| (*e, <[_; 4]>::from(t)[i] * units[i].1)).collect();
            let ys: Vec<f64> = pts.iter().map(|p| p.1).collect();
            let mut hlines = vec![plots::HLine {
                name: "calibrated".into(),
                y: <[_; 4]>::from(r.theta)[i] * units[i].1,
                color: plots::RED,
            }];
            if let Some(t) = r.truth {
                hlines.push(plots::HLine {
                    name: "truth".into(),
                    y: <[_; 4]>::from(t)[i] * units[i].1,
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
    Ok(())
}

/// Section 6: residual time series, the one-step yaw-rate residual and the
/// dead-reckoning position error along the validation segments; with
/// several drives one figure per drive, on that drive's own clock (their
/// times are not one axis).
pub(crate) fn residuals(h: &mut String, r: &ReportInput<'_>, segs: &[SegmentData<'_>]) -> Result<()> {
    h.push_str("<section id=\"residuals\">\n<h2>Residuals</h2>\n");
    if r.drives() == 1 {
        let panels = [yaw_rate_residual_panel(r, 0), position_error_panel(r, segs, 0)];
        h.push_str(&figure_svg("Residuals over the drive", (900, 640), (2, 1), &panels)?);
    } else {
        for k in 0..r.drives() {
            let panels = [yaw_rate_residual_panel(r, k), position_error_panel(r, segs, k)];
            let title = format!("Residuals on {}", r.drive_label(k));
            h.push_str(&figure_svg(&title, (900, 640), (2, 1), &panels)?);
        }
    }
    h.push_str("</section>\n");
    Ok(())
}

/// The time axis label of drive `k`'s residuals.
fn time_label(r: &ReportInput<'_>, k: usize) -> String {
    if r.drives() == 1 {
        "t (s)".into()
    } else {
        format!("t on {}'s clock (s)", r.drive_label(k))
    }
}

/// The yaw-rate residual on drive `k`, reference − model one step ahead,
/// for θ_0 and the calibrated θ, in 5 s means within each part (a line per
/// part: no line across a gap).
fn yaw_rate_residual_panel(r: &ReportInput<'_>, k: usize) -> Panel {
    let drive = r.drive;
    let ts = drive.sample_time_s();
    let samples = r.drive_samples(k);
    // Means over 5 s make a systematic yaw-rate error visible above the wheel noise.
    let w = ((5.0 / ts).round() as usize).max(1);
    let smooth = |v: &[(f64, f64)]| -> Vec<(f64, f64)> {
        v.chunks(w).map(|c| (c[0].0, c.iter().map(|p| p.1).sum::<f64>() / c.len() as f64)).collect()
    };
    let (mut series, mut ys) = (Vec::new(), Vec::new());
    for p in drive.parts().iter().filter(|p| samples.contains(&p.start)) {
        let mut heading = Vec::new();
        let mut heading0 = Vec::new();
        let m = drive.measured();
        for i in p.start..p.end.saturating_sub(1) {
            let x = State::new(m.px[i], m.py[i], m.psi[i]);
            let u = Input { n_rl: m.n_rl[i], n_rr: m.n_rr[i], beta: m.beta[i], a_y: m.a_y[i] };
            let r1 = m.psi[i + 1] - step(&x, &u, &r.theta, ts)[2];
            let r0 = m.psi[i + 1] - step(&x, &u, &r.theta0, ts)[2];
            heading.push((drive.own_time_s(i), r1 / ts));
            heading0.push((drive.own_time_s(i), r0 / ts));
        }
        let (hs, hs0) = (smooth(&heading), smooth(&heading0));
        ys.extend(hs.iter().chain(&hs0).map(|p| p.1));
        let first = series.is_empty();
        series.push(Series::line(if first { "θ_0" } else { "" }, hs0, plots::ORANGE));
        series.push(Series::line(if first { "calibrated" } else { "" }, hs, plots::BLUE));
    }
    Panel {
        title: "yaw-rate residual: reference − model one step ahead (5 s means)".into(),
        x_label: time_label(r, k),
        y_label: "rad/s".into(),
        y_range: plots::robust_range(&ys, &[0.0]),
        series,
        ..Default::default()
    }
}

/// The dead-reckoning position error along each validation segment of
/// drive `k` for θ_0 and the calibrated θ.
fn position_error_panel(r: &ReportInput<'_>, segs: &[SegmentData<'_>], k: usize) -> Panel {
    let drive = r.drive;
    let samples = r.drive_samples(k);
    let mut pos_series = Vec::new();
    let mut ys = Vec::new();
    for (j, (s, seg)) in r.validation_segments.iter().zip(segs).enumerate() {
        if !samples.contains(&s.start) {
            continue;
        }
        let [e0, e1] = r.extrinsics_of(j);
        let (a, b) = (dead_reckoning(seg, &r.theta0, &e0), dead_reckoning(seg, &r.theta, &e1));
        let err_of = |d: &[(f64, f64)]| -> Vec<(f64, f64)> {
            d.iter()
                .enumerate()
                .map(|(k, p)| (drive.own_time_s(s.start + k), (seg.px[k] - p.0).hypot(seg.py[k] - p.1)))
                .collect()
        };
        let (e_a, e_b) = (err_of(&a), err_of(&b));
        ys.extend(e_a.iter().chain(&e_b).map(|p| p.1));
        let first = pos_series.is_empty();
        pos_series.push(Series::line(if first { "θ_0" } else { "" }, thin(e_a, 200), plots::ORANGE));
        pos_series.push(Series::line(if first { "calibrated" } else { "" }, thin(e_b, 200), plots::BLUE));
    }
    Panel {
        title: "dead-reckoning position error along each validation segment".into(),
        x_label: time_label(r, k),
        y_label: "m".into(),
        y_range: Some((0.0, 1.05 * ys.iter().copied().filter(|v| v.is_finite()).fold(1e-3, f64::max))),
        series: pos_series,
        ..Default::default()
    }
}

/// Section 7: the warnings and notes, and the end of the page.
pub(crate) fn warnings(h: &mut String, r: &ReportInput<'_>) {
    h.push_str("<section id=\"warnings\">\n<h2>Warnings and notes</h2>\n");
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
}
