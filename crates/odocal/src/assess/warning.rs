//! Typed warnings of a calibration: what the user should know about a
//! result that is not an error.
//!
//! Each [`Warning`] carries its numbers as fields (in the JSON report, tagged
//! by `"kind"`) and reads as one sentence through `Display`. Human output can
//! group them by that kind: a noisy drive gives hundreds of
//! [`Warning::CompensationFailed`] and the CLI prints a count and the first
//! few.

use serde::{Deserialize, Serialize};

use crate::assess::trust::GuardViolation;
use crate::compensate::CompensationWarning;
use crate::eiv::EivWarning;
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

/// Something the user should know about a calibration result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
#[non_exhaustive]
pub enum Warning {
    /// An identification ended with parameters the data cannot determine
    /// (alone, or in a near-collinear combination): their estimates are not
    /// to be trusted.
    Unobservable {
        /// Which check named them: `"final identification"` (batch
        /// Gauss-Newton's `JᵀWJ`) or `"EIV filter"` (its `H_θ`).
        stage: String,
        /// The parameters.
        params: ParamSet,
        /// Batch Gauss-Newton: RMS pose change per resolution step of each θ
        /// parameter, m ([`crate::identify::Observability::sensitivity_m`]).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sensitivity_m: Option<[f64; 4]>,
        /// EIV: each θ parameter's σ over its resolution at the filter's
        /// start; above 1 the filter held it
        /// ([`crate::identify::Observability::sigma_over_resolution`]).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        sigma_over_resolution: Option<[f64; 4]>,
        /// Reciprocal condition number of the equilibrated information over
        /// the parameters estimated.
        rcond: f64,
        /// The rcond below which a combination's parameters are named.
        min_rcond: f64,
    },
    /// `auto_fix`: no segment turns enough, so the yaw-only parameters were
    /// held at θ_0 and every segment was used.
    AutoFixNoTurns {
        /// The parameters held.
        params: ParamSet,
        /// Segments used (all cut).
        segments: usize,
        /// The selection threshold, rad/s.
        min_peak_yaw_rate_rad_per_s: f64,
        /// The fastest segment's peak yaw rate, rad/s.
        peak_yaw_rate_rad_per_s: f64,
    },
    /// `auto_fix`: parameters the observability check named at θ_0 were held.
    AutoFixUnobservable {
        /// The parameters held, in the order they were held.
        params: Vec<Param>,
        /// Selected segments the check ran on.
        segments: usize,
    },
    /// With auto-fix: the fit found these parameters not observable (its
    /// own check, after the selection's at θ_0 passed), so they were held
    /// at θ_0 and the calibration ran again.
    AutoFixRefit {
        /// The parameters held.
        params: Vec<Param>,
    },
    /// Every selected calibration segment turns the same way, which makes
    /// c_d and t_r nearly collinear: every cut segment was used instead
    /// (the straight ones separate them; see
    /// [`crate::CalibrationOptions::keep_one_way_selection`]).
    OneWayTurns {
        /// The common turning direction.
        sense: String,
        /// Segments selected by the yaw-rate threshold.
        selected: usize,
        /// Segments added (those below the threshold).
        added: usize,
    },
    /// A step-1 batch identification failed and was left out.
    BatchFailed {
        /// Batch index (0-based, in batch order).
        batch: usize,
        /// Why.
        reason: String,
    },
    /// A step-1 batch result failed a plausibility guard and was not picked.
    BatchRejected {
        /// Batch index (0-based, in batch order).
        batch: usize,
        /// The guards it failed.
        violations: Vec<GuardViolation>,
    },
    /// Fewer step-1 results passed the guards than θ_B,I are to be picked.
    FewUsableBatches {
        /// Results that passed.
        usable: usize,
        /// θ_B,I asked for.
        picks: usize,
    },
    /// A compensation job (one segment at one θ_B,I) failed and was left out.
    CompensationFailed {
        /// First sample of the segment.
        segment_start: usize,
        /// Why.
        reason: String,
    },
    /// A QP the configured solver did not finish was solved by the fallback.
    SolverFallback {
        /// First sample of the segment.
        segment_start: usize,
        /// Which θ_B,I (1-based).
        theta_index: usize,
        /// The linearization (1-based).
        linearization: usize,
        /// The solver that did not finish.
        solver: String,
        /// The solver that did.
        fallback: String,
        /// Why the first one stopped.
        reason: String,
    },
    /// EIV: a consistency check of the filter failed (the model does not
    /// fit the data): NIS or whiteness in a window, divergence in a window,
    /// θ unstable across halves, a noise scale at its upper clamp, or no
    /// convergence. The finding carries the window or parameter.
    EivCheckFailed {
        /// The filter's finding.
        finding: EivWarning,
        /// True when the report's θ is therefore the batch G-N fallback;
        /// false when the EIV θ was kept despite it: the fallback is off,
        /// or the only findings are θ unstable across halves, which does
        /// not send the result to the fallback.
        fell_back: bool,
    },
    /// EIV: a finding of the filter that is not a failure: innovations
    /// smaller than the noise model allows (NIS below its band, and their
    /// lag-1 correlation in such a window).
    EivCheckNote {
        /// The filter's finding.
        finding: EivWarning,
    },
    /// EIV: the EIV estimate was not used; the report's θ is batch
    /// Gauss-Newton over all cut segments (no yaw-rate selection).
    EivFallback {
        /// Why: the checks that failed, or the filter's error.
        reason: String,
        /// Segments the batch Gauss-Newton fitted.
        segments: usize,
        /// The EIV θ that was not used (none when the filter failed).
        eiv_theta: Option<Theta>,
    },
    /// EIV with reference extrinsics: a two-stage estimate. The extrinsics
    /// were estimated jointly with θ by the method's batch Gauss-Newton
    /// start (or given), then held while the filter ran on the axle poses
    /// they imply; the EIV θ covariance does not include their uncertainty.
    EivExtrinsicsHeld {
        /// The extrinsics the filter held.
        extrinsics: crate::model::extrinsics::Extrinsics,
        /// Which of them the batch Gauss-Newton start estimated (empty:
        /// all given).
        estimated: ParamSet,
    },
    /// EIV: the bias correction's bootstrap fitted only some of its
    /// replicates. The subtracted bias is the mean over the complete
    /// antithetic pairs that were fitted; its Monte Carlo error, larger with
    /// fewer pairs, is in θ's σ.
    EivBiasCorrectionIncomplete {
        /// Replicates that could not be fitted.
        failed: usize,
        /// Replicates asked for.
        replicates: usize,
        /// The first replicate's error.
        first_error: String,
    },
    /// EIV: the bias correction could not be computed (too few of its
    /// replicates could be fitted). The result is the uncorrected EIV
    /// estimate (the profile cost's root), which the checks accepted.
    EivBiasCorrectionFailed {
        /// Why.
        error: String,
    },
}

impl From<CompensationWarning> for Warning {
    fn from(w: CompensationWarning) -> Self {
        match w {
            CompensationWarning::Failed { segment_start, reason } => {
                Warning::CompensationFailed { segment_start, reason }
            }
            CompensationWarning::SolverFallback {
                segment_start,
                theta_index,
                linearization,
                solver,
                fallback,
                reason,
            } => Warning::SolverFallback { segment_start, theta_index, linearization, solver, fallback, reason },
        }
    }
}

impl Warning {
    /// A short name of the kind of warning (the JSON `"kind"`).
    #[cfg(test)]
    pub(crate) fn kind(&self) -> &'static str {
        match self {
            Warning::Unobservable { .. } => "unobservable",
            Warning::AutoFixNoTurns { .. } => "auto_fix_no_turns",
            Warning::AutoFixUnobservable { .. } => "auto_fix_unobservable",
            Warning::AutoFixRefit { .. } => "auto_fix_refit",
            Warning::OneWayTurns { .. } => "one_way_turns",
            Warning::BatchFailed { .. } => "batch_failed",
            Warning::BatchRejected { .. } => "batch_rejected",
            Warning::FewUsableBatches { .. } => "few_usable_batches",
            Warning::CompensationFailed { .. } => "compensation_failed",
            Warning::SolverFallback { .. } => "solver_fallback",
            Warning::EivCheckFailed { .. } => "eiv_check_failed",
            Warning::EivCheckNote { .. } => "eiv_check_note",
            Warning::EivFallback { .. } => "eiv_fallback",
            Warning::EivExtrinsicsHeld { .. } => "eiv_extrinsics_held",
            Warning::EivBiasCorrectionIncomplete { .. } => "eiv_bias_correction_incomplete",
            Warning::EivBiasCorrectionFailed { .. } => "eiv_bias_correction_failed",
        }
    }

    /// True for what informs rather than warns: a statement about how the
    /// result was made that holds on every such calibration (the EIV filter
    /// held the reference extrinsics its start estimated) or a check's
    /// finding that is not a failure. The CLI prints these as `note:`; the
    /// JSON lists them with the warnings, by kind.
    pub fn is_note(&self) -> bool {
        matches!(self, Warning::EivExtrinsicsHeld { .. } | Warning::EivCheckNote { .. })
    }

    /// True for a failed EIV consistency check whose θ is the report's
    /// result (the fallback was off): the verdict counts these.
    pub(crate) fn misspecifies_result(&self) -> bool {
        matches!(self, Warning::EivCheckFailed { fell_back: false, .. })
    }
}

/// The EIV filter's reasons for naming `params`, with the numbers that
/// decided: the σ over resolution at its start (above 1: held at the
/// start's value), and for a parameter it kept estimating, the rcond of
/// the combination it is in.
fn unobservable_by_filter(
    f: &mut std::fmt::Formatter<'_>,
    params: ParamSet,
    ratio: &[f64; 4],
    rcond: f64,
    min_rcond: f64,
) -> std::fmt::Result {
    let names = |held: bool| -> Vec<&str> {
        params.into_iter().filter(|p| p.index() < 4 && (ratio[p.index()] > 1.0) == held).map(|p| p.name()).collect()
    };
    let (held, collinear) = (names(true), names(false));
    write!(
        f,
        "the filter's σ / resolution at its start, [c_e, c_d, t_r, d] = [{:.2}, {:.2}, {:.2}, {:.2}]",
        ratio[0], ratio[1], ratio[2], ratio[3]
    )?;
    if !held.is_empty() {
        write!(f, ", is above 1 for {}: held at the batch G-N start's values", held.join(", "))?;
    }
    if collinear.is_empty() {
        write!(f, "; rcond {rcond:.1e} over the parameters estimated")
    } else {
        write!(f, "; {} in a near-collinear combination: rcond {rcond:.1e} < {min_rcond:.0e}", collinear.join(", "))
    }
}

impl std::fmt::Display for Warning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Warning::Unobservable { stage, params, sensitivity_m, sigma_over_resolution, rcond, min_rcond } => {
                write!(f, "{stage}: {params} not observable from these data (")?;
                match (sigma_over_resolution, sensitivity_m) {
                    (Some(r), _) => unobservable_by_filter(f, *params, r, *rcond, *min_rcond)?,
                    (None, Some(s)) => write!(
                        f,
                        "sensitivity [c_e, c_d, t_r, d] = [{:.3}, {:.3}, {:.3}, {:.3}] m per resolution step, rcond \
                         {rcond:.1e}",
                        s[0], s[1], s[2], s[3]
                    )?,
                    (None, None) => write!(f, "a near-collinear combination: rcond {rcond:.1e} < {min_rcond:.0e}")?,
                }
                write!(
                    f,
                    "); their estimates are not to be trusted — hold them fixed at θ_0 (--fix) or use a drive with \
                     more turns"
                )
            }
            Warning::AutoFixNoTurns { params, segments, min_peak_yaw_rate_rad_per_s, peak_yaw_rate_rad_per_s } => {
                write!(
                    f,
                    "auto-fix: {params} held at θ_0 and all {segments} segments used: none turns at \
                     {min_peak_yaw_rate_rad_per_s} rad/s or faster (the fastest: {peak_yaw_rate_rad_per_s:.3} rad/s), so only \
                     c_e is observable"
                )
            }
            Warning::OneWayTurns { sense, selected, added } => write!(
                f,
                "all {selected} selected segments turn {sense}, so c_d and t_r are nearly collinear on them: the \
                 {added} straighter segments were added (--keep-one-way keeps the turning ones only)"
            ),
            Warning::AutoFixUnobservable { params, segments } => {
                let names: Vec<&str> = params.iter().map(|p| p.name()).collect();
                write!(
                    f,
                    "auto-fix: {} held at θ_0 (not observable from the {segments} selected segments at θ_0)",
                    names.join(", ")
                )
            }
            Warning::AutoFixRefit { params } => {
                let names: Vec<&str> = params.iter().map(|p| p.name()).collect();
                write!(
                    f,
                    "auto-fix: {} held at θ_0 and the calibration run again (the fit found them not observable, \
                     where the check at θ_0 did not)",
                    names.join(", ")
                )
            }
            Warning::BatchFailed { batch, reason } => write!(f, "initial batch {batch} left out: {reason}"),
            Warning::BatchRejected { batch, violations } => {
                let v: Vec<String> = violations.iter().map(ToString::to_string).collect();
                write!(f, "initial batch {batch} not picked (implausible): {}", v.join("; "))
            }
            Warning::FewUsableBatches { usable, picks } => write!(
                f,
                "only {usable} step-1 results passed the plausibility guards; {usable} θ_B,I picked instead of {picks}"
            ),
            Warning::CompensationFailed { reason, .. } => write!(f, "compensation left out: {reason}"),
            Warning::SolverFallback { segment_start, theta_index, linearization, solver, fallback, reason } => write!(
                f,
                "compensation of the segment at sample {segment_start} (θ_B,I {theta_index}): linearization \
                 {linearization}: {solver} → {fallback}: {reason}"
            ),
            Warning::EivCheckFailed { finding, fell_back } => write!(
                f,
                "EIV check failed: {finding}{}",
                match (fell_back, finding) {
                    (true, _) => "",
                    (false, EivWarning::UnstableAcrossHalves { .. }) => {
                        " (EIV result kept: θ moved along the drive, or its σ is short of the drive's slow noise; \
                         batch G-N over the same drive would mend neither)"
                    }
                    (false, _) => " (EIV result kept: fallback off)",
                }
            ),
            Warning::EivCheckNote { finding } => write!(
                f,
                "EIV innovation check (not a failure): {finding}; the innovations are smaller than the noise model allows (a \
                 noise source absent or over-estimated)"
            ),
            Warning::EivFallback { reason, segments, eiv_theta } => {
                write!(
                    f,
                    "EIV result NOT used ({reason}): the result is batch Gauss-Newton on all {segments} cut segments \
                     (no yaw-rate selection)"
                )?;
                match eiv_theta {
                    Some(t) => write!(f, "; the rejected EIV θ was {t}"),
                    None => Ok(()),
                }
            }
            Warning::EivExtrinsicsHeld { extrinsics, estimated } => {
                let origin = if estimated.is_empty() {
                    "given".to_string()
                } else {
                    format!("{estimated} estimated by its batch Gauss-Newton start")
                };
                write!(
                    f,
                    "EIV two-stage: the reference extrinsics ({extrinsics}; {origin}) were held while the filter ran \
                     on the rear-axle poses they imply; the EIV θ σ does not include their uncertainty (their σ is \
                     the batch Gauss-Newton start's)"
                )
            }
            Warning::EivBiasCorrectionIncomplete { failed, replicates, first_error } => write!(
                f,
                "EIV bias correction from {} of {replicates} replicates ({failed} could not be fitted, the first: \
                 {first_error}); its Monte Carlo error is in θ's σ",
                replicates.saturating_sub(*failed)
            ),
            Warning::EivBiasCorrectionFailed { error } => write!(
                f,
                "EIV bias correction NOT applied ({error}): the result is the uncorrected EIV estimate; another \
                 bootstrap seed or more replicates may succeed"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn notes_are_the_held_extrinsics_and_the_check_notes() {
        let held = Warning::EivExtrinsicsHeld {
            extrinsics: crate::model::extrinsics::Extrinsics::default(),
            estimated: "heading_offset".parse().expect("params"),
        };
        assert!(held.is_note());
        let failed = Warning::BatchFailed { batch: 3, reason: "singular".into() };
        assert!(!failed.is_note());
        let fallback = Warning::EivFallback { reason: "1 check failed".into(), segments: 4, eiv_theta: None };
        assert!(!fallback.is_note());
    }

    #[test]
    fn json_is_tagged_by_kind_with_named_parameters() {
        let w = Warning::AutoFixNoTurns {
            params: "c_d,t_r,d".parse().expect("params"),
            segments: 4,
            min_peak_yaw_rate_rad_per_s: 0.15,
            peak_yaw_rate_rad_per_s: 0.01,
        };
        let v = serde_json::to_value(&w).expect("json");
        assert_eq!(v["kind"], "auto_fix_no_turns");
        assert_eq!(v["params"], serde_json::json!(["c_d", "t_r", "d"]));
        assert_eq!(serde_json::from_value::<Warning>(v).expect("back"), w);
        assert!(w.to_string().starts_with("auto-fix: c_d, t_r, d held at θ_0 and all 4 segments used"), "{w}");
    }
}
