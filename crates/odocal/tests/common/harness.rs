//! The bad-input harness shared by the fuzz targets (`fuzz/`, cargo-fuzz on
//! nightly) and the stable replay and mutation tests
//! (`tests/bad_input.rs`): each function feeds one input to a reader and
//! checks what must hold for *any* input — no panic (a panic fails the
//! caller), an error message of bounded length that is one line, and a
//! drive that is finite and consistent when the input is accepted.

#![allow(dead_code)]

use std::path::Path;

use odocal::import::{import, Manifest};
use odocal::Drive;

/// Longest acceptable error message, bytes: echoed fields are truncated.
pub const MAX_MESSAGE_BYTES: usize = 2000;

/// What a reader made of an input.
#[derive(Debug)]
pub enum Outcome {
    /// Accepted: a drive with this many samples.
    Drive(usize),
    /// Accepted (the manifest parser).
    Parsed,
    /// Rejected with this message.
    Error(String),
}

fn check_message(m: String) -> Outcome {
    assert!(m.len() <= MAX_MESSAGE_BYTES, "error message of {} bytes: {}…", m.len(), &m[..200.min(m.len())]);
    assert!(!m.trim().is_empty(), "empty error message");
    Outcome::Error(m)
}

fn check_drive(d: &Drive) -> Outcome {
    assert!(!d.is_empty());
    assert!(d.sample_time_s().is_finite() && d.sample_time_s() > 0.0);
    for (name, c) in d.measured().columns() {
        assert_eq!(c.len(), d.len(), "{name}");
        assert!(c.iter().all(|v| v.is_finite()), "{name} not finite");
    }
    assert!(d.t().windows(2).all(|w| w[1] > w[0]));
    let covered: usize = d.parts().iter().map(|p| p.len()).sum();
    assert_eq!(covered, d.len());
    Outcome::Drive(d.len())
}

/// The canonical CSV reader.
pub fn csv_drive(data: &[u8]) -> Outcome {
    match Drive::parse_csv(data, Path::new("fuzz.csv")) {
        Ok(d) => check_drive(&d),
        Err(e) => check_message(e.to_string()),
    }
}

/// The manifest parser and its checks.
pub fn manifest(data: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(data) else { return Outcome::Error("not UTF-8".into()) };
    match Manifest::parse(text, Path::new("fuzz.toml")) {
        Ok(_) => Outcome::Parsed,
        Err(e) => check_message(e.to_string()),
    }
}

/// A whole import from a bundle: sections `=== NAME` followed by the file's
/// text; the section named `m.toml` is the manifest, the others are the
/// stream files it may name. Written to a temporary folder and imported.
pub fn import_bundle(data: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(data) else { return Outcome::Error("not UTF-8".into()) };
    let dir = tempfile::tempdir().expect("tempdir");
    let mut manifest_path = None;
    for section in text.split("=== ").skip(1) {
        let (name, body) = section.split_once('\n').unwrap_or((section, ""));
        let name = name.trim();
        // Only plain file names inside the folder.
        if name.is_empty()
            || name.len() > 64
            || !name.chars().all(|c| c.is_ascii_alphanumeric() || c == '.' || c == '_')
        {
            continue;
        }
        let path = dir.path().join(name);
        std::fs::write(&path, body).expect("write section");
        if name == "m.toml" {
            manifest_path = Some(path);
        }
    }
    let Some(path) = manifest_path else { return Outcome::Error("no m.toml section".into()) };
    match odocal::import::load_drive(&path) {
        Ok((d, _)) => check_drive(&d),
        Err(e) => check_message(e.to_string()),
    }
}

/// Imports a manifest already parsed (used by the fuzz target on bundles).
pub fn import_manifest(m: &Manifest) -> Outcome {
    match import(m) {
        Ok(imp) => check_drive(&imp.drive),
        Err(e) => check_message(e.to_string()),
    }
}
