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
//! Results are judged by dead-reckoning error on validation segments. The
//! exact statement is docs/method.md; every default is in docs/reference.md.
//!
//! ## The front door
//!
//! The crate root holds what a program needs: a [`Drive`] (read with
//! [`load_drive`] or [`import`], built with [`DriveBuilder`], or
//! simulated with [`sim::simulate`]), [`calibrate()`] (or [`Calibration`] for held-out data,
//! validation drives and progress) with [`CalibrationOptions`] and the
//! [`CalibrationReport`] with its [`Verdict`], [`validate()`] for a θ on a
//! drive, [`ParamFile`] to write and read the result, and [`Error`].
//! docs/guide.md, "The Rust library", goes through a manifest's drive:
//! its settings, a held-out half, progress and a parameter file judged
//! on another drive.
//!
//! [`calibrate()`] uses only the options it is given. A manifest's
//! `[noise]`, `[reference]` and `[calibration]` tables, which `odocal
//! calibrate` applies, reach them through [`settings`]:
//!
//! ```
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal::settings::{Caller, ManifestSettings, Settings};
//! let manifest = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/comma2k19-rav4/manifest.toml");
//! let (drive, import_report) = odocal::load_drive(manifest)?;
//! // None for a drive CSV: the defaults.
//! let manifests: Vec<ManifestSettings> =
//!     import_report.as_ref().map(ManifestSettings::try_from).transpose()?.into_iter().collect();
//! let opts = Settings::default().resolve(&manifests, Caller::CommandLine)?.options;
//! // This 60 s slice is too short for the default validation segments; a
//! // drive of a few km calibrates with `odocal::calibrate(&drive, &opts)?`.
//! # let _ = (drive, opts);
//! # Ok(()) }
//! ```
//!
//! ## Expert modules
//!
//! The public modules are for programs that run the method's steps or
//! build their own front end: [`model`] (the equations and their
//! derivatives), [`segment`] (cutting a drive into segments),
//! [`identify`] (the Gauss-Newton options and observability), [`compensate`] (the input-compensation QP),
//! [`eiv`] (the errors-in-variables options), [`sim`] (the simulator),
//! [`experiment`] (the paper's §6), [`mod@io`] (ROS 2 bags, streamed
//! import, drive files read in chunks), [`settings`] (calibration
//! settings as key–value pairs) and [`output`] (atomic writes and output paths checked
//! against inputs, for a front end's own files). Calibration that keeps up
//! with a streaming drive is the crate odocal-online; the per-vehicle
//! calibration history in SQLite, with the gated write-back of `odocal
//! follow`, is the crate odocal-history.
//!
//! Each public item is there for a user outside this crate (a program,
//! the `odocal` tool, the Python package, the crates odocal-online,
//! -history, -report and -bench, the fuzz targets) or as the type of a
//! public field or result (the reports' types are their JSON schema). What only the studies in
//! crates/odocal-lab use (the module `research`, the estimator itself and
//! its report in [`eiv`], the Gauss-Newton report in [`identify`], the
//! parts of the σ for the next drive in the module `pooling`) is
//! public with the feature `research` (off by default) and crate-internal
//! without it. tests/architecture.rs holds the number of public items to a
//! budget.
//!
//! ## Examples
//!
//! A drive CSV calibrated with the defaults: θ, its σ and the verdict, the
//! parameter file as `odocal calibrate --params-out` writes it, and θ
//! validated on another drive as `odocal validate --theta FILE` does.
//!
//! ```
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! use odocal::{calibrate, validate, CalibrationOptions, Drive, ValidateOptions, VerdictLevel};
//! # use odocal::sim::{simulate, SimOptions};
//! # let dir = tempfile::tempdir()?;
//! # let (path, other_path) = (dir.path().join("drive.csv"), dir.path().join("other.csv"));
//! # simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) })?.drive.write_csv(&path)?;
//! # simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(2) })?.drive.write_csv(&other_path)?;
//! let (drive, _notes) = Drive::read_csv(&path)?;
//! let report = calibrate(&drive, &CalibrationOptions::default())?;
//! // The 1σ for the next drive of the vehicle; its fields are Option<f64>, None for a held parameter.
//! let sigma = report.result_sigma();
//! println!("θ: {}", report.theta);
//! println!("σ: {sigma}");
//! println!("verdict: {}", report.verdict); // level and reasons; `report.verdict.level` to branch on
//! assert_ne!(report.verdict.level, VerdictLevel::Rejected);
//!
//! let file = report.param_file(&path.display().to_string());
//! let params = path.with_file_name("odocal.yaml");
//! odocal::output::write_text(&params, &file.text_for(&params)?)?;
//!
//! // The file's reference extrinsics, with the other drive's own heading offset.
//! let (other, _) = Drive::read_csv(&other_path)?;
//! let mut opts = ValidateOptions::default();
//! opts.set_extrinsics(Some(&file), None, false);
//! let v = validate(&other, &report.theta, &opts, None)?;
//! println!("Ē_p on the other drive: {:.2} m", v.validation.mean_position_error_m);
//! assert!(v.drive_fit.expect("the other drive's own fit").fits);
//! # Ok(()) }
//! ```
//!
//! Errors are [`Error`]: its message names the file, line, column or option
//! and what to do, and its variants carry the same as fields.
//!
//! ```
//! use odocal::{Drive, Error};
//! match Drive::read_csv("no-such-drive.csv") {
//!     Err(Error::Io { path, source }) => assert_eq!(source.kind(), std::io::ErrorKind::NotFound, "{}", path.display()),
//!     Err(Error::Csv { line, column, .. }) => eprintln!("line {line}, column {column:?}"),
//!     Err(Error::MissingColumns { missing, .. }) => eprintln!("missing {missing:?}"),
//!     Err(e) => eprintln!("{e}"), // `Error` is non-exhaustive
//!     Ok(_) => unreachable!(),
//! }
//! ```
//!
//! A noise-free simulated drive: batch Gauss-Newton recovers the true θ.
//!
//! ```
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal::{calibrate, sim, CalibrationOptions, Method};
//! let sim = sim::simulate(&sim::SimOptions { length_km: 2.0, substeps: 1, noise: "off".parse()?, ..sim::SimOptions::paper(1) })?;
//! let opts = CalibrationOptions { method: Method::BatchGn, ..Default::default() };
//! let report = calibrate(&sim.drive, &opts)?;
//! assert!((report.theta.t_r - sim.sidecar.theta_true.t_r).abs() < 1e-6);
//! # Ok(()) }
//! ```
//!
//! ## References
//! G. Fazekas, P. Gáspár, B. Németh, "Wheel Odometry Model Calibration with
//! Input Compensation by Optimal Control", IFAC-PapersOnLine, 2022.

#![deny(clippy::float_cmp)]
// With `research` every public item is reachable (the research-only ones
// through `research` and `eiv`); without it those stay crate-internal.
#![cfg_attr(feature = "research", warn(unreachable_pub))]
// A drive of one continuous part is `vec![0..n]`: one range is the intent.
#![allow(clippy::single_range_in_vec_init)]
// Numerical loops index several parallel arrays at once; index loops read like the maths.
#![allow(clippy::needless_range_loop)]

/// Declares an item `pub` with feature `research` (for the studies in
/// crates/odocal-lab) and crate-internal without it: research-only API.
macro_rules! research_pub {
    ($(#[$attr:meta])* $kind:ident $name:ident $($rest:tt)*) => {
        $(#[$attr])*
        #[cfg(feature = "research")]
        pub $kind $name $($rest)*
        $(#[$attr])*
        #[cfg(not(feature = "research"))]
        #[allow(dead_code)]
        pub(crate) $kind $name $($rest)*
    };
}

/// Re-exports a use tree `pub` with feature `research` and crate-internal
/// without it: one list for the research-only re-exports of a module.
macro_rules! research_use {
    ($($tree:tt)*) => {
        #[cfg(feature = "research")]
        pub use {$($tree)*};
        #[cfg(not(feature = "research"))]
        #[allow(unused_imports)]
        pub(crate) use {$($tree)*};
    };
}

// The modules in layers, lowest first; a module uses only its own subtree
// and modules of lower layers (tests/architecture.rs checks it). The public
// ones are expert API, each saying whom it is for; what a user needs to
// calibrate, validate, import and simulate is re-exported below.
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
pub mod output; // 1
mod progress; // 0
pub mod sim; // 3
mod simd; // 0

/// The `schema_version` of every JSON report the `odocal` tool writes
/// (calibrate, validate, import, experiment). Raised when a field is
/// renamed, moved or removed; adding a field does not raise it.
pub const REPORT_SCHEMA_VERSION: u32 = 1;

/// The README's code examples, compiled and run as doc-tests.
#[cfg(doctest)]
#[doc = include_str!("../../../README.md")]
struct ReadmeDoctests;

/// The Rust example of docs/guide.md ("The Rust library"), compiled as a
/// doc-test.
#[cfg(doctest)]
#[doc = include_str!("../../../docs/guide.md")]
struct GuideDoctests;

// Errors, progress, θ, the parameters and the reference extrinsics.
pub use error::{Error, Result};
pub use model::{extrinsics::Extrinsics, extrinsics::ExtrinsicsEstimate, param::Param, param::ParamSet, Theta};
pub use progress::Progress;
// Drives: building and importing; parameter files. `segment` is
// an expert module (its docs say for whom).
pub use drive::{
    fingerprint::refuse_duplicates, segment, stream::StreamChunk, Drive, DriveBuilder, ExtraColumn, ExtraValues,
    Signals,
};
pub use io::import::{
    import, is_manifest_path, load_drive, manifest::Manifest, report::ImportReport, settings::ReferenceSpec,
    wheel_scale_mismatch,
};
pub use io::param_file::{ParamFile, ParamMapping};
// Calibration: the entry points, the options, the report. `settings` is an
// expert module.
pub use calibrate::{
    calibrate,
    drive_fit::validate,
    eiv::{CorrectBias, EivMethodOptions},
    report::{CalibrationReport, ResultSigma, SegmentCounts, SigmaCovers, ThetaScore, ValidationSummary},
    settings,
    three_step::{FinalSegments, ThreeStepOptions},
    Calibration, CalibrationOptions, Holdout, Method,
};
// Validation and the verdict; the parts of the σ for the next drive
// (research).
research_use! { assess::pooling }
pub use assess::{
    heading_offset::HeadingOffsetFit,
    position_error::{dead_reckoning, mean_position_error, ValidationReport},
    reachable::{ReachableOptions, ReachableReport},
    trust::{GuardViolation, Guards, TrustOptions, Verdict, VerdictLevel, VerdictReason},
    validate::{DriveFit, DriveValidation, MultiValidation, ValidateOptions, ValidateReport},
    validation_drives::ValidationDrive,
    warning::Warning,
};

research_pub! {
    /// What the studies in crates/odocal-lab use beyond the public API: steps
    /// and diagnostics a study compares (feature `research`, off by default;
    /// not part of the stable API).
    mod research {
        research_use! {
            crate::assess::{position_error::mean_position_error_with, reachable::reachable_minimum},
            crate::calibrate::report::{SigmaSource, Timing},
            crate::model::extrinsics::DriveHeadingOffset,
            crate::calibrate::{
                calibrate_detailed,
                input_noise::{simex_bias, wheel_white_noise},
                eiv::is_misspecification,
                three_step::{random_batches, score_batches},
                DetailedCalibration,
            },
        }
    }
}
