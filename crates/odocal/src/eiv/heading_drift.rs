//! The reference's heading drift on a scale of its own, released from the
//! pose-drift scale η_4 only where the data say the tie is wrong.
//!
//! The filter's pose-drift scale η_4 scales the position drift and the
//! heading drift together. A reference whose position drifts far more
//! than its heading (or the reverse) fits η_4 to the position and grants
//! the heading a drift it does not have, which biases t_r. The separate
//! model has a seventh scale η_6 for the heading drift; η_6 = η_4 is the
//! tied model, so the separate model contains it. With `r = η_6 − η_4`,
//! the separate model at `r` is the tied model with the heading drift's
//! starting σ multiplied by `exp(r/2)`: the fit of the separate model is a
//! one-dimensional search over `r` of tied fits.
//!
//! After the tied fit (θ̂, η̂, objective M_0), a score test evaluates the
//! objective at `r = ±1` with θ̂ and η̂ held (two objective-only filter
//! passes). Where its statistic stays below
//! [`HEADING_DRIFT_SCORE_GATE`], the tied fit is the result, unchanged to
//! the bit. Otherwise the likelihood ratio of the separate model is
//! measured with θ held at θ̂: at up to [`MAX_RATIOS`] values of `r`
//! (the first from the score test's parabola, each next from the parabola
//! through the values so far), M is minimised over η alone, from η̂. θ is
//! held because θ̂ solves the profile cost J's equations, not M's: M has
//! a slope in θ at θ̂, so M compared between fits whose θ differ measures
//! that slope as much as the heading drift (docs/method.md, "Heading
//! drift"). Where the ratio `2 (M_0 − min_r M_r)` exceeds
//! [`HEADING_DRIFT_LR_THRESHOLD`], the separate model is fitted at the best
//! `r` (a scoring pass from θ̂ and that η, with the covariance reference of
//! the tied fit) and is the result when it converged.
//!
//! # The floor's alternative
//!
//! The tie scales the heading drift by η_4 only down to a floor
//! ([`ResearchOptions::heading_drift_min_eta`](crate::eiv::ResearchOptions::heading_drift_min_eta)):
//! on a centimetre-grade position η_4 falls far below it, and a heading
//! drift tied all the way down biased t_r by +2.5 % on simulated drives
//! whose reference heading drifts by 3 mrad. Where the reference heading
//! drifts less than the floor grants, the floor biases t_r instead (a
//! random noise world with 0.56 mrad of heading drift: t_r −2.8 % with the
//! floor, −0.7 % without). The data do not settle the level (the score
//! test above looks at the likelihood, which prefers more drift on both
//! kinds of drive), so where the result holds the heading drift at the
//! floor, the drive is fitted once more without it, from the same start
//! ([`HeadingDriftTest::theta_without_floor`], [`options_without_floor`]),
//! and the two θ bracket what the floor's choice does to the estimate;
//! the σ for the next drive carries their difference as a fallback's gap
//! is carried (`crate::pooling`, `f`).

use serde::{Deserialize, Serialize};

use super::filter::Mode;
use super::problem::{Evaluation, Problem};
use super::scoring::{eta_ratio, line_search, scoring_pass, PassOutcome, PassStart, Search};
use super::steps::{damp_eta_step, eta_step};
use super::{CovarianceMode, EivOptions, NoiseSource};
use crate::error::Result;
use crate::model::Theta;

/// The score statistic below which the tie is kept without fitting the
/// separate model: the decrease of 2M that one Newton step in `r` would
/// give with θ and η held (a lower bound of the likelihood ratio's
/// quadratic approximation when η_4 is re-fitted too).
pub(crate) const HEADING_DRIFT_SCORE_GATE: f64 = 3.84;

/// The likelihood ratio `2 (M_tied − M_r)` (θ held) above which the separate
/// heading-drift scale is the result: the χ²₁ quantile at 0.1 %.
pub(crate) const HEADING_DRIFT_LR_THRESHOLD: f64 = 10.83;

/// Values of `r` tried at most.
const MAX_RATIOS: usize = 3;

/// The step in `r` of the score test's differences.
const SCORE_STEP: f64 = 1.0;

/// Largest |r| tried: the heading drift's variance within e^±6 of the tied one.
const MAX_RATIO: f64 = 6.0;

research_pub! {
    /// The test of the heading-drift scale against the pose-drift scale
    /// ([`EivReport::heading_drift`](crate::eiv::EivReport::heading_drift)).
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct HeadingDriftTest {
        /// The score test's statistic at the tied fit: twice the decrease of
        /// the objective M that a Newton step in `r = η_6 − η_4` would give
        /// with θ and η held (from M at `r = −1, 0, +1`).
        pub score_statistic: f64,
        /// `2 (M_tied − M_r)` at the best `r` tried, M_r minimised over η with
        /// θ held at the tied θ̂ (None where the score statistic kept the
        /// tie).
        pub likelihood_ratio: Option<f64>,
        /// The best `r = η_6 − η_4` tried (0 where none was).
        pub log_ratio: f64,
        /// The result uses the separate heading-drift scale.
        pub separate: bool,
        /// The heading-drift scale η_6 of the result (when tied η_4, not
        /// below its floor
        /// [`ResearchOptions::heading_drift_min_eta`](crate::eiv::ResearchOptions::heading_drift_min_eta)).
        pub eta: f64,
        /// Filter passes of the test, its η fits and the separate fit, `[with
        /// derivatives, objective only]` (not in [`EivReport::evaluations`](crate::eiv::EivReport::evaluations)).
        pub evaluations: [usize; 2],
        /// Where the tie holds the heading drift at its floor (η_4 below
        /// [`ResearchOptions::heading_drift_min_eta`](crate::eiv::ResearchOptions::heading_drift_min_eta),
        /// a centimetre-grade position): the score statistic towards *more*
        /// heading drift than the floor grants, from the same three
        /// objective values as [`Self::score_statistic`] (no extra filter
        /// pass). A diagnostic: the test releases only towards less, and
        /// nothing is judged on it. It is 0 on a perfect reference and in
        /// the hundreds on RTK-grade drives whose t_r the default biases
        /// up by about 1 %, but as large on random noise worlds whose t_r
        /// is right (docs/validation.md, "What is left: the drift's
        /// correlation time, and no guard"). None where η_4 lies above the
        /// floor. In JSON only when present.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub upward_at_floor: Option<f64>,
        /// Where the result is the tied fit holding the heading drift at its
        /// floor: θ (before any bias correction) of the same fit without the
        /// floor, the heading drift following η_4 all the way down, fitted from
        /// the same start. The floor is a modelling choice the fit does
        /// not estimate, and θ can depend on it (module docs, "The floor's
        /// alternative"); the σ for the next drive carries the difference.
        /// Where that fit stops at its iteration limit, its θ there. None
        /// where the heading drift lies above its floor, the separate scale
        /// is the result, or that fit failed. In JSON only when present.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub theta_without_floor: Option<Theta>,
    }
}

/// What the tied fit ended with.
pub(super) struct TiedFit {
    pub(super) theta: Theta,
    pub(super) eta: [f64; 6],
    pub(super) theta_reference: Theta,
    pub(super) free: [bool; 4],
    pub(super) cost: f64,
}

/// The separate model at a ratio `r`: its options (the noise model with the
/// heading drift's σ scaled) and problem.
pub(super) struct SeparateModel<'a> {
    pub(super) opts: EivOptions,
    pub(super) prob: Problem<'a>,
}

/// The separate model's fit chosen as the result: the model and its pass.
pub(super) struct SeparateFit<'a> {
    pub(super) model: SeparateModel<'a>,
    pub(super) pass: PassOutcome,
}

/// Whether the heading-drift test applies: η estimated, the pose drift
/// free, the heading drift in the model.
pub(super) fn applies(opts: &EivOptions) -> bool {
    !opts.fix_noise
        && !opts.eta_held[NoiseSource::PoseDrift.index()]
        && opts.noise.heading_drift_sigma_rad > 0.0
        && opts.research.heading_drift_test
}

/// The tied model's heading-drift scale at pose-drift scale `eta_4`:
/// `max(η_4, m)`, m its floor
/// [`ResearchOptions::heading_drift_min_eta`](crate::eiv::ResearchOptions::heading_drift_min_eta).
fn heading_drift_eta(opts: &EivOptions, eta_4: f64) -> f64 {
    if !opts.research.position_drift_own_scale {
        eta_4.max(opts.research.heading_drift_min_eta)
    } else {
        eta_4
    }
}

/// Whether the tied model holds the heading drift at its floor at
/// pose-drift scale `eta_4`: η_4 below
/// [`ResearchOptions::heading_drift_min_eta`](crate::eiv::ResearchOptions::heading_drift_min_eta),
/// the heading drift tied to it.
pub(super) fn held_at_floor(opts: &EivOptions, eta_4: f64) -> bool {
    !opts.research.position_drift_own_scale && eta_4 < opts.research.heading_drift_min_eta
}

/// `opts` without the heading drift's floor: the heading drift tied to η_4
/// all the way down (the floor at the η lower bound). The fit the σ for the
/// next drive compares with where the result holds the heading drift at
/// its floor (module docs, "The floor's alternative").
pub(super) fn options_without_floor(opts: &EivOptions) -> EivOptions {
    let mut o = opts.clone();
    o.research.heading_drift_min_eta = opts.eta_bounds[0];
    o
}

/// `opts` with the heading drift's σ multiplied by `exp(r/2)`.
pub(super) fn options_at(opts: &EivOptions, r: f64) -> EivOptions {
    let mut o = opts.clone();
    o.noise.heading_drift_sigma_rad *= (0.5 * r).exp();
    o
}

/// The problem of `prob` under `opts` (its own filter-pass counter).
pub(super) fn problem_at<'a>(prob: &Problem<'a>, opts: &EivOptions) -> Problem<'a> {
    Problem::new(prob.input, prob.windows.clone(), opts)
}

/// Runs the test after the tied fit and, where the data ask for it, the
/// separate fit. Returns the test and the separate fit when it is the result.
pub(super) fn test<'a>(
    prob: &Problem<'a>,
    tied: &TiedFit,
    opts: &EivOptions,
) -> Result<(HeadingDriftTest, Option<SeparateFit<'a>>)> {
    let follows = opts.research.covariance == CovarianceMode::FollowsTheta;
    let evaluations = std::cell::Cell::new([0usize; 2]);
    let count = |p: &Problem<'_>| {
        let (e, sum) = (p.evaluations.get(), evaluations.get());
        evaluations.set([sum[0] + e[0], sum[1] + e[1]]);
    };
    let h = SCORE_STEP;
    let mut m = [0.0; 2];
    for (k, r) in [-h, h].into_iter().enumerate() {
        let p = problem_at(prob, &options_at(opts, r));
        m[k] = p.evaluate(&tied.theta, &tied.theta_reference, &tied.eta, Mode::cost(follows))?.total.merit();
        count(&p);
    }
    let m0 = tied.cost;
    let g = (m[1] - m[0]) / (2.0 * h);
    let c = (m[1] - 2.0 * m0 + m[0]) / (h * h);
    let two_sided = opts.research.heading_drift_two_sided;
    // One-sided: only a heading drift smaller than the tie grants (r < 0,
    // so g > 0) counts as evidence against the tie.
    let newton = if c > 0.0 && (two_sided || g > 0.0) { g * g / c } else { 0.0 };
    let lowest = if two_sided { m[0].min(m[1]) } else { m[0] };
    let score_statistic = newton.max(2.0 * (m0 - lowest)).max(0.0);
    let upward_at_floor = held_at_floor(opts, tied.eta[NoiseSource::PoseDrift.index()]).then(|| {
        let newton_up = if c > 0.0 && g < 0.0 { g * g / c } else { 0.0 };
        newton_up.max(2.0 * (m0 - m[1])).max(0.0)
    });
    let mut out = HeadingDriftTest {
        score_statistic,
        likelihood_ratio: None,
        log_ratio: 0.0,
        separate: false,
        eta: heading_drift_eta(opts, tied.eta[NoiseSource::PoseDrift.index()]),
        evaluations: evaluations.get(),
        upward_at_floor,
        theta_without_floor: None,
    };
    if score_statistic < opts.research.heading_drift_score_gate {
        return Ok((out, None));
    }
    let upper = if two_sided { MAX_RATIO } else { 0.0 };
    let r_max = upper.min(opts.eta_bounds[1] - tied.eta[NoiseSource::PoseDrift.index()]).max(0.0);
    let r_min = -MAX_RATIO;
    let first = if c > 0.0 { -g / c } else { -2.0 * g.signum() };
    // The likelihood ratio with θ held at the tied θ̂: M minimised over η
    // alone at each `r` tried (module docs: why θ is held).
    let mut tried: Vec<(f64, f64)> = vec![(0.0, m0)];
    let mut best: Option<(f64, f64, [f64; 6])> = None;
    let mut r = first.clamp(r_min, r_max);
    for _ in 0..MAX_RATIOS {
        if tried.iter().any(|(x, _)| (x - r).abs() < 0.1) {
            break;
        }
        let p = problem_at(prob, &options_at(opts, r));
        let profile = eta_profile(&p, tied, follows, opts);
        count(&p);
        let Ok((cost, eta)) = profile else { break };
        tried.push((r, cost));
        if best.is_none_or(|(_, c, _)| cost < c) {
            best = Some((r, cost, eta));
        }
        r = next_ratio(&tried, g).clamp(r_min, r_max);
    }
    let separate = best.and_then(|(r, cost, eta)| {
        let lr = 2.0 * (m0 - cost);
        out.likelihood_ratio = Some(lr);
        out.log_ratio = r;
        if lr <= opts.research.heading_drift_lr_threshold {
            return None;
        }
        // The data reject the tie: the separate model's fit at the best `r`,
        // from θ̂ and the η that minimised M there.
        let o = options_at(opts, r);
        let p = problem_at(prob, &o);
        let pass = scoring_pass(&p, tied.theta, eta, tied.theta_reference, tied.free, PassStart::Later, &o);
        count(&p);
        match pass {
            Ok(pass) if pass.report.termination.converged() => {
                out.separate = true;
                out.eta = heading_drift_eta(opts, pass.eta[NoiseSource::PoseDrift.index()]) + r;
                Some(SeparateFit { model: SeparateModel { opts: o, prob: p }, pass })
            }
            _ => None,
        }
    });
    out.evaluations = evaluations.get();
    Ok((out, separate))
}

/// Fisher-scoring steps in η at most of [`eta_profile`].
const MAX_PROFILE_STEPS: usize = 6;

/// The `max |Δη|/σ` below which [`eta_profile`] stops: M is then within
/// about `½·0.1²` per source of its minimum over η, far below the
/// likelihood ratio's threshold.
const PROFILE_TOLERANCE: f64 = 0.1;

/// A step of [`eta_profile`] within this many [`PROFILE_TOLERANCE`]s, or
/// one that shrinking as the step before did would leave less than the
/// tolerance (`r_k²/r_{k−1}`), is its last: its point is evaluated for M
/// only (no η derivatives, about a fifth of the pass), and the profile ends
/// there, unless the step had to be halved (then its point is evaluated
/// with the derivatives and the profile goes on). The rule is the fit's
/// for its likely last iteration.
const PROFILE_LAST: f64 = 5.0;

/// The objective M minimised over η with θ held at the tied θ̂, on the
/// problem `p` (a separate model's), from the tied η̂: Fisher-scoring steps
/// in η, each halved until M does not rise, the last one
/// ([`PROFILE_LAST`]) without the derivatives after it. Returns M and η
/// there.
pub(super) fn eta_profile(
    p: &Problem<'_>,
    tied: &TiedFit,
    follows: bool,
    opts: &EivOptions,
) -> Result<(f64, [f64; 6])> {
    let bounds = opts.eta_bounds;
    let mode = Mode::eta_only(follows);
    let mut eta = tied.eta;
    let mut ev = p.evaluate(&tied.theta, &tied.theta_reference, &eta, mode)?;
    let mut before: Option<f64> = None;
    for _ in 0..MAX_PROFILE_STEPS {
        let es = eta_step(&ev.total, &eta, bounds, &opts.eta_held);
        let ratio = eta_ratio(&eta, &es.step, &es.sigma, bounds);
        if ratio < PROFILE_TOLERANCE {
            break;
        }
        let last = opts.research.final_step
            && (ratio < PROFILE_LAST * PROFILE_TOLERANCE
                || before.is_some_and(|b| ratio * ratio < PROFILE_TOLERANCE * b));
        let step_mode = if last { Mode::cost(follows) } else { mode };
        let deta = damp_eta_step(&es.step, &eta, 1.0, bounds);
        let previous = ev.total.merit();
        let accept = |t: &Evaluation, _: &Theta, _: &[f64; 6]| {
            let c = t.total.merit();
            (c <= previous, c)
        };
        let search = line_search(
            p,
            &tied.theta,
            &eta,
            &[0.0; 4],
            &deta,
            &tied.theta_reference,
            step_mode,
            false,
            opts,
            &accept,
        )?;
        match search {
            Search::Accepted { eta: et, ev: e, lambda, .. } => {
                eta = et;
                ev = *e;
                let halved = lambda < 1.0;
                if last && !halved {
                    break;
                }
                if last {
                    // A halved last step leaves more than predicted: the
                    // profile goes on from its point, with the derivatives.
                    ev = p.evaluate(&tied.theta, &tied.theta_reference, &eta, mode)?;
                }
            }
            Search::Rejected { .. } => break,
        }
        before = Some(ratio);
    }
    Ok((ev.total.merit(), eta))
}

/// The next `r` to fit: the vertex of the parabola through the three
/// lowest points tried (with two, through both with the slope `g` at 0);
/// where it opens downwards, twice the best point's `r`.
fn next_ratio(tried: &[(f64, f64)], g: f64) -> f64 {
    let mut pts: Vec<(f64, f64)> = tried.to_vec();
    pts.sort_by(|a, b| a.1.total_cmp(&b.1));
    let (rb, _) = pts[0];
    let curvature_vertex = if pts.len() >= 3 {
        let [(x0, y0), (x1, y1), (x2, y2)] = [pts[0], pts[1], pts[2]];
        let d = (x0 - x1) * (x0 - x2) * (x1 - x2);
        let a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / d;
        let b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / d;
        (a > 0.0 && d.is_finite() && d != 0.0).then(|| -b / (2.0 * a))
    } else {
        // M(r) ≈ M_0 + g r + a r² through (r_1, M_1).
        let (m0, (r1, m1)) = (tried[0].1, tried[1]);
        let a = (m1 - m0 - g * r1) / (r1 * r1);
        (a > 0.0).then(|| -g / (2.0 * a))
    };
    curvature_vertex.filter(|v| v.is_finite()).unwrap_or(2.0 * rb)
}
