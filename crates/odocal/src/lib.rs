//! # odocal — wheel-odometry model calibration
//!
//! odocal calibrates the wheel-odometry model of a car or robot — effective
//! rear wheel circumference `c_e`, circumference difference `c_d`, rear track
//! width `t_r` and load-transfer coefficient `d` — from an ordinary logged
//! drive: rear wheel rotation speeds, lateral acceleration, sideslip and a
//! GNSS/INS reference pose.
//!
//! ## The model
//!
//! ```text
//! c_rl = c_e + c_d/2 + d·a_y          c_rr = c_e − c_d/2 − d·a_y
//! v    = (n_rl·c_rl + n_rr·c_rr)/2    ω    = (n_rr·c_rr − n_rl·c_rl)/t_r
//! p_x' = p_x + v·t_s·cos(ψ + ω·t_s/2 + β)
//! p_y' = p_y + v·t_s·sin(ψ + ω·t_s/2 + β)
//! ψ'   = ψ + ω·t_s
//! ```
//!
//! ## The method
//!
//! Plain least squares on this nonlinear model is biased by noise on the
//! wheel inputs. The 3-step method removes most of that bias:
//! 1. batch Gauss-Newton ([`identify`]) on random batches of turning
//!    segments gives several initial estimates θ_B,I;
//! 2. for each θ_B,I a box-constrained optimal-control QP ([`compensate`])
//!    estimates noise-free wheel rotations of every segment;
//! 3. batch Gauss-Newton with the compensated inputs gives θ_B,F.
//!
//! Results are judged by dead-reckoning error on validation segments
//! (`assess`). The exact statement, with every default, is the
//! project's SPEC.md. [`calibrate()`] runs a whole calibration with any
//! method (`mod@calibrate`); [`experiment::run`] reproduces the paper's §6.
//!
//! ## The modules
//!
//! In layers, lowest first; a module uses only modules of lower layers:
//! `error` and `progress`; [`model`] (θ, the equations, parameters,
//! extrinsics, physical limits); `drive` (drives, segments, plausibility);
//! [`mod@io`] (manifest import, bags, parameter files) and [`sim`];
//! [`identify`] (Gauss-Newton); [`compensate`] (the QP) and [`eiv`];
//! `assess` (Ē_p, reachable minimum, verdict, warnings);
//! `mod@calibrate` (the methods, settings, validation on other drives,
//! cross-run); [`experiment`].
//!
//! ## Example
//!
//! ```
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal::{identify, segment, sim, Theta};
//! // A noise-free simulated drive: batch Gauss-Newton recovers the true θ.
//! let sim = sim::simulate(&sim::SimOptions { length_km: 2.0, substeps: 1, ..sim::SimOptions::noise_free(1) })?;
//! let drive = &sim.drive;
//! let sel = segment::calibration_segments(drive, &Default::default())?;
//! let data: Vec<_> = sel.selected.iter().map(|s| segment::SegmentData::new(drive, s)).collect();
//! let opts = identify::IdentifyOptions { max_iterations: 20, ..Default::default() };
//! let report = identify::batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts)?;
//! assert!((report.theta.t_r - sim.sidecar.theta_true.t_r).abs() < 1e-9);
//! # Ok(()) }
//! ```
//!
//! ## References
//! G. Fazekas, P. Gáspár, B. Németh, "Wheel Odometry Model Calibration with
//! Input Compensation by Optimal Control", IFAC-PapersOnLine, 2022.

#![deny(clippy::float_cmp)]
// A drive of one continuous part is `vec![0..n]`: one range is the intent.
#![allow(clippy::single_range_in_vec_init)]
// Numerical loops index several parallel arrays at once; index loops read like the maths.
#![allow(clippy::needless_range_loop)]

// The modules in layers, lowest first; a module uses only its own subtree
// and modules of lower layers (tests/architecture.rs checks it). The public
// ones are expert API (each says whom it is for); everything a user needs
// to calibrate, validate, import and simulate is re-exported below.
mod assess; // 6
mod calibrate; // 7
pub mod compensate; // 5
mod drive; // 2
pub mod eiv; // 5
mod error; // 0
pub mod experiment; // 8
pub mod identify; // 4
pub mod io; // 3
pub mod model; // 1
mod progress; // 0
pub mod sim; // 3

/// The `schema_version` of every JSON report the `odocal` tool writes
/// (calibrate, validate, import, experiment). Raised when a field is
/// renamed, moved or removed; adding a field does not raise it.
pub const REPORT_SCHEMA_VERSION: u32 = 1;

/// The README's code examples, compiled and run as doc-tests.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;

// Errors and progress.
pub use error::{Error, Result};
pub use progress::{Progress, ProgressFn};
// θ, the parameters and the reference extrinsics.
pub use model::extrinsics::{Extrinsics, ExtrinsicsEstimate};
pub use model::param::{Param, ParamSet};
pub use model::Theta;
// Drives.
/// Calibration and validation segments: cutting a drive into the pieces
/// the methods fit and Ē_p averages over. Expert API, for programs that
/// run the steps ([`identify`], [`compensate`]) or score θ themselves.
pub use drive::segment;
pub use drive::{Drive, DriveBuilder, ExtraColumn, ExtraValues, Signals};
/// The drive manifest as Rust types. Expert API, for programs that build or
/// edit a manifest.
pub use io::import::manifest;
pub use io::import::{import, load_drive, ImportReport, ImportedDrive, Manifest, ReferenceSpec};
pub use io::param_file::{ParamFile, ParamMapping};
pub use sim::{simulate, NoiseOptions, SimOptions, SimOutput, SimSidecar};
// Calibration.
/// Cross-run checks: calibrate on each of several drives of one vehicle
/// (or on groups of them) and validate on the others. Expert API, for
/// judging whether a calibration carries over between drives.
pub use calibrate::crossrun;
/// The calibration settings as key–value pairs, one type for every front
/// end: a manifest's tables, the command line's flags and Python's keywords
/// become a [`settings::Settings`], resolved to [`CalibrationOptions`].
/// For programs that take settings from users.
/// The calibration settings as key–value pairs, one type for every front
/// end: a manifest's tables, the command line's flags and Python's keywords
/// become a [`settings::Settings`], resolved to [`CalibrationOptions`].
/// Expert API, for programs that take settings from users.
pub use calibrate::settings;
pub use calibrate::settings::Settings;
pub use calibrate::{
    calibrate, BatchGnOptions, Calibration, CalibrationOptions, CalibrationReport, EivMethodOptions, FinalSegments,
    Holdout, Method, MethodDetail, ResultSigma, SigmaSource, ThreeStepOptions,
};
// The methods' own report details.
pub use calibrate::{BatchGnDetail, BatchSpread, CorrectBias, EivDetail, EivOutcome, InitialStep, ThreeStepDetail};
// The 3-step method's compensation settings.
pub use compensate::qp::SolverKind;
pub use compensate::{CompensateOptions, QpOptions};
// Validation and the verdict.
pub use assess::position_error::{mean_position_error, segment_position_error, ValidationReport};
pub use assess::reachable::{ReachableOptions, ReachableReport};
pub use assess::trust::{TrustOptions, Verdict, VerdictLevel, VerdictReason};
pub use assess::validate::{validate, DriveValidation, MultiValidation, ValidateOptions, ValidateReport};
pub use assess::validation_drives::ValidationDrive;
pub use assess::warning::Warning;

/// What the studies in crates/odocal-lab use beyond the public API: the
/// steps and diagnostics a study compares (feature `research`, off by
/// default; not part of the stable API).
#[cfg(feature = "research")]
pub mod research {
    pub use crate::assess::position_error::mean_position_error_with;
    pub use crate::assess::reachable::reachable_minimum;
    pub use crate::assess::validation_drives::{validate_drives_with, CalibrationExtrinsics};
    pub use crate::calibrate::eiv::{is_misspecification, noise_summary};
    pub use crate::calibrate::three_step::{random_batches, score_batches};
    pub use crate::calibrate::{calibrate_detailed, DetailedCalibration};
}
