//! Reading drives and writing reports: what every subcommand shares.

use std::path::Path;

use anyhow::Result;
use odocal::settings::ManifestSettings;
use odocal::sim::{self, SimSidecar};
use odocal::{Drive, Warning};

/// What the importer warned about for every manifest this command read
/// (`path: warning`), for the JSON report's `import_warnings` (the command
/// reads its drives before it writes its one report).
static IMPORT_WARNINGS: std::sync::Mutex<Vec<String>> = std::sync::Mutex::new(Vec::new());

/// Reads a drive: a canonical CSV, or a `.toml` manifest of a multi-stream log
/// (its import summary goes to stderr). Also returns how to read c_e when
/// the drive came from a manifest (e.g. "c_e is metres per 40360 ticks")
/// and the manifest's calibration settings (`[noise]`, `[reference]`).
pub fn load_drive_with_scale(path: &Path) -> Result<(Drive, Option<String>, Option<ManifestSettings>)> {
    if odocal::output::is_stdout(path) {
        anyhow::bail!(
            "-: a drive is read from a file, not from stdin (its checks, fingerprint and simulator sidecar need \
             one): save it first (`… > drive.csv`) and give that path"
        );
    }
    let (drive, report) = if odocal::is_manifest_path(path) {
        odocal::load_drive(path)?
    } else {
        let (drive, warnings) = Drive::read_csv(path)?;
        for w in warnings {
            eprintln!("warning: {w}");
        }
        (drive, None)
    };
    let settings = report.as_ref().map(ManifestSettings::try_from).transpose()?;
    if let Some(r) = &report {
        eprintln!(
            "imported {}: {} samples in {} part(s), {:.2} km (run `odocal import` for the full import report)",
            path.display(),
            drive.len(),
            drive.parts().len(),
            drive.distance_m() / 1e3
        );
        // What the import warned about (a clock offset not applied, a yaw-rate
        // ratio far from 1) bears on the result: shown as `import` shows it.
        for w in &r.warnings {
            eprintln!("warning: {}: {w}", path.display());
        }
        if let Ok(mut all) = IMPORT_WARNINGS.lock() {
            all.extend(r.warnings.iter().map(|w| format!("{}: {w}", path.display())));
        }
    }
    Ok((drive, report.map(|r| r.wheel_scale), settings))
}

/// An error about "drive" (the library's name for the drive it was given,
/// e.g. a failed convention check), or that it has no usable segments,
/// named by the file the drive was read from.
pub fn name_drive(e: odocal::Error, path: &Path) -> odocal::Error {
    match e {
        odocal::Error::InvalidDrive { context, reason } if context == "drive" => {
            odocal::Error::InvalidDrive { context: path.display().to_string(), reason }
        }
        odocal::Error::NoSegments(why) => odocal::Error::InvalidDrive {
            context: path.display().to_string(),
            reason: format!("no usable segments: {why}"),
        },
        e => e,
    }
}

/// The simulator's sidecar beside a drive, when there is one and it
/// records this drive's fingerprint; a sidecar of another drive is ignored
/// with a note on stderr.
pub fn load_truth(drive_path: &Path, drive: &Drive) -> Option<SimSidecar> {
    let (sidecar, note) = sim::SimSidecar::for_drive(drive_path, drive);
    if let Some(note) = note {
        eprintln!("note: {note}");
    }
    sidecar
}

/// The true θ and the reference's true extrinsics of a simulated drive, as
/// the measured signals show them: the mount, plus the reference's
/// constant heading bias and the sideslip's constant bias, which act on
/// the data exactly as a heading offset of the mount does (so the truth's
/// Ē_p is the truth's best, as a calibration's is with its own δ).
pub fn truth_of(s: &SimSidecar) -> (odocal::Theta, odocal::Extrinsics) {
    let (mut mount, noise) = (s.settings.reference_mount, &s.settings.noise);
    mount.heading_offset += noise.heading_bias_rad + noise.sideslip_bias_rad;
    (s.theta_true, mount)
}

/// Writes a JSON report ([`json_text`]) to `path` ("-": stdout), atomically.
pub fn write_json(path: &Path, value: serde_json::Value) -> Result<()> {
    crate::output::write_text(path, &json_text(value)?)
}

/// A JSON report's text, with its `schema_version` and, when a manifest
/// read for it warned, its `import_warnings`.
pub fn json_text(mut value: serde_json::Value) -> Result<String> {
    if let Some(obj) = value.as_object_mut() {
        obj.insert("schema_version".into(), odocal::REPORT_SCHEMA_VERSION.into());
        let imported = import_warnings();
        if !imported.is_empty() {
            obj.insert("import_warnings".into(), imported.into());
        }
    }
    Ok(serde_json::to_string_pretty(&value)?)
}

/// What the importer warned about for every manifest this command read so
/// far (`path: warning`): the JSON report's `import_warnings`, listed in the
/// HTML report before the calibration's warnings.
pub fn import_warnings() -> Vec<String> {
    IMPORT_WARNINGS.lock().map(|w| w.clone()).unwrap_or_default()
}

/// A drive's entry in a JSON report: its role (`calibration`,
/// `validation`), its path and its fingerprint.
pub fn drive_entry(role: &str, path: &str, fingerprint: &str) -> serde_json::Value {
    serde_json::json!({"role": role, "path": path, "fingerprint": fingerprint})
}

/// Warnings to stderr, grouped by kind: at most [`WARNINGS_PER_KIND`] of
/// each and a count of the rest (the JSON report lists all). Those that
/// inform rather than warn ([`Warning::is_note`]) print as `note:`.
pub fn print_warnings(warnings: &[Warning]) {
    let (notes, warnings): (Vec<Warning>, Vec<Warning>) = warnings.iter().cloned().partition(Warning::is_note);
    let mut collapsed = false;
    for (prefix, list) in [("note", &notes), ("warning", &warnings)] {
        for l in odocal::Warning::summarize(list, WARNINGS_PER_KIND) {
            collapsed |= l.starts_with('…');
            eprintln!("{prefix}: {l}");
        }
    }
    if collapsed {
        eprintln!("warning: (the --json report lists every warning)");
    }
}

/// Warnings of one kind printed before the rest are counted.
const WARNINGS_PER_KIND: usize = 3;
