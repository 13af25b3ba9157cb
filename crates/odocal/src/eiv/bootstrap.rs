//! Parametric bootstrap of the EIV estimate: re-simulate the fitted noise
//! on the drive's own inputs at the fitted θ, re-fit, B times.
//!
//! Replicate world b (its own seeded random stream, so the result does not
//! depend on the number of threads):
//! - true inputs: the drive's measured wheel rotations, a_y and β
//!   ([`BootstrapInputs::Measured`], the default) or their moving averages
//!   ([`BootstrapInputs::Smoothed`]);
//! - true poses: the model rolled out at θ̂ from the reference pose at the
//!   start of each part (dead reckoning; the replicate's "truth");
//! - measured wheel rotations `n·(1 + s_c + s_w + ε)` with s_c, s_w
//!   Gauss-Markov and ε white at the fitted σ and the model's time
//!   constants, then an encoder of step q (random phase);
//! - measured a_y + white σ_a, β + Gauss-Markov σ_β;
//! - reference poses: truth + Gauss-Markov drift + white noise.
//!
//! With [`BootstrapOptions::antithetic`] replicates 2j and 2j + 1 share
//! stream j, the second with every Gaussian draw negated: each is still a
//! draw of the fitted model, and the pair's mean cancels the part of the
//! fit's error that is odd in the noise.
//!
//! Each replicate is fitted with the same options as the original fit
//! (same starting noise model, same `fix_noise`), from θ̂, with the
//! original's free parameters (but without a bootstrap bias correction,
//! `super::BiasCorrection::Bootstrap`, inside). The spread of the replicates estimates the
//! estimator's sampling distribution; their mean minus θ̂ its bias (at θ̂
//! and the fitted noise), which gives the bias-corrected estimate
//! `θ̂ − bias`.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::estimate::one_step;
use super::{
    estimate, BiasCorrection, EivInput, EivOptions, EivReport, InnovationNull, NoiseEstimateTerm, NoiseModel,
    ResearchOptions,
};
use crate::error::{Error, Result};
use crate::model::{step, Input, State, Theta};

/// Declares [`BootstrapOptions`] with the replicate worlds' design at
/// visibility `$vis`: public with the `research` feature, crate-private
/// without it.
macro_rules! bootstrap_options {
    ($vis:vis) => {
        /// Options of `bootstrap`: the replicates, their seed and the intervals'
        /// level (the replicate worlds' design is research-only, feature
        /// `research`).
        #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
        #[serde(default)]
        pub struct BootstrapOptions {
            /// Number of replicates B. Default 50.
            pub replicates: usize,
            /// Seed of the replicates' random streams. Default 0.
            pub seed: u64,
            /// Coverage of the percentile intervals. Default 0.95.
            pub level: f64,
            /// The true inputs of the replicate worlds. Default
            /// `BootstrapInputs::Measured`.
            $vis true_inputs: BootstrapInputs,
            /// Antithetic pairs: replicates 2j and 2j + 1 share one random stream
            /// with every Gaussian draw's sign flipped in the second, and the bias
            /// is the mean of the pairs' means (`replicates` must then be even).
            /// Each replicate is still a draw of the fitted noise model; the pair's
            /// mean cancels the part of the estimator's error that is odd in the
            /// noise (to first order all of its spread) and keeps the even part,
            /// whose mean is the bias. Default false.
            $vis antithetic: bool,
            /// How each replicate is re-fitted. Default `BootstrapRefit::Converged`.
            $vis refit: BootstrapRefit,
        }
    };
}

#[cfg(feature = "research")]
bootstrap_options!(pub);
#[cfg(not(feature = "research"))]
bootstrap_options!(pub(crate));

research_pub! {
    /// How `bootstrap` re-fits a replicate.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    enum BootstrapRefit {
        /// `estimate` to convergence, from θ̂.
        #[default]
        Converged,
        /// One Fisher-scoring step from θ̂: a single filter pass per replicate
        /// instead of two or more (the "k-step bootstrap" with k = 1). With the
        /// noise model held (`EivOptions::fix_noise`) and the covariance
        /// following θ only; otherwise, and where the step leaves the valid
        /// range of θ, the replicate is fitted to convergence. A replicate
        /// whose converged fit takes one full step (the usual case from θ̂) gets
        /// the same θ to the bit; elsewhere the later steps are left out. What
        /// the bias correction (`EivOptions::correct_bias`) uses; measured
        /// against converged replicates in crates/odocal-lab/PERFORMANCE.md.
        OneStep,
    }
}

impl BootstrapOptions {
    /// Checks the options.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] for fewer than 2 replicates, a level outside
    /// (0, 1), an odd number of antithetic replicates or a zero smoothing
    /// half-width.
    fn validate(&self) -> Result<()> {
        if self.replicates < 2 {
            return Err(Error::InvalidOption { field: "replicates", reason: "must be at least 2".into() });
        }
        if !(self.level > 0.0 && self.level < 1.0) {
            return Err(Error::InvalidOption {
                field: "level",
                reason: format!("must be in (0, 1), got {}", self.level),
            });
        }
        if self.antithetic && !self.replicates.is_multiple_of(2) {
            return Err(Error::InvalidOption {
                field: "replicates",
                reason: format!("antithetic pairs need an even number of replicates, got {}", self.replicates),
            });
        }
        if let BootstrapInputs::Smoothed { half_width_samples: 0 } = self.true_inputs {
            return Err(Error::InvalidOption {
                field: "true_inputs",
                reason: "the smoothing half-width must be at least 1 sample".into(),
            });
        }
        Ok(())
    }
}

impl Default for BootstrapOptions {
    fn default() -> Self {
        BootstrapOptions {
            replicates: 50,
            seed: 0,
            level: 0.95,
            true_inputs: BootstrapInputs::Measured,
            antithetic: false,
            refit: BootstrapRefit::Converged,
        }
    }
}

research_pub! {
    /// The true inputs (wheel rotations, a_y, β) of a bootstrap replicate world.
    ///
    /// Why the choice (measured with `study_eiv` in crates/odocal-lab). With the
    /// measured inputs as the truth, the replicate's true yaw rate carries the
    /// measured wheels' white noise (on `high` about 5 mrad per 25 ms step at
    /// 10 m/s, more than the turning itself), so the replicates see a far larger
    /// true yaw signal than the drive had, and the t_r bias of the errors-in-
    /// variables fit, which grows with noise over signal, does not appear in
    /// them: on `high` (known noise, 20 seeds × 12 km, B = 10) the bootstrap on
    /// the measured inputs corrects c_e (+0.059 → +0.008 %) but not t_r
    /// (+0.66 → +0.70 %).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    enum BootstrapInputs {
        /// The drive's measured inputs.
        #[default]
        Measured,
        /// The measured inputs averaged over ±`half_width_samples` within each
        /// continuous part (truncated at the part's ends): a smoothed
        /// trajectory.
        Smoothed {
            /// Half-width K of the centred moving average, samples (at least 1).
            half_width_samples: usize,
        },
    }
}

research_pub! {
    /// The result of [`bootstrap`].
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct BootstrapReport {
        /// The estimate being bootstrapped (θ̂).
        pub theta_hat: Theta,
        /// θ of every replicate that was fitted, in replicate order.
        pub replicates: Vec<Theta>,
        /// Replicates whose fit failed: index and reason.
        pub failed: Vec<(usize, String)>,
        /// Mean of the replicates.
        pub mean: Theta,
        /// Estimated bias of the estimator, mean − θ̂ (`[c_e, c_d, t_r, d]`).
        pub bias: [f64; 4],
        /// Standard deviation of the replicates.
        pub sd: [f64; 4],
        /// Coverage of the intervals.
        pub level: f64,
        /// Percentile intervals `[q_lo, q_hi]` of the replicates per parameter.
        /// They are centred on θ̂ + bias: with a biased estimator they miss the
        /// truth by the bias (use [`BootstrapReport::interval_basic`]).
        pub interval: [[f64; 2]; 4],
        /// Basic (reflected) bootstrap intervals `[2θ̂ − q_hi, 2θ̂ − q_lo]`:
        /// the percentile interval moved by −2·bias, centred on the
        /// bias-corrected estimate.
        pub interval_basic: [[f64; 2]; 4],
        /// The bias-corrected estimate θ̂ − bias.
        pub theta_corrected: Theta,
        /// With [`BootstrapOptions::antithetic`]: the mean of each pair whose
        /// two replicates were both fitted, in pair order ([`BootstrapReport::mean`]
        /// is their mean). Empty otherwise.
        #[serde(default)]
        pub pair_means: Vec<Theta>,
    }
}

/// Test-only fault injection (the replicates' fits do not fail on any drive
/// found so far, yet the paths that handle a failure must be tested): with
/// this seed, replicate 1 fails (the first antithetic pair is incomplete).
#[cfg(test)]
pub(crate) const FAIL_ONE_REPLICATE_SEED: u64 = 0xFA11_0001;
/// Test-only fault injection: with this seed every replicate fails.
#[cfg(test)]
pub(crate) const FAIL_EVERY_REPLICATE_SEED: u64 = 0xFA11_0002;

#[cfg(test)]
fn injected_failure(seed: u64, b: usize) -> Option<Error> {
    (seed == FAIL_EVERY_REPLICATE_SEED || (seed == FAIL_ONE_REPLICATE_SEED && b == 1))
        .then(|| Error::Numerical(format!("replicate {b}: failure injected by a test")))
}

research_pub! {
    /// Parametric bootstrap of an EIV estimate (see the module docs of
    /// `eiv::bootstrap`): `boot.replicates` re-simulations of the fitted noise
    /// model (`report.noise`) at the fitted θ on the drive's own inputs, each
    /// re-fitted with `opts` (the options of the original fit) from θ̂.
    /// Replicates run in parallel; each has its own random stream, so the
    /// report depends only on the inputs and the seed, not on the thread count.
    ///
    /// Errors for invalid options or when fewer than two replicates could be fitted.
    fn bootstrap(
        input: &EivInput<'_>,
        report: &EivReport,
        opts: &EivOptions,
        boot: &BootstrapOptions,
    ) -> Result<BootstrapReport> {
        boot.validate()?;
        input.validate()?;
        opts.validate()?;
        report.noise.validate_fitted()?;
        let smoothed = match boot.true_inputs {
            BootstrapInputs::Measured => None,
            BootstrapInputs::Smoothed { half_width_samples } => Some(SmoothedInputs::new(input, half_width_samples)),
        };
        let theta_hat = report.theta;
        // The fit's own quantisation level: `FromReadings` resolved as it was on
        // the drive (`report.quantisation_step_from_readings`), not re-read off
        // the replicates' readings, which are counted with the fitted step and
        // so lie on a lattice even where the drive's readings did not; and
        // a_y's noise floor and the heading readings' white noise the drive's
        // (`report.a_y_noise_floor`, `report.heading_noise_floor`).
        let resolved = opts
            .with_resolved_readings(report.quantisation_step_from_readings, report.a_y_noise_floor)
            .with_heading_floor(report.heading_noise_floor);
        // The replicates' θ is all that is used: no covariance term for η, and
        // no null pass for the innovation checks (their warnings are not
        // read).
        let mut refit = EivOptions {
            free: report.free,
            fix_unobservable: false,
            research: ResearchOptions {
                noise_estimate_term: NoiseEstimateTerm::Omitted,
                innovation_null: InnovationNull::FittedModel,
                ..resolved.research.clone()
            },
            ..resolved
        };
        if matches!(refit.research.bias_correction, BiasCorrection::Bootstrap { .. }) {
            // No bootstrap inside the bootstrap (B² fits): the replicates are
            // fitted without it.
            refit.research.bias_correction = BiasCorrection::None;
        }
        let results: Vec<Result<Theta>> = (0..boot.replicates)
            .into_par_iter()
            .map(|b| {
                // Antithetic: the pair (2j, 2j + 1) shares stream j, the second
                // with its Gaussian draws negated.
                let (stream, sign) = if boot.antithetic {
                    ((b / 2) as u64, if b.is_multiple_of(2) { 1.0 } else { -1.0 })
                } else {
                    (b as u64, 1.0)
                };
                #[cfg(test)]
                if let Some(e) = injected_failure(boot.seed, b) {
                    return Err(e);
                }
                let data = replicate(input, smoothed.as_ref(), &theta_hat, &report.noise, boot.seed, stream, sign);
                let rin = data.input(input);
                match boot.refit {
                    BootstrapRefit::Converged => estimate(&rin, &theta_hat, &refit).map(|r| r.theta),
                    BootstrapRefit::OneStep => one_step(&rin, &theta_hat, &refit),
                }
            })
            .collect();
        let pair_means: Vec<Theta> = if boot.antithetic {
            results
                .chunks(2)
                .filter_map(|p| match p {
                    [Ok(a), Ok(b)] => {
                        let (a, b) = (a.to_array(), b.to_array());
                        Some(Theta::from_array(std::array::from_fn(|i| 0.5 * (a[i] + b[i]))))
                    }
                    _ => None,
                })
                .collect()
        } else {
            Vec::new()
        };
        summarise(results, pair_means, report, boot)
    }
}

/// The bootstrap's statistics from the replicates' fits (`results`, in
/// replicate order) and, for antithetic pairs, the complete pairs' means.
fn summarise(
    results: Vec<Result<Theta>>,
    pair_means: Vec<Theta>,
    report: &EivReport,
    boot: &BootstrapOptions,
) -> Result<BootstrapReport> {
    let theta_hat = report.theta;
    let mut replicates = Vec::new();
    let mut failed = Vec::new();
    for (b, r) in results.into_iter().enumerate() {
        match r {
            Ok(t) => replicates.push(t),
            Err(e) => failed.push((b, e.to_string())),
        }
    }
    if replicates.len() < 2 || (boot.antithetic && pair_means.is_empty()) {
        return Err(Error::Numerical(format!(
            "bootstrap: only {} of {} replicates could be fitted{}",
            replicates.len(),
            boot.replicates,
            if boot.antithetic { format!(" ({} complete antithetic pairs)", pair_means.len()) } else { String::new() }
        )));
    }
    let cols: [Vec<f64>; 4] = std::array::from_fn(|i| replicates.iter().map(|t| t.to_array()[i]).collect());
    let hat = theta_hat.to_array();
    // The mean over the replicates, or over the complete pairs' means (a
    // replicate whose partner failed would bring its odd error back).
    let mean = mean_of(if boot.antithetic { &pair_means } else { &replicates });
    let cov = sample_covariance(&replicates, &mean_of(&replicates));
    let sd: [f64; 4] = std::array::from_fn(|i| cov[i][i].sqrt());
    let bias: [f64; 4] = std::array::from_fn(|i| if report.free[i] { mean[i] - hat[i] } else { 0.0 });
    let alpha = (1.0 - boot.level) / 2.0;
    let interval: [[f64; 2]; 4] = std::array::from_fn(|i| {
        let mut v = cols[i].clone();
        v.sort_by(f64::total_cmp);
        [quantile(&v, alpha), quantile(&v, 1.0 - alpha)]
    });
    let interval_basic: [[f64; 2]; 4] =
        std::array::from_fn(|i| [2.0 * hat[i] - interval[i][1], 2.0 * hat[i] - interval[i][0]]);
    let corrected: [f64; 4] = std::array::from_fn(|i| hat[i] - bias[i]);
    Ok(BootstrapReport {
        theta_hat,
        replicates,
        failed,
        mean: Theta::from_array(mean),
        bias,
        sd,
        level: boot.level,
        interval,
        interval_basic,
        theta_corrected: Theta::from_array(corrected),
        pair_means,
    })
}

/// The mean of a non-empty set of θ.
fn mean_of(thetas: &[Theta]) -> [f64; 4] {
    let n = thetas.len() as f64;
    std::array::from_fn(|i| thetas.iter().map(|t| t.to_array()[i]).sum::<f64>() / n)
}

impl BootstrapReport {
    research_pub! {
        /// The covariance of the replicates' mean (their sample covariance over
        /// the number of replicates fitted; with antithetic pairs the pair
        /// means' over the number of pairs): the Monte Carlo error of
        /// [`BootstrapReport::mean`] and so of the bias and the corrected
        /// estimate. `[c_e, c_d, t_r, d]` order, SI units.
        ///
        /// With a single complete antithetic pair the pairs' spread cannot be
        /// estimated: the replicates' covariance over 2 stands in, the
        /// plain bootstrap's error for two replicates (an upper bound in the
        /// usual case that the pair's errors are negatively correlated).
        fn mean_covariance(&self) -> [[f64; 4]; 4] {
            // The set whose spread is measured, and the number its mean averages.
            let (set, n) = match self.pair_means.len() {
                0 => (&self.replicates, self.replicates.len()),
                1 => (&self.replicates, 2),
                k => (&self.pair_means, k),
            };
            if set.len() < 2 {
                return [[0.0; 4]; 4];
            }
            sample_covariance(set, &mean_of(set)).map(|row| row.map(|x| x / n as f64))
        }
    }
}

/// The sample covariance (divisor n − 1) of at least two replicates about
/// their `mean`.
fn sample_covariance(replicates: &[Theta], mean: &[f64; 4]) -> [[f64; 4]; 4] {
    let mut c = [[0.0; 4]; 4];
    for t in replicates {
        let a = t.to_array();
        for i in 0..4 {
            for j in 0..4 {
                c[i][j] += (a[i] - mean[i]) * (a[j] - mean[j]);
            }
        }
    }
    let n = replicates.len() as f64;
    c.map(|row| row.map(|x| x / (n - 1.0)))
}

/// Linear-interpolation quantile of sorted data.
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q * (sorted.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = (lo + 1).min(sorted.len() - 1);
    let f = pos - lo as f64;
    sorted[lo] * (1.0 - f) + sorted[hi] * f
}

/// The re-simulated columns of one replicate.
pub(crate) struct ReplicateData {
    px: Vec<f64>,
    py: Vec<f64>,
    psi: Vec<f64>,
    n_rl: Vec<f64>,
    n_rr: Vec<f64>,
    beta: Vec<f64>,
    a_y: Vec<f64>,
}

impl ReplicateData {
    fn input<'a>(&'a self, like: &EivInput<'a>) -> EivInput<'a> {
        EivInput {
            sample_time_s: like.sample_time_s,
            parts: like.parts,
            px: &self.px,
            py: &self.py,
            psi: &self.psi,
            n_rl: &self.n_rl,
            n_rr: &self.n_rr,
            beta: &self.beta,
            a_y: &self.a_y,
            reference_measured: like.reference_measured,
        }
    }
}

/// A replicate's random draws: standard normals times `sign` (−1 for the
/// second replicate of an antithetic pair), uniforms as drawn.
struct Draws {
    rng: ChaCha8Rng,
    sign: f64,
}

impl Draws {
    fn normal(&mut self) -> f64 {
        self.sign * self.rng.sample::<f64, _>(StandardNormal)
    }
    fn uniform(&mut self) -> f64 {
        self.rng.random::<f64>()
    }
}

/// First-order Gauss-Markov sequence, stationary start.
struct Gm {
    a: f64,
    q: f64,
    x: f64,
}

impl Gm {
    fn new(rng: &mut Draws, sigma: f64, tau: f64, ts: f64) -> Self {
        let a = (-ts / tau).exp();
        Gm { a, q: sigma * (1.0 - a * a).sqrt(), x: sigma * rng.normal() }
    }
    fn next(&mut self, rng: &mut Draws) -> f64 {
        let out = self.x;
        self.x = self.a * self.x + self.q * rng.normal();
        out
    }
}

/// The true inputs of [`BootstrapInputs::Smoothed`]: centred moving
/// averages over ±K samples within each part.
pub(crate) struct SmoothedInputs {
    n_rl: Vec<f64>,
    n_rr: Vec<f64>,
    beta: Vec<f64>,
    a_y: Vec<f64>,
}

impl SmoothedInputs {
    fn new(input: &EivInput<'_>, half_width: usize) -> Self {
        let mut out = SmoothedInputs {
            n_rl: input.n_rl.to_vec(),
            n_rr: input.n_rr.to_vec(),
            beta: input.beta.to_vec(),
            a_y: input.a_y.to_vec(),
        };
        for part in input.parts {
            if part.end <= part.start {
                continue;
            }
            for (src, dst) in [
                (input.n_rl, &mut out.n_rl),
                (input.n_rr, &mut out.n_rr),
                (input.beta, &mut out.beta),
                (input.a_y, &mut out.a_y),
            ] {
                moving_average(&src[part.clone()], half_width, &mut dst[part.clone()]);
            }
        }
        out
    }
}

/// Centred moving average of `x` over ±`k` samples, truncated at the ends, into `out`.
fn moving_average(x: &[f64], k: usize, out: &mut [f64]) {
    let mut prefix = Vec::with_capacity(x.len() + 1);
    prefix.push(0.0);
    for v in x {
        prefix.push(prefix.last().copied().unwrap_or(0.0) + v);
    }
    for (i, o) in out.iter_mut().enumerate() {
        let lo = i.saturating_sub(k);
        let hi = (i + k + 1).min(x.len());
        *o = (prefix[hi] - prefix[lo]) / (hi - lo) as f64;
    }
}

/// One replicate world (module docs), from stream `b` of `seed` with every
/// Gaussian draw times `sign` (±1); the true inputs are `smoothed` if given,
/// else the measured ones.
pub(crate) fn replicate(
    input: &EivInput<'_>,
    smoothed: Option<&SmoothedInputs>,
    theta: &Theta,
    nm: &NoiseModel,
    seed: u64,
    b: u64,
    sign: f64,
) -> ReplicateData {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(b + 1);
    let mut rng = Draws { rng, sign };
    let ts = input.sample_time_s;
    let mut d = ReplicateData {
        px: input.px.to_vec(),
        py: input.py.to_vec(),
        psi: input.psi.to_vec(),
        n_rl: input.n_rl.to_vec(),
        n_rr: input.n_rr.to_vec(),
        beta: input.beta.to_vec(),
        a_y: input.a_y.to_vec(),
    };
    let q = nm.quantisation_step_rev_per_s;
    let ticks = if q > 0.0 { 1.0 / (q * ts) } else { 0.0 };
    for part in input.parts {
        if part.end <= part.start {
            continue;
        }
        let mut common = Gm::new(&mut rng, nm.wheel_common_rel_sigma, nm.wheel_common_time_constant_s, ts);
        let wt = nm.wheel_differential_time_constant_s;
        let mut wl = Gm::new(&mut rng, nm.wheel_differential_rel_sigma, wt, ts);
        let mut wr = Gm::new(&mut rng, nm.wheel_differential_rel_sigma, wt, ts);
        let dt = nm.drift_time_constant_s;
        let mut dx = Gm::new(&mut rng, nm.position_drift_sigma_m, dt, ts);
        let mut dy = Gm::new(&mut rng, nm.position_drift_sigma_m, dt, ts);
        let mut dpsi = Gm::new(&mut rng, nm.heading_drift_sigma_rad, dt, ts);
        let mut beta_err = Gm::new(&mut rng, nm.sideslip_sigma_rad, nm.sideslip_time_constant_s, ts);
        let mut rev: [f64; 2] = [rng.uniform(), rng.uniform()];
        let s = part.start;
        let mut x = State::new(input.px[s], input.py[s], input.psi[s]);
        for k in part.clone() {
            let u = match smoothed {
                Some(t) => Input { n_rl: t.n_rl[k], n_rr: t.n_rr[k], beta: t.beta[k], a_y: t.a_y[k] },
                None => Input { n_rl: input.n_rl[k], n_rr: input.n_rr[k], beta: input.beta[k], a_y: input.a_y[k] },
            };
            d.px[k] = x[0] + dx.next(&mut rng) + nm.position_white_sigma_m * rng.normal();
            d.py[k] = x[1] + dy.next(&mut rng) + nm.position_white_sigma_m * rng.normal();
            d.psi[k] = x[2] + dpsi.next(&mut rng) + nm.heading_white_sigma_rad * rng.normal();
            let sc = common.next(&mut rng);
            let sw = [wl.next(&mut rng), wr.next(&mut rng)];
            for (w, n) in [u.n_rl, u.n_rr].into_iter().enumerate() {
                let rel = sc + sw[w] + nm.wheel_white_rel_sigma * rng.normal();
                let noisy = n * (1.0 + rel);
                let measured = if ticks > 0.0 {
                    // Encoder: whole ticks over the interval (rev holds the phase in ticks).
                    let before = rev[w].floor();
                    rev[w] += noisy * ts * ticks;
                    (rev[w].floor() - before) / (ticks * ts)
                } else {
                    noisy
                };
                if w == 0 {
                    d.n_rl[k] = measured;
                } else {
                    d.n_rr[k] = measured;
                }
            }
            d.a_y[k] = u.a_y + nm.lateral_acceleration_sigma_m_per_s2 * rng.normal();
            d.beta[k] = u.beta + beta_err.next(&mut rng);
            x = step(&x, &u, theta, ts);
        }
    }
    d
}

#[cfg(test)]
mod tests {
    use super::{moving_average, replicate, SmoothedInputs};
    use crate::eiv::{EivInput, NoiseModel};
    use crate::sim::{simulate, SimOptions};

    /// The two replicates of an antithetic pair mirror each other about the
    /// replicate world's truth: without an encoder every noise enters
    /// linearly, so their mean is the true wheel rotations, a_y, β and poses
    /// to rounding, and their difference is not zero.
    #[test]
    fn antithetic_replicates_mirror_each_other_about_the_truth() {
        let out = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(3) }).expect("sim");
        let input = EivInput::from_drive(&out.drive);
        let nm = NoiseModel { quantisation_step_rev_per_s: 0.0, ..NoiseModel::PRODUCTION_CAR };
        let theta = out.sidecar.theta_true;
        let smooth = SmoothedInputs::new(&input, 20);
        let plus = replicate(&input, Some(&smooth), &theta, &nm, 9, 4, 1.0);
        let minus = replicate(&input, Some(&smooth), &theta, &nm, 9, 4, -1.0);
        // The world's true poses: the noise-free replicate (every σ zero).
        let quiet = NoiseModel {
            wheel_white_rel_sigma: 0.0,
            wheel_common_rel_sigma: 0.0,
            wheel_differential_rel_sigma: 0.0,
            position_white_sigma_m: 0.0,
            position_drift_sigma_m: 0.0,
            heading_white_sigma_rad: 0.0,
            heading_drift_sigma_rad: 0.0,
            lateral_acceleration_sigma_m_per_s2: 0.0,
            sideslip_sigma_rad: 0.0,
            ..nm
        };
        let truth = replicate(&input, Some(&smooth), &theta, &quiet, 9, 4, 1.0);
        let cols = |d: &super::ReplicateData| {
            [d.px.clone(), d.py.clone(), d.psi.clone(), d.n_rl.clone(), d.n_rr.clone(), d.beta.clone(), d.a_y.clone()]
        };
        let (p, m, t) = (cols(&plus), cols(&minus), cols(&truth));
        for c in 0..7 {
            let mut apart = 0.0f64;
            for k in 0..p[c].len() {
                let mid = 0.5 * (p[c][k] + m[c][k]);
                let scale = t[c][k].abs().max(1.0);
                assert!((mid - t[c][k]).abs() <= 1e-12 * scale, "column {c}, sample {k}: {mid} against {}", t[c][k]);
                apart = apart.max((p[c][k] - m[c][k]).abs());
            }
            assert!(apart > 0.0, "column {c}: the pair is identical");
        }
    }

    /// Centred, truncated at the ends: [1, 2, 3, 4, 10] over ±1.
    #[test]
    fn moving_average_is_centred_and_truncated_at_the_ends() {
        let x = [1.0, 2.0, 3.0, 4.0, 10.0];
        let mut out = [0.0; 5];
        moving_average(&x, 1, &mut out);
        let want = [1.5, 2.0, 3.0, 17.0 / 3.0, 7.0];
        for (o, w) in out.iter().zip(want) {
            assert!((o - w).abs() < 1e-12, "{out:?} against {want:?}");
        }
    }
}
