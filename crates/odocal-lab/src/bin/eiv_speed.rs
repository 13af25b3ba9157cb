//! Wall time of `calibrate` per method on simulated paper-noise drives,
//! side by side in one run (docs/performance.md, "By method and drive
//! length").
//!
//! The minimum wall time over the repetitions is reported (on a shared
//! machine compare ratios within one run). Per EIV run: filter passes
//! `[with derivatives, objective only]`, scoring iterations, windows, and
//! the split of the wall time between the batch G-N start and the filter.
//! With a fingerprint path the results (θ, η, σ, passes; no timings) are
//! written as JSON, to check that a speed change leaves them unchanged.
//!
//! Methods: `batch-gn`, `three-step`, `eiv-fixed` (`--fix-noise`, the
//! production-car noise model), `eiv-estimated` (the EIV filter's defaults
//! without the method's bias correction, `--no-bias-correction`), the same
//! two with quantisation as process noise (`eiv-fixed-process`,
//! `eiv-estimated-process`: two filter states fewer),
//! `eiv-estimated-no-eta-cov` (`eiv-estimated` without the η term of θ's
//! covariance, `ResearchOptions::noise_estimate_term`), and the
//! default method with its bootstrap bias correction, `eiv-corrected-4`
//! (B = 4, the default) and `eiv-corrected-10` (`--correct-bias 10`).

use std::time::Instant;

use odocal::eiv::{EivOptions, NoiseEstimateTerm, QuantisationModel, ResearchOptions};
use odocal::sim::{simulate, SimOptions};
use odocal::{calibrate, CalibrationOptions, CalibrationReport, Method};
use odocal::{CorrectBias, EivMethodOptions};
use odocal_lab::report_json::eiv_part;
use odocal_lab::{Args, Res};

const USAGE: &str = "eiv_speed [KM,KM,… 12,24,48] [REPS 3] [SEED 1] [FINGERPRINT.json|- -] [METHODS all]";

/// The EIV method without its bias correction, with these filter options.
fn uncorrected(filter: EivOptions) -> Method {
    Method::Eiv(EivMethodOptions { filter, correct_bias: None, ..Default::default() })
}

fn methods() -> Res<Vec<(&'static str, Method)>> {
    let eiv = |fix_noise: bool, quantisation: QuantisationModel| {
        uncorrected(EivOptions { fix_noise, quantisation, ..Default::default() })
    };
    let counting = EivOptions::default().quantisation;
    let process = QuantisationModel::ProcessNoise;
    let no_eta_cov = EivOptions {
        research: ResearchOptions { noise_estimate_term: NoiseEstimateTerm::Omitted, ..Default::default() },
        ..Default::default()
    };
    let corrected = |replicates: usize| {
        Method::Eiv(EivMethodOptions {
            correct_bias: Some(CorrectBias { replicates, ..Default::default() }),
            ..Default::default()
        })
    };
    Ok(vec![
        ("batch-gn", "batch-gn".parse::<Method>()?),
        ("three-step", "three-step".parse::<Method>()?),
        ("eiv-fixed", eiv(true, counting)),
        ("eiv-estimated", eiv(false, counting)),
        ("eiv-fixed-process", eiv(true, process)),
        ("eiv-estimated-process", eiv(false, process)),
        ("eiv-estimated-no-eta-cov", uncorrected(no_eta_cov)),
        ("eiv-corrected-4", corrected(4)),
        ("eiv-corrected-10", corrected(10)),
    ])
}

fn main() {
    odocal_lab::main_with(run)
}

fn run() -> Res<()> {
    let args = Args::parse(USAGE, &[])?;
    let kms: Vec<f64> = args.pos(0, "12,24,48".to_string())?.split(',').map(str::parse).collect::<Result<_, _>>()?;
    let reps: usize = args.pos(1, 3usize)?.max(1);
    let seed: u64 = args.pos(2, 1)?;
    let fingerprint_path = Some(args.pos(3, "-".to_string())?).filter(|p| p.as_str() != "-");
    let pick: Option<Vec<String>> = args.positional().get(4).map(|s| s.split(',').map(str::to_string).collect());
    args.finish()?;
    let mut fingerprint = Vec::new();
    println!(
        "threads {}; filter kernels {}; minimum of {reps} wall time(s) per cell",
        rayon::current_num_threads(),
        odocal::eiv::kernel_instruction_set()
    );
    println!("km | samples | method | wall s (min, all) | start s | filter s | passes [derivs, cost] | it | windows");
    for &km in &kms {
        let out = simulate(&SimOptions { length_km: km, ..SimOptions::paper(seed) })?;
        let d = &out.drive;
        for (name, method) in methods()? {
            if pick.as_ref().is_some_and(|p| !p.iter().any(|x| x == name)) {
                continue;
            }
            let opts = CalibrationOptions { method, ..Default::default() };
            let mut times = Vec::with_capacity(reps);
            let mut last: Option<CalibrationReport> = None;
            for _ in 0..reps {
                let t = Instant::now();
                let r = calibrate(d, &opts)?;
                times.push(t.elapsed().as_secs_f64());
                last = Some(r);
            }
            let Some(r) = last else { continue };
            let best = times.iter().copied().fold(f64::INFINITY, f64::min);
            let all: Vec<String> = times.iter().map(|t| format!("{t:.2}")).collect();
            let (mut passes, mut it, mut windows) = (String::new(), String::new(), String::new());
            let mut entry = serde_json::json!({ "km": km, "method": name, "theta": r.theta });
            if let Some(e) = eiv_part(&r) {
                if let Some(f) = &e.eiv {
                    passes = format!("{:?}", f.evaluations);
                    it = f.iterations.to_string();
                    windows = f.windows.len().to_string();
                    entry = serde_json::json!({
                        "km": km, "method": name, "theta": f.theta, "eta": f.eta, "sigma": f.sigma,
                        "sigma_sandwich": f.sigma_sandwich, "sigma_fisher": f.sigma_fisher,
                        "eta_sigma": f.eta_sigma, "evaluations": f.evaluations, "iterations": f.iterations,
                        "final_cost": f.final_cost, "termination": f.termination, "warnings": f.warnings,
                        "result": e.eiv_result, "returned_theta": r.theta,
                    });
                }
            }
            fingerprint.push(entry);
            println!(
                "{km} | {} | {name} | {best:.2} ({}) | {:.2} | {:.2} | {passes} | {it} | {windows}",
                d.len(),
                all.join(" "),
                r.timing().initial_identification,
                r.timing().final_identification,
            );
        }
    }
    if let Some(p) = fingerprint_path {
        std::fs::write(p, serde_json::to_string_pretty(&fingerprint)?)?;
    }
    Ok(())
}
