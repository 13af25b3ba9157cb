//! Text helpers of the EIV method's details: θ-shaped lists in the text
//! report's units, and the heading-drift test's line.

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
