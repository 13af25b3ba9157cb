//! The estimator's entry points: a fit and its checks.

use std::borrow::Cow;
use std::time::Instant;

use nalgebra::Matrix4;

use super::covariance::{eta_on_theta, fisher_covariance, inflate_to_block, noise_estimate_covariance};
use super::filter::{self, Mode, WindowSums, NETA};
use super::heading_drift::{self, HeadingDriftTest, SeparateFit, SeparateModel, TiedFit};
use super::input::make_windows;
use super::problem::{free_inverse, free_sigma, theta_add, to_array, Evaluation, Problem};
use super::scoring::{held_start, scoring_pass, start_decision, PassOutcome, PassStart};
use super::steps::{at_lower_clamp, at_upper_clamp, observability_of, reentering_sources, theta_step};
use super::{
    apply_bias_correction, first_order_bias, CovarianceEstimate, CovarianceMode, EivInput, EivOptions, EivReport,
    EivWarning, HalvesCheck, HeadingScale, InnovationNull, LateralNoise, NoiseEstimateTerm, NoiseModel, NoiseSource,
    PassReport, PoseComponent, QuantisationLevel, Termination, Window, WindowDiagnostics, NOISE_SOURCES, PARAMETERS,
};
use crate::error::{Error, Result};
use crate::model::param::Param;
use crate::model::Theta;

research_pub! {
/// The instruction set the filter's kernels run with in this process:
/// `"avx2"` where the CPU has AVX2 and FMA (x86-64, detected at run time),
/// else `"baseline"` (the build's target features, SSE2 on a default x86-64
/// build). The environment variable `ODOCAL_SIMD=baseline` forces the
/// baseline; it is read once per process. Both give results
/// identical to the bit; AVX2 is faster (docs/performance.md). A
/// benchmark's diagnostic (feature `research`).
fn kernel_instruction_set() -> &'static str {
    match filter::kernels() {
        filter::Kernels::Avx2 => "avx2",
        filter::Kernels::Baseline => "baseline",
    }
}
}

research_pub! {
    /// Estimates θ (and the noise scales η) by the EIV method of docs/method.md §9,
    /// starting from `theta_start` (batch Gauss-Newton on all segments).
    ///
    /// Two passes of Fisher scoring on the objective M of the module docs;
    /// the covariance recursion of pass i is linearised at the θ that pass
    /// starts from. Returns the estimate with `H_θ⁻¹`, the estimated noise in
    /// physical units, observability and consistency diagnostics, and typed
    /// warnings. Errors only for invalid input, a singular information matrix
    /// (with `fix_unobservable` off) or a numerically failing filter (naming
    /// the window).
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// # #[cfg(feature = "research")] {
    /// use odocal::{eiv, sim, Theta};
    /// let out = sim::simulate(&sim::SimOptions { length_km: 1.0, substeps: 1, noise: "off".parse()?, ..sim::SimOptions::paper(3) })?;
    /// let input = eiv::EivInput::from_drive(&out.drive);
    /// let start = Theta { c_e: 1.951, ..out.sidecar.theta_true };
    /// let report = eiv::estimate(&input, &start, &eiv::EivOptions::default())?;
    /// assert!((report.theta.c_e - 1.95).abs() < 1e-6);
    /// # }
    /// # Ok(()) }
    /// ```
    fn estimate(input: &EivInput<'_>, theta_start: &Theta, opts: &EivOptions) -> Result<EivReport> {
        let t0 = Instant::now();
        let (windows, opts, q_found) = prepare(input, theta_start, opts)?;
        let start_prob = Problem::new(input, windows, &opts);
        let fit = run_passes(&start_prob, theta_start, &opts)?;
        let fit = release_clamped(&start_prob, fit, &opts)?;
        let (fit, slow, time_constant_costs) = choose_time_constants(&start_prob, fit, &opts)?;
        let (tied_prob, tied_opts) = match &slow {
            Some((p, o)) => (p, o),
            None => (&start_prob, &*opts),
        };
        let (mut fit, heading_drift, separate) = heading_drift_test(tied_prob, fit, theta_start, tied_opts)?;
        hold_scales_at_clamps(&mut fit.eta_sigma, &fit.eta, tied_opts.eta_bounds);
        let (prob, opts) = match &separate {
            Some(s) => (&s.prob, &s.opts),
            None => (tied_prob, tied_opts),
        };
        let (ev, free, theta) = (&fit.ev, fit.free, fit.theta);
        let unc = uncertainty(prob, &fit, opts)?;
        let observability = observability_of(&ev.total.h_theta, &free, (fit.unobservable.clone(), fit.start_ratios), opts);
        let follows = opts.research.covariance == CovarianceMode::FollowsTheta;
        let first_order_bias = if follows { first_order_bias(&ev.total, &free) } else { None };
        let mut warnings = fit_warnings(&fit, opts);
        let diags = window_diagnostics(prob, &fit, opts, &mut warnings)?;
        let halves = halves_check(ev, &theta, &free, follows, opts.research.covariance_estimate);
        if let Some(h) = &halves {
            for i in 0..4 {
                if h.z[i].abs() > opts.max_half_z {
                    warnings.push(EivWarning::UnstableAcrossHalves {
                        parameter: PARAMETERS[i],
                        z: h.z[i],
                        threshold: opts.max_half_z,
                    });
                }
            }
        }
        let heading_white_above_floor = heading_white_ratio(prob, &fit, opts)?;
        let (mut eta, mut eta_sigma) = (fit.eta, fit.eta_sigma);
        if opts.heading_scale == HeadingScale::TiedToPosition {
            // The heading white noise was scaled by η_3: report it so.
            eta[5] = eta[3];
            eta_sigma[5] = 0.0;
        }
        let iterations = fit.passes.iter().map(|p| p.history.len()).sum();
        let mut report = EivReport {
            initial_theta: *theta_start,
            theta,
            first_order_bias,
            theta_uncorrected: theta,
            bias_subtracted: [0.0; 4],
            sigma_bias_correction: [0.0; 4],
            bias_replicates_failed: Vec::new(),
            free,
            covariance: to_array(&unc.covariance),
            sigma: unc.sigma,
            sigma_sandwich: unc.sigma_sandwich,
            sigma_block: unc.sigma_block,
            sigma_fisher: unc.sigma_fisher,
            sigma_noise_estimate: unc.sigma_noise_estimate,
            theta_eta_sensitivity: unc.theta_eta_sensitivity,
            eta_theta_sensitivity: eta_on_theta(&ev.total.info, &free, &unc.eta_free),
            eta,
            eta_sigma,
            evaluations: evaluations_of(tied_prob, separate.as_ref()),
            heading_drift,
            released: fit.released.0.clone(),
            release_kept: fit.released.1,
            noise: reported_noise(opts, &eta),
            final_cost: ev.total.merit(),
            iterations,
            termination: fit.termination(),
            passes: fit.passes,
            observability,
            windows: diags,
            halves,
            warnings,
            updates: fit.ev.total.updates,
            timing_s: t0.elapsed().as_secs_f64(),
            quantisation_step_from_readings: q_found,
            a_y_noise_floor: opts.research.a_y_sigma_floor,
            heading_noise_floor: opts.research.heading_white_sigma_floor.filter(|_| opts.heading_floor_given()),
            heading_white_at_floor: opts.research.heading_white_held_at_floor.is_some(),
            heading_white_above_floor,
            time_constant_costs,
        };
        apply_bias_correction(input, &mut report, opts)?;
        Ok(report)
    }
}

/// θ after one Fisher-scoring step from `theta_start` with the noise model
/// held (`opts.fix_noise`, the covariance following θ): one filter pass at
/// the start, `θ_start + Δθ`, no line search and no convergence test. The
/// bias correction's replicates are fitted so ([`super::apply_bias_correction`]).
///
/// Where the fit of [`estimate`] ends after its first iteration with the
/// full step (a replicate started at the estimate it re-fits usually does),
/// this is its θ to the bit: the same pass, step and sum. Elsewhere it
/// leaves out the later steps, which the bias correction's measured
/// tolerance covers (docs/performance.md). Falls back to [`estimate`] for
/// other options, and where the step leaves the valid range of θ.
pub(super) fn one_step(input: &EivInput<'_>, theta_start: &Theta, opts: &EivOptions) -> Result<Theta> {
    let follows = opts.research.covariance == CovarianceMode::FollowsTheta;
    if !(follows && opts.fix_noise) || opts.fix_unobservable {
        return estimate(input, theta_start, opts).map(|r| r.theta);
    }
    let (windows, opts, _) = prepare(input, theta_start, opts)?;
    let opts = &*opts;
    let prob = Problem::new(input, windows, opts);
    // The first evaluation and step of `scoring_pass` (its start mode with
    // the noise held is the full mode without η derivatives).
    let ev = prob.evaluate(theta_start, theta_start, &[0.0; 6], Mode::full(true, false))?;
    let (dth, sth) = theta_step(&ev.total, &opts.free, true)?;
    let ratio = super::scoring::step_ratio(&dth, &sth, &opts.free, &[0.0; 6], &[0.0; 6], &[0.0; 6], opts.eta_bounds);
    if ratio < opts.step_tolerance {
        return Ok(*theta_start);
    }
    let theta = theta_add(theta_start, &dth, 1.0);
    if theta.validate().is_err() {
        return estimate(input, theta_start, opts).map(|r| r.theta);
    }
    Ok(theta)
}

/// What every fit starts with: the options, the input and the start
/// checked, the windows made, and `FromReadings` quantisation resolved once,
/// on the drive's readings — the rest of the fit sees `Given` with the step
/// found, or `ScaledWithWhite` (and so does a bootstrap of the fit:
/// `bootstrap` resolves it from the report, not from its replicates'
/// readings). Returns the windows, the options to fit with and the step
/// found in the readings.
fn prepare<'o>(
    input: &EivInput<'_>,
    theta_start: &Theta,
    opts: &'o EivOptions,
) -> Result<(Vec<Window>, Cow<'o, EivOptions>, Option<f64>)> {
    opts.validate()?;
    input.validate()?;
    theta_start.validate()?;
    let windows = make_windows(input.parts, opts.window_samples);
    if windows.is_empty() {
        return Err(Error::NoSegments("EIV needs a drive part of at least two samples".into()));
    }
    // Three independent reads of the drive, by rayon's threads.
    let (q_found, (a_y_floor, heading_floor)) = rayon::join(
        || opts.quantisation_level.step_found(input),
        || {
            rayon::join(
                || opts.reads_a_y_floor().then(|| input.a_y_sample_noise()),
                || opts.reads_heading_floor().then(|| input.heading_sample_noise()),
            )
        },
    );
    // Below R's own heading floor the readings' noise changes nothing; held
    // at the readings' level, the heading's white noise is then R's floor.
    let heading_floor = match heading_floor {
        Some(f) if f > filter::HEADING_FLOOR_RAD => Some(f),
        Some(_) if opts.heading_white_at_floor => Some(filter::HEADING_FLOOR_RAD),
        _ => None,
    };
    let opts =
        if opts.quantisation_level == QuantisationLevel::FromReadings || a_y_floor.is_some() || heading_floor.is_some()
        {
            Cow::Owned(opts.with_resolved_readings(q_found, a_y_floor).with_heading_floor(heading_floor))
        } else {
            Cow::Borrowed(opts)
        };
    Ok((windows, opts, q_found))
}

/// Where the heading's white noise is held at its readings' level
/// ([`EivOptions::heading_white_at_floor`]): twice the fall of M from that
/// level to one with a level above it (the larger of the starting model's
/// level, which the fit at the floor dropped, and the readings' own), θ
/// and η held at the fit's (one objective-only pass). A lower bound of the
/// likelihood ratio of a level above the readings'
/// ([`EivReport::heading_white_above_floor`]).
fn heading_white_ratio(prob: &Problem<'_>, fit: &Fit, opts: &EivOptions) -> Result<Option<f64>> {
    let (Some(floor), Some(start)) =
        (opts.research.heading_white_sigma_floor, opts.research.heading_white_held_at_floor)
    else {
        return Ok(None);
    };
    let mut above = opts.clone();
    above.noise.heading_white_sigma_rad = start.max(floor);
    let p = Problem::new(prob.input, prob.windows.clone(), &above);
    let mode = Mode::cost(opts.research.covariance == CovarianceMode::FollowsTheta);
    let m = p.evaluate(&fit.theta, &fit.theta_reference(), &fit.eta, mode)?.total.merit();
    prob.count_evaluations_of(&p, 1);
    Ok(Some(2.0 * (fit.ev.total.merit() - m)))
}

/// The scoring passes of a fit and where they ended.
struct Fit {
    theta: Theta,
    eta: [f64; 6],
    eta_sigma: [f64; 6],
    free: [bool; 4],
    unobservable: Vec<Param>,
    /// The ratios that decided `unobservable` ([`EivObservability::start_sigma_over_resolution`](super::report::EivObservability::start_sigma_over_resolution)).
    start_ratios: Option<[f64; 4]>,
    passes: Vec<PassReport>,
    /// The last pass's evaluation at the estimate.
    ev: Evaluation,
    /// The sources released from their lower clamp at the end of the fit
    /// ([`release_clamped`]) and whether the released fit is the estimate.
    released: (Vec<NoiseSource>, bool),
}

impl Fit {
    /// Why the last pass stopped.
    fn termination(&self) -> Termination {
        self.passes
            .last()
            .map(|p| p.termination)
            .unwrap_or(Termination::MaxIterations { iterations: 0, step_over_sigma: f64::NAN })
    }

    /// The covariance reference of the last pass.
    fn theta_reference(&self) -> Theta {
        self.passes.last().map(|p| p.theta_reference).unwrap_or(self.theta)
    }
}

/// Runs the scoring passes from η = 0: one with the covariance following θ
/// (there is no reference to update), else `research.passes`, each with the
/// reference at the previous pass's result. The first pass decides which
/// parameters are observable.
#[inline(never)] // a symbol of its own for profiles (docs/performance.md)
fn run_passes(prob: &Problem<'_>, theta_start: &Theta, opts: &EivOptions) -> Result<Fit> {
    let mut theta = *theta_start;
    let mut eta = [0.0; 6];
    let mut free = opts.free;
    let mut unobservable = Vec::new();
    let mut start_ratios = None;
    let mut passes = Vec::new();
    let mut last: Option<(Evaluation, [f64; 6])> = None;
    let r = &opts.research;
    let passes_to_run = if r.covariance == CovarianceMode::FollowsTheta { 1 } else { r.passes };
    for pass in 0..passes_to_run {
        let mut outs = if pass == 0 {
            first_pass(prob, theta, free, opts)?
        } else {
            vec![scoring_pass(prob, theta, eta, theta, free, PassStart::Later, opts)?]
        };
        let Some(out) = outs.pop() else {
            return Err(Error::Numerical("no EIV pass ran".into()));
        };
        if pass == 0 {
            unobservable = out.unobservable.clone();
            start_ratios = out.start_ratios;
            free = out.free;
        }
        theta = out.theta;
        eta = out.eta;
        passes.extend(outs.into_iter().map(|o| o.report));
        passes.push(out.report);
        last = Some((out.eval, out.eta_sigma));
    }
    let Some((ev, eta_sigma)) = last else {
        return Err(Error::Numerical("no EIV pass ran".into()));
    };
    Ok(Fit { theta, eta, eta_sigma, free, unobservable, start_ratios, passes, ev, released: (Vec::new(), false) })
}

/// The number of windows a long drive's first stage fits ([`first_pass`]):
/// about a 24 km drive's at the default window length.
const COARSE_WINDOWS: usize = 12;

/// The coarse stage's step tolerance, `max |step|/σ` in the coarse fit's
/// own σ. Its estimate lies about one of its σ from the whole drive's, so
/// steps much finer than that would be wasted.
const COARSE_STEP_TOLERANCE: f64 = 0.5;

/// The stride of the coarse stage on a drive of `windows` windows: the
/// coarse fit runs on every `k`-th window; below 2 (no coarse stage) on a
/// drive of fewer than twice [`COARSE_WINDOWS`] windows.
pub(super) fn coarse_stride(windows: usize) -> usize {
    windows / COARSE_WINDOWS
}

/// The first scoring pass from the start `(θ_0, η = 0)`.
///
/// On a drive with at least twice [`COARSE_WINDOWS`] windows it runs in
/// two stages. The first fits θ and η on every `k`-th window, spread evenly
/// over the drive (`k` = [`coarse_stride`]), to [`COARSE_STEP_TOLERANCE`];
/// the second is the pass over all windows from that fit's estimate. Both
/// stages seek the root of the same scores, so the estimate is the whole
/// drive's, within the step tolerance of the one-stage pass; only the path
/// to it changes. The start (batch Gauss-Newton's θ) carries an
/// errors-in-variables bias that does not shrink with the drive, while σ
/// does, so on a long drive it lies farther from the estimate in σ units
/// (375 σ at 96 km against 102 σ at 24 km on the drives of seed 1) and
/// the pass over all windows needs more iterations; the coarse stage
/// takes those first iterations at `1/k` of their cost and the whole
/// drive's pass starts a coarse σ (about `√k` of its own σ) away, with a
/// simultaneous step. Against the one-stage pass (`coarse_start` off) on
/// 32 simulated drives of 48 and 96 km, θ moved by at most 0.033 σ and
/// the passes with derivatives fell by 27 % (docs/method.md).
///
/// The observability decision is taken as in the one-stage pass, at the
/// start on all windows with the starting noise model: on the coarse
/// windows, a mostly straight drive whose turns fall in windows the stride
/// skips would have a parameter held that the whole drive determines.
/// Where the coarse stage fails or does not converge, the pass starts from
/// `θ_0` as on a short drive. The coarse pass's report comes first in the
/// passes, with its stride ([`PassReport::window_stride`]).
fn first_pass(prob: &Problem<'_>, theta0: Theta, free0: [bool; 4], opts: &EivOptions) -> Result<Vec<PassOutcome>> {
    let stride = coarse_stride(prob.windows.len());
    let follows = opts.research.covariance == CovarianceMode::FollowsTheta;
    if stride < 2 || !follows || opts.fix_noise || !opts.research.coarse_start {
        return Ok(vec![scoring_pass(prob, theta0, [0.0; 6], theta0, free0, PassStart::First, opts)?]);
    }
    let (free, unobservable, start_ratios) = if opts.fix_unobservable {
        // The decision of `Pass::start`, from its (lean) start evaluation.
        let ev = prob.evaluate(&theta0, &theta0, &[0.0; 6], Mode::full(true, false))?;
        start_decision(&ev.total.h_theta, &free0, opts)
    } else {
        (free0, Vec::new(), None)
    };
    // A parameter found unobservable starts where `Pass::start` puts it.
    let theta0 = held_start(&theta0, &free0, &free, opts)?.unwrap_or(theta0);
    let coarse_opts = EivOptions { step_tolerance: COARSE_STEP_TOLERANCE, ..opts.clone() };
    let windows = prob.windows.iter().skip(stride / 2).step_by(stride).copied().collect();
    let coarse_prob = prob.with_windows(windows);
    let coarse = scoring_pass(&coarse_prob, theta0, [0.0; 6], theta0, free, PassStart::Later, &coarse_opts).ok();
    prob.count_evaluations_of(&coarse_prob, stride);
    let mut outs = Vec::new();
    let (theta, eta, start) = match coarse {
        Some(mut c) if c.report.termination.converged() => {
            c.report.window_stride = Some(stride);
            let start = (c.theta, c.eta, PassStart::Near);
            outs.push(c);
            start
        }
        _ => (theta0, [0.0; 6], PassStart::Later),
    };
    let mut out = scoring_pass(prob, theta, eta, theta0, free, start, opts)?;
    (out.free, out.unobservable, out.start_ratios) = (free, unobservable, start_ratios);
    outs.push(out);
    Ok(outs)
}

/// The fit again from its estimate with the noise sources released that
/// sit at their lower clamp while its score says the data hold them
/// ([`reentering_sources`]: each restarts at its one-step estimate), kept
/// when it converges and lowers M (the negative log marginal likelihood).
/// A source that the first scoring steps sent to the clamp, from a starting
/// model far from the drive's, cannot come back on its own (its variance
/// is then e^−20 of the start's, its information e^−40); held there, the other scales absorb it and θ with them (a
/// reference drifting slower than the model's τ under white wheel noise:
/// t_r 5.3 σ low, test `a_scale_sent_to_its_lower_clamp_early_comes_back`).
/// Released, a source may go back to the clamp; the converged fit with
/// the lower M is the estimate, the other's pass stays in the report.
fn release_clamped(prob: &Problem<'_>, fit: Fit, opts: &EivOptions) -> Result<Fit> {
    if opts.fix_noise || fit.ev.mode != Mode::full(opts.research.covariance == CovarianceMode::FollowsTheta, true) {
        return Ok(fit);
    }
    let released = reentering_sources(&fit.ev.total, &fit.eta, opts.eta_bounds, &opts.eta_held);
    if released.is_empty() {
        return Ok(fit);
    }
    let mut eta = fit.eta;
    for &(j, to) in &released {
        eta[j] = to;
    }
    let sources: Vec<NoiseSource> = released.iter().map(|(j, _)| NOISE_SOURCES[*j]).collect();
    // A released fit that fails numerically leaves the estimate as it was.
    let Ok(out) = scoring_pass(prob, fit.theta, eta, fit.theta_reference(), fit.free, PassStart::Later, opts) else {
        return Ok(fit);
    };
    let better = out.report.termination.converged() && out.eval.total.merit() < fit.ev.total.merit();
    let mut passes = fit.passes;
    if better {
        passes.push(out.report);
        let released = (sources, true);
        Ok(Fit { theta: out.theta, eta: out.eta, eta_sigma: out.eta_sigma, passes, ev: out.eval, released, ..fit })
    } else {
        // The estimate stays; its own pass stays the last.
        passes.insert(passes.len() - 1, out.report);
        Ok(Fit { passes, released: (sources, false), ..fit })
    }
}

/// The slow wheel-noise model's problem and options, when its fit is the estimate.
type SlowModel<'a> = (Problem<'a>, EivOptions);

/// The slow model's common-mode correlation time over the starting model's.
const SLOW_COMMON_TIME_FACTOR: f64 = 10.0;
/// The slow model's per-wheel correlation time over the starting model's.
const SLOW_DIFFERENTIAL_TIME_FACTOR: f64 = 20.0;

/// The fit with the wheel noise's correlation times slow, and the fit
/// that is the estimate ([`ResearchOptions::choose_time_constants`](super::ResearchOptions::choose_time_constants)),
/// tried only where `fit` leaves a noise source that is not held at its
/// lower clamp (the symptom of a model that cannot place some noise: on
/// the second simulator's drives the heading's white noise or the
/// per-wheel noise, with t_r off by up to 1.5 %). The slow model's
/// problem has `start`'s input and windows. Its scoring pass starts at
/// `fit`'s estimate, with those sources back at their starting level
/// (a source absent under the fast model may be the one the slow model
/// needs, and from the clamp it cannot return); where that pass stops at
/// its iteration limit, one more pass continues from where it stopped (its
/// steps shrink slowly on drives whose M changes a lot between the two
/// models). It is the estimate where it converges, has no noise scale at
/// its upper clamp and reaches a lower M than `fit`: the time constants are
/// hyperparameters of one likelihood, so M compares them. A scale at its
/// upper clamp is the slow model's degenerate fit (from η = 0 on the second
/// simulator's drives: common-mode and per-wheel noise at the clamp, white
/// noise at zero, M far below the proper fit's), not a better one.
/// Returns the estimate's fit, the slow model's problem and options when it
/// is the estimate, and the `[τ_c, τ_w, M]` of both fits
/// ([`EivReport::time_constant_costs`]).
fn choose_time_constants<'a>(
    start: &Problem<'a>,
    fit: Fit,
    opts: &EivOptions,
) -> Result<(Fit, Option<SlowModel<'a>>, Vec<[f64; 3]>)> {
    // The heading's white noise at its clamp with the readings' noise as its
    // floor is at that floor, not at none: no runaway's symptom.
    let floored = |j: usize| j == NoiseSource::HeadingWhite.index() && opts.heading_floor_given();
    let clamped = |j: usize| !opts.eta_held[j] && !floored(j) && at_lower_clamp(fit.eta[j], opts.eta_bounds);
    if opts.fix_noise || !opts.research.choose_time_constants || !(0..NETA).any(clamped) {
        return Ok((fit, None, Vec::new()));
    }
    let row =
        |o: &EivOptions, m: f64| [o.noise.wheel_common_time_constant_s, o.noise.wheel_differential_time_constant_s, m];
    let mut slow_opts = opts.clone();
    slow_opts.noise.wheel_common_time_constant_s *= SLOW_COMMON_TIME_FACTOR;
    slow_opts.noise.wheel_differential_time_constant_s *= SLOW_DIFFERENTIAL_TIME_FACTOR;
    let prob = Problem::new(start.input, start.windows.clone(), &slow_opts);
    let first = row(opts, fit.ev.total.merit());
    let runaway = |eta: &[f64; 6]| eta.iter().any(|e| at_upper_clamp(*e, opts.eta_bounds));
    let eta0: [f64; 6] = std::array::from_fn(|j| if clamped(j) { 0.0 } else { fit.eta[j] });
    let theta_ref = fit.theta_reference();
    // A slow fit that fails numerically leaves the estimate as it was.
    let Ok(mut out) = scoring_pass(&prob, fit.theta, eta0, theta_ref, fit.free, PassStart::Later, &slow_opts) else {
        return Ok((fit, None, vec![first]));
    };
    if matches!(out.report.termination, Termination::MaxIterations { .. }) && !runaway(&out.eta) {
        if let Ok(again) = scoring_pass(&prob, out.theta, out.eta, theta_ref, fit.free, PassStart::Later, &slow_opts) {
            out = again;
        }
    }
    let slow = Fit {
        theta: out.theta,
        eta: out.eta,
        eta_sigma: out.eta_sigma,
        passes: vec![out.report],
        ev: out.eval,
        released: (Vec::new(), false),
        unobservable: fit.unobservable.clone(),
        start_ratios: fit.start_ratios,
        free: fit.free,
    };
    let slow = release_clamped(&prob, slow, &slow_opts)?;
    let costs = vec![first, row(&slow_opts, slow.ev.total.merit())];
    if slow.termination().converged() && !runaway(&slow.eta) && slow.ev.total.merit() < fit.ev.total.merit() {
        // The estimate's passes last; the first fit's stay in the report before them.
        let mut passes = fit.passes;
        passes.extend(slow.passes);
        Ok((Fit { passes, ..slow }, Some((prob, slow_opts)), costs))
    } else {
        let mut passes = slow.passes;
        passes.extend(fit.passes);
        Ok((Fit { passes, ..fit }, None, costs))
    }
}

/// The heading-drift test after the tied fit ([`super::heading_drift`]):
/// the fit that is the result (the tied one, or the separate one with its
/// pass appended), the test and the separate fit's problem and options
/// when it is the result. Where the tied fit is the result and holds the
/// heading drift at its floor, the test carries the fit without the floor
/// from `theta_start` ([`HeadingDriftTest::theta_without_floor`]).
#[inline(never)] // a symbol of its own for profiles (docs/performance.md)
fn heading_drift_test<'a>(
    prob: &Problem<'a>,
    fit: Fit,
    theta_start: &Theta,
    opts: &EivOptions,
) -> Result<(Fit, Option<HeadingDriftTest>, Option<SeparateModel<'a>>)> {
    if !heading_drift::applies(opts) {
        return Ok((fit, None, None));
    }
    let tied = TiedFit {
        theta: fit.theta,
        eta: fit.eta,
        theta_reference: fit.theta_reference(),
        free: fit.free,
        cost: fit.ev.total.merit(),
    };
    let (mut test, separate) = heading_drift::test(prob, &tied, opts)?;
    let Some(SeparateFit { model, pass }) = separate else {
        if heading_drift::held_at_floor(opts, tied.eta[NoiseSource::PoseDrift.index()]) {
            let o = heading_drift::options_without_floor(opts);
            let p = heading_drift::problem_at(prob, &o);
            // Its θ where it stopped: converged, or at its iteration limit on
            // the way (the floor's effect is then at least what it reached).
            test.theta_without_floor =
                run_passes(&p, theta_start, &o).and_then(|f| release_clamped(&p, f, &o)).ok().map(|f| f.theta);
            let e = p.evaluations.get();
            test.evaluations = [test.evaluations[0] + e[0], test.evaluations[1] + e[1]];
        }
        return Ok((fit, Some(test), None));
    };
    let mut passes = fit.passes;
    passes.push(pass.report);
    let sep = Fit {
        theta: pass.theta,
        eta: pass.eta,
        eta_sigma: pass.eta_sigma,
        free: fit.free,
        unobservable: fit.unobservable,
        start_ratios: fit.start_ratios,
        passes,
        ev: pass.eval,
        released: fit.released,
    };
    Ok((sep, Some(test), Some(model)))
}

/// A noise scale the fit ends at a clamp of `bounds` counts as held there:
/// σ 0, and outside θ's noise-estimate term and the joint Fisher inverse.
/// The fit keeps a clamped scale in its η step while its score points into
/// the range, so at the estimate such a scale has a σ exactly when its
/// score does; but the fit converged with the scale's step within the step
/// tolerance of that σ, so the estimate is the clamp whichever way the
/// score points, and at a boundary the Gaussian delta-method term does not
/// describe the estimate's spread. At the lower clamp (−20, the source
/// absent) the σ is not small in log units (35.6 for the per-wheel scale on
/// the 96 km length-series drive, more than the range of η) because the
/// variance is tiny: as a variance it is `σ_η e^η` = 7.3e-8 of the starting
/// model's, determined, and its term in θ's σ was 2e-8 of that σ.
fn hold_scales_at_clamps(eta_sigma: &mut [f64; 6], eta: &[f64; 6], bounds: [f64; 2]) {
    for (s, e) in eta_sigma.iter_mut().zip(eta) {
        if at_lower_clamp(*e, bounds) || at_upper_clamp(*e, bounds) {
            *s = 0.0;
        }
    }
}

/// The filter passes of the fit: the tied fit's, and the separate fit's
/// continuation when it is the result (its other passes are the test's).
fn evaluations_of(tied: &Problem<'_>, separate: Option<&SeparateModel<'_>>) -> [usize; 2] {
    let mut e = tied.evaluations.get();
    if let Some(s) = separate {
        let more = s.prob.evaluations.get();
        e = [e[0] + more[0], e[1] + more[1]];
    }
    e
}

/// θ's uncertainty at the estimate.
struct Uncertainty {
    /// The reported covariance ([`CovarianceEstimate`], plus the noise-estimate term).
    covariance: Matrix4<f64>,
    sigma: [f64; 4],
    sigma_sandwich: [f64; 4],
    sigma_block: [f64; 4],
    sigma_fisher: [f64; 4],
    sigma_noise_estimate: [f64; 4],
    theta_eta_sensitivity: [[f64; 6]; 4],
    /// The noise scales estimated (with a σ).
    eta_free: [bool; 6],
}

/// θ's covariance and σ of every kind ([`EivReport::sigma`] and the others).
#[inline(never)] // a symbol of its own for profiles (docs/performance.md)
fn uncertainty(prob: &Problem<'_>, fit: &Fit, opts: &EivOptions) -> Result<Uncertainty> {
    let (ev, free) = (&fit.ev, fit.free);
    let cov = free_inverse(&ev.total.h_theta, &free).unwrap_or_else(|| Matrix4::from_element(f64::NAN));
    let sandwich = cov * ev.total.opg * cov;
    let sigma_sandwich: [f64; 4] = free_sigma(&free, |i| sandwich[(i, i)]);
    let sigma_block: [f64; 4] = match ev.total.blocks.meat() {
        Some(b) => {
            let c = cov * b * cov;
            free_sigma(&free, |i| c[(i, i)])
        }
        None => [f64::NAN; 4],
    };
    let cov_reported = match opts.research.covariance_estimate {
        CovarianceEstimate::Model => cov,
        CovarianceEstimate::LargerOfModelAndBlock => inflate_to_block(&cov, &ev.total.blocks),
    };
    let eta_free: [bool; 6] = std::array::from_fn(|j| !opts.fix_noise && fit.eta_sigma[j] > 0.0);
    let any_eta = eta_free.iter().any(|f| *f);
    let (noise_cov, theta_eta_sensitivity) = match opts.research.noise_estimate_term {
        NoiseEstimateTerm::Observed if any_eta => {
            let theta_ref = fit.theta_reference();
            let follows = opts.research.covariance == CovarianceMode::FollowsTheta;
            let by_symmetry = prob.mixed_partials_by_symmetry();
            noise_estimate_covariance(
                prob,
                &fit.theta,
                &theta_ref,
                &fit.eta,
                &eta_free,
                &ev.total,
                &cov,
                follows,
                by_symmetry,
            )?
        }
        _ => (Matrix4::zeros(), [[0.0; 6]; 4]),
    };
    let sigma_noise_estimate: [f64; 4] = free_sigma(&free, |i| noise_cov[(i, i)]);
    let covariance = cov_reported + noise_cov;
    let sigma: [f64; 4] = free_sigma(&free, |i| covariance[(i, i)]);
    let sigma_fisher: [f64; 4] = match fisher_covariance(&ev.total.info, &free, &eta_free) {
        Some(c) => free_sigma(&free, |i| c[(i, i)]),
        None => [f64::NAN; 4],
    };
    Ok(Uncertainty {
        covariance,
        sigma,
        sigma_sandwich,
        sigma_block,
        sigma_fisher,
        sigma_noise_estimate,
        theta_eta_sensitivity,
        eta_free,
    })
}

/// The fit's own warnings: unobservable parameters, no convergence, noise
/// scales at their upper clamp.
fn fit_warnings(fit: &Fit, opts: &EivOptions) -> Vec<EivWarning> {
    let mut warnings = Vec::new();
    if !fit.unobservable.is_empty() {
        warnings.push(EivWarning::Unobservable { parameters: fit.unobservable.clone() });
    }
    let termination = fit.termination();
    if !termination.converged() {
        warnings.push(EivWarning::NotConverged { termination });
    }
    if !opts.fix_noise {
        for j in 0..NETA {
            if at_upper_clamp(fit.eta[j], opts.eta_bounds) {
                warnings.push(EivWarning::NoiseAtUpperClamp { source: NOISE_SOURCES[j], eta: fit.eta[j] });
            }
        }
    }
    warnings
}

/// The noise model at the estimate, as reported: the starting model scaled
/// by η, with the held variances (a given quantisation level, stated
/// lateral noise) as the model states them.
fn reported_noise(opts: &EivOptions, eta: &[f64; 6]) -> NoiseModel {
    let mut n = opts.noise.scaled(eta);
    if opts.research.position_drift_own_scale {
        let heading = if opts.heading_scale == HeadingScale::Separate { eta[5] } else { eta[3] };
        n.heading_drift_sigma_rad = opts.noise.heading_drift_sigma_rad * (0.5 * heading).exp();
    } else if eta[4] < opts.research.heading_drift_min_eta {
        n.heading_drift_sigma_rad =
            opts.noise.heading_drift_sigma_rad * (0.5 * opts.research.heading_drift_min_eta).exp();
    }
    if opts.quantisation_level == QuantisationLevel::Given {
        n.quantisation_step_rev_per_s = opts.noise.quantisation_step_rev_per_s;
    }
    if opts.lateral_noise == LateralNoise::Stated {
        n.lateral_acceleration_sigma_m_per_s2 = opts.noise.lateral_acceleration_sigma_m_per_s2;
        n.sideslip_sigma_rad = opts.noise.sideslip_sigma_rad;
    }
    if let Some(sigma) = opts.research.a_y_sigma_held {
        n.lateral_acceleration_sigma_m_per_s2 = sigma;
    }
    if let Some(floor) = opts.research.a_y_sigma_floor.filter(|_| opts.a_y_tied()) {
        n.lateral_acceleration_sigma_m_per_s2 = n.lateral_acceleration_sigma_m_per_s2.max(floor);
    }
    if let Some(floor) = opts.research.heading_white_sigma_floor.filter(|_| opts.heading_floor_given()) {
        n.heading_white_sigma_rad = n.heading_white_sigma_rad.hypot(floor);
    }
    n
}

/// Every window's consistency numbers ([`WindowDiagnostics`]), with their
/// warnings pushed to `warnings`. With
/// [`InnovationNull::FloorsAsRegularisation`] the null comes from one more
/// (objective-only) filter pass at the estimate, with the recursion of the
/// floor-free null.
#[inline(never)] // a symbol of its own for profiles (docs/performance.md)
fn window_diagnostics(
    prob: &Problem<'_>,
    fit: &Fit,
    opts: &EivOptions,
    warnings: &mut Vec<EivWarning>,
) -> Result<Vec<WindowDiagnostics>> {
    let null_sums = match opts.research.innovation_null {
        InnovationNull::FittedModel => None,
        InnovationNull::FloorsAsRegularisation => {
            let theta_ref = fit.theta_reference();
            let mode = Mode::cost(opts.research.covariance == CovarianceMode::FollowsTheta);
            Some(prob.evaluate_with(&fit.theta, &theta_ref, &fit.eta, mode, true)?.windows)
        }
    };
    let mut diags = Vec::with_capacity(prob.windows.len());
    for (i, (w, s)) in prob.windows.iter().zip(&fit.ev.windows).enumerate() {
        let nis = if s.updates > 0 { s.quad / (3 * s.updates) as f64 } else { f64::NAN };
        let lag1: [f64; 3] = std::array::from_fn(|c| if s.e2[c] > 0.0 { s.lag1[c] / s.e2[c] } else { 0.0 });
        let (nis0, lag1_0) = match null_sums.as_ref().and_then(|n| n.get(i)) {
            Some(n) if n.updates > 0 => (
                n.quad_null / (3 * n.updates) as f64,
                std::array::from_fn(|c| if n.e2_null[c] > 0.0 { n.lag1_null[c] / n.e2_null[c] } else { 0.0 }),
            ),
            _ => (1.0, [0.0; 3]),
        };
        if s.updates > 0 {
            window_warnings(w, nis, nis0, &lag1, &lag1_0, opts, warnings);
        }
        diags.push(WindowDiagnostics {
            window: *w,
            updates: s.updates,
            nis,
            lag1,
            nis_without_floors: nis0,
            lag1_without_floors: lag1_0,
        });
    }
    Ok(diags)
}

/// The warnings of one window: NIS above the divergence limit or outside
/// its band, lag-1 correlation of a component beyond its null.
fn window_warnings(
    w: &Window,
    nis: f64,
    nis0: f64,
    lag1: &[f64; 3],
    lag1_0: &[f64; 3],
    opts: &EivOptions,
    warnings: &mut Vec<EivWarning>,
) {
    let band = [opts.nis_band[0] * nis0.min(1.0), opts.nis_band[1] * nis0.max(1.0)];
    if nis > opts.divergence_nis {
        warnings.push(EivWarning::FilterDiverged { window: w.index, nis, threshold: opts.divergence_nis });
    } else if !(band[0]..=band[1]).contains(&nis) {
        warnings.push(EivWarning::InconsistentInnovations { window: w.index, nis, band });
    }
    let comps = [PoseComponent::X, PoseComponent::Y, PoseComponent::Heading];
    for c in 0..3 {
        let (above, below) = (lag1[c] - lag1_0[c].max(0.0), lag1_0[c].min(0.0) - lag1[c]);
        let below_limit = match opts.research.innovation_null {
            InnovationNull::FittedModel => opts.max_lag1,
            InnovationNull::FloorsAsRegularisation => opts.max_lag1_below,
        };
        if above > opts.max_lag1 || below > below_limit {
            warnings.push(EivWarning::CorrelatedInnovations {
                window: w.index,
                component: comps[c],
                lag1: lag1[c],
                expected: lag1_0[c],
                threshold: if above > opts.max_lag1 { opts.max_lag1 } else { below_limit },
            });
        }
    }
}

/// θ from each half of the windows (split by measurement updates), one
/// scoring step from the joint estimate.
pub(super) fn halves_check(
    ev: &Evaluation,
    theta: &Theta,
    free: &[bool; 4],
    follows: bool,
    estimate: CovarianceEstimate,
) -> Option<HalvesCheck> {
    if ev.windows.len() < 2 {
        return None;
    }
    let total = ev.total.updates;
    let mut first = WindowSums::zero();
    let mut second = WindowSums::zero();
    let mut acc = 0usize;
    for w in &ev.windows {
        if acc * 2 < total {
            first.add(w);
        } else {
            second.add(w);
        }
        acc += w.updates;
    }
    let (s1, sd1) = theta_step(&first, free, follows).ok()?;
    let (s2, sd2) = theta_step(&second, free, follows).ok()?;
    let robust = |sums: &WindowSums, sd: [f64; 4]| -> [f64; 4] {
        match (estimate, free_inverse(&sums.h_theta, free)) {
            (CovarianceEstimate::LargerOfModelAndBlock, Some(c)) => {
                let r = inflate_to_block(&c, &sums.blocks);
                std::array::from_fn(|i| r[(i, i)].max(0.0).sqrt())
            }
            _ => sd,
        }
    };
    let (sd1, sd2) = (robust(&first, sd1), robust(&second, sd2));
    let t1 = theta_add(theta, &s1, 1.0);
    let t2 = theta_add(theta, &s2, 1.0);
    let (a1, a2) = (t1.to_array(), t2.to_array());
    let z = std::array::from_fn(|i| {
        let v = sd1[i] * sd1[i] + sd2[i] * sd2[i];
        if free[i] && v > 0.0 {
            (a1[i] - a2[i]) / v.sqrt()
        } else {
            0.0
        }
    });
    Some(HalvesCheck { first: t1, second: t2, z })
}
