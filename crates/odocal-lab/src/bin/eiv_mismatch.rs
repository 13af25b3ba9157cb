//! Which departure of the simulator from the EIV filter's model costs the
//! efficiency on `high`? Also the reported σ against the bound
//! (docs/validation.md, "Coverage of the reported σ": `eiv_mismatch high 20
//! 12 as-is`, with `EST=1` the noise model estimated).
//!
//! The known-noise EIV fit (the simulator's noise model, fixed) is run on
//! the same drives with one simulator effect switched off at a time, and its
//! RMS error is read against the Cramér–Rao bound of that drive at θ_true
//! (full Fisher, mean-only and with the noise scales unknown, CRB_η).
//!
//! Variants (comma-separated; default all): `as-is`, `no-slip` (no slip
//! with acceleration), `one-substep` (truth integrated with the filter's
//! own step), `no-quant` (no encoder quantisation), `no-lateral` (exact a_y
//! and β), `none` (all of the above off).
//!
//! The bound is linearised along the drive's true inputs
//! (`EivInput::from_drive_truth`) with `EivOptions::spec()`. Environment:
//! `CRB_MEASURED=1` linearises it along the measured inputs instead (which
//! overstates t_r's and d's information about 2× on `high`); `CRB_KNOWN=1`
//! computes it with the fit's own options; `START_TRUE=1` starts the fit at
//! θ_true instead of batch G-N; `EST=1` estimates the noise model
//! (uncorrected) instead of knowing it.

use odocal::eiv::{cramer_rao_bound, estimate, EivInput, EivOptions, NoiseModel};
use odocal::sim::{simulate, NoiseOptions, SimOptions};
use odocal_lab::{batch_gn_all, Args, Res, PARAMETERS};

const USAGE: &str =
    "[EST=1] [START_TRUE=1] [CRB_KNOWN=1] [CRB_MEASURED=1] eiv_mismatch [PRESET high] [SEEDS 20] [KM 12]
    [VARIANTS as-is,no-slip,one-substep,no-quant,no-lateral,none]";

/// The simulator's departures from the filter's model, each a variant that switches it off.
const DEPARTURES: [&str; 4] = ["no-slip", "one-substep", "no-quant", "no-lateral"];

fn switch_off(o: &mut SimOptions, departure: &str) {
    match departure {
        "no-slip" => o.noise.wheel_slip_per_m_per_s2 = 0.0,
        "one-substep" => o.substeps = 1,
        "no-quant" => o.noise.encoder_ticks_per_revolution = 0,
        "no-lateral" => {
            o.noise.lateral_acceleration_white_sigma_m_per_s2 = 0.0;
            o.noise.sideslip_sigma_rad = 0.0;
        }
        other => unreachable!("not a departure: {other}"),
    }
}

fn variant(base: &SimOptions, name: &str) -> Result<SimOptions, String> {
    let mut o = base.clone();
    match name {
        "as-is" => {}
        "none" => DEPARTURES.iter().for_each(|d| switch_off(&mut o, d)),
        d if DEPARTURES.contains(&d) => switch_off(&mut o, d),
        other => return Err(format!("unknown variant '{other}'")),
    }
    Ok(o)
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let preset: String = args.pos(0, "high".to_string())?;
    let seeds: u64 = args.pos(1, 20)?;
    let km: f64 = args.pos(2, 12.0)?;
    let variants: Vec<String> = args.positional().get(3).map_or_else(
        || std::iter::once("as-is").chain(DEPARTURES).chain(["none"]).map(String::from).collect(),
        |s| s.split(',').map(str::to_string).collect(),
    );
    args.finish()?;
    let noise = preset.parse::<NoiseOptions>()?;
    let flag = |name: &str| std::env::var_os(name).is_some();
    let (start_true, estimated, crb_known, crb_measured) =
        (flag("START_TRUE"), flag("EST"), flag("CRB_KNOWN"), flag("CRB_MEASURED"));
    let model = if estimated { "the noise model estimated" } else { "the simulator's noise model, fixed" };
    println!("preset {preset}, {km} km, seeds 1..={seeds}; EIV with {model}, uncorrected");
    println!(
        "| variant | parameter | mean error | t | RMS / CRB | RMS / mean-only | RMS / CRB_η | fit's σ / mean-only bound |"
    );
    println!("|---|---|---:|---:|---:|---:|---:|---:|");
    for v in &variants {
        let (mut sum, mut sq, mut crb2, mut mean2, mut eta2) = ([0.0f64; 4], [0.0f64; 4], [0.0; 4], [0.0; 4], [0.0; 4]);
        // The fits' own reported σ (RMS over drives).
        let mut fit2 = [0.0f64; 4];
        let mut n = 0usize;
        for seed in 1..=seeds {
            let base = SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) };
            let out = simulate(&variant(&base, v)?)?;
            let d = &out.drive;
            let truth = <[_; 4]>::from(out.sidecar.theta_true);
            let input = EivInput::from_drive(d);
            let mut start = batch_gn_all(d)?;
            if start_true {
                start = out.sidecar.theta_true;
            }
            let true_noise = NoiseModel::from_sim(&out.sidecar.settings.noise, d.sample_time_s());
            let known = EivOptions { noise: true_noise, fix_noise: true, ..Default::default() };
            // EST=1: the noise model estimated from the drive (uncorrected) instead of known.
            let fit_opts = if estimated { EivOptions::default() } else { known.clone() };
            let fit = match estimate(&input, &start, &fit_opts) {
                Ok(f) => f,
                Err(e) => {
                    eprintln!("{v} seed {seed}: {e}");
                    continue;
                }
            };
            let crb_opts = if crb_known { known } else { EivOptions::spec() };
            // CRB_MEASURED: linearised along the measured inputs.
            let crb_input = if crb_measured { input } else { EivInput::from_drive_truth(d)? };
            let crb = cramer_rao_bound(&crb_input, &out.sidecar.theta_true, &true_noise, &crb_opts)?;
            let t = <[_; 4]>::from(fit.theta);
            for i in 0..4 {
                // c_e and t_r relative, c_d and d absolute (as the study prints them).
                let scale = if i == 1 || i == 3 { 1.0 } else { 1.0 / truth[i].abs() };
                let e = (t[i] - truth[i]) * scale;
                sum[i] += e;
                sq[i] += e * e;
                crb2[i] += (crb.sigma[i] * scale).powi(2);
                fit2[i] += (fit.sigma[i] * scale).powi(2);
                mean2[i] += (crb.sigma_mean_only[i] * scale).powi(2);
                eta2[i] += (crb.sigma_noise_estimated.map_or(f64::NAN, |s| s[i]) * scale).powi(2);
            }
            n += 1;
        }
        if n < 2 {
            return Err(format!("{v}: {n} drive(s) fitted, at least 2 needed for a spread").into());
        }
        let nf = n as f64;
        for i in 0..4 {
            let mean = sum[i] / nf;
            let sd = ((sq[i] - nf * mean * mean) / (nf - 1.0)).max(0.0).sqrt();
            let rms = (sq[i] / nf).sqrt();
            let r = |b: f64| rms / (b / nf).sqrt();
            println!(
                "| {v} | {} | {mean:+.3e} | {:.1} | {:.2} | {:.2} | {:.2} | {:.2} |",
                PARAMETERS[i],
                mean / (sd / nf.sqrt()),
                r(crb2[i]),
                r(mean2[i]),
                r(eta2[i]),
                (fit2[i] / mean2[i]).sqrt()
            );
        }
    }
    Ok(())
}
