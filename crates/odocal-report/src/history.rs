//! A vehicle's calibration history as one self-contained HTML page (`odocal
//! history VEHICLE --db FILE --report FILE.html`): per parameter an SVG
//! plot of every recorded value with its ±σ bar in recording order, the
//! drift flags marked and the pooled mean drawn; then the rows, the flags
//! and the pooled estimate as tables.

use odocal::model::THETA_NAMES;
use odocal_history::{DriftFlag, HistoryRow, Pooled, VehicleHistory, BIASED_NOTE, DRIFT_SIGMAS, MODEL_SIGMA_NOTE};
use plotters::prelude::*;

use crate::plots::{BLUE, GREY, RED};
use crate::{esc, ReportError, Result};

/// Display scale and unit of each parameter (c_d and d in mm).
const UNITS: [(f64, &str); 4] = [(1.0, "m"), (1e3, "mm"), (1.0, "m"), (1e3, "mm/(m/s²)")];

/// One parameter's plot: value ± σ per row (x: the row's place in
/// recording order, 1-based), the rows a drift flag ends at circled in red,
/// the pooled mean as a grey line.
fn parameter_svg(i: usize, rows: &[HistoryRow], drift: &[DriftFlag], pooled: Option<&Pooled>) -> Result<String> {
    let (scale, unit) = UNITS[i];
    let name = THETA_NAMES[i];
    let pts: Vec<(f64, f64, f64)> = rows
        .iter()
        .enumerate()
        .map(|(k, r)| {
            let v = <[_; 4]>::from(r.record.theta)[i] * scale;
            let s = <[_; 4]>::from(r.record.sigma)[i].map_or(0.0, |s| s * scale);
            ((k + 1) as f64, v, if s.is_finite() { s } else { 0.0 })
        })
        .collect();
    let mean = pooled.map(|p| <[_; 4]>::from(p.mean)[i] * scale).filter(|m| m.is_finite());
    let lo = pts.iter().map(|p| p.1 - p.2).chain(mean).fold(f64::INFINITY, f64::min);
    let hi = pts.iter().map(|p| p.1 + p.2).chain(mean).fold(f64::NEG_INFINITY, f64::max);
    let (lo, hi) = if hi > lo { (lo, hi) } else { (lo - 0.5 * lo.abs().max(1e-9), hi + 0.5 * hi.abs().max(1e-9)) };
    let pad = 0.08 * (hi - lo);
    let x_hi = pts.len() as f64 + 0.5;
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, (760, 300)).into_drawing_area();
        let err = |e: DrawingAreaErrorKind<std::io::Error>| ReportError::Draw(format!("history plot of {name}: {e:?}"));
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(format!("{name} ({unit}) ± σ"), ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(38)
            .y_label_area_size(80)
            // Headroom above the data for the legend.
            .build_cartesian_2d(0.5..x_hi, (lo - pad)..(hi + pad + 0.5 * (hi - lo)))
            .map_err(err)?;
        let digits = (1.0 - (hi - lo).max(1e-12).log10().floor()).clamp(0.0, 8.0) as usize + 1;
        let fy = move |v: &f64| format!("{v:.digits$}");
        let fx = |v: &f64| if v.fract() == 0.0 { format!("{v:.0}") } else { String::new() };
        chart
            .configure_mesh()
            .x_desc("row, in recording order")
            .y_desc(format!("{name}, {unit}"))
            .x_label_formatter(&fx)
            .y_label_formatter(&fy)
            .label_style(("sans-serif", 13))
            .draw()
            .map_err(err)?;
        if let Some(m) = mean {
            chart
                .draw_series(LineSeries::new(vec![(0.5, m), (x_hi, m)], GREY.stroke_width(1)))
                .map_err(err)?
                .label("pooled mean")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], GREY.stroke_width(1)));
        }
        // The σ bars: a vertical line with short caps (x in row units).
        let cap = 0.08;
        let bars = pts.iter().filter(|p| p.2 > 0.0).flat_map(|&(x, v, s)| {
            [
                vec![(x, v - s), (x, v + s)],
                vec![(x - cap, v - s), (x + cap, v - s)],
                vec![(x - cap, v + s), (x + cap, v + s)],
            ]
        });
        chart.draw_series(bars.map(|b| PathElement::new(b, BLUE.stroke_width(1)))).map_err(err)?;
        chart
            .draw_series(pts.iter().map(|&(x, v, _)| Circle::new((x, v), 3, BLUE.filled())))
            .map_err(err)?
            .label("value ± σ")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, BLUE.filled()));
        let flagged: Vec<(f64, f64)> = drift
            .iter()
            .filter(|f| f.parameter == name)
            .filter_map(|f| rows.iter().position(|r| r.id == f.to_id))
            .map(|k| (pts[k].0, pts[k].1))
            .collect();
        if !flagged.is_empty() {
            chart
                .draw_series(flagged.into_iter().map(|q| Circle::new(q, 9, RED.stroke_width(2))))
                .map_err(err)?
                .label(format!("drift flag (> {DRIFT_SIGMAS} combined σ from the row before)"))
                .legend(|(x, y)| Circle::new((x + 8, y), 6, RED.stroke_width(2)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 13))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(out)
}

/// A value with its σ in a table cell, in display units.
fn cell(v: f64, s: Option<f64>, i: usize) -> String {
    let (scale, _) = UNITS[i];
    let d = if i == 0 || i == 2 { 6 } else { 4 };
    match s.filter(|s| s.is_finite()) {
        Some(s) => format!("{:.d$} ± {:.2e}", v * scale, s * scale),
        None => format!("{:.d$}", v * scale),
    }
}

/// The drives a row's fingerprint names (a joint calibration's, comma
/// separated), each by its first 12 characters.
fn short_fingerprints(fingerprint: &str) -> String {
    let short: Vec<&str> =
        fingerprint.split(',').map(str::trim).filter(|f| !f.is_empty()).map(|f| f.get(..12).unwrap_or(f)).collect();
    short.join(", ")
}

fn rows_table(rows: &[HistoryRow]) -> String {
    let mut h = String::from(
        "<table><tr><th>row</th><th>id</th><th>recorded (UTC)</th><th>method</th><th>c_e (m)</th><th>c_d (mm)</th>\
         <th>t_r (m)</th><th>d (mm/(m/s²))</th><th>verdict</th><th>source</th><th>fingerprint</th></tr>\n",
    );
    for (k, r) in rows.iter().enumerate() {
        let c = &r.record;
        let (th, sd) = (<[_; 4]>::from(c.theta), <[_; 4]>::from(c.sigma));
        let cells: Vec<String> = (0..4)
            .map(|i| match c.not_measured(i) {
                Some(why) => format!("{} ({why})", cell(th[i], None, i)),
                None => cell(th[i], sd[i], i),
            })
            .collect();
        h.push_str(&format!(
            "<tr><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td><td><code>{}</code></td></tr>\n",
            k + 1,
            r.id,
            esc(&r.recorded_at),
            esc(&c.method),
            cells[0],
            cells[1],
            cells[2],
            cells[3],
            esc(c.verdict.as_deref().unwrap_or("-")),
            esc(&c.sources.join(", ")),
            esc(&short_fingerprints(&c.fingerprint)),
        ));
    }
    h.push_str("</table>\n");
    h
}

fn drift_list(drift: &[DriftFlag]) -> String {
    if drift.is_empty() {
        return format!("<p>No drift: consecutive rows agree within {DRIFT_SIGMAS} combined σ.</p>\n");
    }
    let mut h = format!("<p>Changes beyond {DRIFT_SIGMAS} combined σ (|Δ| > 3·sqrt(σ₁² + σ₂²)):</p>\n<ul>\n");
    for f in drift {
        let i = THETA_NAMES.iter().position(|n| *n == f.parameter).unwrap_or(0);
        let (scale, unit) = UNITS[i];
        h.push_str(&format!(
            "<li class=\"flag\">{} row id {} ({}) → id {} ({}): {:+.4e} {unit} ({:.1} σ){}{}</li>\n",
            esc(&f.parameter),
            f.from_id,
            esc(&f.from_recorded_at),
            f.to_id,
            esc(&f.to_recorded_at),
            f.change * scale,
            f.change.abs() / f.combined_sigma,
            if f.model_sigma_only { esc(MODEL_SIGMA_NOTE) } else { String::new() },
            if f.biased { esc(BIASED_NOTE) } else { String::new() }
        ));
    }
    h.push_str("</ul>\n");
    h
}

fn pooled_table(p: &Pooled) -> String {
    let (m, s, b) = (<[_; 4]>::from(p.mean), <[_; 4]>::from(p.sigma_of_mean), <[_; 4]>::from(p.between_drive_sd));
    let aside: Vec<String> = p.set_aside.iter().map(|s| format!("row {} for row {}", s.id, s.by_id)).collect();
    let mut aside = if aside.is_empty() {
        String::new()
    } else {
        format!(" Each drive counted once, by its most recent row; set aside: {}.", aside.join(", "))
    };
    if !p.rejected.is_empty() {
        let ids: Vec<String> = p.rejected.iter().map(i64::to_string).collect();
        aside.push_str(&format!(" Not pooled, their verdict rejected: row(s) {}.", ids.join(", ")));
    }
    if !p.online.is_empty() {
        let ids: Vec<String> = p.online.iter().map(i64::to_string).collect();
        aside.push_str(&format!(
            " Not pooled, online running estimates (each holds the drives followed before it): row(s) {}.",
            ids.join(", ")
        ));
    }
    if !p.biased.is_empty() {
        let rows: Vec<String> = p.biased.iter().map(|b| format!("row {} ({})", b.id, b.reasons.join(", "))).collect();
        aside.push_str(&format!(" Not pooled, the verdict names a bias beyond its σ: {}.", rows.join(", ")));
    }
    let mut h = format!(
        "<p>Pooled over {} drive(s) in {} row(s): the inverse-variance mean ± its σ and the between-drive sd.{aside}</p>\n\
         <table><tr><th>parameter</th><th>mean ± σ</th><th>between-drive sd</th></tr>\n",
        p.drives, p.rows
    );
    for (i, name) in THETA_NAMES.iter().enumerate() {
        let (scale, unit) = UNITS[i];
        let sd =
            if b[i].is_finite() { format!("{:.2e} {unit}", b[i] * scale) } else { "— (needs two drives)".into() };
        let left_out: Vec<String> =
            p.not_measured.iter().filter(|n| n.parameter == *name).map(|n| format!("row {} {}", n.id, n.why)).collect();
        let left_out =
            if left_out.is_empty() { String::new() } else { format!(" (not pooled: {})", esc(&left_out.join(", "))) };
        let value = if m[i].is_finite() {
            format!("{} {unit}", cell(m[i], Some(s[i]), i))
        } else {
            "— no measured row (held or not observable in every row pooled)".to_string()
        };
        h.push_str(&format!("<tr><td>{name}</td><td>{value}{left_out}</td><td>{sd}</td></tr>\n"));
    }
    h.push_str("</table>\n");
    h
}

/// The history page of a vehicle: a plot per parameter (`<figure
/// id="plot-c_e">`, …), the rows, the drift flags and the pooled estimate.
/// Text from the database (vehicle, sources, methods) is escaped.
pub fn render_history_html(history: &VehicleHistory) -> Result<String> {
    let VehicleHistory { vehicle, rows, drift, pooled, .. } = history;
    let pooled = pooled.as_ref();
    let title = format!("odocal history of vehicle '{}'", esc(vehicle));
    let mut h = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>{title}</title>\n<style>\
         body{{font-family:sans-serif;max-width:1000px;margin:1em auto}}table{{border-collapse:collapse}}\
         td,th{{border:1px solid #ccc;padding:2px 6px;font-size:13px}}.flag{{color:#d55e00}}</style></head>\n\
         <body><h1>{title}</h1>\n<p>{} calibration(s) recorded; {} drift flag(s).</p>\n",
        rows.len(),
        drift.len()
    );
    if rows.is_empty() {
        h.push_str("<p>No calibrations of this vehicle are recorded.</p>\n");
    } else {
        h.push_str("<section id=\"plots\"><h2>Parameters over the recorded calibrations</h2>\n");
        for (i, name) in THETA_NAMES.iter().enumerate() {
            h.push_str(&format!("<figure id=\"plot-{name}\">{}</figure>\n", parameter_svg(i, rows, drift, pooled)?));
        }
        h.push_str("</section>\n<section id=\"drift\"><h2>Drift</h2>\n");
        h.push_str(&drift_list(drift));
        if let Some(p) = pooled {
            h.push_str("</section>\n<section id=\"pooled\"><h2>Pooled estimate</h2>\n");
            h.push_str(&pooled_table(p));
        } else if let Some(note) = history.running_estimate() {
            h.push_str("</section>\n<section id=\"pooled\"><h2>Pooled estimate</h2>\n");
            h.push_str(&format!("<p>Nothing pooled: {}.</p>\n", esc(&note)));
        }
        h.push_str("</section>\n<section id=\"rows\"><h2>Recorded calibrations</h2>\n");
        h.push_str(&rows_table(rows));
        h.push_str("</section>\n");
    }
    h.push_str("</body></html>\n");
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use odocal::Theta;
    use odocal_history::{CalibrationRecord, ONLINE};

    fn row(id: i64, c_d: f64) -> HistoryRow {
        let theta = Theta { c_d, ..odocal::sim::SimOptions::default().theta_true };
        let sigma = Theta { c_e: 1e-4, c_d: 2e-5, t_r: 1e-3, d: 1e-5 };
        HistoryRow {
            id,
            recorded_at: format!("2026-11-2{id}T10:00:00.000Z"),
            odocal_version: "0".into(),
            record: CalibrationRecord {
                sigma: sigma.into(),
                sources: vec![format!("<run{id}>.csv")],
                ..CalibrationRecord::new("v", &format!("drive{id}"), "eiv", theta)
            },
        }
    }

    #[test]
    fn one_plot_per_parameter_the_flags_and_escaped_text() {
        let rows = vec![row(1, -2e-3), row(2, -2.01e-3), row(5, -1e-3)];
        let history = VehicleHistory::of_rows("<van & co>", rows, None);
        assert_eq!(history.drift.len(), 1);
        let html = render_history_html(&history).expect("html");
        assert_eq!(html.matches("<svg").count(), 4);
        for name in THETA_NAMES {
            assert!(html.contains(&format!("<figure id=\"plot-{name}\">")), "{name}");
        }
        assert!(html.contains("&lt;van &amp; co&gt;") && !html.contains("<van"));
        assert!(html.contains("&lt;run5&gt;.csv") && !html.contains("<run5>"));
        assert!(html.contains("-1.0000 ± 2.00e-2") && html.contains("-2.0100 ± 2.00e-2"), "{html}");
        assert!(html.contains("class=\"flag\">c_d row id 2"));
        assert!(html.contains("Pooled over 3 drive(s) in 3 row(s)"), "{html}");
        // Rows 1 and 2 of one drive: row 1 is set aside, no flag between them.
        let mut rows = vec![row(1, -2e-3), row(2, -2.5e-3), row(5, -2.49e-3)];
        rows[0].record.fingerprint = rows[1].record.fingerprint.clone();
        let html = render_history_html(&VehicleHistory::of_rows("v", rows, None)).expect("html");
        assert!(html.contains("Pooled over 2 drive(s) in 2 row(s)") && html.contains("set aside: row 1 for row 2"));
        assert!(html.contains("No drift"), "{html}");
        let empty = render_history_html(&VehicleHistory::of_rows("v", Vec::new(), None)).expect("html");
        assert!(!empty.contains("<svg") && empty.contains("No calibrations"));
    }

    /// A joint calibration's row names each of its drives; a held
    /// parameter is marked and has no σ; a parameter no pooled row
    /// measured has no pooled value, and no cell says NaN.
    #[test]
    fn a_joint_row_names_every_drive_and_a_held_parameter_is_marked() {
        let mut joint = row(1, -2e-3);
        joint.record.fingerprint = format!("{}, {}, {}", "a".repeat(64), "b".repeat(64), "c".repeat(64));
        joint.record.held = vec!["d".into()];
        joint.record.sigma.d = None;
        let html = render_history_html(&VehicleHistory::of_rows("v", vec![joint], None)).expect("html");
        let short = format!("{}, {}, {}", "a".repeat(12), "b".repeat(12), "c".repeat(12));
        assert!(html.contains(&format!("<code>{short}</code>")), "{html}");
        assert!(html.contains("0.8000 (held)"), "{html}");
        assert!(html.contains("— no measured row") && html.contains("not pooled: row 1 held"), "{html}");
        assert!(!html.contains("NaN"), "{html}");
        // Online rows alone: nothing pooled, the most recent named.
        let mut online = vec![row(1, -2e-3), row(2, -2e-3)];
        online.iter_mut().for_each(|r| r.record.method = ONLINE.into());
        let html = render_history_html(&VehicleHistory::of_rows("v", online, None)).expect("html");
        assert!(
            html.contains("Nothing pooled") && html.contains("row 2, is the estimate follow continues from"),
            "{html}"
        );
    }

    #[test]
    fn a_row_whose_verdict_names_a_bias_is_named_as_not_pooled() {
        let mut rows = vec![row(1, -2e-3), row(2, -2e-3)];
        rows[1].record.reasons = Some(vec!["input_noise_bias".into()]);
        let html = render_history_html(&VehicleHistory::of_rows("v", rows, None)).expect("html");
        assert!(
            html.contains("Pooled over 1 drive(s) in 1 row(s)")
                && html.contains("Not pooled, the verdict names a bias beyond its σ: row 2 (input_noise_bias)."),
            "{html}"
        );
    }
}
