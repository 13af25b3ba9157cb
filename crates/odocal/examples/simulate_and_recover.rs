//! Simulates a drive with a known θ and realistic noise, calibrates it with
//! each method and compares the estimates with the truth: the check that a
//! calibration recovers what it should.
//!
//! ```sh
//! cargo run --release -p odocal --example simulate_and_recover             # 6 km, paper-like noise
//! cargo run --release -p odocal --example simulate_and_recover -- drive.csv   # also write the drive
//! ```

use odocal::sim::{simulate, SimOptions};
use odocal::{calibrate, mean_position_error, CalibrationOptions, Method, Theta};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // The paper's city route with its noise (wheel, reference, a_y, β); seed 1.
    let sim = simulate(&SimOptions { length_km: 6.0, ..SimOptions::paper(1) })?;
    let (drive, truth) = (&sim.drive, sim.sidecar.theta_true);
    println!("simulated {} km, {} samples; true θ: {truth}", sim.sidecar.settings.length_km, drive.len());
    if let Some(out) = std::env::args().nth(1) {
        drive.write_csv(&out)?; // the CSV that `odocal calibrate` and `load_drive` read
        println!("wrote {out}");
    }

    for name in ["batch-gn", "three-step", "eiv"] {
        let options = CalibrationOptions { method: name.parse::<Method>()?, ..Default::default() };
        let report = calibrate(drive, &options)?;
        let sigma = <[_; 4]>::from(report.result_sigma());
        // Error over the reported σ: about ±2 or less for an unbiased estimate with an honest σ.
        let z: Vec<String> = error(&report.theta, &truth)
            .iter()
            .zip(sigma)
            .map(|(e, s)| s.map_or("held".into(), |s| format!("{:+.1}", e / s)))
            .collect();
        println!("{name:10} θ: {}  error/σ [c_e, c_d, t_r, d] = [{}]", report.theta, z.join(", "));
    }

    // Dead reckoning with the true θ: the floor that noise leaves on Ē_p.
    let validation = odocal::segment::validation_segments(drive, &Default::default())?;
    let floor = mean_position_error(drive, &validation, &truth)?;
    println!("Ē_p with the true θ: {:.2} m", floor.mean_position_error_m);
    Ok(())
}

/// θ − truth, SI.
fn error(theta: &Theta, truth: &Theta) -> [f64; 4] {
    let (a, b) = (<[f64; 4]>::from(theta), <[f64; 4]>::from(truth));
    std::array::from_fn(|i| a[i] - b[i])
}
