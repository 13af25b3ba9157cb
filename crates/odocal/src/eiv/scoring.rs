//! One Fisher-scoring pass: θ and η steps, step halving, convergence.

use super::filter::{Mode, NETA};
use super::problem::{theta_add, Evaluation, Problem};
use super::steps::{
    damp_eta_step, eta_add, eta_step, fix_unobservable, score_norm, secant_eta_factor, theta_step, EtaStep,
};
use super::{CovarianceMode, EivOptions, IterationRecord, PassReport, Termination};
use crate::error::Result;
use crate::model::param::Param;
use crate::model::Theta;

pub(super) struct PassOutcome {
    pub(super) theta: Theta,
    pub(super) eta: [f64; 6],
    pub(super) eval: Evaluation,
    pub(super) report: PassReport,
    pub(super) free: [bool; 4],
    pub(super) unobservable: Vec<Param>,
    /// The σ-over-resolution ratios that decided `unobservable` (the first
    /// pass only).
    pub(super) start_ratios: Option<[f64; 4]>,
    pub(super) eta_sigma: [f64; 6],
}

/// Where a scoring pass starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PassStart {
    /// The fit's first pass: the observability decision is taken at its start.
    First,
    /// A pass from an earlier pass's estimate or a chosen point, with the
    /// parameters it is given free.
    Later,
    /// A pass from the estimate of a coarse fit of the same drive
    /// (`first_pass` in estimate.rs), a few σ from its own: its start is
    /// evaluated in full and its first step is simultaneous
    /// ([`SIMULTANEOUS_BELOW`]), as after an alternating iteration that
    /// converges fast.
    Near,
}

/// The observability decision at a first pass's start, from `H_θ` there
/// ([`fix_unobservable`] where `opts.fix_unobservable`): the free mask, the
/// parameters held and the ratios that decided; `free0` unchanged and
/// nothing held otherwise.
pub(super) fn start_decision(
    h_theta: &nalgebra::Matrix4<f64>,
    free0: &[bool; 4],
    opts: &EivOptions,
) -> ([bool; 4], Vec<Param>, Option<[f64; 4]>) {
    if !opts.fix_unobservable {
        return (*free0, Vec::new(), None);
    }
    let (free, held, ratios) = fix_unobservable(h_theta, free0, opts);
    (free, held, Some(ratios))
}

/// The start with the parameters that the observability decision held
/// (free in `free0`, not in `free`) at
/// [`ResearchOptions::hold_unobservable_at`](super::ResearchOptions::hold_unobservable_at);
/// `None` where nothing was held or no value is given.
pub(super) fn held_start(
    theta: &Theta,
    free0: &[bool; 4],
    free: &[bool; 4],
    opts: &EivOptions,
) -> Result<Option<Theta>> {
    let Some(held) = opts.research.hold_unobservable_at.filter(|_| free != free0) else {
        return Ok(None);
    };
    let (mut a, h) = (theta.to_array(), held.to_array());
    for i in (0..4).filter(|i| free0[*i] && !free[*i]) {
        a[i] = h[i];
    }
    let theta = Theta::from_array(a);
    theta.validate()?;
    Ok(Some(theta))
}

/// Result of a line search: the accepted point, or the last cost tried.
pub(super) enum Search {
    Accepted { theta: Theta, eta: [f64; 6], ev: Box<Evaluation>, lambda: f64 },
    Rejected { cost: f64 },
}

/// Whether a trial point is accepted, and its objective.
pub(super) type Acceptance<'a> = dyn Fn(&Evaluation, &Theta, &[f64; 6]) -> (bool, f64) + 'a;

/// Step halving along `(dθ, dη)` from `(θ, η)`. The full step is evaluated
/// with derivatives (it is usually accepted); shorter steps with the
/// objective only, unless `accept` needs the derivatives (`needs_derivs`).
/// The accepted point is returned with derivatives.
#[allow(clippy::too_many_arguments)]
pub(super) fn line_search(
    prob: &Problem<'_>,
    theta: &Theta,
    eta: &[f64; 6],
    dth: &[f64; 4],
    deta: &[f64; 6],
    theta_ref: &Theta,
    full: Mode,
    needs_derivs: bool,
    opts: &EivOptions,
    accept: &Acceptance<'_>,
) -> Result<Search> {
    let mut lambda = 1.0;
    let mut last_cost = f64::NAN;
    for h in 0..=opts.max_halvings {
        let th = theta_add(theta, dth, lambda);
        if th.validate().is_ok() {
            let et = eta_add(eta, deta, lambda, opts.eta_bounds);
            let mode = if h == 0 || needs_derivs { full } else { Mode::cost(full.follows_theta) };
            if let Ok(t) = prob.evaluate(&th, theta_ref, &et, mode) {
                let (ok, cost) = accept(&t, &th, &et);
                if cost.is_finite() {
                    last_cost = cost;
                    if ok {
                        let ev = if t.mode == full { t } else { prob.evaluate(&th, theta_ref, &et, full)? };
                        return Ok(Search::Accepted { theta: th, eta: et, ev: Box::new(ev), lambda });
                    }
                }
            }
        }
        lambda *= 0.5;
    }
    Ok(Search::Rejected { cost: last_cost })
}

/// `max |Δη_j|/σ_j` of an η step alone ([`step_ratio`] without θ).
pub(super) fn eta_ratio(eta: &[f64; 6], deta: &[f64; 6], seta: &[f64; 6], bounds: [f64; 2]) -> f64 {
    step_ratio(&[0.0; 4], &[0.0; 4], &[false; 4], eta, deta, seta, bounds)
}

/// `max |step_i|/σ_i` over the free θ and the η that move.
pub(super) fn step_ratio(
    dth: &[f64; 4],
    sth: &[f64; 4],
    free: &[bool; 4],
    eta: &[f64; 6],
    deta: &[f64; 6],
    seta: &[f64; 6],
    bounds: [f64; 2],
) -> f64 {
    let mut ratio = 0.0f64;
    for i in 0..4 {
        if free[i] && sth[i] > 0.0 {
            ratio = ratio.max(dth[i].abs() / sth[i]);
        }
    }
    for j in 0..NETA {
        if seta[j] > 0.0 {
            // A step that lands on a clamp counts by its size, not its σ.
            let at_clamp = (eta[j] + deta[j] - bounds[0]).abs() < 1e-12 || (eta[j] + deta[j] - bounds[1]).abs() < 1e-12;
            if !at_clamp || deta[j].abs() > 1e-12 {
                ratio = ratio.max(deta[j].abs() / seta[j]);
            }
        }
    }
    ratio
}

/// One scoring pass (with [`CovarianceMode::HeldAtReference`], at a fixed
/// covariance reference).
///
/// With the covariance following θ, θ and η have different objectives (the
/// profile cost J for θ, the marginal likelihood M for η), so each
/// iteration takes a θ step halved on J at fixed η, then an η step halved
/// on M at fixed θ (block coordinate); once the iteration converges fast,
/// both step together from one evaluation ([`SIMULTANEOUS_BELOW`]). With
/// the covariance held, one joint step on M (corrected score for θ).
pub(super) fn scoring_pass(
    prob: &Problem<'_>,
    theta0: Theta,
    eta0: [f64; 6],
    theta_ref: Theta,
    free0: [bool; 4],
    start: PassStart,
    opts: &EivOptions,
) -> Result<PassOutcome> {
    let mut pass = Pass::start(prob, theta0, eta0, theta_ref, free0, start, opts)?;
    for it in 0..opts.max_iterations {
        let Some(ratio) = pass.iterate()? else {
            break;
        };
        if it + 1 == opts.max_iterations {
            pass.termination = Termination::MaxIterations { iterations: opts.max_iterations, step_over_sigma: ratio };
        }
    }
    pass.finish()
}

/// A lean pass evaluates the point after an iteration in full where that
/// point is likely converged: where the iteration's `max |step|/σ` is below
/// this many step tolerances, or where the step shrinking as it did in the
/// iteration before (`r_k²/r_{k−1}`) would be below the tolerance. A lean
/// evaluation of a converged point is followed by a full one at the same
/// point (its η derivatives decide the convergence test). The fixed
/// threshold alone misses on long drives: the step is measured in σ, which
/// shrinks with the drive's length, so the same path to the estimate ends
/// with larger ratios (the 96 km length-series drive: 7.61, 0.61, then
/// 0.017 converged). Near the estimate the scoring iteration shrinks the
/// step 3–55× per iteration (simulated `paper` and `high` drives, 12–96
/// km), mostly more as it converges; on the test-track drives 2–25×, where
/// the shrink also falls. Where the guess is wrong the iteration costs the η columns
/// it did not need (about 0.8 of the lean pass the right guess saves), and
/// its result is the same.
const LIKELY_LAST: f64 = 5.0;

/// With [`ResearchOptions::simultaneous_steps`](super::ResearchOptions):
/// after an iteration whose `max |step|/σ` is below this and at most
/// [`SIMULTANEOUS_SHRINK`] of the iteration's before, the next start is
/// evaluated in full and θ and η step together from it (Jacobi instead of
/// Gauss–Seidel): one pass with all derivatives per iteration instead of a
/// θ-step pass with the η derivatives and an η-step pass with the θ
/// derivatives, which cost 1.3 of it together. Both iterations have the
/// same fixed point, the root of θ's score on J and η's on M, and end by
/// the same test; near it the θ–η coupling is weak, so the simultaneous
/// step shrinks the remaining step about as much as the alternating pair
/// (the 24 km drive of seed 1: 3.39 → 0.112 → 0.0029 σ against 3.39 →
/// 0.112 → 0.0033 σ). Far from it the alternating steps converge faster
/// (on that drive, from 26 σ a simultaneous step left 10.3 σ, the
/// alternating pair 3.39 σ), so they stay there. A simultaneous step is
/// kept when the remaining step at its point is at most
/// [`SIMULTANEOUS_SHRINK`] of the iteration's; otherwise its pass is lost
/// and the pass goes on with alternating steps from the same start to its
/// end (where the step grows again near the estimate, or along a ridge of
/// correlated noise scales, where the alternating steps zig-zag too).
const SIMULTANEOUS_BELOW: f64 = 30.0;

/// The shrink of `max |step|/σ` per iteration that simultaneous steps ask
/// for ([`SIMULTANEOUS_BELOW`]): of the alternating iteration before the
/// first, and of each simultaneous step.
const SIMULTANEOUS_SHRINK: f64 = 0.5;

/// Relative tolerance of a step's acceptance: the objective may rise by
/// rounding.
fn tol(c: f64) -> f64 {
    1e-12 * c.abs().max(1.0)
}

/// The state of one scoring pass.
///
/// Lean iterations: with the covariance following θ and η estimated, the
/// evaluation an iteration starts from needs its η derivatives only for the
/// convergence test, whose θ part alone decides while the θ step is ≥ the
/// tolerance (the test takes the maximum over θ and η). So it is evaluated
/// with the θ derivatives only (4 of the 10 covariance derivatives) and
/// evaluated again in full only when its θ step is below the tolerance, or
/// at the end; once that happened, later starts are evaluated in full
/// directly, and so is the start after an iteration whose step was within
/// [`LIKELY_LAST`] tolerances. Steps and decisions are those of full evaluations (the θ
/// entries are identical to the bit; test
/// `lean_iteration_starts_give_the_full_evaluations_results_to_the_bit`);
/// only `IterationRecord::step_over_sigma` of an unconverged iteration can
/// be smaller (it lacks the η step at the iteration's start).
struct Pass<'p> {
    prob: &'p Problem<'p>,
    opts: &'p EivOptions,
    theta_ref: Theta,
    free: [bool; 4],
    unobservable: Vec<Param>,
    start_ratios: Option<[f64; 4]>,
    follows: bool,
    eta_derivs: bool,
    /// The mode of a full evaluation, and of an iteration's start (lean or full).
    full: Mode,
    start_mode: Mode,
    bounds: [f64; 2],
    theta: Theta,
    eta: [f64; 6],
    ev: Evaluation,
    initial_cost: f64,
    history: Vec<IterationRecord>,
    termination: Termination,
    eta_sigma: [f64; 6],
    /// With the covariance following θ and η estimated, the evaluation at
    /// the end of a θ step only serves the η step that follows (its η
    /// gradient and information), so it skips `∂P/∂θ` (4 of the 10
    /// covariance derivatives); when that η step is not taken, the point is
    /// evaluated again in full. After an iteration whose η did not move, the
    /// θ step is evaluated in full directly (η at a clamp: the η step is
    /// likely not taken again).
    eta_moved: bool,
    /// The previous iteration's η scoring step and the factor it was taken
    /// with (secant damping, see `secant_eta_factor`).
    last_eta_step: Option<([f64; 6], f64)>,
    eta_last: Option<f64>,
    /// The loop stopped after an iteration start that was evaluated lean
    /// (its η step and σ are then taken from the final full evaluation).
    stopped_at_lean_start: bool,
    /// Once an iteration start had to be evaluated again in full (θ's step
    /// below the tolerance, η's not yet), the later ones are evaluated in
    /// full directly: θ stays settled while η finishes.
    theta_settled: bool,
    /// Near the estimate θ and η step together ([`SIMULTANEOUS_BELOW`]).
    simultaneous: bool,
    /// The last iteration's step was below [`SIMULTANEOUS_BELOW`] and at
    /// most [`SIMULTANEOUS_SHRINK`] of the one before (or it was a kept
    /// simultaneous step): the next starts with a simultaneous step.
    simultaneous_ready: bool,
    /// The `max |step|/σ` of the last iteration when it was a kept
    /// simultaneous step ([`Pass::final_step`]).
    simultaneous_before: Option<f64>,
}

impl<'p> Pass<'p> {
    /// The pass's first evaluation at `(θ_0, η_0)`, with the unobservable
    /// parameters held when asked.
    fn start(
        prob: &'p Problem<'p>,
        theta0: Theta,
        eta0: [f64; 6],
        theta_ref: Theta,
        free0: [bool; 4],
        start: PassStart,
        opts: &'p EivOptions,
    ) -> Result<Self> {
        let follows = opts.research.covariance == CovarianceMode::FollowsTheta;
        let eta_derivs = !opts.fix_noise;
        let full = Mode::full(follows, eta_derivs);
        let lean = prob.lean_iterations && follows && eta_derivs;
        let start_mode = if lean { Mode::full(follows, false) } else { full };
        let simultaneous = follows && eta_derivs && opts.research.simultaneous_steps;
        let near = start == PassStart::Near && simultaneous;
        let mut theta = theta0;
        let mut ev = prob.evaluate(&theta, &theta_ref, &eta0, if near { full } else { start_mode })?;
        let (free, unobservable, start_ratios) = if start == PassStart::First {
            start_decision(&ev.total.h_theta, &free0, opts)
        } else {
            (free0, Vec::new(), None)
        };
        if let Some(held) = held_start(&theta, &free0, &free, opts)? {
            theta = held;
            ev = prob.evaluate(&theta, &theta_ref, &eta0, start_mode)?;
        }
        let mut pass = Pass {
            prob,
            opts,
            theta_ref,
            free,
            unobservable,
            start_ratios,
            follows,
            eta_derivs,
            full,
            start_mode,
            bounds: opts.eta_bounds,
            theta,
            eta: eta0,
            ev,
            initial_cost: 0.0,
            history: Vec::new(),
            termination: Termination::MaxIterations { iterations: opts.max_iterations, step_over_sigma: f64::NAN },
            eta_sigma: [0.0; 6],
            eta_moved: true,
            last_eta_step: None,
            eta_last: None,
            stopped_at_lean_start: false,
            theta_settled: false,
            simultaneous,
            simultaneous_ready: near,
            simultaneous_before: None,
        };
        pass.initial_cost = pass.objective(&pass.ev, &pass.theta);
        Ok(pass)
    }

    /// The objective of θ: the profile cost J with the covariance following
    /// θ, else the corrected merit.
    fn objective(&self, ev: &Evaluation, th: &Theta) -> f64 {
        if self.follows {
            ev.total.profile()
        } else {
            ev.total.corrected_merit(th, &self.theta_ref)
        }
    }

    /// A θ-only evaluation whose θ step is below the tolerance is evaluated
    /// again in full; `true` when that happened.
    fn upgrade(&mut self) -> Result<bool> {
        if self.ev.mode == self.full {
            return Ok(false);
        }
        let (dth, sth) = theta_step(&self.ev.total, &self.free, self.follows)?;
        if step_ratio(&dth, &sth, &self.free, &self.eta, &[0.0; 6], &[0.0; 6], self.bounds) < self.opts.step_tolerance {
            self.ev = self.prob.evaluate(&self.theta, &self.theta_ref, &self.eta, self.full)?;
            Ok(true)
        } else {
            Ok(false)
        }
    }

    /// Stops the pass as converged at `ratio` (`max |step|/σ`).
    fn converged(&mut self, ratio: f64) -> Option<f64> {
        self.termination = Termination::StepTolerance { step_over_sigma: ratio, threshold: self.opts.step_tolerance };
        None
    }

    /// One iteration. `None` when the pass stops (its `termination` says
    /// why), else the iteration's `max |step|/σ`.
    fn iterate(&mut self) -> Result<Option<f64>> {
        let opts = self.opts;
        self.theta_settled |= self.upgrade()?;
        let at_full = self.ev.mode == self.full;
        let (dth, sth) = theta_step(&self.ev.total, &self.free, self.follows)?;
        let es = if self.eta_derivs && at_full {
            eta_step(&self.ev.total, &self.eta, self.bounds, &opts.eta_held)
        } else {
            EtaStep::none()
        };
        let (deta, seta) = (es.step, es.sigma);
        if at_full {
            self.eta_sigma = seta;
        }
        let mut ratio = step_ratio(&dth, &sth, &self.free, &self.eta, &deta, &seta, self.bounds);
        if self.eta_derivs && at_full {
            self.eta_last = Some(eta_ratio(&self.eta, &deta, &seta, self.bounds));
        }
        if ratio < opts.step_tolerance {
            // Converged: the remaining step is negligible against σ, so it is not
            // taken (the estimate is the point the derivatives were evaluated at).
            return Ok(self.converged(ratio));
        }
        let simultaneous_before = self.simultaneous_before.take();
        if self.simultaneous_ready && at_full {
            if let Some(before) = simultaneous_before {
                if self.final_step(&dth, &deta, ratio, before)? {
                    return Ok(None);
                }
            }
            if let Some(r) = self.simultaneous_step(&dth, &deta, ratio)? {
                return Ok(if r < opts.step_tolerance { self.converged(r) } else { Some(r) });
            }
        }
        let previous = self.objective(&self.ev, &self.theta);
        let lambda = if self.follows {
            let Some(lambda) = self.theta_step_on_profile(&dth, previous, at_full)? else {
                return Ok(None);
            };
            if self.eta_derivs {
                let Some(r) = self.eta_step_on_marginal(ratio)? else {
                    return Ok(None);
                };
                ratio = r;
            }
            lambda
        } else {
            let Some(lambda) = self.joint_step(&dth, &deta, previous)? else {
                return Ok(None);
            };
            lambda
        };
        self.history.push(IterationRecord {
            theta: self.theta,
            eta: self.eta,
            cost: self.objective(&self.ev, &self.theta),
            step_over_sigma: ratio,
            step_factor: lambda,
        });
        if ratio < opts.step_tolerance {
            return Ok(self.converged(ratio));
        }
        if self.converged_after_step()? {
            return Ok(None);
        }
        Ok(Some(ratio))
    }

    /// The θ step on the profile cost J at fixed η (cost-only halvings);
    /// its step factor, or `None` when J could not be lowered.
    fn theta_step_on_profile(&mut self, dth: &[f64; 4], previous: f64, at_full: bool) -> Result<Option<f64>> {
        let (prob, opts, free, follows) = (self.prob, self.opts, self.free, self.follows);
        let accept_j = |t: &Evaluation, th: &Theta, _: &[f64; 6]| {
            let c = self.objective(t, th);
            (c <= previous + tol(previous), c)
        };
        let theta_mode = if self.eta_derivs && self.eta_moved { Mode::eta_only(follows) } else { self.full };
        let search = line_search(
            prob,
            &self.theta,
            &self.eta,
            dth,
            &[0.0; 6],
            &self.theta_ref,
            theta_mode,
            false,
            opts,
            &accept_j,
        )?;
        match search {
            Search::Accepted { theta: th, ev: e, lambda: l, .. } => {
                self.theta = th;
                self.ev = *e;
                Ok(Some(l))
            }
            Search::Rejected { cost } => {
                // The θ-score holds the input log-Jacobian's weights, which
                // depend on θ through S, so it is not J's exact gradient and
                // near its root the scoring step need not lower J (a `high`
                // drive can stop so, J up by 2.5e-11 relative, and fall back).
                // The estimate is the score's root: take the full step when
                // it shrinks the score in the scoring metric, as the joint
                // step with the covariance held does.
                let th = theta_add(&self.theta, dth, 1.0);
                let before = score_norm(&self.ev.total, &free, follows);
                let rescue = if th.validate().is_ok() {
                    prob.evaluate(&th, &self.theta_ref, &self.eta, self.full).ok().filter(|t| {
                        let after = score_norm(&t.total, &free, follows);
                        after.is_finite() && after < before
                    })
                } else {
                    None
                };
                match rescue {
                    Some(t) => {
                        self.theta = th;
                        self.ev = t;
                        Ok(Some(1.0))
                    }
                    None => {
                        self.termination = Termination::CostIncreased { cost, previous, halvings: opts.max_halvings };
                        self.stopped_at_lean_start = !at_full;
                        Ok(None)
                    }
                }
            }
        }
    }

    /// The η step on the marginal likelihood M at fixed θ (cost-only
    /// halvings); the iteration's `max |step|/σ` with it, or `None` when M
    /// could not be lowered.
    fn eta_step_on_marginal(&mut self, ratio: f64) -> Result<Option<f64>> {
        let (prob, opts, bounds) = (self.prob, self.opts, self.bounds);
        let es = eta_step(&self.ev.total, &self.eta, bounds, &opts.eta_held);
        let (deta, seta) = (es.step, es.sigma);
        self.eta_sigma = seta;
        let ratio = ratio.max(eta_ratio(&self.eta, &deta, &seta, bounds));
        self.eta_moved = false;
        // Lean: the next evaluation in full where θ has settled or this
        // iteration is likely the last but one (`LIKELY_LAST`: the next
        // start is then most likely converged, and a lean start would be
        // evaluated twice).
        let before = self.history.last().map(|h| h.step_over_sigma);
        let shrinking = before.is_some_and(|b| ratio * ratio < opts.step_tolerance * b);
        let likely_last = ratio < LIKELY_LAST * opts.step_tolerance || shrinking;
        // Ready where the alternating steps are converging fast; a step
        // that shrinks less (a ridge of correlated scales) keeps them.
        let converging = before.is_some_and(|b| ratio < SIMULTANEOUS_SHRINK * b);
        self.simultaneous_ready = self.simultaneous && ratio < SIMULTANEOUS_BELOW && converging;
        let next_mode =
            if self.theta_settled || likely_last || self.simultaneous_ready { self.full } else { self.start_mode };
        if deta.iter().any(|x| *x != 0.0) {
            let deta_raw = deta;
            let (deta, factor) = self.damped_eta_step(&deta);
            let previous_m = self.ev.total.merit();
            let accept_m = |t: &Evaluation, _: &Theta, _: &[f64; 6]| {
                let c = t.total.merit();
                (c <= previous_m + tol(previous_m), c)
            };
            match line_search(
                prob,
                &self.theta,
                &self.eta,
                &[0.0; 4],
                &deta,
                &self.theta_ref,
                next_mode,
                false,
                opts,
                &accept_m,
            )? {
                Search::Accepted { eta: et, ev: e, lambda: l, .. } => {
                    self.eta = et;
                    self.ev = *e;
                    self.eta_moved = true;
                    self.last_eta_step = Some((deta_raw, factor * l));
                }
                Search::Rejected { cost } => {
                    self.termination =
                        Termination::CostIncreased { cost, previous: previous_m, halvings: opts.max_halvings };
                    self.ev = prob.evaluate(&self.theta, &self.theta_ref, &self.eta, self.full)?;
                    return Ok(None);
                }
            }
        }
        // An η step not taken leaves the θ step's evaluation, without ∂P/∂θ.
        if self.ev.mode != self.full && self.ev.mode != self.start_mode {
            self.ev = prob.evaluate(&self.theta, &self.theta_ref, &self.eta, next_mode)?;
        }
        Ok(Some(ratio))
    }

    /// The η scoring step `deta` from the current η, damped by the secant
    /// factor (research option `eta_secant_damping`) except where it lands
    /// on a clamp; with that factor.
    fn damped_eta_step(&self, deta: &[f64; 6]) -> ([f64; 6], f64) {
        let factor =
            if self.opts.research.eta_secant_damping { secant_eta_factor(deta, self.last_eta_step) } else { 1.0 };
        (damp_eta_step(deta, &self.eta, factor, self.bounds), factor)
    }

    /// θ and η stepped together from the full evaluation at the iteration's
    /// start ([`SIMULTANEOUS_BELOW`]): the θ scoring step on J and the η
    /// step on M (damped as in [`Pass::eta_step_on_marginal`]), both from
    /// the same point, evaluated in full. Kept when the remaining
    /// `max |step|/σ` there is at most [`SIMULTANEOUS_SHRINK`] of the
    /// iteration's `ratio`; returns it, or `None` (nothing changed) when not
    /// kept, and then the pass takes alternating steps to its end.
    fn simultaneous_step(&mut self, dth: &[f64; 4], deta: &[f64; 6], ratio: f64) -> Result<Option<f64>> {
        let (prob, opts, bounds) = (self.prob, self.opts, self.bounds);
        // Whatever is not kept, alternating steps from here to the end of
        // the pass.
        self.simultaneous = false;
        let Some((th, et, factor)) = self.simultaneous_point(dth, deta) else {
            return Ok(None);
        };
        let Ok(ev) = prob.evaluate(&th, &self.theta_ref, &et, self.full) else {
            return Ok(None);
        };
        let (dth_next, sth_next) = theta_step(&ev.total, &self.free, self.follows)?;
        let es = eta_step(&ev.total, &et, bounds, &opts.eta_held);
        let r = step_ratio(&dth_next, &sth_next, &self.free, &et, &es.step, &es.sigma, bounds);
        // A NaN step counts as not shrinking.
        let shrinks = r < SIMULTANEOUS_SHRINK * ratio;
        if !shrinks {
            return Ok(None);
        }
        self.simultaneous = true;
        self.ev = ev;
        self.eta_moved = deta.iter().any(|x| *x != 0.0);
        self.eta_sigma = es.sigma;
        self.eta_last = Some(eta_ratio(&et, &es.step, &es.sigma, bounds));
        self.simultaneous_before = Some(ratio);
        self.move_to(th, et, deta, factor, ratio);
        Ok(Some(r))
    }

    /// The point of a simultaneous step from here: θ + `dth` and η + `deta`
    /// damped ([`Pass::damped_eta_step`]), with the damping factor; `None`
    /// where that θ is not valid.
    fn simultaneous_point(&self, dth: &[f64; 4], deta: &[f64; 6]) -> Option<(Theta, [f64; 6], f64)> {
        let th = theta_add(&self.theta, dth, 1.0);
        th.validate().ok()?;
        let (damped, factor) = self.damped_eta_step(deta);
        Some((th, eta_add(&self.eta, &damped, 1.0, self.bounds), factor))
    }

    /// Moves the pass to the point `(th, et)` of a simultaneous step of
    /// `max |step|/σ` `ratio` (the η scoring step `deta`, damped by `factor`)
    /// and records the iteration, its cost from the evaluation `ev` holds
    /// there.
    fn move_to(&mut self, th: Theta, et: [f64; 6], deta: &[f64; 6], factor: f64, ratio: f64) {
        if deta.iter().any(|x| *x != 0.0) {
            self.last_eta_step = Some((*deta, factor));
        }
        self.theta = th;
        self.eta = et;
        self.history.push(IterationRecord {
            theta: th,
            eta: et,
            cost: self.objective(&self.ev, &th),
            step_over_sigma: ratio,
            step_factor: 1.0,
        });
    }

    /// The last step, taken without the derivatives after it
    /// ([`ResearchOptions::final_step`](super::ResearchOptions::final_step)):
    /// after a kept simultaneous step of `max |step|/σ` `before`, where the
    /// step from here (`ratio`) shrinking as that one did would leave a
    /// remainder `ratio²/before` below the tolerance, θ and η take the
    /// simultaneous step and the pass ends converged
    /// ([`Termination::FinalStep`]). The new point is evaluated for its
    /// objective only (about an eighth of a pass in full), so the objective
    /// values, the whiteness sums and the final cost are the estimate's;
    /// the derivatives, the information and so θ's σ are those of the
    /// evaluation the step was taken from, `ratio` σ away.
    ///
    /// The rule is the one that makes the next start a full evaluation
    /// ([`LIKELY_LAST`]); here it saves that evaluation, whose only use
    /// would be to confirm the remainder. Near the estimate the simultaneous
    /// steps mostly shrink faster than linearly (the 24 km drive of seed 1:
    /// 3.39 → 0.112 → 0.0029 σ, predicted 0.0037 σ), but not always (the
    /// length series' 24 km drive: 3.62 → 0.24 σ, predicted 0.016 σ, the
    /// remainder 0.053 σ); over 74 drives θ moved by at most 0.023 σ
    /// against fits that evaluate the point and stop by the step test.
    /// Returns whether the step was taken; where the point is not a valid θ
    /// or its evaluation fails, nothing changed.
    fn final_step(&mut self, dth: &[f64; 4], deta: &[f64; 6], ratio: f64, before: f64) -> Result<bool> {
        let opts = self.opts;
        let predicted = ratio * ratio / before;
        if !(opts.research.final_step && predicted < opts.step_tolerance) {
            return Ok(false);
        }
        let Some((th, et, factor)) = self.simultaneous_point(dth, deta) else {
            return Ok(false);
        };
        let Ok(at) = self.prob.evaluate(&th, &self.theta_ref, &et, Mode::cost(self.follows)) else {
            return Ok(false);
        };
        self.ev.total.take_values(&at.total);
        for (w, a) in self.ev.windows.iter_mut().zip(&at.windows) {
            w.take_values(a);
        }
        self.eta_last = self.eta_last.map(|r| r * r / before);
        self.move_to(th, et, deta, factor, ratio);
        self.termination = Termination::FinalStep {
            step_over_sigma: ratio,
            predicted_over_sigma: predicted,
            threshold: opts.step_tolerance,
        };
        Ok(true)
    }

    /// The joint step with the covariance held: accepted when the objective
    /// falls, or when the corrected score (whose root is the estimate; the
    /// bias term is not an exact gradient) shrinks in the Fisher metric.
    /// Its step factor, or `None` when neither happened.
    fn joint_step(&mut self, dth: &[f64; 4], deta: &[f64; 6], previous: f64) -> Result<Option<f64>> {
        let (free, follows) = (self.free, self.follows);
        let previous_q = score_norm(&self.ev.total, &free, follows);
        let accept = |t: &Evaluation, th: &Theta, _: &[f64; 6]| {
            let c = self.objective(t, th);
            (c <= previous + tol(previous) || score_norm(&t.total, &free, follows) < previous_q, c)
        };
        let search = line_search(
            self.prob,
            &self.theta,
            &self.eta,
            dth,
            deta,
            &self.theta_ref,
            self.full,
            true,
            self.opts,
            &accept,
        )?;
        match search {
            Search::Accepted { theta: th, eta: et, ev: e, lambda: l } => {
                self.theta = th;
                self.eta = et;
                self.ev = *e;
                Ok(Some(l))
            }
            Search::Rejected { cost } => {
                self.termination = Termination::CostIncreased { cost, previous, halvings: self.opts.max_halvings };
                Ok(None)
            }
        }
    }

    /// With the covariance following θ and η estimated: the convergence
    /// test on the step (θ and η) remaining at the new point, so that the
    /// last iteration can end converged (without it, on `white` with the
    /// separate heading scale every fit stopped by the iteration limit had a
    /// remaining step of 0.001–0.002 σ; it changes no θ on 80 simulated
    /// fits). No extra filter evaluation: the point is evaluated in full.
    /// `true` when the pass has converged.
    fn converged_after_step(&mut self) -> Result<bool> {
        let opts = self.opts;
        if self.eta_derivs && self.follows {
            // Lean: in full only where the θ step alone is below the tolerance.
            self.theta_settled |= self.upgrade()?;
        }
        if !(self.eta_derivs && self.follows && self.ev.mode == self.full) {
            return Ok(false);
        }
        // No filter evaluation: `ev` is in full mode here.
        let (dth, sth) = theta_step(&self.ev.total, &self.free, self.follows)?;
        let es = eta_step(&self.ev.total, &self.eta, self.bounds, &opts.eta_held);
        let (deta, seta) = (es.step, es.sigma);
        self.eta_last = Some(eta_ratio(&self.eta, &deta, &seta, self.bounds));
        let r = step_ratio(&dth, &sth, &self.free, &self.eta, &deta, &seta, self.bounds);
        if r < opts.step_tolerance {
            self.converged(r);
            return Ok(true);
        }
        Ok(false)
    }

    /// The pass's outcome at its last point (evaluated in full for the
    /// report where the loop stopped at a lean evaluation).
    fn finish(mut self) -> Result<PassOutcome> {
        if self.ev.mode != self.full {
            // Lean: the report needs the η derivatives at the estimate (the loop
            // ran out of iterations, or a θ step from a lean start failed).
            self.ev = self.prob.evaluate(&self.theta, &self.theta_ref, &self.eta, self.full)?;
            let es = eta_step(&self.ev.total, &self.eta, self.bounds, &self.opts.eta_held);
            self.eta_last = Some(eta_ratio(&self.eta, &es.step, &es.sigma, self.bounds));
            if self.stopped_at_lean_start {
                self.eta_sigma = es.sigma;
            }
        }
        let report = PassReport {
            theta_reference: self.theta_ref,
            theta: self.theta,
            initial_cost: self.initial_cost,
            final_cost: self.objective(&self.ev, &self.theta),
            termination: self.termination,
            history: self.history,
            eta_step_over_sigma: self.eta_last,
            window_stride: None,
        };
        let (theta, eta, free, eta_sigma) = (self.theta, self.eta, self.free, self.eta_sigma);
        let (unobservable, start_ratios) = (self.unobservable, self.start_ratios);
        Ok(PassOutcome { theta, eta, eval: self.ev, report, free, unobservable, start_ratios, eta_sigma })
    }
}
