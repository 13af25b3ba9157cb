//! The parametric bootstrap and the bias correction built on it.

use super::support::*;
use crate::eiv::estimate::one_step;
use crate::eiv::filter::NETA;
use crate::eiv::*;
use crate::model::param::{Param, ParamSet};
use crate::sim::{simulate, SimOptions};
use crate::Error;
use crate::Theta;

#[test]
fn bootstrap_is_identical_for_one_and_two_threads() {
    let (out, opts) = known_noise_fit(2.0, 31);
    let input = input_of(&out.drive);
    let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let boot = BootstrapOptions { replicates: 4, seed: 9, ..Default::default() };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let b = pool.install(|| bootstrap(&input, &r, &opts, &boot)).expect("bootstrap");
        serde_json::to_string(&b).expect("json")
    };
    let one = run(1);
    assert_eq!(one, run(2));
    // Another seed gives other replicates.
    let other = bootstrap(&input, &r, &opts, &BootstrapOptions { seed: 10, ..boot }).expect("bootstrap");
    assert_ne!(one, serde_json::to_string(&other).expect("json"));
}

/// Paper noise, 6 km, the true noise model fixed, 40 replicates.
/// With the sideslip error white-equivalent c_e θ̂ is off by +0.090 % here
/// (2.6 reported σ), and the bootstrap's bias estimate +0.077 % brings it
/// to +0.013 %. With the sideslip error a filter state ([`SideslipNoise::GaussMarkovState`])
/// c_e θ̂ is off by +0.009 % (0.2σ) and the bootstrap finds no c_e bias
/// beyond its Monte Carlo error: the bias was the white-equivalent
/// sideslip noise, which the bootstrap's replicates (simulated from the
/// same model) shared. t_r is −1.1 % off here (2.3σ, an unlucky draw), so
/// the assertion for every parameter is the 3σ one; 95 % coverage over
/// seeds is measured by `study_eiv` in crates/odocal-lab. In the slow tier
/// (a statistical claim); the bootstrap's mechanics keep fast tests here and
/// in `calibrate::eiv_tests`.
#[test]
#[ignore = "slow tier, a statistical claim (~9 s of CPU): cargo test --workspace -- --ignored"]
fn bootstrap_brackets_the_truth_and_finds_no_c_e_bias_left() {
    let (out, opts) = known_noise_fit(6.0, 4);
    let truth = out.sidecar.theta_true.to_array();
    let input = input_of(&out.drive);
    let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let b = bootstrap(&input, &r, &opts, &BootstrapOptions { replicates: 40, seed: 1, ..Default::default() })
        .expect("bootstrap");
    assert!(b.failed.is_empty(), "{:?}", b.failed);
    for i in 0..4 {
        let [lo, hi] = b.interval_basic[i];
        eprintln!(
            "{}: truth {:.6e}, θ̂ {:.6e}, basic [{lo:.6e}, {hi:.6e}], percentile {:?}, bias {:.2e}, sd {:.2e}, σ {:.2e}",
            PARAMETERS[i],
            truth[i],
            r.theta.to_array()[i],
            b.interval[i],
            b.bias[i],
            b.sd[i],
            r.sigma[i]
        );
        let off = (b.theta_corrected.to_array()[i] - truth[i]).abs();
        assert!(
            off <= 3.0 * b.sd[i],
            "{}: bias-corrected error {off:.2e} > 3 sd = {:.2e}",
            PARAMETERS[i],
            3.0 * b.sd[i]
        );
        if i == 0 {
            assert!(lo <= truth[i] && truth[i] <= hi, "c_e: {} outside the basic [{lo}, {hi}]", truth[i]);
        }
        let ratio = (hi - lo) / (2.0 * 1.96 * r.sigma[i]);
        assert!((1.0 / 3.0..3.0).contains(&ratio), "{}: interval / reported ±1.96σ = {ratio}", PARAMETERS[i]);
    }
    let raw = (r.theta.c_e - truth[0]).abs();
    assert!(raw <= 2.0 * r.sigma[0], "c_e error {raw:.2e} > 2σ = {:.2e}", 2.0 * r.sigma[0]);
    let mc = 3.0 * b.sd[0] / (b.replicates.len() as f64).sqrt();
    assert!(b.bias[0].abs() <= mc, "c_e bootstrap bias {:.2e} beyond 3 Monte Carlo se {mc:.2e}", b.bias[0]);
}

/// `BiasCorrection::Bootstrap` subtracts exactly what [`bootstrap`] with the
/// same seed estimates (c_e only, or every parameter); the uncorrected
/// root is the plain fit's θ, whose first-order bias diagnostic is there.
/// Two replicates on 1 km keep it cheap (this checks the plumbing; the
/// correction's effect over seeds is measured by `study_eiv` in crates/odocal-lab).
#[test]
fn bootstrap_bias_correction_subtracts_the_bootstrap_bias() {
    let (out, opts) = known_noise_fit(1.0, 12);
    let input = input_of(&out.drive);
    let start = out.sidecar.theta_true;
    let plain = estimate(&input, &start, &opts).expect("eiv");
    assert_eq!(plain.theta, plain.theta_uncorrected);
    let bits = |a: [f64; 4]| a.map(f64::to_bits);
    assert_eq!(bits(plain.bias_subtracted), bits([0.0; 4]));
    let fo = plain.first_order_bias.expect("first-order bias with the covariance following θ");
    assert!(fo.bias.iter().all(|b| b.is_finite()), "{fo:?}");

    let one_step = BootstrapOptions { replicates: 2, seed: 3, refit: BootstrapRefit::OneStep, ..Default::default() };
    let boot = bootstrap(&input, &plain, &opts, &one_step).expect("bootstrap");
    let c_e: ParamSet = [Param::CE].into_iter().collect();
    for parameters in [c_e, c_e.with(Param::TR), ParamSet::THETA] {
        let corr = BiasCorrection::Bootstrap { replicates: 2, seed: 3, parameters };
        let r = estimate(&input, &start, &with_correction(&opts, corr)).expect("eiv");
        assert_eq!(r.theta_uncorrected, plain.theta);
        let named: [bool; 4] = std::array::from_fn(|i| parameters.contains(Param::THETA[i]));
        let want: [f64; 4] = std::array::from_fn(|i| if named[i] { boot.bias[i] } else { 0.0 });
        assert!(want[0] != 0.0, "the bootstrap found no c_e bias at all: {want:?}");
        assert_eq!(bits(r.bias_subtracted), bits(want));
        // Bit-exact: the correction is one subtraction.
        let p = plain.theta.to_array();
        let shifted: [f64; 4] = std::array::from_fn(|i| p[i] - want[i]);
        assert_eq!(bits(r.theta.to_array()), bits(shifted));
        // The σ of a corrected parameter carries the Monte Carlo error of the
        // subtracted mean (replicates' variance / B); the others are unchanged.
        let mc = boot.mean_covariance();
        for i in 0..4 {
            let corrected = plain.free[i] && named[i];
            let want_var = plain.sigma[i].powi(2) + if corrected { mc[i][i] } else { 0.0 };
            assert!(
                (r.sigma[i].powi(2) - want_var).abs() <= 1e-12 * want_var,
                "parameter {i}: σ² {} against {want_var}",
                r.sigma[i].powi(2)
            );
            let want_mc: f64 = if corrected { mc[i][i].sqrt() } else { 0.0 };
            assert_eq!(r.sigma_bias_correction[i].to_bits(), want_mc.to_bits(), "parameter {i}");
            assert!(!corrected || mc[i][i] > 0.0, "parameter {i}: no Monte Carlo variance");
        }
    }
    let one = BiasCorrection::Bootstrap { replicates: 1, seed: 0, parameters: c_e };
    let bad = with_correction(&opts, one);
    assert!(matches!(bad.validate(), Err(Error::InvalidOption { field: "bias_correction", .. })));
    // Only θ's parameters, and at least one of them, can be corrected.
    for parameters in [ParamSet::default(), ParamSet::EXTRINSICS, c_e.with(Param::HeadingOffset)] {
        let corr = BiasCorrection::Bootstrap { replicates: 2, seed: 0, parameters };
        let bad = with_correction(&opts, corr);
        let err = bad.validate();
        assert!(matches!(err, Err(Error::InvalidOption { field: "bias_correction", .. })), "{parameters}: {err:?}");
    }
}

/// With the noise scales estimated, the bias correction fits the replicates
/// with the fitted noise model held (what `--correct-bias` does): it
/// subtracts exactly the bias of a bootstrap run with
/// `EivOptions { noise: fit.noise, fix_noise: true }`, and another bias
/// than replicates that re-estimate the noise. 2 km, 2 replicates: the
/// plumbing (the effect over seeds is in [`BiasCorrection`]'s docs).
#[test]
fn held_noise_bias_correction_fits_the_replicates_with_the_fitted_noise() {
    let out = simulate(&SimOptions { length_km: 2.0, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let start = out.sidecar.theta_true;
    let mut opts = EivOptions::default();
    opts.research.bootstrap_inputs = BootstrapInputs::Smoothed { half_width_samples: 20 };
    let plain = estimate(&input, &start, &opts).expect("eiv");
    assert!(plain.eta.iter().any(|e| *e != 0.0), "the noise scales were not estimated: {:?}", plain.eta);
    // ∂η̂/∂θ: rows of the estimated sources (σ > 0) only, columns of the free parameters only.
    let b = plain.eta_theta_sensitivity;
    for j in 0..NETA {
        for t in 0..4 {
            assert!(b[j][t].is_finite());
            if plain.eta_sigma[j] == 0.0 || !plain.free[t] {
                assert_eq!(b[j][t].to_bits(), 0.0f64.to_bits(), "source {j}, parameter {t}");
            }
        }
    }
    assert!(b.iter().flatten().any(|x| *x != 0.0), "{b:?}");
    let boot_opts = BootstrapOptions {
        replicates: 2,
        seed: 4,
        true_inputs: BootstrapInputs::Smoothed { half_width_samples: 20 },
        refit: BootstrapRefit::OneStep,
        ..Default::default()
    };
    let held = EivOptions { noise: plain.noise, fix_noise: true, ..opts.clone() };
    let boot = bootstrap(&input, &plain, &held, &boot_opts).expect("bootstrap");
    let corr = BiasCorrection::Bootstrap { replicates: 2, seed: 4, parameters: ParamSet::THETA };
    let r = estimate(&input, &start, &with_correction(&opts, corr)).expect("eiv");
    assert_eq!(r.theta_uncorrected, plain.theta);
    assert_eq!(r.bias_subtracted.map(f64::to_bits), boot.bias.map(f64::to_bits));
    let reestimating = bootstrap(&input, &plain, &opts, &boot_opts).expect("bootstrap");
    assert_ne!(
        reestimating.bias.map(f64::to_bits),
        r.bias_subtracted.map(f64::to_bits),
        "re-estimating replicates gave the held-noise bias"
    );
}

/// Antithetic pairs ([`BootstrapOptions::antithetic`], what
/// [`EivOptions::correct_bias`] sets): the bias is the mean of the pairs'
/// means and its Monte Carlo covariance their spread over the number of
/// pairs; the pairs' means spread far less than single replicates (the odd
/// part of each replicate's error cancels); an odd B is refused; the
/// correction subtracts exactly that bootstrap's bias. 2 km, 8 replicates.
#[test]
fn antithetic_pairs_average_out_the_replicates_odd_error() {
    let out = simulate(&SimOptions { length_km: 2.0, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let start = out.sidecar.theta_true;
    let opts = EivOptions { fix_noise: true, ..Default::default() };
    let fit = estimate(&input, &start, &opts).expect("eiv");
    let smoothed = BootstrapInputs::Smoothed { half_width_samples: BIAS_BOOTSTRAP_SMOOTHING_SAMPLES };
    let boot_opts = |antithetic: bool, replicates: usize| BootstrapOptions {
        replicates,
        seed: 4,
        true_inputs: smoothed,
        antithetic,
        refit: BootstrapRefit::OneStep,
        ..Default::default()
    };
    let anti = bootstrap(&input, &fit, &opts, &boot_opts(true, 8)).expect("bootstrap");
    let plain = bootstrap(&input, &fit, &opts, &boot_opts(false, 8)).expect("bootstrap");
    assert!(anti.failed.is_empty() && plain.failed.is_empty(), "{:?} {:?}", anti.failed, plain.failed);
    assert_eq!(anti.pair_means.len(), 4);
    assert!(plain.pair_means.is_empty());
    let hat = fit.theta.to_array();
    let pm: Vec<[f64; 4]> = anti.pair_means.iter().map(|t| t.to_array()).collect();
    for (j, m) in pm.iter().enumerate() {
        let (a, b) = (anti.replicates[2 * j].to_array(), anti.replicates[2 * j + 1].to_array());
        for i in 0..4 {
            assert_eq!(m[i].to_bits(), (0.5 * (a[i] + b[i])).to_bits(), "pair {j}, parameter {i}");
        }
    }
    let mc = anti.mean_covariance();
    for i in 0..4 {
        let mean = pm.iter().map(|m| m[i]).sum::<f64>() / 4.0;
        assert!((anti.mean.to_array()[i] - mean).abs() <= 1e-15 * mean.abs(), "parameter {i}");
        assert_eq!(anti.bias[i].to_bits(), (anti.mean.to_array()[i] - hat[i]).to_bits(), "parameter {i}");
        let var_pairs = pm.iter().map(|m| (m[i] - mean).powi(2)).sum::<f64>() / 3.0;
        assert!(
            (mc[i][i] - var_pairs / 4.0).abs() <= 1e-12 * var_pairs,
            "parameter {i}: {} {}",
            mc[i][i],
            var_pairs / 4.0
        );
        // The Monte Carlo variance of the bias at equal B: the pairs' against
        // single replicates' (sd² / 8). Measured here: 1/1300 (c_e), 1/1500
        // (c_d), 1/17 (t_r, the most even error), 1/75 (d).
        let plain_var = plain.mean_covariance()[i][i];
        eprintln!(
            "parameter {i}: Monte Carlo variance of the bias, antithetic {:.3e}, plain {plain_var:.3e}",
            mc[i][i]
        );
        assert!(mc[i][i] < 0.2 * plain_var, "parameter {i}: antithetic {} against plain {plain_var}", mc[i][i]);
    }
    let odd = bootstrap(&input, &fit, &opts, &boot_opts(true, 5));
    assert!(matches!(odd, Err(Error::InvalidOption { field: "replicates", .. })), "{odd:?}");
    let mut o = opts.clone();
    o.correct_bias(5, 4, ParamSet::THETA);
    assert!(matches!(o.validate(), Err(Error::InvalidOption { field: "bias_correction", .. })));
    // The correction (held noise: here the fixed model, as the fit's) subtracts that bootstrap's bias.
    let mut o = opts.clone();
    o.correct_bias(8, 4, ParamSet::THETA);
    assert!(o.research.bootstrap_antithetic);
    let r = estimate(&input, &start, &o).expect("eiv");
    assert_eq!(r.theta_uncorrected, fit.theta);
    assert_eq!(r.bias_subtracted.map(f64::to_bits), anti.bias.map(f64::to_bits));
    // Applied after the fit, the same to the bit; a second application is refused.
    let mut after = fit.clone();
    apply_bias_correction(&input, &mut after, &o).expect("correction");
    assert_eq!(after.theta, r.theta);
    assert_eq!(after.sigma.map(f64::to_bits), r.sigma.map(f64::to_bits));
    let twice = apply_bias_correction(&input, &mut after, &o);
    assert!(matches!(twice, Err(Error::InvalidOption { field: "bias_correction", .. })), "{twice:?}");
    for i in (0..4).filter(|i| fit.free[*i]) {
        let want = mc[i][i].sqrt();
        assert!((r.sigma_bias_correction[i] - want).abs() <= 1e-12 * want, "parameter {i}");
    }
}

/// A bootstrap of a `FromReadings` fit refits its replicates at the level
/// the fit resolved to on the drive, not at one re-read off the replicates'
/// readings (white wheel noise, no encoder: the fit models no
/// quantisation, and so do its replicates, as with a step given as zero).
#[test]
fn bootstrap_refits_at_the_quantisation_level_of_the_fit() {
    let opts =
        SimOptions { length_km: 0.5, noise: crate::sim::NoiseOptions::white_wheel_only(), ..SimOptions::paper(5) };
    let out = simulate(&opts).expect("sim");
    let input = input_of(&out.drive);
    let fit = EivOptions { max_iterations: 2, ..EivOptions::default() };
    assert_eq!(fit.quantisation_level, QuantisationLevel::FromReadings);
    let r = estimate(&input, &out.sidecar.theta_true, &fit).expect("eiv");
    assert_eq!(r.quantisation_step_from_readings, None, "no lattice in white-noise readings");
    assert!(r.noise.quantisation_step_rev_per_s == 0.0, "no lattice, no quantisation: {:?}", r.noise);
    let boot = BootstrapOptions { replicates: 2, seed: 4, ..Default::default() };
    let replicates = |o: &EivOptions| bootstrap(&input, &r, o, &boot).expect("bootstrap").replicates;
    let from_readings = replicates(&fit);
    let no_step = NoiseModel { quantisation_step_rev_per_s: 0.0, ..fit.noise };
    let given = EivOptions { quantisation_level: QuantisationLevel::Given, noise: no_step, ..fit.clone() };
    assert_eq!(from_readings, replicates(&given));
    let scaled = EivOptions { quantisation_level: QuantisationLevel::ScaledWithWhite, ..fit.clone() };
    assert_ne!(from_readings, replicates(&scaled), "the test cannot tell the levels apart");
}

/// `BootstrapInputs::Smoothed`: the replicate worlds run on the moving
/// average of the measured inputs, so the same seed gives other replicates
/// than with the measured inputs; a half-width of 0 is rejected. (Its effect
/// on the bias estimate over seeds: `study_eiv --bootstrap-smooth` in crates/odocal-lab.)
#[test]
fn smoothed_bootstrap_inputs_change_the_replicate_worlds() {
    let (out, opts) = known_noise_fit(1.0, 31);
    let input = input_of(&out.drive);
    let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let boot = BootstrapOptions { replicates: 4, seed: 9, ..Default::default() };
    let smooth = BootstrapOptions { true_inputs: BootstrapInputs::Smoothed { half_width_samples: 20 }, ..boot };
    let measured = bootstrap(&input, &r, &opts, &boot).expect("bootstrap, measured inputs");
    let smoothed = bootstrap(&input, &r, &opts, &smooth).expect("bootstrap, smoothed inputs");
    assert_ne!(measured.replicates, smoothed.replicates);
    let zero = BootstrapOptions { true_inputs: BootstrapInputs::Smoothed { half_width_samples: 0 }, ..boot };
    assert!(bootstrap(&input, &r, &opts, &zero).is_err());
}

/// One-step refits ([`BootstrapRefit::OneStep`]): from a start whose
/// converged fit takes one full step (as a replicate started at the
/// estimate usually does) the one-step θ is the converged θ to the bit;
/// from a start far away (several iterations) one scoring step lands much
/// closer to the converged θ than the start.
#[test]
#[allow(clippy::float_cmp)] // identity to the bit is the claim
fn one_step_refit_is_the_converged_fit_where_that_takes_one_full_step() {
    let (out, opts) = known_noise_fit(2.0, 31);
    let input = input_of(&out.drive);
    let fit = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let t_r = |k: f64| Theta { t_r: fit.theta.t_r + k * fit.sigma[2], ..fit.theta };
    let near = t_r(1.0);
    let converged = estimate(&input, &near, &opts).expect("eiv");
    let history = &converged.passes[0].history;
    assert_eq!(history.len(), 1, "the case needs a fit of one iteration: {history:?}");
    assert_eq!(history[0].step_factor, 1.0);
    assert!(converged.termination.converged());
    assert_eq!(one_step(&input, &near, &opts).expect("one step"), converged.theta);

    let far = t_r(30.0);
    let converged = estimate(&input, &far, &opts).expect("eiv");
    assert!(converged.passes[0].history.len() > 1, "the case needs several iterations");
    let step = one_step(&input, &far, &opts).expect("one step");
    let off = |t: &Theta| (t.t_r - converged.theta.t_r).abs();
    assert!(off(&step) < 0.2 * off(&far), "one step: {} from the converged t_r, the start {}", off(&step), off(&far));
}

/// The default bias correction fits its replicates by one scoring step
/// ([`BootstrapRefit::OneStep`]); replicates fitted to convergence (as
/// `ResearchOptions::bias_correction_refit` asks) would subtract a bias
/// that differs by at most [`ONE_STEP_TOLERANCE_SIGMA`] of each
/// parameter's σ (paper and high noise, η estimated, 2 km).
#[test]
#[ignore = "slow tier, a statistical claim (~4 s): cargo test --workspace -- --ignored"]
fn one_step_replicates_move_the_correction_by_a_small_fraction_of_sigma() {
    for (noise, seed) in [(crate::sim::NoiseOptions::paper(), 3), (crate::sim::NoiseOptions::high(), 2)] {
        let out = simulate(&SimOptions { length_km: 2.0, noise, ..SimOptions::paper(seed) }).expect("sim");
        let input = input_of(&out.drive);
        let mut opts = EivOptions::default();
        opts.correct_bias(4, 0, ParamSet::THETA);
        let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
        // The bootstrap the correction runs, with converged replicates.
        let inner = EivOptions {
            noise: r.noise,
            fix_noise: true,
            ..opts
                .with_resolved_readings(r.quantisation_step_from_readings, r.a_y_noise_floor)
                .without_bias_correction()
        };
        let boot = BootstrapOptions {
            replicates: 4,
            seed: 0,
            true_inputs: opts.research.bootstrap_inputs,
            antithetic: true,
            refit: BootstrapRefit::Converged,
            ..Default::default()
        };
        // The fit as the correction saw it: θ̂ before the subtraction.
        let fit = EivReport { theta: r.theta_uncorrected, ..r.clone() };
        let converged = bootstrap(&input, &fit, &inner, &boot).expect("bootstrap");
        let one_step = bootstrap(&input, &fit, &inner, &BootstrapOptions { refit: BootstrapRefit::OneStep, ..boot })
            .expect("bootstrap");
        assert_eq!(one_step.bias.map(f64::to_bits), r.bias_subtracted.map(f64::to_bits), "seed {seed}");
        // `bias_correction_refit` switches the correction to the converged replicates.
        let mut converged_opts = opts.clone();
        converged_opts.research.bias_correction_refit = BootstrapRefit::Converged;
        let rc = estimate(&input, &out.sidecar.theta_true, &converged_opts).expect("eiv");
        assert_eq!(rc.bias_subtracted.map(f64::to_bits), converged.bias.map(f64::to_bits), "seed {seed}");
        for i in (0..4).filter(|i| r.free[*i]) {
            let moved = (one_step.bias[i] - converged.bias[i]).abs() / r.sigma[i];
            eprintln!("seed {seed}, {}: one-step against converged replicates {moved:.4} σ", PARAMETERS[i]);
            assert!(moved <= ONE_STEP_TOLERANCE_SIGMA, "seed {seed}, {}: {moved} σ", PARAMETERS[i]);
        }
    }
}

/// The stated tolerance of the one-step replicates: 0.1 σ (measured on
/// 12 km drives, seeds 1–6: ≤ 0.011 σ under paper noise, ≤ 0.10 σ under
/// high noise, where the correction's own Monte Carlo error, the spread
/// over bootstrap seeds, is 0.2–0.26 σ for t_r and d).
const ONE_STEP_TOLERANCE_SIGMA: f64 = 0.1;

/// `opts` with the bias correction `corr`.
fn with_correction(opts: &EivOptions, corr: BiasCorrection) -> EivOptions {
    let mut o = opts.clone();
    o.research.bias_correction = corr;
    o
}
