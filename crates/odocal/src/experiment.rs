//! The paper's §6 on one drive: batch calibrations (Fig. 4), picked θ_B,I
//! (Fig. 5), compensated inputs (Fig. 6), per-segment and batch estimates
//! with raw vs compensated inputs (Fig. 7/8, Table 1), θ_nom and the
//! reachable minimum.
//!
//! Expert API: the `odocal experiment` command's computation, for programs
//! that reproduce or extend the paper's evaluation.
//!
//! [`run`] computes every number; the `odocal experiment` command renders
//! them as `report.md`, SVG figures and `experiment.json`.
//!
//! When the truth and the noise are known (a simulated drive,
//! [`ExperimentOptions::noise`]), every θ's error is also read against the
//! Cramér–Rao bound (`crate::eiv::cramer_rao_bound` at θ_true with the
//! true noise model): [`Experiment::cramer_rao`] holds σ_CRB and each
//! [`Scored::error_over_crb`] is (θ − θ_true)/σ_CRB.

use std::time::Instant;

use serde::Serialize;

use crate::assess::position_error::mean_position_error;
use crate::assess::reachable::{reachable_minimum, ReachableOptions};
use crate::assess::warning::Warning;
use crate::calibrate::{
    calibrate_detailed, per_segment_identification, score_batches, BatchResult, CalibrationOptions, CalibrationReport,
    InitialStep, Method, SegmentCounts, ThreeStepOptions,
};
use crate::compensate::{CompensatedInputs, CompensationStep};
use crate::drive::segment::{Segment, SegmentData};
use crate::drive::Drive;
use crate::eiv::{cramer_rao_bound, EivInput, EivOptions, NoiseModel};
use crate::error::{Error, Result};
use crate::identify::IdentifyOptions;
use crate::model::{step, Theta};
use crate::progress::{emit, Progress, ProgressFn};
use crate::sim::NoiseOptions;

/// Settings of an experiment.
#[derive(Debug, Clone, PartialEq)]
pub struct ExperimentOptions {
    /// The calibration; its method must be the 3-step method. Default the 3-step method with docs/method.md's defaults.
    pub calibration: CalibrationOptions,
    /// The reachable-minimum search (the estimates are added to its starts).
    /// Default the box around the paper's θ_0, seed 0.
    pub reachable: ReachableOptions,
    /// The simulator's noise settings of the drive (a simulated drive's
    /// sidecar, `settings.noise`): its true noise model, in the EIV
    /// filter's form at the drive's sample time. With θ_true it gives the
    /// Cramér–Rao bound column ([`Experiment::cramer_rao`]); `None` (a real
    /// drive) leaves the column out, saying why. Default `None`.
    pub noise: Option<NoiseOptions>,
}

impl Default for ExperimentOptions {
    fn default() -> Self {
        let calibration = CalibrationOptions::default();
        let reachable = ReachableOptions::around(&calibration.theta0);
        ExperimentOptions { calibration, reachable, noise: None }
    }
}

/// A θ with its validation error and, when the truth is known, its error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Scored {
    /// The parameters.
    pub theta: Theta,
    /// Ē_p, m.
    pub mean_position_error_m: f64,
    /// θ − θ_true, SI units (None without truth).
    pub error_vs_true: Option<Theta>,
    /// (θ − θ_true)/σ_CRB per parameter, dimensionless (None without the
    /// Cramér–Rao bound, [`Experiment::cramer_rao`]).
    pub error_over_crb: Option<Theta>,
}

/// The Cramér–Rao bound of θ on the experiment's drive: the smallest
/// standard deviation an unbiased estimator that knows the noise model can
/// have (`crate::eiv::cramer_rao_bound` at θ_true with the true noise
/// model, all four parameters free, default EIV windows).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CramerRao {
    /// σ_CRB per parameter, SI units (None when not available).
    pub sigma: Option<Theta>,
    /// σ from the mean-only information (no ∂S/∂θ term; ≥ `sigma`).
    pub sigma_mean_only: Option<Theta>,
    /// σ with the noise scales η unknown too (nuisance parameters; ≥
    /// `sigma`): the fair bound for EIV with η estimated
    /// (`crate::eiv::CrbReport::sigma_noise_estimated`).
    pub sigma_noise_estimated: Option<Theta>,
    /// The noise model of the bound.
    pub noise: Option<NoiseModel>,
    /// Why the bound is not available: no truth or no noise model (a given
    /// real drive), or the bound failed (e.g. a noise-free drive).
    pub unavailable: Option<String>,
}

impl CramerRao {
    fn unavailable(reason: impl Into<String>) -> Self {
        CramerRao {
            sigma: None,
            sigma_mean_only: None,
            sigma_noise_estimated: None,
            noise: None,
            unavailable: Some(reason.into()),
        }
    }

    /// (θ − θ_true)/σ_CRB, when the bound is available and positive for
    /// every parameter.
    pub(crate) fn ratio(&self, error: &Theta) -> Option<Theta> {
        let s = self.sigma?;
        let (e, s) = (error.to_array(), s.to_array());
        if !s.iter().all(|x| x.is_finite() && *x > 0.0) {
            return None;
        }
        Some(Theta { c_e: e[0] / s[0], c_d: e[1] / s[1], t_r: e[2] / s[2], d: e[3] / s[3] })
    }
}

/// The bound at θ_true with the true noise model, or why it is not available.
pub(crate) fn cramer_rao_column(drive: &Drive, theta_true: Option<&Theta>, noise: Option<&NoiseModel>) -> CramerRao {
    let (theta, noise) = match (theta_true, noise) {
        (Some(t), Some(n)) => (t, n),
        (None, _) => {
            return CramerRao::unavailable("the true θ is not known (a given drive without simulator sidecar)")
        }
        (Some(_), None) => return CramerRao::unavailable("the drive's noise model is not known"),
    };
    // Linearised along the true inputs, not the measured ones (whose noise
    // would count as excitation: `EivInput::from_drive_truth`).
    let Ok(input) = EivInput::from_drive_truth(drive) else {
        return CramerRao {
            noise: Some(*noise),
            ..CramerRao::unavailable("the drive has no truth columns (*_true) to evaluate the bound along")
        };
    };
    let of = Theta::from_array;
    match cramer_rao_bound(&input, theta, noise, &EivOptions::spec()) {
        Ok(c) if c.sigma.iter().all(|s| s.is_finite() && *s > 0.0) => CramerRao {
            sigma: Some(of(c.sigma)),
            sigma_mean_only: Some(of(c.sigma_mean_only)),
            sigma_noise_estimated: c.sigma_noise_estimated.map(of),
            noise: Some(*noise),
            unavailable: None,
        },
        Ok(c) => CramerRao {
            noise: Some(*noise),
            ..CramerRao::unavailable(format!("the bound is degenerate (σ_CRB = {:?})", c.sigma))
        },
        Err(e) => CramerRao { noise: Some(*noise), ..CramerRao::unavailable(format!("the bound failed: {e}")) },
    }
}

/// One step-1 batch, raw and compensated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct BatchRow {
    /// First samples of the batch's segments.
    pub segment_starts: Vec<usize>,
    /// G-N from θ_0 with the measured inputs (step 1's result).
    pub raw: Scored,
    /// G-N from θ_0 on the same segments with compensated inputs (segments
    /// whose compensation failed are left out).
    pub compensated: Option<Scored>,
    /// Segments of the batch with compensated inputs.
    pub compensated_segments: usize,
}

/// One selected segment, identified alone, raw and compensated.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SegmentRow {
    /// First sample.
    pub start: usize,
    /// Peak yaw rate, rad/s.
    pub peak_yaw_rate_rad_per_s: f64,
    /// Pure G-N with the measured inputs.
    pub raw: Option<Scored>,
    /// Pure G-N with the compensated inputs.
    pub compensated: Option<Scored>,
}

/// Table 1: one segment and one batch, raw vs compensated inputs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table1 {
    /// The compensated segment turning hardest.
    pub segment_start: usize,
    /// Its raw estimate.
    pub segment_raw: Scored,
    /// Its compensated estimate.
    pub segment_compensated: Scored,
    /// The middle picked step-1 batch (or the first with a compensated result).
    pub batch_index: usize,
    /// Its segments' first samples.
    pub batch_starts: Vec<usize>,
    /// Its raw estimate.
    pub batch_raw: Scored,
    /// Its compensated estimate.
    pub batch_compensated: Scored,
}

/// Fig. 6: the Table 1 segment, dead reckoning at θ_B,F; its numbers and
/// its curves, `(time from the segment start in s, value)` (the curves are
/// not serialised).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Figure6 {
    /// First sample of the segment.
    pub segment_start: usize,
    /// θ of the dead reckoning (θ_B,F).
    pub theta: Theta,
    /// RMS of measured − true wheel rotations, rev/s (simulated drives).
    pub rms_measured_input_error_rev_per_s: Option<f64>,
    /// RMS of compensated − true wheel rotations, rev/s.
    pub rms_compensated_input_error_rev_per_s: Option<f64>,
    /// Mean position error of dead reckoning with measured inputs, m.
    pub mean_position_error_measured_m: f64,
    /// Mean position error of dead reckoning with compensated inputs, m.
    pub mean_position_error_compensated_m: f64,
    /// Measured n_rl, rev/s.
    #[serde(skip)]
    pub n_rl_measured: Vec<(f64, f64)>,
    /// Compensated n_rl, rev/s.
    #[serde(skip)]
    pub n_rl_compensated: Vec<(f64, f64)>,
    /// True n_rl (simulated drives), rev/s.
    #[serde(skip)]
    pub n_rl_true: Option<Vec<(f64, f64)>>,
    /// Measured n_rr, rev/s.
    #[serde(skip)]
    pub n_rr_measured: Vec<(f64, f64)>,
    /// Compensated n_rr, rev/s.
    #[serde(skip)]
    pub n_rr_compensated: Vec<(f64, f64)>,
    /// True n_rr, rev/s.
    #[serde(skip)]
    pub n_rr_true: Option<Vec<(f64, f64)>>,
    /// Dead-reckoning position error with the measured inputs, m.
    #[serde(skip)]
    pub pos_err_measured: Vec<(f64, f64)>,
    /// Dead-reckoning position error with the compensated inputs, m.
    #[serde(skip)]
    pub pos_err_compensated: Vec<(f64, f64)>,
}

/// Wall time of the experiment's stages, s.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ExperimentTiming {
    /// The 3-step calibration.
    pub calibrate: f64,
    /// Per-segment G-N, raw and compensated.
    pub per_segment: f64,
    /// The step-1 batches again with compensated inputs.
    pub compensated_batches: f64,
    /// The reachable-minimum search.
    pub reachable_minimum: f64,
    /// The Cramér–Rao bound (one filter pass with derivatives at θ_true).
    pub cramer_rao_bound: f64,
}

/// The reachable minimum and how it was found.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ReachableSummary {
    /// The minimum.
    #[serde(flatten)]
    pub scored: Scored,
    /// Ē_p evaluations.
    pub evaluations: usize,
    /// Search time, s.
    pub time_s: f64,
    /// Why the search stopped.
    pub termination: String,
}

/// Every number of the experiment.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Experiment {
    /// Segment counts.
    pub segments: SegmentCounts,
    /// The QP solver used.
    pub qp_solver: String,
    /// θ_true, when known.
    pub truth: Option<Scored>,
    /// The Cramér–Rao bound of θ, or why it is not available.
    pub cramer_rao: CramerRao,
    /// The paper's θ_nom.
    pub nominal: Scored,
    /// θ_0.
    pub initial_guess: Scored,
    /// Step 1 batch size N.
    pub batch_size: usize,
    /// Every step-1 batch, raw and compensated.
    pub batches: Vec<BatchRow>,
    /// Indices into `batches` of the picked θ_B,I.
    pub picked_batches: Vec<usize>,
    /// The picked θ_B,I.
    pub picked: Vec<Scored>,
    /// θ_B,F.
    pub final_estimate: Scored,
    /// One line on the final identification.
    pub final_identification: String,
    /// The reachable minimum.
    pub reachable_minimum: ReachableSummary,
    /// Table 1.
    pub table1: Table1,
    /// Every selected segment alone, raw and compensated.
    pub per_segment: Vec<SegmentRow>,
    /// Step 2.
    pub compensation: CompensationStep,
    /// Fig. 6.
    pub figure6: Figure6,
    /// The calibration's warnings.
    pub warnings: Vec<Warning>,
    /// Wall time per stage.
    pub timing_s: ExperimentTiming,
}

fn diff(a: &Theta, b: &Theta) -> Theta {
    Theta { c_e: a.c_e - b.c_e, c_d: a.c_d - b.c_d, t_r: a.t_r - b.t_r, d: a.d - b.d }
}

/// Runs the experiment on `drive` (θ_true when known).
///
/// # Errors
/// Those of the calibration; [`Error::InvalidOption`] when the method is not
/// the 3-step method; [`Error::NoSegments`] when no compensated segment or
/// batch can be identified (Table 1 needs one of each).
pub fn run(
    drive: &Drive,
    theta_true: Option<&Theta>,
    opts: &ExperimentOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<Experiment> {
    let mut timing = ExperimentTiming::default();
    let copts = &opts.calibration;
    let three = three_step_options(copts)?;

    // The Cramér–Rao bound at θ_true with the true noise model.
    let t = Instant::now();
    let noise = opts.noise.as_ref().map(|n| NoiseModel::from_sim(n, drive.sample_time_s()));
    let crb = cramer_rao_column(drive, theta_true, noise.as_ref());
    timing.cramer_rao_bound = t.elapsed().as_secs_f64();

    // The 3-step calibration (steps 1–3), keeping the compensated inputs.
    let t = Instant::now();
    let det = calibrate_detailed(drive, None, copts, progress)?;
    timing.calibrate = t.elapsed().as_secs_f64();
    let r = &det.report;
    let (init, comp) = match (r.initial_step(), &det.compensated) {
        (Some(i), Some(c)) => (i, c),
        _ => return Err(Error::Numerical("the 3-step calibration returned no step 1/2 results".into())),
    };
    let ctx = Scorer {
        drive,
        theta_true,
        crb,
        validation: &det.validation,
        theta0: &copts.theta0,
        identify: &r.options.identify,
    };

    // Per-segment G-N, raw and compensated.
    let t = Instant::now();
    emit(progress, Progress::Stage { name: "per-segment G-N", total: 1 });
    let segs = ctx.per_segment(&det.selected, comp);
    emit(progress, Progress::Advance(1));
    timing.per_segment = t.elapsed().as_secs_f64();

    // The step-1 batches again, with compensated inputs.
    let t = Instant::now();
    let batches = ctx.compensated_batches(init, comp, &segs.comp_data);
    timing.compensated_batches = t.elapsed().as_secs_f64();

    // Reference points: truth, θ_nom, θ_0, θ_B,F and the reachable minimum.
    let truth = theta_true.map(|t| ctx.score(t)).transpose()?;
    let nominal = ctx.score(&Theta::PAPER_NOMINAL)?;
    let initial_guess = ctx.score(&copts.theta0)?;
    let final_estimate = ctx.score(&r.theta)?;
    let picked: Vec<Scored> = init.picked_batches.iter().map(|&i| ctx.of(&init.batches[i])).collect();
    let t = Instant::now();
    emit(progress, Progress::Stage { name: "reachable minimum", total: 1 });
    let reach = ctx.reachable(&opts.reachable, &picked, &r.theta)?;
    emit(progress, Progress::Advance(1));
    timing.reachable_minimum = t.elapsed().as_secs_f64();

    // Table 1: the compensated segment turning hardest, and the middle picked batch.
    let pick = table1_pick(&det.selected, comp, init, &segs, &batches)?;
    let table1 = table1(&pick, comp, &segs, &batches, &ctx)?;
    // Figure 6: the Table 1 segment, dead reckoning at θ_B,F.
    let figure6 = figure6_data(drive, &segs.comp_data[pick.segment], &segs.raw_data[pick.raw_segment], &r.theta);

    Ok(Experiment {
        segments: r.segments,
        qp_solver: three.qp.solver.to_string(),
        truth,
        cramer_rao: ctx.crb,
        nominal,
        initial_guess,
        batch_size: three.initial_batch_size,
        batches,
        picked_batches: init.picked_batches.clone(),
        picked,
        final_estimate,
        final_identification: identification_line(r),
        reachable_minimum: reach,
        table1,
        per_segment: segs.rows,
        compensation: comp.step.clone(),
        figure6,
        warnings: r.warnings.clone(),
        timing_s: timing,
    })
}

/// The method options of the experiment's calibration, which must be the
/// 3-step method (the experiment compares its steps).
fn three_step_options(copts: &CalibrationOptions) -> Result<&ThreeStepOptions> {
    match &copts.method {
        Method::ThreeStep(o) => Ok(o),
        other => Err(Error::InvalidOption {
            field: "method",
            reason: format!("the experiment runs the three-step method, not {other}"),
        }),
    }
}

/// Scores θ on the calibration's validation segments and reads it against
/// the truth and its Cramér–Rao bound; also runs the experiment's extra
/// identifications with the calibration's θ_0 and settings.
struct Scorer<'a> {
    /// The drive.
    drive: &'a Drive,
    /// θ_true, when known.
    theta_true: Option<&'a Theta>,
    /// The bound at θ_true.
    crb: CramerRao,
    /// The calibration's validation segments.
    validation: &'a [Segment],
    /// Start of every identification.
    theta0: &'a Theta,
    /// Identification settings of the calibration.
    identify: &'a IdentifyOptions,
}

/// The selected segments identified alone, with measured and compensated
/// inputs.
struct PerSegment<'a> {
    /// Each selected segment with its measured inputs.
    raw_data: Vec<SegmentData<'a>>,
    /// Each compensated segment (those whose compensation succeeded).
    comp_data: Vec<SegmentData<'a>>,
    /// G-N on each of `raw_data` alone.
    raw: Vec<Result<BatchResult>>,
    /// G-N on each of `comp_data` alone.
    comp: Vec<Result<BatchResult>>,
    /// One row per selected segment.
    rows: Vec<SegmentRow>,
}

impl<'a> Scorer<'a> {
    /// θ with its validation error `e_p`, and its error against the truth
    /// in SI units and in units of σ_CRB.
    fn scored(&self, theta: &Theta, e_p: f64) -> Scored {
        let error_vs_true = self.theta_true.map(|t| diff(theta, t));
        Scored {
            theta: *theta,
            mean_position_error_m: e_p,
            error_vs_true,
            error_over_crb: error_vs_true.and_then(|e| self.crb.ratio(&e)),
        }
    }

    /// θ scored by its Ē_p on the validation segments.
    fn score(&self, theta: &Theta) -> Result<Scored> {
        let v = mean_position_error(self.drive, self.validation, theta)?;
        Ok(self.scored(theta, v.mean_position_error_m))
    }

    /// A batch's estimate with the Ē_p it was scored with.
    fn of(&self, b: &BatchResult) -> Scored {
        self.scored(&b.score.theta, b.score.mean_position_error_m)
    }

    /// Pure G-N on every selected segment alone, once with the measured
    /// and once with the compensated inputs; a row per selected segment
    /// pairs the two (no compensated estimate when its compensation failed).
    fn per_segment(&self, selected: &[Segment], comp: &'a CompensatedInputs) -> PerSegment<'a> {
        let raw_data: Vec<SegmentData> = selected.iter().map(|s| SegmentData::new(self.drive, s)).collect();
        let comp_data = comp.segment_data(self.drive);
        let raw = per_segment_identification(self.drive, &raw_data, self.validation, self.theta0, self.identify);
        let comp_seg = per_segment_identification(self.drive, &comp_data, self.validation, self.theta0, self.identify);
        let rows: Vec<SegmentRow> = selected
            .iter()
            .zip(&raw)
            .map(|(s, rr)| SegmentRow {
                start: s.start,
                peak_yaw_rate_rad_per_s: s.peak_yaw_rate_rad_per_s,
                raw: rr.as_ref().ok().map(|b| self.of(b)),
                compensated: compensated_index(comp, s.start)
                    .and_then(|i| comp_seg[i].as_ref().ok().map(|b| self.of(b))),
            })
            .collect();
        PerSegment { raw_data, comp_data, raw, comp: comp_seg, rows }
    }

    /// The step-1 batches again from θ_0 on the same segments with
    /// compensated inputs (segments whose compensation failed left out),
    /// each beside its raw result.
    fn compensated_batches(
        &self,
        init: &InitialStep,
        comp: &CompensatedInputs,
        comp_data: &[SegmentData<'_>],
    ) -> Vec<BatchRow> {
        let comp_batches: Vec<Vec<usize>> = init
            .batches
            .iter()
            .map(|b| b.segment_starts.iter().filter_map(|&s| compensated_index(comp, s)).collect())
            .collect();
        let comp_results =
            score_batches(self.drive, comp_data, &comp_batches, self.validation, self.theta0, self.identify, None);
        init.batches
            .iter()
            .zip(&comp_results)
            .zip(&comp_batches)
            .map(|((b, c), cb)| BatchRow {
                segment_starts: b.segment_starts.clone(),
                raw: self.of(b),
                compensated: if cb.is_empty() { None } else { c.as_ref().ok().map(|b| self.of(b)) },
                compensated_segments: cb.len(),
            })
            .collect()
    }

    /// The reachable minimum: the search of `base` with the picked θ_B,I
    /// and θ_B,F added to its starts.
    fn reachable(&self, base: &ReachableOptions, picked: &[Scored], final_theta: &Theta) -> Result<ReachableSummary> {
        let mut ro = base.clone();
        ro.starts.extend(picked.iter().map(|p| p.theta));
        ro.starts.push(*final_theta);
        let rm = reachable_minimum(self.drive, self.validation, &ro, None)?;
        Ok(ReachableSummary {
            scored: self.scored(&rm.theta, rm.mean_position_error_m),
            evaluations: rm.evaluations,
            time_s: rm.time_s,
            termination: rm.termination.clone(),
        })
    }
}

/// Index among the compensated segments of the one starting at `start`.
fn compensated_index(comp: &CompensatedInputs, start: usize) -> Option<usize> {
    comp.segments.iter().position(|s| s.start == start)
}

/// Table 1's rows, as indices.
struct Table1Pick {
    /// The compensated segment turning hardest among those identified
    /// (index into the compensated segments).
    segment: usize,
    /// The same segment among the selected ones.
    raw_segment: usize,
    /// The middle picked step-1 batch, or the first with a compensated
    /// result when it has none.
    batch: usize,
}

/// Picks Table 1's segment and batch.
fn table1_pick(
    selected: &[Segment],
    comp: &CompensatedInputs,
    init: &InitialStep,
    segs: &PerSegment<'_>,
    batches: &[BatchRow],
) -> Result<Table1Pick> {
    let segment = (0..comp.segments.len())
        .filter(|&i| segs.comp[i].is_ok())
        .max_by(|&x, &y| comp.segments[x].peak_yaw_rate_rad_per_s.total_cmp(&comp.segments[y].peak_yaw_rate_rad_per_s))
        .ok_or_else(|| Error::NoSegments("no compensated segment could be identified on its own".into()))?;
    let start = comp.segments[segment].start;
    let raw_segment = selected
        .iter()
        .position(|s| s.start == start)
        .ok_or_else(|| Error::NoSegments(format!("the segment at sample {start} is not among the selected")))?;
    let batch = init
        .picked_batches
        .get(init.picked_batches.len() / 2)
        .copied()
        .filter(|&i| batches[i].compensated.is_some())
        .or_else(|| batches.iter().position(|b| b.compensated.is_some()))
        .ok_or_else(|| Error::NoSegments("no batch could be identified with compensated inputs".into()))?;
    Ok(Table1Pick { segment, raw_segment, batch })
}

/// Table 1 from its picked segment and batch.
fn table1(
    pick: &Table1Pick,
    comp: &CompensatedInputs,
    segs: &PerSegment<'_>,
    batches: &[BatchRow],
    ctx: &Scorer<'_>,
) -> Result<Table1> {
    let no_batch = || Error::NoSegments("batch without compensated result".into());
    let of = |b: &BatchResult| ctx.of(b);
    let batch = &batches[pick.batch];
    Ok(Table1 {
        segment_start: comp.segments[pick.segment].start,
        segment_raw: segs.raw[pick.raw_segment].as_ref().map(of).map_err(|e| Error::Numerical(e.to_string()))?,
        segment_compensated: segs.comp[pick.segment].as_ref().map(of).map_err(|e| Error::Numerical(e.to_string()))?,
        batch_index: pick.batch,
        batch_starts: batch.segment_starts.clone(),
        batch_raw: batch.raw,
        batch_compensated: batch.compensated.ok_or_else(no_batch)?,
    })
}

/// One line on the final identification (empty when the method has none).
fn identification_line(r: &CalibrationReport) -> String {
    r.identification()
        .map(|id| {
            format!(
                "{} segments, {} iterations, {}, rcond {:.2e}",
                id.segments, id.iterations, id.termination, id.observability.rcond
            )
        })
        .unwrap_or_default()
}

/// Position error along a segment of dead reckoning at θ with the segment's inputs.
fn position_errors(seg: &SegmentData<'_>, theta: &Theta) -> Vec<(f64, f64)> {
    let mut x = seg.reference(0);
    (0..seg.steps())
        .map(|k| {
            x = step(&x, &seg.input(k), theta, seg.sample_time_s);
            ((k + 1) as f64 * seg.sample_time_s, (seg.px[k + 1] - x[0]).hypot(seg.py[k + 1] - x[1]))
        })
        .collect()
}

fn figure6_data(drive: &Drive, comp: &SegmentData<'_>, raw: &SegmentData<'_>, theta: &Theta) -> Figure6 {
    let ts = drive.sample_time_s();
    let series = |v: &[f64]| -> Vec<(f64, f64)> { v.iter().enumerate().map(|(k, &n)| (k as f64 * ts, n)).collect() };
    let (a, k) = (raw.start, raw.steps());
    let truth = drive.truth().filter(|t| t.n_rl.len() >= a + k);
    let rms = |x: &[f64], y: &[f64], tx: &[f64], ty: &[f64]| {
        let s: f64 = (0..x.len()).map(|i| (x[i] - tx[i]).powi(2) + (y[i] - ty[i]).powi(2)).sum();
        (s / (2 * x.len()) as f64).sqrt()
    };
    let (tl, tr) = match truth {
        Some(t) => (Some(&t.n_rl[a..a + k]), Some(&t.n_rr[a..a + k])),
        None => (None, None),
    };
    let pm = position_errors(raw, theta);
    let pc = position_errors(comp, theta);
    let mean = |v: &[(f64, f64)]| v.iter().map(|p| p.1).sum::<f64>() / v.len().max(1) as f64;
    Figure6 {
        segment_start: a,
        theta: *theta,
        rms_measured_input_error_rev_per_s: tl.zip(tr).map(|(l, r)| rms(raw.n_rl, raw.n_rr, l, r)),
        rms_compensated_input_error_rev_per_s: tl.zip(tr).map(|(l, r)| rms(comp.n_rl, comp.n_rr, l, r)),
        mean_position_error_measured_m: mean(&pm),
        mean_position_error_compensated_m: mean(&pc),
        n_rl_measured: series(raw.n_rl),
        n_rl_compensated: series(comp.n_rl),
        n_rl_true: tl.map(series),
        n_rr_measured: series(raw.n_rr),
        n_rr_compensated: series(comp.n_rr),
        n_rr_true: tr.map(series),
        pos_err_measured: pm,
        pos_err_compensated: pc,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, SimOptions};

    #[test]
    fn experiment_on_a_short_drive_is_consistent() {
        let sim = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(3) }).expect("sim");
        let method = Method::ThreeStep(ThreeStepOptions { initial_batches: 4, ..Default::default() });
        let calibration = CalibrationOptions { method, seed: 3, ..Default::default() };
        let reachable = ReachableOptions { particles: 10, iterations: 5, refine_iterations: 20, ..Default::default() };
        let opts = ExperimentOptions { calibration, reachable, noise: Some(sim.sidecar.settings.noise.clone()) };
        let e = run(&sim.drive, Some(&sim.sidecar.theta_true), &opts, None).expect("experiment");
        let sigma = e.cramer_rao.sigma.expect("the bound of a simulated drive");
        assert!(e.cramer_rao.unavailable.is_none());
        for (s, m) in sigma.to_array().iter().zip(e.cramer_rao.sigma_mean_only.expect("mean-only").to_array()) {
            assert!(*s > 0.0 && *s <= m * (1.0 + 1e-9), "σ_CRB {sigma:?}");
        }
        let f = &e.final_estimate;
        let (err, ratio) = (f.error_vs_true.expect("truth").to_array(), f.error_over_crb.expect("ratio").to_array());
        for i in 0..4 {
            assert!((ratio[i] * sigma.to_array()[i] - err[i]).abs() <= 1e-12 * err[i].abs().max(1e-12), "{i}");
        }
        assert_eq!(e.truth.and_then(|t| t.error_over_crb), Some(Theta { c_e: 0.0, c_d: 0.0, t_r: 0.0, d: 0.0 }));
        assert_eq!(e.batches.len(), 4);
        assert_eq!(e.picked.len(), 5);
        let e_min = e.reachable_minimum.scored.mean_position_error_m;
        assert!(e.final_estimate.mean_position_error_m >= e_min - 1e-9, "the minimum is seeded with θ_B,F");
        assert!(e.per_segment.iter().any(|s| s.compensated.is_some()));
        assert_eq!(e.figure6.segment_start, e.table1.segment_start);
        assert_eq!(e.figure6.pos_err_measured.len(), e.figure6.n_rl_measured.len());
        let err = e.final_estimate.error_vs_true.expect("truth known");
        assert!(err.c_e.abs() < 0.05, "{err:?}");
        let batch_gn = ExperimentOptions {
            calibration: CalibrationOptions { method: Method::BatchGn, ..Default::default() },
            ..ExperimentOptions::default()
        };
        let e = run(&sim.drive, None, &batch_gn, None).expect_err("three-step only");
        assert!(e.to_string().contains("three-step"), "{e}");
    }

    #[test]
    fn the_bound_says_why_it_is_not_available() {
        let sim = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) }).expect("sim");
        let truth = sim.sidecar.theta_true;
        let noise = NoiseModel::from_sim(&sim.sidecar.settings.noise, sim.drive.sample_time_s());
        let no_truth = cramer_rao_column(&sim.drive, None, Some(&noise));
        assert!(no_truth.sigma.is_none() && no_truth.unavailable.as_deref().is_some_and(|r| r.contains("true θ")));
        let no_noise = cramer_rao_column(&sim.drive, Some(&truth), None);
        assert!(no_noise.sigma.is_none() && no_noise.unavailable.as_deref().is_some_and(|r| r.contains("noise")));
        assert_eq!(no_noise.ratio(&truth), None);
        let bare = crate::drive::DriveBuilder {
            t: sim.drive.t().to_vec(),
            measured: sim.drive.measured().clone(),
            sample_time_s: Some(sim.drive.sample_time_s()),
            context: "no truth".into(),
            ..Default::default()
        }
        .build()
        .expect("drive");
        let no_columns = cramer_rao_column(&bare, Some(&truth), Some(&noise));
        assert!(
            no_columns.sigma.is_none()
                && no_columns.unavailable.as_deref().is_some_and(|r| r.contains("truth columns")),
            "{no_columns:?}"
        );
        let bad = NoiseModel { wheel_common_time_constant_s: 0.0, ..noise };
        let failed = cramer_rao_column(&sim.drive, Some(&truth), Some(&bad));
        assert!(
            failed.unavailable.as_deref().is_some_and(|r| r.contains("wheel_common_time_constant_s")),
            "{failed:?}"
        );
    }
}
