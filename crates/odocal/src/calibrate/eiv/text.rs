//! The EIV method's details as text: the summary the CLI prints, θ-shaped
//! lists in the text report's units, and the heading-drift test's line.

use std::fmt::Write as _;

use super::{EivDetail, EivOutcome};
use crate::eiv::NoiseSource;
use crate::model::THETA_UNITS;

/// `[c_e, c_d, t_r, d]` (SI) as "c_e … m, c_d … mm, t_r … m, d … mm/(m/s²)",
/// with a sign when `signed`.
pub(super) fn theta_in_units(a: &[f64; 4], signed: bool) -> String {
    only(a, signed, [true; 4])
}

/// [`theta_in_units`] of the parameters `keep` marks.
pub(super) fn only(a: &[f64; 4], signed: bool, keep: [bool; 4]) -> String {
    let parts: Vec<String> = THETA_UNITS
        .iter()
        .zip(a)
        .zip(keep)
        .filter(|(_, k)| *k)
        .map(|(((name, scale, unit, digits), v), _)| {
            let x = v * scale;
            // A value that rounds to zero prints as 0, not -0.
            let x = if (x * 10f64.powi(*digits as i32)).round() == 0.0 { 0.0 } else { x };
            if signed {
                format!("{name} {x:+.digits$} {unit}")
            } else {
                format!("{name} {x:.digits$} {unit}")
            }
        })
        .collect();
    parts.join(", ")
}

/// The heading-drift test in one line of the method details.
pub(super) fn heading_drift_line(h: &crate::eiv::HeadingDriftTest) -> String {
    match (h.separate, h.likelihood_ratio) {
        (true, Some(lr)) => format!(
            "own scale η_6 = {:.2} (e^{:+.2} × the position drift's; likelihood ratio {lr:.1}, score {:.1})",
            h.eta, h.log_ratio, h.score_statistic
        ),
        (_, Some(lr)) if lr > crate::eiv::HEADING_DRIFT_LR_THRESHOLD => format!(
            "tied to the position drift (score {:.1}, likelihood ratio {lr:.1}; the separate fit did not converge)",
            h.score_statistic
        ),
        (_, Some(lr)) => format!(
            "tied to the position drift (score {:.1}; likelihood ratio {lr:.1} not significant)",
            h.score_statistic
        ),
        (_, None) => format!("tied to the position drift (score {:.1})", h.score_statistic),
    }
}

impl EivDetail {
    /// The EIV fit in lines as the CLI prints them: the filter's windows,
    /// updates, iterations, termination and passes; the noise model at the
    /// start and as estimated (physical units, `NoiseModel`'s `Display`); the
    /// `known` sources held at the start; the σ widening for the estimated
    /// noise levels; a bias correction; which estimate the result is (EIV
    /// or the batch G-N fallback); the bootstrap's intervals. Through
    /// [`crate::CalibrationReport::method_details`].
    pub(crate) fn summary(&self, known: &[NoiseSource]) -> String {
        let d = self;
        let mut out = String::new();
        match &d.eiv {
            Some(e) => {
                let _ = writeln!(
                    out,
                    "EIV: {} window(s), {} pose updates, {} it, {}; {} filter passes",
                    e.windows.len(),
                    e.updates,
                    e.iterations,
                    e.termination,
                    e.evaluations[0] + e.evaluations[1]
                );
                let fixed = e.eta.iter().all(|x| *x == 0.0) && e.eta_sigma.iter().all(|x| *x == 0.0);
                let _ = writeln!(out, "  noise, start:     {}", d.noise_start);
                if !known.is_empty() {
                    let names: Vec<&str> = known.iter().map(|s| s.name()).collect();
                    let _ = writeln!(out, "  known (held at the start): {}", names.join(", "));
                }
                let _ = writeln!(out, "  noise, {}: {}", if fixed { "fixed    " } else { "estimated" }, e.noise);
                crate::calibrate::render::clamp_lines(&mut out, e);
                heading_white_lines(&mut out, d, e);
                if let Some(h) = &e.heading_drift {
                    let _ = writeln!(out, "  heading drift: {}", heading_drift_line(h));
                }
                if e.sigma_noise_estimate.iter().any(|x| *x > 0.0) {
                    // σ with the η term over σ without it, per estimated parameter.
                    let names = ["c_e", "c_d", "t_r", "d"];
                    let parts: Vec<String> = (0..4)
                        .filter(|i| e.sigma[*i] > 0.0)
                        .map(|i| {
                            // (The bias correction's Monte Carlo share is not part of the ratio.)
                            let (m, n) = (e.sigma_bias_correction[i], e.sigma_noise_estimate[i]);
                            let s = (e.sigma[i] * e.sigma[i] - m * m).max(0.0).sqrt();
                            let without = (s * s - n * n).max(0.0).sqrt();
                            format!("{} ×{:.2}", names[i], if without > 0.0 { s / without } else { f64::INFINITY })
                        })
                        .collect();
                    let _ = writeln!(out, "  σ widened for the estimated noise levels: {}", parts.join(", "));
                }
                if e.bias_subtracted.iter().any(|b| *b != 0.0) {
                    // The parameters the correction named (the others' entries are zeros).
                    let corrected: [bool; 4] =
                        std::array::from_fn(|i| e.bias_subtracted[i] != 0.0 || e.sigma_bias_correction[i] != 0.0);
                    let _ = writeln!(
                        out,
                        "  bias correction: subtracted {}; uncorrected {}",
                        only(&e.bias_subtracted, true, corrected),
                        theta_in_units(&e.theta_uncorrected.to_array(), false)
                    );
                    let _ = writeln!(
                        out,
                        "  σ includes the correction's Monte Carlo error: {}",
                        only(&e.sigma_bias_correction, false, corrected)
                    );
                }
            }
            None => {
                let _ = writeln!(out, "EIV: filter failed: {}", d.eiv_error.as_deref().unwrap_or("unknown error"));
            }
        }
        let _ = writeln!(
            out,
            "  result: {}",
            match d.eiv_result {
                EivOutcome::Eiv if d.clamp_refit.as_ref().is_some_and(|c| c.scale_held) => "EIV estimate (refitted with c_e held at the batch G-N start's after a noise scale at its upper clamp; its gap to the start and the start's σ of c_e are in σ)",
                EivOutcome::Eiv if d.clamp_refit.is_some() => "EIV estimate (refitted with the common-mode wheel noise scale held after it reached its upper clamp; its gap to the batch G-N start is in σ)",
                EivOutcome::Eiv if d.refit => "EIV estimate (refitted with the noise sources released; its gap to the batch G-N start is in σ)",
                EivOutcome::Eiv => "EIV estimate",
                EivOutcome::BatchGnFallback =>
                    "BATCH G-N FALLBACK (all segments): the EIV checks failed (see the warnings; with the fallback off, --no-fallback, EIV's θ is kept)",
            }
        );
        if let Some(r) = &d.held_noise_released {
            let names: Vec<&str> = r.held.iter().map(|s| s.name()).collect();
            let verdict = if r.passes() {
                "passes the checks: the drive contradicts the held level(s)".to_string()
            } else {
                format!("fails {} check(s) too", r.findings.len())
            };
            let _ = writeln!(
                out,
                "  with the held noise level(s) ({}) estimated: {}; {verdict}",
                names.join(", "),
                theta_in_units(&r.theta.to_array(), false)
            );
        }
        if let Some(b) = &d.bootstrap {
            let _ = writeln!(
                out,
                "  bootstrap: {} replicates ({} failed), {:.0} % basic intervals and the estimator's own bias:",
                b.replicates.len(),
                b.failed.len(),
                100.0 * b.level
            );
            // c_e, t_r in m; c_d in mm; d in mm/(m/s²), as the θ table.
            for (i, &(name, scale, _, prec)) in THETA_UNITS.iter().enumerate() {
                let [lo, hi] = b.interval_basic[i];
                let _ = writeln!(
                    out,
                    "    {name:<4} [{:.prec$}, {:.prec$}]  bias {:+.prec$}  corrected {:.prec$}",
                    lo * scale,
                    hi * scale,
                    b.bias[i] * scale,
                    b.theta_corrected.to_array()[i] * scale
                );
            }
        }
        out
    }
}

/// The line on the reference heading's white noise where the fit held it
/// at its readings' own level, or set that fit aside for one with the
/// level above estimated ([`super::EivMethodOptions::heading_white_readings_first`]).
fn heading_white_lines(out: &mut String, d: &EivDetail, e: &crate::eiv::EivReport) {
    let readings = e.heading_noise_floor.map_or_else(String::new, |f| format!(" ({:.3} mrad)", f * 1e3));
    if e.heading_white_at_floor {
        let _ = writeln!(out, "  heading white noise: its readings' own{readings}, no level above it fitted");
    } else if let Some(found) = &d.heading_white_floor_set_aside {
        let why = match (&found.error, found.findings.first()) {
            (Some(e), _) => format!("the filter failed there: {e}"),
            (None, Some(w)) if found.findings.len() == 1 => format!("that fit failed a check: {w}"),
            (None, Some(w)) => format!("that fit failed {} checks, first: {w}", found.findings.len()),
            (None, None) => format!(
                "the heading is noisier than its readings show (likelihood ratio {:.1} > {})",
                found.likelihood_ratio.unwrap_or(f64::NAN),
                super::HEADING_WHITE_LR_THRESHOLD
            ),
        };
        let _ = writeln!(out, "  heading white noise: estimated above its readings' own{readings}; {why}");
    }
}
