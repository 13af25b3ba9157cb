//! The Cramér–Rao bound of drives from the lab's second simulator
//! (`scripts/independent_sim.py`), for comparing the default's errors on
//! them with what the drive can tell (docs/validation.md, "The default's
//! t_r bias"). The bound is the filter's model's, so it holds for drives
//! whose noise that model can represent: run the simulator with
//! `--set slip=0 --set head_offset=0` (slip with acceleration and the
//! reference's heading offset are not in it; the small a_y and β biases
//! the simulator adds are left out of the bound).
//!
//! With `--fit VARIANT` it fits instead: the default method with the
//! simulator's noise model as its start, every level held but the
//! reference heading's white noise, and prints t_r's error and that
//! level over the simulator's. Variants: `as-is`; `no-heading-floor`
//! (the heading readings' own white noise not in the heading's variance);
//! `eta-without-jacobian` (the η step on M without the Gauss-Markov
//! log-Jacobian); `no-common-jacobian` (no common-mode log-Jacobian in J
//! and M). `default+VARIANT`: the same switch on the default as it is
//! (its own starting noise model, every level estimated); `free+VARIANT`:
//! the simulator's model as the start, every level estimated.
//!
//! For each `DRIVE.csv` (with `DRIVE.truth.json` beside it) prints the
//! bound at θ_true with the simulator's noise model stated in the filter's
//! terms, linearised along the drive's true inputs, with the noise known
//! and with the noise scales estimated (CRB_η), and the mean-only bound
//! (the information the innovations' mean carries, not their size), in %
//! of θ_true for c_e and t_r, mm for c_d and mm/(m/s²) for d.

use std::path::Path;

use odocal::eiv::{cramer_rao_bound, EivInput, EivOptions, NoiseModel};
use odocal::model::Theta;
use odocal::{calibrate, CalibrationOptions, Method};
use odocal_lab::{error_scale, Args, Res};
use serde_json::Value;

const USAGE: &str = "second_sim_crb [--fit as-is|no-heading-floor|eta-without-jacobian|no-common-jacobian] DRIVE.csv \
                     [DRIVE.csv ...]   (each with DRIVE.truth.json beside it)";

fn main() {
    odocal_lab::main_with(run)
}

/// A number of the truth file's `settings`.
fn setting(settings: &Value, key: &str) -> Res<f64> {
    settings[key].as_f64().ok_or_else(|| format!("truth settings: no number `{key}`").into())
}

/// The simulator's noise settings in the filter's terms: the relative white
/// wheel error per sample, one encoder tick per sample as the quantisation
/// step, the common-mode and per-wheel Gauss-Markov errors with their time
/// constants, the reference's white and drifting errors (one correlation
/// time), white a_y and β noise (β's time constant one sample).
fn noise_of(settings: &Value, sample_time_s: f64) -> Res<NoiseModel> {
    let ticks = setting(settings, "ticks")?;
    Ok(NoiseModel {
        wheel_white_rel_sigma: setting(settings, "white")?,
        quantisation_step_rev_per_s: if ticks > 0.0 { 1.0 / (ticks * sample_time_s) } else { 0.0 },
        wheel_common_rel_sigma: setting(settings, "common")?,
        wheel_common_time_constant_s: setting(settings, "tau_common")?,
        wheel_differential_rel_sigma: setting(settings, "wheel")?,
        wheel_differential_time_constant_s: setting(settings, "tau_wheel")?,
        position_white_sigma_m: setting(settings, "pos_white")?,
        heading_white_sigma_rad: setting(settings, "head_white")?,
        position_drift_sigma_m: setting(settings, "pos_drift")?,
        heading_drift_sigma_rad: setting(settings, "head_drift")?,
        drift_time_constant_s: setting(settings, "tau_drift")?,
        lateral_acceleration_sigma_m_per_s2: setting(settings, "ay_sigma")?,
        sideslip_sigma_rad: setting(settings, "beta_sigma")?,
        sideslip_time_constant_s: sample_time_s,
    })
}

/// The default method with `noise` as its start, every level held but the
/// reference heading's white noise (η_5), and the variant's research switch.
fn fit_options(noise: NoiseModel, variant: &str) -> Res<CalibrationOptions> {
    let mut o = CalibrationOptions::default();
    let Method::Eiv(e) = &mut o.method else { return Err("the default method is not EIV".into()) };
    // `default+VARIANT`: the default's own start with every level
    // estimated; `free+VARIANT`: the simulator's model as the start, every
    // level estimated.
    let variant = if let Some(v) = variant.strip_prefix("default+") {
        v
    } else if let Some(v) = variant.strip_prefix("free+") {
        e.filter.noise = noise;
        v
    } else {
        e.filter.noise = noise;
        e.filter.eta_held = [true, true, true, true, true, false];
        variant
    };
    let r = &mut e.filter.research;
    match variant {
        "as-is" => {}
        "no-heading-floor" => r.heading_floor_from_readings = false,
        "eta-without-jacobian" => r.coloured_jacobian_in_marginal = false,
        "no-common-jacobian" => r.common_mode_jacobian = false,
        other => return Err(format!("--fit {other}: {USAGE}").into()),
    }
    Ok(o)
}

/// A drive of the second simulator with what its truth file says: θ_true,
/// the noise settings and that noise in the filter's terms.
struct SimDrive {
    drive: odocal::Drive,
    settings: Value,
    theta: Theta,
    noise: NoiseModel,
}

impl SimDrive {
    fn load(csv: &str) -> Res<SimDrive> {
        let truth: Value = serde_json::from_str(&std::fs::read_to_string(Path::new(csv).with_extension("truth.json"))?)?;
        let t = &truth["theta_true"];
        let num = |k: &str| t[k].as_f64().ok_or_else(|| format!("{csv}: truth has no theta_true.{k}"));
        let theta = Theta { c_e: num("c_e")?, c_d: num("c_d")?, t_r: num("t_r")?, d: num("d")? };
        let (drive, _) = odocal::load_drive(csv)?;
        let settings = truth["settings"].clone();
        let noise = noise_of(&settings, drive.sample_time_s())?;
        Ok(SimDrive { drive, settings, theta, noise })
    }
}

/// `--fit VARIANT` on one drive: t_r's error, the heading's white noise
/// over the simulator's, and which estimate the result is.
fn fit_line(csv: &str, sim: &SimDrive, variant: &str) -> Res<String> {
    let r = calibrate(&sim.drive, &fit_options(sim.noise, variant)?)?;
    let json = serde_json::to_value(&r)?;
    let heading = json["eiv"]["noise"]["heading_white_sigma_rad"].as_f64().unwrap_or(f64::NAN);
    let ratio = heading / setting(&sim.settings, "head_white")?;
    Ok(format!("{csv} | {:+.4} | {ratio:.4} | {}", (r.theta.t_r / sim.theta.t_r - 1.0) * 100.0, r.method))
}

/// The bounds of one drive, refused where the simulator ran what the
/// bound's model cannot represent.
fn bound_line(csv: &str, sim: &SimDrive) -> Res<String> {
    for key in ["slip", "head_offset"] {
        if setting(&sim.settings, key)?.abs() > 0.0 {
            return Err(format!("{csv}: `{key}` is not 0, which the bound's model cannot represent").into());
        }
    }
    let input = EivInput::from_drive_truth(&sim.drive)?;
    let crb = cramer_rao_bound(&input, &sim.theta, &sim.noise, &EivOptions::spec())?;
    let scale = error_scale(&sim.theta);
    let show = |s: [f64; 4]| (0..4).map(|i| format!("{:.4}", s[i] * scale[i])).collect::<Vec<_>>().join(" ");
    let estimated = crb.sigma_noise_estimated.map_or("-".to_string(), show);
    Ok(format!("{csv} | {} | {estimated} | {}", show(crb.sigma), show(crb.sigma_mean_only)))
}

fn run() -> Res<()> {
    let mut args = Args::parse(USAGE, &[])?;
    let fit: Option<String> = args.opt("fit")?;
    let paths: Vec<String> = args.positional().to_vec();
    args.finish()?;
    if paths.is_empty() {
        return Err(USAGE.into());
    }
    match &fit {
        Some(_) => println!("drive | t_r error % | heading white noise / the simulator's | result"),
        None => println!(
            "drive | CRB known noise: c_e % c_d mm t_r % d | CRB_η (noise estimated) | mean-only (known noise, the \
             innovations' size carries nothing)"
        ),
    }
    for csv in &paths {
        let sim = SimDrive::load(csv)?;
        let line = match &fit {
            Some(variant) => fit_line(csv, &sim, variant)?,
            None => bound_line(csv, &sim)?,
        };
        println!("{line}");
    }
    Ok(())
}
