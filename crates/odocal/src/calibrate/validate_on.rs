//! Calibration validated on other drives of the same vehicle
//! (`calibrate --validate-on`, `validate_on=`), each validation drive with
//! the reference extrinsics that apply to it
//! ([docs/guide.md, "Several drives of one vehicle"]).

use super::{calibrate_core, CalibrationOptions, CalibrationReport};
use crate::assess::validation_drives::{validate_drives_with, CalibrationExtrinsics, HeldOutDrives, ValidationDrive};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::model::param::ParamSet;
use crate::progress::ProgressFn;

impl CalibrationReport {
    /// The reference extrinsics of this calibration as validation drives
    /// see them; `given` names the parameters the caller gave (e.g.
    /// `--lever-arm` gives `lever_x`, `lever_y`).
    pub fn extrinsics_for_validation(&self, given: ParamSet) -> CalibrationExtrinsics {
        CalibrationExtrinsics::of_estimate(self.extrinsics.as_ref(), self.options.identify.extrinsics, given)
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
    let given = given.intersection(ParamSet::EXTRINSICS);
    let mut held = HeldOutDrives::new(validation, given)?;
    held.carry_heading_offset = carry_heading_offset;
    let mut report = calibrate_core(drive, Some((&held.joined, Some(&held))), opts, progress)?.report;
    let cal = CalibrationExtrinsics { carry_heading_offset, ..report.extrinsics_for_validation(given) };
    let per = validate_drives_with(validation, &report.theta, &report.initial.theta, &cal, &opts.validation)?;
    report.validate_on = Some(per);
    Ok(report)
}
