//! Imports a drive manifest and writes the canonical CSV:
//! `cargo run --release -p odocal --example import -- MANIFEST [OUT.csv]`.

use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let manifest = args.get(1).ok_or("usage: import MANIFEST [OUT.csv]")?;
    let m = odocal::io::import::Manifest::from_path(Path::new(manifest))?;
    let imported = odocal::io::import::import(&m)?;
    println!("{}", imported.report);
    let sel = odocal::drive::segment::calibration_segments(&imported.drive, &odocal::SegmentOptions::default())?;
    let val =
        odocal::drive::segment::validation_segments(&imported.drive, &odocal::ValidationSegmentOptions::default())?;
    println!(
        "  segments (SPEC defaults): {} cut, {} selected (peak yaw rate > 0.15 rad/s); {} validation segments",
        sel.all.len(),
        sel.selected.len(),
        val.len()
    );
    if let Some(out) = args.get(2) {
        imported.drive.write_csv(out)?;
    }
    Ok(())
}
