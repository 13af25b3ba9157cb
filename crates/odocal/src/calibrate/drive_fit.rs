//! `validate` with its verdict: Ē_p of a given θ on a drive
//! ([`crate::assess::validate`]), judged against θ fitted on the same
//! drive ([`DriveFit`]).

use super::batch_gn::BatchGnOptions;
use super::{calibrate, CalibrationOptions, Method};
use crate::assess::position_error::mean_position_error_with;
use crate::assess::trust::VerdictReason;
use crate::assess::validate::{validate_theta, DriveFit, ValidateOptions, ValidateReport};
use crate::drive::segment::validation_segments;
use crate::drive::Drive;
use crate::error::Result;
use crate::identify::IdentifyOptions;
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
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{simulate, validate, SimOptions, ValidateOptions};
/// let s = simulate(&SimOptions { length_km: 2.0, substeps: 1, ..SimOptions::noise_free(1) })?;
/// let r = validate(&s.drive, &s.sidecar.theta_true, &ValidateOptions::default(), None)?;
/// assert!(r.validation.mean_position_error_m < 1e-6);
/// assert!(r.drive_fit.expect("the drive's own fit").fits);
/// # Ok(()) }
/// ```
///
/// θ is checked first ([`Theta::validate`]: finite, c_e and t_r positive),
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
    let mut report = validate_theta(drive, theta, opts, progress)?;
    if opts.fit_drive {
        match drive_fit(drive, theta, opts, report.validation.mean_position_error_m) {
            Ok(fit) => report.drive_fit = Some(fit),
            Err(why) => report.drive_fit_error = Some(why),
        }
    }
    Ok(report)
}

/// Batch Gauss-Newton on `drive` from `theta` (the paper's θ_0 when θ is
/// beyond the physical limits a start must keep), the heading offset free
/// when validation re-estimates it, the other extrinsics held at the
/// validation's; judged against `given_m`, Ē_p of θ. Batch G-N rather
/// than the default method: it is the reference the other methods are
/// judged against, and a fraction of their cost. Why there is no verdict
/// when the fit fails or is implausible (beyond the guards, or not moved
/// from θ: such a fit says nothing of how well θ fits). A fit whose Ē_p is
/// above θ's stands: θ fits the drive better than its own fit.
fn drive_fit(
    drive: &Drive,
    theta: &Theta,
    opts: &ValidateOptions,
    given_m: f64,
) -> std::result::Result<DriveFit, String> {
    let mut free = ParamSet::THETA;
    if opts.reestimate_heading_offset {
        free = free.with(Param::HeadingOffset);
    }
    let fit = CalibrationOptions {
        method: Method::BatchGn(BatchGnOptions::default()),
        theta0: if theta.check_physical_limits().is_ok() { *theta } else { Theta::PAPER_INITIAL },
        validation: opts.segments.clone(),
        identify: IdentifyOptions { free, extrinsics: opts.extrinsics, ..IdentifyOptions::default() },
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
        return Err(format!("batch G-N on this drive, started from θ: {}", implausible.join("; ")));
    }
    let extrinsics = r.extrinsics.as_ref().map_or(opts.extrinsics, |x| x.value);
    let own = validation_segments(drive, &opts.segments)
        .and_then(|segs| mean_position_error_with(drive, &segs, &r.theta, &extrinsics))
        .map_err(|e| e.to_string())?
        .mean_position_error_m;
    let heading_offset_rad = opts.reestimate_heading_offset.then_some(extrinsics.heading_offset);
    Ok(DriveFit::judge(r.theta, heading_offset_rad, own, given_m))
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

    /// The rule: within 1.6 times the fit's Ē_p, or within 1 cm of it.
    #[test]
    fn a_theta_fits_within_the_ratio_or_the_floor() {
        let t = Theta::PAPER_NOMINAL;
        assert!(DriveFit::judge(t, None, 1.0, 1.6).fits);
        assert!(!DriveFit::judge(t, None, 1.0, 1.61).fits);
        assert!(DriveFit::judge(t, None, 0.001, 0.011).fits);
        assert!(!DriveFit::judge(t, None, 0.001, 0.012).fits);
        assert_eq!(DriveFit::judge(t, None, 2.0, 1.0).ratio.to_bits(), 0.5f64.to_bits());
    }
}
