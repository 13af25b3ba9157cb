//! `odocal import`: a multi-stream log described by a manifest into a
//! canonical drive CSV.

use std::path::PathBuf;

use crate::output::is_stdout;
use anyhow::Result;
use clap::Args;

use crate::io::write_json;
use crate::output::{report_line, write_drive, Files};

/// Arguments of `odocal import`.
#[derive(Args)]
pub struct ImportArgs {
    /// The drive manifest (TOML; docs/reference.md, "The drive manifest").
    manifest: PathBuf,
    /// Output canonical CSV ("-" for stdout; the report then goes to stderr).
    #[arg(long)]
    out: PathBuf,
    /// Write the import report as JSON here ("-" for stdout).
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Imports the log, writes the CSV and prints (or writes) the import report.
pub fn run(a: ImportArgs) -> Result<()> {
    if is_stdout(&a.manifest) {
        anyhow::bail!(
            "-: a manifest is read from a file, not from stdin (its stream files are found beside it): give the \
             manifest's path"
        );
    }
    let mut files = Files::default();
    files.manifest("the manifest being imported", &a.manifest);
    files.output("--out", Some(&a.out)).output("--json", a.json.as_deref()).check()?;
    let m = odocal::Manifest::from_path(&a.manifest)?;
    // The calibration settings are checked too, so a bad one is named now.
    odocal::settings::ManifestSettings::try_from(&m)?;
    let (drive, mut report) = odocal::import(&m)?;
    write_drive(&drive, &a.out)?;
    // Warnings go to stderr, whichever outputs take stdout.
    for w in &report.warnings {
        eprintln!("warning: {w}");
    }
    if let Some(p) = &a.json {
        let mut v = odocal::settings::import_report_json(&report)?;
        if let Some(obj) = v.as_object_mut() {
            obj.insert("fingerprint".into(), drive.fingerprint().into());
        }
        write_json(p, v)?;
        if is_stdout(p) {
            return Ok(());
        }
    }
    // With the CSV on stdout, the report goes to stderr; its warnings went
    // to stderr above.
    report.warnings.clear();
    report_line(is_stdout(&a.out), report.to_string().trim_end());
    if !is_stdout(&a.out) {
        println!("wrote {}", a.out.display());
    }
    Ok(())
}
