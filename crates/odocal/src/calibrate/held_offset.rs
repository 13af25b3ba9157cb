//! The verdict's check of a reference heading offset δ held by batch
//! Gauss-Newton or the 3-step ([`crate::VerdictReason::HeadingOffsetHeld`]).
//!
//! A real reference's δ is its mount angle and its own heading bias (14–23
//! mrad on the PSU test-track van). Held at a wrong value, δ tilts every
//! segment's reference start heading, and θ absorbs part of it: c_d above
//! all, whose heading drift bends the dead-reckoned path the same way over
//! a segment. EIV's start fits each drive's δ; batch G-N and the 3-step fit
//! it only with `--estimate heading-offset`. The check fits, on each
//! calibration drive's calibration segments, θ with δ held (the base) and
//! θ with δ free (batch G-N from the result's θ, as `--estimate
//! heading-offset` would). The result is doubtful when the fitted δ lies
//! more than [`MIN_OFFSET_SIGMAS`] of its σ (cluster-robust where
//! computed) from the held value and the free fit moves a free θ parameter
//! by more than [`MAX_SHIFT_SIGMAS`] of its σ for the next drive (after a
//! joint calibration, the σ with the drives' measured spread): holding
//! δ then biases θ by as much as θ's stated uncertainty. The first test
//! alone would flag offsets of a few tenths of a milliradian that the σ of
//! a long drive resolves but that move θ by far less than its σ; the second
//! names the offsets that matter for θ. δ fitted with θ held (validation's
//! fit, [`crate::assess::heading_offset`]) does not serve here: on the
//! drive θ was fitted on, θ has already absorbed most of the offset.

use crate::assess::trust::VerdictReason;
use crate::drive::segment::SegmentData;
use crate::drive::Drive;
use crate::identify::{batch_gauss_newton, IdentifyOptions};
use crate::model::extrinsics::Extrinsics;
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

use super::checks::largest_against_sigma;
use super::report::MethodDetail;
use super::{CalibrationOptions, Selection};

/// The fitted δ must lie more than this many of its σ from the held value.
pub(crate) const MIN_OFFSET_SIGMAS: f64 = 3.0;
/// θ fitted with δ free must move a free parameter by more than
/// this many of its σ for the next drive.
pub(crate) const MAX_SHIFT_SIGMAS: f64 = 1.0;
/// The relative step (`‖Δθ/θ_scale‖∞`) at which the check's fits stop: they
/// start from the result, and the check compares shifts against σ with
/// thresholds of 1 and 3, so the last per-mille of a step does not decide
/// it (the EIV start stops at the same tolerance).
const STEP_TOLERANCE: f64 = 1e-3;

/// The reasons of the check (module docs), one per drive whose held δ
/// matters; none for EIV, with δ estimated, or when a fit fails (the check
/// is then left out rather than failing the calibration).
pub(super) fn held_heading_offset_reasons(
    drive: &Drive,
    selection: &Selection,
    (theta, detail): (&Theta, &MethodDetail),
    held: &Extrinsics,
    opts: &CalibrationOptions,
    sigma_next: &[Option<f64>; 4],
) -> Vec<VerdictReason> {
    let (segments, identify) = (&selection.segments, &selection.identify(opts));
    if !matches!(detail, MethodDetail::BatchGn(_) | MethodDetail::ThreeStep(_))
        || identify.free.contains(Param::HeadingOffset)
    {
        return Vec::new();
    }
    let starts = drive.drive_starts();
    let free = identify.free.intersection(ParamSet::THETA);
    let fit = |data: &[SegmentData<'_>], free: ParamSet| {
        let step_tolerance = identify.step_tolerance.max(STEP_TOLERANCE);
        let o = IdentifyOptions { free, extrinsics: *held, step_tolerance, ..identify.clone() };
        batch_gauss_newton(data, theta, &o).ok()
    };
    (0..starts.len())
        .filter_map(|k| {
            let data: Vec<SegmentData<'_>> = segments
                .iter()
                .filter(|s| drive.drive_of_sample(s.start) == k)
                .map(|s| SegmentData::new(drive, s))
                .collect();
            if data.is_empty() {
                return None;
            }
            let joint = fit(&data, free.with(Param::HeadingOffset))?;
            let x = joint.extrinsics.as_ref()?;
            let fitted = x.value.heading_offset;
            let sigma = x.robust.as_ref().map_or(x.std_dev, |r| r.std_dev).heading_offset;
            if !(sigma > 0.0 && (fitted - held.heading_offset).abs() > MIN_OFFSET_SIGMAS * sigma) {
                return None;
            }
            let base = fit(&data, free)?.theta;
            let shift = |p: Param| p.value(&joint.theta) - p.value(&base);
            let (param, shift, _, shift_sigmas) = largest_against_sigma(free, sigma_next, shift)?;
            (shift_sigmas > MAX_SHIFT_SIGMAS).then_some(VerdictReason::HeadingOffsetHeld {
                drive: (starts.len() > 1).then_some(k),
                held: held.heading_offset,
                fitted,
                sigma,
                param,
                shift,
                shift_sigmas,
            })
        })
        .collect()
}
