//! Writes a calibration as a ROS 2 parameter file, reads it back and uses
//! the θ it holds: the round trip of `odocal calibrate --params-out` and
//! `odocal validate --params`.
//!
//! ```sh
//! cargo run --release -p odocal --example param_file -- examples/psu-mapping-van-testtrack/run-14-45-26.toml \
//!     examples/psu-mapping-van-testtrack/run-16-47-33.toml params.yaml
//! ```

use std::path::Path;

use odocal::segment::validation_segments;
use odocal::ParamFile;
use odocal::{calibrate, load_drive, mean_position_error, CalibrationOptions};

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
    file.write(Path::new(out))?;
    print!("{}", std::fs::read_to_string(out)?);

    // Read back: the same θ, to the printed precision of the file.
    let back = ParamFile::read(Path::new(out), None)?;
    let theta = odocal::Theta::try_from(&back)?;
    println!("read back θ: {theta} (calibrated: {})", report.theta);

    // Use it: dead-reckoning error on another drive of the same vehicle.
    let (other_drive, _) = load_drive(Path::new(other))?;
    let segments = validation_segments(&other_drive, &Default::default())?;
    let v = mean_position_error(&other_drive, &segments, &theta)?;
    println!("Ē_p on {other}: {:.2} m over {} segments", v.mean_position_error_m, v.segments);
    Ok(())
}
