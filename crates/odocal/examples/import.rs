//! Imports a drive manifest (logs of wheel speeds, a reference pose and
//! optionally an IMU, in CSV, MCAP or Parquet) into one drive, prints what
//! the import did, counts the segments a calibration would use and writes
//! the drive as odocal's CSV.
//!
//! ```sh
//! cargo run --release -p odocal --example import -- examples/psu-mapping-van/manifest.toml van.csv
//! ```

use std::path::Path;

use odocal::segment::{calibration_segments, cut, validation_segments, SegmentOptions};
use odocal::{import, Manifest};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let manifest = args.get(1).ok_or("usage: import MANIFEST [OUT.csv]")?;
    // Paths in a manifest are relative to the manifest (docs/reference.md, "The drive manifest").
    let m = Manifest::from_path(Path::new(manifest))?;
    let (drive, report) = import(&m)?;
    // Streams, clock offset, gaps and the continuous parts kept.
    println!("{report}");
    let o = SegmentOptions::default();
    let all = cut(&drive, o.offset_steps, o.length_steps, o.stride_steps);
    let selected = calibration_segments(&drive, &o)?;
    let val = validation_segments(&drive, &Default::default())?;
    println!(
        "segments (the paper's defaults): {} cut, {} selected (peak yaw rate ≥ 0.15 rad/s); {} validation segments",
        all.len(),
        selected.len(),
        val.len()
    );
    if let Some(out) = args.get(2) {
        drive.write_csv(out)?;
        println!("wrote {out}");
    }
    Ok(())
}
