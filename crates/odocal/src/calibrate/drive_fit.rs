//! `validate` with its verdict: Ē_p of a given θ on a drive
//! ([`crate::assess::validate`]), judged against θ fitted on the same
//! drive ([`DriveFit`]).

use std::borrow::Cow;

use super::eiv::EivOutcome;
use super::{calibrate, CalibrationOptions, Method, MethodDetail};
use crate::assess::trust::VerdictReason;
use crate::assess::validate::{
    beyond_the_line, validate_theta, DriveFit, ValidateOptions, ValidateReport, FIT_FLOOR_M, FIT_RATIO,
};
use crate::drive::Drive;
use crate::error::Result;
use crate::identify::IdentifyOptions;
use crate::model::extrinsics::Extrinsics;
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;
use crate::progress::ProgressFn;

/// Ē_p of θ on the validation segments of `drive`, with the drive's own
/// heading offset when [`ValidateOptions::reestimate_heading_offset`], the
/// reachable minimum when [`ValidateOptions::reachable`], and the verdict
/// of [`ValidateOptions::fit_drive`] (on by default): whether θ fits the
/// drive as well as θ fitted on it ([`DriveFit`]). `progress` hears the
/// reachable-minimum search (one stage per box searched, advancing by one
/// per evaluation of Ē_p).
///
/// [`ValidateOptions::default`] validates at the rear axle with no heading
/// offset. For a calibration's θ, [`ValidateOptions::set_extrinsics`] with
/// its parameter file ([`CalibrationReport::param_file`](crate::CalibrationReport::param_file))
/// sets the reference extrinsics the calibration estimated and re-estimates
/// the drive's own heading offset, as `odocal validate --theta FILE` does
/// ([the crate's examples](crate#examples) show it).
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{validate, ValidateOptions, sim::{simulate, SimOptions}};
/// let s = simulate(&SimOptions { length_km: 2.0, substeps: 1, noise: "off".parse()?, ..SimOptions::paper(1) })?;
/// let r = validate(&s.drive, &s.sidecar.theta_true, &ValidateOptions::default(), None)?;
/// assert!(r.validation.mean_position_error_m < 1e-6);
/// assert!(r.drive_fit.expect("the drive's own fit").fits);
/// # Ok(()) }
/// ```
///
/// θ is checked first (finite, c_e and t_r positive),
/// then the options, then the drive's wheel, heading and
/// lateral-acceleration conventions at θ, as `calibrate` checks them at θ_0.
/// A drive that cannot be fitted (too few turning segments, say) is still
/// validated: [`ValidateReport::drive_fit_error`] says why it has no
/// verdict.
///
/// # Errors
/// [`Error::InvalidTheta`](crate::Error::InvalidTheta) for a θ that is not
/// finite or has c_e or t_r not positive;
/// [`Error::InvalidOption`](crate::Error::InvalidOption) naming an invalid
/// option; [`Error::InvalidDrive`](crate::Error::InvalidDrive) for a
/// convention the drive breaks; a drive too short for one validation
/// segment, non-finite errors.
pub fn validate(
    drive: &Drive,
    theta: &Theta,
    opts: &ValidateOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<ValidateReport> {
    let own = own_heading_offset(drive, opts);
    let opts = &match own {
        Some(delta) => Cow::Owned(ValidateOptions {
            extrinsics: Extrinsics { heading_offset: delta, ..opts.extrinsics },
            reestimate_heading_offset: false,
            ..opts.clone()
        }),
        None => Cow::Borrowed(opts),
    };
    let mut report = validate_theta(drive, theta, opts, progress)?;
    report.calibration_drive = own.is_some();
    if opts.fit_drive {
        match drive_fit(drive, theta, opts, report.validation.mean_position_error_m) {
            Ok(fit) => report.drive_fit = Some(fit),
            Err(why) => report.drive_fit_error = Some(why),
        }
    }
    Ok(report)
}

/// The heading offset the θ's calibration estimated for `drive`, when
/// validation would re-estimate the drive's own and the drive is one that
/// calibration ran on ([`ValidateOptions::calibration_heading_offsets`]).
fn own_heading_offset(drive: &Drive, opts: &ValidateOptions) -> Option<f64> {
    if !opts.reestimate_heading_offset || opts.calibration_heading_offsets.is_empty() {
        return None;
    }
    let print = drive.fingerprint();
    opts.calibration_heading_offsets.iter().find(|(p, _)| *p == print).map(|(_, delta)| *delta)
}

/// θ fitted on `drive`, judged against `given_m`, Ē_p of θ: batch
/// Gauss-Newton from θ and from the paper's θ_0, the heading offset free
/// when validation re-estimates it, the other extrinsics held at the
/// validation's; of the fits that are plausible, the one with the lower
/// Ē_p. Two starts, because one fit alone can stop where it started: from
/// a θ already at the drive's optimum it takes no step (and is named
/// "did not move"), and from a θ far off its first step can raise the
/// cost. Batch G-N first: it is the reference the other methods are judged
/// against, and a fraction of their cost. The parameters a drive cannot
/// determine are held at the start ([`CalibrationOptions::auto_fix`]).
///
/// A fit whose Ē_p is more than 1 cm above θ's found nothing better than
/// θ, and such a fit can only make θ look good; one beyond [`FIT_RATIO`]
/// times θ's is a failed fit, no evidence at all; one that held parameters
/// of θ the drive does not determine fitted the rest on the few turning
/// segments batch G-N uses, and ends near any θ. Then (and when batch G-N
/// gives nothing plausible) the drive is also fitted the way `calibrate`
/// fits it by default (the default method from θ_0, on every segment), and
/// the better of the plausible fits counts: a drive that hardly turns is
/// judged on what the drive shows (the highway van: batch G-N 112 m
/// against the default's 20 m; the RAV4 with another vehicle's θ: 9.6 m,
/// worse than θ's 7.5 m, or with its δ held 18.8 m against θ's 26.0 m,
/// against the default's 2.3 m). Why there is no verdict when no fit is
/// left.
fn drive_fit(
    drive: &Drive,
    theta: &Theta,
    opts: &ValidateOptions,
    given_m: f64,
) -> std::result::Result<DriveFit, String> {
    let batch_gn = Method::BatchGn;
    let mut starts = vec![("θ", *theta), ("θ_0", Theta::PAPER_INITIAL)];
    starts.retain(|(_, t)| t.check_physical_limits().is_ok());
    let mut best: Option<DriveFit> = None;
    let mut why: Vec<(Vec<&str>, String)> = Vec::new();
    for (name, start) in starts {
        match fit_from(drive, &start, &batch_gn, opts, given_m) {
            Ok(fit) if best.as_ref().is_none_or(|b| fit.mean_position_error_m < b.mean_position_error_m) => {
                best = Some(fit)
            }
            Ok(_) => {}
            Err(e) => match why.iter_mut().find(|(_, w)| *w == e) {
                Some((names, _)) => names.push(name),
                None => why.push((vec![name], e)),
            },
        }
    }
    // Batch G-N's fit stands unless it is worse than θ itself: a fit that
    // found nothing better than θ can only make θ look good.
    let (kept, batch_gn_failed) = match best {
        Some(fit) if !worse(&fit, given_m) && fit.held.is_empty() => return Ok(fit),
        Some(fit) if !worse(&fit, given_m) => {
            let why = format!("{} held {}, which this drive does not determine", fit.method, fit.held);
            (Some(fit), why)
        }
        Some(fit) if !failed(&fit, given_m) => {
            let why = format!("{} gives {:.4} m, more than θ's {given_m:.4} m", fit.method, fit.mean_position_error_m);
            (Some(fit), why)
        }
        Some(fit) => (None, failed_fit(&fit, given_m)),
        None => {
            let why: Vec<String> = why.iter().map(|(names, w)| format!("from {}: {w}", names.join(" and "))).collect();
            (None, format!("batch G-N on this drive {}", why.join("; ")))
        }
    };
    let default = Method::default();
    match (fit_from(drive, &Theta::PAPER_INITIAL, &default, opts, given_m), kept) {
        (Ok(fit), kept)
            if !failed(&fit, given_m)
                && kept.as_ref().is_none_or(|k| fit.mean_position_error_m < k.mean_position_error_m) =>
        {
            Ok(DriveFit { batch_gn_failure: Some(batch_gn_failed), ..fit })
        }
        (_, Some(kept)) => Ok(kept),
        (Ok(fit), None) => Err(format!("{batch_gn_failed}; the default method: {}", failed_fit(&fit, given_m))),
        (Err(e), None) => Err(format!("{batch_gn_failed}; the default method ({default}) from θ_0: {e}")),
    }
}

/// A fit worse than the given θ by more than [`FIT_FLOOR_M`].
fn worse(fit: &DriveFit, given_m: f64) -> bool {
    fit.mean_position_error_m > given_m + FIT_FLOOR_M
}

/// A fit whose Ē_p lies beyond the verdict's line from θ's
/// ([`beyond_the_line`], the rule by which θ does not fit, the other way
/// round): it did not find the drive's optimum. Within the 1 cm floor,
/// where a noise-free drive's Ē_p are rounding, no fit has failed.
fn failed(fit: &DriveFit, given_m: f64) -> bool {
    beyond_the_line(fit.mean_position_error_m, given_m)
}

/// Why a failed fit is no evidence.
fn failed_fit(fit: &DriveFit, given_m: f64) -> String {
    format!(
        "{} gives {:.4} m, more than {FIT_RATIO} times θ's {given_m:.4} m, and does not fit this drive",
        fit.method, fit.mean_position_error_m
    )
}

/// `method` on `drive` from `start` (module docs of [`drive_fit`]), judged
/// against `given_m` (with the parameters of θ it held because the drive
/// does not determine them, [`DriveFit::held`]); the reason when the fit
/// is implausible or fails.
fn fit_from(
    drive: &Drive,
    start: &Theta,
    method: &Method,
    opts: &ValidateOptions,
    given_m: f64,
) -> std::result::Result<DriveFit, String> {
    let mut free = ParamSet::THETA;
    if opts.reestimate_heading_offset {
        free = free.with(Param::HeadingOffset);
    }
    let fit = CalibrationOptions {
        method: method.clone(),
        theta0: *start,
        validation: opts.segments.clone(),
        identify: IdentifyOptions { free, extrinsics: opts.extrinsics, ..IdentifyOptions::default() },
        // A drive that does not resolve every parameter (one that hardly
        // turns) is still fitted in those it resolves, the others held.
        auto_fix: true,
        ..CalibrationOptions::default()
    };
    let r = calibrate(drive, &fit).map_err(|e| e.to_string())?;
    let implausible: Vec<String> = r
        .verdict
        .reasons
        .iter()
        .filter(|x| matches!(x, VerdictReason::Implausible { .. }))
        .map(ToString::to_string)
        .collect();
    if !implausible.is_empty() {
        return Err(implausible.join("; "));
    }
    // The calibration validated its θ on this drive's validation segments
    // (`validation` is `opts.segments`) with the extrinsics it fitted: Ē_p
    // of the fit on the segments θ's Ē_p was taken on.
    let extrinsics = r.extrinsics.as_ref().map_or(opts.extrinsics, |x| x.value);
    let own = r.validation.mean_position_error_m;
    let heading_offset_rad = opts.reestimate_heading_offset.then_some(extrinsics.heading_offset);
    let method = match &r.detail {
        MethodDetail::Eiv(d) if d.eiv_result == EivOutcome::BatchGnFallback => {
            format!("{} (batch-gn fallback)", r.method)
        }
        _ => r.method.clone(),
    };
    let held = r.auto_fixed.iter().copied().collect::<ParamSet>().intersection(ParamSet::THETA);
    Ok(DriveFit { held, ..DriveFit::judge(r.theta, heading_offset_rad, &method, own, given_m) })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, SimOptions};

    /// A noise-free 3 km drive: the true θ fits it (its Ē_p and the fit's
    /// are at round-off, within the floor), θ with t_r 3 % wide does not,
    /// and the fit recovers the truth from it; `fit_drive: false` leaves
    /// the fit out.
    #[test]
    fn the_truth_fits_a_noise_free_drive_and_a_wide_t_r_does_not() {
        let out = simulate(&SimOptions { length_km: 3.0, substeps: 1, ..SimOptions::noise_free(5) }).expect("sim");
        let truth = out.sidecar.theta_true;
        let opts = ValidateOptions::default();
        let r = validate(&out.drive, &truth, &opts, None).expect("validate");
        let fit = r.drive_fit.as_ref().expect("fit");
        assert!(fit.fits, "{fit:?}");
        assert!(fit.mean_position_error_m < 1e-6, "{fit:?}");
        assert_eq!(fit.heading_offset_rad, None);
        assert_eq!(fit.method, "batch-gn");
        assert_eq!(fit.batch_gn_failure, None);

        let wide = Theta { t_r: truth.t_r * 1.03, ..truth };
        let r = validate(&out.drive, &wide, &opts, None).expect("validate");
        let fit = r.drive_fit.as_ref().expect("fit");
        assert!(!fit.fits, "{fit:?}");
        assert!(fit.ratio > 1e3, "{fit:?}");
        assert!((fit.theta.t_r - truth.t_r).abs() < 1e-6, "fitted t_r {} vs {}", fit.theta.t_r, truth.t_r);
        assert!(r.drive_fit_error.is_none());

        let r = validate(&out.drive, &wide, &ValidateOptions { fit_drive: false, ..opts }, None).expect("validate");
        assert!(r.drive_fit.is_none() && r.drive_fit_error.is_none());
    }

    /// θ at the drive's optimum (batch G-N's own result on a 3 km paper
    /// drive): the fit from θ takes no step and is implausible ("did not
    /// move"), the fit from θ_0 is that calibration again, so θ fits with a
    /// ratio of exactly 1.
    #[test]
    fn a_theta_at_the_drive_s_optimum_fits_with_a_ratio_of_one() {
        let out = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(3) }).expect("sim");
        let opts = CalibrationOptions { method: Method::BatchGn, ..Default::default() };
        let own = calibrate(&out.drive, &opts).expect("calibrate").theta;
        let r = validate(&out.drive, &own, &ValidateOptions::default(), None).expect("validate");
        let fit = r.drive_fit.as_ref().unwrap_or_else(|| panic!("no fit: {:?}", r.drive_fit_error));
        assert!(fit.fits, "{fit:?}");
        assert_eq!(fit.ratio.to_bits(), 1f64.to_bits(), "{fit:?}");
    }

    /// The rule: within 1.6 times the fit's Ē_p, or within 1 cm of it.
    #[test]
    fn a_theta_fits_within_the_ratio_or_the_floor() {
        let t = Theta::PAPER_NOMINAL;
        assert!(DriveFit::judge(t, None, "batch-gn", 1.0, 1.6).fits);
        assert!(!DriveFit::judge(t, None, "batch-gn", 1.0, 1.61).fits);
        assert!(DriveFit::judge(t, None, "batch-gn", 0.001, 0.011).fits);
        assert!(!DriveFit::judge(t, None, "batch-gn", 0.001, 0.012).fits);
        assert_eq!(DriveFit::judge(t, None, "batch-gn", 2.0, 1.0).ratio.to_bits(), 0.5f64.to_bits());
    }

    /// A fit more than 1.6 times worse than θ failed, one more than 1 cm
    /// worse is worse (both send `validate` on to the default method), and
    /// the reason names the method.
    #[test]
    fn a_fit_far_worse_than_theta_failed() {
        let t = Theta::PAPER_NOMINAL;
        assert!(!failed(&DriveFit::judge(t, None, "batch-gn", 1.5, 1.0), 1.0));
        let far = DriveFit::judge(t, None, "batch-gn", 1.61, 1.0);
        assert!(failed(&far, 1.0));
        // Worse than θ by more than 1 cm: the default method gets a chance.
        assert!(worse(&DriveFit::judge(t, None, "batch-gn", 1.02, 1.0), 1.0));
        assert!(!worse(&DriveFit::judge(t, None, "batch-gn", 1.005, 1.0), 1.0));
        // Rounding on a noise-free drive: five times worse, within 1 cm.
        assert!(!failed(&DriveFit::judge(t, None, "batch-gn", 5e-9, 1e-9), 1e-9));
        assert!(!failed(&DriveFit::judge(t, None, "batch-gn", 0.0105, 0.001), 0.001));
        assert!(failed(&DriveFit::judge(t, None, "batch-gn", 0.0115, 0.001), 0.001));
        let why = failed_fit(&far, 1.0);
        assert!(why.starts_with("batch-gn gives 1.6100 m, more than 1.6 times"), "{why}");
    }
}
