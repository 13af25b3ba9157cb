//! Where the default's residual t_r bias comes from (docs/validation.md,
//! "Where the default's t_r bias comes from").
//!
//! Per seed (`--first-seed` .. + `--seeds`) and drive variant it simulates
//! one drive of the paper route (`--preset` noise, `--km` long,
//! `--substeps` substeps) and calibrates it, all through `odocal::calibrate`,
//! with the estimators of `--estimators`:
//! - `default`: `calibrate` without options; also gives the row
//!   `uncorrected`, the same fit without its bias correction (the EIV fit's
//!   `theta_uncorrected`, or the batch G-N fallback where it fell back:
//!   the correction runs only on a kept fit);
//! - `b16`: the default with B = 16 bias-correction replicates;
//! - `conv`: the default with each bias-correction replicate fitted to
//!   convergence (`ResearchOptions::bias_correction_refit`);
//! - `q0`: the default with no quantisation in its wheel-noise model (the
//!   step given as 0, `QuantisationLevel::Given`);
//! - `qscaled`: the default with the quantisation step scaled with the
//!   white wheel noise from the starting model's even where the readings
//!   lie on a lattice (`QuantisationLevel::ScaledWithWhite`);
//! - `twosided`: the default with its heading-drift test two-sided
//!   (`heading_drift_two_sided`);
//! - `ownscale`: the default with the pose-drift scale on the position
//!   drift only (`position_drift_own_scale`);
//! - `floor2cm`: the default with a 2 cm position floor (`position_floor_m`);
//! - `gn`: `--method batch-gn --estimate heading-offset`;
//! - `known`: the default with the simulator's noise model given and held
//!   (`NoiseModel::from_sim`, `fix_noise`); `knownstart`: that model as the
//!   start, the scales estimated;
//! - `held`: the default with the covariance recursion held at a reference
//!   θ (`CovarianceMode::HeldAtReference`; the wheel noise scaled by the
//!   measured rotation, `WheelNoiseScale::MeasuredInput`, which it needs);
//! - `nojac`: the default without the input log-Jacobian term
//!   (`InputJacobian::None`);
//! - `floor1mm`: the default with a 1 mm position floor;
//! - `latstated`: the a_y and β noise held at the model's σ
//!   (`LateralNoise::Stated`) instead of scaled with the white wheel noise;
//! - `notest`: the default without its heading-drift test;
//! - `tiedall`: the heading drift tied to the pose-drift scale all the way
//!   (`heading_drift_min_eta` at the lower η bound);
//! - `hdmin:X`: the default with `heading_drift_min_eta` X;
//! - `tau:X`: the default with the noise model's drift correlation time
//!   (`drift_time_constant_s`, position and heading) X s instead of 100.
//!
//! Drive variants (`--drives`), each the preset with one group of noise
//! sources switched off (every source draws from its own stream of the
//! seed, so the others' realisations are the same): `full`, `no-slip`
//! (acceleration slip), `no-heading` (reference heading drift and white
//! noise), `no-position` (reference position drift and white noise),
//! `no-lateral` (a_y and β noise), `no-quant` (encoder quantisation),
//! `no-coloured` (common and per-wheel coloured wheel noise), `no-white`
//! (white wheel noise); `slip-only` (no noise but the slip) and `off` (no
//! noise); `drift-tau100`, the reference's position and heading drift at
//! the filter's correlation time, 100 s; `position-tenth` and
//! `position-hundredth`, the reference's position drift and white noise at
//! a tenth and a hundredth of the preset's (an RTK-grade reference).
//! `no-heading-drift`, `no-heading-white`: the reference heading's drift or
//! white noise alone off. Variants join with `+` (`position-tenth+no-slip`:
//! both changes). With the environment variable `EIV_TR_BIAS_VERBOSE` set,
//! each EIV fit's t_r, its σ, η, heading-drift test and verdict go to stderr.
//! Errors are against `SimOptions::equivalent_truth`.
//!
//! Per drive variant and estimator: mean error, bias t = |mean|/(sd/√n)
//! and RMS per parameter (c_e, t_r in %, c_d in mm, d in mm/(m/s²)) and the
//! fallbacks. `--csv FILE` writes a row per seed, drive and estimator.
//! Seeds run in parallel (`--threads`); the output does not depend on it.

use std::fmt::Write as _;

use odocal::eiv::{
    BootstrapRefit, CovarianceMode, InputJacobian, LateralNoise, NoiseModel, QuantisationLevel, WheelNoiseScale,
};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal::{calibrate, CalibrationOptions, CorrectBias, Method, Param, Theta, VerdictLevel};
use odocal_lab::report_json::{eiv_part, EivPart};
use odocal_lab::{errors, noise_preset, Args, Res, Summary, Table, ERROR_UNITS};
use rayon::prelude::*;

const USAGE: &str = "eiv_tr_bias [--km 12] [--seeds 40] [--first-seed 1] [--preset paper] [--substeps 10]
    [--drives full,no-slip,no-heading,no-position,no-lateral,no-quant,no-coloured,no-white]
    [--estimators default,gn] [--threads N] [--csv FILE]

drives: full, no-slip, no-heading, no-position, no-lateral, no-quant, no-coloured, no-white, slip-only, off,
    drift-tau100, position-tenth, position-hundredth, no-heading-drift, no-heading-white;
    variants join with '+' (position-tenth+no-slip);
estimators: default (with its uncorrected fit), b16, conv, q0, qscaled, twosided, ownscale, floor2cm, gn,
    known, knownstart, held, nojac, floor1mm, latstated, notest, tiedall, hdmin:X, tau:X.";

const DRIVES: [&str; 15] = [
    "full",
    "no-slip",
    "no-heading",
    "no-position",
    "no-lateral",
    "no-quant",
    "no-coloured",
    "no-white",
    "slip-only",
    "off",
    "drift-tau100",
    "position-tenth",
    "position-hundredth",
    "no-heading-drift",
    "no-heading-white",
];
const ESTIMATORS: [&str; 17] = [
    "default",
    "b16",
    "conv",
    "q0",
    "qscaled",
    "floor2cm",
    "twosided",
    "ownscale",
    "gn",
    "known",
    "knownstart",
    "held",
    "nojac",
    "floor1mm",
    "latstated",
    "notest",
    "tiedall",
];

/// `preset` changed by drive variant `drive`: one variant, or several
/// joined by `+` (`position-tenth+no-slip`), applied left to right.
fn drive_noise(preset: &NoiseOptions, drive: &str) -> NoiseOptions {
    drive.split('+').fold(preset.clone(), |n, d| one_drive_noise(&n, d))
}

/// `preset` with the sources of the single drive variant `drive` switched off.
fn one_drive_noise(preset: &NoiseOptions, drive: &str) -> NoiseOptions {
    let mut n = preset.clone();
    match drive {
        "no-slip" => n.wheel_slip_per_m_per_s2 = 0.0,
        "no-heading" => {
            n.heading_drift_sigma_rad = 0.0;
            n.heading_white_sigma_rad = 0.0;
        }
        "no-heading-drift" => n.heading_drift_sigma_rad = 0.0,
        "no-heading-white" => n.heading_white_sigma_rad = 0.0,
        "no-position" => {
            n.position_drift_sigma_m = 0.0;
            n.position_white_sigma_m = 0.0;
        }
        "no-lateral" => {
            n.lateral_acceleration_white_sigma_m_per_s2 = 0.0;
            n.sideslip_sigma_rad = 0.0;
        }
        "no-quant" => n.encoder_ticks_per_revolution = 0,
        "no-coloured" => {
            n.wheel_coloured_rel_sigma = 0.0;
            n.wheel_coloured_differential_rel_sigma = 0.0;
        }
        "no-white" => n.wheel_white_rel_sigma = 0.0,
        "drift-tau100" => {
            n.position_drift_time_constant_s = 100.0;
            n.heading_drift_time_constant_s = 100.0;
        }
        "position-tenth" | "position-hundredth" => {
            let f = if drive == "position-tenth" { 0.1 } else { 0.01 };
            n.position_drift_sigma_m *= f;
            n.position_white_sigma_m *= f;
        }
        "slip-only" => {
            n = NoiseOptions { wheel_slip_per_m_per_s2: preset.wheel_slip_per_m_per_s2, ..NoiseOptions::off() }
        }
        "off" => n = NoiseOptions::off(),
        _ => {}
    }
    n
}

/// The calibration options of estimator `est` on drives simulated with
/// `noise` at sample time `ts` (s).
fn options(est: &str, noise: &NoiseOptions, ts: f64) -> Res<CalibrationOptions> {
    let mut o = CalibrationOptions::default();
    if let Method::Eiv(e) = &mut o.method {
        let r = &mut e.filter.research;
        match est {
            "known" | "knownstart" => {
                e.filter.noise = NoiseModel::from_sim(noise, ts);
                e.filter.fix_noise = est == "known";
            }
            "held" => {
                r.covariance = CovarianceMode::HeldAtReference;
                r.wheel_noise_scale = WheelNoiseScale::MeasuredInput;
            }
            "nojac" => r.input_jacobian = InputJacobian::None,
            "floor1mm" => r.position_floor_m = 0.001,
            "latstated" => e.filter.lateral_noise = LateralNoise::Stated,
            "notest" => r.heading_drift_test = false,
            "tiedall" => r.heading_drift_min_eta = e.filter.eta_bounds[0],
            _ if est.starts_with("hdmin:") => r.heading_drift_min_eta = est["hdmin:".len()..].parse()?,
            _ if est.starts_with("tau:") => e.filter.noise.drift_time_constant_s = est["tau:".len()..].parse()?,
            _ => {}
        }
    }
    match est {
        "gn" => {
            o.method = "batch-gn".parse::<Method>()?;
            o.identify.free = o.identify.free.with(Param::HeadingOffset);
        }
        "b16" | "conv" => {
            if let Method::Eiv(e) = &mut o.method {
                if est == "b16" {
                    e.correct_bias =
                        Some(CorrectBias { replicates: 16, parameters: odocal::ParamSet::THETA, ..Default::default() });
                } else {
                    e.filter.research.bias_correction_refit = BootstrapRefit::Converged;
                }
            }
        }
        "twosided" => {
            if let Method::Eiv(e) = &mut o.method {
                e.filter.research.heading_drift_two_sided = true;
            }
        }
        "ownscale" => {
            if let Method::Eiv(e) = &mut o.method {
                e.filter.research.position_drift_own_scale = true;
            }
        }
        "floor2cm" => {
            if let Method::Eiv(e) = &mut o.method {
                e.filter.research.position_floor_m = 0.02;
            }
        }
        "q0" | "qscaled" => {
            if let Method::Eiv(e) = &mut o.method {
                if est == "q0" {
                    e.filter.quantisation_level = QuantisationLevel::Given;
                    e.filter.noise.quantisation_step_rev_per_s = 0.0;
                } else {
                    e.filter.quantisation_level = QuantisationLevel::ScaledWithWhite;
                }
            }
        }
        _ => {}
    }
    Ok(o)
}

/// One row: estimator row name, fell back, θ, the result's σ of t_r (as
/// θ's t_r; NaN where none) and whether the verdict accepted it.
struct Row {
    name: String,
    fell_back: bool,
    theta: Theta,
    sigma_t_r: f64,
    accepted: bool,
}

/// The rows of estimator `est` on `drive`.
fn run(est: &str, drive: &odocal::Drive, noise: &NoiseOptions) -> Res<Vec<Row>> {
    let r = calibrate(drive, &options(est, noise, drive.sample_time_s())?)?;
    let part = eiv_part(&r);
    let fell_back = part.as_ref().is_some_and(EivPart::fell_back);
    if std::env::var_os("EIV_TR_BIAS_VERBOSE").is_some() {
        if let Some(e) = part.as_ref().and_then(|p| p.eiv.as_ref()) {
            let eta: Vec<String> = e.eta.iter().map(|x| format!("{x:+.2}")).collect();
            let hd = e.heading_drift.as_ref().map(|h| {
                format!(
                    "score {:.1} lr {:?} r {:+.2} separate {} upward at floor {:?}",
                    h.score_statistic, h.likelihood_ratio, h.log_ratio, h.separate, h.upward_at_floor
                )
            });
            eprintln!(
                "{est}: t_r {:.5} σ {:?} η [{}] heading drift {:?} verdict {}",
                r.theta.t_r,
                r.result_sigma().t_r,
                eta.join(", "),
                hd,
                r.verdict.level
            );
        }
    }
    let (sigma_t_r, accepted) = (r.result_sigma().t_r.unwrap_or(f64::NAN), r.verdict.level == VerdictLevel::Accepted);
    let row = |name: &str, theta: Theta| Row { name: name.to_string(), fell_back, theta, sigma_t_r, accepted };
    let mut rows = vec![row(est, r.theta)];
    if est == "default" {
        let own = part.as_ref().and_then(|p| p.eiv.as_ref()).map(|e| e.theta_uncorrected);
        let plain = if fell_back { r.theta } else { own.unwrap_or(r.theta) };
        rows.push(row("uncorrected", plain));
    }
    Ok(rows)
}

struct Settings {
    km: f64,
    seeds: u64,
    first: u64,
    preset: String,
    substeps: usize,
    drives: Vec<String>,
    estimators: Vec<String>,
    csv: Option<String>,
}

/// One seed: per drive variant, its equivalent truth and rows.
fn seed_rows(s: &Settings, seed: u64) -> Res<Vec<(String, Theta, Vec<Row>)>> {
    let preset = noise_preset(&s.preset)?;
    let mut out = Vec::new();
    for d in &s.drives {
        let o = SimOptions {
            length_km: s.km,
            substeps: s.substeps,
            noise: drive_noise(&preset, d),
            ..SimOptions::paper(seed)
        };
        let truth = o.equivalent_truth().0;
        let sim = simulate(&o)?;
        let mut rows = Vec::new();
        for e in &s.estimators {
            rows.extend(run(e, &sim.drive, &o.noise)?);
        }
        out.push((d.clone(), truth, rows));
    }
    Ok(out)
}

fn main() {
    odocal_lab::main_with(|| {
        let mut a = Args::parse(USAGE, &[])?;
        let s = Settings {
            km: a.get("km", 12.0)?,
            seeds: a.get("seeds", 40)?,
            first: a.get("first-seed", 1)?,
            preset: a.get("preset", "paper".to_string())?,
            substeps: a.get("substeps", 10)?,
            drives: a.list("drives", &DRIVES[..8]),
            estimators: a.list("estimators", &["default", "gn"]),
            csv: a.opt("csv")?,
        };
        let threads: Option<usize> = a.opt("threads")?;
        a.finish()?;
        if let Some(d) = s.drives.iter().flat_map(|d| d.split('+')).find(|d| !DRIVES.contains(d)) {
            return Err(format!("unknown drive variant '{d}'").into());
        }
        if let Some(e) = s
            .estimators
            .iter()
            .find(|e| !ESTIMATORS.contains(&e.as_str()) && !e.starts_with("hdmin:") && !e.starts_with("tau:"))
        {
            return Err(format!("unknown estimator '{e}'").into());
        }
        if let Some(n) = threads {
            rayon::ThreadPoolBuilder::new().num_threads(n).build_global()?;
        }
        let seeds: Vec<u64> = (s.first..s.first + s.seeds).collect();
        let per_seed: Vec<Vec<(String, Theta, Vec<Row>)>> = seeds
            .par_iter()
            .map(|&seed| {
                let r = seed_rows(&s, seed).map_err(|e| format!("seed {seed}: {e}"));
                eprintln!("seed {seed} done");
                r
            })
            .collect::<Result<_, String>>()?;
        report(&s, &seeds, &per_seed)
    });
}

fn report(s: &Settings, seeds: &[u64], per_seed: &[Vec<(String, Theta, Vec<Row>)>]) -> Res<()> {
    println!(
        "preset {}, {} km, {} substeps, seeds {}..={}; mean error (t) · RMS; errors against the equivalent truth\n",
        s.preset,
        s.km,
        s.substeps,
        s.first,
        s.first + s.seeds - 1
    );
    let mut header = vec!["drive", "estimator", "n", "fallbacks", "accepted (beyond 3σ in t_r)"];
    header.extend(ERROR_UNITS);
    let mut table = Table::new(&header);
    let mut csv = String::from("drive,estimator,seed,fallback,e_c_e_pct,e_c_d_mm,e_t_r_pct,e_d,z_t_r,accepted\n");
    for (di, d) in s.drives.iter().enumerate() {
        let names: Vec<String> = per_seed[0][di].2.iter().map(|r| r.name.clone()).collect();
        for (ri, name) in names.iter().enumerate() {
            let mut errs: Vec<[f64; 4]> = Vec::new();
            let (mut fallbacks, mut accepted, mut beyond) = (0, 0, 0);
            for (seed, rows) in seeds.iter().zip(per_seed) {
                let (_, truth, r) = &rows[di];
                let row = &r[ri];
                let e = errors(&row.theta, truth);
                let z = (row.theta.t_r - truth.t_r) / row.sigma_t_r;
                fallbacks += usize::from(row.fell_back);
                accepted += usize::from(row.accepted);
                beyond += usize::from(row.accepted && z.abs() > 3.0);
                writeln!(
                    csv,
                    "{d},{name},{seed},{},{:.6},{:.6},{:.6},{:.6},{z:.3},{}",
                    row.fell_back, e[0], e[1], e[2], e[3], row.accepted
                )?;
                errs.push(e);
            }
            let mut cells = vec![
                d.clone(),
                name.clone(),
                errs.len().to_string(),
                fallbacks.to_string(),
                format!("{accepted} ({beyond})"),
            ];
            for p in 0..4 {
                let x: Vec<f64> = errs.iter().map(|e| e[p]).collect();
                let m = Summary::of(&x);
                cells.push(format!("{:+.4} ({:.1}) · {:.4}", m.mean, m.t(), m.rms));
            }
            table.row(cells);
        }
    }
    println!("{table}");
    if let Some(p) = &s.csv {
        std::fs::write(p, csv)?;
    }
    Ok(())
}
