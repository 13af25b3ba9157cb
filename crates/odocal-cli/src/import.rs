//! `odocal import`: a multi-stream log described by a manifest into a
//! canonical drive CSV.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;

use crate::io::write_json;

/// Arguments of `odocal import`.
#[derive(Args)]
pub struct ImportArgs {
    /// The drive manifest (TOML; docs/reference.md, "The drive manifest").
    manifest: PathBuf,
    /// Output canonical CSV.
    #[arg(long)]
    out: PathBuf,
    /// Write the import report as JSON here ("-" for stdout).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Imports the log, writes the CSV and prints (or writes) the import report.
pub fn run(a: ImportArgs) -> Result<()> {
    let m = odocal::Manifest::from_path(&a.manifest)?;
    // The calibration settings are checked too, so a bad one is named now.
    odocal::settings::ManifestSettings::of_manifest(&m)?;
    let imported = odocal::import(&m)?;
    imported.drive.write_csv(&a.out)?;
    if let Some(p) = &a.json {
        write_json(p, odocal::settings::import_report_json(&imported.report)?)?;
        if p == Path::new("-") {
            return Ok(());
        }
    }
    println!("{}", imported.report.to_string().trim_end());
    println!("wrote {}", a.out.display());
    Ok(())
}
