//! The bad-input harness shared by the fuzz targets (`fuzz/`, cargo-fuzz on
//! nightly) and the stable replay and mutation tests
//! (`tests/integration/bad_input.rs`): each function feeds one input to a reader and
//! checks what must hold for *any* input — no panic (a panic fails the
//! caller), an error message of bounded length that is one line, and a
//! drive that is finite and consistent when the input is accepted.

#![allow(dead_code)]

use std::path::Path;

use odocal::settings::ManifestSettings;
use odocal::Drive;
use odocal::{import, Manifest};

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
    assert!(d.len() > 0);
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

/// The canonical CSV reader, of the input written to a file.
pub fn csv_drive(data: &[u8]) -> Outcome {
    let dir = tempfile::tempdir().expect("a temporary folder");
    let path = dir.path().join("fuzz.csv");
    std::fs::write(&path, data).expect("write the input");
    match Drive::read_csv(&path) {
        Ok((d, _)) => check_drive(&d),
        Err(e) => check_message(e.to_string()),
    }
}

/// The manifest parser and its checks, with the calibration settings the
/// manifest states (its `[noise]` read as a noise model).
pub fn manifest(data: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(data) else { return Outcome::Error("not UTF-8".into()) };
    match Manifest::parse(text, Path::new("fuzz.toml")).and_then(|m| ManifestSettings::try_from(&m)) {
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
    match odocal::load_drive(&path) {
        Ok((d, _)) => check_drive(&d),
        Err(e) => check_message(e.to_string()),
    }
}

/// A ROS 2 bag (MCAP): the bytes written to a temporary `.mcap` file, then
/// `inspect` and every topic read with all its columns (header stamps, and
/// the log time), as `odocal inspect` and a `format = "mcap"` stream do.
#[cfg(feature = "mcap")]
pub fn bag(data: &[u8]) -> Outcome {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("fuzz.mcap");
    std::fs::write(&path, data).expect("write");
    let info = match odocal::io::bag::inspect(&path) {
        Ok(info) => info,
        Err(e) => return check_message(e.to_string()),
    };
    let _ = check_message(info.to_string());
    let mut last = Outcome::Parsed;
    for t in &info.topics {
        for time in [odocal::io::bag::TimeSource::HeaderStamp, odocal::io::bag::TimeSource::LogTime] {
            last = match odocal::io::bag::read_topic(&path, &t.topic, &[], time) {
                Ok(table) => {
                    assert!(table.columns.values().all(|c| c.len() == table.t_s.len()));
                    assert!(table.t_s.windows(2).all(|w| w[0] <= w[1]));
                    Outcome::Drive(table.t_s.len())
                }
                Err(e) => check_message(e.to_string()),
            };
        }
    }
    let _ = info.manifest_columns();
    last
}

/// A parameter file (`--theta`, `--params-out`'s YAML or JSON): the bytes
/// written to a temporary `.yaml` file (`.json` when they start with `{`)
/// and read as `--theta` reads it.
pub fn params(data: &[u8]) -> Outcome {
    let dir = tempfile::tempdir().expect("tempdir");
    let name = if data.first() == Some(&b'{') { "fuzz.json" } else { "fuzz.yaml" };
    let path = dir.path().join(name);
    std::fs::write(&path, data).expect("write");
    match odocal::ParamFile::read(&path, None) {
        Ok(f) => match odocal::Theta::try_from(&f) {
            Ok(t) => {
                assert!([t.c_e, t.c_d, t.t_r, t.d].iter().all(|v| v.is_finite()), "{t:?}");
                Outcome::Parsed
            }
            Err(e) => check_message(e.to_string()),
        },
        Err(e) => check_message(e.to_string()),
    }
}

/// Imports a manifest already parsed (used by the fuzz target on bundles).
pub fn import_manifest(m: &Manifest) -> Outcome {
    match import(m) {
        Ok((drive, _)) => check_drive(&drive),
        Err(e) => check_message(e.to_string()),
    }
}

/// One mutation of a text: insert a token, delete bytes, duplicate, drop or
/// swap lines, or overwrite a byte, for each `(op, a, b)`. Lines starting
/// with `=== ` (bundle section markers) are never touched.
pub fn mutate(base: &str, ops: &[(u8, usize, usize)], tokens: &[&str]) -> Vec<u8> {
    let mut lines: Vec<Vec<u8>> = base.split('\n').map(|l| l.as_bytes().to_vec()).collect();
    for &(op, a, b) in ops {
        let n = lines.len();
        let (i, j) = (a % n, b % n);
        if lines[i].starts_with(b"=== ") {
            continue;
        }
        match op % 6 {
            0 => {
                let t = tokens[b % tokens.len()].as_bytes();
                let l = &mut lines[i];
                let at = b % (l.len() + 1);
                l.splice(at..at, t.iter().copied());
            }
            1 => {
                let l = &mut lines[i];
                if !l.is_empty() {
                    let at = b % l.len();
                    l.drain(at..(at + 1 + b % 7).min(l.len()));
                }
            }
            2 => {
                let l = lines[i].clone();
                lines.insert(j.max(1), l);
            }
            3 => {
                if n > 1 {
                    lines.remove(i);
                }
            }
            4 => {
                if !lines[j].starts_with(b"=== ") {
                    lines.swap(i, j);
                }
            }
            _ => {
                let l = &mut lines[i];
                if !l.is_empty() {
                    let at = b % l.len();
                    l[at] = (b % 256) as u8;
                }
            }
        }
    }
    lines.join(&b'\n')
}

/// Replays corpus `files` (sorted by name) through `reader` and checks each
/// against `expect` (file name, substrings of the one-line error; no
/// substrings: the input must be accepted as a drive).
pub fn replay(files: &[std::path::PathBuf], expect: &[(&str, &[&str])], reader: fn(&[u8]) -> Outcome) {
    assert_eq!(files.len(), expect.len(), "every corpus file has an expectation");
    for (path, (name, needles)) in files.iter().zip(expect) {
        assert_eq!(path.file_name().and_then(|n| n.to_str()), Some(*name));
        let o = reader(&std::fs::read(path).expect("read"));
        if needles.is_empty() {
            assert!(matches!(o, Outcome::Drive(_) | Outcome::Parsed), "{name}: {o:?}");
            continue;
        }
        let Outcome::Error(m) = &o else { panic!("{name}: expected an error, got {o:?}") };
        assert_eq!(m.lines().count(), 1, "{name}: one line: {m}");
        for n in *needles {
            assert!(m.contains(n), "{name}: expected '{n}' in: {m}");
        }
    }
}
