//! Validation on other drives of the same vehicle, each with the reference
//! extrinsics that apply to it (`calibrate --validate-on`, `validate_on=`).
//!
//! A validation drive read from a manifest may state its own `[reference]`
//! (lever arm, heading offset). Which values its Ē_p uses, per parameter
//! (`lever_x`, `lever_y`, `heading_offset`), first rule that applies:
//!
//! 1. **Estimated by the calibration** → the estimate. The extrinsics are
//!    the reference sensor's, and the sensor is the vehicle's: an estimate
//!    from one drive holds for every drive of the vehicle. If the drive's
//!    manifest states another value for it (and does not list it under
//!    `estimate`, i.e. as a mere start), that is a *conflict*: reported,
//!    the estimate used.
//! 2. **Given by the caller** (`--lever-arm`, `--heading-offset`, the Python
//!    keywords) → that value, for every drive: the command line wins over
//!    manifests, as everywhere. A drive stating another value is a conflict.
//! 3. **Stated by the drive's own manifest** → the drive's value: it
//!    describes that drive's recording (a sensor can be re-mounted).
//! 4. Otherwise **the calibration's held value** (its own manifest's, or 0).
//!
//! An estimated heading offset δ is the exception to rule 1: δ is the
//! reference's heading bias as much as a mount angle, and it changes from
//! drive to drive. Unless the caller carries it
//! ([`CalibrationExtrinsics::carry_heading_offset`]), each validation drive
//! gets its own δ, fitted with θ and the lever arm held
//! ([`super::heading_offset`]), starting from the calibration's.
//!
//! θ_0's Ē_p on the drive uses the same values, with an estimated parameter
//! at the value the estimate started from (as the calibration's own
//! `initial` Ē_p; a re-estimated δ is fitted for θ_0 too). Each drive's
//! [`DriveExtrinsics`] says which values were used, from where, and lists
//! the conflicts.

use serde::{Deserialize, Serialize};

use super::heading_offset::{fit_heading_offset, with_fit, HeadingOffsetFit};
use super::position_error::{mean_position_error_by, ValidationReport};
use super::validate::{DriveValidation, MultiValidation};
use crate::drive::segment::{too_short_for_validation, validation_segments, Segment, ValidationSegmentOptions};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::io::import::ReferenceSpec;
use crate::model::extrinsics::{Extrinsics, ExtrinsicsEstimate};
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

/// Where a validation drive's value of one extrinsic parameter comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub(crate) enum ExtrinsicSource {
    /// The calibration's estimate (rule 1).
    Estimated,
    /// The caller's value, e.g. `--lever-arm` (rule 2).
    Given,
    /// The drive's own manifest `[reference]` (rule 3).
    Drive,
    /// The calibration's held value: its manifest's, or 0 (rule 4).
    Calibration,
    /// Fitted on this drive with θ and the lever arm held (the heading
    /// offset the calibration estimated, unless carried).
    Reestimated,
}

impl std::fmt::Display for ExtrinsicSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            ExtrinsicSource::Estimated => "the calibration's estimate",
            ExtrinsicSource::Given => "the command line",
            ExtrinsicSource::Drive => "the drive's manifest",
            ExtrinsicSource::Calibration => "the calibration's value",
            ExtrinsicSource::Reestimated => "re-estimated on this drive",
        })
    }
}

/// The reference extrinsics of a calibration, as validation drives see
/// them: what was estimated, what the caller gave, the held and final values.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub(crate) struct CalibrationExtrinsics {
    /// The start of the estimate and the value of held parameters.
    pub initial: Extrinsics,
    /// The result (equal to `initial` for held parameters).
    pub value: Extrinsics,
    /// The parameters the calibration estimated.
    pub estimated: ParamSet,
    /// The parameters the caller gave itself (they win over every
    /// validation drive's manifest).
    pub given: ParamSet,
    /// Carry an estimated heading offset to every validation drive instead
    /// of re-estimating it on each (module docs). Default false.
    #[serde(default)]
    pub carry_heading_offset: bool,
}

impl CalibrationExtrinsics {
    /// The extrinsics of a calibration: its estimate (`None` when it held
    /// every extrinsic, at `held`); `given` names the parameters the caller
    /// gave (e.g. `--lever-arm` gives `lever_x`, `lever_y`).
    pub(crate) fn of_estimate(estimate: Option<&ExtrinsicsEstimate>, held: Extrinsics, given: ParamSet) -> Self {
        match estimate {
            Some(e) => CalibrationExtrinsics {
                initial: e.initial,
                value: e.value,
                estimated: e.free,
                given,
                carry_heading_offset: false,
            },
            None => CalibrationExtrinsics {
                initial: held,
                value: held,
                estimated: ParamSet::EMPTY,
                given,
                carry_heading_offset: false,
            },
        }
    }

    /// Before the estimate: the start values `x`, `free`'s extrinsics as estimated.
    pub(crate) fn before(x: Extrinsics, free: ParamSet, given: ParamSet) -> Self {
        let estimated = free.intersection(ParamSet::EXTRINSICS);
        CalibrationExtrinsics { initial: x, value: x, estimated, given, carry_heading_offset: false }
    }

    /// True when validation drives re-estimate their heading offset.
    pub(crate) fn reestimates_heading_offset(&self) -> bool {
        self.estimated.contains(Param::HeadingOffset) && !self.carry_heading_offset
    }
}

/// A drive's stated value differs from the one used (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct ExtrinsicConflict {
    /// The parameter.
    pub param: Param,
    /// The drive's manifest's value (m or rad).
    pub stated: f64,
    /// The value used.
    pub used: f64,
    /// Where the value used comes from.
    pub source: ExtrinsicSource,
}

impl std::fmt::Display for ExtrinsicConflict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "its manifest states {} = {}, {} ({}) was used",
            self.param,
            fmt_value(self.param, self.stated),
            fmt_value(self.param, self.used),
            self.source
        )
    }
}

fn fmt_value(p: Param, v: f64) -> String {
    match p {
        Param::HeadingOffset => format!("{:+.2} mrad", v * 1e3),
        _ => format!("{v:+.3} m"),
    }
}

/// Where each extrinsic parameter of a validation drive comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub(crate) struct ExtrinsicSources {
    /// Of `lever_x`.
    pub lever_x: ExtrinsicSource,
    /// Of `lever_y`.
    pub lever_y: ExtrinsicSource,
    /// Of `heading_offset`.
    pub heading_offset: ExtrinsicSource,
}

/// The extrinsics one validation drive used (see the module docs). The
/// text shows θ's, then θ_0's where they differ.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct DriveExtrinsics {
    /// With the calibrated θ.
    pub value: Extrinsics,
    /// With θ_0: the calibration's start of an estimated parameter, and a
    /// re-estimated heading offset fitted on the drive for θ_0, as for θ.
    pub initial: Extrinsics,
    /// Where each comes from.
    pub source: ExtrinsicSources,
    /// The drive's stated values that were not used.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub conflicts: Vec<ExtrinsicConflict>,
    /// The heading offset fitted on this drive for θ, when re-estimated
    /// (`value` holds it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub heading_offset_fit: Option<HeadingOffsetFit>,
}

impl std::fmt::Display for DriveExtrinsics {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = &self.value;
        let s = &self.source;
        write!(f, "lever arm ({:+.3}, {:+.3}) m", v.lever_x, v.lever_y)?;
        if s.lever_x == s.lever_y {
            write!(f, " [{}]", s.lever_x)?;
        } else {
            write!(f, " [x: {}, y: {}]", s.lever_x, s.lever_y)?;
        }
        write!(f, ", heading offset {:+.2} mrad [{}", v.heading_offset * 1e3, s.heading_offset)?;
        if let Some(fit) = &self.heading_offset_fit {
            write!(f, "; calibration's {:+.2} mrad", fit.calibration * 1e3)?;
        }
        f.write_str("]")?;
        // θ_0's Ē_p on the drive, where its values differ from θ's.
        let v0 = &self.initial;
        let differs = |a: f64, b: f64| a.to_bits() != b.to_bits();
        let mut initial = Vec::new();
        if differs(v0.lever_x, v.lever_x) || differs(v0.lever_y, v.lever_y) {
            initial.push(format!("lever arm ({:+.3}, {:+.3}) m [the calibration's start]", v0.lever_x, v0.lever_y));
        }
        if differs(v0.heading_offset, v.heading_offset) {
            let from = match s.heading_offset {
                ExtrinsicSource::Reestimated => "re-estimated on this drive for θ_0",
                _ => "the calibration's start",
            };
            initial.push(format!("heading offset {:+.2} mrad [{from}]", v0.heading_offset * 1e3));
        }
        if !initial.is_empty() {
            write!(f, "; θ_0's: {}", initial.join(", "))?;
        }
        Ok(())
    }
}

/// The extrinsics a validation drive whose manifest states `reference`
/// uses under the calibration's `cal` (the rules of the module docs).
pub(crate) fn drive_extrinsics(cal: &CalibrationExtrinsics, reference: Option<&ReferenceSpec>) -> DriveExtrinsics {
    // The drive's stated values, and which it lists as a start of an estimate only.
    let stated = |p: Param| -> Option<f64> {
        let r = reference?;
        match p {
            Param::LeverX => r.lever_arm.map(|l| l[0]),
            Param::LeverY => r.lever_arm.map(|l| l[1]),
            Param::HeadingOffset => r.heading_offset,
            _ => None,
        }
    };
    let start_only = |p: Param| reference.is_some_and(|r| r.estimate_set().is_ok_and(|s| s.contains(p)));
    let (mut value, mut initial) = ([0.0; 3], [0.0; 3]);
    let mut source = [ExtrinsicSource::Calibration; 3];
    let mut conflicts = Vec::new();
    for (i, p) in Param::EXTRINSICS.into_iter().enumerate() {
        let (v, v0, src) = if cal.estimated.contains(p) {
            (cal.value.to_array()[i], cal.initial.to_array()[i], ExtrinsicSource::Estimated)
        } else if cal.given.contains(p) {
            (cal.initial.to_array()[i], cal.initial.to_array()[i], ExtrinsicSource::Given)
        } else if let Some(s) = stated(p) {
            (s, s, ExtrinsicSource::Drive)
        } else {
            (cal.initial.to_array()[i], cal.initial.to_array()[i], ExtrinsicSource::Calibration)
        };
        if let Some(s) = stated(p) {
            let overruled = matches!(src, ExtrinsicSource::Estimated | ExtrinsicSource::Given);
            let excused = src == ExtrinsicSource::Estimated && start_only(p);
            if overruled && !excused && (s - v).abs() > 1e-12 {
                conflicts.push(ExtrinsicConflict { param: p, stated: s, used: v, source: src });
            }
        }
        (value[i], initial[i], source[i]) = (v, v0, src);
    }
    DriveExtrinsics {
        value: Extrinsics::from_array(value),
        initial: Extrinsics::from_array(initial),
        source: ExtrinsicSources { lever_x: source[0], lever_y: source[1], heading_offset: source[2] },
        conflicts,
        heading_offset_fit: None,
    }
}

/// [`drive_extrinsics`], with the heading offset re-estimated on `drive`'s
/// `segments` for θ and for θ_0 when `cal` says so (module docs).
fn fitted_drive_extrinsics(
    cal: &CalibrationExtrinsics,
    reference: Option<&ReferenceSpec>,
    drive: &Drive,
    segments: &[Segment],
    theta: &Theta,
    theta0: &Theta,
) -> Result<DriveExtrinsics> {
    let mut x = drive_extrinsics(cal, reference);
    if cal.reestimates_heading_offset() && x.source.heading_offset == ExtrinsicSource::Estimated {
        let fit = fit_heading_offset(drive, segments, theta, &x.value)?;
        let fit0 = fit_heading_offset(drive, segments, theta0, &x.initial)?;
        x.value = with_fit(&x.value, &fit);
        x.initial = with_fit(&x.initial, &fit0);
        x.source.heading_offset = ExtrinsicSource::Reestimated;
        x.heading_offset_fit = Some(fit);
    }
    Ok(x)
}

/// One validation drive: its name (e.g. its file), samples and the
/// `[reference]` its manifest states (`None` for a CSV or a manifest without one).
#[derive(Debug, Clone, Copy)]
pub struct ValidationDrive<'a> {
    /// The name in reports.
    pub name: &'a str,
    /// The drive.
    pub drive: &'a Drive,
    /// Its manifest's `[reference]`.
    pub reference: Option<&'a ReferenceSpec>,
}

/// The validation drives joined ([`Drive::concat`]) with what is needed to
/// give each of its segments its own drive's extrinsics.
pub(crate) struct HeldOutDrives<'a> {
    /// The drives joined.
    pub joined: Drive,
    /// First sample of each drive in `joined`.
    starts: Vec<usize>,
    /// Each drive's `[reference]`.
    references: Vec<Option<&'a ReferenceSpec>>,
    /// The parameters the caller gave.
    pub given: ParamSet,
    /// Carry an estimated heading offset instead of re-estimating it on
    /// each drive ([`CalibrationExtrinsics::carry_heading_offset`]).
    pub carry_heading_offset: bool,
}

impl<'a> HeldOutDrives<'a> {
    pub(crate) fn new(drives: &[ValidationDrive<'a>], given: ParamSet) -> Result<Self> {
        let refs: Vec<&Drive> = drives.iter().map(|d| d.drive).collect();
        let joined = Drive::concat(&refs)?;
        let mut starts = Vec::with_capacity(drives.len());
        let mut n = 0;
        for d in drives {
            starts.push(n);
            n += d.drive.len();
        }
        Ok(HeldOutDrives {
            joined,
            starts,
            references: drives.iter().map(|d| d.reference).collect(),
            given,
            carry_heading_offset: false,
        })
    }

    /// Ē_p of θ (or of θ_0 with `initial`) over the joined drive's
    /// `segments`, each with its drive's extrinsics under `cal`.
    pub(crate) fn error(
        &self,
        segments: &[Segment],
        theta: &Theta,
        cal: &CalibrationExtrinsics,
        initial: bool,
    ) -> Result<ValidationReport> {
        let cal = &CalibrationExtrinsics { carry_heading_offset: self.carry_heading_offset, ..*cal };
        let drive_of = |s: &Segment| self.starts.partition_point(|&b| b <= s.start).saturating_sub(1);
        let mut per_drive = Vec::with_capacity(self.references.len());
        for (i, r) in self.references.iter().enumerate() {
            let mine: Vec<Segment> = segments.iter().filter(|s| drive_of(s) == i).cloned().collect();
            let x = if mine.is_empty() {
                drive_extrinsics(cal, *r)
            } else {
                fitted_drive_extrinsics(cal, *r, &self.joined, &mine, theta, theta)?
            };
            x.value.validate()?;
            per_drive.push(x);
        }
        mean_position_error_by(&self.joined, segments, theta, |s| {
            let x = &per_drive[drive_of(s)];
            if initial {
                x.initial
            } else {
                x.value
            }
        })
    }
}

/// Ē_p of `theta` and of `theta0` on the validation segments of each
/// drive, with the extrinsics each drive uses under `cal` (module docs);
/// each row carries them ([`DriveValidation::extrinsics`]).
///
/// # Errors
/// [`Error::NoSegments`] naming a drive too short for one validation
/// segment (or when `drives` is empty); non-finite errors.
pub(crate) fn validate_drives_with(
    drives: &[ValidationDrive<'_>],
    theta: &Theta,
    theta0: &Theta,
    cal: &CalibrationExtrinsics,
    segments: &ValidationSegmentOptions,
) -> Result<MultiValidation> {
    if drives.is_empty() {
        return Err(Error::NoSegments("no validation drive given".into()));
    }
    let mut out = Vec::with_capacity(drives.len());
    for d in drives {
        let segs = validation_segments(d.drive, segments)?;
        if segs.is_empty() {
            return Err(too_short_for_validation(&format!("validation drive {}", d.name), d.drive, segments));
        }
        let x = fitted_drive_extrinsics(cal, d.reference, d.drive, &segs, theta, theta0)?;
        x.value.validate()?;
        let applies = !(x.value.is_zero() && x.initial.is_zero() && x.conflicts.is_empty());
        out.push(DriveValidation {
            name: d.name.to_string(),
            mean_position_error_m: mean_position_error_by(d.drive, &segs, theta, |_| x.value)?.mean_position_error_m,
            initial_mean_position_error_m: mean_position_error_by(d.drive, &segs, theta0, |_| x.initial)?
                .mean_position_error_m,
            segments: segs.len(),
            extrinsics: applies.then_some(x),
        });
    }
    Ok(MultiValidation::from_rows(*theta, *theta0, out))
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // values copied, not computed
mod tests {
    use super::*;

    fn spec(lever: Option<[f64; 2]>, heading: Option<f64>, estimate: &[&str]) -> ReferenceSpec {
        ReferenceSpec {
            lever_arm: lever,
            heading_offset: heading,
            estimate: estimate.iter().map(|s| s.to_string()).collect(),
        }
    }

    #[test]
    fn a_drive_validated_with_its_own_mount_is_exact() {
        use crate::sim::{simulate, SimOptions};
        let mount = Extrinsics { lever_x: -0.9, lever_y: 0.3, heading_offset: -0.01 };
        let o = SimOptions { length_km: 2.0, substeps: 1, reference_mount: mount, ..SimOptions::noise_free(6) };
        let s = simulate(&o).expect("simulate");
        let theta = s.sidecar.theta_true;
        let r = spec(Some([-0.9, 0.3]), Some(-0.01), &[]);
        let drives = [
            ValidationDrive { name: "stated", drive: &s.drive, reference: Some(&r) },
            ValidationDrive { name: "bare", drive: &s.drive, reference: None },
        ];
        let m = validate_drives_with(&drives, &theta, &theta, &CalibrationExtrinsics::default(), &Default::default())
            .expect("validate");
        let (with, without) = (m.drives[0].mean_position_error_m, m.drives[1].mean_position_error_m);
        assert!(with < 1e-6 && without > 0.1, "Ē_p {with} m with the drive's mount, {without} m without");
        assert_eq!(m.drives[0].extrinsics.as_ref().map(|x| x.value), Some(mount));
        assert!(m.drives[1].extrinsics.is_none());
        // The joined held-out drives give each segment its own drive's mount.
        let held = HeldOutDrives::new(&drives, ParamSet::EMPTY).expect("join");
        let segs = validation_segments(&held.joined, &Default::default()).expect("segments");
        let cal = CalibrationExtrinsics::default();
        let joint = held.error(&segs, &theta, &cal, false).expect("error");
        assert!((joint.mean_position_error_m - (with + without) / 2.0).abs() < 1e-9 * without, "{joint:?}");
        assert_eq!(joint.segments, 2 * m.drives[0].segments);
    }

    #[test]
    fn the_rules_pick_estimate_caller_drive_calibration_in_that_order() {
        let cal = CalibrationExtrinsics {
            initial: Extrinsics { lever_x: -0.5, lever_y: 0.0, heading_offset: 0.002 },
            value: Extrinsics { lever_x: -0.8, lever_y: 0.1, heading_offset: 0.002 },
            estimated: ParamSet::LEVER_ARM,
            given: ParamSet::EMPTY,
            carry_heading_offset: false,
        };
        // No manifest: estimate for the lever arm, the calibration's held heading offset.
        let x = drive_extrinsics(&cal, None);
        assert_eq!(x.value, cal.value);
        assert_eq!(x.initial, cal.initial);
        assert_eq!(x.source.lever_x, ExtrinsicSource::Estimated);
        assert_eq!(x.source.heading_offset, ExtrinsicSource::Calibration);
        assert!(x.conflicts.is_empty());
        // The drive states both: its heading offset applies; its lever arm conflicts with the estimate.
        let r = spec(Some([-0.9, 0.0]), Some(-0.01), &[]);
        let x = drive_extrinsics(&cal, Some(&r));
        assert_eq!(x.value, Extrinsics { lever_x: -0.8, lever_y: 0.1, heading_offset: -0.01 });
        assert_eq!(x.initial.heading_offset, -0.01);
        assert_eq!(x.source.heading_offset, ExtrinsicSource::Drive);
        let params: Vec<Param> = x.conflicts.iter().map(|c| c.param).collect();
        assert_eq!(params, [Param::LeverX, Param::LeverY]);
        assert!(x.conflicts[0]
            .to_string()
            .contains("states lever_x = -0.900 m, -0.800 m (the calibration's estimate)"));
        // ... unless the drive lists the lever arm as estimated too: its value is only a start.
        let r = spec(Some([-0.9, 0.0]), None, &["lever-arm"]);
        assert!(drive_extrinsics(&cal, Some(&r)).conflicts.is_empty());
        // A caller's heading offset wins over the drive's, reported.
        let cal = CalibrationExtrinsics { given: ParamSet::EMPTY.with(Param::HeadingOffset), ..cal };
        let r = spec(None, Some(-0.01), &[]);
        let x = drive_extrinsics(&cal, Some(&r));
        assert_eq!(x.value.heading_offset, 0.002);
        assert_eq!(x.source.heading_offset, ExtrinsicSource::Given);
        assert_eq!(x.conflicts.len(), 1);
        assert_eq!(x.conflicts[0].source, ExtrinsicSource::Given);
    }

    #[test]
    fn each_validation_drive_gets_its_own_heading_offset_unless_carried() {
        use crate::sim::{simulate, SimOptions};
        let sim = |seed, delta| {
            let mount = Extrinsics { lever_x: -0.9, lever_y: 0.05, heading_offset: delta };
            simulate(&SimOptions {
                length_km: 2.0,
                substeps: 1,
                reference_mount: mount,
                ..SimOptions::noise_free(seed)
            })
            .expect("simulate")
        };
        let (a, b) = (sim(11, 0.0142), sim(12, 0.0225));
        let theta = a.sidecar.theta_true;
        // A calibration that estimated the whole mount at 18.8 mrad.
        let estimated = Extrinsics { lever_x: -0.9, lever_y: 0.05, heading_offset: 0.0188 };
        let cal = CalibrationExtrinsics {
            initial: Extrinsics::ZERO,
            value: estimated,
            estimated: ParamSet::EXTRINSICS,
            given: ParamSet::EMPTY,
            carry_heading_offset: false,
        };
        let drives = [
            ValidationDrive { name: "a", drive: &a.drive, reference: None },
            ValidationDrive { name: "b", drive: &b.drive, reference: None },
        ];
        let opts = ValidationSegmentOptions::default();
        let m = validate_drives_with(&drives, &theta, &theta, &cal, &opts).expect("validate");
        for (row, want) in m.drives.iter().zip([0.0142, 0.0225]) {
            let x = row.extrinsics.as_ref().expect("extrinsics");
            assert_eq!(x.source.heading_offset, ExtrinsicSource::Reestimated);
            assert_eq!(x.source.lever_x, ExtrinsicSource::Estimated);
            assert!((x.value.heading_offset - want).abs() < 1e-10, "{x}");
            assert_eq!(x.heading_offset_fit.map(|f| f.calibration), Some(0.0188));
            assert!(row.mean_position_error_m < 1e-6, "{}: {}", row.name, row.mean_position_error_m);
            assert!(x.to_string().contains("[re-estimated on this drive; calibration's +18.80 mrad]"), "{x}");
        }
        // θ_0's Ē_p on each drive takes the lever arm the calibration
        // started from and a heading offset fitted on the drive for θ_0 (as
        // θ's is for θ), and the text says which.
        let theta0 = Theta::PAPER_INITIAL;
        let m0 = validate_drives_with(&drives, &theta, &theta0, &cal, &opts).expect("validate");
        for (row, d) in m0.drives.iter().zip(&drives) {
            let x = row.extrinsics.as_ref().expect("extrinsics");
            let segs = validation_segments(d.drive, &opts).expect("segments");
            let fit0 = fit_heading_offset(d.drive, &segs, &theta0, &Extrinsics::ZERO).expect("fit for θ_0");
            assert_eq!(x.initial, with_fit(&Extrinsics::ZERO, &fit0));
            let e0 = mean_position_error_by(d.drive, &segs, &theta0, |_| x.initial).expect("Ē_p");
            assert_eq!(row.initial_mean_position_error_m.to_bits(), e0.mean_position_error_m.to_bits());
            let want = format!(
                "; θ_0's: lever arm (+0.000, +0.000) m [the calibration's start], heading offset {:+.2} mrad \
                 [re-estimated on this drive for θ_0]",
                x.initial.heading_offset * 1e3
            );
            assert!(x.to_string().ends_with(&want), "{x}");
        }
        // The joined held-out drives: each segment with its own drive's fitted δ.
        let held = HeldOutDrives::new(&drives, ParamSet::EMPTY).expect("join");
        let segs = validation_segments(&held.joined, &opts).expect("segments");
        assert!(held.error(&segs, &theta, &cal, false).expect("error").mean_position_error_m < 1e-6);
        // Carried: the calibration's 18.8 mrad on both drives, metres off.
        let carried = CalibrationExtrinsics { carry_heading_offset: true, ..cal };
        let m = validate_drives_with(&drives, &theta, &theta, &carried, &opts).expect("validate");
        for row in &m.drives {
            let x = row.extrinsics.as_ref().expect("extrinsics");
            assert_eq!(x.source.heading_offset, ExtrinsicSource::Estimated);
            assert!(x.heading_offset_fit.is_none());
            assert!(row.mean_position_error_m > 0.1, "{}: {}", row.name, row.mean_position_error_m);
        }
        let held = HeldOutDrives { carry_heading_offset: true, ..held };
        assert!(held.error(&segs, &theta, &cal, false).expect("error").mean_position_error_m > 0.1);
    }
}
