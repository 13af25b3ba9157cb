//! Calibrates a logged drive with the default method and prints θ with its
//! 1σ, the verdict and the dead-reckoning error Ē_p against the start θ_0.
//!
//! The drive is a CSV of odocal's columns (docs/reference.md, "The drive
//! CSV") or a manifest that imports a log (`examples/*/`):
//!
//! ```sh
//! cargo run --release -p odocal --example calibrate_drive -- examples/psu-mapping-van-testtrack/run-14-45-26.toml
//! cargo run --release -p odocal --example simulate_and_recover -- drive.csv   # writes a simulated CSV first
//! cargo run --release -p odocal --example calibrate_drive -- drive.csv
//! ```

use std::path::Path;

use odocal::{calibrate, load_drive, CalibrationOptions, Method};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).ok_or("usage: calibrate_drive DRIVE.csv|MANIFEST.toml [METHOD]")?;
    // A manifest also returns what its import did (streams, clock offset, parts).
    let (drive, import) = load_drive(Path::new(&path))?;
    if let Some(report) = import {
        println!("{report}");
    }
    // The default method is `eiv`; `batch-gn` and `three-step` (the paper's) are the others.
    let mut options = CalibrationOptions::default();
    if let Some(name) = std::env::args().nth(2) {
        options.method = name.parse::<Method>()?;
    }
    let report = calibrate(&drive, &options)?;

    // The σ that stands for the result (the verdict and the parameter file use it).
    let sigma = report.result_sigma();
    let names = ["c_e m", "c_d m", "t_r m", "d m/(m/s²)"];
    println!("method {}: θ: {}", report.method, report.theta);
    for ((name, value), s) in names.iter().zip(<[_; 4]>::from(report.theta)).zip(<[_; 4]>::from(sigma)) {
        match s {
            Some(s) => println!("  {name:11} {value:+.6} ± {s:.6} (1σ, {})", sigma.covers),
            None => println!("  {name:11} {value:+.6} (held)"),
        }
    }
    println!(
        "Ē_p on {} validation segments: {:.2} m (θ_0: {:.2} m)",
        report.validation.segments, report.validation.mean_position_error_m, report.initial.mean_position_error_m
    );
    println!("verdict: {}", report.verdict.level);
    for reason in &report.verdict.reasons {
        println!("  - {reason}");
    }
    for warning in &report.warnings {
        println!("warning: {warning}");
    }
    Ok(())
}
