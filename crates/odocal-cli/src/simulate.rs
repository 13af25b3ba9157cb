//! `odocal simulate`: a drive with known true parameters.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use odocal::sim::{self, CdStep, NoiseOptions, SimOptions};

use crate::args::ThetaArg;
use crate::output::{refuse_foreign_sidecar, refuse_sidecar_onto_drive, refuse_stdout, Files};
use crate::progress::Bars;

/// Arguments of `odocal simulate`.
#[derive(Args)]
pub struct SimulateArgs {
    /// Random seed.
    #[arg(long, default_value_t = 0, value_parser = crate::args::whole::<u64>)]
    seed: u64,
    /// Route length, km.
    #[arg(long, default_value_t = 24.0, allow_hyphen_values = true, value_parser = route_length_km)]
    length_km: f64,
    /// Output CSV; the sidecar JSON (the truth, bound to the CSV by its
    /// fingerprint) is written beside it, with the extension .json (a file
    /// there that is not a simulator sidecar is left alone: the run is
    /// refused).
    #[arg(long)]
    out: PathBuf,
    /// Noise preset: paper, off, white (white wheel noise only), high, or
    /// random:N, the random noise world of seed N (every source drawn from
    /// a wide range; docs/reference.md, "Random noise worlds").
    #[arg(long, default_value = "paper", value_parser = noise_preset)]
    noise: String,
    /// True θ as c_e,c_d,t_r,d in SI units (c_d in m, d in m per m/s²), or a
    /// parameter file (.yaml, .yml, .json, as --params-out writes).
    #[arg(long, allow_hyphen_values = true)]
    theta: Option<ThetaArg>,
    /// Integration substeps per output sample (1 makes the model exact).
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=10_000))]
    substeps: Option<u16>,
    /// Let c_e drift linearly: its change per hour of driving as a fraction
    /// of its starting value (-0.003: falling 0.3 % an hour). The sidecar
    /// records the drift and θ at the end (theta_true_end).
    #[arg(long, allow_hyphen_values = true, value_name = "FRACTION", value_parser = finite_number)]
    ce_ramp_per_hour: Option<f64>,
    /// A step of c_d: MM millimetres added from SECONDS into the drive on
    /// (0.5@1800: +0.5 mm after 30 min).
    #[arg(long, allow_hyphen_values = true, value_name = "MM@SECONDS", value_parser = parse_cd_step)]
    cd_step: Option<CdStep>,
}

/// The simulator's errors of the options a flag sets, as usage errors
/// naming the flag: the route's length (`demo` and `simulate`).
pub fn flag_error(e: odocal::Error) -> odocal::Error {
    match e {
        odocal::Error::InvalidOption { field: "length_km", reason } => {
            odocal::Error::InvalidFlags(format!("--length-km: {reason}"))
        }
        e => e,
    }
}

/// [`flag_error`], and the drift's errors naming the drift flags given
/// (`--ce-ramp-per-hour`, `--cd-step`, or both).
fn simulate_flag_error(a: &SimulateArgs, e: odocal::Error) -> odocal::Error {
    match e {
        odocal::Error::InvalidOption { field, reason } if field.starts_with("drift.c_e") => {
            odocal::Error::InvalidFlags(format!("--ce-ramp-per-hour: {reason}"))
        }
        odocal::Error::InvalidOption { field, reason } if field.starts_with("drift.c_d") => {
            odocal::Error::InvalidFlags(format!("--cd-step: {reason}"))
        }
        odocal::Error::InvalidOption { field: "drift", reason } => {
            let given: Vec<&str> =
                [("--ce-ramp-per-hour", a.ce_ramp_per_hour.is_some()), ("--cd-step", a.cd_step.is_some())]
                    .into_iter()
                    .filter_map(|(flag, given)| given.then_some(flag))
                    .collect();
            let flags = if given.is_empty() { "--ce-ramp-per-hour, --cd-step".to_string() } else { given.join(", ") };
            odocal::Error::InvalidFlags(format!("{flags}: {reason}"))
        }
        e => flag_error(e),
    }
}

/// `--length-km`: a positive number of kilometres (the simulator's
/// ceiling is its own check).
pub fn route_length_km(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(km) if km.is_finite() && km > 0.0 => Ok(km),
        Ok(km) => Err(format!("must be a positive number of kilometres, got {km}")),
        Err(e) => Err(e.to_string()),
    }
}

/// A finite number (`nan` and `inf` are refused when the command line is parsed).
fn finite_number(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        Ok(x) => Err(format!("must be a finite number, got {x}")),
        Err(e) => Err(e.to_string()),
    }
}

/// `--noise`: a preset the simulator knows (`paper`, `random:N`, …), as
/// the library parses it.
pub fn noise_preset(s: &str) -> Result<String, String> {
    s.parse::<NoiseOptions>().map(|_| s.to_string()).map_err(|e| match e {
        odocal::Error::InvalidOption { reason, .. } => reason,
        e => e.to_string(),
    })
}

/// `MM@SECONDS` of --cd-step.
fn parse_cd_step(s: &str) -> Result<CdStep, String> {
    let (mm, at) = s.split_once('@').ok_or_else(|| format!("'{s}': expected MM@SECONDS, e.g. 0.5@1800"))?;
    let num = |v: &str, what: &str| {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("'{s}': {what} '{v}' is not a finite number"))
    };
    let (change_mm, at_s) = (num(mm, "the change (mm)")?, num(at, "the time (s)")?);
    if at_s < 0.0 {
        return Err(format!("'{s}': the time must not be negative"));
    }
    Ok(CdStep { change_m: change_mm * 1e-3, at_s })
}

/// The simulator's options for a seed, a route length and a noise preset.
pub fn sim_options(seed: u64, length_km: f64, noise: &str) -> Result<SimOptions> {
    let noise = noise.parse::<NoiseOptions>()?;
    Ok(SimOptions { seed, length_km, noise, ..SimOptions::paper(seed) })
}

/// Simulates the drive and writes its CSV and sidecar JSON.
pub fn run(mut a: SimulateArgs, bars: &Bars) -> Result<()> {
    a.theta = a.theta.map(|t| t.resolved(None)).transpose()?;
    refuse_stdout("--out", &a.out, "simulate writes the drive's sidecar (the truth) beside the CSV")?;
    refuse_sidecar_onto_drive("--out", &a.out)?;
    let side = sim::SimSidecar::path_beside(&a.out);
    let mut files = Files::default();
    if let Some((p, _)) = a.theta.as_ref().and_then(|t| t.file.as_ref()) {
        files.input("the --theta parameter file", p);
    }
    files.output("--out", Some(&a.out)).output("the sidecar beside --out (its name with .json)", Some(&side));
    files.check()?;
    refuse_foreign_sidecar("--out", &a.out)?;
    let mut o = sim_options(a.seed, a.length_km, &a.noise)?;
    if let Some(t) = &a.theta {
        o.theta_true = t.theta;
    }
    if let Some(s) = a.substeps {
        o.substeps = s.into();
    }
    if let Some(r) = a.ce_ramp_per_hour {
        o.drift.c_e_relative_per_hour = r;
    }
    o.drift.c_d_step = a.cd_step;
    bars.stage("simulating");
    let out = sim::simulate(&o).map_err(|e| simulate_flag_error(&a, e))?;
    bars.finish();
    out.drive.write_csv(&a.out)?;
    out.sidecar.write_beside(&a.out)?;
    if a.noise.starts_with("random:") {
        println!("noise world {}: {}", a.noise, o.noise.world_summary());
    }
    let s = &out.sidecar.stats;
    println!(
        "wrote {} ({} samples, {:.2} km, {:.0} s, max yaw rate {:.2} rad/s, max |a_y| {:.2} m/s², wheel error {:.2} % rms) and {}",
        a.out.display(),
        s.samples,
        s.distance_m / 1e3,
        s.duration_s,
        s.max_yaw_rate_rad_per_s,
        s.max_abs_lateral_acceleration_m_per_s2,
        s.wheel_rotation_rel_error_rms * 100.0,
        side.display()
    );
    if let Some(end) = out.sidecar.theta_true_end {
        println!("the true θ drifts from {} at the start to {} at the end", out.sidecar.theta_true, end);
    }
    Ok(())
}
