//! The verdict's checks of what a method's own σ cannot see: a reference
//! heading offset held by batch G-N or the 3-step ([`super::held_offset`])
//! and batch G-N's errors-in-variables bias ([`super::input_noise`]).

use crate::assess::pooling::NextDriveSigma;
use crate::assess::trust::VerdictReason;
use crate::drive::Drive;
use crate::model::extrinsics::Extrinsics;
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;

use super::report::MethodDetail;
use super::{held_offset, input_noise, CalibrationOptions, Selection};

/// The reasons of both checks for a result `fit` whose extrinsics are
/// `ext`, judged against its σ for the next drive.
pub(super) fn method_reasons(
    drive: &Drive,
    selection: &Selection,
    fit: (&Theta, &MethodDetail),
    ext: &Extrinsics,
    opts: &CalibrationOptions,
    next_drive: &NextDriveSigma,
) -> Vec<VerdictReason> {
    let sigma = &next_drive.sigma;
    let mut reasons = held_offset::held_heading_offset_reasons(drive, selection, fit, ext, opts, sigma);
    reasons.extend(input_noise::input_noise_bias_reason(drive, selection, fit, ext, opts, sigma));
    reasons
}

/// The parameter of `free` (θ's only) whose `value` is largest against its
/// σ for the next drive, as `(param, value, σ, |value| / σ)`; parameters
/// without a positive finite σ are passed over. None when none is left.
pub(super) fn largest_against_sigma(
    free: ParamSet,
    sigma_next: &[Option<f64>; 4],
    value: impl Fn(Param) -> f64,
) -> Option<(Param, f64, f64, f64)> {
    free.intersection(ParamSet::THETA)
        .iter()
        .filter_map(|p| {
            let s = sigma_next[p.index()].filter(|s| *s > 0.0 && s.is_finite())?;
            let v = value(p);
            Some((p, v, s, v.abs() / s))
        })
        .filter(|r| r.3.is_finite())
        .max_by(|a, b| a.3.total_cmp(&b.3))
}
