//! Coverage of the 3-step method's σ candidates over simulated drives with
//! a known truth: step 3's model σ and cluster-robust σ (both from the
//! compensated inputs), the cluster-robust σ on the measured inputs at the
//! 3-step θ, and the scaled spread of step 1's batch estimates
//! (the library's `ThreeStepUncertainty`); docs/validation.md,
//! "Coverage of the reported σ".
//!
//! Defaults: 20 seeds (1..=20), 12 km, preset `paper`, 50 step-1 batches;
//! otherwise the default calibration. Per parameter and σ it prints the
//! fraction of seeds whose error lies within ±1σ (nominal 68.3 %) and
//! ±1.96σ (nominal 95 %), the RMS σ and the RMS error. An honest σ has
//! RMS σ ≈ RMS error and coverage near nominal.

use odocal::{CalibrationOptions, Method, Theta, ThreeStepOptions};
use odocal_lab::report_json::{std_dev_of, three_step_part};
use odocal_lab::{coverage, simulate_preset, Args, Res, PARAMETERS};

const USAGE: &str = "three_step_coverage [SEEDS 20] [KM 12] [PRESET paper] [BATCHES 50]";
const SIGMAS: [&str; 4] = ["step-3 model", "step-3 robust", "measured-input robust", "batch spread"];

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let seeds: u64 = args.pos(0, 20)?;
    let km: f64 = args.pos(1, 12.0)?;
    let preset: String = args.pos(2, "paper".to_string())?;
    let batches: usize = args.pos(3, 50)?;
    args.finish()?;
    // err[seed][param], sigma[kind][seed][param] (NaN where a kind is missing)
    let mut err: Vec<[f64; 4]> = Vec::new();
    let mut sigma: Vec<Vec<[f64; 4]>> = vec![Vec::new(); SIGMAS.len()];
    for seed in 1..=seeds {
        let s = simulate_preset(&preset, km, seed)?;
        let opts = CalibrationOptions {
            method: Method::ThreeStep(ThreeStepOptions { initial_batches: batches, ..Default::default() }),
            ..Default::default()
        };
        let r = odocal::calibrate(&s.drive, &opts)?;
        let Some(d) = three_step_part(&r) else { return Err("not a 3-step report".into()) };
        let truth = <[_; 4]>::from(s.sidecar.theta_true);
        let theta = <[_; 4]>::from(r.theta);
        err.push(std::array::from_fn(|i| theta[i] - truth[i]));
        let nan = [f64::NAN; 4];
        let sd = |t: Theta| <[_; 4]>::from(t);
        sigma[0].push(sd(r.std_dev()));
        sigma[1].push(d.identification.robust.as_ref().map_or(nan, |b| sd(b.std_dev())));
        sigma[2].push(d.uncertainty.measured_inputs.as_ref().map_or(nan, |b| sd(b.std_dev())));
        sigma[3].push(d.uncertainty.batch_spread.as_ref().map_or(nan, |b| sd(std_dev_of(&b.covariance))));
        eprintln!(
            "seed {seed}: θ − truth = [{:+.2e}, {:+.2e}, {:+.2e}, {:+.2e}]",
            err[err.len() - 1][0],
            err[err.len() - 1][1],
            err[err.len() - 1][2],
            err[err.len() - 1][3]
        );
    }
    let n = err.len() as f64;
    println!("== 3-step ({batches} batches), preset {preset}: {seeds} seeds x {km} km");
    println!("param | σ | within ±1σ | within ±1.96σ | RMS σ | RMS err | mean err");
    for (i, name) in PARAMETERS.iter().enumerate() {
        let e: Vec<f64> = err.iter().map(|e| e[i]).collect();
        let rms_err = (e.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
        let mean = e.iter().sum::<f64>() / n;
        for (k, kind) in SIGMAS.iter().enumerate() {
            let s: Vec<f64> = sigma[k].iter().map(|s| s[i]).collect();
            let within = |z: f64| coverage(&e, &s, z);
            let rms_s = (sigma[k].iter().map(|s| s[i] * s[i]).sum::<f64>() / n).sqrt();
            println!(
                "{name} | {kind} | {:.2} | {:.2} | {rms_s:.3e} | {rms_err:.3e} | {mean:+.2e}",
                within(1.0),
                within(1.96)
            );
        }
    }
    Ok(())
}
