//! Estimation of the Gauss-Markov time constants (wheel τ_c, τ_w and the
//! reference drift τ) with the noise scales: a profile of the Gaussian
//! marginal likelihood over a grid in log τ.
//!
//! Why a profile and not exact derivatives. `a = exp(−t_s/τ)` enters the
//! transition of the s and b states, so `∂x̂/∂τ`, `∂ν/∂τ`, `∂P/∂τ` and
//! `∂S/∂τ` would have to be carried through the filter as three more
//! sensitivity columns (the parameter vector of `filter` from 10 to 13,
//! every sensitivity matrix and the covariance-derivative recursion with
//! it, and the default path paying for the larger fixed-size types). The
//! likelihood is smooth and, per coordinate, unimodal in log τ over the
//! measured range; a coordinate search over a coarse log grid with one
//! parabolic refinement per coordinate finds its minimum with a handful of
//! fits, each of which re-estimates θ and η exactly as [`super::estimate`].
//!
//! Objective. Each candidate τ is fitted as usual (θ by the profile cost, η
//! by the marginal likelihood); the candidate's score is the Gaussian
//! negative log-likelihood `½ Σ (νᵀS⁻¹ν + log det S)` at its estimate (the
//! marginal likelihood η maximises, without the coloured-noise correction,
//! which is not part of the data's density). The best candidate's fit is
//! returned as is: with time constants estimated the report's θ, η and
//! covariance are those of a fit at the chosen τ (the τ uncertainty is not
//! propagated into θ's covariance), and so are its iteration and
//! evaluation counters; `timing_s` is the whole search's.
//!
//! Measured (docs/study.md, EIV section): the search does not make EIV with
//! estimated noise match the known model, and on a perfect reference it
//! follows a degenerate likelihood to τ_wheel ≈ 0.06 s; opt-in diagnostic.

use serde::{Deserialize, Serialize};

use super::{estimate_from, BiasCorrection, EivInput, EivOptions, EivReport};
use crate::error::{Error, Result};
use crate::model::Theta;

/// The range every time constant is clamped to, s.
pub const TIME_CONSTANT_RANGE_S: [f64; 2] = [0.05, 600.0];

/// Candidates of the time-constant search ([`EivOptions::estimate_time_constants`]).
///
/// Coordinate search: the wheel time constant(s) over `wheel_s` (the drift
/// at the starting model's value), then the drift over `drift_s` at the best
/// wheel value. Per coordinate the grid is extended by its outermost
/// spacing (at most `max_extensions` times, within
/// [`TIME_CONSTANT_RANGE_S`]) while the best candidate is at an end, and
/// with `refine` one more fit is made at the vertex of the parabola in
/// log τ through the best candidate and its two neighbours. Each candidate
/// is one full fit (θ and η), warm-started from the best so far: with the
/// defaults 7–9 fits per drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TimeConstantGrid {
    /// Candidate wheel time constants, s (ascending). Default
    /// `[0.25, 1, 4, 16]`.
    pub wheel_s: Vec<f64>,
    /// Candidate reference-drift time constants, s (ascending). Default
    /// `[25, 100, 400]`.
    pub drift_s: Vec<f64>,
    /// One time constant for the common and the per-wheel process (τ_c =
    /// τ_w). Otherwise τ_c and then τ_w are searched over `wheel_s` one after
    /// the other (two coordinates). Default true.
    pub shared_wheel: bool,
    /// Search the drift time constant too (otherwise it keeps the starting
    /// model's value). Default true.
    pub search_drift: bool,
    /// Parabolic refinement per coordinate. Default true.
    pub refine: bool,
    /// Grid extensions per coordinate and side while the best candidate is
    /// at an end of the grid. Default 1.
    pub max_extensions: usize,
    /// A candidate replaces the best only if it lowers the negative
    /// log-likelihood by more than this (a flat likelihood, as for a noise
    /// source that is absent, keeps the first candidate). Default 0.01.
    pub min_improvement: f64,
}

impl Default for TimeConstantGrid {
    fn default() -> Self {
        TimeConstantGrid {
            wheel_s: vec![0.25, 1.0, 4.0, 16.0],
            drift_s: vec![25.0, 100.0, 400.0],
            shared_wheel: true,
            search_drift: true,
            refine: true,
            max_extensions: 1,
            min_improvement: 0.01,
        }
    }
}

impl TimeConstantGrid {
    /// Checks the grid, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: String| Err(Error::InvalidOption { field, reason });
        let [lo, hi] = TIME_CONSTANT_RANGE_S;
        for (field, g) in [("time_constant_grid.wheel_s", &self.wheel_s), ("time_constant_grid.drift_s", &self.drift_s)]
        {
            if g.is_empty() {
                return bad(field, "needs at least one candidate".into());
            }
            if g.iter().any(|t| !(t.is_finite() && (lo..=hi).contains(t))) {
                return bad(field, format!("candidates must lie in [{lo}, {hi}] s, got {g:?}"));
            }
            if g.windows(2).any(|w| w[1] <= w[0]) {
                return bad(field, format!("candidates must be strictly ascending, got {g:?}"));
            }
        }
        if !(self.min_improvement.is_finite() && self.min_improvement >= 0.0) {
            return bad("time_constant_grid.min_improvement", format!("must be >= 0, got {}", self.min_improvement));
        }
        Ok(())
    }
}

/// One fit of the time-constant search.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeConstantCandidate {
    /// `[τ_c, τ_w, τ_drift]`, s.
    pub time_constants_s: [f64; 3],
    /// `½ Σ (νᵀS⁻¹ν + log det S)` at the candidate's estimate (NaN when the fit failed).
    pub neg_log_likelihood: f64,
    /// The candidate's θ.
    pub theta: Theta,
    /// Whether the candidate's fit converged.
    pub converged: bool,
    /// Wall time of the candidate's fit, s.
    pub timing_s: f64,
}

/// The result of the time-constant search (units: s).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TimeConstantFit {
    /// Chosen common-mode wheel time constant τ_c.
    pub wheel_common_s: f64,
    /// Chosen per-wheel time constant τ_w.
    pub wheel_differential_s: f64,
    /// Chosen reference-drift time constant.
    pub drift_s: f64,
    /// The starting model's `[τ_c, τ_w, τ_drift]`.
    pub start_s: [f64; 3],
    /// The chosen value is at an end of the (extended) grid of its
    /// coordinate (`[wheel common, wheel differential, drift]`): the
    /// likelihood may keep falling beyond it (or be flat).
    pub at_grid_end: [bool; 3],
    /// Every fit, in search order.
    pub candidates: Vec<TimeConstantCandidate>,
}

struct Best {
    tau: [f64; 3],
    nll: f64,
    report: EivReport,
}

struct Search<'a, 'b> {
    input: &'a EivInput<'b>,
    theta_start: Theta,
    inner: EivOptions,
    candidates: Vec<TimeConstantCandidate>,
    best: Option<Best>,
    min_improvement: f64,
}

impl Search<'_, '_> {
    /// Fits at `tau` (cached), warm-started from the best so far, and makes
    /// it the best if it improves by more than `min_improvement`. Returns
    /// its negative log-likelihood (NaN when the fit failed).
    fn fit(&mut self, tau: [f64; 3]) -> Result<f64> {
        if let Some(c) = self.candidates.iter().find(|c| same3(c.time_constants_s, tau)) {
            return Ok(c.neg_log_likelihood);
        }
        let mut opts = self.inner.clone();
        opts.noise.wheel_common_time_constant_s = tau[0];
        opts.noise.wheel_differential_time_constant_s = tau[1];
        opts.noise.drift_time_constant_s = tau[2];
        let (theta0, eta0) = match &self.best {
            Some(b) => (b.report.theta, b.report.eta),
            None => (self.theta_start, [0.0; 6]),
        };
        let t = std::time::Instant::now();
        let out = estimate_from(self.input, &theta0, &eta0, &opts);
        let timing_s = t.elapsed().as_secs_f64();
        let (nll, theta, converged, report) = match out {
            Ok((r, nll)) if nll.is_finite() => (nll, r.theta, r.termination.converged(), Some(r)),
            Ok((r, _)) => (f64::NAN, r.theta, false, None),
            // A numerical failure at one candidate disqualifies the candidate only;
            // invalid input fails the same way at every candidate.
            Err(Error::Numerical(_)) => (f64::NAN, theta0, false, None),
            Err(e) => return Err(e),
        };
        self.candidates.push(TimeConstantCandidate {
            time_constants_s: tau,
            neg_log_likelihood: nll,
            theta,
            converged,
            timing_s,
        });
        if let Some(r) = report {
            let better = match &self.best {
                None => true,
                Some(b) => nll < b.nll - self.min_improvement,
            };
            if better {
                self.best = Some(Best { tau, nll, report: r });
            }
        }
        Ok(nll)
    }

    /// Coordinate `k` of τ over `grid` (plus extensions and refinement),
    /// the other coordinates at the best's (or `base`'s) values; `tie_wheel`
    /// sets τ_c = τ_w. Returns whether the chosen value is at a grid end.
    fn coordinate(
        &mut self,
        base: [f64; 3],
        k: usize,
        grid: &TimeConstantGrid,
        values: &[f64],
        tie_wheel: bool,
    ) -> Result<bool> {
        let place = |b: [f64; 3], v: f64| {
            let mut t = b;
            t[k] = v;
            if tie_wheel {
                t[0] = v;
                t[1] = v;
            }
            t
        };
        let [lo, hi] = TIME_CONSTANT_RANGE_S;
        let start = self.best.as_ref().map_or(base, |b| b.tau);
        let mut xs: Vec<f64> = values.to_vec();
        if self.best.is_some() && !xs.iter().any(|x| same(*x, start[k])) {
            // The best so far lies on this coordinate's line too.
            xs.push(start[k]);
            xs.sort_by(f64::total_cmp);
        }
        for &v in values {
            self.fit(place(start, v))?;
        }
        let chosen = |s: &Self| s.best.as_ref().map(|b| b.tau[k]);
        // Extend while the best is at an end.
        for _ in 0..grid.max_extensions {
            let Some(c) = chosen(self) else { break };
            let n = xs.len();
            let next = if n >= 2 && same(c, xs[0]) {
                (xs[0] * xs[0] / xs[1]).max(lo)
            } else if n >= 2 && same(c, xs[n - 1]) {
                (xs[n - 1] * xs[n - 1] / xs[n - 2]).min(hi)
            } else {
                break;
            };
            if xs.iter().any(|x| same(*x, next)) {
                break;
            }
            self.fit(place(start, next))?;
            xs.push(next);
            xs.sort_by(f64::total_cmp);
        }
        let Some(c) = chosen(self) else { return Ok(false) };
        let i = xs.iter().position(|x| same(*x, c));
        let at_end = match i {
            Some(i) => xs.len() < 3 || i == 0 || i == xs.len() - 1,
            None => false,
        };
        if grid.refine && !at_end {
            if let Some(i) = i {
                let nll_at = |s: &Self, v: f64| {
                    let t = place(start, v);
                    s.candidates.iter().find(|c| same3(c.time_constants_s, t)).map(|c| c.neg_log_likelihood)
                };
                let (x0, x1, x2) = (xs[i - 1].ln(), xs[i].ln(), xs[i + 1].ln());
                if let (Some(f0), Some(f1), Some(f2)) =
                    (nll_at(self, xs[i - 1]), nll_at(self, xs[i]), nll_at(self, xs[i + 1]))
                {
                    if let Some(x) = parabola_vertex([x0, x1, x2], [f0, f1, f2]) {
                        let v = round_significant(x.exp(), 3).clamp(lo, hi);
                        if (x - x1).abs() > 0.05 {
                            self.fit(place(start, v))?;
                        }
                    }
                }
            }
        }
        Ok(at_end)
    }
}

/// The same grid value (candidates are copied from the grid, so equal up to round-off at most).
fn same(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-12 * a.abs().max(b.abs())
}

fn same3(a: [f64; 3], b: [f64; 3]) -> bool {
    (0..3).all(|k| same(a[k], b[k]))
}

/// `x` rounded to `digits` significant digits (refined time constants are
/// reported as such, not as the parabola's full-precision vertex).
fn round_significant(x: f64, digits: i32) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return x;
    }
    let scale = 10f64.powi(digits - 1 - x.log10().floor() as i32);
    (x * scale).round() / scale
}

/// The vertex of the parabola through three points (None unless it is a
/// minimum strictly inside `[x_0, x_2]`).
pub(crate) fn parabola_vertex(x: [f64; 3], f: [f64; 3]) -> Option<f64> {
    let d01 = (f[1] - f[0]) / (x[1] - x[0]);
    let d12 = (f[2] - f[1]) / (x[2] - x[1]);
    let curv = (d12 - d01) / (x[2] - x[0]);
    if !(curv.is_finite() && curv > 0.0) {
        return None;
    }
    // f = f1 + d·(x − x1) + curv·(x − x1)², with d the slope at x1.
    let slope = d01 + curv * (x[1] - x[0]);
    let v = x[1] - slope / (2.0 * curv);
    (v > x[0] && v < x[2]).then_some(v)
}

/// [`super::estimate`] with [`EivOptions::estimate_time_constants`].
pub(crate) fn estimate_with_time_constants(
    input: &EivInput<'_>,
    theta_start: &Theta,
    opts: &EivOptions,
) -> Result<EivReport> {
    let t0 = std::time::Instant::now();
    opts.validate()?;
    let grid = &opts.time_constant_grid;
    // The candidates are compared by likelihood alone: the η term of the
    // covariance (about ten filter passes) is computed once, for the chosen
    // time constants, by the re-fit below.
    let inner = EivOptions {
        estimate_time_constants: false,
        bias_correction: BiasCorrection::None,
        noise_estimate_in_covariance: false,
        ..opts.clone()
    };
    let n = &opts.noise;
    let start = [n.wheel_common_time_constant_s, n.wheel_differential_time_constant_s, n.drift_time_constant_s];
    let mut s = Search {
        input,
        theta_start: *theta_start,
        inner,
        candidates: Vec::new(),
        best: None,
        min_improvement: grid.min_improvement,
    };
    let mut at_end = [false; 3];
    if grid.shared_wheel {
        let e = s.coordinate(start, 0, grid, &grid.wheel_s, true)?;
        at_end[0] = e;
        at_end[1] = e;
    } else {
        at_end[0] = s.coordinate(start, 0, grid, &grid.wheel_s, false)?;
        at_end[1] = s.coordinate(start, 1, grid, &grid.wheel_s, false)?;
    }
    if grid.search_drift {
        at_end[2] = s.coordinate(start, 2, grid, &grid.drift_s, false)?;
    }
    let Some(best) = s.best else {
        return Err(Error::Numerical("EIV: the filter failed at every candidate time constant".into()));
    };
    let fit = TimeConstantFit {
        wheel_common_s: best.tau[0],
        wheel_differential_s: best.tau[1],
        drift_s: best.tau[2],
        start_s: start,
        at_grid_end: at_end,
        candidates: s.candidates,
    };
    // The η term needs the re-fit only when some scale was estimated (not
    // held at a clamp: σ > 0, as in the fit's own η term); else it is zero.
    let eta_term =
        opts.noise_estimate_in_covariance && !opts.fix_noise && best.report.eta_sigma.iter().any(|s| *s > 0.0);
    let mut report = if opts.bias_correction == BiasCorrection::None && !eta_term {
        best.report
    } else {
        // The correction at the chosen time constants (its replicates keep
        // them fixed) and the η term of the covariance, from the best
        // candidate's θ and η.
        let mut o = EivOptions { estimate_time_constants: false, ..opts.clone() };
        o.noise.wheel_common_time_constant_s = fit.wheel_common_s;
        o.noise.wheel_differential_time_constant_s = fit.wheel_differential_s;
        o.noise.drift_time_constant_s = fit.drift_s;
        estimate_from(input, &best.report.theta, &best.report.eta, &o)?.0
    };
    report.initial_theta = *theta_start;
    report.time_constants = Some(fit);
    report.timing_s = t0.elapsed().as_secs_f64();
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, NoiseOptions, SimOptions};

    #[test]
    fn parabola_vertex_is_the_minimum_of_a_quadratic() {
        let f = |x: f64| 3.0 * (x - 0.7).powi(2) - 2.0;
        let x = [0.0, 1.0, 2.5];
        let v = parabola_vertex(x, x.map(f)).expect("vertex");
        assert!((v - 0.7).abs() < 1e-12, "{v}");
        // A maximum or a vertex outside the bracket is no answer.
        assert!(parabola_vertex(x, x.map(|x| -f(x))).is_none());
        assert!(parabola_vertex([0.0, 1.0, 2.0], [0.0, 1.0, 2.5]).is_none());
        assert!(same(round_significant(1.99777, 3), 2.0));
        assert!(same(round_significant(47.7612, 3), 47.8));
    }

    #[test]
    fn grid_validation_names_the_field() {
        let g = TimeConstantGrid { wheel_s: vec![1.0, 0.5], ..Default::default() };
        let e = g.validate().expect_err("unsorted");
        assert!(e.to_string().contains("wheel_s"), "{e}");
        let g = TimeConstantGrid { drift_s: vec![10.0, 1000.0], ..Default::default() };
        assert!(g.validate().expect_err("out of range").to_string().contains("drift_s"));
        let g = TimeConstantGrid { wheel_s: vec![], ..Default::default() };
        assert!(g.validate().is_err());
        assert!(TimeConstantGrid::default().validate().is_ok());
        let o = EivOptions { estimate_time_constants: true, time_constant_grid: g, ..Default::default() };
        assert!(o.validate().is_err());
    }

    /// Strong coloured wheel noise (1 %, τ = 5 s) on a perfect reference,
    /// its σ known: the marginal likelihood picks τ = 5 s out of
    /// {0.5, 5, 50} s, the report carries the chosen value and the search's
    /// candidates, and the chosen candidate has the smallest score.
    #[test]
    fn search_recovers_the_wheel_time_constant() {
        let noise = NoiseOptions {
            wheel_coloured_rel_sigma: 0.01,
            wheel_coloured_differential_rel_sigma: 0.002,
            wheel_coloured_time_constant_s: 5.0,
            ..NoiseOptions::coloured_wheels_only()
        };
        let out = simulate(&SimOptions { length_km: 2.0, noise: noise.clone(), ..SimOptions::paper(5) }).expect("sim");
        let d = &out.drive;
        let input = EivInput::from_drive(d);
        let known = super::super::NoiseModel::from_sim(&noise, d.sample_time_s());
        let start_model = super::super::NoiseModel {
            wheel_common_time_constant_s: 0.25,
            wheel_differential_time_constant_s: 0.25,
            ..known
        };
        let opts = EivOptions {
            noise: start_model,
            fix_noise: true,
            estimate_time_constants: true,
            time_constant_grid: TimeConstantGrid {
                wheel_s: vec![0.5, 5.0, 50.0],
                search_drift: false,
                refine: false,
                max_extensions: 0,
                ..Default::default()
            },
            ..Default::default()
        };
        let r = super::super::estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
        let fit = r.time_constants.as_ref().expect("time constants reported");
        let scores: Vec<String> =
            fit.candidates.iter().map(|c| format!("{:?}: {:.2}", c.time_constants_s, c.neg_log_likelihood)).collect();
        assert_eq!(fit.candidates.len(), 3, "{scores:?}");
        assert!(same(fit.wheel_common_s, 5.0), "{scores:?}");
        assert!(same(fit.wheel_differential_s, 5.0));
        assert!(same(r.noise.wheel_common_time_constant_s, 5.0));
        assert!(same(r.noise.drift_time_constant_s, start_model.drift_time_constant_s));
        assert!(same3(fit.start_s, [0.25, 0.25, start_model.drift_time_constant_s]));
        let best = fit.candidates.iter().map(|c| c.neg_log_likelihood).fold(f64::INFINITY, f64::min);
        let chosen = fit.candidates.iter().find(|c| same(c.time_constants_s[0], 5.0)).expect("chosen");
        assert!(same(chosen.neg_log_likelihood, best), "{scores:?}");
        assert_eq!(chosen.theta, r.theta);
        assert_eq!(fit.at_grid_end, [false, false, false]);
    }

    /// With η estimated, the candidates are fitted without the η term of
    /// the covariance and the chosen one is re-fitted with it: a search
    /// with one candidate, the start's time constants, reports the σ (η
    /// term included) and θ of a plain fit at those time constants.
    #[test]
    fn the_eta_term_is_added_for_the_chosen_time_constants() {
        let out = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(2) }).expect("sim");
        let input = EivInput::from_drive(&out.drive);
        let mut noise = super::super::NoiseModel::default();
        noise.wheel_differential_time_constant_s = noise.wheel_common_time_constant_s;
        let plain = EivOptions { noise, ..Default::default() };
        let direct = super::super::estimate(&input, &out.sidecar.theta_true, &plain).expect("eiv");
        let grid = TimeConstantGrid {
            wheel_s: vec![noise.wheel_common_time_constant_s],
            search_drift: false,
            refine: false,
            max_extensions: 0,
            ..Default::default()
        };
        let opts = EivOptions { estimate_time_constants: true, time_constant_grid: grid, ..plain };
        let r = super::super::estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
        assert_eq!(r.time_constants.as_ref().map(|f| f.candidates.len()), Some(1));
        assert!(r.sigma_noise_estimate.iter().any(|s| *s > 0.0), "{:?}", r.sigma_noise_estimate);
        for i in 0..4 {
            let (a, b) = (r.sigma[i], direct.sigma[i]);
            assert!((a - b).abs() <= 1e-3 * b, "σ {i}: {a:e} vs {b:e}");
            let (a, b) = (r.sigma_noise_estimate[i], direct.sigma_noise_estimate[i]);
            assert!((a - b).abs() <= 1e-2 * b.max(1e-12), "η-term σ {i}: {a:e} vs {b:e}");
            let (a, b) = (r.theta.to_array()[i], direct.theta.to_array()[i]);
            assert!((a - b).abs() <= 1e-2 * direct.sigma[i], "θ {i}: {a} vs {b}");
        }
    }
}
