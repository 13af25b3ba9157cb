//! Calibration validated on other drives of the same vehicle
//! (`calibrate --validate-on`, `validate_on=`), each validation drive with
//! the reference extrinsics that apply to it
//! ([docs/guide.md, "Several drives of one vehicle"]).

use super::{calibrate_core, CalibrationOptions, CalibrationReport};
use crate::assess::validation_drives::{validate_drives_with, CalibrationExtrinsics, HeldOutDrives, ValidationDrive};
use crate::drive::segment::Segment;
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::model::extrinsics::Extrinsics;
use crate::model::param::ParamSet;
use crate::progress::ProgressFn;

impl CalibrationReport {
    /// The reference extrinsics behind this report's `initial` and
    /// `validation` Ē_p on each of `segments` (the validation segments of
    /// the drive the report validated on): `[θ_0's, θ's]` per segment.
    /// With validation drives ([`CalibrationReport::validate_on`]),
    /// `drive_starts` gives the first sample of each in the joined drive and
    /// each segment takes its drive's row; otherwise every segment takes
    /// the calibration's start and result, and after a joint calibration
    /// validated on its own drives (`drive_starts`: the calibration
    /// drive's, [`Drive::drive_starts`]) the result with the segment's
    /// drive's heading offset (JSON `heading_offset_per_drive`).
    pub fn validation_extrinsics(&self, drive_starts: &[usize], segments: &[Segment]) -> Vec<[Extrinsics; 2]> {
        let start = self.options.identify.extrinsics;
        let result = self.extrinsics.as_ref().map_or(start, |x| x.value);
        let own = self.extrinsics.as_ref().filter(|x| !x.per_drive.is_empty() && !self.validation.held_out);
        if let Some(x) = own {
            return segments
                .iter()
                .map(|s| [start, x.for_drive(drive_starts.partition_point(|&b| b <= s.start).saturating_sub(1))])
                .collect();
        }
        let rows = self.validate_on.as_ref().map(|m| &m.drives);
        segments
            .iter()
            .map(|s| match rows {
                Some(rows) if rows.len() == drive_starts.len() => {
                    let i = drive_starts.partition_point(|&b| b <= s.start).saturating_sub(1);
                    rows[i].extrinsics.as_ref().map_or([Extrinsics::ZERO; 2], |x| [x.initial, x.value])
                }
                _ => [start, result],
            })
            .collect()
    }

    /// The reference extrinsics of this calibration as validation drives
    /// see them; `given` names the parameters the caller gave (e.g.
    /// `--lever-arm` gives `lever_x`, `lever_y`).
    pub(crate) fn extrinsics_for_validation(&self, given: ParamSet) -> CalibrationExtrinsics {
        CalibrationExtrinsics::of_estimate(self.extrinsics.as_ref(), self.options.identify.extrinsics, given)
    }

    /// Ē_p of this calibration's θ and of its θ_0 on the validation
    /// segments of each of `drives` (other drives of the same vehicle,
    /// after the calibration: what [`Calibration::validate_on`](crate::Calibration::validate_on)
    /// does during it), each drive with the reference extrinsics that apply
    /// to it; an estimated heading offset is re-estimated on each drive
    /// unless `carry_heading_offset`. Cross-run checks (calibrate on each
    /// drive, validate on the others) are built from it.
    ///
    /// # Errors
    /// [`Error::NoSegments`] naming a drive too short for one validation
    /// segment (or when `drives` is empty); non-finite errors.
    pub fn validate_on_drives(
        &self,
        drives: &[ValidationDrive<'_>],
        carry_heading_offset: bool,
    ) -> Result<crate::assess::validate::MultiValidation> {
        let cal = CalibrationExtrinsics { carry_heading_offset, ..self.extrinsics_for_validation(ParamSet::EMPTY) };
        validate_drives_with(drives, &self.theta, &self.options.theta0, &cal, &self.options.validation)
    }
}

/// Calibrates `drive` with `opts` and validates on `validation` (other
/// drives of the same vehicle), each validation drive with its own
/// extrinsics (module docs): the report's `validation` and `initial` are
/// Ē_p over all their segments, as with [`crate::Holdout::Other`] of the
/// joined drives, and its `validate_on` has each drive's row. `given` names
/// the extrinsic parameters the caller gave itself; an estimated heading
/// offset is re-estimated on each validation drive unless
/// `carry_heading_offset`.
pub(super) fn calibrate_validated_on(
    drive: &Drive,
    validation: &[ValidationDrive<'_>],
    given: ParamSet,
    carry_heading_offset: bool,
    opts: &CalibrationOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<CalibrationReport> {
    if validation.is_empty() {
        return Err(Error::NoSegments("no validation drive given".into()));
    }
    for v in validation {
        drive.refuse_other_rate(&format!("validation drive {}", v.name), v.drive)?;
    }
    let given = given.intersection(ParamSet::EXTRINSICS);
    let mut held = HeldOutDrives::new(validation, given)?;
    held.carry_heading_offset = carry_heading_offset;
    let mut report = calibrate_core(drive, Some((&held.joined, Some(&held))), opts, progress)?.report;
    let cal = CalibrationExtrinsics { carry_heading_offset, ..report.extrinsics_for_validation(given) };
    let per = validate_drives_with(validation, &report.theta, &report.initial.theta, &cal, &opts.validation)?;
    report.validate_on = Some(per);
    Ok(report)
}
