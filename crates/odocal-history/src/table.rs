//! The table `odocal history` prints: [`VehicleHistory`]'s
//! [`Display`](std::fmt::Display) (rows, drift flags, pooled estimate)
//! and [`VehicleHistory::running_estimate`], with the phrases they share.

use std::fmt::Write as _;

use odocal::model::THETA_NAMES;

use crate::pooled::{self, SetAside};
use crate::{VehicleHistory, BIASED_NOTE, MODEL_SIGMA_NOTE, ONLINE};

/// `rows 4, 5 stand aside for row 6; row 2 for row 3`: each set-aside row
/// with the row that stands for its drive, grouped by that row.
fn set_aside_text(set_aside: &[SetAside]) -> String {
    let mut by: Vec<(i64, Vec<i64>)> = Vec::new();
    for s in set_aside {
        match by.iter_mut().find(|(b, _)| *b == s.by_id) {
            Some((_, ids)) => ids.push(s.id),
            None => by.push((s.by_id, vec![s.id])),
        }
    }
    by.iter()
        .map(|(b, ids)| {
            let list = ids.iter().map(i64::to_string).collect::<Vec<_>>().join(", ");
            if ids.len() == 1 {
                format!("row {list} stands aside for row {b}")
            } else {
                format!("rows {list} stand aside for row {b}")
            }
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// `not pooled, the verdict names a bias beyond its σ: row 4 (input_noise_bias)`.
fn biased_text(biased: &[pooled::Biased]) -> String {
    let list: Vec<String> = biased.iter().map(|b| format!("row {} ({})", b.id, b.reasons.join(", "))).collect();
    format!("not pooled, the verdict names a bias beyond its σ: {}", list.join(", "))
}

/// `row 3` or `rows 3, 5`.
fn rows_text(ids: &[i64]) -> String {
    let list: Vec<String> = ids.iter().map(i64::to_string).collect();
    format!("row{} {}", if ids.len() == 1 { "" } else { "s" }, list.join(", "))
}

/// Display scale and unit of each θ parameter in the history's table (c_d
/// and d in mm, as the calibration report shows them): value and σ alike.
const DISPLAY_UNITS: [(f64, &str); 4] = [(1.0, "m"), (1e3, "mm"), (1.0, "m"), (1e3, "mm/(m/s²)")];

impl VehicleHistory {
    /// When the rows are online running estimates alone (nothing pooled),
    /// what the most recent of them is, in words: the estimate `follow`
    /// continues from, and how many drives followed after it were held or
    /// flagged (their data are not in it). Which drives a running estimate
    /// holds is not recorded (a run's held drives are dropped with it; a
    /// concurrent run starts from an older row), so no more is said.
    /// `None` when something is pooled or no online row stands.
    pub fn running_estimate(&self) -> Option<String> {
        if self.pooled.is_some() {
            return None;
        }
        let last = self.rows.iter().rev().find(|r| r.record.method == ONLINE && !pooled::is_rejected(r))?;
        // After the row's own decision when the decisions hold it, else
        // after its time of recording.
        let own = self.decisions.iter().find(|d| d.fingerprint == last.record.fingerprint && d.decision == "written");
        let after = self
            .decisions
            .iter()
            .filter(|d| d.decision != "written")
            .filter(|d| own.map_or(d.decided_at >= last.recorded_at, |o| d.id > o.id))
            .count();
        let unwritten = match after {
            0 => String::new(),
            1 => "; 1 drive followed after it was held or flagged, and its data are not in it".to_string(),
            n => format!("; {n} drives followed after it were held or flagged, and their data are not in it"),
        };
        Some(format!(
            "the rows are online running estimates, each holding drives followed before it; the most recent, \
             row {}, is the estimate follow continues from{unwritten}",
            last.id
        ))
    }
}

impl std::fmt::Display for VehicleHistory {
    /// The rows as a table (one line per recorded drive and method), the
    /// drift flags and the pooled estimate, each value and σ in the unit
    /// its column or line names (c_d in mm, d in mm/(m/s²)).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "{:>4}  {:<24} {:<10} {:>14} {:>14} {:>13} {:>14}  {:<9} source",
            "id", "recorded (UTC)", "method", "c_e (m)", "c_d (mm)", "t_r (m)", "d (mm/(m/s²))", "verdict"
        )?;
        for r in &self.rows {
            let c = &r.record;
            let (v, sd) = (<[_; 4]>::from(c.theta), <[_; 4]>::from(c.sigma));
            let cell = |i: usize, digits: usize, width: usize| {
                let scale = DISPLAY_UNITS[i].0;
                let text = match (c.not_measured(i), sd[i]) {
                    (Some("held"), _) => format!("{:.digits$} held", v[i] * scale),
                    (Some(_), _) => format!("{:.digits$} unobs.", v[i] * scale),
                    (None, Some(s)) => format!("{:.digits$}±{:.1e}", v[i] * scale, s * scale),
                    (None, None) => format!("{:.digits$}", v[i] * scale),
                };
                format!("{text:>width$}")
            };
            writeln!(
                f,
                "{:>4}  {:<24} {:<10} {} {} {} {}  {:<9} {}",
                r.id,
                r.recorded_at,
                c.method,
                cell(0, 5, 14),
                cell(1, 3, 14),
                cell(2, 3, 13),
                cell(3, 3, 14),
                c.verdict.as_deref().unwrap_or("-"),
                c.sources.join(", ")
            )?;
        }
        if self.rows.iter().any(|r| (0..4).any(|i| r.record.not_measured(i).is_some())) {
            writeln!(
                f,
                "held: held at θ_0; unobs.: not observable from the row's drive; neither is a measurement, so \
                 neither counts in that parameter's drift flags or pooled estimate"
            )?;
        }
        if !self.set_aside.is_empty() {
            writeln!(
                f,
                "\neach drive counted once, by its most recent row: {} (the same drive)",
                set_aside_text(&self.set_aside)
            )?;
        }
        if self.drift.is_empty() {
            writeln!(f, "\nno drift: consecutive rows agree within 3 combined σ")?;
        } else {
            writeln!(f, "\ndrift (|Δ| > 3·sqrt(σ₁² + σ₂²)):")?;
            for d in &self.drift {
                let (scale, unit) =
                    THETA_NAMES.iter().position(|n| *n == d.parameter).map_or((1.0, "SI"), |i| DISPLAY_UNITS[i]);
                writeln!(
                    f,
                    "  {} row {} ({}) → row {} ({}): {:+.4e} {unit} (combined σ {:.2e} {unit}, {:.1}σ){}{}",
                    d.parameter,
                    d.from_id,
                    d.from_recorded_at,
                    d.to_id,
                    d.to_recorded_at,
                    d.change * scale,
                    d.combined_sigma * scale,
                    d.change.abs() / d.combined_sigma,
                    if d.model_sigma_only { MODEL_SIGMA_NOTE } else { "" },
                    if d.biased { BIASED_NOTE } else { "" }
                )?;
            }
        }
        self.fmt_pooled(f)
    }
}

impl VehicleHistory {
    /// The pooled estimate's lines of the table (or why nothing is pooled).
    fn fmt_pooled(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        if let Some(p) = &self.pooled {
            let mut aside =
                if p.set_aside.is_empty() { String::new() } else { format!("; {}", set_aside_text(&p.set_aside)) };
            if !p.rejected.is_empty() {
                let _ = write!(aside, "; not pooled, verdict rejected: {}", rows_text(&p.rejected));
            }
            if !p.online.is_empty() {
                let _ = write!(aside, "; not pooled, online running estimates: {}", rows_text(&p.online));
            }
            if !p.biased.is_empty() {
                let _ = write!(aside, "; {}", biased_text(&p.biased));
            }
            writeln!(
                f,
                "\npooled over {} drive(s) in {} row(s){aside} (inverse-variance mean ± its σ; between-drive sd):",
                p.drives, p.rows
            )?;
            let (m, s, b) =
                (<[_; 4]>::from(p.mean), <[_; 4]>::from(p.sigma_of_mean), <[_; 4]>::from(p.between_drive_sd));
            for (i, name) in THETA_NAMES.iter().enumerate() {
                let (scale, unit) = DISPLAY_UNITS[i];
                let left_out: Vec<String> = p
                    .not_measured
                    .iter()
                    .filter(|n| n.parameter == *name)
                    .map(|n| format!("row {} {}", n.id, n.why))
                    .collect();
                let left_out =
                    if left_out.is_empty() { String::new() } else { format!("; not pooled: {}", left_out.join(", ")) };
                if !m[i].is_finite() {
                    writeln!(
                        f,
                        "  {name:<4} {unit:<10} {:>12} — no measured row (held or not observable in every row pooled){left_out}",
                        "-"
                    )?;
                    continue;
                }
                // One drive has no spread between drives.
                let sd =
                    if b[i].is_finite() { format!("{:.2e}", b[i] * scale) } else { "— (needs two drives)".into() };
                let se =
                    if s[i].is_finite() { format!("{:.2e}", s[i] * scale) } else { "— (one row, without σ)".into() };
                writeln!(f, "  {name:<4} {unit:<10} {:>12.6} ± {se}   between-drive sd {sd}{left_out}", m[i] * scale)?;
            }
        } else if let Some(note) = self.running_estimate() {
            writeln!(f, "\nnothing pooled: {note}")?;
        } else {
            let biased = pooled::biased(&self.rows);
            if !biased.is_empty() {
                writeln!(f, "\nnothing pooled; {}", biased_text(&biased))?;
            }
        }
        Ok(())
    }
}
