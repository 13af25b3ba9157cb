//! Writes a sample HTML report of a simulated drive calibrated with batch
//! Gauss-Newton: `cargo run --release -p odocal-report --example sample_report -- OUT.html`.

use odocal::{segment, sim, Theta};
use odocal_report::{write_html, ParamRow, ReportInput};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out_path = std::env::args().nth(1).unwrap_or_else(|| "report.html".into());
    let out = sim::simulate(&sim::SimOptions { length_km: 6.0, ..sim::SimOptions::paper(1) })?;
    let drive = &out.drive;
    let opts = odocal::CalibrationOptions { method: odocal::Method::BatchGn, ..Default::default() };
    let report = odocal::calibrate(drive, &opts)?;
    let segs = segment::validation_segments(drive, &Default::default())?;
    let truth = out.sidecar.theta_true;
    let th0 = Theta::PAPER_INITIAL;
    let input = ReportInput {
        params: ParamRow::theta_rows(&th0, &report.theta, None, Some(&truth)),
        truth: Some(truth),
        provenance: vec![("method".into(), "batch-gn".into()), ("drive".into(), "simulated 6 km, seed 1".into())],
        ..ReportInput::new("simulated drive", drive, &segs, th0, report.theta)
    };
    write_html(std::path::Path::new(&out_path), &input)?;
    println!("wrote {out_path}");
    Ok(())
}
