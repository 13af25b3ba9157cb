//! The report of a calibration: θ, its σ, the validation, the method's
//! detail, the verdict and warnings; and the parameter file written from it.

use serde::{Deserialize, Serialize};

use super::{
    outcome_covariance, outcome_robust, BatchGnDetail, CalibrationOptions, EivDetail, EivOutcome, InitialStep, Method,
    ThreeStepDetail,
};
use crate::assess::pooling::NextDriveSigma;
use crate::assess::trust::{Verdict, VerdictReason};
use crate::assess::validate::MultiValidation;
use crate::assess::warning::Warning;
use crate::compensate::CompensationStep;
use crate::identify::{IdentifyReport, Observability, RobustCovariance};
use crate::io::param_file::ParamFile;
use crate::model::extrinsics::ExtrinsicsEstimate;
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

/// θ with its mean validation position error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThetaScore {
    /// Parameters.
    pub theta: Theta,
    /// Ē_p on the validation segments, m.
    pub mean_position_error_m: f64,
}

/// Counts of segments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SegmentCounts {
    /// Calibration segments cut.
    pub cut: usize,
    /// Calibration segments selected (turning enough).
    pub selected: usize,
    /// Validation segments.
    pub validation: usize,
}

research_pub! {
    /// Wall time per stage, s.
    #[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
    struct Timing {
        /// Whole calibration.
        pub total: f64,
        /// Preparation, segment selection and validation of θ_0.
        pub setup: f64,
        /// Step 1 (or the single batch G-N of batch-gn).
        pub initial_identification: f64,
        /// Step 2.
        pub compensation: f64,
        /// Step 3.
        pub final_identification: f64,
        /// Validation of the result.
        pub validation: f64,
    }
}

/// Validation summary of the result (docs/reference.md, "Outputs": `validation`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationSummary {
    /// Ē_p of the result, m.
    pub mean_position_error_m: f64,
    /// Validation segments.
    pub segments: usize,
    /// True when the validation ran on held-out data that the calibration
    /// did not see (see [`super::Calibration::holdout`]).
    pub held_out: bool,
}

/// What a method reports beyond the shared estimate. In JSON its fields
/// stand at the top level of the report (`initial_step`, `compensation`,
/// `identification`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub(crate) enum MethodDetail {
    /// The 3-step method's steps 1–3.
    ThreeStep(ThreeStepDetail),
    /// The EIV method's start, fit and fallback (before `BatchGn`: both
    /// have `identification`, and untagged deserialisation takes the first
    /// variant that fits).
    Eiv(EivDetail),
    /// Batch Gauss-Newton's identification.
    BatchGn(BatchGnDetail),
}

/// The calibration report (docs/reference.md, "Outputs").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReport {
    /// The method run (`"three-step"`, `"batch-gn"`, `"eiv"`).
    pub method: String,
    /// The calibrated θ.
    pub theta: Theta,
    /// The method's within-drive model covariance of θ (4×4, row-major,
    /// zero rows for parameters not estimated), SI units squared: how well
    /// this drive's data determine θ under the model, not how far the
    /// result may be off on the next drive. The σ that stands for the
    /// result (the verdict's, the parameter file's, the CLI's JSON `sigma`)
    /// is [`CalibrationReport::result_sigma`].
    pub covariance: [[f64; 4]; 4],
    /// Observability of the parameters at the estimate.
    pub observability: Observability,
    /// Ē_p of the result.
    pub validation: ValidationSummary,
    /// Whether to trust the result: accepted, doubtful or rejected, with
    /// the reasons ([`Verdict`]).
    pub verdict: Verdict,
    /// θ_0 and its Ē_p.
    pub initial: ThetaScore,
    /// Wall time per stage (JSON `timing_s`).
    pub(crate) timing_s: Timing,
    /// Segment counts.
    pub segments: SegmentCounts,
    /// The reference sensor's extrinsics (lever arm, heading offset:
    /// initial and estimated values, σ, covariance) when the calibration
    /// involved them (some extrinsics free in
    /// [`IdentifyOptions::free`](crate::identify::IdentifyOptions::free), or
    /// [`IdentifyOptions::extrinsics`](crate::identify::IdentifyOptions::extrinsics)
    /// not all 0); validation
    /// (and θ_0's Ē_p, at the initial values) then compares the model's
    /// reference point with the measured one. Absent otherwise. For `eiv`
    /// they are its batch Gauss-Newton start's estimate and σ, held by the
    /// filter, so the EIV θ covariance does not include their uncertainty
    /// ([`Warning::EivExtrinsicsHeld`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extrinsics: Option<ExtrinsicsEstimate>,
    /// The method's own results.
    #[serde(flatten)]
    pub(crate) detail: MethodDetail,
    /// Things the user should know (unobservable parameters, dropped
    /// segments, solver fallbacks).
    pub warnings: Vec<Warning>,
    /// Parameters held at θ_0 by [`CalibrationOptions::auto_fix`], in the
    /// order they were held (`options.identify.free` shows the final set).
    pub auto_fixed: Vec<Param>,
    /// Ē_p of θ and θ_0 on each validation drive, when the calibration was
    /// validated on other drives ([`super::Calibration::validate_on`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validate_on: Option<MultiValidation>,
    /// The σ for the next drive and its parts (within-drive, EIV fallback
    /// gap, between-drive; docs/method.md, "The σ for the next drive"):
    /// [`Self::result_sigma`] and JSON `next_drive_sigma`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) next_drive_sigma: Option<NextDriveSigma>,
    /// The options used.
    pub options: CalibrationOptions,
}

impl CalibrationReport {
    /// The method's own account of the fit, in lines as `odocal calibrate`
    /// prints them and the HTML report shows them ("Method details"):
    /// for EIV, `EivDetail::summary` with the sources the options held as
    /// known; for batch-gn, the fit (segments, iterations, termination,
    /// rcond) and which σ stands beside the model σ; for the 3-step method
    /// also step 1 (batch runs, picked estimates) and step 2 (segments
    /// compensated, QP jobs and failures, solver).
    ///
    /// ```
    /// use odocal::sim::{simulate, SimOptions};
    /// use odocal::{calibrate, CalibrationOptions};
    ///
    /// let out = simulate(&SimOptions { length_km: 2.0, ..SimOptions::paper(1) })?;
    /// let r = calibrate(&out.drive, &CalibrationOptions::default())?;
    /// let lines = r.method_details();
    /// assert!(lines.starts_with("EIV: ") || lines.starts_with("EIV: filter failed"), "{lines}");
    /// assert!(lines.contains("  result: "));
    /// # Ok::<(), odocal::Error>(())
    /// ```
    pub fn method_details(&self) -> String {
        match &self.detail {
            MethodDetail::Eiv(d) => {
                let known = match &self.options.method {
                    Method::Eiv(m) if !m.filter.fix_noise => m.filter.known_sources(),
                    _ => Vec::new(),
                };
                d.summary(&known)
            }
            MethodDetail::BatchGn(_) | MethodDetail::ThreeStep(_) => super::render::fit_lines(self),
        }
    }

    /// The final Gauss-Newton identification (batch-gn: the only one;
    /// three-step: step 3; eiv: the starting batch G-N on all segments).
    pub(crate) fn identification(&self) -> Option<&IdentifyReport> {
        match &self.detail {
            MethodDetail::ThreeStep(d) => Some(&d.identification),
            MethodDetail::BatchGn(d) => Some(&d.identification),
            MethodDetail::Eiv(d) => Some(&d.identification),
        }
    }

    /// Step 1 of the 3-step method.
    pub(crate) fn initial_step(&self) -> Option<&InitialStep> {
        match &self.detail {
            MethodDetail::ThreeStep(d) => Some(&d.initial_step),
            MethodDetail::BatchGn(_) | MethodDetail::Eiv(_) => None,
        }
    }

    /// Step 2 of the 3-step method.
    pub(crate) fn compensation(&self) -> Option<&CompensationStep> {
        match &self.detail {
            MethodDetail::ThreeStep(d) => Some(&d.compensation),
            MethodDetail::BatchGn(_) | MethodDetail::Eiv(_) => None,
        }
    }

    research_pub! {
        /// Wall time per stage, s (JSON `timing_s`).
        fn timing(&self) -> Timing {
            self.timing_s
        }
    }

    research_pub! {
        /// The σ for the next drive and its parts (JSON `next_drive_sigma`):
        /// what [`Self::result_sigma`] gives, term by term.
        fn next_drive_sigma(&self) -> Option<&NextDriveSigma> {
            self.next_drive_sigma.as_ref()
        }
    }

    research_pub! {
        /// One-σ model standard deviations of θ (square roots of the covariance diagonal).
        fn std_dev(&self) -> Theta {
            let c = &self.covariance;
            Theta { c_e: c[0][0].sqrt(), c_d: c[1][1].sqrt(), t_r: c[2][2].sqrt(), d: c[3][3].sqrt() }
        }
    }

    /// The cluster-robust covariance of the result ([`RobustCovariance`]:
    /// unlike the model covariance it allows for residuals correlated along
    /// and across segments), for batch-gn, whose result is one batch
    /// Gauss-Newton estimate. `None` for the other methods and when it could
    /// not be computed. The 3-step method's step 3 has one too
    /// (`identification.robust`), but it does not see steps 1–2 and is
    /// 5–13× smaller than the spread of 3-step estimates over seeds
    /// (`examples/gn_coverage.rs 20 12 paper 1300 three-step`), so it does
    /// not stand for the result; the 3-step's is its batch spread
    /// (`Self::result_covariance`).
    pub(crate) fn robust(&self) -> Option<&RobustCovariance> {
        outcome_robust(&self.detail)
    }

    /// The covariance of θ that stands for the result's uncertainty, the
    /// one the verdict's large-σ and cross-split checks use: batch-gn's
    /// cluster-robust covariance ([`Self::robust`]); the 3-step method's
    /// step-1 batch spread ([`super::three_step::ThreeStepUncertainty::batch_spread`]), since
    /// step 3's own σ sees only its compensated inputs; `None` otherwise
    /// (then the model covariance is all there is).
    pub(crate) fn result_covariance(&self) -> Option<&[[f64; 4]; 4]> {
        outcome_covariance(&self.detail)
    }

    /// A joint calibration's heading offset of each drive, as the JSON
    /// reports' `heading_offset_per_drive`: `[{source, fingerprint, value,
    /// sigma}]` (rad; σ the one that stands for the value,
    /// [`DriveHeadingOffset::result_std_dev`](crate::model::extrinsics::DriveHeadingOffset::result_std_dev)).
    /// `drives` are the reports' drive entries (objects with `role`,
    /// `path`, `fingerprint`); a drive is named by the entry of its index
    /// among those with role `"calibration"`. `None` without one offset per
    /// drive.
    pub(crate) fn heading_offset_per_drive(&self, drives: &[serde_json::Value]) -> Option<serde_json::Value> {
        let per = &self.extrinsics.as_ref()?.per_drive;
        if per.is_empty() {
            return None;
        }
        let calibration: Vec<&serde_json::Value> = drives.iter().filter(|d| d["role"] == "calibration").collect();
        let rows = per
            .iter()
            .map(|p| {
                let entry = calibration.get(p.drive);
                serde_json::json!({
                    "source": entry.map_or(serde_json::Value::Null, |e| e["path"].clone()),
                    "fingerprint": entry.map_or(serde_json::Value::Null, |e| e["fingerprint"].clone()),
                    "value": p.value,
                    "sigma": p.result_std_dev(),
                })
            })
            .collect();
        Some(serde_json::Value::Array(rows))
    }

    research_pub! {
        /// The method's within-drive 1σ: the square roots of the diagonal of
        /// `Self::result_covariance`, else of the model covariance (EIV's filter
        /// covariance, or a method's when nothing better was computed), with
        /// where it comes from. Held parameters (not free, or a zero covariance
        /// row: not estimated) have none. It says how well this drive
        /// determines θ, not how far the next drive's θ lies: that is
        /// [`Self::result_sigma`]. In the CLI's JSON `sigma_within_drive`.
        fn within_drive_sigma(&self) -> ResultSigma {
            within_sigma_of(&self.detail, &self.covariance, self.options.identify.free)
        }
    }

    /// The 1σ that stands for the result: the σ for the next drive of the
    /// same vehicle, `√(within-drive² + fallback gap²/3 + EIV t_r above its start² + between-drive²)`
    /// per parameter (docs/method.md, "The σ for the next drive"; its parts
    /// in JSON `next_drive_sigma`).
    /// The verdict, the parameter file ([`CalibrationReport::param_file`]),
    /// the HTML report and the CLI's JSON `sigma` all give this σ. A report
    /// without `next_drive_sigma` (written by an older odocal) gives the
    /// method's within-drive σ, labelled so
    /// (`covers`).
    pub fn result_sigma(&self) -> ResultSigma {
        let within = self.within_drive_sigma();
        match &self.next_drive_sigma {
            Some(n) => ResultSigma {
                covers: SigmaCovers::NextDrive,
                c_e: n.sigma[0],
                c_d: n.sigma[1],
                t_r: n.sigma[2],
                d: n.sigma[3],
                ..within
            },
            None => within,
        }
    }
}

impl CalibrationReport {
    /// With several drives of one vehicle calibrated jointly (`drives`, the
    /// drives the report's drive was joined from): fits each drive
    /// separately with batch Gauss-Newton (the report's free parameters and
    /// extrinsics settings; every cut segment, as EIV), pools them per
    /// parameter by random effects (`dersimonian_laird`
    /// on each drive's within-drive σ) and makes the between-drive σ of
    /// [`Self::result_sigma`] their τ (at least the prior). The joint fit's
    /// θ stays the result: it is the report's method on all the data,
    /// while the separate fits are batch G-N's, which carries an
    /// errors-in-variables bias under input noise; the pooled θ is
    /// reported beside it (`next_drive_sigma.pooled`). The verdict's σ
    /// checks are redone with the new σ. A drive whose separate fit fails
    /// (too short, nothing to fit) is left out; with fewer than two fits
    /// left, the report keeps the prior. Returns the number of drives
    /// pooled.
    ///
    /// # Errors
    /// None from the separate fits (they are left out); an error only when
    /// the report has no next-drive σ ([`Error::InvalidOption`](crate::Error)).
    pub(crate) fn pool_drives(&mut self, drives: &[&crate::Drive]) -> crate::Result<usize> {
        let Some(next) = self.next_drive_sigma.as_mut() else {
            return Err(crate::Error::InvalidOption {
                field: "next_drive_sigma",
                reason: "the report has no σ for the next drive to pool into".into(),
            });
        };
        let mut o = CalibrationOptions { method: Method::BatchGn, ..self.options.clone() };
        o.segments.min_peak_yaw_rate_rad_per_s = 0.0;
        o.auto_fix = false;
        o.trust.max_split_sigmas = 0.0;
        let fits: Vec<CalibrationReport> = drives.iter().filter_map(|d| super::calibrate(d, &o).ok()).collect();
        if fits.len() < 2 {
            return Ok(0);
        }
        let theta = fits.iter().map(|r| r.theta).collect();
        let sigma = fits.iter().map(|r| r.within_drive_sigma().to_array()).collect();
        next.with_pooled(crate::assess::pooling::PooledDrives::new("batch-gn".into(), theta, sigma));
        let reasons = std::mem::take(&mut self.verdict.reasons);
        let free = self.options.identify.free;
        // The pooled σ's between-drive part is the drives' measured spread:
        // a σ checked against the data, so a model σ no longer stands alone.
        let mut kept: Vec<_> =
            reasons
                .into_iter()
                .filter(|r| {
                    !crate::assess::trust::is_sigma_reason(r) && !matches!(r, VerdictReason::ModelSigmaOnly { .. })
                })
                .filter_map(|r| match r {
                    // θ's move with δ fitted, against the new σ.
                    VerdictReason::HeadingOffsetHeld { drive, held, fitted, sigma, param, shift, .. } => {
                        let shift_sigmas = shift.abs() / next.sigma[param.index()]?;
                        (shift_sigmas > super::held_offset::MAX_SHIFT_SIGMAS).then_some(
                            VerdictReason::HeadingOffsetHeld { drive, held, fitted, sigma, param, shift, shift_sigmas },
                        )
                    }
                    // The predicted bias, against the new σ: the drives'
                    // spread does not contain a bias they share.
                    VerdictReason::InputNoiseBias { param, estimate, bias, wheel_white_rel_sigma, .. } => {
                        let sigma = next.sigma[param.index()]?;
                        let sigmas = bias.abs() / sigma;
                        (sigmas > super::input_noise::MAX_BIAS_SIGMAS).then_some(VerdictReason::InputNoiseBias {
                            param,
                            estimate,
                            bias,
                            sigma,
                            sigmas,
                            wheel_white_rel_sigma,
                        })
                    }
                    r => Some(r),
                })
                .collect();
        kept.extend(crate::assess::trust::sigma_reasons(
            &self.theta,
            &self.initial.theta,
            free,
            next,
            &self.options.trust,
        ));
        self.verdict = Verdict::from_reasons(kept);
        Ok(fits.len())
    }
}

/// The within-drive σ of a method's result (see
/// [`CalibrationReport::within_drive_sigma`]).
pub(crate) fn within_sigma_of(detail: &MethodDetail, covariance: &[[f64; 4]; 4], free: ParamSet) -> ResultSigma {
    let (source, c) = match (detail, outcome_covariance(detail)) {
        (MethodDetail::BatchGn(_) | MethodDetail::Eiv(_), Some(c)) => (SigmaSource::ClusterRobust, c),
        (MethodDetail::ThreeStep(_), Some(c)) => (SigmaSource::BatchSpread, c),
        (_, c) => (SigmaSource::Model, c.unwrap_or(covariance)),
    };
    let sd: [Option<f64>; 4] = std::array::from_fn(|i| {
        let estimated = Param::from_index(i).is_some_and(|p| free.contains(p)) && covariance[i][i] != 0.0;
        estimated.then(|| c[i][i].max(0.0).sqrt())
    });
    ResultSigma { source, covers: SigmaCovers::WithinDrive, c_e: sd[0], c_d: sd[1], t_r: sd[2], d: sd[3] }
}

/// The σ for the next drive of one drive's result (`crate::pooling`):
/// the within-drive σ (for a free parameter the EIV filter held at its
/// batch Gauss-Newton start's estimate, the start's σ, when the start
/// estimated it and found it observable: the value came from there, so it
/// is not held; one the start named not observable stays at θ_0), after an EIV
/// fallback the gap to EIV's own estimate when that passes the
/// plausibility guards (or to EIV's fit with the held noise levels
/// released, when that passes the checks and the guards:
/// [`super::eiv::HeldNoiseReleased`]; when the result is EIV's refit, the gap to its
/// batch Gauss-Newton start), when the result is EIV's own estimate its
/// t_r above its start's, and the prior between-drive σ.
pub(crate) fn next_drive_of(
    theta: &Theta,
    detail: &MethodDetail,
    within: &ResultSigma,
    free: ParamSet,
    opts: &CalibrationOptions,
) -> NextDriveSigma {
    let mut w = within.to_array();
    let mut gap = [0.0; 4];
    let mut released_held = Vec::new();
    let mut unchecked = None;
    let mut from_start = [0.0; 4];
    if let MethodDetail::Eiv(d) = detail {
        let start = &d.identification;
        let start_sd = start.robust_or_model_covariance();
        for (i, w) in w.iter_mut().enumerate() {
            let v = start_sd[i][i];
            if w.is_none() && start_estimated(d, free, i) && v.is_finite() {
                *w = Some(v.max(0.0).sqrt());
            }
        }
        if d.eiv_result == EivOutcome::Eiv {
            from_start = start_robust_floor(d, free, &mut w);
        }
        let plausible = |t: &Theta| {
            crate::assess::trust::check_theta(t, &opts.theta0, free, None, 1.0, &opts.trust.guards).is_empty()
        };
        let eiv = d.eiv.as_ref().filter(|e| plausible(&e.theta));
        let released = d.held_noise_released.as_ref().filter(|r| r.passes() && plausible(&r.theta));
        // The other estimate: after a fallback EIV's fit with the held
        // noise levels released when it passes the checks, else EIV's
        // own (neither plausible: the fallback is unchecked); the batch
        // G-N start after a refit.
        let other = match d.eiv_result {
            EivOutcome::BatchGnFallback => {
                if let Some(r) = released {
                    released_held = r.held.clone();
                    Some((r.theta, r.free))
                } else if let Some(e) = eiv {
                    Some((e.theta, e.free))
                } else {
                    unchecked = d.eiv.as_ref().map(|e| fallback_unchecked(e, opts));
                    None
                }
            }
            EivOutcome::Eiv if d.refit => eiv.map(|e| (start.theta, e.free)),
            EivOutcome::Eiv => None,
        };
        if let Some((other, other_free)) = other {
            let (a, b) = (other.to_array(), theta.to_array());
            for i in 0..4 {
                let g = (a[i] - b[i]).abs();
                if other_free[i] && w[i].is_some() && g.is_finite() {
                    gap[i] = g;
                }
            }
        }
    }
    let mut n = NextDriveSigma::one_drive(theta, w, gap);
    n.within_from_start = from_start;
    n.gap_is_refit = matches!(detail, MethodDetail::Eiv(d) if d.refit && d.eiv_result == EivOutcome::Eiv);
    n.gap_released_noise = released_held;
    n.fallback_unchecked = unchecked;
    if let Some((excess, cov)) = eiv_t_r_above_start(detail, free) {
        n.with_t_r_above_start(excess, cov);
    }
    if let Some((fit, without_floor)) = eiv_without_heading_drift_floor(detail) {
        n.with_heading_drift_floor(fit, without_floor);
    }
    if let MethodDetail::Eiv(EivDetail { eiv: Some(e), .. }) = detail {
        let clamped = e.warnings.iter().any(|w| {
            matches!(w, crate::eiv::EivWarning::NoiseAtUpperClamp { source: crate::eiv::NoiseSource::WheelCommon, .. })
        });
        n.with_common_mode(e.noise.wheel_common_rel_sigma, clamped);
    }
    n
}

/// Whether EIV's batch Gauss-Newton start estimated parameter `i`: free,
/// not held by the start, observable there, with a covariance row.
fn start_estimated(d: &EivDetail, free: ParamSet, i: usize) -> bool {
    let start = &d.identification;
    Param::from_index(i).is_some_and(|p| {
        free.contains(p) && !d.start_held.contains(&p) && !start.observability.unobservable.contains(p)
    }) && start.covariance[i][i] > 0.0
}

/// Raises EIV's within-drive σ `w` to its batch Gauss-Newton start's
/// cluster-robust σ where that is larger (`crate::pooling`, `σ_within`),
/// for the parameters both estimated; returns the raised values (zeros
/// elsewhere). Nothing without a cluster-robust σ (too few clusters): the
/// start's model σ assumes independent residuals and bounds nothing.
fn start_robust_floor(d: &EivDetail, free: ParamSet, w: &mut [Option<f64>; 4]) -> [f64; 4] {
    let mut raised = [0.0; 4];
    let Some(robust) = &d.identification.robust else { return raised };
    for (i, w) in w.iter_mut().enumerate() {
        let r = robust.covariance[i][i];
        if let Some(s) = w {
            if start_estimated(d, free, i) && r.is_finite() && r > *s * *s {
                *s = r.sqrt();
                raised[i] = *s;
            }
        }
    }
    raised
}

/// After a fallback from EIV's fit `e` whose θ fails the guards (with no
/// passing, plausible fit with held noise levels released): the wheel
/// noise sources at their upper clamp and the levels held
/// (`crate::assess::pooling::FallbackUnchecked`).
fn fallback_unchecked(
    e: &crate::eiv::EivReport,
    opts: &CalibrationOptions,
) -> crate::assess::pooling::FallbackUnchecked {
    use crate::eiv::{EivWarning, NoiseSource};
    let clamped = e
        .warnings
        .iter()
        .filter_map(|w| match w {
            EivWarning::NoiseAtUpperClamp { source, .. }
                if matches!(
                    source,
                    NoiseSource::WheelWhite | NoiseSource::WheelCommon | NoiseSource::WheelDifferential
                ) =>
            {
                Some(*source)
            }
            _ => None,
        })
        .collect();
    let held = match &opts.method {
        crate::Method::Eiv(m) => m.filter.known_sources(),
        _ => Vec::new(),
    };
    crate::assess::pooling::FallbackUnchecked { clamped, held }
}

/// When the result is EIV's own estimate (not a refit) with t_r estimated
/// by it and by its batch Gauss-Newton start: how far EIV's t_r lies above
/// the start's (negative when below), with EIV's covariance
/// (`crate::pooling`, `a`).
fn eiv_t_r_above_start(detail: &MethodDetail, free: ParamSet) -> Option<(f64, &[[f64; 4]; 4])> {
    let MethodDetail::Eiv(d) = detail else { return None };
    let e = d.eiv.as_ref()?;
    let start = &d.identification;
    let estimated = free.contains(Param::TR)
        && e.free[2]
        && !d.start_held.contains(&Param::TR)
        && !start.observability.unobservable.contains(Param::TR);
    (d.eiv_result == EivOutcome::Eiv && !d.refit && estimated).then_some((e.theta.t_r - start.theta.t_r, &e.covariance))
}

/// When the result is EIV's own estimate (not a refit) and its fit holds
/// the reference's heading drift at its floor: its θ before the bias
/// correction and the same fit's θ without the floor (`crate::pooling`, `f`).
fn eiv_without_heading_drift_floor(detail: &MethodDetail) -> Option<(&Theta, &Theta)> {
    let MethodDetail::Eiv(d) = detail else { return None };
    let e = d.eiv.as_ref()?;
    let without = e.heading_drift.as_ref()?.theta_without_floor.as_ref()?;
    (d.eiv_result == EivOutcome::Eiv && !d.refit).then_some((&e.theta_uncorrected, without))
}

research_pub! {
    /// Which covariance a result's σ comes from ([`CalibrationReport::result_sigma`]).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
    #[serde(rename_all = "kebab-case")]
    enum SigmaSource {
        /// batch-gn's cluster-robust covariance (`RobustCovariance`).
        ClusterRobust,
        /// The 3-step method's step-1 batch spread: the sample covariance of its
        /// plausible batch estimates, scaled to all the data.
        BatchSpread,
        /// The model covariance ([`CalibrationReport::covariance`]): EIV's
        /// filter covariance (per parameter the larger of `H_θ⁻¹` and a block
        /// sandwich, at the fitted noise levels;
        /// `crate::eiv::EivReport::covariance`) (after an EIV fallback the start's cluster-robust σ stands,
        /// where computed), or batch-gn's / step 3's `σ²(JᵀWJ)⁻¹` when the robust or
        /// batch-spread σ could not be computed (then it understates the
        /// uncertainty under input noise).
        Model,
    }
}

impl SigmaSource {
    /// The name in reports (`cluster-robust`, `batch-spread`, `model`).
    pub(crate) fn name(self) -> &'static str {
        match self {
            SigmaSource::ClusterRobust => "cluster-robust",
            SigmaSource::BatchSpread => "batch-spread",
            SigmaSource::Model => "model",
        }
    }
}

impl std::fmt::Display for SigmaSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What a σ covers ([`ResultSigma::covers`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SigmaCovers {
    /// The spread of θ on the next drive of the same vehicle: within-drive
    /// ⊕ between-drive (`crate::pooling`).
    NextDrive,
    /// This drive only: the method's within-drive σ.
    #[default]
    WithinDrive,
}

impl std::fmt::Display for SigmaCovers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            SigmaCovers::NextDrive => crate::assess::pooling::NEXT_DRIVE_SIGMA_LABEL,
            SigmaCovers::WithinDrive => "within-drive σ",
        })
    }
}

/// The 1σ of a calibration's result, per parameter (SI units; `None` for
/// a parameter held), and what it covers. In JSON, with which covariance
/// its within-drive part comes from (`source`, as the parameter file's
/// provenance `sigma` names it):
/// `{"source": "batch-spread", "covers": "next-drive", "c_e": …, "c_d": …, "t_r": …, "d": null}`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ResultSigma {
    /// Which covariance the within-drive part comes from.
    pub(crate) source: SigmaSource,
    /// What the σ covers: the next drive (within-drive ⊕ between-drive) or
    /// this drive only.
    #[serde(default)]
    pub covers: SigmaCovers,
    /// 1σ of c_e, m.
    pub c_e: Option<f64>,
    /// 1σ of c_d, m.
    pub c_d: Option<f64>,
    /// 1σ of t_r, m.
    pub t_r: Option<f64>,
    /// 1σ of d, m per m/s².
    pub d: Option<f64>,
}

impl ResultSigma {
    research_pub! {
        /// Which covariance the within-drive part comes from.
        fn source(&self) -> SigmaSource {
            self.source
        }
    }

    /// `[c_e, c_d, t_r, d]` (outside the crate: `<[Option<f64>; 4]>::from(sigma)`).
    pub(crate) fn to_array(self) -> [Option<f64>; 4] {
        [self.c_e, self.c_d, self.t_r, self.d]
    }
}

/// Each parameter's 1σ in the units and digits of θ's `Display`, `held`
/// for a parameter without one: `c_e ± 0.001124 m, c_d ± 0.2535 mm, t_r ±
/// 0.010935 m, d held`. What it covers is [`ResultSigma::covers`].
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{calibrate, CalibrationOptions, sim::{simulate, SimOptions}};
/// let drive = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) })?.drive;
/// let report = calibrate(&drive, &CalibrationOptions::default())?;
/// let sigma = report.result_sigma();
/// println!("θ: {}\nσ: {sigma} ({})", report.theta, sigma.covers);
/// assert!(sigma.to_string().starts_with("c_e ± "));
/// # Ok(()) }
/// ```
impl std::fmt::Display for ResultSigma {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let sigma = [self.c_e, self.c_d, self.t_r, self.d];
        for (i, ((name, scale, unit, digits), sigma)) in crate::model::THETA_UNITS.iter().zip(sigma).enumerate() {
            if i > 0 {
                f.write_str(", ")?;
            }
            match sigma {
                Some(s) => write!(f, "{name} ± {:.digits$} {unit}", s * scale)?,
                None => write!(f, "{name} held")?,
            }
        }
        Ok(())
    }
}

/// `[c_e, c_d, t_r, d]`.
impl From<ResultSigma> for [Option<f64>; 4] {
    fn from(sigma: ResultSigma) -> Self {
        sigma.to_array()
    }
}

impl CalibrationReport {
    /// The parameter file of this calibration: θ with the σ that stands for
    /// the result ([`CalibrationReport::result_sigma`]: the σ for the next
    /// drive; the same σ as the verdict, the HTML report and the CLI's JSON
    /// `sigma`), `<name>_held` for held parameters, the reference
    /// extrinsics when the calibration involved them (with their own σ,
    /// labelled `extrinsics_sigma`, `extrinsics_sigma_covers`:
    /// [`ParamFile`]'s format), the verdict with its
    /// reasons, `<name>_observable: false` for a free parameter the result
    /// names not observable (its `observability`, as the verdict, the text
    /// and the JSON name them), and provenance (`input`, `method`, `sigma`: which covariance
    /// the within-drive part comes from, `sigma_covers`: what the σ covers,
    /// the odocal version, today's date).
    pub fn param_file(&self, input: &str) -> ParamFile {
        let sigma = self.result_sigma();
        let mut f = ParamFile::from_theta(&self.theta, sigma.to_array(), input, &self.method);
        f.provenance.insert(2, ("sigma".into(), sigma.source.name().into()));
        f.provenance.insert(3, ("sigma_covers".into(), sigma.covers.to_string()));
        if let Some(x) = &self.extrinsics {
            f.add_extrinsics(x);
        }
        // The result's own check, as the verdict and the reports name it:
        // for method eiv the filter's (its batch G-N start, fitted with
        // every parameter free, may name more: c_d beside t_r on a drive
        // without turns, which the filter determines with t_r held); after
        // a fallback, the start's.
        f.mark_not_observable(self.observability.unobservable.intersection(self.options.identify.free));
        f.verdict = Some(self.verdict.level.to_string());
        f.verdict_reasons = self.verdict.reasons.iter().map(|r| r.to_string()).collect();
        f
    }
}

/// Whose model σ stands for the result, and what a σ checked against the
/// data needs, when [`outcome_covariance`] has none for a method whose
/// model σ is known to be too small (batch G-N, the 3-step, EIV's
/// fallback); `None` for EIV's own estimate, whose σ is its filter's.
pub(super) fn model_sigma_only(detail: &MethodDetail, opts: &CalibrationOptions) -> Option<(&'static str, String)> {
    if outcome_covariance(detail).is_some() {
        return None;
    }
    let o = &opts.identify;
    let robust = || {
        format!(
            "its cluster-robust σ needs selected segments in at least {} blocks of {} samples: calibrate on a \
             longer drive, or on several drives together",
            o.robust_min_clusters, o.robust_block_steps
        )
    };
    match detail {
        MethodDetail::BatchGn(_) => Some(("batch Gauss-Newton", robust())),
        MethodDetail::Eiv(d) if d.eiv_result == EivOutcome::BatchGnFallback => {
            Some(("the EIV fallback's batch Gauss-Newton", robust()))
        }
        MethodDetail::ThreeStep(_) => Some((
            "the 3-step method",
            "its σ from the spread of step-1 batch estimates needs more plausible batches: calibrate on a \
             longer drive, or on several drives together"
                .to_string(),
        )),
        MethodDetail::Eiv(_) => None,
    }
}

/// Whose model σ stands for the estimated extrinsics `x`, and what a σ
/// checked against the data needs, when they have no cluster-robust σ
/// ([`crate::VerdictReason::ExtrinsicsModelSigmaOnly`]): always for the
/// 3-step (its batch spread covers θ alone, and step 3's cluster-robust σ
/// does not stand for its result), for batch G-N and EIV (whose extrinsics
/// are its batch G-N start's) when that fit had too few clusters. `None`
/// without an estimated lever arm: the heading offset alone is the
/// reference's, re-estimated on every drive the result is validated on,
/// so its σ does not travel with θ as the lever arm's does.
pub(super) fn extrinsics_model_sigma_only(
    detail: &MethodDetail,
    opts: &CalibrationOptions,
    x: Option<&ExtrinsicsEstimate>,
) -> Option<(&'static str, String)> {
    let x = x?;
    let lever_arm = x.free.contains(Param::LeverX) || x.free.contains(Param::LeverY);
    if !lever_arm || x.robust.is_some() {
        return None;
    }
    let o = &opts.identify;
    let robust = || {
        format!(
            "a cluster-robust σ needs selected segments in at least {} blocks of {} samples: calibrate on a longer \
             drive, or on several drives together",
            o.robust_min_clusters, o.robust_block_steps
        )
    };
    Some(match detail {
        MethodDetail::ThreeStep(_) => (
            "the 3-step method",
            "its batch-spread σ covers θ alone: estimate the extrinsics with eiv or batch-gn, whose cluster-robust \
             σ checks them, or hold them at measured values"
                .to_string(),
        ),
        MethodDetail::BatchGn(_) => ("batch Gauss-Newton", robust()),
        MethodDetail::Eiv(_) => ("EIV's batch Gauss-Newton start", robust()),
    })
}

/// The batch Gauss-Newton whose θ is the result, and what to call it in
/// the verdict; `None` when the EIV filter's θ is the result (its own
/// convergence is an EIV check, [`crate::eiv::EivWarning`]).
pub(super) fn result_identification(detail: &MethodDetail) -> Option<(&'static str, &IdentifyReport)> {
    match detail {
        MethodDetail::BatchGn(d) => Some(("batch Gauss-Newton", &d.identification)),
        MethodDetail::ThreeStep(d) => Some(("the 3-step's final identification", &d.identification)),
        MethodDetail::Eiv(d) if d.eiv_result == EivOutcome::BatchGnFallback => {
            Some(("the EIV fallback's batch Gauss-Newton", &d.identification))
        }
        MethodDetail::Eiv(_) => None,
    }
}
