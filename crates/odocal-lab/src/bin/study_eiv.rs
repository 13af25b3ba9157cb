//! The errors-in-variables estimator against batch Gauss-Newton, the 3-step
//! method and the Cramér–Rao bound on simulated drives: the tables of
//! docs/validation.md ("Simulated drives against the Cramér–Rao bound",
//! "Coverage of the reported σ", "Drive length", "Known noise levels", "The
//! 3-step method").
//!
//! Per preset and seed (1..=S) it simulates a drive and runs, all through
//! `odocal::calibrate` as a user would (EIV rows with the fallback off and
//! without the method's bias correction, which the `+ boot` rows apply):
//! - `G-N`: batch Gauss-Newton from θ_0 on every cut segment (no yaw-rate
//!   selection), the EIV method's start and fallback, here as the `EIV
//!   known` row's start: the reference heading offset held at its true 0;
//! - `3-step`: the paper's method (first `--three-step-seeds` seeds only);
//! - `EIV known`: the simulator's noise model, fixed (`--fix-noise`; an
//!   oracle: it also holds the heading offset at its true 0);
//! - `EIV est.`: the default options (η estimated from the production-car
//!   model, the heading offset estimated by the start), and `EIV est. +
//!   fallback`: θ = G-N where a consistency check failed;
//! - with `--bootstrap B`, on the first `--bootstrap-seeds` seeds of
//!   `--bootstrap-presets`: `EIV est. + boot held η̂` (c_e corrected by a
//!   bootstrap whose replicates hold the fitted noise model) and `… (all)`
//!   (every parameter corrected: with `--bootstrap 4 --bootstrap-smooth 20
//!   --bootstrap-antithetic` what the default method does), `… (all, fed
//!   back)` (θ̂ − (I − A B)⁻¹ b with the fit's A = ∂θ̂/∂η, B = ∂η̂/∂θ);
//!   `EIV est. + boot re-est. η` with replicates that re-estimate the noise
//!   (first `--bootstrap-reestimate-seeds` seeds); `EIV known + boot`.
//!
//! `--methods` adds rows (default `known,est`; `known` always runs):
//! `est-hgiven` (`EIV est. σ_ψ given`: the reference heading's white σ
//! given at the simulator's and its scale held, `--known-noise
//! heading-white`), `est-qgiven` (the encoder's q given,
//! `QuantisationLevel::Given`), `est-qgiven-hgiven`, `est-lat` (a_y and β
//! noise held at the production car's σ, `LateralNoise::Stated`),
//! `est-lat-given` (at the simulator's), `est-lat-hgiven`, `est-simtau`
//! (the production-car start with the simulator's time constants),
//! `est-model` (σ = H_θ⁻¹ alone, `CovarianceEstimate::Model`),
//! `est-undamped` (no secant damping of the η step), `known-spec` (the
//! base formulation of docs/method.md's Notes, `EivOptions::spec`: the measured-input noise scale,
//! no input log-Jacobian term, the 1 mm floor), `known-smoothed-share`
//! (`InputJacobian::SmoothedShare`), and `fo` (`+ fo` rows: each fit minus
//! its first-order bias, `EivReport::first_order_bias`, no extra filter
//! pass).
//!
//! The Cramér–Rao bound (`eiv::cramer_rao_bound` with `EivOptions::spec`)
//! is at θ_true with the true noise model, linearised along the drive's true
//! inputs. Per method and parameter: mean error, sd, RMS over the bound
//! (full Fisher, mean-only, and with the noise scales unknown, CRB_η), bias
//! t = |mean|/(sd/√n), coverage of ±1.96 σ for each reported σ (`H` = the
//! report's covariance; sandwich, block, Fisher); Ē_p on the drive's
//! validation segments against Ē_p(θ_true), and on a fresh drive (same
//! preset and length, seed + 10 000) that no method saw; wall time.

use std::collections::BTreeMap;
use std::time::Instant;

use odocal::eiv::{
    bootstrap, cramer_rao_bound, BootstrapInputs, BootstrapOptions, CovarianceEstimate, EivInput, EivOptions,
    EivReport, HeadingScale, InputJacobian, LateralNoise, NoiseModel, QuantisationLevel, QuantisationModel,
    ResearchOptions,
};
use odocal::segment::{validation_segments, ValidationSegmentOptions};
use odocal::EivMethodOptions;
use odocal::{calibrate, mean_position_error, CalibrationOptions, CalibrationReport, Drive, Method, Theta, Warning};
use odocal_lab::report_json::{eiv_part, EivPart};
use odocal_lab::{
    coverage, error_scale, errors, noise_preset, simulate_preset, Args, Res, Summary, Table, ERROR_UNITS,
    FRESH_SEED_OFFSET,
};
use serde::Serialize;

const USAGE: &str = "study_eiv [--km 12] [--seeds 20] [--presets off,white,paper,high,coloured] [--methods known,est]
    [--three-step-seeds 0] [--bootstrap B] [--bootstrap-seeds 0] [--bootstrap-presets paper,coloured]
    [--bootstrap-smooth K] [--bootstrap-antithetic] [--bootstrap-reestimate-seeds 0]
    [--quantisation process|measurement|counting] [--heading tied|separate]
    [--quantisation-level scaled|given|from-readings] [--hold-heading-offset] [--json out.json]

--bootstrap-smooth K: the replicates' true inputs are the ±K-sample moving average of the measured ones;
--bootstrap-antithetic: replicates in pairs with negated Gaussian draws; --hold-heading-offset: every
EIV start holds the reference heading offset at 0. Defaults of the filter options: the library's.";

struct Settings {
    km: f64,
    seeds: u64,
    presets: Vec<String>,
    methods: Vec<String>,
    three_step_seeds: u64,
    bootstrap: usize,
    bootstrap_seeds: u64,
    bootstrap_reestimate_seeds: u64,
    bootstrap_presets: Vec<String>,
    bootstrap_inputs: BootstrapInputs,
    bootstrap_antithetic: bool,
    quantisation: QuantisationModel,
    quantisation_level: QuantisationLevel,
    heading: HeadingScale,
    estimate_heading_offset: bool,
    json: Option<String>,
}

fn settings() -> Res<Settings> {
    let mut a = Args::parse(USAGE, &["bootstrap-antithetic", "hold-heading-offset"])?;
    let d = EivOptions::default();
    let s = Settings {
        km: a.get("km", 12.0)?,
        seeds: a.get("seeds", 20)?,
        presets: a.list("presets", &["off", "white", "paper", "high", "coloured"]),
        methods: a.list("methods", &["known", "est"]),
        three_step_seeds: a.get("three-step-seeds", 0)?,
        bootstrap: a.get("bootstrap", 0)?,
        bootstrap_seeds: a.get("bootstrap-seeds", 0)?,
        bootstrap_reestimate_seeds: a.get("bootstrap-reestimate-seeds", 0)?,
        bootstrap_presets: a.list("bootstrap-presets", &["paper", "coloured"]),
        bootstrap_inputs: match a.opt("bootstrap-smooth")? {
            Some(k) => BootstrapInputs::Smoothed { half_width_samples: k },
            None => BootstrapInputs::Measured,
        },
        bootstrap_antithetic: a.flag("bootstrap-antithetic"),
        quantisation: a.get("quantisation", d.quantisation)?,
        quantisation_level: a.get("quantisation-level", d.quantisation_level)?,
        heading: a.get("heading", d.heading_scale)?,
        estimate_heading_offset: !a.flag("hold-heading-offset"),
        json: a.opt("json")?,
    };
    a.finish()?;
    Ok(s)
}

/// One method's result on one drive.
#[derive(Debug, Clone, Serialize)]
struct Run {
    theta: Theta,
    /// Reported σ by kind (name, σ), SI.
    sigmas: Vec<(String, [f64; 4])>,
    e_p_m: f64,
    time_s: f64,
    /// Failed EIV checks (or failed bootstrap replicates).
    warnings: usize,
    /// Kinds of the failed EIV checks (`EivWarning`'s tag), one per finding.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    checks: Vec<String>,
}

impl Run {
    fn plain(theta: Theta, sigmas: Vec<(String, [f64; 4])>, e_p_m: f64, time_s: f64, warnings: usize) -> Run {
        Run { theta, sigmas, e_p_m, time_s, warnings, checks: Vec::new() }
    }
}

#[derive(Debug, Clone, Serialize)]
struct DriveResult {
    preset: String,
    seed: u64,
    theta_true: Theta,
    crb: [f64; 4],
    crb_mean_only: [f64; 4],
    /// The bound with the noise scales η unknown too (nuisance parameters).
    crb_noise_estimated: [f64; 4],
    e_p_true_m: f64,
    runs: BTreeMap<String, Run>,
    /// Ē_p on a fresh drive of the same preset (seed + 10 000), per method,
    /// minus Ē_p(θ_true) there, m.
    e_p_fresh_excess_m: BTreeMap<String, f64>,
}

/// `calibrate` with the EIV method (fallback and bias correction off) and
/// the given filter options; with `heading_offset` the start also estimates
/// the reference's heading offset.
fn calibrate_eiv(
    d: &Drive,
    filter: EivOptions,
    seed: u64,
    heading_offset: bool,
) -> Res<(CalibrationReport, EivPart, f64)> {
    let t = Instant::now();
    let method = Method::Eiv(EivMethodOptions {
        filter,
        fallback: false,
        bootstrap: None,
        estimate_heading_offset: heading_offset,
        correct_bias: None,
        // The filter as the row gives it (no fit at the heading readings' level first).
        heading_white_readings_first: false,
    });
    let r = calibrate(d, &CalibrationOptions { method, seed, ..Default::default() })?;
    let time_s = t.elapsed().as_secs_f64();
    let Some(detail) = eiv_part(&r) else {
        return Err("calibrate with Method::Eiv returned another method's report".into());
    };
    Ok((r, detail, time_s))
}

/// The EIV rows asked for: (label, filter options).
fn jobs(a: &Settings, true_noise: &NoiseModel) -> Vec<(&'static str, EivOptions)> {
    let base = EivOptions {
        quantisation: a.quantisation,
        quantisation_level: a.quantisation_level,
        heading_scale: a.heading,
        ..Default::default()
    };
    let known = EivOptions { noise: *true_noise, fix_noise: true, ..base.clone() };
    let est = base;
    let want = |m: &str| a.methods.iter().any(|x| x == m);
    let heading_given = |noise: NoiseModel| {
        let mut eta_held = [false; 6];
        eta_held[odocal::eiv::NoiseSource::HeadingWhite.index()] = true;
        let noise = NoiseModel { heading_white_sigma_rad: true_noise.heading_white_sigma_rad, ..noise };
        (noise, eta_held)
    };
    let q_given = NoiseModel { quantisation_step_rev_per_s: true_noise.quantisation_step_rev_per_s, ..est.noise };
    let lateral_given = NoiseModel {
        lateral_acceleration_sigma_m_per_s2: true_noise.lateral_acceleration_sigma_m_per_s2,
        sideslip_sigma_rad: true_noise.sideslip_sigma_rad,
        ..est.noise
    };
    let research = |r: ResearchOptions, o: &EivOptions| EivOptions { research: r, ..o.clone() };
    let mut out = vec![("EIV known", known.clone())];
    let mut add = |m: &str, label: &'static str, o: EivOptions| {
        if want(m) {
            out.push((label, o));
        }
    };
    add("est", "EIV est.", est.clone());
    let (noise, eta_held) = heading_given(est.noise);
    add("est-hgiven", "EIV est. σ_ψ given", EivOptions { noise, eta_held, ..est.clone() });
    let given = QuantisationLevel::Given;
    add("est-qgiven", "EIV est. q given", EivOptions { noise: q_given, quantisation_level: given, ..est.clone() });
    let (noise, eta_held) = heading_given(q_given);
    add(
        "est-qgiven-hgiven",
        "EIV est. q, σ_ψ given",
        EivOptions { noise, eta_held, quantisation_level: given, ..est.clone() },
    );
    let stated = LateralNoise::Stated;
    add("est-lat", "EIV est. lateral stated", EivOptions { lateral_noise: stated, ..est.clone() });
    add(
        "est-lat-given",
        "EIV est. lateral given",
        EivOptions { noise: lateral_given, lateral_noise: stated, ..est.clone() },
    );
    let (noise, eta_held) = heading_given(est.noise);
    add(
        "est-lat-hgiven",
        "EIV est. lateral stated, σ_ψ given",
        EivOptions { noise, eta_held, lateral_noise: stated, ..est.clone() },
    );
    let simtau = NoiseModel {
        wheel_common_time_constant_s: true_noise.wheel_common_time_constant_s,
        wheel_differential_time_constant_s: true_noise.wheel_differential_time_constant_s,
        drift_time_constant_s: true_noise.drift_time_constant_s,
        ..est.noise
    };
    add("est-simtau", "EIV est. sim τ", EivOptions { noise: simtau, ..est.clone() });
    let model = ResearchOptions { covariance_estimate: CovarianceEstimate::Model, ..Default::default() };
    add("est-model", "EIV est. model σ", research(model, &est));
    let undamped = ResearchOptions { eta_secant_damping: false, ..Default::default() };
    add("est-undamped", "EIV est. undamped η", research(undamped, &est));
    add("known-spec", "EIV known, base formulation", research(EivOptions::spec().research, &known));
    let smoothed = ResearchOptions { input_jacobian: InputJacobian::SmoothedShare, ..Default::default() };
    add("known-smoothed-share", "EIV known + jac smoothed", research(smoothed, &known));
    out
}

/// The report's σ of every kind: `H` (the reported covariance), sandwich, block, Fisher.
fn sigmas_of(r: &CalibrationReport, fit: &EivReport) -> Vec<(String, [f64; 4])> {
    let sigma_h: [f64; 4] = std::array::from_fn(|i| r.covariance[i][i].max(0.0).sqrt());
    vec![
        ("H".to_string(), sigma_h),
        ("sandwich".to_string(), fit.sigma_sandwich),
        ("block".to_string(), fit.sigma_block),
        ("Fisher".to_string(), fit.sigma_fisher),
    ]
}

/// The tag of every failed EIV check in `r`'s warnings.
fn failed_checks(r: &CalibrationReport) -> Vec<String> {
    r.warnings
        .iter()
        .filter_map(|w| match w {
            Warning::EivCheckFailed { finding, .. } => serde_json::to_value(finding)
                .ok()
                .and_then(|v| v.get("kind").and_then(|k| k.as_str()).map(str::to_string)),
            _ => None,
        })
        .collect()
}

/// What one drive needs to judge a θ: Ē_p on its validation segments.
struct Judge<'a> {
    drive: &'a Drive,
    validation: Vec<odocal::segment::Segment>,
}

impl Judge<'_> {
    fn ep(&self, t: &Theta) -> Res<f64> {
        Ok(mean_position_error(self.drive, &self.validation, t)?.mean_position_error_m)
    }
}

/// The bootstrap rows of the η-estimated fit `fit` (report `r`).
#[allow(clippy::too_many_arguments)]
fn bootstrap_rows(
    runs: &mut BTreeMap<String, Run>,
    judge: &Judge<'_>,
    input: &EivInput<'_>,
    r: &CalibrationReport,
    fit: &EivReport,
    opts: &EivOptions,
    boot_opts: &BootstrapOptions,
    (tag, seed, time_s, reestimate): (&str, u64, f64, bool),
) -> Res<()> {
    let sigma_h = vec![("H".to_string(), sigmas_of(r, fit)[0].1)];
    let mut variants = vec![(
        "EIV est. + boot held η̂",
        EivOptions { noise: fit.noise, fix_noise: true, free: fit.free, ..opts.clone() },
    )];
    if reestimate {
        variants.push(("EIV est. + boot re-est. η", EivOptions { free: fit.free, ..opts.clone() }));
    }
    for (row, filter) in variants {
        let t = Instant::now();
        let b = match bootstrap(input, fit, &filter, boot_opts) {
            Ok(b) => b,
            Err(e) => {
                eprintln!("{tag} {seed}: {row} failed: {e}");
                continue;
            }
        };
        let mc = b.mean_covariance();
        eprintln!(
            "  {tag} {seed} {row}: bias {:?}, replicate sd {:?}, Monte Carlo sd of the bias {:?}, pairs {}",
            b.bias,
            b.sd,
            [mc[0][0].sqrt(), mc[1][1].sqrt(), mc[2][2].sqrt(), mc[3][3].sqrt()],
            b.pair_means.len()
        );
        let time_s = time_s + t.elapsed().as_secs_f64();
        // c_e only corrected (`--correct-bias-of c_e`) and every parameter (`--correct-bias-of c_e,c_d,t_r,d`).
        let mut rows = vec![("", Theta { c_e: b.theta_corrected.c_e, ..r.theta }), (" (all)", b.theta_corrected)];
        if row == "EIV est. + boot held η̂" {
            // The held-noise bias b carried through the θ̂–η̂ feedback,
            // (I − A B)⁻¹ b, with A = ∂θ̂/∂η and B = ∂η̂/∂θ of the fit.
            let (a_s, b_s) = (fit.theta_eta_sensitivity, fit.eta_theta_sensitivity);
            let ab = nalgebra::Matrix4::from_fn(|i, k| (0..6).map(|j| a_s[i][j] * b_s[j][k]).sum::<f64>());
            let bias = nalgebra::Vector4::from(b.bias);
            let fed = (nalgebra::Matrix4::identity() - ab).try_inverse().map_or(bias, |m| m * bias);
            let u = <[_; 4]>::from(r.theta);
            rows.push((" (all, fed back)", Theta::from(std::array::from_fn(|i| u[i] - fed[i]))));
        }
        for (suffix, th) in rows {
            runs.insert(
                format!("{row}{suffix}"),
                Run::plain(th, sigma_h.clone(), judge.ep(&th)?, time_s, b.failed.len()),
            );
        }
    }
    Ok(())
}

/// The `+ fo` rows: the fit's θ minus its first-order bias (all, c_e only,
/// c_e's conditional bias, c_e's bias with the coloured-noise correction kept).
fn first_order_rows(
    runs: &mut BTreeMap<String, Run>,
    judge: &Judge<'_>,
    label: &str,
    fit: &EivReport,
    base: &Run,
) -> Res<()> {
    let Some(b) = &fit.first_order_bias else { return Ok(()) };
    let u = <[_; 4]>::from(fit.theta_uncorrected);
    for (suffix, shift) in [
        ("+ fo", b.bias),
        ("+ fo c_e", [b.bias[0], 0.0, 0.0, 0.0]),
        ("+ fo c_e cond", [b.bias_conditional[0], 0.0, 0.0, 0.0]),
        ("+ fo logdet c_e", [b.bias_logdet_only[0], 0.0, 0.0, 0.0]),
    ] {
        let th = Theta::from(std::array::from_fn(|i| u[i] - shift[i]));
        let run = Run::plain(th, base.sigmas.clone(), judge.ep(&th)?, base.time_s, base.warnings);
        runs.insert(format!("{label} {suffix}"), run);
    }
    Ok(())
}

fn study_drive(name: &str, seed: u64, a: &Settings) -> Res<DriveResult> {
    let sim = simulate_preset(name, a.km, seed)?;
    let d = &sim.drive;
    let truth = sim.sidecar.theta_true;
    let judge = Judge { drive: d, validation: validation_segments(d, &ValidationSegmentOptions::default())? };
    let input = EivInput::from_drive(d);
    let true_noise = NoiseModel::from_sim(&noise_preset(name)?, d.sample_time_s());
    let (crb, crb_mean_only, crb_noise_estimated) =
        match cramer_rao_bound(&EivInput::from_drive_truth(d)?, &truth, &true_noise, &EivOptions::spec()) {
            Ok(c) => (c.sigma, c.sigma_mean_only, c.sigma_noise_estimated.unwrap_or([f64::NAN; 4])),
            Err(_) => ([f64::NAN; 4], [f64::NAN; 4], [f64::NAN; 4]),
        };
    let mut runs = BTreeMap::new();
    if seed <= a.three_step_seeds {
        let t = Instant::now();
        let opts = CalibrationOptions { method: "three-step".parse::<Method>()?, seed, ..Default::default() };
        match calibrate(d, &opts) {
            Ok(r) => {
                runs.insert(
                    "3-step".into(),
                    Run::plain(r.theta, vec![], judge.ep(&r.theta)?, t.elapsed().as_secs_f64(), 0),
                );
            }
            Err(e) => eprintln!("{name} {seed}: 3-step failed: {e}"),
        }
    }
    let boot_opts = BootstrapOptions {
        replicates: a.bootstrap,
        seed,
        true_inputs: a.bootstrap_inputs,
        antithetic: a.bootstrap_antithetic,
        ..Default::default()
    };
    let boot_here = a.bootstrap >= 2 && seed <= a.bootstrap_seeds && a.bootstrap_presets.iter().any(|p| p == name);
    for (label, opts) in jobs(a, &true_noise) {
        // A fixed (given) noise model is an oracle row: it also knows the
        // reference heading offset (0 here), as the Cramér–Rao bound does.
        let estimate_delta = a.estimate_heading_offset && !opts.fix_noise;
        let (r, detail, time_s) = match calibrate_eiv(d, opts.clone(), seed, estimate_delta) {
            Ok(x) => x,
            Err(e) => {
                eprintln!("{name} {seed}: {label} failed: {e}");
                continue;
            }
        };
        let gn = detail.identification.theta;
        if label == "EIV known" {
            let t_gn = r.timing().initial_identification;
            runs.insert("G-N".to_string(), Run::plain(gn, vec![], judge.ep(&gn)?, t_gn, 0));
        }
        let Some(fit) = detail.eiv.as_deref() else {
            eprintln!("{name} {seed}: {label}: the filter failed: {:?}", detail.eiv_error);
            continue;
        };
        if let Some(p) = fit.passes.last() {
            let step = p.eta_step_over_sigma.unwrap_or(f64::NAN);
            eprintln!(
                "  {name} {seed} {label}: iterations {}, {:?}, last η step/σ {step:.3}",
                p.history.len(),
                p.termination
            );
        }
        let sigmas = sigmas_of(&r, fit);
        let checks = failed_checks(&r);
        let run = Run {
            theta: r.theta,
            sigmas: sigmas.clone(),
            e_p_m: judge.ep(&r.theta)?,
            time_s,
            warnings: checks.len(),
            checks,
        };
        if a.methods.iter().any(|m| m == "fo") {
            first_order_rows(&mut runs, &judge, label, fit, &run)?;
        }
        if label == "EIV est." {
            // What a user gets with the default fallback on: G-N when a check failed.
            let (th, sig) = if run.warnings > 0 { (gn, vec![]) } else { (r.theta, sigmas) };
            runs.insert(format!("{label} + fallback"), Run::plain(th, sig, judge.ep(&th)?, time_s, run.warnings));
            if boot_here {
                let reestimate = seed <= a.bootstrap_reestimate_seeds;
                bootstrap_rows(
                    &mut runs,
                    &judge,
                    &input,
                    &r,
                    fit,
                    &opts,
                    &boot_opts,
                    (name, seed, time_s, reestimate),
                )?;
            }
        }
        if label == "EIV known" && boot_here {
            let t = Instant::now();
            match bootstrap(&input, fit, &EivOptions { free: fit.free, ..opts.clone() }, &boot_opts) {
                Ok(b) => {
                    let th = b.theta_corrected;
                    let half: [f64; 4] = std::array::from_fn(|i| (b.interval[i][1] - b.interval[i][0]) / (2.0 * 1.96));
                    let sig = vec![("H".into(), sigmas_of(&r, fit)[0].1), ("boot".into(), half)];
                    let time = time_s + t.elapsed().as_secs_f64();
                    runs.insert("EIV known + boot".into(), Run::plain(th, sig, judge.ep(&th)?, time, b.failed.len()));
                }
                Err(e) => eprintln!("{name} {seed}: bootstrap failed: {e}"),
            }
        }
        runs.insert(label.to_string(), run);
    }
    // Ē_p on a drive no method saw: in-sample, a θ can lower Ē_p below
    // Ē_p(θ_true) by fitting this drive's noise; on a fresh drive it cannot.
    let fresh = simulate_preset(name, a.km, seed + FRESH_SEED_OFFSET)?;
    let fresh_judge = Judge {
        drive: &fresh.drive,
        validation: validation_segments(&fresh.drive, &ValidationSegmentOptions::default())?,
    };
    let fresh_true = fresh_judge.ep(&truth)?;
    let mut e_p_fresh_excess_m = BTreeMap::new();
    for (m, r) in &runs {
        e_p_fresh_excess_m.insert(m.clone(), fresh_judge.ep(&r.theta)? - fresh_true);
    }
    Ok(DriveResult {
        preset: name.into(),
        seed,
        theta_true: truth,
        crb,
        crb_mean_only,
        crb_noise_estimated,
        e_p_true_m: judge.ep(&truth)?,
        runs,
        e_p_fresh_excess_m,
    })
}

/// Per parameter, the mean over drives of a bound's σ in [`ERROR_UNITS`].
fn mean_bound(results: &[DriveResult], f: fn(&DriveResult) -> [f64; 4]) -> [f64; 4] {
    std::array::from_fn(|i| {
        let v: Vec<f64> = results.iter().map(|r| f(r)[i] * error_scale(&r.theta_true)[i]).collect();
        Summary::of(&v).mean
    })
}

fn summarise(preset: &str, results: &[DriveResult]) {
    let mut methods: Vec<String> = Vec::new();
    for m in results.iter().flat_map(|r| r.runs.keys()) {
        if !methods.contains(m) {
            methods.push(m.clone());
        }
    }
    println!("\n### {preset} ({} drives)\n", results.len());
    let crb = mean_bound(results, |r| r.crb);
    let crb_mo = mean_bound(results, |r| r.crb_mean_only);
    let crb_ne = mean_bound(results, |r| r.crb_noise_estimated);
    let cells = |b: &[f64; 4]| (0..4).map(|i| format!("{} {:.4}", ERROR_UNITS[i], b[i])).collect::<Vec<_>>().join(", ");
    println!(
        "CRB σ (full Fisher): {}; mean-only: {}; noise scales unknown too (CRB_η): {}\n",
        cells(&crb),
        cells(&crb_mo),
        cells(&crb_ne)
    );
    let mut t = Table::new(&[
        "method",
        ">n",
        "parameter",
        ">mean error",
        ">sd",
        ">RMS/CRB",
        ">RMS/CRB mean-only",
        ">RMS/CRB_η",
        ">t",
        "coverage (σ kinds)",
    ]);
    for m in &methods {
        let rs: Vec<(&DriveResult, &Run)> = results.iter().filter_map(|r| r.runs.get(m).map(|x| (r, x))).collect();
        for i in 0..4 {
            let errs: Vec<f64> = rs.iter().map(|(r, x)| errors(&x.theta, &r.theta_true)[i]).collect();
            let s = Summary::of(&errs);
            let mut cov = Vec::new();
            for (k, (kind, _)) in rs.first().map_or(&[][..], |(_, x)| &x.sigmas[..]).iter().enumerate() {
                let sig: Vec<f64> = rs
                    .iter()
                    .map(|(r, x)| x.sigmas.get(k).map_or(f64::NAN, |s| s.1[i]) * error_scale(&r.theta_true)[i])
                    .collect();
                cov.push(format!("{kind} {:.0} %", 100.0 * coverage(&errs, &sig, 1.96)));
            }
            t.row([
                m.clone(),
                s.n.to_string(),
                ERROR_UNITS[i].to_string(),
                format!("{:+.4}", s.mean),
                format!("{:.4}", s.sd),
                format!("{:.2}", s.rms / crb[i]),
                format!("{:.2}", s.rms / crb_mo[i]),
                format!("{:.2}", s.rms / crb_ne[i]),
                format!("{:.1}", s.t()),
                cov.join(", "),
            ]);
        }
    }
    println!("{t}");
    let mut t = Table::new(&[
        "method",
        ">Ē_p − Ē_p(θ_true) mean, m",
        ">max, m",
        ">fresh drive: mean, m",
        ">max, m",
        ">mean wall s",
        "runs with a failed EIV check",
    ]);
    for m in &methods {
        let rs: Vec<(&DriveResult, &Run)> = results.iter().filter_map(|r| r.runs.get(m).map(|x| (r, x))).collect();
        let ex: Vec<f64> = rs.iter().map(|(r, x)| x.e_p_m - r.e_p_true_m).collect();
        let fx: Vec<f64> = rs.iter().filter_map(|(r, _)| r.e_p_fresh_excess_m.get(m).copied()).collect();
        let max = |v: &[f64]| v.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let time = Summary::of(&rs.iter().map(|(_, x)| x.time_s).collect::<Vec<_>>()).mean;
        let warned = rs.iter().filter(|(_, x)| x.warnings > 0).count();
        // Runs with each kind of failed check.
        let mut kinds: BTreeMap<&str, usize> = BTreeMap::new();
        for (_, x) in &rs {
            let mut seen: Vec<&str> = x.checks.iter().map(String::as_str).collect();
            seen.sort_unstable();
            seen.dedup();
            for k in seen {
                *kinds.entry(k).or_default() += 1;
            }
        }
        let kinds: Vec<String> = kinds.iter().map(|(k, n)| format!("{k} {n}")).collect();
        let kinds = if kinds.is_empty() { String::new() } else { format!(" ({})", kinds.join(", ")) };
        t.row([
            m.clone(),
            format!("{:+.4}", Summary::of(&ex).mean),
            format!("{:+.4}", max(&ex)),
            format!("{:+.4}", Summary::of(&fx).mean),
            format!("{:+.4}", max(&fx)),
            format!("{time:.2}"),
            format!("{warned}{kinds}"),
        ]);
    }
    println!("{t}");
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let a = settings()?;
    let t0 = Instant::now();
    let mut all = Vec::new();
    for p in &a.presets {
        let mut results = Vec::new();
        for seed in 1..=a.seeds {
            let r = study_drive(p, seed, &a)?;
            let line: Vec<String> = r
                .runs
                .iter()
                .map(|(k, x)| {
                    let e = errors(&x.theta, &r.theta_true).map(|v| format!("{v:+.4}"));
                    format!("{k} [{}] {:.2}s", e.join(" "), x.time_s)
                })
                .collect();
            eprintln!("{p} {seed}: {}", line.join(" | "));
            results.push(r);
        }
        summarise(p, &results);
        all.extend(results);
    }
    println!("\nTotal wall time {:.0} s", t0.elapsed().as_secs_f64());
    if let Some(path) = &a.json {
        std::fs::write(path, serde_json::to_string_pretty(&all)?)?;
    }
    Ok(())
}
