//! Wall time of `calibrate` per method on simulated paper-noise drives,
//! side by side in one run (issue 9's speed target for `--method eiv`):
//!
//! ```text
//! cargo run --release -p odocal --example eiv_speed -- [km,km,..] [reps] [seed] [fingerprint.json|-] [methods]
//! ```
//!
//! Defaults: 12,24,48 km, 3 repetitions (the minimum wall time is
//! reported; the machine is shared, so compare ratios within one run),
//! seed 1. Methods: batch G-N, the 3-step (the default) and EIV with the
//! production-car noise model fixed (`--fix-noise`) and estimated (the
//! method's default). Per EIV run: filter passes `[with derivatives,
//! objective only]`, scoring iterations, windows, and the split of the
//! wall time between the batch G-N start and the filter. With a fourth
//! argument the results (θ, η, σ, passes; no timings) are written as JSON,
//! to check that a speed change leaves them unchanged (`-`: not written).
//! The fifth argument picks methods by name (comma separated: `batch-gn`,
//! `three-step`, `eiv-fixed`, `eiv-estimated` (the library's EIV filter
//! defaults without the method's bias correction, stop 21:
//! counting quantisation since stop 14), and the same two EIV runs with
//! quantisation as process noise (the default before stop 14, two filter
//! states fewer), `eiv-fixed-process`, `eiv-estimated-process`, and
//! `eiv-estimated-no-eta-cov` (the default without
//! `EivOptions::noise_estimate_in_covariance`, stop 16), and the default
//! with the bootstrap bias correction, `eiv-corrected-4` (the method's
//! default since stop 21) and `eiv-corrected-10` (`--correct-bias 10`);
//! default all).

use std::time::Instant;

use odocal::calibrate::{EivMethodOptions, MethodDetail};
use odocal::eiv::{EivOptions, QuantisationModel};
use odocal::sim::{simulate, SimOptions};
use odocal::{calibrate, CalibrationOptions, CalibrationReport, Method};

fn methods() -> Vec<(&'static str, Method)> {
    // `None`: the library's default quantisation model (counting since stop 14).
    let eiv = |fix_noise: bool, quantisation: Option<QuantisationModel>| {
        let d = EivOptions::default();
        Method::Eiv(EivMethodOptions {
            filter: EivOptions { fix_noise, quantisation: quantisation.unwrap_or(d.quantisation), ..d },
            // The fit alone (the method's default bias correction: `eiv-corrected-*`).
            correct_bias: None,
            ..Default::default()
        })
    };
    let process = Some(QuantisationModel::ProcessNoise);
    vec![
        ("batch-gn", Method::from_name("batch-gn").expect("method")),
        ("three-step", Method::from_name("three-step").expect("method")),
        ("eiv-fixed", eiv(true, None)),
        ("eiv-estimated", eiv(false, None)),
        ("eiv-fixed-process", eiv(true, process)),
        ("eiv-estimated-process", eiv(false, process)),
        // Stop 16: the default without the covariance term for η (its extra filter passes).
        (
            "eiv-estimated-no-eta-cov",
            Method::Eiv(EivMethodOptions {
                filter: EivOptions { noise_estimate_in_covariance: false, ..EivOptions::default() },
                correct_bias: None,
                ..Default::default()
            }),
        ),
        // Stop 21: the default with the bootstrap bias correction (`--correct-bias B`, antithetic pairs).
        ("eiv-corrected-4", corrected(4)),
        ("eiv-corrected-10", corrected(10)),
    ]
}

/// The default EIV method with its bias correction at B replicates (B = 4
/// is the default since stop 21).
fn corrected(b: usize) -> Method {
    Method::Eiv(EivMethodOptions {
        correct_bias: Some(odocal::calibrate::CorrectBias { replicates: b, seed: 0 }),
        ..Default::default()
    })
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let kms: Vec<f64> = match args.get(1) {
        Some(s) => s.split(',').map(str::parse).collect::<Result<_, _>>()?,
        None => vec![12.0, 24.0, 48.0],
    };
    let reps: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(3).max(1);
    let seed: u64 = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(1);
    let fingerprint_path = args.get(4).filter(|p| p.as_str() != "-");
    let pick: Option<Vec<&str>> = args.get(5).map(|s| s.split(',').collect());
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
        for (name, method) in methods() {
            if pick.as_ref().is_some_and(|p| !p.contains(&name)) {
                continue;
            }
            let opts = CalibrationOptions { method, ..Default::default() };
            let mut times = Vec::with_capacity(reps);
            let mut last: Option<CalibrationReport> = None;
            for _ in 0..reps {
                let t = Instant::now();
                let r = calibrate(d, &opts, None)?;
                times.push(t.elapsed().as_secs_f64());
                last = Some(r);
            }
            let Some(r) = last else { continue };
            let best = times.iter().copied().fold(f64::INFINITY, f64::min);
            let all: Vec<String> = times.iter().map(|t| format!("{t:.2}")).collect();
            let (mut passes, mut it, mut windows) = (String::new(), String::new(), String::new());
            let mut entry = serde_json::json!({ "km": km, "method": name, "theta": r.theta });
            if let MethodDetail::Eiv(e) = &r.detail {
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
                r.timing_s.initial_identification,
                r.timing_s.final_identification,
            );
        }
    }
    if let Some(p) = fingerprint_path {
        std::fs::write(p, serde_json::to_string_pretty(&fingerprint)?)?;
    }
    Ok(())
}
