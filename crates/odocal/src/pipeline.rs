//! Calibration pipelines: raw batch Gauss-Newton and the 3-step method with
//! input compensation (SPEC §6, paper §4.2, Fig. 2).
//!
//! 1. *Initial identification*: batch G-N from θ_0 on `initial_batches`
//!    random batches of `initial_batch_size` selected segments, with the
//!    measured wheel rotations. Each result is validated; sorted by
//!    validation error, `picks` results are taken at equal steps through the
//!    sorted list: θ_B,I(1..picks).
//! 2. *Input compensation*: every segment used in step 3 is compensated once
//!    per θ_B,I; its compensated input is the mean of those.
//! 3. *Final identification*: batch G-N from θ_0 with the compensated inputs.
//!
//! Every random choice takes [`CalibrationOptions::seed`]; work runs in
//! parallel (rayon) and results are collected in a fixed order, so the
//! output does not depend on the thread count.

use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::compensate::{compensate_segment_with_fallback, CompensateOptions};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::identify::{batch_gauss_newton, batch_normal_equations, observability, IdentifyOptions, IdentifyReport};
use crate::model::{Theta, THETA_NAMES};
use crate::qp::SolverKind;
use crate::segment::{
    calibration_segments, validation_segments, Segment, SegmentData, SegmentOptions, ValidationSegmentOptions,
};
use crate::validate::mean_position_error;

/// Which calibration method to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The 3-step method with input compensation (default).
    ThreeStep,
    /// Raw batch Gauss-Newton over all selected segments.
    BatchGn,
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Method::ThreeStep => "three-step",
            Method::BatchGn => "batch-gn",
        })
    }
}

impl std::str::FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "three-step" => Ok(Method::ThreeStep),
            "batch-gn" => Ok(Method::BatchGn),
            _ => Err(Error::InvalidOption { field: "method", reason: format!("'{s}': use three-step or batch-gn") }),
        }
    }
}

/// Which segments the final identification (step 3) uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FinalSegments {
    /// Every selected segment (default: lowest variance).
    All,
    /// A random batch of this many selected segments (the paper shows 5 suffice).
    Random(usize),
}

/// All settings of a calibration. `Default` holds the SPEC defaults.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationOptions {
    /// The method. Default three-step.
    pub method: Method,
    /// Initial guess θ_0. Default the paper's `[2.0, 0, 1.6, 0]`.
    pub theta0: Theta,
    /// Calibration segments. Default K = 650, stride 100, yaw rate > 0.15 rad/s.
    pub segments: SegmentOptions,
    /// Validation segments. Default K_v = 1300, stride 650, offset 50.
    pub validation: ValidationSegmentOptions,
    /// Gauss-Newton settings (all identifications).
    pub identify: IdentifyOptions,
    /// Compensation QP settings.
    pub compensate: CompensateOptions,
    /// QP solver. Default structured (Riccati interior point).
    pub qp_solver: SolverKind,
    /// Step 1: number of random batches. Default 50.
    pub initial_batches: usize,
    /// Step 1: segments per batch N. Default 10.
    pub initial_batch_size: usize,
    /// Step 1: number of θ_B,I picked at equal steps through the sorted list. Default 5.
    pub picks: usize,
    /// Step 3: segments of the final identification. Default all selected.
    pub final_segments: FinalSegments,
    /// Seed of every random choice. Default 0.
    pub seed: u64,
    /// Hold at θ_0 the parameters these data cannot determine, instead of
    /// estimating them (not in the paper; default false, the SPEC
    /// behaviour). When no segment turns enough, c_d, t_r and d are held and
    /// every segment is used; otherwise the observability check
    /// ([`crate::identify::observability`]) runs on the selected segments at
    /// θ_0 and the named parameter with the smallest sensitivity is held,
    /// repeatedly, until none is named (c_e is never held). What was held is
    /// listed in [`CalibrationReport::auto_fixed`].
    #[serde(default)]
    pub auto_fix: bool,
}

impl Default for CalibrationOptions {
    fn default() -> Self {
        CalibrationOptions {
            method: Method::ThreeStep,
            theta0: Theta::PAPER_INITIAL,
            segments: SegmentOptions::default(),
            validation: ValidationSegmentOptions::default(),
            identify: IdentifyOptions::default(),
            compensate: CompensateOptions::default(),
            qp_solver: SolverKind::default(),
            initial_batches: 50,
            initial_batch_size: 10,
            picks: 5,
            final_segments: FinalSegments::All,
            seed: 0,
            auto_fix: false,
        }
    }
}

impl CalibrationOptions {
    /// Checks all options, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        self.theta0.validate()?;
        self.segments.validate()?;
        self.validation.validate()?;
        self.identify.validate()?;
        self.compensate.validate()?;
        if self.initial_batches == 0 {
            return Err(Error::InvalidOption { field: "initial_batches", reason: "must be at least 1".into() });
        }
        if self.initial_batch_size == 0 {
            return Err(Error::InvalidOption { field: "initial_batch_size", reason: "must be at least 1".into() });
        }
        if self.picks == 0 {
            return Err(Error::InvalidOption { field: "picks", reason: "must be at least 1".into() });
        }
        if self.final_segments == FinalSegments::Random(0) {
            return Err(Error::InvalidOption { field: "final_segments", reason: "must be at least 1".into() });
        }
        Ok(())
    }
}

/// Progress events for a caller's progress display. The library never prints.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Progress {
    /// A stage starts with this many units of work.
    Stage {
        /// Stage name.
        name: &'static str,
        /// Units of work.
        total: u64,
    },
    /// Units of work done in the current stage.
    Advance(u64),
}

/// A progress callback (may be called from several threads).
pub type ProgressFn<'a> = &'a (dyn Fn(Progress) + Sync);

/// θ with its mean validation position error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ThetaScore {
    /// Parameters.
    pub theta: Theta,
    /// Ē_p on the validation segments, m.
    pub mean_position_error_m: f64,
}

/// Step 1 of the 3-step method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitialStep {
    /// Every batch result, in batch order, with the segment starts used.
    pub batches: Vec<BatchResult>,
    /// The picked θ_B,I (best first).
    pub picked: Vec<ThetaScore>,
    /// Indices into `batches` of the picked results.
    pub picked_batches: Vec<usize>,
}

/// One batch Gauss-Newton result of step 1.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatchResult {
    /// First samples of the segments in the batch.
    pub segment_starts: Vec<usize>,
    /// The estimate and its validation error.
    pub score: ThetaScore,
    /// Gauss-Newton iterations.
    pub iterations: usize,
}

/// Step 2 of the 3-step method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompensationStep {
    /// Segments compensated (with at least one successful QP).
    pub segments: usize,
    /// QP compensation jobs (segment × θ_B,I) run.
    pub jobs: usize,
    /// Jobs that failed (left out).
    pub failed_jobs: usize,
    /// QP solves that the configured solver did not finish (iteration limit
    /// or numerical failure) and the Clarabel fallback solved.
    #[serde(default)]
    pub fallback_solves: usize,
    /// Total QP solves (linearizations).
    pub qp_solves: usize,
    /// Mean QP solver iterations per solve.
    pub mean_qp_iterations: f64,
    /// Jobs whose inputs did not settle within the linearization limit.
    pub unconverged_jobs: usize,
    /// RMS relative change of the wheel rotations made by compensation.
    pub rms_relative_input_change: f64,
    /// The solver used.
    pub solver: String,
}

/// Counts of segments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SegmentCounts {
    /// Calibration segments cut.
    pub cut: usize,
    /// Calibration segments selected (turning enough).
    pub selected: usize,
    /// Validation segments.
    pub validation: usize,
}

/// Wall time per stage, s.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Timing {
    /// Whole calibration.
    pub total: f64,
    /// Segmenting and validation of θ_0.
    pub setup: f64,
    /// Step 1 (or the single batch G-N of batch-gn).
    pub initial_identification: f64,
    /// Step 2.
    pub compensation: f64,
    /// Step 3.
    pub final_identification: f64,
    /// Validation of the result.
    pub validation: f64,
}

/// Validation summary of the result (SPEC §9 `validation`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationSummary {
    /// Ē_p of the result, m.
    pub mean_position_error_m: f64,
    /// Validation segments.
    pub segments: usize,
    /// True when the validation ran on held-out data that the calibration
    /// did not see (see [`calibrate_held_out`]).
    pub held_out: bool,
}

/// The calibration report (SPEC §9 and more).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationReport {
    /// The method run.
    pub method: Method,
    /// The calibrated θ.
    pub theta: Theta,
    /// Ē_p of the result.
    pub validation: ValidationSummary,
    /// θ_0 and its Ē_p.
    pub initial: ThetaScore,
    /// Wall time per stage.
    pub timing_s: Timing,
    /// Segment counts.
    pub segments: SegmentCounts,
    /// Step 1 (three-step only).
    pub initial_step: Option<InitialStep>,
    /// Step 2 (three-step only).
    pub compensation: Option<CompensationStep>,
    /// The final Gauss-Newton identification (the only one for batch-gn).
    pub identification: IdentifyReport,
    /// Things the user should know (unobservable parameters, dropped segments).
    pub warnings: Vec<String>,
    /// Parameters held at θ_0 by [`CalibrationOptions::auto_fix`], in the
    /// order they were held (`options.identify.free` shows the final set).
    pub auto_fixed: Vec<String>,
    /// The options used.
    pub options: CalibrationOptions,
}

/// Random batches of `size` distinct indices out of `n` (all when n ≤ size).
pub fn random_batches(n: usize, size: usize, count: usize, seed: u64) -> Vec<Vec<usize>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut idx: Vec<usize> = (0..n).collect();
    (0..count)
        .map(|_| {
            idx.shuffle(&mut rng);
            let mut b: Vec<usize> = idx.iter().copied().take(size.min(n)).collect();
            b.sort_unstable();
            b
        })
        .collect()
}

/// Indices of `picks` entries at equal steps through a list of length `n`
/// (first, …, last), rounding to the nearest.
pub fn equal_step_picks(n: usize, picks: usize) -> Vec<usize> {
    if n == 0 {
        return Vec::new();
    }
    if picks == 1 {
        return vec![0];
    }
    (0..picks).map(|i| ((i * (n - 1)) as f64 / (picks - 1) as f64).round() as usize).collect()
}

/// Compensated inputs of a set of segments: per segment, the mean of the
/// compensations over several θ (SPEC §6 step 2).
#[derive(Debug, Clone, PartialEq)]
pub struct CompensatedInputs {
    /// The segments, in order.
    pub segments: Vec<Segment>,
    /// Compensated `n_rl` per segment.
    pub n_rl: Vec<Vec<f64>>,
    /// Compensated `n_rr` per segment.
    pub n_rr: Vec<Vec<f64>>,
    /// Statistics.
    pub step: CompensationStep,
    /// One line per failed job.
    pub warnings: Vec<String>,
}

/// Compensates every segment once per θ in `thetas` and averages (step 2).
/// Jobs run in parallel; a failed job is left out with a warning; a segment
/// with no successful job is dropped. With the structured solver, a QP it
/// does not finish (iteration limit, numerical failure) is solved again by
/// Clarabel; such fallbacks are counted and reported as warnings.
pub fn compensate_segments(
    drive: &Drive,
    segments: &[Segment],
    thetas: &[Theta],
    opts: &CompensateOptions,
    solver_kind: SolverKind,
    progress: Option<ProgressFn<'_>>,
) -> Result<CompensatedInputs> {
    opts.validate()?;
    let solver = solver_kind.solver();
    let fallback = match solver_kind {
        SolverKind::Structured => Some(SolverKind::Clarabel.solver()),
        SolverKind::Clarabel => None,
    };
    let jobs: Vec<(usize, usize)> = (0..segments.len()).flat_map(|s| (0..thetas.len()).map(move |t| (s, t))).collect();
    if let Some(p) = progress {
        p(Progress::Stage { name: "compensation", total: jobs.len() as u64 });
    }
    let results: Vec<_> = jobs
        .par_iter()
        .map(|&(s, t)| {
            let r = compensate_segment_with_fallback(
                &SegmentData::new(drive, &segments[s]),
                &thetas[t],
                solver.as_ref(),
                fallback.as_deref(),
                opts,
            );
            if let Some(p) = progress {
                p(Progress::Advance(1));
            }
            r
        })
        .collect();
    let mut out = CompensatedInputs {
        segments: Vec::new(),
        n_rl: Vec::new(),
        n_rr: Vec::new(),
        step: CompensationStep {
            segments: 0,
            jobs: jobs.len(),
            failed_jobs: 0,
            fallback_solves: 0,
            qp_solves: 0,
            mean_qp_iterations: 0.0,
            unconverged_jobs: 0,
            rms_relative_input_change: 0.0,
            solver: solver.name().to_string(),
        },
        warnings: Vec::new(),
    };
    let mut qp_iters = 0usize;
    let (mut rel_sq, mut rel_n) = (0.0, 0usize);
    for (s, seg) in segments.iter().enumerate() {
        let k = seg.steps;
        let (mut a, mut b, mut count) = (vec![0.0; k], vec![0.0; k], 0usize);
        for t in 0..thetas.len() {
            match &results[s * thetas.len() + t] {
                Ok(c) => {
                    for i in 0..k {
                        a[i] += c.n_rl[i];
                        b[i] += c.n_rr[i];
                    }
                    count += 1;
                    out.step.qp_solves += c.linearizations;
                    qp_iters += c.qp_iterations;
                    if !c.converged {
                        out.step.unconverged_jobs += 1;
                    }
                    out.step.fallback_solves += c.fallbacks.len();
                    for f in &c.fallbacks {
                        out.warnings.push(format!(
                            "compensation of the segment at sample {} (θ_B,I {}): {f}",
                            seg.start,
                            t + 1
                        ));
                    }
                }
                Err(e) => {
                    out.step.failed_jobs += 1;
                    out.warnings.push(format!("compensation left out: {e}"));
                }
            }
        }
        if count == 0 {
            continue;
        }
        for i in 0..k {
            a[i] /= count as f64;
            b[i] /= count as f64;
            for (m, c) in [(drive.n_rl()[seg.start + i], a[i]), (drive.n_rr()[seg.start + i], b[i])] {
                if m.abs() > 1e-3 {
                    rel_sq += ((c - m) / m).powi(2);
                    rel_n += 1;
                }
            }
        }
        out.segments.push(*seg);
        out.n_rl.push(a);
        out.n_rr.push(b);
    }
    out.step.segments = out.segments.len();
    out.step.mean_qp_iterations =
        if out.step.qp_solves > 0 { qp_iters as f64 / out.step.qp_solves as f64 } else { 0.0 };
    out.step.rms_relative_input_change = if rel_n > 0 { (rel_sq / rel_n as f64).sqrt() } else { 0.0 };
    Ok(out)
}

impl CompensatedInputs {
    /// Segment data with the compensated wheel rotations.
    pub fn segment_data<'a>(&'a self, drive: &'a Drive) -> Vec<SegmentData<'a>> {
        self.segments
            .iter()
            .enumerate()
            .map(|(i, s)| SegmentData::new(drive, s).with_wheels(&self.n_rl[i], &self.n_rr[i]))
            .collect()
    }
}

fn unobservable_warning(report: &IdentifyReport, what: &str) -> Option<String> {
    let o = &report.observability;
    if o.unobservable.is_empty() {
        return None;
    }
    Some(format!(
        "{what}: {} not observable from these data (sensitivity [c_e, c_d, t_r, d] = [{:.3}, {:.3}, {:.3}, {:.3}] m per resolution step, rcond {:.1e}); their estimates are not to be trusted — hold them fixed at θ_0 (--fix) or use a drive with more turns",
        o.unobservable.join(", "),
        o.sensitivity_m[0],
        o.sensitivity_m[1],
        o.sensitivity_m[2],
        o.sensitivity_m[3],
        o.rcond
    ))
}

/// Batch Gauss-Newton from `theta0` on each batch of `data` (indices into
/// `data`), each result validated on `validation` (SPEC §6 step 1, and the
/// same on compensated inputs). Batches run in parallel; results come back in
/// batch order whatever the thread count. A failed batch is an `Err` in its
/// place, so callers decide whether to leave it out.
pub fn score_batches(
    drive: &Drive,
    data: &[SegmentData<'_>],
    batches: &[Vec<usize>],
    validation: &[Segment],
    theta0: &Theta,
    opts: &IdentifyOptions,
    progress: Option<ProgressFn<'_>>,
) -> Vec<Result<BatchResult>> {
    batches
        .par_iter()
        .map(|b| {
            let r = if let Some(&bad) = b.iter().find(|&&i| i >= data.len()) {
                Err(Error::InvalidOption {
                    field: "batches",
                    reason: format!("index {bad} out of range for {} segments", data.len()),
                })
            } else {
                let batch: Vec<SegmentData> = b.iter().map(|&i| data[i]).collect();
                batch_gauss_newton(&batch, theta0, opts).and_then(|rep| {
                    let v = mean_position_error(drive, validation, &rep.theta)?;
                    Ok(BatchResult {
                        segment_starts: b.iter().map(|&i| data[i].start).collect(),
                        score: ThetaScore { theta: rep.theta, mean_position_error_m: v.mean_position_error_m },
                        iterations: rep.iterations,
                    })
                })
            };
            if let Some(p) = progress {
                p(Progress::Advance(1));
            }
            r
        })
        .collect()
}

/// Pure Gauss-Newton on every segment of `data` alone (a batch of one), each
/// result validated on `validation` — the per-segment estimates of the
/// paper's Fig. 7/8. Pass compensated segment data
/// ([`CompensatedInputs::segment_data`]) to get the compensated-input
/// estimates. Results are in segment order.
pub fn per_segment_identification(
    drive: &Drive,
    data: &[SegmentData<'_>],
    validation: &[Segment],
    theta0: &Theta,
    opts: &IdentifyOptions,
) -> Vec<Result<BatchResult>> {
    let singles: Vec<Vec<usize>> = (0..data.len()).map(|i| vec![i]).collect();
    score_batches(drive, data, &singles, validation, theta0, opts, None)
}

/// A calibration with the intermediate data an experiment needs: the report,
/// the segments used and (three-step only) the compensated inputs of step 2.
#[derive(Debug, Clone, PartialEq)]
pub struct DetailedCalibration {
    /// The report [`calibrate`] returns.
    pub report: CalibrationReport,
    /// The selected calibration segments (all segments when none turns enough).
    pub selected: Vec<Segment>,
    /// The validation segments.
    pub validation: Vec<Segment>,
    /// Step 2's compensated inputs (three-step only).
    pub compensated: Option<CompensatedInputs>,
}

/// Runs a calibration of `drive` with `opts` (SPEC §6).
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{sim, pipeline};
/// let drive = sim::simulate(&sim::SimOptions { length_km: 3.0, ..sim::SimOptions::paper(1) })?.drive;
/// let opts = pipeline::CalibrationOptions { initial_batches: 8, ..Default::default() };
/// let report = pipeline::calibrate(&drive, &opts, None)?;
/// assert!(report.validation.mean_position_error_m < report.initial.mean_position_error_m);
/// # Ok(()) }
/// ```
pub fn calibrate(
    drive: &Drive,
    opts: &CalibrationOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<CalibrationReport> {
    calibrate_held_out(drive, None, opts, progress)
}

/// Runs a calibration on `drive` and, when `held_out` is given, reports
/// `validation` and `initial` Ē_p on the held-out drive instead (the
/// calibration, including the choice of θ_B,I in step 1, sees only `drive`).
pub fn calibrate_held_out(
    drive: &Drive,
    held_out: Option<&Drive>,
    opts: &CalibrationOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<CalibrationReport> {
    calibrate_detailed(drive, held_out, opts, progress).map(|d| d.report)
}

/// [`calibrate_held_out`], also returning the segments and step 2's
/// compensated inputs.
pub fn calibrate_detailed(
    drive: &Drive,
    held_out: Option<&Drive>,
    opts: &CalibrationOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<DetailedCalibration> {
    opts.validate()?;
    let t_start = Instant::now();
    let mut timing = Timing::default();
    let mut warnings = Vec::new();
    let mut effective = opts.clone();
    let mut auto_fixed: Vec<String> = Vec::new();

    let selection = calibration_segments(drive, &opts.segments)?;
    let validation = validation_segments(drive, &opts.validation)?;
    if selection.all.is_empty() {
        return Err(Error::NoSegments(format!(
            "the drive has {} samples in {} part(s); a calibration segment needs {} steps",
            drive.len(),
            drive.parts().len(),
            opts.segments.length_steps + 1
        )));
    }
    if selection.selected.is_empty() {
        let free_yaw: Vec<&'static str> = [(1, "c_d"), (2, "t_r"), (3, "d")]
            .iter()
            .filter(|(i, _)| opts.identify.free[*i])
            .map(|(_, n)| *n)
            .collect();
        let peak = selection.all.iter().map(|s| s.peak_yaw_rate_rad_per_s).fold(0.0, f64::max);
        if !free_yaw.is_empty() && opts.auto_fix {
            for i in 1..4 {
                effective.identify.free[i] = false;
            }
            auto_fixed.extend(free_yaw.iter().map(|n| n.to_string()));
            warnings.push(format!(
                "auto-fix: {} held at θ_0 and all {} segments used: none turns faster than {} rad/s (the fastest: \
                 {peak:.3} rad/s), so only c_e is observable",
                free_yaw.join(", "),
                selection.all.len(),
                opts.segments.min_peak_yaw_rate_rad_per_s
            ));
        } else if !free_yaw.is_empty() {
            return Err(Error::NotObservable {
                params: free_yaw,
                reason: format!(
                    "none of the {} segments turns faster than {} rad/s (the fastest: {peak:.3} rad/s); these \
                     parameters act only through the yaw equation. Hold them at θ_0 (--fix c_d,t_r,d) and \
                     select every segment (--min-yaw-rate 0) to calibrate c_e alone",
                    selection.all.len(),
                    opts.segments.min_peak_yaw_rate_rad_per_s
                ),
            });
        }
    }
    if validation.is_empty() {
        return Err(Error::NoSegments(format!(
            "the drive ({} samples) is too short for one validation segment of {} steps",
            drive.len(),
            opts.validation.length_steps
        )));
    }
    let selected = if selection.selected.is_empty() { selection.all.clone() } else { selection.selected.clone() };
    if opts.auto_fix && auto_fixed.is_empty() {
        let data: Vec<SegmentData> = selected.iter().map(|s| SegmentData::new(drive, s)).collect();
        let held = hold_unobservable(&data, &mut effective);
        if !held.is_empty() {
            warnings.push(format!(
                "auto-fix: {} held at θ_0 (not observable from the {} selected segments at θ_0)",
                held.join(", "),
                selected.len()
            ));
        }
        auto_fixed.extend(held);
    }
    let opts = &effective;
    let (report_drive, report_segments) = match held_out {
        Some(h) => {
            let segs = validation_segments(h, &opts.validation)?;
            if segs.is_empty() {
                return Err(Error::NoSegments(format!(
                    "the held-out drive ({} samples) is too short for one validation segment of {} steps",
                    h.len(),
                    opts.validation.length_steps
                )));
            }
            (h, segs)
        }
        None => (drive, validation.clone()),
    };
    let initial_val = mean_position_error(report_drive, &report_segments, &opts.theta0)?;
    timing.setup = t_start.elapsed().as_secs_f64();

    let counts = SegmentCounts {
        cut: selection.all.len(),
        selected: selection.selected.len(),
        validation: report_segments.len(),
    };
    let (identification, initial_step, compensated) = match opts.method {
        Method::BatchGn => {
            let t = Instant::now();
            if let Some(p) = progress {
                p(Progress::Stage { name: "batch Gauss-Newton", total: 1 });
            }
            let data: Vec<SegmentData> = selected.iter().map(|s| SegmentData::new(drive, s)).collect();
            let report = batch_gauss_newton(&data, &opts.theta0, &opts.identify)?;
            if let Some(p) = progress {
                p(Progress::Advance(1));
            }
            timing.initial_identification = t.elapsed().as_secs_f64();
            (report, None, None)
        }
        Method::ThreeStep => {
            // Step 1.
            let t = Instant::now();
            let batches = random_batches(selected.len(), opts.initial_batch_size, opts.initial_batches, opts.seed);
            if let Some(p) = progress {
                p(Progress::Stage { name: "initial identification", total: batches.len() as u64 });
            }
            let data: Vec<SegmentData> = selected.iter().map(|s| SegmentData::new(drive, s)).collect();
            let results = score_batches(drive, &data, &batches, &validation, &opts.theta0, &opts.identify, progress);
            let mut ok = Vec::new();
            for (i, r) in results.into_iter().enumerate() {
                match r {
                    Ok(b) => ok.push(b),
                    Err(e) => warnings.push(format!("initial batch {i} left out: {e}")),
                }
            }
            if ok.is_empty() {
                return Err(Error::Numerical("every initial batch identification failed".into()));
            }
            let mut order: Vec<usize> = (0..ok.len()).collect();
            order.sort_by(|&a, &b| ok[a].score.mean_position_error_m.total_cmp(&ok[b].score.mean_position_error_m));
            let picked_batches: Vec<usize> =
                equal_step_picks(order.len(), opts.picks).into_iter().map(|i| order[i]).collect();
            let picked: Vec<ThetaScore> = picked_batches.iter().map(|&i| ok[i].score).collect();
            timing.initial_identification = t.elapsed().as_secs_f64();

            // Step 2.
            let t = Instant::now();
            let final_segs: Vec<Segment> = match opts.final_segments {
                FinalSegments::All => selected.clone(),
                FinalSegments::Random(n) => random_batches(selected.len(), n, 1, opts.seed ^ 0x5eed_f1a1)[0]
                    .iter()
                    .map(|&i| selected[i])
                    .collect(),
            };
            let thetas: Vec<Theta> = picked.iter().map(|p| p.theta).collect();
            let comp = compensate_segments(drive, &final_segs, &thetas, &opts.compensate, opts.qp_solver, progress)?;
            warnings.extend(comp.warnings.iter().cloned());
            if comp.segments.is_empty() {
                return Err(Error::Qp("input compensation failed on every segment".into()));
            }
            timing.compensation = t.elapsed().as_secs_f64();

            // Step 3.
            let t = Instant::now();
            if let Some(p) = progress {
                p(Progress::Stage { name: "final identification", total: 1 });
            }
            let data = comp.segment_data(drive);
            let report = batch_gauss_newton(&data, &opts.theta0, &opts.identify)?;
            if let Some(p) = progress {
                p(Progress::Advance(1));
            }
            timing.final_identification = t.elapsed().as_secs_f64();
            (report, Some(InitialStep { batches: ok, picked, picked_batches }), Some(comp))
        }
    };
    warnings.extend(unobservable_warning(&identification, "final identification"));
    let t = Instant::now();
    let val = mean_position_error(report_drive, &report_segments, &identification.theta)?;
    timing.validation = t.elapsed().as_secs_f64();
    timing.total = t_start.elapsed().as_secs_f64();
    let report = CalibrationReport {
        method: opts.method,
        theta: identification.theta,
        validation: ValidationSummary {
            mean_position_error_m: val.mean_position_error_m,
            segments: val.segments,
            held_out: held_out.is_some(),
        },
        initial: ThetaScore { theta: opts.theta0, mean_position_error_m: initial_val.mean_position_error_m },
        timing_s: timing,
        segments: counts,
        initial_step,
        compensation: compensated.as_ref().map(|c| c.step.clone()),
        identification,
        warnings,
        auto_fixed,
        options: opts.clone(),
    };
    Ok(DetailedCalibration { report, selected, validation, compensated })
}

/// Holds at θ_0, one at a time, the parameter (never c_e) with the smallest
/// sensitivity among those the observability check names on `segments` at
/// θ_0, until none is named. Returns the names held, in order.
fn hold_unobservable(segments: &[SegmentData<'_>], opts: &mut CalibrationOptions) -> Vec<String> {
    let ne = batch_normal_equations(segments, &opts.theta0, &opts.identify.weights);
    let mut held = Vec::new();
    loop {
        let o = observability(&ne, &opts.identify.free, &opts.identify);
        let pick = o
            .unobservable
            .iter()
            .filter_map(|n| THETA_NAMES.iter().position(|t| t == n))
            .filter(|&i| i != 0 && opts.identify.free[i])
            .min_by(|&a, &b| o.sensitivity_m[a].total_cmp(&o.sensitivity_m[b]));
        match pick {
            Some(i) => {
                opts.identify.free[i] = false;
                held.push(THETA_NAMES[i].to_string());
            }
            None => return held,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, SimOptions};

    /// Relative error to which a noise-free, exact-model (1 substep) drive
    /// gives θ back from a batch of all its turning segments.
    const EXACT_REL_TOL: f64 = 1e-6;

    #[test]
    fn per_segment_and_batch_helpers() {
        let sim = simulate(&SimOptions { length_km: 2.0, substeps: 1, ..SimOptions::noise_free(4) }).expect("sim");
        let drive = &sim.drive;
        let sel = calibration_segments(drive, &SegmentOptions::default()).expect("segments");
        let val = validation_segments(drive, &ValidationSegmentOptions::default()).expect("validation");
        let segs: Vec<Segment> = sel.selected.clone();
        assert!(segs.len() >= 3, "the drive turns");
        let data: Vec<SegmentData> = segs.iter().map(|s| SegmentData::new(drive, s)).collect();
        let (theta0, id) = (Theta::PAPER_INITIAL, IdentifyOptions::default());

        // One result per segment, in segment order.
        let out = per_segment_identification(drive, &data[..3], &val, &theta0, &id);
        assert_eq!(out.len(), 3);
        for (s, r) in segs.iter().zip(&out) {
            assert_eq!(r.as_ref().expect("identified").segment_starts, vec![s.start]);
        }

        // A batch of every segment recovers the truth; a bad index fails in place.
        let all: Vec<usize> = (0..data.len()).collect();
        let out = score_batches(drive, &data, &[all, vec![0, data.len()]], &val, &theta0, &id, None);
        let est = out[0].as_ref().expect("identified").score.theta;
        let truth = sim.sidecar.theta_true;
        for (e, t) in est.to_array().iter().zip(truth.to_array()) {
            assert!(((e - t) / t).abs() < EXACT_REL_TOL, "{est} vs {truth}");
        }
        let e = out[1].as_ref().expect_err("index out of range");
        assert!(e.to_string().contains(&format!("index {}", data.len())), "{e}");
    }

    #[test]
    fn picks_at_equal_steps() {
        assert_eq!(equal_step_picks(50, 5), vec![0, 12, 25, 37, 49]);
        assert_eq!(equal_step_picks(3, 5), vec![0, 1, 1, 2, 2]);
        assert_eq!(equal_step_picks(7, 1), vec![0]);
    }

    #[test]
    fn random_batches_are_seeded_and_distinct() {
        let a = random_batches(40, 10, 5, 7);
        assert_eq!(a, random_batches(40, 10, 5, 7));
        assert_ne!(a, random_batches(40, 10, 5, 8));
        for b in &a {
            let mut u = b.clone();
            u.dedup();
            assert_eq!(u.len(), 10);
        }
    }

    /// Noise off: the 3-step method recovers θ_true. Not to 1e-9: the SPEC's
    /// input-rate penalty rounds off the simulator's acceleration switches
    /// even without noise (the compensated inputs move by ~1.5 % rms). Measured
    /// here (4 km, all selected segments, structured solver): c_e 1.7e-5,
    /// c_d 1.5e-3, t_r 5.9e-4, d 9.8e-3 relative; the bounds keep a ~3× margin.
    #[test]
    fn three_step_noise_free_recovers_truth() {
        let sim = simulate(&SimOptions { length_km: 4.0, ..SimOptions::noise_free(3) }).expect("sim");
        let truth = sim.sidecar.theta_true;
        let opts = CalibrationOptions { initial_batches: 6, ..Default::default() };
        let r = calibrate(&sim.drive, &opts, None).expect("calibrate");
        let rel = |a: f64, b: f64| ((a - b) / b).abs();
        assert!(rel(opts.theta0.t_r, truth.t_r) > 0.04, "the start is off");
        assert!(rel(r.theta.c_e, truth.c_e) < 5e-5, "{}", r.theta);
        assert!(rel(r.theta.c_d, truth.c_d) < 5e-3, "{}", r.theta);
        assert!(rel(r.theta.t_r, truth.t_r) < 2e-3, "{}", r.theta);
        assert!(rel(r.theta.d, truth.d) < 3e-2, "{}", r.theta);
        let step = r.compensation.expect("three-step");
        assert_eq!(step.failed_jobs, 0);
        assert!(r.validation.mean_position_error_m < 0.05, "{}", r.validation.mean_position_error_m);
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod solver_tests {
    use super::*;
    use crate::sim::{simulate, SimOptions};

    /// θ from the structured solver and from Clarabel, relative: both QP
    /// solvers stop ~1e-9 relative from the optimum, compensated inputs
    /// agree to ~1e-8 rev/s, and step 3 maps that to θ well below 1e-6.
    const THETA_RTOL: f64 = 1e-6;

    fn short_drive() -> Drive {
        simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) }).unwrap().drive
    }

    fn short_opts(solver: SolverKind) -> CalibrationOptions {
        CalibrationOptions {
            initial_batches: 8,
            final_segments: FinalSegments::Random(8),
            qp_solver: solver,
            ..Default::default()
        }
    }

    /// The report as JSON without wall times: equal strings mean every
    /// number is bitwise equal (serde_json writes f64 round-trip exactly).
    fn without_timing(r: &CalibrationReport) -> String {
        let mut r = r.clone();
        r.timing_s = Timing::default();
        serde_json::to_string(&r).unwrap()
    }

    #[test]
    fn three_step_same_theta_with_either_qp_solver() {
        let drive = short_drive();
        let s = calibrate(&drive, &short_opts(SolverKind::Structured), None).unwrap();
        let c = calibrate(&drive, &short_opts(SolverKind::Clarabel), None).unwrap();
        let (sc, cc) = (s.compensation.as_ref().unwrap(), c.compensation.as_ref().unwrap());
        assert_eq!((sc.failed_jobs, cc.failed_jobs), (0, 0));
        assert_eq!(sc.fallback_solves, 0);
        assert_eq!(sc.segments, 8);
        let (a, b) = (s.theta.to_array(), c.theta.to_array());
        for i in 0..4 {
            // c_d and d are near 0: relative to the θ scale [c_e, c_e, t_r, t_r].
            let scale = [a[0], a[0], a[2], a[2]][i].abs();
            assert!((a[i] - b[i]).abs() <= THETA_RTOL * scale, "θ[{i}]: structured {} vs clarabel {}", a[i], b[i]);
        }
        // And the compensation did something: θ moved from step 1's.
        assert!(s.theta != s.initial_step.as_ref().unwrap().picked[0].theta);
    }

    #[test]
    fn report_does_not_depend_on_thread_count() {
        let drive = short_drive();
        let opts = short_opts(SolverKind::Structured);
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap();
            pool.install(|| calibrate(&drive, &opts, None).unwrap())
        };
        let one = without_timing(&run(1));
        for threads in [2, 4] {
            assert_eq!(one, without_timing(&run(threads)), "{threads} threads");
        }
    }
}
