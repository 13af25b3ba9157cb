//! Writes a calibration as a ROS 2 parameter file, reads it back and uses
//! the θ it holds: the round trip of `odocal calibrate --params-out` and
//! `odocal validate --theta FILE`, with its verdict.
//!
//! ```sh
//! cargo run --release -p odocal --example param_file -- examples/psu-mapping-van-testtrack/run-14-45-26.toml \
//!     examples/psu-mapping-van-testtrack/run-16-47-33.toml params.yaml
//! ```

use std::path::Path;

use odocal::{calibrate, load_drive, validate, CalibrationOptions, ParamFile, ValidateOptions};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let [_, fit, other, out] = &args[..] else {
        return Err("usage: param_file FIT_DRIVE OTHER_DRIVE OUT.yaml|OUT.json".into());
    };
    let (drive, _) = load_drive(Path::new(fit))?;
    let report = calibrate(&drive, &CalibrationOptions::default())?;

    // θ with its 1σ (None for held parameters), the verdict and provenance;
    // `.yaml` writes the ROS 2 `ros__parameters` layout, `.json` JSON.
    let file = report.param_file(fit);
    let text = file.text_for(Path::new(out))?;
    odocal::output::write_text(Path::new(out), &text)?; // atomically
    print!("{text}");

    // Read back: the same θ, to the printed precision of the file.
    let back = ParamFile::read(Path::new(out), None)?;
    let theta = odocal::Theta::try_from(&back)?;
    println!("read back θ: {theta} (calibrated: {})", report.theta);

    // Use it as `odocal validate OTHER --theta OUT` does: dead-reckoning
    // error on another drive of the same vehicle, with the extrinsics the
    // calibration estimated (they hold for the vehicle) and the other
    // drive's own heading offset re-estimated with θ held (the reference's
    // heading bias changes from drive to drive).
    let (other_drive, _) = load_drive(Path::new(other))?;
    let mut opts = ValidateOptions::default();
    opts.set_extrinsics(Some(&back), None, false);
    let v = validate(&other_drive, &theta, &opts, None)?;
    let delta = v.extrinsics.heading_offset * 1e3;
    println!(
        "Ē_p on {other}: {:.2} m over {} segments (its heading offset {delta:.1} mrad)",
        v.validation.mean_position_error_m, v.validation.segments
    );
    // The verdict: θ fits the drive when its Ē_p is within 1.6 times that of
    // θ fitted on the drive itself.
    match (&v.drive_fit, &v.drive_fit_error) {
        (Some(f), _) => {
            println!("θ {} the drive: Ē_p {:.2} × its own fit's", if f.fits { "fits" } else { "does not fit" }, f.ratio)
        }
        (None, Some(why)) => println!("not judged: {why}"),
        (None, None) => {}
    }
    Ok(())
}
