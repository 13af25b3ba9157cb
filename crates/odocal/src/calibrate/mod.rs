//! Calibration: the methods that turn a drive into θ, and what they share
//! (docs/method.md §6).
//!
//! A calibration runs in three parts:
//! 1. *shared preparation* (this module): options checked, validation
//!    segments cut, and Ē_p of θ_0 on the report's validation data (the
//!    drive itself or held-out data, [`Holdout`]);
//! 2. the method's own *selection* of the data it fits and of the
//!    parameters it can estimate: the segment-based methods cut calibration
//!    segments, keep those turning at least as fast as the threshold and apply the
//!    observability rules ([`CalibrationOptions::auto_fix`]); a method that
//!    fits whole drive parts is not held to the yaw-rate rule;
//! 3. the method's *estimate*, then the shared validation of the result
//!    and the [`CalibrationReport`]: θ, covariance, observability, validation
//!    and a per-method [`MethodDetail`].
//!
//! The methods:
//! - [`batch_gn`]: raw batch Gauss-Newton over all selected segments;
//! - [`three_step`]: the paper's 3-step method with input compensation;
//! - [`eiv`]: errors-in-variables filter over whole drive parts (docs/method.md §9),
//!   started from batch G-N on all segments, falling back to it when the
//!   filter's consistency checks fail.
//!
//! ## Adding a method
//!
//! A method is one file and one variant. In `calibrate/my_method.rs`:
//! `MyMethodOptions` (public fields, `Default`, `validate()`), its report
//! detail `MyMethodDetail`, and `impl Estimator for MyMethodOptions` (a
//! crate-internal trait) with `name`, `validate` and `run(&self, prep,
//! selection, progress) -> Result<MethodOutcome>`, and `select` when the
//! method does not fit the turning segments (the default). Then add `Method::MyMethod(MyMethodOptions)` and
//! `MethodDetail::MyMethod(MyMethodDetail)`, and one arm in
//! `Method::estimator`, `Method::from_name` (`FromStr`) and `Method::NAMES` (the tests' list). The shared
//! preparation, validation, report, JSON and CLI (`--method my-method`) need
//! no change.
//!
//! Every random choice takes a seed ([`CalibrationOptions::seed`] the
//! three-step method's, the EIV method's bootstrap its own); work runs in
//! parallel (rayon) and results are collected in a fixed order, so the
//! output does not depend on the thread count.

use std::borrow::Cow;
use std::time::Instant;

use serde::{Deserialize, Serialize};

use crate::assess::position_error::ValidationReport;
use crate::assess::position_error::{mean_position_error_by, mean_position_error_with, segment_log_ratio};
use crate::assess::trust::{judge, Evidence, TrustOptions};
use crate::assess::validation_drives::{CalibrationExtrinsics, HeldOutDrives, ValidationDrive};
use crate::assess::warning::Warning;
use crate::compensate::CompensatedInputs;
use crate::drive::segment::{
    too_short_for_validation, validation_segments, Segment, SegmentOptions, ValidationSegmentOptions,
};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::identify::{IdentifyOptions, Observability, RobustCovariance};
use crate::model::extrinsics::{Extrinsics, ExtrinsicsEstimate};
use crate::model::param::{Param, ParamSet};
use crate::model::Theta;
use crate::progress::{emit, Progress, ProgressFn};

pub(crate) mod batch_gn;
mod checks;
pub(crate) mod drive_fit;
pub(crate) mod eiv;
mod held_offset;
pub(crate) mod input_noise;
mod render;
pub(crate) mod report;
mod selection;
pub mod settings;
pub(crate) mod three_step;
mod turn_sense;
pub(crate) mod validate_on;

pub(crate) use report::MethodDetail;
use report::{extrinsics_model_sigma_only, model_sigma_only, result_identification};
pub(crate) use report::{CalibrationReport, SigmaSource};
pub(crate) use report::{SegmentCounts, ThetaScore, Timing, ValidationSummary};

pub(crate) use batch_gn::BatchGnDetail;
pub(crate) use batch_gn::BatchGnOptions;
pub(crate) use eiv::EivMethodOptions;
pub(crate) use eiv::{EivDetail, EivOutcome};
pub(crate) use selection::{cut_segments, hold_unobservable, turning_segments, Selection};
pub(crate) use three_step::{per_segment_identification, score_batches, BatchResult};
pub(crate) use three_step::{BatchSpread, InitialStep, ThreeStepDetail};
pub(crate) use three_step::{FinalSegments, ThreeStepOptions};

/// Which calibration method to run, with its settings.
///
/// Serialised as `{"name": "three-step", …settings}`; the report's `method`
/// is the name alone (docs/reference.md).
// Options are built once per calibration and borrowed: boxing the large
// variant would only make `Method::ThreeStep(ThreeStepOptions { .. })` harder to write.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "name", rename_all = "kebab-case")]
pub enum Method {
    /// The paper's 3-step method with input compensation.
    ThreeStep(ThreeStepOptions),
    /// Raw batch Gauss-Newton over all selected segments (its settings are
    /// [`CalibrationOptions::identify`]).
    BatchGn,
    /// Errors-in-variables filter over every drive part (docs/method.md §9), started
    /// from batch G-N on all segments and falling back to it when its
    /// consistency checks fail (default: docs/validation.md measures it against
    /// batch G-N and the 3-step on simulated and real drives).
    Eiv(EivMethodOptions),
}

impl Default for Method {
    fn default() -> Self {
        Method::Eiv(EivMethodOptions::default())
    }
}

impl Method {
    /// The names of the methods, as `--method` takes them.
    #[cfg(test)]
    pub(crate) const NAMES: [&'static str; 3] = ["three-step", "batch-gn", "eiv"];

    /// The method's name (`"three-step"`, `"batch-gn"`, `"eiv"`).
    pub(crate) fn name(&self) -> &'static str {
        self.estimator().name()
    }

    /// The named method with its default settings (outside the crate:
    /// `"eiv".parse::<Method>()`, the `FromStr` impl).
    pub(crate) fn from_name(name: &str) -> Result<Method> {
        match name.trim() {
            "three-step" => Ok(Method::ThreeStep(ThreeStepOptions::default())),
            "batch-gn" => Ok(Method::BatchGn),
            "eiv" => Ok(Method::Eiv(EivMethodOptions::default())),
            _ => Err(Error::Parse { what: "method", input: name.to_string(), expected: "three-step, batch-gn or eiv" }),
        }
    }

    /// Checks the method's settings, naming the offending field.
    pub(crate) fn validate(&self) -> Result<()> {
        self.estimator().validate()
    }

    pub(crate) fn estimator(&self) -> &dyn Estimator {
        match self {
            Method::ThreeStep(o) => o,
            Method::BatchGn => &BatchGnOptions {},
            Method::Eiv(o) => o,
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The named method with its default settings: `three-step`, `batch-gn`
/// or `eiv` (`--method`).
impl std::str::FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        Method::from_name(s)
    }
}

/// All settings of a calibration. `Default` holds the defaults docs/method.md names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationOptions {
    /// The method and its own settings. Default eiv.
    pub method: Method,
    /// Initial guess θ_0. Default the paper's `[2.0, 0, 1.6, 0]`. Within
    /// [`Theta::check_physical_limits`], else [`Error::InvalidTheta`]
    /// naming `theta0`, before the drive is looked at.
    pub theta0: Theta,
    /// Calibration segments (segment-based methods). Default K = 650,
    /// stride 100, yaw rate > 0.15 rad/s.
    pub segments: SegmentOptions,
    /// Validation segments. Default K_v = 1300, stride 650, offset 50.
    pub validation: ValidationSegmentOptions,
    /// Gauss-Newton settings (every identification), including which
    /// parameters are free.
    pub identify: IdentifyOptions,
    /// Seed of the three-step method's random choices (the other methods
    /// make none; method eiv's bootstrap and bias correction have their
    /// own seed). Default 0.
    pub seed: u64,
    /// Plausibility guards (applied to every step-1 batch and to the final
    /// θ) and the verdict's thresholds.
    #[serde(default)]
    pub trust: TrustOptions,
    /// Hold at θ_0 the parameters these data cannot determine, instead of
    /// estimating them (not in the paper; default false, the paper's
    /// behaviour). When no segment turns enough, c_d, t_r and d are held and
    /// every segment is used; otherwise the observability check
    /// (`crate::identify::observability`) runs on the selected segments at
    /// θ_0 and the named parameter with the smallest sensitivity is held,
    /// repeatedly, until none is named (c_e is never held). When the fit's
    /// own check names parameters the one at θ_0 passed (the default
    /// method's, on a drive that turns one way), they are held too and the
    /// method runs again ([`crate::Warning::AutoFixRefit`]). What was held is
    /// listed in [`CalibrationReport::auto_fixed`].
    #[serde(default)]
    pub auto_fix: bool,
    /// Keep the paper's turning-only selection even when every selected
    /// segment turns the same way (default false: then every cut segment is
    /// used, with [`crate::Warning::OneWayTurns`], because on one-way turns
    /// c_d and t_r are nearly collinear and the straight segments separate
    /// them; not in the paper). Segment-based methods only.
    #[serde(default)]
    pub keep_one_way_selection: bool,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            method: Method::default(),
            theta0: Theta::PAPER_INITIAL,
            segments: SegmentOptions::default(),
            validation: ValidationSegmentOptions::default(),
            identify: IdentifyOptions::default(),
            seed: 0,
            trust: TrustOptions::default(),
            auto_fix: false,
            keep_one_way_selection: false,
        }
    }
}

impl CalibrationOptions {
    /// Checks all options, naming the offending field (θ_0 first).
    pub(crate) fn validate(&self) -> Result<()> {
        self.theta0.check_physical_limits().map_err(|e| match e {
            Error::InvalidTheta(m) => Error::InvalidTheta(format!("theta0 (θ_0): {m}")),
            e => e,
        })?;
        self.segments.validate()?;
        self.validation.validate()?;
        self.identify.validate()?;
        self.trust.validate()?;
        self.method.validate()
    }

    /// Holds `p` at its initial value (θ_0, or the extrinsics' value): it
    /// leaves `identify.free`, and for the heading offset the EIV start no
    /// longer estimates it by default
    /// ([`EivMethodOptions::estimate_heading_offset`]). What `--fix` does.
    pub(crate) fn hold(&mut self, p: Param) {
        self.identify.free.remove(p);
        if p == Param::HeadingOffset {
            self.hold_stated_heading_offset();
        }
    }

    /// A heading offset was stated (`--heading-offset`, a manifest's
    /// `reference.heading_offset`): the EIV start holds it at
    /// `identify.extrinsics.heading_offset` instead of estimating it by
    /// default, as the other methods do; `identify.free` still estimates it
    /// when it holds δ (`--estimate heading-offset`).
    pub(crate) fn hold_stated_heading_offset(&mut self) {
        if let Method::Eiv(m) = &mut self.method {
            m.estimate_heading_offset = false;
        }
    }
}

/// Where the report's validation runs: on part of the drive the calibration
/// does not see, or on another drive of the same vehicle.
// One per calibration; `Other` owns its drive so callers need not keep it alive.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone, PartialEq)]
pub enum Holdout {
    /// Hold out the first half (by time); calibrate on the second.
    FirstHalf,
    /// Hold out the second half; calibrate on the first.
    SecondHalf,
    /// Calibrate on the whole drive; validate on this one.
    Other(Drive),
}

impl Holdout {
    /// The drive to calibrate on and the held-out drive. The halves are
    /// split at the middle of `[t_0, t_last + t_s)`; parts are clipped to
    /// each half.
    pub fn split<'a>(&'a self, drive: &'a Drive) -> Result<(Cow<'a, Drive>, Cow<'a, Drive>)> {
        let halves = || -> Result<(Drive, Drive)> {
            if drive.t().is_empty() {
                return Err(Error::InvalidDrive { context: "hold-out".into(), reason: "the drive is empty".into() });
            }
            let (t0, t1) = (drive.t()[0], drive.t()[drive.len() - 1] + drive.sample_time_s());
            drive.split_at_time(0.5 * (t0 + t1))
        };
        Ok(match self {
            Holdout::FirstHalf => {
                let (first, second) = halves()?;
                (Cow::Owned(second), Cow::Owned(first))
            }
            Holdout::SecondHalf => {
                let (first, second) = halves()?;
                (Cow::Owned(first), Cow::Owned(second))
            }
            Holdout::Other(other) => (Cow::Borrowed(drive), Cow::Borrowed(other)),
        })
    }
}

/// Runs a calibration of `drive` with `opts` (docs/method.md §6), validated on the
/// drive itself. For validation on held-out or other drives, or a progress
/// callback, use [`Calibration`].
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{calibrate, CalibrationOptions, Method, ThreeStepOptions, sim::{simulate, SimOptions}};
/// let drive = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) })?.drive;
/// let method = Method::ThreeStep(ThreeStepOptions { initial_batches: 8, ..Default::default() });
/// let report = calibrate(&drive, &CalibrationOptions { method, ..Default::default() })?;
/// assert!(report.validation.mean_position_error_m < report.initial.mean_position_error_m);
/// # Ok(()) }
/// ```
pub fn calibrate(drive: &Drive, opts: &CalibrationOptions) -> Result<CalibrationReport> {
    Calibration::new(drive, opts).run()
}

/// A calibration with its optional inputs: where the report's validation
/// runs (a held-out half, another drive, or several validation drives each
/// with its own reference extrinsics) and a progress callback. [`calibrate`]
/// is `Calibration::new(drive, options).run()`.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{Calibration, CalibrationOptions, Holdout, Method, Progress, sim::{simulate, SimOptions}};
/// let drive = simulate(&SimOptions { length_km: 4.0, ..SimOptions::paper(1) })?.drive;
/// let opts = CalibrationOptions { method: "batch-gn".parse::<Method>()?, ..Default::default() };
/// let progress = |p: Progress| eprintln!("{p:?}");
/// let run = Calibration {
///     holdout: Some(&Holdout::SecondHalf),
///     progress: Some(&progress),
///     ..Calibration::new(&drive, &opts)
/// };
/// let report = run.run()?;
/// // Ē_p on the second half, which the calibration did not see.
/// assert!(report.validation.held_out);
/// # Ok(()) }
/// ```
#[derive(Clone, Copy)]
pub struct Calibration<'a> {
    /// The drive to calibrate on.
    pub drive: &'a Drive,
    /// What to estimate and how.
    pub options: &'a CalibrationOptions,
    /// Validate on data the calibration does not see: a half of the drive
    /// or another drive ([`Holdout`]). The report's `validation` and
    /// `initial` are Ē_p on the held-out data; the calibration, including
    /// the choice of θ_B,I in step 1, sees only the rest. Not together
    /// with `validate_on`.
    pub holdout: Option<&'a Holdout>,
    /// Calibrate on the whole drive and validate on these drives (other
    /// drives of the same vehicle), each with the reference extrinsics that
    /// apply to it (the rules are in docs/guide.md, "Several drives of one
    /// vehicle"). The report's `validation` and `initial` are Ē_p over all
    /// their segments, as with [`Holdout::Other`] of the joined drives, and
    /// [`CalibrationReport::validate_on`] has each drive's row.
    pub validate_on: &'a [ValidationDrive<'a>],
    /// With `validate_on`: the extrinsic parameters the caller gave itself.
    pub given: ParamSet,
    /// With `validate_on`: carry the heading offset the calibration
    /// estimated to every validation drive instead of fitting each drive's
    /// own with θ and the lever arm held (the default, `false`; the heading
    /// offset is the reference's per-drive bias as much as a mount angle).
    pub carry_heading_offset: bool,
    /// The drives of one vehicle that `drive` was joined from
    /// ([`Drive::concat`]), when several are fitted jointly: each is also
    /// fitted alone and the between-drive σ of the result comes from their
    /// spread ([`CalibrationReport::result_sigma`]; not when a half of the
    /// joined drive is held out). Default none.
    pub drives: &'a [&'a Drive],
    /// Receives the stages and their progress.
    pub progress: Option<&'a (dyn Fn(Progress) + Sync)>,
}

impl<'a> Calibration<'a> {
    /// A calibration of `drive` with `options`, validated on `drive` itself;
    /// set the other fields with struct update syntax.
    pub fn new(drive: &'a Drive, options: &'a CalibrationOptions) -> Self {
        Calibration {
            drive,
            options,
            holdout: None,
            validate_on: &[],
            given: ParamSet::EMPTY,
            carry_heading_offset: false,
            drives: &[],
            progress: None,
        }
    }

    /// Runs the calibration (docs/method.md §6).
    ///
    /// # Errors
    /// Invalid options, a drive too short or without the data a method
    /// needs, numerical failures; with validation drives, also those of
    /// joining them ([`Drive::concat`]) and of their validation; both a
    /// hold-out and validation drives: [`Error::InvalidOption`]; a
    /// validation drive ([`Holdout::Other`], `validate_on`) whose sample
    /// time differs from `drive`'s by more than 1 %: [`Error::InvalidDrive`]
    /// naming it (validation segments are counted in samples).
    pub fn run(self) -> Result<CalibrationReport> {
        let mut report = self.run_joint()?;
        // The separate fits need the drives whole: not with a half held out.
        let halves = matches!(self.holdout, Some(Holdout::FirstHalf | Holdout::SecondHalf));
        if self.drives.len() >= 2 && !halves {
            emit(self.progress, Progress::Stage { name: "fitting each drive alone for the between-drive σ", total: 1 });
            report.pool_drives(self.drives)?;
            emit(self.progress, Progress::Advance(1));
        }
        Ok(report)
    }

    /// [`Calibration::run`] without the separate fits of [`Calibration::drives`].
    fn run_joint(self) -> Result<CalibrationReport> {
        if self.validate_on.is_empty() {
            return match self.holdout {
                None => calibrate_core(self.drive, None, self.options, self.progress),
                Some(h) => {
                    if let Holdout::Other(other) = h {
                        self.drive.refuse_other_rate("the held-out drive", other)?;
                    }
                    let (fit, held) = h.split(self.drive)?;
                    calibrate_core(&fit, Some((&held, None)), self.options, self.progress)
                }
            }
            .map(|d| d.report);
        }
        if self.holdout.is_some() {
            return Err(Error::InvalidOption {
                field: "validate_on",
                reason: "give a hold-out or validation drives, not both".into(),
            });
        }
        validate_on::calibrate_validated_on(
            self.drive,
            self.validate_on,
            self.given,
            self.carry_heading_offset,
            self.options,
            self.progress,
        )
    }
}
research_pub! {
    /// A calibration with the intermediate data an experiment needs: the report,
    /// the segments used and (three-step only) the compensated inputs of step 2.
    #[derive(Debug, Clone, PartialEq)]
    struct DetailedCalibration {
        /// The report [`calibrate`] returns.
        pub report: CalibrationReport,
        /// The calibration segments fitted (all segments when none turns
        /// enough and `auto_fix` is on).
        pub selected: Vec<Segment>,
        /// The validation segments of the calibration drive.
        pub validation: Vec<Segment>,
        /// Step 2's compensated inputs (three-step only).
        pub compensated: Option<CompensatedInputs>,
    }
}

/// What the shared preparation hands to a method.
pub(crate) struct Prepared<'a> {
    /// The drive to calibrate on.
    pub drive: &'a Drive,
    /// The options as given.
    pub options: &'a CalibrationOptions,
    /// Validation segments of `drive` (step 1 scores its batches on them).
    pub validation: Vec<Segment>,
}

/// What a method returns to the shared part.
pub(crate) struct MethodOutcome {
    /// The estimate.
    pub theta: Theta,
    /// Accepted iterations of the final identification (for the "did not
    /// move" guard), when the method iterates.
    pub iterations: Option<usize>,
    /// Its covariance.
    pub covariance: [[f64; 4]; 4],
    /// Observability at the estimate.
    pub observability: Observability,
    /// The method's own results.
    pub detail: MethodDetail,
    /// Stage times (the method's stages only).
    pub timing: Timing,
    /// The method's warnings.
    pub warnings: Vec<Warning>,
    /// Step 2's compensated inputs, for methods that compensate.
    pub compensated: Option<CompensatedInputs>,
}

/// A calibration method (crate-internal seam; see the module docs).
pub(crate) trait Estimator {
    /// The method's name in reports and on the command line.
    fn name(&self) -> &'static str;
    /// Checks the method's settings.
    fn validate(&self) -> Result<()>;
    /// Chooses the data to fit and the parameters to estimate. Default:
    /// the segment-based selection ([`turning_segments`]); a method over
    /// whole drive parts overrides it.
    fn select(&self, prep: &Prepared<'_>) -> Result<Selection> {
        turning_segments(prep)
    }
    /// True when the method estimates (or holds at a given value) the
    /// reference extrinsics of [`IdentifyOptions::extrinsics`] through the
    /// shared identification. A method that does not is refused when the
    /// options involve them. Default false.
    fn supports_extrinsics(&self) -> bool {
        false
    }
    /// The method's own change to the identification settings before
    /// anything else runs (e.g. a parameter the method estimates by
    /// default); the report's `options` show the result. Default none.
    fn adjust_identify(&self, _identify: &mut IdentifyOptions) {}
    /// Estimates θ.
    fn run(
        &self,
        prep: &Prepared<'_>,
        selection: &Selection,
        progress: Option<ProgressFn<'_>>,
    ) -> Result<MethodOutcome>;
}

research_pub! {
    /// A calibration of `drive`, validated on `held_out` when given, also
    /// returning the segments and step 2's compensated inputs.
    fn calibrate_detailed(
        drive: &Drive,
        held_out: Option<&Drive>,
        opts: &CalibrationOptions,
        progress: Option<ProgressFn<'_>>,
    ) -> Result<DetailedCalibration> {
        calibrate_core(drive, held_out.map(|h| (h, None)), opts, progress)
    }
}

/// Runs `method`; with auto-fix, what the fit finds not observable where the
/// check at θ_0 passed (EIV's on a one-way loop) is held and it runs again.
fn run_with_auto_fix(
    method: &dyn Estimator,
    prep: &Prepared<'_>,
    selection: &mut Selection,
    progress: Option<ProgressFn<'_>>,
) -> Result<MethodOutcome> {
    let outcome = method.run(prep, selection, progress)?;
    let named: Vec<Param> =
        outcome.observability.unobservable.iter().filter(|p| *p != Param::CE && selection.free.contains(*p)).collect();
    if !prep.options.auto_fix || named.is_empty() {
        return Ok(outcome);
    }
    named.iter().for_each(|p| selection.free.remove(*p));
    selection.auto_fixed.extend(named.iter().copied());
    selection.warnings.push(Warning::AutoFixRefit { params: named });
    method.run(prep, selection, progress)
}

/// [`calibrate_detailed`]; with held-out drives that each have their own
/// extrinsics ([docs/guide.md, "Several drives of one vehicle"]), the held-out Ē_p gives every
/// segment its drive's.
pub(crate) fn calibrate_core(
    drive: &Drive,
    held: Option<(&Drive, Option<&HeldOutDrives<'_>>)>,
    opts: &CalibrationOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<DetailedCalibration> {
    let held_out = held.map(|h| h.0);
    let held_refs = held.and_then(|h| h.1);
    opts.validate()?;
    let method = opts.method.estimator();
    let opts = &*method_options(opts, method)?;
    let t_start = Instant::now();
    crate::drive::plausibility::check_conventions(drive, &opts.theta0, "drive")?;
    if let Some(h) = held_out {
        crate::drive::plausibility::check_conventions(h, &opts.theta0, "held-out drive")?;
    }
    let prep = Prepared { drive, options: opts, validation: validation_segments(drive, &opts.validation)? };
    let mut selection = method.select(&prep)?;
    if prep.validation.is_empty() {
        return Err(too_short_for_validation("the drive", drive, &opts.validation));
    }
    let reported = ReportValidation::new(&prep, held_out, held_refs)?;
    let setup = t_start.elapsed().as_secs_f64();

    let outcome = run_with_auto_fix(method, &prep, &mut selection, progress)?;
    let initial_val = reported.initial(opts, selection.free)?;
    let warnings = result_warnings(&selection.warnings, outcome.warnings, &outcome.observability, opts);
    let extrinsics = if opts.identify.uses_extrinsics() { method_extrinsics(&outcome.detail) } else { None };
    let ext = extrinsics.as_ref().map_or(opts.identify.extrinsics, |e| e.value);
    let t = Instant::now();
    let val = reported.result(&outcome.theta, opts.identify.extrinsics, extrinsics.as_ref(), ext)?;
    let fit_m = match held_out {
        Some(_) => {
            Some(own_error(drive, &prep.validation, &outcome.theta, &ext, extrinsics.as_ref())?.mean_position_error_m)
        }
        None => None,
    };
    let split = match held_out {
        Some(h) if opts.trust.max_split_sigmas > 0.0 => split_fit(h, opts, selection.free),
        _ => None,
    };
    let within = report::within_sigma_of(&outcome.detail, &outcome.covariance, selection.free);
    let next_drive = report::next_drive_of(&outcome.theta, &outcome.detail, &within, selection.free, opts);
    let verdict = judge(
        &Evidence {
            theta: &outcome.theta,
            theta0: &opts.theta0,
            free: selection.free,
            iterations: outcome.iterations,
            rcond: outcome.observability.rcond,
            unobservable: outcome.observability.unobservable,
            // The σ that stands for the result (batch-gn: cluster-robust;
            // 3-step: step-1 batch spread): the model σ is 5–120× too small
            // under input noise (examples/gn_coverage.rs), 3-step's
            // 100–1000× (examples/three_step_coverage.rs).
            covariance: outcome_covariance(&outcome.detail).unwrap_or(&outcome.covariance),
            calibrated_m: val.mean_position_error_m,
            initial_m: initial_val.mean_position_error_m,
            segment_log_ratio: segment_log_ratio(&val.per_segment_m, &initial_val.per_segment_m),
            fit_m,
            split,
            extrinsics: extrinsics.as_ref(),
            misspecified: warnings.iter().filter(|w| w.misspecifies_result()).count(),
            identification: result_identification(&outcome.detail),
            next_drive: Some(&next_drive),
            model_sigma_only: model_sigma_only(&outcome.detail, opts),
            extrinsics_model_sigma_only: extrinsics_model_sigma_only(&outcome.detail, opts, extrinsics.as_ref()),
        },
        &opts.trust,
    );
    let checks = checks::method_reasons(drive, &selection, (&outcome.theta, &outcome.detail), &ext, opts, &next_drive);
    let verdict = crate::assess::trust::Verdict::from_reasons(verdict.reasons.into_iter().chain(checks).collect());
    let timing = Timing {
        setup,
        validation: t.elapsed().as_secs_f64(),
        total: t_start.elapsed().as_secs_f64(),
        ..outcome.timing
    };
    let mut options = opts.clone();
    options.identify.free = selection.free;
    let report = CalibrationReport {
        method: method.name().to_string(),
        theta: outcome.theta,
        covariance: outcome.covariance,
        observability: outcome.observability,
        validation: ValidationSummary {
            mean_position_error_m: val.mean_position_error_m,
            segments: val.segments,
            held_out: held_out.is_some(),
        },
        verdict,
        initial: ThetaScore { theta: opts.theta0, mean_position_error_m: initial_val.mean_position_error_m },
        timing_s: timing,
        extrinsics,
        segments: SegmentCounts {
            cut: selection.cut,
            selected: selection.selected,
            validation: reported.segments.len(),
        },
        detail: outcome.detail,
        warnings,
        auto_fixed: selection.auto_fixed.clone(),
        validate_on: None,
        next_drive_sigma: Some(next_drive),
        options,
    };
    Ok(DetailedCalibration {
        report,
        selected: selection.segments,
        validation: prep.validation,
        compensated: outcome.compensated,
    })
}

/// The options with the method's adjustment of the identification
/// ([`Estimator::adjust_identify`]; borrowed as given when it changes
/// nothing). Reference extrinsics with a method that cannot estimate or
/// apply them are an error.
fn method_options<'o>(opts: &'o CalibrationOptions, method: &dyn Estimator) -> Result<Cow<'o, CalibrationOptions>> {
    let mut identify = opts.identify.clone();
    method.adjust_identify(&mut identify);
    let opts = if identify == opts.identify {
        Cow::Borrowed(opts)
    } else {
        Cow::Owned(CalibrationOptions { identify, ..opts.clone() })
    };
    if opts.identify.uses_extrinsics() && !method.supports_extrinsics() {
        return Err(Error::InvalidOption {
            field: "identify.extrinsics",
            reason: format!(
                "method {} does not estimate or apply the reference extrinsics (lever arm, heading offset); \
                 use batch-gn, three-step or eiv",
                method.name()
            ),
        });
    }
    Ok(opts)
}

/// Where the calibration reports Ē_p: the validation segments of the
/// calibration drive, or of the held-out drive (with each held-out drive's
/// own extrinsics when it has its reference's).
struct ReportValidation<'a> {
    /// The drive the segments are on.
    drive: &'a Drive,
    /// Its validation segments.
    segments: Vec<Segment>,
    /// The held-out drives joined, when each has its own extrinsics.
    held_refs: Option<&'a HeldOutDrives<'a>>,
    /// True when `drive` is held-out data, not the calibration drive.
    held_out: bool,
}

impl<'a> ReportValidation<'a> {
    /// The held-out drive's validation segments (at least one), else the
    /// calibration drive's.
    fn new(prep: &Prepared<'a>, held_out: Option<&'a Drive>, held_refs: Option<&'a HeldOutDrives<'a>>) -> Result<Self> {
        let opts = prep.options;
        let (drive, segments) = match held_out {
            Some(h) => {
                let segs = validation_segments(h, &opts.validation)?;
                if segs.is_empty() {
                    return Err(too_short_for_validation("the held-out drive", h, &opts.validation));
                }
                (h, segs)
            }
            None => (prep.drive, prep.validation.clone()),
        };
        Ok(ReportValidation { drive, segments, held_refs, held_out: held_out.is_some() })
    }

    /// Ē_p at θ_0 with the extrinsics as given (`free`'s to be estimated).
    fn initial(&self, opts: &CalibrationOptions, free: ParamSet) -> Result<ValidationReport> {
        match self.held_refs {
            Some(h) => {
                let cal = CalibrationExtrinsics::before(opts.identify.extrinsics, free, h.given);
                h.error(&self.segments, &opts.theta0, &cal, true)
            }
            None => mean_position_error_with(self.drive, &self.segments, &opts.theta0, &opts.identify.extrinsics),
        }
    }

    /// Ē_p at the result θ with the extrinsics `ext` it used (`given` the
    /// options' values, `estimate` the method's estimate when it made one).
    fn result(
        &self,
        theta: &Theta,
        given: Extrinsics,
        estimate: Option<&ExtrinsicsEstimate>,
        ext: Extrinsics,
    ) -> Result<ValidationReport> {
        match self.held_refs {
            Some(h) => {
                let cal = CalibrationExtrinsics {
                    value: ext,
                    ..CalibrationExtrinsics::before(given, estimate.map_or(ParamSet::EMPTY, |e| e.free), h.given)
                };
                h.error(&self.segments, theta, &cal, false)
            }
            None if self.held_out => mean_position_error_with(self.drive, &self.segments, theta, &ext),
            None => own_error(self.drive, &self.segments, theta, &ext, estimate),
        }
    }
}

/// Ē_p of θ on `segments` of the calibration drive with the extrinsics
/// `ext`; after a joint calibration with a heading offset per drive
/// ([`ExtrinsicsEstimate::per_drive`]) each segment takes its drive's.
fn own_error(
    drive: &Drive,
    segments: &[Segment],
    theta: &Theta,
    ext: &Extrinsics,
    estimate: Option<&ExtrinsicsEstimate>,
) -> Result<ValidationReport> {
    match estimate {
        Some(x) if !x.per_drive.is_empty() => {
            mean_position_error_by(drive, segments, theta, |s| x.for_drive(drive.drive_of_sample(s.start)))
        }
        _ => mean_position_error_with(drive, segments, theta, ext),
    }
}

/// The selection's warnings, the method's, and one when the result's
/// observability check (the final identification's, or the EIV filter's
/// when its θ is the result) left parameters unobservable, with that
/// check's numbers.
fn result_warnings(
    selection: &[Warning],
    method: Vec<Warning>,
    o: &Observability,
    opts: &CalibrationOptions,
) -> Vec<Warning> {
    let mut warnings = selection.to_vec();
    warnings.extend(method);
    if !o.unobservable.is_empty() {
        // An EIV result carries the filter's observability, without batch
        // G-N's sensitivities (its fallback carries the start's, with them).
        let (stage, min_rcond) = match (&opts.method, o.sensitivity_m) {
            (Method::Eiv(m), None) => ("EIV filter", m.filter.min_rcond),
            _ => ("final identification", opts.identify.min_rcond),
        };
        warnings.push(Warning::Unobservable {
            stage: stage.into(),
            params: o.unobservable,
            sensitivity_m: o.sensitivity_m,
            sigma_over_resolution: o.sigma_over_resolution,
            rcond: o.rcond,
            min_rcond,
        });
    }
    warnings
}

/// θ and its covariance fitted on the held-out drive alone with the same
/// options and free set (the cross-split check of [[`Verdict`](crate::Verdict)]); `None`
/// when that fit fails (too short, nothing turns, …): the check is then
/// left out rather than failing the calibration.
fn split_fit(held_out: &Drive, opts: &CalibrationOptions, free: ParamSet) -> Option<(Theta, [[f64; 4]; 4])> {
    let mut o = opts.clone();
    o.identify.free = free;
    o.auto_fix = false;
    o.trust.max_split_sigmas = 0.0;
    let r = calibrate_detailed(held_out, None, &o, None).ok()?.report;
    Some((r.theta, *r.result_covariance().unwrap_or(&r.covariance)))
}

/// The cluster-robust covariance of a method's result
/// ([`CalibrationReport::robust`]).
fn outcome_robust(detail: &MethodDetail) -> Option<&RobustCovariance> {
    match detail {
        MethodDetail::BatchGn(d) => d.identification.robust.as_ref(),
        MethodDetail::ThreeStep(_) | MethodDetail::Eiv(_) => None,
    }
}

/// The covariance standing for a method's result
/// ([`CalibrationReport::result_covariance`]).
fn outcome_covariance(detail: &MethodDetail) -> Option<&[[f64; 4]; 4]> {
    match detail {
        MethodDetail::BatchGn(d) => d.identification.robust.as_ref().map(|r| &r.covariance),
        MethodDetail::ThreeStep(d) => d.uncertainty.batch_spread.as_ref().map(|b| &b.covariance),
        // A fallback result is the start's batch G-N: its cluster-robust σ.
        MethodDetail::Eiv(d) if d.eiv_result == EivOutcome::BatchGnFallback => {
            d.identification.robust.as_ref().map(|r| &r.covariance)
        }
        MethodDetail::Eiv(_) => None,
    }
}

/// The extrinsics estimate of a method's final identification.
fn method_extrinsics(detail: &MethodDetail) -> Option<ExtrinsicsEstimate> {
    match detail {
        // Step 3's robust σ does not stand for the 3-step result
        // ([`CalibrationReport::robust`]); it stays in `identification`.
        MethodDetail::ThreeStep(d) => {
            d.identification.extrinsics.clone().map(|x| ExtrinsicsEstimate { robust: None, ..x })
        }
        MethodDetail::BatchGn(d) => d.identification.extrinsics.clone(),
        // Two-stage: the start's joint estimate, held by the filter (its σ
        // is the start's; see `Warning::EivExtrinsicsHeld`).
        MethodDetail::Eiv(d) => d.identification.extrinsics.clone(),
    }
}

#[cfg(test)]
mod tests;
