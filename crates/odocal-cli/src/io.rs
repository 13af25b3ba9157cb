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
    if crate::output::is_stdout(path) {
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
        for l in summarize(list, WARNINGS_PER_KIND) {
            collapsed |= l.starts_with('…');
            eprintln!("{prefix}: {l}");
        }
    }
    if collapsed {
        eprintln!("warning: (the --json report lists every warning)");
    }
}

/// The kind of a warning: its JSON `"kind"`.
fn kind(w: &Warning) -> String {
    serde_json::to_value(w).ok().and_then(|v| v["kind"].as_str().map(String::from)).unwrap_or_default()
}

/// Lines for a human reader: warnings grouped by kind (in order of first
/// appearance), at most `per_kind` of each, then `"… and N more <kind>
/// warnings"` for the rest.
pub fn summarize(warnings: &[Warning], per_kind: usize) -> Vec<String> {
    let kinds: Vec<String> = warnings.iter().map(kind).collect();
    let mut order: Vec<&str> = Vec::new();
    for k in &kinds {
        if !order.contains(&k.as_str()) {
            order.push(k);
        }
    }
    let mut out = Vec::new();
    for k in order {
        let of_kind: Vec<&Warning> = warnings.iter().zip(&kinds).filter(|(_, wk)| *wk == k).map(|(w, _)| w).collect();
        out.extend(of_kind.iter().take(per_kind).map(|w| w.to_string()));
        if of_kind.len() > per_kind {
            out.push(format!("… and {} more {} warnings", of_kind.len() - per_kind, k.replace('_', " ")));
        }
    }
    out
}

/// Warnings of one kind printed before the rest are counted.
const WARNINGS_PER_KIND: usize = 3;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repeated_warnings_collapse_to_a_count() {
        let mut w: Vec<Warning> = (0..500)
            .map(|i| Warning::CompensationFailed { segment_start: i * 100, reason: format!("job {i}") })
            .collect();
        w.insert(1, Warning::BatchFailed { batch: 3, reason: "singular".into() });
        let lines = summarize(&w, 3);
        assert_eq!(lines.len(), 5, "{lines:?}");
        assert_eq!(lines[0], "compensation left out: job 0");
        assert_eq!(lines[3], "… and 497 more compensation failed warnings");
        assert_eq!(lines[4], "initial batch 3 left out: singular");
    }
}
