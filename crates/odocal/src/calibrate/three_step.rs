//! The 3-step method with input compensation (docs/method.md §6, paper §4.2, Fig. 2).
//!
//! 1. *Initial identification*: batch G-N from θ_0 on `initial_batches`
//!    random batches of `initial_batch_size` selected segments, with the
//!    measured wheel rotations. Each result is validated; sorted by
//!    validation error, `picks` results are taken at equal steps through the
//!    sorted list: θ_B,I(1..picks).
//! 2. *Input compensation* ([`crate::compensate::compensate_segments`]):
//!    every segment used in step 3 is compensated once per θ_B,I; its
//!    compensated input is the mean of those.
//! 3. *Final identification*: batch G-N from θ_0 with the compensated inputs.
//!
//! Reference extrinsics ([[`Extrinsics`]]): steps 1 and 3 estimate (or
//! hold) them with θ through the shared identification; step 2's QP does
//! not estimate them, it tracks the axle poses implied by the picked
//! batches' mean extrinsics.

use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Estimator, MethodDetail, MethodOutcome, Prepared, Selection, ThetaScore, Timing};
use crate::assess::position_error::mean_position_error_with;
use crate::assess::trust::{check_theta, GuardViolation, Guards};
use crate::assess::warning::Warning;
use crate::compensate::{compensate_segments, CompensateOptions, CompensatedInputs, CompensationStep, QpOptions};
use crate::drive::segment::{Segment, SegmentData};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::identify::{batch_gauss_newton, robust_covariance_at, IdentifyOptions, IdentifyReport, RobustCovariance};
use crate::model::extrinsics::Extrinsics;
use crate::model::param::ParamSet;
use crate::model::Theta;
use crate::progress::{emit, Progress, ProgressFn};

/// Mixed into [`super::CalibrationOptions::seed`] to draw step 3's random
/// batch ([`FinalSegments::Random`]) independently of step 1's batches.
pub(crate) const FINAL_SEGMENTS_SEED_SALT: u64 = 0x5eed_f1a1;

/// Which segments the final identification (step 3) uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FinalSegments {
    /// Every selected segment (default: lowest variance).
    All,
    /// A random batch of this many selected segments (the paper shows 5 suffice).
    Random(usize),
}

impl std::str::FromStr for FinalSegments {
    type Err = Error;
    /// `"all"` or a number of segments.
    fn from_str(s: &str) -> Result<Self> {
        match s.trim() {
            "all" => Ok(FinalSegments::All),
            n => n.parse().map(FinalSegments::Random).map_err(|_| Error::Parse {
                what: "final segments",
                input: s.to_string(),
                expected: "'all' or a number of segments",
            }),
        }
    }
}

/// Settings of the 3-step method. `Default` holds the defaults docs/method.md names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ThreeStepOptions {
    /// Step 1: number of random batches. Default 50.
    pub initial_batches: usize,
    /// Step 1: segments per batch N. Default 10.
    pub initial_batch_size: usize,
    /// Step 1: number of θ_B,I picked at equal steps through the sorted
    /// list of plausible batch results. Default 5. Indices are rounded, so
    /// more picks than that list holds (e.g. more than `initial_batches`)
    /// take some results more than once, each a compensation and a final
    /// fit of its own: they weigh more, and the run takes longer.
    pub picks: usize,
    /// Step 3: segments of the final identification. Default all selected.
    pub final_segments: FinalSegments,
    /// Step 2: the compensation QP.
    pub compensate: CompensateOptions,
    /// Step 2: the QP solver and its settings. Default structured, with
    /// Clarabel as fallback.
    pub qp: QpOptions,
}

impl Default for ThreeStepOptions {
    fn default() -> Self {
        ThreeStepOptions {
            initial_batches: 50,
            initial_batch_size: 10,
            picks: 5,
            final_segments: FinalSegments::All,
            compensate: CompensateOptions::default(),
            qp: QpOptions::default(),
        }
    }
}

/// Step 1 of the 3-step method.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct InitialStep {
    /// Every batch result, in batch order, with the segment starts used.
    pub batches: Vec<BatchResult>,
    /// The picked θ_B,I (best first).
    pub picked: Vec<ThetaScore>,
    /// Indices into `batches` of the picked results.
    pub picked_batches: Vec<usize>,
    /// Results that failed a plausibility guard (never picked).
    #[serde(default)]
    pub rejected: Vec<RejectedBatch>,
}

research_pub! {
    /// One batch Gauss-Newton result of step 1.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct BatchResult {
        /// First samples of the segments in the batch.
        pub segment_starts: Vec<usize>,
        /// The estimate and its validation error.
        pub score: ThetaScore,
        /// Gauss-Newton iterations.
        pub iterations: usize,
        /// Reciprocal condition number of `JᵀWJ` at the estimate.
        #[serde(default)]
        pub rcond: f64,
        /// The batch's reference extrinsics (estimated or held), when the
        /// identification involved them.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub extrinsics: Option<Extrinsics>,
    }
}

/// A step-1 result that failed a plausibility guard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct RejectedBatch {
    /// Index into [`InitialStep::batches`].
    pub index: usize,
    /// The guards it failed.
    pub violations: Vec<GuardViolation>,
}

/// What the 3-step method reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct ThreeStepDetail {
    /// Step 1.
    pub initial_step: InitialStep,
    /// Step 2.
    pub compensation: CompensationStep,
    /// Step 3.
    pub identification: IdentifyReport,
    /// Uncertainty of the result beyond step 3's own σ (boxed: it would
    /// make this the report's one large variant).
    #[serde(default)]
    pub uncertainty: Box<ThreeStepUncertainty>,
}

/// Candidate covariances of the 3-step result that, unlike step 3's own
/// (model or cluster-robust), do not take its compensated inputs for data:
/// step 3 re-fits on inputs compensated with θ near its own result, so its
/// residuals are too small to measure the result's error.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub(crate) struct ThreeStepUncertainty {
    /// The cluster-robust covariance ([`RobustCovariance`]) of batch
    /// Gauss-Newton on step 3's segments with the *measured* inputs,
    /// evaluated at the 3-step θ ([`crate::identify::robust_covariance_at`]).
    /// `None` with reference extrinsics, or as for [`IdentifyReport::robust`].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub measured_inputs: Option<RobustCovariance>,
    /// The spread of step 1's plausible batch estimates, scaled to all the
    /// data ([`BatchSpread`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub batch_spread: Option<BatchSpread>,
}

/// The covariance of θ from the spread of step 1's plausible batch
/// estimates: their sample covariance times `b/(n − b)`, the subsampling
/// (delete-d jackknife) factor for estimates on `b` of `n` independent
/// units; `n` is the selected segments' distinct samples over the segment
/// length (overlapping segments share samples).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct BatchSpread {
    /// Covariance of θ, 4×4, row-major, SI units squared.
    pub covariance: [[f64; 4]; 4],
    /// Batch estimates used.
    pub batches: usize,
    /// Segments per batch `b`.
    pub batch_size: usize,
    /// Independent segment lengths in the selection `n`.
    pub effective_segments: f64,
}

impl BatchSpread {
    /// The spread of `thetas` (each on `batch_size` segments) scaled to
    /// `effective_segments`; `None` with fewer than 3 estimates or
    /// `effective_segments ≤ batch_size`.
    pub(crate) fn new(thetas: &[Theta], batch_size: usize, effective_segments: f64) -> Option<Self> {
        let n = thetas.len();
        let b = batch_size as f64;
        if n < 3 || effective_segments <= b {
            return None;
        }
        let a: Vec<[f64; 4]> = thetas.iter().map(|t| t.to_array()).collect();
        let mean: [f64; 4] = std::array::from_fn(|i| a.iter().map(|x| x[i]).sum::<f64>() / n as f64);
        let factor = b / (effective_segments - b) / (n - 1) as f64;
        let covariance = std::array::from_fn(|i| {
            std::array::from_fn(|j| a.iter().map(|x| (x[i] - mean[i]) * (x[j] - mean[j])).sum::<f64>() * factor)
        });
        Some(BatchSpread { covariance, batches: n, batch_size, effective_segments })
    }

    /// One-σ of θ.
    pub(crate) fn std_dev(&self) -> Theta {
        let c = &self.covariance;
        Theta { c_e: c[0][0].sqrt(), c_d: c[1][1].sqrt(), t_r: c[2][2].sqrt(), d: c[3][3].sqrt() }
    }
}

/// Distinct samples covered by `segments` over one segment's steps.
fn effective_segments(segments: &[Segment]) -> f64 {
    let Some(k) = segments.first().map(|s| s.steps) else { return 0.0 };
    let mut iv: Vec<(usize, usize)> = segments.iter().map(|s| (s.start, s.start + s.steps)).collect();
    iv.sort_unstable();
    let (mut covered, mut end) = (0usize, 0usize);
    for (a, b) in iv {
        let a = a.max(end);
        if b > a {
            covered += b - a;
            end = b;
        }
    }
    covered as f64 / k.max(1) as f64
}

research_pub! {
    /// Random batches of `size` distinct indices out of `n` (all when n ≤ size).
    fn random_batches(n: usize, size: usize, count: usize, seed: u64) -> Vec<Vec<usize>> {
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
}

/// Indices of `picks` entries at equal steps through a list of length `n`
/// (first, …, last), rounding to the nearest.
pub(crate) fn equal_step_picks(n: usize, picks: usize) -> Vec<usize> {
    if n == 0 {
        return Vec::new();
    }
    if picks == 1 {
        return vec![0];
    }
    (0..picks).map(|i| ((i * (n - 1)) as f64 / (picks - 1) as f64).round() as usize).collect()
}

research_pub! {
    /// Batch Gauss-Newton from `theta0` on each batch of `data` (indices into
    /// `data`), each result validated on `validation` (docs/method.md §6 step 1, and the
    /// same on compensated inputs). Batches run in parallel; results come back in
    /// batch order whatever the thread count. A failed batch is an `Err` in its
    /// place, so callers decide whether to leave it out.
    fn score_batches(
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
                        // A batch that estimated extrinsics is scored with them.
                        let ext = rep.extrinsics.as_ref().map_or(opts.extrinsics, |e| e.value);
                        let v = mean_position_error_with(drive, validation, &rep.theta, &ext)?;
                        Ok(BatchResult {
                            segment_starts: b.iter().map(|&i| data[i].start).collect(),
                            score: ThetaScore { theta: rep.theta, mean_position_error_m: v.mean_position_error_m },
                            iterations: rep.iterations,
                            rcond: rep.observability.rcond,
                            extrinsics: rep.extrinsics.map(|_| ext),
                        })
                    })
                };
                emit(progress, Progress::Advance(1));
                r
            })
            .collect()
    }
}

/// Pure Gauss-Newton on every segment of `data` alone (a batch of one), each
/// result validated on `validation` — the per-segment estimates of the
/// paper's Fig. 7/8. Pass compensated segment data
/// ([`crate::compensate::CompensatedInputs::segment_data`]) to get the
/// compensated-input estimates. Results are in segment order.
pub(crate) fn per_segment_identification(
    drive: &Drive,
    data: &[SegmentData<'_>],
    validation: &[Segment],
    theta0: &Theta,
    opts: &IdentifyOptions,
) -> Vec<Result<BatchResult>> {
    let singles: Vec<Vec<usize>> = (0..data.len()).map(|i| vec![i]).collect();
    score_batches(drive, data, &singles, validation, theta0, opts, None)
}

impl Estimator for ThreeStepOptions {
    fn name(&self) -> &'static str {
        "three-step"
    }

    fn validate(&self) -> Result<()> {
        self.compensate.validate()?;
        self.qp.validate()?;
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

    /// Steps 1 and 3 estimate (or hold) the extrinsics through the shared
    /// identification, and step 1 scores each batch with its own. Step 2's
    /// QP does not estimate them: it tracks the axle poses the reference
    /// implies under the mean extrinsics of the picked batches
    /// ([`crate::drive::axle_reference_drive`]).
    fn supports_extrinsics(&self) -> bool {
        true
    }

    fn run(
        &self,
        prep: &Prepared<'_>,
        selection: &Selection,
        progress: Option<ProgressFn<'_>>,
    ) -> Result<MethodOutcome> {
        let (drive, opts) = (prep.drive, prep.options);
        let identify = selection.identify(opts);
        let selected = &selection.segments;
        let mut timing = Timing::default();
        let mut warnings = Vec::new();

        // Step 1.
        let t = Instant::now();
        let step1 = self.initial_step(prep, selected, &identify, progress, &mut warnings)?;
        timing.initial_identification = t.elapsed().as_secs_f64();

        // Step 2.
        let t = Instant::now();
        let comp = self.compensation_step(drive, selected, &step1, &identify, opts.seed, progress)?;
        warnings.extend(comp.warnings.iter().cloned().map(Warning::from));
        if comp.segments.is_empty() {
            return Err(Error::NoSegments("input compensation failed on every segment".into()));
        }
        timing.compensation = t.elapsed().as_secs_f64();

        // Step 3.
        let t = Instant::now();
        emit(progress, Progress::Stage { name: "final identification", total: 1 });
        let report = batch_gauss_newton(&comp.segment_data(drive), &opts.theta0, &identify)?;
        emit(progress, Progress::Advance(1));
        let uncertainty = self.uncertainty(drive, selected, &comp, &report, &step1, &identify);
        timing.final_identification = t.elapsed().as_secs_f64();
        let InitialResults { ok, rejected, picked_batches, picked, .. } = step1;
        Ok(MethodOutcome {
            theta: report.theta,
            iterations: Some(report.iterations),
            covariance: report.covariance,
            observability: report.observability.clone(),
            detail: MethodDetail::ThreeStep(ThreeStepDetail {
                initial_step: InitialStep { batches: ok, picked, picked_batches, rejected },
                compensation: comp.step.clone(),
                identification: report,
                uncertainty,
            }),
            timing,
            warnings,
            compensated: Some(comp),
        })
    }
}

/// Step 1's results.
struct InitialResults {
    /// Every batch identified, in batch order (failed batches left out).
    ok: Vec<BatchResult>,
    /// The results of `ok` that failed the plausibility guards.
    rejected: Vec<RejectedBatch>,
    /// Indices into `ok` of the plausible results, by increasing Ē_p.
    order: Vec<usize>,
    /// Indices into `ok` of the picked θ_B,I.
    picked_batches: Vec<usize>,
    /// The picked θ_B,I with their Ē_p.
    picked: Vec<ThetaScore>,
}

impl ThreeStepOptions {
    /// Step 1: batch Gauss-Newton from θ_0 on random batches of the
    /// selected segments, each scored by Ē_p on the validation segments;
    /// the plausible results sorted by Ē_p and `picks` of them taken at
    /// equal steps (fewer when not enough are plausible).
    fn initial_step(
        &self,
        prep: &Prepared<'_>,
        selected: &[Segment],
        identify: &IdentifyOptions,
        progress: Option<ProgressFn<'_>>,
        warnings: &mut Vec<Warning>,
    ) -> Result<InitialResults> {
        let (drive, opts) = (prep.drive, prep.options);
        #[allow(unused_mut)]
        let mut batches = random_batches(selected.len(), self.initial_batch_size, self.initial_batches, opts.seed);
        emit(progress, Progress::Stage { name: "initial identification", total: batches.len() as u64 });
        #[allow(unused_mut)]
        let mut data: Vec<SegmentData> = selected.iter().map(|s| SegmentData::new(drive, s)).collect();
        #[cfg(test)]
        forced::apply(drive, &mut data, &mut batches);
        let results = score_batches(drive, &data, &batches, &prep.validation, &opts.theta0, identify, progress);
        let (ok, rejected) = screen_batches(results, &opts.theta0, identify.free, &opts.trust.guards, warnings);
        if ok.is_empty() {
            return Err(Error::Numerical("every initial batch identification failed".into()));
        }
        let order = plausible_by_error(&ok, &rejected)?;
        let picks = if order.len() < self.picks && !rejected.is_empty() {
            warnings.push(Warning::FewUsableBatches { usable: order.len(), picks: self.picks });
            order.len()
        } else {
            self.picks
        };
        let picked_batches: Vec<usize> = equal_step_picks(order.len(), picks).into_iter().map(|i| order[i]).collect();
        let picked: Vec<ThetaScore> = picked_batches.iter().map(|&i| ok[i].score).collect();
        Ok(InitialResults { ok, rejected, order, picked_batches, picked })
    }

    /// Step 2: the inputs of the final segments (all selected, or a random
    /// batch of them) compensated at every picked θ_B,I. With extrinsics the
    /// QP tracks the axle poses the reference implies under the picked
    /// batches' mean extrinsics (the QP itself models the axle only); step
    /// 3 fits the original reference again.
    fn compensation_step(
        &self,
        drive: &Drive,
        selected: &[Segment],
        step1: &InitialResults,
        identify: &IdentifyOptions,
        seed: u64,
        progress: Option<ProgressFn<'_>>,
    ) -> Result<CompensatedInputs> {
        let final_segs: Vec<Segment> = match self.final_segments {
            FinalSegments::All => selected.to_vec(),
            FinalSegments::Random(n) => random_batches(selected.len(), n, 1, seed ^ FINAL_SEGMENTS_SEED_SALT)[0]
                .iter()
                .map(|&i| selected[i])
                .collect(),
        };
        let thetas: Vec<Theta> = step1.picked.iter().map(|p| p.theta).collect();
        let extrinsics = match identify.uses_extrinsics() {
            true => {
                let e: Vec<[f64; 3]> = step1
                    .picked_batches
                    .iter()
                    .map(|&i| step1.ok[i].extrinsics.unwrap_or(identify.extrinsics).to_array())
                    .collect();
                Extrinsics::from_array(std::array::from_fn(|j| {
                    e.iter().map(|a| a[j]).sum::<f64>() / e.len().max(1) as f64
                }))
            }
            false => Extrinsics::ZERO,
        };
        let opts = CompensateOptions { extrinsics, ..self.compensate.clone() };
        compensate_segments(drive, &final_segs, &thetas, &opts, &self.qp, progress)
    }

    /// The uncertainty of the result: the robust σ at θ with the measured
    /// inputs of the compensated segments (without extrinsics), and the
    /// spread of the plausible step-1 estimates.
    fn uncertainty(
        &self,
        drive: &Drive,
        selected: &[Segment],
        comp: &CompensatedInputs,
        report: &IdentifyReport,
        step1: &InitialResults,
        identify: &IdentifyOptions,
    ) -> Box<ThreeStepUncertainty> {
        let measured_inputs = match identify.uses_extrinsics() {
            true => None,
            false => {
                let raw: Vec<SegmentData> = comp.segments.iter().map(|s| SegmentData::new(drive, s)).collect();
                robust_covariance_at(&raw, &report.theta, identify)
            }
        };
        let plausible: Vec<Theta> = step1.order.iter().map(|&i| step1.ok[i].score.theta).collect();
        Box::new(ThreeStepUncertainty {
            measured_inputs,
            batch_spread: BatchSpread::new(
                &plausible,
                self.initial_batch_size.min(selected.len()),
                effective_segments(selected),
            ),
        })
    }
}

/// Step 1's batch results: the identified ones in order, each checked
/// against the plausibility guards (a failure is rejected, not dropped);
/// a warning per failed or rejected batch.
fn screen_batches(
    results: Vec<Result<BatchResult>>,
    theta0: &Theta,
    free: ParamSet,
    guards: &Guards,
    warnings: &mut Vec<Warning>,
) -> (Vec<BatchResult>, Vec<RejectedBatch>) {
    let mut ok = Vec::new();
    let mut rejected = Vec::new();
    for (i, r) in results.into_iter().enumerate() {
        match r {
            Ok(b) => {
                let violations = check_theta(&b.score.theta, theta0, free, Some(b.iterations), b.rcond, guards);
                if !violations.is_empty() {
                    warnings.push(Warning::BatchRejected { batch: i, violations: violations.clone() });
                    rejected.push(RejectedBatch { index: ok.len(), violations });
                }
                ok.push(b);
            }
            Err(e) => warnings.push(Warning::BatchFailed { batch: i, reason: e.to_string() }),
        }
    }
    (ok, rejected)
}

/// Indices into `ok` of the plausible results (only those are sorted and
/// picked), by increasing Ē_p; none plausible is an error.
fn plausible_by_error(ok: &[BatchResult], rejected: &[RejectedBatch]) -> Result<Vec<usize>> {
    let mut order: Vec<usize> = (0..ok.len()).filter(|i| !rejected.iter().any(|r| r.index == *i)).collect();
    if order.is_empty() {
        let first = rejected.first().map(|r| r.violations.iter().map(ToString::to_string).collect::<Vec<_>>());
        return Err(Error::Numerical(format!(
            "every one of the {} step-1 results failed the plausibility guards (the first: {}); the data do \
             not determine θ near θ_0 — check θ_0, hold parameters (--fix) or use a drive with more turns",
            ok.len(),
            first.map(|v| v.join("; ")).unwrap_or_default()
        )));
    }
    order.sort_by(|&a, &b| ok[a].score.mean_position_error_m.total_cmp(&ok[b].score.mean_position_error_m));
    Ok(order)
}

/// Test-only hook: replace step 1's first random batch by chosen segments
/// of the drive, selected or not (the forced-divergence test composes a
/// batch of straight segments).
#[cfg(test)]
pub(crate) mod forced {
    use std::cell::RefCell;

    use crate::drive::segment::{Segment, SegmentData};
    use crate::drive::Drive;

    thread_local! {
        static FIRST_BATCH: RefCell<Option<Vec<Segment>>> = const { RefCell::new(None) };
    }

    /// Step 1 of calibrations on this thread uses `batch` as its first
    /// batch; `None` restores random batches.
    pub(crate) fn set_first_batch(batch: Option<Vec<Segment>>) {
        FIRST_BATCH.with(|b| *b.borrow_mut() = batch);
    }

    pub(super) fn apply<'a>(drive: &'a Drive, data: &mut Vec<SegmentData<'a>>, batches: &mut [Vec<usize>]) {
        FIRST_BATCH.with(|b| {
            if let (Some(forced), Some(first)) = (b.borrow().as_ref(), batches.first_mut()) {
                let base = data.len();
                data.extend(forced.iter().map(|s| SegmentData::new(drive, s)));
                *first = (base..data.len()).collect();
            }
        });
    }
}

#[cfg(test)]
mod forced_divergence_tests {
    use super::*;
    use crate::assess::trust::GuardViolation;
    use crate::calibrate::{calibrate, CalibrationOptions, Method};
    use crate::drive::segment::select_segments;
    use crate::sim::{simulate, SimOptions};

    /// A step-1 batch of the ten straightest segments cannot determine c_d,
    /// t_r and d: the guards reject it, it is never picked, and the 3-step
    /// result stays as good as without it.
    #[test]
    fn a_batch_of_straight_segments_is_rejected_and_not_picked() {
        let sim = simulate(&SimOptions { length_km: 4.0, ..SimOptions::paper(7) }).expect("sim");
        let truth = sim.sidecar.theta_true;
        let opts = CalibrationOptions {
            method: Method::ThreeStep(ThreeStepOptions {
                initial_batches: 12,
                final_segments: FinalSegments::Random(12),
                ..Default::default()
            }),
            ..Default::default()
        };
        // The ten straightest segments of the drive (none of them selected).
        let mut all = select_segments(&sim.drive, &opts.segments).expect("segments").all;
        all.sort_by(|a, b| a.peak_yaw_rate_rad_per_s.total_cmp(&b.peak_yaw_rate_rad_per_s));
        let mut straight: Vec<Segment> = all[..10].to_vec();
        straight.sort_by_key(|s| s.start);
        let peak = straight.iter().map(|s| s.peak_yaw_rate_rad_per_s).fold(0.0, f64::max);
        // None of them turns enough to be selected by the default rule.
        let threshold = crate::drive::segment::SegmentOptions::default().min_peak_yaw_rate_rad_per_s;
        assert!(peak < threshold, "the batch is straight: peak yaw rate {peak} rad/s");

        let plain = calibrate(&sim.drive, &opts).expect("calibrate");
        forced::set_first_batch(Some(straight.clone()));
        let forced = calibrate(&sim.drive, &opts);
        forced::set_first_batch(None);
        let forced = forced.expect("calibrate with the forced batch");

        let init = forced.initial_step().expect("three-step");
        let starts: Vec<usize> = straight.iter().map(|s| s.start).collect();
        assert_eq!(init.batches[0].segment_starts, starts, "the first batch is the forced one");
        let rej = init.rejected.iter().find(|r| r.index == 0).expect("the straight batch is rejected");
        // It runs away in a yaw-only parameter (measured: t_r 68 m, d 49 mm/(m/s²))
        // or its normal equations are near-singular.
        assert!(
            rej.violations.iter().any(|v| matches!(
                v,
                GuardViolation::IllConditioned { .. }
                    | GuardViolation::OutOfRange {
                        param: crate::model::param::Param::TR | crate::model::param::Param::D,
                        ..
                    }
            )),
            "{:?} at {}",
            rej.violations,
            init.batches[0].score.theta
        );
        assert!(!init.picked_batches.contains(&0), "picked {:?}", init.picked_batches);
        // The result: as good as the run without the forced batch.
        let rel = |a: f64, b: f64| ((a - b) / b).abs();
        for r in [&plain, &forced] {
            assert!(rel(r.theta.c_e, truth.c_e) < 2e-3, "{}", r.theta);
            assert!(rel(r.theta.t_r, truth.t_r) < 0.03, "{}", r.theta);
            assert!(r.validation.mean_position_error_m < r.initial.mean_position_error_m);
        }
        assert!(
            forced.validation.mean_position_error_m < 1.1 * plain.validation.mean_position_error_m,
            "{} vs {}",
            forced.validation.mean_position_error_m,
            plain.validation.mean_position_error_m
        );
    }
}

#[cfg(test)]
#[allow(clippy::float_cmp)] // exact: sums of small integers and a binary fraction
mod uncertainty_tests {
    use super::*;

    #[test]
    fn batch_spread_is_the_scaled_sample_covariance() {
        let t = |c_e: f64, t_r: f64| Theta { c_e, c_d: 0.0, t_r, d: 0.0 };
        // c_e: 1, 2, 3 (mean 2, sample variance 1); t_r: 1, 1, 4 (variance 3)
        let thetas = [t(1.0, 1.0), t(2.0, 1.0), t(3.0, 4.0)];
        let b = BatchSpread::new(&thetas, 10, 50.0).expect("spread");
        let f = 10.0 / 40.0;
        assert!((b.covariance[0][0] - f).abs() < 1e-15, "{:?}", b.covariance);
        assert!((b.covariance[2][2] - 3.0 * f).abs() < 1e-15);
        assert!((b.covariance[0][2] - 1.5 * f).abs() < 1e-15, "cov(c_e, t_r) = 1.5");
        assert_eq!(b.covariance[1], [0.0; 4], "a parameter that never moves has no spread");
        assert!((b.std_dev().c_e - f.sqrt()).abs() < 1e-15);
        assert!(BatchSpread::new(&thetas[..2], 10, 50.0).is_none(), "two estimates are too few");
        assert!(BatchSpread::new(&thetas, 10, 10.0).is_none(), "no data beyond one batch");
    }

    #[test]
    fn effective_segments_count_distinct_samples() {
        let s = |start| Segment { start, steps: 100, peak_yaw_rate_rad_per_s: 1.0 };
        assert_eq!(effective_segments(&[]), 0.0);
        // 0..100 and 50..150 overlap: 150 samples; 1000..1100 adds 100
        assert_eq!(effective_segments(&[s(1000), s(50), s(0)]), 2.5);
        assert_eq!(effective_segments(&[s(0), s(0)]), 1.0);
    }
}
