//! The errors-in-variables study (docs/study.md, section "EIV"): batch
//! Gauss-Newton on all segments, the paper's 3-step and EIV on simulated
//! drives, read against the Cramér–Rao bound.
//!
//! ```text
//! cargo run --release -p odocal --example study_eiv -- [--km 12] [--seeds 20]
//!     [--presets off,white,paper,high,coloured] [--three-step-seeds 0]
//!     [--bootstrap 0] [--bootstrap-smooth K (replicates' true inputs: ±K moving average, stop 14)] [--bootstrap-antithetic (pairs with negated Gaussian draws, stop 21)] [--bootstrap-seeds 0] [--bootstrap-presets paper,coloured] [--json out.json]
//!     [--quantisation process|measurement|counting] [--heading tied|separate]
//!     [--quantisation-level scaled|given|from-readings] (defaults: the library's EivOptions)
//!     [--hold-heading-offset] (every EIV run's batch G-N start holds the reference heading offset at 0, the
//!     stop-14 default; by default it estimates it, `EivMethodOptions::estimate_heading_offset`, except
//!     for rows with a fixed noise model such as `known`: those are oracle rows and hold it at its true 0)
//!     [--methods known,est] (also: est-qgiven = `est` with the encoder's q given, est-qgiven-hgiven = est-qgiven
//!     with the reference's heading white σ given too and η_5 held (stop 14; with `--bootstrap B` also
//!     `+ boot held η̂`: every parameter minus the bias of a bootstrap holding the fitted noise), est-thconv = `est` with `theta_convergence`, est-it20 = `est` with 20 iterations, est-final = `est` with `final_step_check`, est-stop11 = `est` with the stop-11 checks and iteration, fitted, fo, esttau, estsimtau, jac-*, est-jac-*, smooth*, ref*, no-known-boot; stop 17: est-lat = `est` with `LateralNoise::Stated` at the production car's a_y and β σ, est-lat-given = the same at the simulator's, est-tied = `LateralNoise::TiedToWheelWhite`, the default; est-hgiven / est-lat-hgiven = `est` / `est-lat` with the simulator's heading white σ given and η_5 held)
//!     [--tau-candidates] [--bootstrap-reestimate-seeds 0] [--smooth-half-width 20]
//!     [--reentry-score 10] (with `--methods est-reentry`: `EIV est. reentry` = `est` with
//!     `EivOptions::eta_reentry_min_score` = that value, stop 13; `est-robust`: `est` with
//!     `CovarianceEstimate::LargerOfModelAndBlock`, the default since stop 13; `est-model`: `est`
//!     with `CovarianceEstimate::Model`, the σ before stop 13; `est-reentry-robust`: both)
//! ```
//!
//! Per preset and seed (1..=S) it simulates a drive and runs, all through
//! `odocal::calibrate` as a user would:
//! - `G-N`: batch Gauss-Newton from θ_0 on every cut segment (no yaw-rate
//!   selection) — the EIV method's own start (`EivDetail::identification`);
//! - `3-step`: the paper's method (first `--three-step-seeds` seeds only);
//! - `EIV known`: `Method::Eiv` with the simulator's noise model, fixed
//!   (`--fix-noise`), fallback off;
//! - `EIV est.`: `Method::Eiv` with the default options (η estimated from
//!   the production-car model), fallback off: the estimator itself;
//! - `EIV est. + fallback`: the same run as a user gets it with the default
//!   fallback on (θ = G-N when a consistency check failed; no extra fit);
//! - `EIV known + boot`: the known-noise estimate minus its parametric
//!   bootstrap bias (`--bootstrap B` replicates, first `--bootstrap-seeds` seeds
//!   of `--bootstrap-presets`);
//! - with `est` and `--bootstrap B`: `EIV est. + boot held η̂` = the
//!   η-estimated fit with c_e corrected by a bootstrap whose replicates hold
//!   the fitted noise model (fixed-noise re-fits), and `EIV est. + boot
//!   re-est. η` = the same with η re-estimated in every replicate (first
//!   `--bootstrap-reestimate-seeds` seeds); each also as `… (all)`, every
//!   parameter corrected (stop 20; `… boot held η̂ (all)` with
//!   `--bootstrap-smooth 20` is what the CLI's `--correct-bias` does), and
//!   for the held rows `… (all, fed back)`: θ̂ − (I − A B)⁻¹ b with the fit's
//!   `A = ∂θ̂/∂η` and `B = ∂η̂/∂θ` (tried in stop 20, not adopted);
//! - with `--methods` containing `fitted`: `EIV fitted` = EIV known with
//!   `WheelNoiseScale::FittedInput` (the relative wheel noise scaled by the
//!   fitted true input);
//! - `jac-unit`, `jac-filter`, `jac-smoothed`: `EIV fitted` plus the input
//!   log-Jacobian term (`InputJacobian::Unit`, `FilterShare`,
//!   `SmoothedShare`), `jac-filter2` (`FilterShareSecondOrder`), `jac-all` (`SmoothedShareAll`; `known-jac-all` on the
//!   measured-input filter); `smooth`, `smooth-jac-smoothed`, `smooth-jac-all`,
//!   `smooth-jac-filter`: `WheelNoiseScale::SmoothedFittedInput` (±`--smooth-half-width`
//!   samples) without and with the term; `est-smooth`, `est-smooth-jac-smoothed`,
//!   `est-smooth-jac-filter`: the same with η estimated; `ref`, `ref-jac-*`,
//!   `est-ref-jac-*`: `WheelNoiseScale::ReferenceInput`; `est-fitted`, `est-jac-filter`, `est-jac-smoothed`:
//!   the same with η estimated (the `est` options with the fitted input);
//! - with `fo`: rows derived from each known-noise fit without another
//!   filter pass (`EivReport::first_order_bias`): `+ fo` = θ − b for every
//!   parameter, `+ fo c_e` = c_e − b_ce only, `+ fo c_e cond` = c_e minus the
//!   conditional bias, `+ fo logdet c_e` = c_e minus the bias with the
//!   coloured-noise correction kept (J + ½Σ log det S);
//! - with `esttau`: `EIV est. τ` = `EIV est.` with the Gauss-Markov time
//!   constants estimated too (`EivOptions::estimate_time_constants`, the
//!   default grid); the chosen τ (wheel common, per-wheel, drift) are
//!   summarised against the simulator's; with `estsimtau`: `EIV est. sim τ`
//!   = `EIV est.` started from the production-car model with the
//!   simulator's time constants (τ_c = τ_w = the coloured wheel τ, drift τ =
//!   the position drift's), fixed: what a perfect τ estimate could give.
//!
//! The Cramér–Rao bound (`eiv::cramer_rao_bound`, full Gaussian Fisher
//! information, and its mean-only part) at θ_true with the true noise model,
//! linearised along the drive's true inputs (`EivInput::from_drive_truth`;
//! before stop 25 along the measured ones, which overstated t_r's and d's
//! information about 2× on `high`).
//! Per method and parameter: mean error, sd, RMS/CRB, bias t = |mean|/(sd/√n),
//! coverage of ±1.96 σ for each reported σ (EIV: σ = the report's covariance
//! `H⁻¹`, sandwich, Fisher); Ē_p on the drive's validation segments
//! against Ē_p(θ_true), and on a fresh drive (same preset and length, the
//! seed plus 10 000) that no method saw, where fitting the drive's own noise
//! cannot lower Ē_p; wall time.
//!
//! `coloured` is the paper preset's wheel noise (white, encoder, common and
//! per-wheel coloured; no slip) on a perfect reference (no pose, a_y or β noise).

use std::collections::BTreeMap;
use std::error::Error;
use std::time::Instant;

use odocal::calibrate::{EivDetail, EivMethodOptions};
use odocal::drive::segment::validation_segments;
use odocal::eiv::{
    bootstrap, cramer_rao_bound, BootstrapInputs, BootstrapOptions, CovarianceEstimate, EivInput, EivOptions,
    HeadingScale, InputJacobian, NoiseModel, QuantisationLevel, QuantisationModel, WheelNoiseScale,
};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{
    calibrate, mean_position_error, CalibrationOptions, CalibrationReport, Drive, Method, MethodDetail, Theta,
    ValidationSegmentOptions, Warning,
};
use serde::Serialize;

type Res<T> = Result<T, Box<dyn Error>>;

struct Args {
    km: f64,
    seeds: u64,
    presets: Vec<String>,
    three_step_seeds: u64,
    bootstrap: usize,
    bootstrap_seeds: u64,
    bootstrap_reestimate_seeds: u64,
    smooth_half_width: usize,
    bootstrap_presets: Vec<String>,
    json: Option<String>,
    quantisation: QuantisationModel,
    quantisation_level: QuantisationLevel,
    heading: HeadingScale,
    methods: Vec<String>,
    /// Print every candidate of the time-constant search (`--tau-candidates`).
    tau_candidates: bool,
    /// `EivOptions::eta_reentry_min_score` of the `est-reentry` method (`--reentry-score`).
    reentry_score: f64,
    /// The replicate worlds' true inputs (`--bootstrap-smooth K`: moving average ±K, stop 14).
    bootstrap_inputs: BootstrapInputs,
    /// Every EIV run's start also estimates the reference heading offset
    /// (the library default; `--hold-heading-offset` holds it at 0; the
    /// `G-N` rows are that start).
    estimate_heading_offset: bool,
    /// The bootstrap rows' replicates in antithetic pairs (`--bootstrap-antithetic`, stop 21).
    bootstrap_antithetic: bool,
}

fn parse_args() -> Res<Args> {
    let mut a = Args {
        km: 12.0,
        seeds: 20,
        presets: ["off", "white", "paper", "high", "coloured"].iter().map(|s| s.to_string()).collect(),
        three_step_seeds: 0,
        bootstrap: 0,
        bootstrap_seeds: 0,
        bootstrap_reestimate_seeds: 0,
        smooth_half_width: 20,
        bootstrap_presets: vec!["paper".into(), "coloured".into()],
        json: None,
        quantisation: EivOptions::default().quantisation,
        quantisation_level: EivOptions::default().quantisation_level,
        heading: EivOptions::default().heading_scale,
        methods: vec!["known".into(), "est".into()],
        tau_candidates: false,
        reentry_score: 10.0,
        bootstrap_inputs: BootstrapInputs::Measured,
        estimate_heading_offset: EivMethodOptions::default().estimate_heading_offset,
        bootstrap_antithetic: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(k) = it.next() {
        if k == "--tau-candidates" {
            a.tau_candidates = true;
            continue;
        }
        if k == "--bootstrap-antithetic" {
            a.bootstrap_antithetic = true;
            continue;
        }
        if k == "--hold-heading-offset" {
            a.estimate_heading_offset = false;
            continue;
        }
        let mut v = || it.next().ok_or_else(|| format!("{k} needs a value"));
        match k.as_str() {
            "--km" => a.km = v()?.parse()?,
            "--seeds" => a.seeds = v()?.parse()?,
            "--presets" => a.presets = v()?.split(',').map(str::to_string).collect(),
            "--three-step-seeds" => a.three_step_seeds = v()?.parse()?,
            "--reentry-score" => a.reentry_score = v()?.parse()?,
            "--bootstrap" => a.bootstrap = v()?.parse()?,
            "--bootstrap-seeds" => a.bootstrap_seeds = v()?.parse()?,
            "--bootstrap-reestimate-seeds" => a.bootstrap_reestimate_seeds = v()?.parse()?,
            "--smooth-half-width" => a.smooth_half_width = v()?.parse()?,
            "--bootstrap-presets" => a.bootstrap_presets = v()?.split(',').map(str::to_string).collect(),
            "--json" => a.json = Some(v()?),
            "--methods" => a.methods = v()?.split(',').map(str::to_string).collect(),
            "--bootstrap-smooth" => {
                a.bootstrap_inputs = BootstrapInputs::Smoothed { half_width_samples: v()?.parse()? };
            }
            "--heading" => a.heading = v()?.parse()?,
            "--quantisation" => a.quantisation = v()?.parse()?,
            "--quantisation-level" => a.quantisation_level = v()?.parse()?,
            other => return Err(format!("unknown argument '{other}'").into()),
        }
    }
    Ok(a)
}

fn preset(name: &str) -> Res<NoiseOptions> {
    if name == "coloured" {
        return Ok(NoiseOptions::coloured_wheels_only());
    }
    Ok(NoiseOptions::by_name(name)?)
}

/// `calibrate` with the EIV method (fallback off) and the given filter
/// options; with `heading_offset` the start also estimates the reference's
/// heading offset (the library default) and the filter runs on the poses it
/// implies.
fn calibrate_eiv(
    d: &Drive,
    filter: EivOptions,
    seed: u64,
    heading_offset: bool,
) -> Res<(CalibrationReport, EivDetail, f64)> {
    let t = Instant::now();
    let method = Method::Eiv(EivMethodOptions {
        filter,
        fallback: false,
        bootstrap: None,
        estimate_heading_offset: heading_offset,
        // The rows are the uncorrected fits; the `+ boot` rows correct them
        // (`… (all)` with `--bootstrap 4 --bootstrap-smooth 20
        // --bootstrap-antithetic` is the method's default since stop 21).
        correct_bias: None,
    });
    let opts = CalibrationOptions { method, seed, ..Default::default() };
    let r = calibrate(d, &opts, None)?;
    let time_s = t.elapsed().as_secs_f64();
    let MethodDetail::Eiv(detail) = &r.detail else {
        return Err("calibrate with Method::Eiv returned another method's detail".into());
    };
    let detail = detail.clone();
    Ok((r, detail, time_s))
}

/// One method's result on one drive.
#[derive(Debug, Clone, Serialize)]
struct Run {
    theta: Theta,
    /// Reported σ by kind (name, σ), SI.
    sigmas: Vec<(String, [f64; 4])>,
    e_p_m: f64,
    time_s: f64,
    warnings: usize,
    /// Time constants chosen by the τ search `[τ_c, τ_w, τ_drift]`, s.
    tau_s: Option<[f64; 3]>,
    /// Kinds of the failed EIV checks (`EivWarning`'s tag), one per finding.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    checks: Vec<String>,
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

/// Seed offset of the fresh drive each θ is also validated on.
const FRESH_SEED_OFFSET: u64 = 10_000;

fn study_drive(name: &str, seed: u64, a: &Args) -> Res<DriveResult> {
    let noise = preset(name)?;
    let sim = simulate(&SimOptions { length_km: a.km, noise: noise.clone(), ..SimOptions::paper(seed) })?;
    let d = &sim.drive;
    let truth = sim.sidecar.theta_true;
    let val = validation_segments(d, &ValidationSegmentOptions::default())?;
    let ep = |t: &Theta| -> Res<f64> { Ok(mean_position_error(d, &val, t)?.mean_position_error_m) };
    let input = EivInput::from_drive(d);
    let true_noise = NoiseModel::from_sim(&noise, d.sample_time_s());
    let (crb, crb_mean_only, crb_noise_estimated) =
        match cramer_rao_bound(&EivInput::from_drive_truth(d)?, &truth, &true_noise, &EivOptions::spec()) {
            Ok(c) => (c.sigma, c.sigma_mean_only, c.sigma_noise_estimated.unwrap_or([f64::NAN; 4])),
            Err(_) => ([f64::NAN; 4], [f64::NAN; 4], [f64::NAN; 4]),
        };
    let mut runs = BTreeMap::new();
    if seed <= a.three_step_seeds {
        let t = Instant::now();
        let opts = CalibrationOptions { method: Method::from_name("three-step")?, seed, ..Default::default() };
        match calibrate(d, &opts, None) {
            Ok(r) => {
                let th = r.theta;
                let time_s = t.elapsed().as_secs_f64();
                runs.insert(
                    "3-step".into(),
                    Run {
                        theta: th,
                        sigmas: vec![],
                        e_p_m: ep(&th)?,
                        time_s,
                        warnings: 0,
                        tau_s: None,
                        checks: vec![],
                    },
                );
            }
            Err(e) => eprintln!("{name} {seed}: 3-step failed: {e}"),
        }
    }
    let q = a.quantisation;
    let h = a.heading;
    let ql = a.quantisation_level;
    let known = EivOptions {
        noise: true_noise,
        fix_noise: true,
        quantisation: q,
        quantisation_level: ql,
        heading_scale: h,
        ..Default::default()
    };
    let est = EivOptions { quantisation: q, quantisation_level: ql, heading_scale: h, ..Default::default() };
    let fitted = EivOptions { wheel_noise_scale: WheelNoiseScale::FittedInput, ..known.clone() };
    let want = |m: &str| a.methods.iter().any(|x| x == m);
    // The known-noise fit always runs: it carries the G-N start.
    let mut jobs = vec![("EIV known", known.clone())];
    if want("est") {
        jobs.push(("EIV est.", est.clone()));
    }
    if want("est-reentry") {
        // Stop 13: a noise scale at its lower clamp re-enters when its score
        // test exceeds `--reentry-score`.
        let o = EivOptions { eta_reentry_min_score: Some(a.reentry_score), ..est.clone() };
        jobs.push(("EIV est. reentry", o));
    }
    let robust = CovarianceEstimate::LargerOfModelAndBlock;
    if want("est-model") {
        // The covariance before stop 13 (H_θ⁻¹ alone; `est` now raises σ to the block sandwich's).
        jobs.push(("EIV est. model σ", EivOptions { covariance_estimate: CovarianceEstimate::Model, ..est.clone() }));
    }
    if want("est-robust") {
        // Stop 13: the reported σ raised to the block sandwich's (the default since stop 13).
        jobs.push(("EIV est. robust", EivOptions { covariance_estimate: robust, ..est.clone() }));
    }
    if want("est-reentry-robust") {
        let o = EivOptions { eta_reentry_min_score: Some(a.reentry_score), covariance_estimate: robust, ..est.clone() };
        jobs.push(("EIV est. reentry robust", o));
    }
    if want("est-lat") {
        // Stop 17: a_y and β noise held at the production car's σ
        // (`LateralNoise::Stated`), not scaled by η_0.
        let o = EivOptions { lateral_noise: odocal::eiv::LateralNoise::Stated, ..est.clone() };
        jobs.push(("EIV est. lateral stated", o));
    }
    if want("est-lat-hgiven") {
        // Stop 17: `est-lat` with the reference's heading white σ given too
        // (the simulator's, η_5 held: `--lateral-noise stated --known-noise
        // heading-white` with the INS datasheet's σ_ψ).
        let noise = NoiseModel { heading_white_sigma_rad: true_noise.heading_white_sigma_rad, ..est.noise };
        let mut eta_held = [false; 6];
        eta_held[5] = true;
        let o = EivOptions { noise, eta_held, lateral_noise: odocal::eiv::LateralNoise::Stated, ..est.clone() };
        jobs.push(("EIV est. lateral stated, σ_ψ given", o));
    }
    if want("est-hgiven") {
        // …the same with the tie (the default's lateral noise).
        let noise = NoiseModel { heading_white_sigma_rad: true_noise.heading_white_sigma_rad, ..est.noise };
        let mut eta_held = [false; 6];
        eta_held[5] = true;
        jobs.push(("EIV est. σ_ψ given", EivOptions { noise, eta_held, ..est.clone() }));
    }
    if want("est-tied") {
        // …and tied to the white wheel noise by η_0 (the default, explicitly).
        let o = EivOptions { lateral_noise: odocal::eiv::LateralNoise::TiedToWheelWhite, ..est.clone() };
        jobs.push(("EIV est. lateral tied", o));
    }
    if want("est-lat-given") {
        // …at the simulator's σ (a user stating the IMU's and the sideslip
        // source's noise).
        let noise = NoiseModel {
            lateral_acceleration_sigma_m_per_s2: true_noise.lateral_acceleration_sigma_m_per_s2,
            sideslip_sigma_rad: true_noise.sideslip_sigma_rad,
            ..est.noise
        };
        let o = EivOptions { noise, lateral_noise: odocal::eiv::LateralNoise::Stated, ..est.clone() };
        jobs.push(("EIV est. lateral given", o));
    }
    if want("est-qgiven") {
        // The encoder's quantisation step given (the simulator's ticks per
        // revolution), not scaled by η_0 (`QuantisationLevel::Given`).
        let noise = NoiseModel {
            quantisation_step_rev_per_s: true_noise.quantisation_step_rev_per_s,
            ..NoiseModel::PRODUCTION_CAR
        };
        jobs.push((
            "EIV est. q given",
            EivOptions { noise, quantisation_level: odocal::eiv::QuantisationLevel::Given, ..est.clone() },
        ));
    }
    if want("est-qgiven-hgiven") {
        // Stop 14: as `est-qgiven`, with the reference's heading white noise
        // also given (the simulator's σ_ψ) and its scale η_5 held
        // (`EivOptions::eta_held`).
        let noise = NoiseModel {
            quantisation_step_rev_per_s: true_noise.quantisation_step_rev_per_s,
            heading_white_sigma_rad: true_noise.heading_white_sigma_rad,
            ..NoiseModel::PRODUCTION_CAR
        };
        let mut eta_held = [false; 6];
        eta_held[5] = true;
        jobs.push((
            "EIV est. q, σ_ψ given",
            EivOptions { noise, quantisation_level: odocal::eiv::QuantisationLevel::Given, eta_held, ..est.clone() },
        ));
    }
    if want("est-thconv") {
        // Stop 13: convergence judged on θ (its step and the θ change the
        // remaining η step would cause).
        jobs.push(("EIV est. θ-conv", EivOptions { theta_convergence: true, ..est.clone() }));
    }
    if want("est-final") {
        // Stop 13: the convergence test on the step remaining at the end of
        // each iteration (also at the iteration limit).
        jobs.push(("EIV est. final-check", EivOptions { final_step_check: true, ..est.clone() }));
    }
    if want("est-it20") {
        // Stop 13: a larger iteration limit.
        jobs.push(("EIV est. it20", EivOptions { max_iterations: 20, ..est.clone() }));
    }
    if want("est-stop11") {
        // The stop-11 checks and iteration: no secant damping of the η
        // step, innovation checks against the fitted model with the floors.
        let before = EivOptions {
            eta_secant_damping: false,
            innovation_null: odocal::eiv::InnovationNull::FittedModel,
            ..est.clone()
        };
        jobs.push(("EIV est. stop-11", before));
    }
    if want("fitted") {
        jobs.push(("EIV fitted", fitted.clone()));
    }
    // The input log-Jacobian term on the fitted-input filter (known noise),
    // and with η estimated (`est-jac-*`).
    let est_fitted = EivOptions { wheel_noise_scale: WheelNoiseScale::FittedInput, ..est.clone() };
    for (m, label, jac) in [
        ("jac-unit", "EIV fitted + jac unit", InputJacobian::Unit),
        ("jac-filter", "EIV fitted + jac filter", InputJacobian::FilterShare),
        ("jac-filter2", "EIV fitted + jac filter2", InputJacobian::FilterShareSecondOrder),
        ("jac-smoothed", "EIV fitted + jac smoothed", InputJacobian::SmoothedShare),
        ("jac-all", "EIV fitted + jac all", InputJacobian::SmoothedShareAll),
        ("known-jac-all", "EIV known + jac all", InputJacobian::SmoothedShareAll),
        ("smooth", "EIV smoothed-input", InputJacobian::None),
        ("smooth-jac-smoothed", "EIV smoothed-input + jac smoothed", InputJacobian::SmoothedShare),
        ("smooth-jac-all", "EIV smoothed-input + jac all", InputJacobian::SmoothedShareAll),
        ("smooth-jac-filter", "EIV smoothed-input + jac filter", InputJacobian::FilterShare),
        ("ref", "EIV reference-input", InputJacobian::None),
        ("ref-jac-smoothed", "EIV reference-input + jac smoothed", InputJacobian::SmoothedShare),
        ("ref-jac-all", "EIV reference-input + jac all", InputJacobian::SmoothedShareAll),
        ("ref-jac-filter", "EIV reference-input + jac filter", InputJacobian::FilterShare),
    ] {
        if want(m) {
            let smoothed = EivOptions {
                wheel_noise_scale: WheelNoiseScale::SmoothedFittedInput { half_width_samples: a.smooth_half_width },
                ..known.clone()
            };
            let reference = EivOptions {
                wheel_noise_scale: WheelNoiseScale::ReferenceInput { half_width_samples: a.smooth_half_width },
                ..known.clone()
            };
            let base = if m.starts_with("known") {
                &known
            } else if m.starts_with("ref") {
                &reference
            } else if m.starts_with("smooth") {
                &smoothed
            } else {
                &fitted
            };
            jobs.push((label, EivOptions { input_jacobian: jac, ..base.clone() }));
        }
    }
    for (m, label, jac) in [
        ("est-fitted", "EIV est. fitted", InputJacobian::None),
        ("est-jac-filter", "EIV est. fitted + jac filter", InputJacobian::FilterShare),
        ("est-jac-filter2", "EIV est. fitted + jac filter2", InputJacobian::FilterShareSecondOrder),
        ("est-jac-smoothed", "EIV est. fitted + jac smoothed", InputJacobian::SmoothedShare),
        ("est-jac-all", "EIV est. fitted + jac all", InputJacobian::SmoothedShareAll),
        ("est-smooth", "EIV est. smoothed-input", InputJacobian::None),
        ("est-smooth-jac-smoothed", "EIV est. smoothed-input + jac smoothed", InputJacobian::SmoothedShare),
        ("est-smooth-jac-filter", "EIV est. smoothed-input + jac filter", InputJacobian::FilterShare),
        ("est-ref-jac-all", "EIV est. reference-input + jac all", InputJacobian::SmoothedShareAll),
        ("est-ref-jac-smoothed", "EIV est. reference-input + jac smoothed", InputJacobian::SmoothedShare),
    ] {
        if want(m) {
            let est_smoothed = EivOptions {
                wheel_noise_scale: WheelNoiseScale::SmoothedFittedInput { half_width_samples: a.smooth_half_width },
                ..est.clone()
            };
            let est_reference = EivOptions {
                wheel_noise_scale: WheelNoiseScale::ReferenceInput { half_width_samples: a.smooth_half_width },
                ..est.clone()
            };
            let base = if m.starts_with("est-smooth") {
                &est_smoothed
            } else if m.starts_with("est-ref") {
                &est_reference
            } else {
                &est_fitted
            };
            jobs.push((label, EivOptions { input_jacobian: jac, ..base.clone() }));
        }
    }
    if want("esttau") {
        jobs.push((
            "EIV est. τ",
            EivOptions { estimate_time_constants: true, quantisation: q, heading_scale: h, ..Default::default() },
        ));
    }
    if want("estsimtau") {
        let noise = NoiseModel {
            wheel_common_time_constant_s: true_noise.wheel_common_time_constant_s,
            wheel_differential_time_constant_s: true_noise.wheel_differential_time_constant_s,
            drift_time_constant_s: true_noise.drift_time_constant_s,
            ..NoiseModel::PRODUCTION_CAR
        };
        jobs.push(("EIV est. sim τ", EivOptions { noise, quantisation: q, heading_scale: h, ..Default::default() }));
    }
    // The bootstrap rows' options (`--bootstrap B`, `--bootstrap-smooth K`).
    let boot_opts = BootstrapOptions {
        replicates: a.bootstrap,
        seed,
        true_inputs: a.bootstrap_inputs,
        antithetic: a.bootstrap_antithetic,
        ..Default::default()
    };
    for (label, opts) in jobs {
        // A fixed (given) noise model is an oracle row: it also knows the
        // reference heading offset (0 here), as the Cramér–Rao bound does. A
        // fixed model with the offset the start estimated (a few 0.1 mrad of
        // noise, then held) collapses t_r on a perfect reference (stop 15).
        let estimate_delta = a.estimate_heading_offset && !opts.fix_noise;
        let (r, detail, time_s) = match calibrate_eiv(d, opts.clone(), seed, estimate_delta) {
            Ok(x) => x,
            Err(e) => {
                eprintln!("{name} {seed}: {label} failed: {e}");
                continue;
            }
        };
        let gn = detail.identification.theta;
        let t_gn = r.timing_s.initial_identification;
        if label == "EIV known" {
            runs.insert(
                "G-N".to_string(),
                Run {
                    theta: gn,
                    sigmas: vec![],
                    e_p_m: ep(&gn)?,
                    time_s: t_gn,
                    warnings: 0,
                    tau_s: None,
                    checks: vec![],
                },
            );
        }
        let Some(fit) = detail.eiv.as_deref() else {
            eprintln!("{name} {seed}: {label}: the filter failed: {:?}", detail.eiv_error);
            continue;
        };
        if let Some(p) = fit.passes.last() {
            eprintln!(
                "  {name} {seed} {label}: iterations {}, {:?}, last η step/σ {:.3}",
                p.history.len(),
                p.termination,
                p.eta_step_over_sigma.unwrap_or(f64::NAN)
            );
        }
        let sigma_h: [f64; 4] = std::array::from_fn(|i| r.covariance[i][i].max(0.0).sqrt());
        let sigmas = vec![
            ("H".to_string(), sigma_h),
            ("sandwich".to_string(), fit.sigma_sandwich),
            ("block".to_string(), fit.sigma_block),
            ("Fisher".to_string(), fit.sigma_fisher),
        ];
        let failed = r.warnings.iter().filter(|w| matches!(w, Warning::EivCheckFailed { .. })).count();
        let tau_s = fit.time_constants.as_ref().map(|t| [t.wheel_common_s, t.wheel_differential_s, t.drift_s]);
        if let (Some(t), true) = (&fit.time_constants, a.tau_candidates) {
            for c in &t.candidates {
                eprintln!(
                    "  {name} {seed} τ candidate {:?}: −log L {:.2}, t_r error {:+.3} %, converged {}, {:.1} s",
                    c.time_constants_s,
                    c.neg_log_likelihood,
                    (c.theta.t_r - truth.t_r) / truth.t_r * 100.0,
                    c.converged,
                    c.timing_s
                );
            }
        }
        let checks: Vec<String> = r
            .warnings
            .iter()
            .filter_map(|w| match w {
                Warning::EivCheckFailed { finding, .. } => serde_json::to_value(finding)
                    .ok()
                    .and_then(|v| v.get("kind").and_then(|k| k.as_str()).map(str::to_string)),
                _ => None,
            })
            .collect();
        let run = Run {
            theta: r.theta,
            sigmas: sigmas.clone(),
            e_p_m: ep(&r.theta)?,
            time_s,
            warnings: failed,
            tau_s,
            checks: checks.clone(),
        };
        runs.insert(label.to_string(), run);
        if want("fo") && label != "EIV est." {
            if let Some(b) = &fit.first_order_bias {
                let u = fit.theta_uncorrected.to_array();
                let shifted = |shift: [f64; 4]| Theta {
                    c_e: u[0] - shift[0],
                    c_d: u[1] - shift[1],
                    t_r: u[2] - shift[2],
                    d: u[3] - shift[3],
                };
                let variants = [
                    ("+ fo", b.bias),
                    ("+ fo c_e", [b.bias[0], 0.0, 0.0, 0.0]),
                    ("+ fo c_e cond", [b.bias_conditional[0], 0.0, 0.0, 0.0]),
                    ("+ fo logdet c_e", [b.bias_logdet_only[0], 0.0, 0.0, 0.0]),
                ];
                for (suffix, shift) in variants {
                    let th = shifted(shift);
                    let run = Run {
                        theta: th,
                        sigmas: sigmas.clone(),
                        e_p_m: ep(&th)?,
                        time_s,
                        warnings: failed,
                        tau_s: None,
                        checks: vec![],
                    };
                    runs.insert(format!("{label} {suffix}"), run);
                }
            }
        }
        if label == "EIV est. τ" {
            let (th, sig) = if failed > 0 { (gn, vec![]) } else { (r.theta, sigmas.clone()) };
            let run = Run {
                theta: th,
                sigmas: sig,
                e_p_m: ep(&th)?,
                time_s,
                warnings: failed,
                tau_s,
                checks: checks.clone(),
            };
            runs.insert("EIV est. τ + fallback".to_string(), run);
        }
        if ["EIV est.", "EIV est. stop-11", "EIV est. reentry", "EIV est. robust", "EIV est. reentry robust"]
            .contains(&label)
        {
            // What a user gets with the default fallback on: G-N when a check failed.
            let (th, sig) = if failed > 0 { (gn, vec![]) } else { (r.theta, sigmas) };
            let run =
                Run { theta: th, sigmas: sig, e_p_m: ep(&th)?, time_s, warnings: failed, tau_s: None, checks: vec![] };
            runs.insert(format!("{label} + fallback"), run);
        }
        if label == "EIV est."
            && a.bootstrap >= 2
            && seed <= a.bootstrap_seeds
            && a.bootstrap_presets.iter().any(|p| p == name)
        {
            // Bootstrap of the η-estimated fit: the replicates either hold the
            // fitted noise model (`held η̂`, fixed-noise re-fits) or
            // re-estimate η from the same start as the fit (`re-est. η`,
            // only on the first `--bootstrap-reestimate-seeds` seeds).
            let mut variants = vec![(
                "EIV est. + boot held η̂",
                EivOptions { noise: fit.noise, fix_noise: true, free: fit.free, ..opts.clone() },
            )];
            if seed <= a.bootstrap_reestimate_seeds {
                variants.push(("EIV est. + boot re-est. η", EivOptions { free: fit.free, ..opts.clone() }));
            }
            for (row, filter) in variants {
                let t = Instant::now();
                match bootstrap(&input, fit, &filter, &boot_opts) {
                    Ok(b) => {
                        // The Monte Carlo sd of the subtracted bias, per parameter
                        // (√ of `mean_covariance`'s diagonal; antithetic pairs: the
                        // pairs' spread), and the replicates' own sd.
                        let mc = b.mean_covariance();
                        eprintln!(
                            "  {name} {seed} {row}: bias {:?}, replicate sd {:?}, Monte Carlo sd of the bias {:?}, pairs {}",
                            b.bias,
                            b.sd,
                            [mc[0][0].sqrt(), mc[1][1].sqrt(), mc[2][2].sqrt(), mc[3][3].sqrt()],
                            b.pair_means.len()
                        );
                        // c_e only corrected, as `--correct-c-e-bias` does, and
                        // (stop 20, `… (all)`) every parameter, as `--correct-bias` does.
                        let time_s = time_s + t.elapsed().as_secs_f64();
                        let mut rows =
                            vec![("", Theta { c_e: b.theta_corrected.c_e, ..r.theta }), (" (all)", b.theta_corrected)];
                        if row == "EIV est. + boot held η̂" {
                            // `(all, fed back)` (stop 20): the held-noise bias b carried
                            // through the θ̂–η̂ feedback, (I − A B)⁻¹ b, with A = ∂θ̂/∂η
                            // and B = ∂η̂/∂θ of the fit.
                            let (a_s, b_s) = (fit.theta_eta_sensitivity, fit.eta_theta_sensitivity);
                            let ab =
                                nalgebra::Matrix4::from_fn(|i, k| (0..6).map(|j| a_s[i][j] * b_s[j][k]).sum::<f64>());
                            let fed = (nalgebra::Matrix4::identity() - ab)
                                .try_inverse()
                                .map(|m| m * nalgebra::Vector4::from(b.bias))
                                .unwrap_or(nalgebra::Vector4::from(b.bias));
                            let u = r.theta.to_array();
                            eprintln!(
                                "  {name} {seed} feedback: A B diag {:?}, b {:?}, fed {:?}",
                                [ab[(0, 0)], ab[(1, 1)], ab[(2, 2)], ab[(3, 3)]],
                                b.bias,
                                [fed[0], fed[1], fed[2], fed[3]]
                            );
                            rows.push((" (all, fed back)", Theta::from_array(std::array::from_fn(|i| u[i] - fed[i]))));
                        }
                        for (suffix, th) in rows {
                            let run = Run {
                                theta: th,
                                sigmas: vec![("H".into(), sigma_h)],
                                e_p_m: ep(&th)?,
                                time_s,
                                warnings: b.failed.len(),
                                tau_s: None,
                                checks: vec![],
                            };
                            runs.insert(format!("{row}{suffix}"), run);
                        }
                    }
                    Err(e) => eprintln!("{name} {seed}: {row} failed: {e}"),
                }
            }
        }
        if label == "EIV est. q, σ_ψ given"
            && a.bootstrap >= 2
            && seed <= a.bootstrap_seeds
            && a.bootstrap_presets.iter().any(|p| p == name)
        {
            // Stop 14: the η-estimated fit (q and σ_ψ given) minus the bias of
            // a bootstrap whose replicates hold the fitted noise model
            // (fixed-noise re-fits), every parameter corrected.
            let t = Instant::now();
            let filter = EivOptions { noise: fit.noise, fix_noise: true, free: fit.free, ..opts.clone() };
            match bootstrap(&input, fit, &filter, &boot_opts) {
                Ok(b) => {
                    let th = b.theta_corrected;
                    let run = Run {
                        theta: th,
                        sigmas: vec![("H".into(), sigma_h)],
                        e_p_m: ep(&th)?,
                        time_s: time_s + t.elapsed().as_secs_f64(),
                        warnings: b.failed.len(),
                        tau_s: None,
                        checks: vec![],
                    };
                    runs.insert(format!("{label} + boot held η̂"), run);
                }
                Err(e) => eprintln!("{name} {seed}: {label} bootstrap failed: {e}"),
            }
        }
        if label == "EIV known"
            && !want("no-known-boot")
            && a.bootstrap >= 2
            && seed <= a.bootstrap_seeds
            && a.bootstrap_presets.iter().any(|p| p == name)
        {
            let t = Instant::now();
            let filter = EivOptions { free: fit.free, ..opts.clone() };
            match bootstrap(&input, fit, &filter, &boot_opts) {
                Ok(b) => {
                    let th = b.theta_corrected;
                    let half: [f64; 4] = std::array::from_fn(|i| (b.interval[i][1] - b.interval[i][0]) / (2.0 * 1.96));
                    let run = Run {
                        theta: th,
                        sigmas: vec![("H".into(), sigma_h), ("boot".into(), half)],
                        e_p_m: ep(&th)?,
                        time_s: time_s + t.elapsed().as_secs_f64(),
                        warnings: b.failed.len(),
                        tau_s: None,
                        checks: vec![],
                    };
                    runs.insert("EIV known + boot".into(), run);
                }
                Err(e) => eprintln!("{name} {seed}: bootstrap failed: {e}"),
            }
        }
    }
    if let (Some(k), Some(f)) = (runs.get("EIV known"), runs.get("EIV fitted")) {
        // The midpoint of the measured- and fitted-input estimates (their c_e
        // biases have opposite signs; two fits).
        let (a, b) = (k.theta.to_array(), f.theta.to_array());
        let th = Theta {
            c_e: 0.5 * (a[0] + b[0]),
            c_d: 0.5 * (a[1] + b[1]),
            t_r: 0.5 * (a[2] + b[2]),
            d: 0.5 * (a[3] + b[3]),
        };
        let run = Run {
            theta: th,
            sigmas: k.sigmas.clone(),
            e_p_m: ep(&th)?,
            time_s: k.time_s + f.time_s,
            warnings: 0,
            tau_s: None,
            checks: vec![],
        };
        runs.insert("EIV mid(known, fitted)".into(), run);
    }
    // Ē_p on a drive no method saw: in-sample, a θ can lower Ē_p below
    // Ē_p(θ_true) by fitting this drive's noise; on a fresh drive it cannot.
    let fresh =
        simulate(&SimOptions { length_km: a.km, noise: noise.clone(), ..SimOptions::paper(seed + FRESH_SEED_OFFSET) })?;
    let fd = &fresh.drive;
    let fval = validation_segments(fd, &ValidationSegmentOptions::default())?;
    let fresh_ep = |t: &Theta| -> Res<f64> { Ok(mean_position_error(fd, &fval, t)?.mean_position_error_m) };
    let fresh_true = fresh_ep(&truth)?;
    let mut e_p_fresh_excess_m = BTreeMap::new();
    for (m, r) in &runs {
        e_p_fresh_excess_m.insert(m.clone(), fresh_ep(&r.theta)? - fresh_true);
    }
    Ok(DriveResult {
        preset: name.into(),
        seed,
        theta_true: truth,
        crb,
        crb_mean_only,
        crb_noise_estimated,
        e_p_true_m: ep(&truth)?,
        runs,
        e_p_fresh_excess_m,
    })
}

const SCALE_NAMES: [&str; 4] = ["c_e %", "c_d mm", "t_r %", "d mm/(m/s²)"];

fn scale(truth: &Theta) -> [f64; 4] {
    [100.0 / truth.c_e, 1e3, 100.0 / truth.t_r, 1e3]
}

fn mean_sd(x: &[f64]) -> (f64, f64) {
    let n = x.len() as f64;
    let m = x.iter().sum::<f64>() / n;
    let v = if x.len() > 1 { x.iter().map(|a| (a - m) * (a - m)).sum::<f64>() / (n - 1.0) } else { f64::NAN };
    (m, v.sqrt())
}

fn summarise(preset: &str, results: &[DriveResult]) {
    let mut methods: Vec<String> = Vec::new();
    for r in results {
        for m in r.runs.keys() {
            if !methods.contains(m) {
                methods.push(m.clone());
            }
        }
    }
    println!("\n### {preset} ({} drives)\n", results.len());
    let crb_mean: [f64; 4] = std::array::from_fn(|i| {
        let v: Vec<f64> = results.iter().map(|r| r.crb[i] * scale(&r.theta_true)[i]).collect();
        mean_sd(&v).0
    });
    let crb_mo: [f64; 4] = std::array::from_fn(|i| {
        let v: Vec<f64> = results.iter().map(|r| r.crb_mean_only[i] * scale(&r.theta_true)[i]).collect();
        mean_sd(&v).0
    });
    let crb_ne: [f64; 4] = std::array::from_fn(|i| {
        let v: Vec<f64> = results.iter().map(|r| r.crb_noise_estimated[i] * scale(&r.theta_true)[i]).collect();
        mean_sd(&v).0
    });
    println!(
        "CRB σ (full Fisher): {}; mean-only: {}; noise scales unknown too (CRB_η): {}",
        (0..4).map(|i| format!("{} {:.4}", SCALE_NAMES[i], crb_mean[i])).collect::<Vec<_>>().join(", "),
        (0..4).map(|i| format!("{:.4}", crb_mo[i])).collect::<Vec<_>>().join(", "),
        (0..4).map(|i| format!("{:.4}", crb_ne[i])).collect::<Vec<_>>().join(", ")
    );
    println!("\n| method | n | parameter | mean error | sd | RMS/CRB | RMS/CRB mean-only | RMS/CRB_η | t | coverage (σ kinds) |");
    println!("|---|---|---|---|---|---|---|---|---|---|");
    for m in &methods {
        let rs: Vec<(&DriveResult, &Run)> = results.iter().filter_map(|r| r.runs.get(m).map(|x| (r, x))).collect();
        let n = rs.len();
        for i in 0..4 {
            let errs: Vec<f64> = rs
                .iter()
                .map(|(r, x)| (x.theta.to_array()[i] - r.theta_true.to_array()[i]) * scale(&r.theta_true)[i])
                .collect();
            let (mean, sd) = mean_sd(&errs);
            let rms = (errs.iter().map(|e| e * e).sum::<f64>() / n as f64).sqrt();
            let t = mean.abs() / (sd / (n as f64).sqrt());
            let mut cov = Vec::new();
            if let Some((_, first)) = rs.first() {
                for (k, (kind, _)) in first.sigmas.iter().enumerate() {
                    let inside = rs
                        .iter()
                        .filter(|(r, x)| {
                            let s = x.sigmas.get(k).map_or(f64::NAN, |s| s.1[i]);
                            let e = (x.theta.to_array()[i] - r.theta_true.to_array()[i]).abs();
                            e <= 1.96 * s
                        })
                        .count();
                    cov.push(format!("{kind} {:.0} %", 100.0 * inside as f64 / n as f64));
                }
            }
            println!(
                "| {m} | {n} | {} | {mean:+.4} | {sd:.4} | {:.2} | {:.2} | {:.2} | {t:.1} | {} |",
                SCALE_NAMES[i],
                rms / crb_mean[i],
                rms / crb_mo[i],
                rms / crb_ne[i],
                cov.join(", ")
            );
        }
    }
    println!(
        "\n| method | Ē_p − Ē_p(θ_true) mean, m | max, m | fresh drive: mean, m | max, m | mean wall s | runs with a failed EIV check |"
    );
    println!("|---|---|---|---|---|---|---|");
    for m in &methods {
        let rs: Vec<(&DriveResult, &Run)> = results.iter().filter_map(|r| r.runs.get(m).map(|x| (r, x))).collect();
        let ex: Vec<f64> = rs.iter().map(|(r, x)| x.e_p_m - r.e_p_true_m).collect();
        let max = ex.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let fx: Vec<f64> = rs.iter().filter_map(|(r, _)| r.e_p_fresh_excess_m.get(m).copied()).collect();
        let fmax = fx.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let time = mean_sd(&rs.iter().map(|(_, x)| x.time_s).collect::<Vec<_>>()).0;
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
        println!(
            "| {m} | {:+.4} | {max:+.4} | {:+.4} | {fmax:+.4} | {time:.2} | {warned}{kinds} |",
            mean_sd(&ex).0,
            mean_sd(&fx).0
        );
    }
    for m in &methods {
        let taus: Vec<[f64; 3]> = results.iter().filter_map(|r| r.runs.get(m).and_then(|x| x.tau_s)).collect();
        if taus.is_empty() || m.ends_with("fallback") {
            continue;
        }
        let col = |k: usize| {
            let mut v: Vec<f64> = taus.iter().map(|t| t[k]).collect();
            v.sort_by(f64::total_cmp);
            format!("median {:.3}, range {:.3}–{:.3}", v[v.len() / 2], v[0], v[v.len() - 1])
        };
        println!("\n{m}: chosen τ_c s {}; τ_w s {}; drift τ s {} ({} drives)", col(0), col(1), col(2), taus.len());
    }
}

fn main() -> Res<()> {
    let a = parse_args()?;
    let t0 = Instant::now();
    let mut all = Vec::new();
    for p in &a.presets {
        let mut results = Vec::new();
        for seed in 1..=a.seeds {
            let r = study_drive(p, seed, &a)?;
            let fmt = |x: &Run| {
                let s = scale(&r.theta_true);
                let e: Vec<String> = (0..4)
                    .map(|i| format!("{:+.4}", (x.theta.to_array()[i] - r.theta_true.to_array()[i]) * s[i]))
                    .collect();
                let tau = x.tau_s.map_or(String::new(), |t| format!(" τ [{:.3} {:.3} {:.1}]", t[0], t[1], t[2]));
                format!("[{}] {:.2}s{tau}", e.join(" "), x.time_s)
            };
            let line: Vec<String> = r.runs.iter().map(|(k, x)| format!("{k} {}", fmt(x))).collect();
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
