//! Judging a θ and a calibration: the dead-reckoning error Ē_p
//! ([`position_error`], docs/method.md §7), the σ for the next drive (`pooling`), validation on the drive and on other
//! drives ([`validate`], [`validation_drives`]), the reachable minimum of
//! Ē_p ([`reachable`]), the trust checks and verdict ([`trust`]) and the
//! warnings a calibration reports ([`warning`]).
//!
//! ## The verdict
//! [`trust::Verdict`] sums up a calibration as `accepted`, `doubtful` or
//! `rejected`, with typed [`trust::VerdictReason`]s:
//! - *rejected*: the final θ fails a guard, or its Ē_p on the validation (or
//!   held-out) data is above θ_0's (dead reckoning gets worse);
//! - *doubtful*: a free parameter is not observable, lies in the outer tenth
//!   of its guard region, has a σ above [`trust::TrustOptions::max_sigma_fraction`]
//!   of its guard half-width (the σ of
//!   [`crate::CalibrationReport::result_covariance`]: batch-gn's
//!   cluster-robust σ, the 3-step's step-1 batch spread; else the model σ;
//!   so also in the cross-split check), or the held-out Ē_p is more than
//!   [`trust::TrustOptions::max_held_out_ratio`] times the Ē_p on the fitting data,
//!   or θ fitted on the held-out data differs from θ fitted on the fitting
//!   data by more than [`trust::TrustOptions::max_split_sigmas`] of their combined σ
//!   and more than [`trust::TrustOptions::min_split_fraction`] of the guard
//!   half-width (*cross-split consistency*: two halves of one drive, or two
//!   drives of one vehicle, should give one θ).
//!   or the filter's consistency checks failed (EIV with its fallback off,
//!   or θ unstable across halves alone, which keeps the EIV θ)
//!   on the returned θ ([`crate::Warning::EivCheckFailed`]), or the batch
//!   Gauss-Newton that gives θ (batch-gn, the EIV fallback, the 3-step's
//!   step 3) stopped at its iteration limit while its last step still moved
//!   a parameter by more than [`trust::TrustOptions::max_final_step_sigmas`] σ,
//!   or the result is EIV's batch G-N fallback and EIV's own estimate lies
//!   more than [`trust::TrustOptions::max_fallback_gap_sigmas`] σ from it,
//!   or the result is EIV's own estimate and its t_r lies that many σ
//!   above its batch G-N start's ([`trust::VerdictReason::TrackWidthAboveStart`]),
//!   or the result is EIV's own estimate holding the reference's heading
//!   drift at its floor and the fit without the floor lies that many σ
//!   away ([`trust::VerdictReason::HeadingDriftFloorDisagrees`]),
//!   or the result is EIV's batch G-N fallback and no plausible EIV
//!   estimate checks it ([`trust::VerdictReason::FallbackUnchecked`]),
//!   or EIV's fit left its common-mode wheel-noise scale at the upper
//!   clamp, so the common-mode term of the σ for the next drive is a lower
//!   bound ([`trust::VerdictReason::HeavyCommonModeNoise`]),
//!   or estimated extrinsics have a model σ alone
//!   ([`trust::VerdictReason::ExtrinsicsModelSigmaOnly`]), or batch-gn or the
//!   3-step held a reference heading offset that moves θ
//!   ([`trust::VerdictReason::HeadingOffsetHeld`]).
//!
//! The large-σ check uses the σ that stands for the result, the σ for the
//! next drive (`crate::pooling`); the cross-split and convergence checks
//! the method's within-drive σ.

pub(crate) mod heading_offset;
research_pub! {
    mod pooling;
}
pub(crate) mod position_error;
pub(crate) mod reachable;
pub(crate) mod trust;
pub(crate) mod validate;
pub(crate) mod validation_drives;
mod verdict_text;
pub(crate) mod warning;
