//! Validation of a calibrated θ by dead reckoning (docs/method.md §7): [`validate_theta`]
//! is the core of the `validate` command, Ē_p ([`super::position_error`]) of a θ and,
//! optionally, the reachable minimum ([`super::reachable`]) on the same
//! segments; [`MultiValidation`] is the table of validation on several
//! drives ([`super::validation_drives`]).

use serde::{Deserialize, Serialize};

use super::heading_offset::{fit_heading_offset, with_fit, HeadingOffsetFit};
use super::position_error::{mean_position_error_with, ValidationReport};
use super::reachable::{reachable_minimum, ReachableOptions, ReachableReport};
use crate::drive::segment::{too_short_for_validation, validation_segments, ValidationSegmentOptions};
use crate::drive::Drive;
use crate::error::Result;
use crate::io::param_file::ParamFile;
use crate::model::extrinsics::Extrinsics;
use crate::model::param::ParamSet;
use crate::model::Theta;
use crate::progress::ProgressFn;

/// Settings of [`validate`](crate::validate()).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidateOptions {
    /// Validation segments. Default K_v = 1300, stride 650, offset 50.
    pub segments: ValidationSegmentOptions,
    /// Also search the reachable minimum of Ē_p with these settings. Default none.
    /// The search uses [`ValidateOptions::extrinsics`] (its own
    /// [`ReachableOptions::extrinsics`] is replaced), so its minimum and Ē_p
    /// of θ are computed against the same reference mount.
    pub reachable: Option<ReachableOptions>,
    /// The pose reference's mount (e.g. the drive manifest's `[reference]`,
    /// `Extrinsics::from(&reference)`). Default 0: the axle.
    #[serde(default)]
    pub extrinsics: Extrinsics,
    /// Re-estimate the drive's own heading offset δ with θ and the lever arm
    /// held ([`ValidateReport::heading_offset_fit`]), starting from
    /// [`ValidateOptions::extrinsics`]. δ is the reference's heading bias as
    /// much as its mount angle, and it changes from drive to drive, so the
    /// CLI and Python set it for a calibration's estimated δ and for a θ
    /// without one, unless told to hold δ as given
    /// ([`ValidateOptions::set_extrinsics`]). Default false (δ as given).
    #[serde(default)]
    pub reestimate_heading_offset: bool,
    /// The heading offset a parameter file's calibration estimated for each
    /// drive it ran on, rad, by the drive's
    /// [`Drive::fingerprint`](crate::Drive::fingerprint)
    /// ([`ValidateOptions::set_extrinsics`] fills it). On one of those
    /// drives [`validate`](crate::validate()) holds that estimate instead
    /// of re-estimating the offset: it is this drive's own, fitted with the
    /// calibration, so θ is judged there as the calibration judged it
    /// ([`ValidateReport::calibration_drive`]). Default none.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub calibration_heading_offsets: Vec<(String, f64)>,
    /// Also fit θ on the drive itself and judge the given θ against that
    /// fit ([`ValidateReport::drive_fit`]): two batch G-N calibrations of
    /// the drive, and one by the default method where their fit fails, is
    /// worse than θ or held parameters the drive does not determine.
    /// Default true; false for Ē_p alone.
    #[serde(default = "yes")]
    pub fit_drive: bool,
}

fn yes() -> bool {
    true
}

impl Default for ValidateOptions {
    fn default() -> Self {
        ValidateOptions {
            segments: ValidationSegmentOptions::default(),
            reachable: None,
            extrinsics: Extrinsics::default(),
            reestimate_heading_offset: false,
            calibration_heading_offsets: Vec::new(),
            fit_drive: true,
        }
    }
}

impl ValidateOptions {
    /// Sets the reference extrinsics to validate θ with on a drive, by the
    /// rules of docs/guide.md, "Several drives of one vehicle": the drive's
    /// own mount (`drive_reference`, its manifest's `[reference]`), except
    /// the extrinsics a calibration estimated (in its parameter `file` with a
    /// σ), which are the sensor's and hold for every drive of the vehicle;
    /// without a drive reference, the file's values. The drive's own heading
    /// offset is then re-estimated from there
    /// ([`Self::reestimate_heading_offset`]) unless `carry_heading_offset`
    /// holds it as given, or the file's calibration held it (as it would on
    /// this drive): the reference's heading bias changes from drive to drive,
    /// so a calibration's estimate is no value for another drive, and a θ
    /// without a file says nothing of it. On a drive the file's calibration
    /// ran on, its estimate for that drive is held instead
    /// ([`Self::calibration_heading_offsets`]). Returns the names of the
    /// extrinsics taken from the file.
    ///
    /// ```
    /// use odocal::{Extrinsics, ParamFile, Theta, ValidateOptions};
    /// let file = ParamFile::from_theta(&Theta::PAPER_NOMINAL, [None; 4], "drive.csv", "eiv");
    /// let mount = Extrinsics { lever_x: 0.5, ..Extrinsics::default() };
    /// let mut opts = ValidateOptions::default();
    /// // Extrinsics the calibration did not estimate give way to the drive's own mount.
    /// assert!(opts.set_extrinsics(Some(&file), Some(&mount), false).is_empty());
    /// assert_eq!(opts.extrinsics, mount);
    /// // Without one, the file's values (0 for those it lacks).
    /// assert_eq!(opts.set_extrinsics(Some(&file), None, false), ["lever_x", "lever_y", "heading_offset"]);
    /// assert_eq!(opts.extrinsics, Extrinsics::default());
    /// // This calibration held the heading offset: so does validation.
    /// assert!(!opts.reestimate_heading_offset);
    /// // A θ without a file: the drive's heading offset is re-estimated,
    /// // unless it is to be held as given.
    /// assert!(opts.set_extrinsics(None, Some(&mount), false).is_empty() && opts.reestimate_heading_offset);
    /// opts.set_extrinsics(None, Some(&mount), true);
    /// assert!(!opts.reestimate_heading_offset);
    /// ```
    pub fn set_extrinsics(
        &mut self,
        file: Option<&ParamFile>,
        drive_reference: Option<&Extrinsics>,
        carry_heading_offset: bool,
    ) -> Vec<&'static str> {
        self.reestimate_heading_offset = !carry_heading_offset && file.is_none_or(ParamFile::estimated_heading_offset);
        self.calibration_heading_offsets = file.map(ParamFile::drive_heading_offsets).unwrap_or_default();
        if let Some(x) = drive_reference {
            self.extrinsics = *x;
        }
        let Some(f) = file else { return Vec::new() };
        let (x, from_file) = f.extrinsics_for_drive(drive_reference);
        self.extrinsics = x;
        from_file
    }
}

/// The `validate` report (docs/reference.md): Ē_p of θ and, when asked, the reachable
/// minimum. In JSON the [`ValidationReport`] fields stand at the top level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidateReport {
    /// Ē_p of θ.
    #[serde(flatten)]
    pub validation: ValidationReport,
    /// The reachable minimum, when asked for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reachable_minimum: Option<ReachableReport>,
    /// The reference extrinsics Ē_p of θ used, when not all 0.
    #[serde(default, skip_serializing_if = "Extrinsics::is_zero")]
    pub extrinsics: Extrinsics,
    /// The drive's heading offset re-estimated with θ held, when asked
    /// ([`ValidateOptions::reestimate_heading_offset`]); `extrinsics` holds it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heading_offset_fit: Option<HeadingOffsetFit>,
    /// θ fitted on this drive and the verdict on the given θ, when asked
    /// ([`ValidateOptions::fit_drive`]) and the drive could be fitted.
    /// On a drive the θ's calibration ran on
    /// ([`ValidateReport::calibration_drive`]) the fit holds that
    /// calibration's heading offset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_fit: Option<DriveFit>,
    /// Why the drive could not be fitted, when it was asked to be.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive_fit_error: Option<String>,
    /// The drive is one the θ's calibration ran on (its fingerprint is in
    /// [`ValidateOptions::calibration_heading_offsets`]) and the heading
    /// offset would have been re-estimated: `extrinsics` holds the
    /// calibration's own estimate for this drive instead, so Ē_p is the
    /// calibration's own validation of it. In JSON only when true.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub calibration_drive: bool,
}

/// How much more Ē_p a θ that fits a drive may give than the drive's own
/// fit on the same segments, as a factor ([`DriveFit::fits`]).
pub(crate) const FIT_RATIO: f64 = 1.6;
/// Excess Ē_p over the drive's own fit that no drive can tell from zero, m:
/// a θ within it fits whatever the ratio (on a drive with no noise, Ē_p of
/// θ and of the fit differ by rounding).
pub(crate) const FIT_FLOOR_M: f64 = 0.01;

/// Ē_p `worse_m` lies beyond the verdict's line from Ē_p `better_m`: more
/// than [`FIT_RATIO`] times it and more than [`FIT_FLOOR_M`] above it. θ
/// does not fit when its Ē_p lies beyond the line from the fit's; a fit
/// has failed when its Ē_p lies beyond the line from θ's.
pub(crate) fn beyond_the_line(worse_m: f64, better_m: f64) -> bool {
    worse_m > (FIT_RATIO * better_m).max(better_m + FIT_FLOOR_M)
}

/// The drive's own fit: batch Gauss-Newton on the drive's calibration
/// segments started from the given θ and from the paper's θ_0 (the better
/// counts), or the default method from θ_0 where batch Gauss-Newton's fit
/// fails, is worse than θ or held parameters of θ the drive does not
/// determine, and the default's is better
/// ([`DriveFit::batch_gn_failure`]), with the heading offset re-estimated where validation
/// re-estimates it, the other extrinsics and what the drive cannot
/// determine held, and Ē_p of its θ on the same validation segments. A θ *fits* the drive when its
/// Ē_p is at most 1.6 times the fit's (or within 1 cm of it). θ carried
/// from another drive of the same vehicle gave up to 1.51 times the
/// drive's own fit on the 30 pairs of shipped test-track runs and up to
/// 1.09 on simulated pairs, where t_r 3 % or c_d 2 mm off gave 1.7 to 12
/// on the test track. A θ that does not fit points at a
/// changed vehicle, another vehicle's θ, or a drive whose data differ from
/// the calibration's (docs/guide.md, "Does θ fit another drive?").
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriveFit {
    /// θ fitted on the drive.
    pub theta: Theta,
    /// The heading offset fitted with it, rad, when re-estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heading_offset_rad: Option<f64>,
    /// The method that fitted it: `batch-gn`, or the default method's
    /// outcome (`eiv`, or `eiv (batch-gn fallback)` when its checks failed
    /// and its batch G-N start on every segment stands) when batch G-N's
    /// fit failed, was worse than θ or held parameters the drive does not
    /// determine, and the default's was better.
    #[serde(default)]
    pub method: String,
    /// Why batch G-N's fit was not used (it failed, was worse than θ, or
    /// held parameters the drive does not determine), when the default
    /// method's fit counts instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch_gn_failure: Option<String>,
    /// Ē_p of the fitted θ on the validation segments, m.
    pub mean_position_error_m: f64,
    /// Ē_p of the given θ over that of the fitted θ.
    pub ratio: f64,
    /// The verdict: the given θ fits the drive.
    pub fits: bool,
    /// The parameters of θ the fit held at its start, θ or the paper's
    /// θ_0, because the drive does not determine them: their values in
    /// [`DriveFit::theta`] are that start's, not fitted. Empty when every
    /// parameter was fitted.
    #[serde(default, skip_serializing_if = "no_params")]
    pub held: ParamSet,
}

/// `skip_serializing_if` for an empty [`ParamSet`].
fn no_params(set: &ParamSet) -> bool {
    set.is_empty()
}

impl DriveFit {
    /// The fit `theta` (with `heading_offset_rad`, by `method`) whose Ē_p
    /// is `own_m`, judged against Ē_p `given_m` of the given θ.
    pub(crate) fn judge(
        theta: Theta,
        heading_offset_rad: Option<f64>,
        method: &str,
        own_m: f64,
        given_m: f64,
    ) -> DriveFit {
        let fits = !beyond_the_line(given_m, own_m);
        let method = method.to_string();
        DriveFit {
            theta,
            heading_offset_rad,
            method,
            batch_gn_failure: None,
            mean_position_error_m: own_m,
            ratio: given_m / own_m,
            fits,
            held: ParamSet::default(),
        }
    }
}

/// Ē_p of θ on the validation segments of `drive` and, with
/// [`ValidateOptions::reachable`], the reachable minimum on the same
/// segments; `progress` hears the reachable-minimum search (one stage per
/// box searched, advancing by one per evaluation of Ē_p). The drive's own
/// fit ([`ValidateOptions::fit_drive`]) is added by
/// [`validate`](crate::validate()), a layer up.
///
/// θ is checked first (finite, c_e and t_r positive),
/// then the options, then the drive's wheel, heading and
/// lateral-acceleration conventions at θ, as `calibrate` checks them at θ_0.
///
/// # Errors
/// [`Error::InvalidTheta`](crate::Error::InvalidTheta) for a θ that is not
/// finite or has c_e or t_r not positive;
/// [`Error::InvalidOption`](crate::Error::InvalidOption) naming an invalid
/// option; [`Error::InvalidDrive`](crate::Error::InvalidDrive) for a
/// convention the drive breaks; a drive too short for one validation
/// segment, non-finite errors.
pub(crate) fn validate_theta(
    drive: &Drive,
    theta: &Theta,
    opts: &ValidateOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<ValidateReport> {
    theta.validate()?;
    opts.segments.validate()?;
    crate::drive::plausibility::check_conventions_at_theta(drive, theta, "drive")?;
    let segs = validation_segments(drive, &opts.segments)?;
    if segs.is_empty() {
        return Err(too_short_for_validation("the drive", drive, &opts.segments));
    }
    let heading_offset_fit = if opts.reestimate_heading_offset && !segs.is_empty() {
        Some(fit_heading_offset(drive, &segs, theta, &opts.extrinsics)?)
    } else {
        None
    };
    let extrinsics = heading_offset_fit.as_ref().map_or(opts.extrinsics, |f| with_fit(&opts.extrinsics, f));
    let validation = mean_position_error_with(drive, &segs, theta, &extrinsics)?;
    let reachable_minimum = match &opts.reachable {
        Some(r) => {
            let r = ReachableOptions { extrinsics, ..r.clone() };
            Some(reachable_minimum(drive, &segs, &r, progress)?)
        }
        None => None,
    };
    Ok(ValidateReport {
        validation,
        reachable_minimum,
        extrinsics,
        heading_offset_fit,
        drive_fit: None,
        drive_fit_error: None,
        calibration_drive: false,
    })
}

/// Ē_p of θ and of θ_0 on one of several validation drives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriveValidation {
    /// The drive's name (e.g. its file).
    pub name: String,
    /// Ē_p of θ on the drive, m.
    pub mean_position_error_m: f64,
    /// Ē_p of θ_0 on the drive, m.
    pub initial_mean_position_error_m: f64,
    /// Validation segments of the drive.
    pub segments: usize,
    /// The reference extrinsics this drive used, where they are not all 0
    /// or a stated value was overruled (docs/guide.md, "Several drives of one vehicle").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) extrinsics: Option<crate::assess::validation_drives::DriveExtrinsics>,
}

impl DriveValidation {
    /// The reference extrinsics θ and θ_0 were validated with on this
    /// drive, in the words of the text report's line `reference
    /// extrinsics:` (θ's, then θ_0's where they differ, each with where it
    /// comes from), then any conflicts; `None` where the drive used none.
    pub fn reference_extrinsics(&self) -> Option<String> {
        let x = self.extrinsics.as_ref()?;
        let mut s = x.to_string();
        for c in &x.conflicts {
            s.push_str(&format!("; CONFLICT: {c}"));
        }
        Some(s)
    }

    research_pub! {
        /// The heading offset θ was validated with on this drive, rad: the
        /// carried, stated or re-estimated one (the JSON report's
        /// `extrinsics` says which); 0 where the drive used no extrinsics.
        fn heading_offset_rad(&self) -> f64 {
            self.extrinsics.as_ref().map_or(0.0, |x| x.value.heading_offset)
        }
    }
}

/// Ē_p of θ and θ_0 on each of several drives, and their means over the
/// drives (each drive weighs the same, however long).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MultiValidation {
    /// The θ validated.
    pub theta: Theta,
    /// θ_0, the reference point.
    pub theta0: Theta,
    /// Per drive, in the order given.
    pub drives: Vec<DriveValidation>,
    /// Mean over drives of Ē_p of θ, m.
    pub mean_over_drives_m: f64,
    /// Mean over drives of Ē_p of θ_0, m.
    pub initial_mean_over_drives_m: f64,
}

impl MultiValidation {
    /// The number of validation segments of all the drives, and the mean
    /// over them of E_p,s of θ and of θ_0 (each segment weighs the same,
    /// as in the calibration's Ē_p on the held-out data; each drive's
    /// Ē_p weighted by its segments), m.
    pub(crate) fn mean_over_segments(&self) -> (usize, f64, f64) {
        let n: usize = self.drives.iter().map(|d| d.segments).sum();
        let weighted = |f: fn(&DriveValidation) -> f64| {
            self.drives.iter().map(|d| d.segments as f64 * f(d)).sum::<f64>() / n.max(1) as f64
        };
        (n, weighted(|d| d.mean_position_error_m), weighted(|d| d.initial_mean_position_error_m))
    }

    /// The rows and their means over the drives.
    pub(crate) fn from_rows(theta: Theta, theta0: Theta, drives: Vec<DriveValidation>) -> Self {
        let n = drives.len().max(1) as f64;
        let mean = |f: fn(&DriveValidation) -> f64| drives.iter().map(f).sum::<f64>() / n;
        MultiValidation {
            theta,
            theta0,
            mean_over_drives_m: mean(|d| d.mean_position_error_m),
            initial_mean_over_drives_m: mean(|d| d.initial_mean_position_error_m),
            drives,
        }
    }
}
