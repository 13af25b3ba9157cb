//! Input compensation by optimal control (docs/method.md §5, paper §4.1).
//!
//! Expert API: for programs that compensate segments themselves (the
//! `odocal compensate` command) or compare the QP solvers
//! ([`SolverKind`]).
//!
//! For one segment and one fixed θ, estimate noise-free wheel rotations
//! `n̂_rl, n̂_rr`. The model is linearized around the trajectory `x̄` run with
//! the current input estimate `n̄` (first the measured `ñ`):
//!
//! ```text
//! x_k = Â_k x_{k−1} + B̂_k n_{k−1} + ĝ_k,   Â_k = ∂f/∂x,  B̂_k = ∂f/∂[n_rl, n_rr]
//! ```
//!
//! β and a_y stay measured. The QP
//!
//! ```text
//! min Σ_k ‖ỹ_k − x_k‖²_Q + Σ_k ‖n_k − n_{k−1}‖²_R
//! s.t. linearized dynamics, x_0 = ỹ_0,
//!      ỹ_k − [5, 5, 0.5] ≤ x_k ≤ ỹ_k + [5, 5, 0.5],   n_k within ±5 % of ñ_k
//! ```
//!
//! with `Q = diag(1, 1, 10)`, `R = diag(1000, 1000)` is posed in deviation
//! variables `z = x − ỹ`, `w = n − ñ` (`qp::StageQp`) and solved; the
//! model is re-linearized around the solution until the inputs change by
//! less than a tolerance (at most 5 linearizations).
//!
//! [`compensate_segments`] runs step 2 of the 3-step method: every segment
//! compensated once per θ_B,I (in parallel), the results averaged.
//!
//! ## References
//! G. Fazekas, P. Gáspár, B. Németh, "Wheel Odometry Model Calibration with
//! Input Compensation by Optimal Control", IFAC-PapersOnLine, 2022, §4.1.

use nalgebra::{Vector2, Vector3};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::drive::segment::{Segment, SegmentData};
use crate::drive::{axle_reference_drive, Drive};
use crate::error::{Error, Result};
use crate::model::extrinsics::Extrinsics;
use crate::model::{step_jacobians, Input, Theta};
use crate::progress::{Progress, ProgressFn};
use qp::clarabel::ClarabelSolver;
use qp::riccati::StructuredSolver;
use qp::{QpError, QpSolution, QpSolver, StageQp};

mod qp;

pub use qp::SolverKind;
pub(crate) use qp::{clarabel::ClarabelOptions, riccati::StructuredOptions};

/// Which QP solver compensation uses, and the settings of each (the
/// solvers' tolerances and iteration limits are the library's; in JSON
/// `structured` and `clarabel`). `QpOptions::from(SolverKind::Clarabel)`
/// picks a solver.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct QpOptions {
    /// The solver. Default structured (Riccati interior point).
    pub solver: SolverKind,
    /// Settings of the structured solver.
    #[serde(default)]
    pub(crate) structured: StructuredOptions,
    /// Settings of Clarabel (the solver itself, or the structured solver's
    /// fallback).
    #[serde(default)]
    pub(crate) clarabel: ClarabelOptions,
}

/// The solver `solver` with the library's settings.
impl From<SolverKind> for QpOptions {
    fn from(solver: SolverKind) -> Self {
        QpOptions { solver, ..QpOptions::default() }
    }
}

impl QpOptions {
    /// Checks both solvers' settings.
    pub(crate) fn validate(&self) -> Result<()> {
        self.structured.validate()?;
        self.clarabel.validate()?;
        Ok(())
    }

    /// The configured solver.
    pub(crate) fn primary(&self) -> Box<dyn QpSolver> {
        match self.solver {
            SolverKind::Structured => Box::new(StructuredSolver { options: self.structured.clone() }),
            SolverKind::Clarabel => Box::new(ClarabelSolver { settings: self.clarabel.clone() }),
        }
    }

    /// The fallback for QPs the primary solver does not finish: Clarabel
    /// behind the structured solver, none behind Clarabel.
    pub(crate) fn fallback(&self) -> Option<Box<dyn QpSolver>> {
        match self.solver {
            SolverKind::Structured => Some(Box::new(ClarabelSolver { settings: self.clarabel.clone() })),
            SolverKind::Clarabel => None,
        }
    }
}

/// Options of the input-compensation QP.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompensateOptions {
    /// Half-width of the pose box around the reference `[p_x m, p_y m, ψ rad]`.
    /// Default `[5, 5, 0.5]`.
    pub pose_box: [f64; 3],
    /// Relative half-width of the wheel-rotation box around the measurement.
    /// Default 0.05 (±5 %).
    pub input_box_rel: f64,
    /// Diagonal of the pose weight Q. Default `[1, 1, 10]`.
    pub q: [f64; 3],
    /// Diagonal of the input-rate weight R. Default `[1000, 1000]`.
    pub r: [f64; 2],
    /// Maximum number of linearizations (QP solves). Default 5.
    pub max_linearizations: usize,
    /// Stop re-linearizing when the inputs change by less than this
    /// (max absolute change, rev/s). Default 0.01. The inputs after a solve
    /// are within about ρ × its change of where the re-linearization
    /// converges, ρ the contraction per re-linearization (on the paper
    /// drives median 0.002, at most 0.4). Against re-linearizing to 1e-9
    /// rev/s, 0.01 moves the 3-step θ by at most 2e-4 of its within-drive
    /// σ on 20 random noise worlds (12 km each), where 0.05 moved c_e by up
    /// to 0.023σ; it takes 2.8 QP solves per job on the 24 km paper drive,
    /// 3.3 at 1e-4.
    pub input_tolerance_rev_per_s: f64,
    /// The pose reference's mount (lever arm, heading offset). The QP
    /// models the rear-axle centre, so with a mount it tracks the axle
    /// poses the reference implies under it ([`crate::Extrinsics`]); the
    /// wheels are the same. The 3-step method sets it to its step-1
    /// batches' mean extrinsics. Default 0: the reference at the axle.
    #[serde(default, skip_serializing_if = "Extrinsics::is_zero")]
    pub extrinsics: Extrinsics,
}

impl Default for CompensateOptions {
    fn default() -> Self {
        CompensateOptions {
            pose_box: [5.0, 5.0, 0.5],
            input_box_rel: 0.05,
            q: [1.0, 1.0, 10.0],
            r: [1000.0, 1000.0],
            max_linearizations: 5,
            input_tolerance_rev_per_s: 0.01,
            extrinsics: Extrinsics::ZERO,
        }
    }
}

impl CompensateOptions {
    /// Checks the options, naming the offending field.
    pub(crate) fn validate(&self) -> Result<()> {
        if self.pose_box.iter().any(|b| !(b.is_finite() && *b > 0.0)) {
            return Err(Error::InvalidOption { field: "pose_box", reason: "must be positive".into() });
        }
        if !(self.input_box_rel.is_finite() && self.input_box_rel >= 0.0) {
            return Err(Error::InvalidOption { field: "input_box_rel", reason: "must be non-negative".into() });
        }
        if self.q.iter().chain(self.r.iter()).any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::InvalidOption {
                field: "q/r",
                reason: "weights must be finite and non-negative".into(),
            });
        }
        if self.max_linearizations == 0 {
            return Err(Error::InvalidOption { field: "max_linearizations", reason: "must be at least 1".into() });
        }
        self.extrinsics.validate()
    }
}

/// The compensated inputs of one segment and how they were obtained.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct Compensation {
    /// First sample of the segment in the drive.
    pub start: usize,
    /// Compensated rear-left wheel rotation, rev/s (K values).
    pub n_rl: Vec<f64>,
    /// Compensated rear-right wheel rotation, rev/s (K values).
    pub n_rr: Vec<f64>,
    /// QP solves (linearizations) done.
    pub linearizations: usize,
    /// Total QP solver iterations.
    pub qp_iterations: usize,
    /// Objective of the last QP.
    pub objective: f64,
    /// Max absolute input change (rev/s) made by each solve relative to the
    /// previous linearization point.
    pub input_change: Vec<f64>,
    /// True when the inputs settled within the tolerance.
    pub converged: bool,
    /// Every QP that the primary solver did not solve
    /// (`QpError::MaxIterations` or `QpError::Numerical`) and the
    /// fallback solver did.
    #[serde(default)]
    pub fallbacks: Vec<QpFallback>,
}

/// A QP solved by the fallback solver after the primary one stopped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct QpFallback {
    /// The linearization (1-based).
    pub linearization: usize,
    /// The primary solver.
    pub solver: String,
    /// The fallback solver.
    pub fallback: String,
    /// Why the primary solver stopped.
    pub reason: QpError,
}

impl std::fmt::Display for QpFallback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "linearization {}: {} → {}: {}", self.linearization, self.solver, self.fallback, self.reason)
    }
}

/// Builds the deviation-variable QP of a segment linearized around the inputs
/// `(n_rl_lin, n_rr_lin)` (K values each).
pub(crate) fn build_qp(
    seg: &SegmentData<'_>,
    theta: &Theta,
    n_rl_lin: &[f64],
    n_rr_lin: &[f64],
    opts: &CompensateOptions,
) -> StageQp {
    let k_steps = seg.steps();
    let ts = seg.sample_time_s;
    let mut qp = StageQp {
        a: Vec::with_capacity(k_steps),
        b: Vec::with_capacity(k_steps),
        c: Vec::with_capacity(k_steps),
        q: Vector3::from(opts.q),
        r: Vector2::from(opts.r),
        delta: Vec::with_capacity(k_steps.saturating_sub(1)),
        z_lo: vec![-Vector3::from(opts.pose_box); k_steps],
        z_hi: vec![Vector3::from(opts.pose_box); k_steps],
        w_lo: Vec::with_capacity(k_steps),
        w_hi: Vec::with_capacity(k_steps),
    };
    let mut x_lin = seg.reference(0);
    for k in 0..k_steps {
        let u_lin = Input { n_rl: n_rl_lin[k], n_rr: n_rr_lin[k], beta: seg.beta[k], a_y: seg.a_y[k] };
        let j = step_jacobians(&x_lin, &u_lin, theta, ts);
        let n_meas = Vector2::new(seg.n_rl[k], seg.n_rr[k]);
        let n_lin = Vector2::new(n_rl_lin[k], n_rr_lin[k]);
        // z_k = A z_{k−1} + B w_{k−1} + c_k with
        // c_k = f(x̄, ū) + A (ỹ_{k−1} − x̄_{k−1}) + B (ñ_{k−1} − n̄_{k−1}) − ỹ_k.
        let c = j.next + j.f_x * (seg.reference(k) - x_lin) + j.f_n * (n_meas - n_lin) - seg.reference(k + 1);
        // The model's pose Jacobian is the identity but for its heading column.
        debug_assert!(qp::heading_column(&j.f_x).is_some(), "step Jacobian {}", j.f_x);
        qp.a.push(Vector2::new(j.f_x[(0, 2)], j.f_x[(1, 2)]));
        qp.b.push(j.f_n);
        qp.c.push(c);
        let half = n_meas.abs() * opts.input_box_rel;
        qp.w_lo.push(-half);
        qp.w_hi.push(half);
        if k > 0 {
            qp.delta.push(n_meas - Vector2::new(seg.n_rl[k - 1], seg.n_rr[k - 1]));
        }
        x_lin = j.next;
    }
    qp
}

/// Compensates one segment at θ (docs/method.md §5): solves, re-linearizes around the
/// solution and solves again until the inputs settle (at most
/// `max_linearizations` solves). A QP failure is returned as an error for
/// this segment; callers leave the segment out with a warning.
#[cfg(test)]
pub(crate) fn compensate_segment(
    seg: &SegmentData<'_>,
    theta: &Theta,
    solver: &dyn QpSolver,
    opts: &CompensateOptions,
) -> Result<Compensation> {
    compensate_segment_with_fallback(seg, theta, solver, None, opts)
}

/// [`compensate_segment`] with a fallback: a QP on which `solver` stops at
/// its iteration limit or fails numerically is solved again by `fallback`
/// (typically Clarabel), and the event is
/// recorded in [`Compensation::fallbacks`]. An infeasible or malformed QP is
/// not retried (no solver can do better); it is returned as an error.
#[cfg(test)]
pub(crate) fn compensate_segment_with_fallback(
    seg: &SegmentData<'_>,
    theta: &Theta,
    solver: &dyn QpSolver,
    fallback: Option<&dyn QpSolver>,
    opts: &CompensateOptions,
) -> Result<Compensation> {
    compensate_from(seg, theta, solver, fallback, opts, None).map(|(c, _)| c)
}

/// Compensates one segment at θ (docs/method.md §5): solves, re-linearizes around the
/// solution and solves again until the inputs settle (at most
/// `max_linearizations` solves). A QP on which `solver` stops at its
/// iteration limit or fails numerically is solved again by `fallback`
/// (typically Clarabel), and the event is recorded in
/// [`Compensation::fallbacks`]; an infeasible or malformed QP is not retried
/// (no solver can do better) and is returned as an error for this segment,
/// which callers leave out with a warning. The first QP is warm-started
/// from `first_warm` (cold when `None`); also returns the solution of the
/// first QP, the warm start of the first QP of the same segment at a
/// nearby θ.
///
/// The first QP is linearized around the measured inputs whatever the warm
/// start, so it is the same problem with or without one (and so are its
/// feasibility and the solver's verdict on it); a warm start changes only
/// the iterations that solve it, and its solution within the solver's
/// tolerances.
pub(crate) fn compensate_from(
    seg: &SegmentData<'_>,
    theta: &Theta,
    solver: &dyn QpSolver,
    fallback: Option<&dyn QpSolver>,
    opts: &CompensateOptions,
    first_warm: Option<&QpSolution>,
) -> Result<(Compensation, QpSolution)> {
    opts.validate()?;
    let k_steps = seg.steps();
    let mut n_rl = seg.n_rl.to_vec();
    let mut n_rr = seg.n_rr.to_vec();
    let mut out = Compensation {
        start: seg.start,
        n_rl: Vec::new(),
        n_rr: Vec::new(),
        linearizations: 0,
        qp_iterations: 0,
        objective: f64::NAN,
        input_change: Vec::new(),
        converged: false,
        fallbacks: Vec::new(),
    };
    let mut warm: Option<QpSolution> = None;
    let mut first: Option<QpSolution> = None;
    for _ in 0..opts.max_linearizations {
        let qp = build_qp(seg, theta, &n_rl, &n_rr, opts);
        let lin = out.linearizations + 1;
        let fail = |source: QpError, fallback: Option<(&'static str, QpError)>| Error::Compensation {
            segment_start: seg.start,
            linearization: lin,
            solver: solver.name(),
            source: Box::new(source),
            fallback: fallback.map(|(name, e)| (name, e.to_string())),
        };
        let warm_start = if lin == 1 { first_warm } else { warm.as_ref() };
        let sol = match (solver.solve(&qp, warm_start), fallback) {
            (Ok(sol), _) => sol,
            (Err(e @ (QpError::MaxIterations { .. } | QpError::Numerical(_))), Some(fb)) => {
                let sol = fb.solve(&qp, warm_start).map_err(|e2| fail(e.clone(), Some((fb.name(), e2))))?;
                out.fallbacks.push(QpFallback {
                    linearization: lin,
                    solver: solver.name().to_string(),
                    fallback: fb.name().to_string(),
                    reason: e,
                });
                sol
            }
            (Err(e), _) => return Err(fail(e, None)),
        };
        out.linearizations += 1;
        out.qp_iterations += sol.iterations;
        out.objective = sol.objective;
        let mut change: f64 = 0.0;
        for k in 0..k_steps {
            let a = seg.n_rl[k] + sol.w[k][0];
            let b = seg.n_rr[k] + sol.w[k][1];
            change = change.max((a - n_rl[k]).abs()).max((b - n_rr[k]).abs());
            n_rl[k] = a;
            n_rr[k] = b;
        }
        if !change.is_finite() {
            return Err(fail(QpError::Numerical("non-finite compensated inputs".into()), None));
        }
        out.input_change.push(change);
        if first.is_none() {
            first = Some(sol.clone());
        }
        warm = Some(sol);
        if change < opts.input_tolerance_rev_per_s {
            out.converged = true;
            break;
        }
    }
    out.n_rl = n_rl;
    out.n_rr = n_rr;
    let first = first
        .ok_or_else(|| Error::InvalidOption { field: "max_linearizations", reason: "must be at least 1".into() })?;
    Ok((out, first))
}

/// Compensates one segment at every θ of `thetas`, in order: the first QP
/// of each job is warm-started from the first QP solution of the last
/// successful job before it (the same QP up to θ). Calls `done` after each
/// job.
fn compensate_chain(
    seg: &SegmentData<'_>,
    thetas: &[Theta],
    solver: &dyn QpSolver,
    fallback: Option<&dyn QpSolver>,
    opts: &CompensateOptions,
    done: &(dyn Fn() + Sync),
) -> Vec<Result<Compensation>> {
    let mut out = Vec::with_capacity(thetas.len());
    let mut last: Option<QpSolution> = None;
    for theta in thetas {
        let r = compensate_from(seg, theta, solver, fallback, opts, last.as_ref());
        out.push(r.map(|(c, first)| {
            last = Some(first);
            c
        }));
        done();
    }
    out
}

/// Step 2 of the 3-step method: what compensation did.
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

/// Compensated inputs of a set of segments: per segment, the mean of the
/// compensations over several θ (docs/method.md §6 step 2).
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
    /// One per failed job and per fallback solve.
    pub warnings: Vec<CompensationWarning>,
}

/// What went wrong in one compensation job (a calibration reports it as a
/// warning).
#[derive(Debug, Clone, PartialEq)]
pub enum CompensationWarning {
    /// A compensation job (one segment at one θ_B,I) failed and was left out.
    Failed {
        /// First sample of the segment.
        segment_start: usize,
        /// Why.
        reason: String,
    },
    /// A QP the configured solver did not finish was solved by the fallback.
    SolverFallback {
        /// First sample of the segment.
        segment_start: usize,
        /// Which θ_B,I (1-based).
        theta_index: usize,
        /// The linearization (1-based).
        linearization: usize,
        /// The solver that did not finish.
        solver: String,
        /// The solver that did.
        fallback: String,
        /// Why the first one stopped.
        reason: String,
    },
}

impl CompensatedInputs {
    research_pub! {
        /// Segment data with the compensated wheel rotations.
        fn segment_data<'a>(&'a self, drive: &'a Drive) -> Vec<SegmentData<'a>> {
            self.segments
                .iter()
                .enumerate()
                .map(|(i, s)| SegmentData::new(drive, s).with_wheels(&self.n_rl[i], &self.n_rr[i]))
                .collect()
        }
    }
}

/// Compensates every segment once per θ in `thetas` and averages (step 2).
/// Segments run in parallel, each segment's jobs in the order of `thetas`:
/// the first QP of a job (linearized around the measured inputs, the same
/// QP up to θ) is warm-started from the previous job's first solution,
/// which changes its solution only within the solver's tolerances. Results
/// are collected in a fixed order; a failed job is left out with a warning; a segment with no successful job is dropped. A
/// QP the configured solver does not finish (iteration limit, numerical
/// failure) is solved again by the fallback (`QpOptions::fallback`); such
/// fallbacks are counted and reported as warnings.
pub fn compensate_segments(
    drive: &Drive,
    segments: &[Segment],
    thetas: &[Theta],
    opts: &CompensateOptions,
    qp: &QpOptions,
    progress: Option<ProgressFn<'_>>,
) -> Result<CompensatedInputs> {
    opts.validate()?;
    qp.validate()?;
    // With a mount, the axle poses the reference implies (the QP's model is the axle's).
    let axle = (!opts.extrinsics.is_zero()).then(|| axle_reference_drive(drive, &opts.extrinsics)).transpose()?;
    let drive = axle.as_ref().unwrap_or(drive);
    let solver = qp.primary();
    let fallback = qp.fallback();
    let jobs: Vec<(usize, usize)> = (0..segments.len()).flat_map(|s| (0..thetas.len()).map(move |t| (s, t))).collect();
    if let Some(p) = progress {
        p(Progress::Stage { name: "compensation", total: jobs.len() as u64 });
    }
    let done = || {
        if let Some(p) = progress {
            p(Progress::Advance(1));
        }
    };
    let results: Vec<Result<Compensation>> = segments
        .par_iter()
        .map(|seg| {
            let data = SegmentData::new(drive, seg);
            compensate_chain(&data, thetas, solver.as_ref(), fallback.as_deref(), opts, &done)
        })
        .collect::<Vec<_>>()
        .into_iter()
        .flatten()
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
        let jobs_of_segment = &results[s * thetas.len()..(s + 1) * thetas.len()];
        let Some((a, b)) = out.average_jobs(seg, jobs_of_segment, &mut qp_iters) else {
            continue;
        };
        // The relative change of the inputs, where the wheel turns.
        for i in 0..seg.steps {
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
    /// The mean compensated `(n_rl, n_rr)` of `seg` over its jobs (one per
    /// θ, in order), or `None` when every job failed; counts the jobs'
    /// solves, iterations (into `qp_iters`), failures and fallbacks, with a
    /// warning per failure and per fallback solve.
    fn average_jobs(
        &mut self,
        seg: &Segment,
        jobs: &[Result<Compensation>],
        qp_iters: &mut usize,
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let k = seg.steps;
        let (mut a, mut b, mut count) = (vec![0.0; k], vec![0.0; k], 0usize);
        for (t, job) in jobs.iter().enumerate() {
            match job {
                Ok(c) => {
                    for i in 0..k {
                        a[i] += c.n_rl[i];
                        b[i] += c.n_rr[i];
                    }
                    count += 1;
                    self.step.qp_solves += c.linearizations;
                    *qp_iters += c.qp_iterations;
                    if !c.converged {
                        self.step.unconverged_jobs += 1;
                    }
                    self.step.fallback_solves += c.fallbacks.len();
                    self.warnings.extend(c.fallbacks.iter().map(|f| CompensationWarning::SolverFallback {
                        segment_start: seg.start,
                        theta_index: t + 1,
                        linearization: f.linearization,
                        solver: f.solver.clone(),
                        fallback: f.fallback.clone(),
                        reason: f.reason.to_string(),
                    }));
                }
                Err(e) => {
                    self.step.failed_jobs += 1;
                    self.warnings.push(CompensationWarning::Failed { segment_start: seg.start, reason: e.to_string() });
                }
            }
        }
        if count == 0 {
            return None;
        }
        for i in 0..k {
            a[i] /= count as f64;
            b[i] /= count as f64;
        }
        Some((a, b))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::compensate::SolverKind;
    use crate::drive::segment::{cut, SegmentData};
    use crate::drive::{Drive, Signals};
    use crate::model::{step, State};
    use crate::sim::{simulate, NoiseOptions, SimOptions};

    /// Circle at constant wheel speeds, reference = exact model trajectory.
    fn circle(n: usize) -> Drive {
        let th = Theta::SIM_DEFAULT_TRUE;
        let ts = 0.025;
        let (v, omega) = (8.0, 0.2);
        let a_y = v * omega;
        let (n_rl, n_rr) = crate::model::wheel_rotations(v, omega, a_y, &th);
        let u = Input { n_rl, n_rr, beta: 0.0, a_y };
        let mut x = State::zeros();
        let mut cols: Vec<Vec<f64>> = (0..4).map(|_| Vec::with_capacity(n)).collect();
        for i in 0..n {
            cols[0].push(i as f64 * ts);
            cols[1].push(x[0]);
            cols[2].push(x[1]);
            cols[3].push(x[2]);
            x = step(&x, &u, &th, ts);
        }
        let sig = Signals {
            px: cols[1].clone(),
            py: cols[2].clone(),
            psi: cols[3].clone(),
            n_rl: vec![u.n_rl; n],
            n_rr: vec![u.n_rr; n],
            beta: vec![0.0; n],
            a_y: vec![a_y; n],
        };
        crate::drive::DriveBuilder { t: cols[0].clone(), measured: sig, context: "circle".into(), ..Default::default() }
            .build()
            .expect("valid")
    }

    /// Noise-free, constant inputs: the measured inputs are optimal (zero
    /// pose error, zero input change), so compensation leaves them unchanged.
    /// (With varying true inputs the paper's R‖Δn‖² term rounds off speed
    /// changes even without noise: see the white-noise test below.)
    #[test]
    fn noise_free_constant_inputs_are_unchanged() {
        let d = circle(700);
        let seg = cut(&d, 0, 650, 650)[0];
        let data = SegmentData::new(&d, &seg);
        for kind in [SolverKind::Structured, SolverKind::Clarabel] {
            let c = compensate_segment(&data, &Theta::SIM_DEFAULT_TRUE, kind.solver().as_ref(), &Default::default())
                .expect("solves");
            for k in 0..seg.steps {
                let rl = (c.n_rl[k] - d.n_rl()[k]).abs() / d.n_rl()[k].abs();
                let rr = (c.n_rr[k] - d.n_rr()[k]).abs() / d.n_rr()[k].abs();
                assert!(rl <= 1e-9 && rr <= 1e-9, "{kind}: step {k}: {rl:.2e} {rr:.2e}");
            }
            assert!(c.converged, "{kind}");
        }
    }

    /// White wheel noise only, compensated at θ_true: the left-right
    /// (yaw-relevant) error of the inputs shrinks several-fold. Measured on
    /// seed 1, 3 km: 0.0866 → 0.0092 rev/s rms.
    #[test]
    fn white_noise_differential_error_shrinks() {
        let o = SimOptions { length_km: 1.5, noise: NoiseOptions::white_wheel_only(), ..SimOptions::paper(1) };
        let d = simulate(&o).expect("sim").drive;
        let truth = d.truth().expect("truth");
        let solver = SolverKind::Clarabel.solver();
        let (mut before, mut after, mut n) = (0.0, 0.0, 0usize);
        for seg in cut(&d, 0, 650, 650).iter().take(3) {
            let c = compensate_segment(&SegmentData::new(&d, seg), &o.theta_true, solver.as_ref(), &Default::default())
                .expect("solves");
            for k in 0..seg.steps {
                let i = seg.start + k;
                let t = truth.n_rr[i] - truth.n_rl[i];
                before += (d.n_rr()[i] - d.n_rl()[i] - t).powi(2);
                after += (c.n_rr[k] - c.n_rl[k] - t).powi(2);
                n += 1;
            }
        }
        let (before, after) = ((before / n as f64).sqrt(), (after / n as f64).sqrt());
        assert!(after < before / 3.0, "differential error {before:.4} -> {after:.4} rev/s");
    }

    /// The default stopping rule, QP tolerances and warm starts against
    /// re-linearizing to 1e-9 rev/s with tight QPs: the 3-step θ differs,
    /// by less than 0.01 of its within-drive σ (1e-4 σ measured here).
    #[test]
    fn default_tolerances_move_the_three_step_theta_by_under_a_hundredth_sigma() {
        use crate::{calibrate, CalibrationOptions, FinalSegments, Method, ThreeStepOptions};
        let drive = simulate(&SimOptions { length_km: 6.0, ..SimOptions::paper(4) }).expect("sim").drive;
        let run = |compensate: CompensateOptions, qp: QpOptions| {
            let method = Method::ThreeStep(ThreeStepOptions {
                initial_batches: 12,
                final_segments: FinalSegments::Random(16),
                compensate,
                qp,
                ..Default::default()
            });
            calibrate(&drive, &CalibrationOptions { method, ..Default::default() }).expect("3-step")
        };
        let fast = run(CompensateOptions::default(), QpOptions::default());
        let exact = run(
            CompensateOptions { input_tolerance_rev_per_s: 1e-9, max_linearizations: 15, ..Default::default() },
            QpOptions {
                structured: StructuredOptions {
                    tol_primal: 1e-9,
                    tol_dual: 1e-9,
                    tol_gap: 1e-12,
                    ..Default::default()
                },
                ..Default::default()
            },
        );
        assert_ne!(fast.theta, exact.theta, "the settings must make a difference for this test to test anything");
        let sigma = exact.within_drive_sigma();
        let (a, b) = (fast.theta.to_array(), exact.theta.to_array());
        for (i, s) in [sigma.c_e, sigma.c_d, sigma.t_r, sigma.d].into_iter().enumerate() {
            let s = s.expect("σ of every parameter");
            let z = (a[i] - b[i]).abs() / s;
            assert!(z <= 0.01, "parameter {i}: {} vs {} differ by {z:.2e} σ", a[i], b[i]);
        }
    }

    /// With the reference's mount given, a drive whose reference is turned
    /// and moved is compensated as the same drive recorded at the axle.
    #[test]
    fn a_mounted_reference_is_compensated_as_the_axle_it_implies() {
        use crate::model::extrinsics::Extrinsics;
        let mount = Extrinsics { lever_x: -0.9, lever_y: 0.1, heading_offset: 0.0188 };
        let sim = |reference_mount| {
            let o = SimOptions { length_km: 1.0, substeps: 1, reference_mount, ..SimOptions::noise_free(6) };
            simulate(&o).expect("sim").drive
        };
        let (axle, mounted) = (sim(Extrinsics::ZERO), sim(mount));
        let segs = cut(&axle, 0, 650, 650);
        let run = |d: &Drive, extrinsics| {
            let opts = CompensateOptions { extrinsics, ..Default::default() };
            compensate_segments(d, &segs, &[Theta::SIM_DEFAULT_TRUE], &opts, &QpOptions::default(), None)
                .expect("compensates")
        };
        let diff = |a: &CompensatedInputs, b: &CompensatedInputs| {
            a.n_rl
                .iter()
                .chain(&a.n_rr)
                .flatten()
                .zip(b.n_rl.iter().chain(&b.n_rr).flatten())
                .fold(0.0, |m, (x, y)| f64::max(m, (x - y).abs()))
        };
        let want = run(&axle, Extrinsics::ZERO);
        assert!(diff(&run(&mounted, mount), &want) < 1e-9);
        assert!(diff(&run(&mounted, Extrinsics::ZERO), &want) > 1e-3, "the mount matters");
    }

    #[test]
    fn invalid_options_name_the_field() {
        let e = CompensateOptions { max_linearizations: 0, ..Default::default() }.validate().expect_err("bad");
        assert!(e.to_string().contains("max_linearizations"));
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod solver_tests {
    use super::*;
    use crate::compensate::qp::clarabel::ClarabelSolver;
    use crate::compensate::qp::riccati::StructuredSolver;
    use crate::drive::segment::{select_segments, SegmentOptions};
    use crate::sim::{simulate, SimOptions};

    /// Relative objective agreement of the two solvers (both stop at ~1e-9
    /// relative tolerances).
    const OBJ_RTOL: f64 = 1e-7;
    /// Input agreement, rev/s.
    const W_ATOL: f64 = 1e-6;

    /// `odocal simulate --seed 2 --length-km 4`: the segment starting at
    /// sample 6700 contains a stop (236 samples with ñ = 0), so the input
    /// boxes have zero width there. Before the structured solver pinned such
    /// inputs it hit its iteration limit on this QP.
    #[test]
    fn standstill_segment_structured_equals_clarabel() {
        let drive = simulate(&SimOptions { length_km: 4.0, ..SimOptions::paper(2) }).unwrap().drive;
        let sel = select_segments(&drive, &SegmentOptions::default()).unwrap();
        let seg = sel.all.iter().find(|s| s.start == 6700).expect("segment at 6700");
        let data = SegmentData::new(&drive, seg);
        let stopped = (0..data.steps()).filter(|&k| data.n_rl[k] == 0.0 && data.n_rr[k] == 0.0).count();
        assert!(stopped > 100, "only {stopped} standstill samples");
        let opts = CompensateOptions::default();
        for theta in [Theta::PAPER_INITIAL, Theta::SIM_DEFAULT_TRUE] {
            let qp = build_qp(&data, &theta, data.n_rl, data.n_rr, &opts);
            let zero_width = qp.w_lo.iter().zip(&qp.w_hi).filter(|(lo, hi)| (*hi - *lo).amax() == 0.0).count();
            assert_eq!(zero_width, stopped);
            let s = StructuredSolver::tight().solve(&qp, None).unwrap();
            let c = ClarabelSolver::default().solve(&qp, None).unwrap();
            let rel = (s.objective - c.objective).abs() / c.objective.abs();
            assert!(rel <= OBJ_RTOL, "objective {} vs {} (rel {rel:.1e})", s.objective, c.objective);
            let dw = s.w.iter().zip(&c.w).map(|(a, b)| (a - b).amax()).fold(0.0, f64::max);
            assert!(dw <= W_ATOL, "inputs differ by {dw:.1e}");

            // The whole re-linearization loop (warm starts included) agrees
            // and needs no fallback.
            let fb = ClarabelSolver::default();
            let cs =
                compensate_segment_with_fallback(&data, &theta, &StructuredSolver::tight(), Some(&fb), &opts).unwrap();
            let cc = compensate_segment(&data, &theta, &fb, &opts).unwrap();
            assert!(cs.fallbacks.is_empty(), "{:?}", cs.fallbacks);
            let dn = cs.n_rl.iter().chain(&cs.n_rr).zip(cc.n_rl.iter().chain(&cc.n_rr)).map(|(a, b)| (a - b).abs());
            let dn = dn.fold(0.0, f64::max);
            assert!(dn <= W_ATOL, "compensated inputs differ by {dn:.1e}");
        }
    }

    /// A solver that always stops at its iteration limit, to exercise the
    /// fallback.
    struct Stalls;
    impl QpSolver for Stalls {
        fn name(&self) -> &'static str {
            "stalls"
        }
        fn solve(&self, _: &StageQp, _: Option<&QpSolution>) -> std::result::Result<QpSolution, QpError> {
            Err(QpError::MaxIterations { iterations: 50, residual: 1e-7 })
        }
    }

    /// A solver that always finds the problem infeasible.
    struct Infeasible;
    impl QpSolver for Infeasible {
        fn name(&self) -> &'static str {
            "infeasible"
        }
        fn solve(&self, _: &StageQp, _: Option<&QpSolution>) -> std::result::Result<QpSolution, QpError> {
            Err(QpError::Infeasible("test".into()))
        }
    }

    #[test]
    fn fallback_is_recorded_and_infeasible_is_not_retried() {
        let drive = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(3) }).unwrap().drive;
        let sel = select_segments(&drive, &SegmentOptions::default()).unwrap();
        let data = SegmentData::new(&drive, &sel.all[0]);
        let opts = CompensateOptions::default();
        let fb = StructuredSolver::tight();
        let c = compensate_segment_with_fallback(&data, &Theta::PAPER_INITIAL, &Stalls, Some(&fb), &opts).unwrap();
        assert_eq!(c.fallbacks.len(), c.linearizations);
        let first = c.fallbacks[0].to_string();
        assert!(first.contains("stalls → structured: iteration limit"), "{first}");
        let direct = compensate_segment(&data, &Theta::PAPER_INITIAL, &fb, &opts).unwrap();
        assert_eq!(c.n_rl, direct.n_rl);
        // Without a fallback the failure is the segment's error.
        assert!(compensate_segment(&data, &Theta::PAPER_INITIAL, &Stalls, &opts).is_err());
        // Infeasible: no retry.
        let e =
            compensate_segment_with_fallback(&data, &Theta::PAPER_INITIAL, &Infeasible, Some(&fb), &opts).unwrap_err();
        assert!(e.to_string().contains("infeasible"), "{e}");
    }
}
