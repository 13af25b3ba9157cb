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
//! ([`assess`]). The exact statement, with every default, is the
//! project's SPEC.md. [`calibrate()`] runs a whole calibration with any
//! method ([`mod@calibrate`]); [`experiment::run`] reproduces the paper's §6.
//!
//! ## The modules
//!
//! In layers, lowest first; a module uses only modules of lower layers:
//! [`error`] and [`progress`]; [`model`] (θ, the equations, parameters,
//! extrinsics, physical limits) and [`output`] (atomic writes, output paths
//! checked against inputs); [`drive`] (drives, segments, plausibility);
//! [`mod@io`] (manifest import, bags, parameter files) and [`sim`];
//! [`identify`] (Gauss-Newton); [`compensate`] (the QP) and [`eiv`];
//! [`assess`] (Ē_p, reachable minimum, verdict, warnings);
//! [`mod@calibrate`] (the methods, settings, validation on other drives,
//! cross-run); [`experiment`].
//!
//! ## Example
//!
//! ```
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal::{drive::segment, identify, sim, Theta};
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
// and modules of lower layers (tests/architecture.rs checks it).
pub mod assess; // 6
pub mod calibrate; // 7
pub mod compensate; // 5
pub mod drive; // 2
pub mod eiv; // 5
pub mod error; // 0
pub mod experiment;
pub mod identify; // 4
pub mod io; // 3
pub mod model; // 1
pub mod output; // 1
pub mod progress; // 0
pub mod sim; // 3 // 8

/// The `schema_version` of every JSON report the `odocal` tool writes
/// (calibrate, validate, import, experiment). Raised when a field is
/// renamed, moved or removed; adding a field does not raise it.
pub const REPORT_SCHEMA_VERSION: u32 = 1;

/// The README's code examples, compiled and run as doc-tests.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
pub struct ReadmeDoctests;

pub use assess::position_error::ValidationReport;
pub use assess::position_error::{mean_position_error, mean_position_error_with};
pub use assess::reachable::{reachable_minimum, reachable_minimum_with_progress, ReachableOptions, ReachableReport};
pub use assess::trust::{GuardViolation, Guards, TrustOptions, Verdict, VerdictLevel, VerdictReason};
pub use assess::validate::{
    validate, validate_drives, validate_with_progress, DriveValidation, MultiValidation, ValidateOptions,
    ValidateReport,
};
pub use assess::validation_drives::{validate_drives_with, CalibrationExtrinsics, ValidationDrive};
pub use assess::warning::Warning;
pub use calibrate::validate_on::calibrate_validated_on;
pub use calibrate::{
    calibrate, calibrate_held_out, calibrate_with_holdout, BatchGnOptions, CalibrationOptions, CalibrationReport,
    EivDetail, EivMethodOptions, EivOutcome, FinalSegments, Holdout, Method, MethodDetail, ResultSigma, SigmaSource,
    ThreeStepOptions,
};
pub use compensate::qp::SolverKind;
pub use compensate::{CompensateOptions, QpOptions};
pub use drive::segment::{Segment, SegmentData, SegmentOptions, ValidationSegmentOptions};
pub use drive::{Drive, Signals};
pub use error::{Error, Result};
pub use experiment::{Experiment, ExperimentOptions};
pub use identify::{batch_gauss_newton, IdentifyOptions, IdentifyReport, Observability, RobustCovariance, Termination};
pub use io::import::{import, load_drive, ImportReport, ImportedDrive, Manifest};
pub use model::extrinsics::{Extrinsics, ExtrinsicsEstimate};
pub use model::param::{Param, ParamSet};
pub use model::{Input, State, Theta};
pub use progress::{Progress, ProgressFn};
