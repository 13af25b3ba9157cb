//! The text of each verdict reason: what a user reads in the CLI's output,
//! the parameter file's comment and the HTML report.

use super::trust::{Verdict, VerdictReason};
use crate::eiv::NoiseSource;
use crate::model::param::Param;

/// The SI unit of a parameter's values in the reasons (the parameter
/// file's units; the text report's table shows c_d and d in mm).
fn unit(p: Param) -> &'static str {
    match p {
        Param::D => "m/(m/s²)",
        Param::HeadingOffset => "rad",
        Param::CE | Param::CD | Param::TR | Param::LeverX | Param::LeverY => "m",
    }
}

/// The level and its reasons on one line: `accepted`, or the level, a
/// colon and the reasons separated by `; `
/// (`doubtful: t_r has a σ of … m (…)`).
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{calibrate, CalibrationOptions, VerdictLevel, sim::{simulate, SimOptions}};
/// let drive = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) })?.drive;
/// let report = calibrate(&drive, &CalibrationOptions::default())?;
/// println!("verdict: {}", report.verdict);
/// assert!(report.verdict.to_string().starts_with(&report.verdict.level.to_string()));
/// assert_ne!(report.verdict.level, VerdictLevel::Rejected);
/// # Ok(()) }
/// ```
impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.level)?;
        for (i, r) in self.reasons.iter().enumerate() {
            f.write_str(if i == 0 { ": " } else { "; " })?;
            write!(f, "{r}")?;
        }
        Ok(())
    }
}

impl std::fmt::Display for VerdictReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VerdictReason::Implausible { violation } => write!(f, "implausible result: {violation}"),
            VerdictReason::WorseThanInitial { .. } | VerdictReason::NotBetterThanInitial { .. } => {
                initial_text(self, f)
            }
            VerdictReason::Unobservable { params } => write!(f, "{params} not observable from these data"),
            VerdictReason::AtGuardBound { param, value, fraction } => {
                write!(f, "{param} = {value:.6} {} is at {:.0} % of its plausible half-width from θ_0", unit(*param), fraction * 100.0)
            }
            VerdictReason::LargeUncertainty { param, sigma, fraction } => {
                write!(f, "{param} has a σ of {sigma:.3e} {} ({:.0} % of its plausible half-width)", unit(*param), fraction * 100.0)
            }
            VerdictReason::InconsistentSplit { param, fit, held_out, sigma } => write!(
                f,
                "{param} = {fit:.6} {u} here but {held_out:.6} {u} fitted on the held-out data alone: {:.0} σ apart \
                 (σ {sigma:.2e} {u}); the data do not agree on {param}",
                (fit - held_out).abs() / sigma,
                u = unit(*param)
            ),
            VerdictReason::FallbackDisagrees { .. } => fallback_text(self, f),
            VerdictReason::FallbackUnchecked { clamped, held, .. } => {
                let names = |v: &[NoiseSource]| v.iter().map(|s| s.name()).collect::<Vec<_>>().join(", ");
                f.write_str("the result is the batch Gauss-Newton fallback, and EIV's own estimate fails the plausibility guards")?;
                if !clamped.is_empty() {
                    write!(
                        f,
                        " with the wheel noise heavier than its model allows ({} at the upper clamp)",
                        names(clamped)
                    )?;
                }
                f.write_str(
                    ": no estimate bounds batch G-N's errors-in-variables bias, which grows with the wheel noise",
                )?;
                if !held.is_empty() {
                    write!(f, "; the noise level(s) held ({}) may not fit this drive", names(held))?;
                }
                Ok(())
            }
            VerdictReason::RefitDisagrees { param, estimate, gap, sigma, sigmas } => write!(
                f,
                "{param} = {estimate:.6} {u} is EIV's refit (its first fit failed its checks); the batch Gauss-Newton \
                 start lies {gap:.2e} {u} away, {sigmas:.1} × the σ without that gap ({sigma:.2e} {u}): the \
                 estimators disagree (the σ for the next drive includes the gap)",
                u = unit(*param)
            ),
            VerdictReason::TrackWidthAboveStart { estimate, start, sigma, sigmas } => write!(
                f,
                "t_r = {estimate:.6} m is EIV's estimate, {sigmas:.1} × the σ without that excess ({sigma:.2e} m) \
                 above its batch Gauss-Newton start's {start:.6} m: batch G-N's errors-in-variables bias on t_r points up, \
                 so the filter's model does not explain this shift (the σ for the next drive includes it)"
            ),
            VerdictReason::HeadingDriftFloorDisagrees { param, estimate, gap, sigma, sigmas } => write!(
                f,
                "{param} = {estimate:.6} {u}: EIV's fit holds the reference's heading drift at its floor \
                 (a centimetre-grade position), and without the floor {param} moves by {gap:.3e} {u}, {sigmas:.1} × \
                 the σ without that gap ({sigma:.2e} {u}); the data do not settle the heading drift's level (the σ for \
                 the next drive includes the gap; stating the reference's heading noise, --noise-model, \
                 settles it)",
                u = unit(*param)
            ),
            VerdictReason::HeavyCommonModeNoise { wheel_common_rel_sigma } => write!(
                f,
                "EIV's fit left the common-mode wheel noise at its upper clamp (σ_c {:.2} %): the drive's wheel \
                 scale varies more than the model allows, so the σ for the next drive, which widens with σ_c, may \
                 still be too small",
                wheel_common_rel_sigma * 100.0
            ),
            VerdictReason::HeldOutMuchWorse { held_out_m, fit_m, max_ratio } => {
                write!(f, "held-out Ē_p {held_out_m:.3} m is more than {max_ratio} × the fitting data's {fit_m:.3} m")
            }
            VerdictReason::Misspecified { checks } => write!(
                f,
                "{checks} EIV consistency check(s) failed on this θ: the noise model does not fit these data, or θ \
                 moved along the drive (see the warnings)"
            ),
            VerdictReason::ModelSigmaOnly { stage, needs } => write!(
                f,
                "only the model σ of {stage} stands for this result: it assumes independent residuals and \
                 understates the spread of such estimates under input noise, so nothing bounds the error ({needs})"
            ),
            VerdictReason::ExtrinsicsModelSigmaOnly { params, stage, needs } => write!(
                f,
                "the σ of {params} is the model σ of {stage} alone: it assumes independent residuals and \
                 understates the spread of such estimates under input noise, so nothing bounds their error ({needs})"
            ),
            VerdictReason::HeadingOffsetHeld { .. } => held_offset_text(self, f),
            VerdictReason::InputNoiseBias { param, estimate, bias, sigma, sigmas, wheel_white_rel_sigma } => write!(
                f,
                "{param} = {estimate:.6} {u} is biased by about {bias:+.2e} {u}, {sigmas:.1} × its σ ({sigma:.2e} {u}): batch \
                 Gauss-Newton takes the wheel rotations as exact, and their noise on this drive (white, {:.2} % \
                 per wheel and sample, from the heading's drift against the reference) biases it beyond what its \
                 σ covers (the default method, eiv, models this noise)",
                wheel_white_rel_sigma * 100.0,
                u = unit(*param)
            ),
            VerdictReason::NotConverged { stage, iterations, param, step_sigmas } => write!(
                f,
                "{stage} stopped at its iteration limit ({iterations}) while still moving: its last step moved \
                 {param} by {step_sigmas:.2} σ (raise --max-iterations)"
            ),
        }
    }
}

/// [`VerdictReason::FallbackDisagrees`]'s text.
fn fallback_text(r: &VerdictReason, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
    match r {
        VerdictReason::FallbackDisagrees { param, fallback, gap, sigma, sigmas, released } if !released.is_empty() => {
            let names: Vec<&str> = released.iter().map(|s| s.name()).collect();
            write!(
                f,
                "{param} = {fallback:.6} {u} is the batch Gauss-Newton fallback: with the noise level(s) held \
                 ({}) EIV's checks failed, with them estimated they pass and EIV's estimate lies {gap:.2e} {u} \
                 away, {sigmas:.1} × the σ without that gap ({sigma:.2e} {u}): the drive contradicts the held \
                 level(s), and batch G-N's errors-in-variables bias may be as large (the σ for the next drive \
                 includes it)",
                names.join(", "),
                u = unit(*param)
            )
        }
        VerdictReason::FallbackDisagrees { param, fallback, gap, sigma, sigmas, .. } => write!(
            f,
            "{param} = {fallback:.6} {u} is the batch Gauss-Newton fallback; EIV's own estimate lies {gap:.2e} {u} \
             away, {sigmas:.1} × the σ without that gap ({sigma:.2e} {u}): batch G-N's errors-in-variables bias \
             may be as large (the σ for the next drive includes it)",
            u = unit(*param)
        ),
        _ => Ok(()),
    }
}

/// [`VerdictReason::HeadingOffsetHeld`]'s text.
fn held_offset_text(r: &VerdictReason, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
    let VerdictReason::HeadingOffsetHeld { drive, held, fitted, sigma, param, shift, shift_sigmas } = r else {
        return Ok(());
    };
    write!(
        f,
        "the reference heading offset was held at {:.2} mrad, but fitted with θ on {} it is {:.2} mrad ({:.0} × its \
         σ {:.3} mrad away), and {param} then moves by {shift:.3e} {} ({shift_sigmas:.1} × its σ): θ absorbs \
         the offset (add --estimate heading-offset)",
        held * 1e3,
        drive.map_or("the drive".to_string(), |k| format!("drive {k}")),
        fitted * 1e3,
        (fitted - held).abs() / sigma,
        sigma * 1e3,
        unit(*param)
    )
}

/// The text of the comparison with θ_0 ([`VerdictReason::WorseThanInitial`],
/// [`VerdictReason::NotBetterThanInitial`]).
fn initial_text(r: &VerdictReason, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
    let (calibrated_m, initial_m, held_out, ratio, sigmas, worse) = match r {
        VerdictReason::WorseThanInitial { calibrated_m, initial_m, held_out, segment_ratio, segment_ratio_sigmas } => {
            (calibrated_m, initial_m, held_out, *segment_ratio, *segment_ratio_sigmas, true)
        }
        VerdictReason::NotBetterThanInitial {
            calibrated_m,
            initial_m,
            held_out,
            segment_ratio,
            segment_ratio_sigmas,
        } => (calibrated_m, initial_m, held_out, Some(*segment_ratio), Some(*segment_ratio_sigmas), false),
        _ => return Ok(()),
    };
    let data = if *held_out { "held-out" } else { "validation" };
    write!(f, "Ē_p {calibrated_m:.3} m is above θ_0's {initial_m:.3} m on the {data} data")?;
    if let Some(q) = ratio {
        write!(f, "; per segment {q:.2} × θ_0's error (geometric mean)")?;
        if let Some(z) = sigmas {
            write!(f, ", {z:.1} standard errors above 1")?;
        }
    }
    if worse {
        write!(f, ": dead reckoning gets worse")
    } else {
        write!(
            f,
            ": not beyond the noise, so these data do not settle whether θ or θ_0 is better (check θ on another drive)"
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A reason's numbers are SI and say so: d's σ of 1.6e-3 is in
    /// m/(m/s²), not the text table's mm/(m/s²).
    #[test]
    fn a_reason_names_the_unit_of_its_numbers() {
        let d = VerdictReason::LargeUncertainty { param: Param::D, sigma: 1.612e-3, fraction: 0.32 };
        assert_eq!(d.to_string(), "d has a σ of 1.612e-3 m/(m/s²) (32 % of its plausible half-width)");
        let t_r = VerdictReason::AtGuardBound { param: Param::TR, value: 1.9, fraction: 0.95 };
        assert_eq!(t_r.to_string(), "t_r = 1.900000 m is at 95 % of its plausible half-width from θ_0");
    }
}
