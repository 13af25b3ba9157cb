//! A drive's source digest: a hash of the files it was read from, so the
//! same recorded data is known however it was imported.
//!
//! A drive's [fingerprint](odocal::Drive::fingerprint) hashes its samples
//! as imported. The same manifest imported whole (`odocal calibrate`) and
//! as a stream (`odocal follow`) can give different samples: with
//! `clock_offset = "auto"` the whole import estimates the clock offset on
//! the whole drive and the stream on its first 300 s. The source digest
//! hashes the data files themselves, so the history knows the two as one
//! drive: the same files, over overlapping times ([`same_data`]).

use std::io::Read;
use std::path::{Path, PathBuf};

use odocal::{Error, Manifest, Result};
use sha2::{Digest, Sha256};

use crate::pooled::drives_of;
use crate::{CalibrationRecord, DecisionRow};

/// What the hash starts with: the digest's name and version.
const DOMAIN: &[u8] = b"odocal source digest v1\0";

/// The source digest of the drive at `path` (a drive CSV, or a manifest):
/// the SHA-256 (lowercase hex) of the SHA-256s of the files the drive is
/// read from, sorted: the CSV itself, or every stream file the manifest
/// names ([`Manifest::stream_files`]; a bag folder's files one by one).
/// The manifest's own text is not part of it: a comment or a setting
/// changed, the data are the same. Each file is read in pieces (memory
/// flat in its size).
///
/// # Errors
/// The manifest's ([`Manifest::from_path`]); a file that cannot be read
/// ([`Error::Io`], naming it).
pub fn source_digest(path: &Path) -> Result<String> {
    let files: Vec<PathBuf> = if odocal::is_manifest_path(path) {
        Manifest::from_path(path)?.stream_files().into_iter().map(|(_, f)| f).collect()
    } else {
        vec![path.to_path_buf()]
    };
    let mut hashes = files.iter().map(|f| file_hash(f)).collect::<Result<Vec<_>>>()?;
    hashes.sort_unstable();
    hashes.dedup();
    let mut h = Sha256::new();
    h.update(DOMAIN);
    for f in &hashes {
        h.update(f);
    }
    Ok(hex(&h.finalize()))
}

/// The [`source_digest`]s of a calibration's drive files, comma separated
/// in their order (as a record's `fingerprint` names its drives): `None`
/// when no file is given or one cannot be read (a drive read from
/// standard input or made from arrays).
pub fn source_digests<P: AsRef<Path>>(paths: &[P]) -> Option<String> {
    if paths.is_empty() {
        return None;
    }
    let digests: Option<Vec<String>> = paths.iter().map(|p| source_digest(p.as_ref()).ok()).collect();
    digests.map(|d| d.join(","))
}

/// The SHA-256 of the file at `path`, read in pieces.
fn file_hash(path: &Path) -> Result<[u8; 32]> {
    let io = |source| Error::Io { path: path.to_path_buf(), source };
    let mut file = std::fs::File::open(path).map_err(io)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        match file.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => h.update(&buf[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io(e)),
        }
    }
    Ok(h.finalize().into())
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// The recorded data a row or a decision holds: per drive, its source
/// digest and the time it spans (s, on its own clock; `None` where not
/// known: a joint calibration records one span for all its drives).
pub(crate) type Held<'a> = Vec<(&'a str, Option<(f64, f64)>)>;

/// The data a calibration row holds (none when its digests are not known).
pub(crate) fn held_by_record(rec: &CalibrationRecord) -> Held<'_> {
    let digests: Vec<&str> = rec.source_digest.as_deref().map(|d| drives_of(d).collect()).unwrap_or_default();
    let span = (digests.len() == 1).then_some((rec.t_start_s, rec.t_end_s));
    digests.into_iter().map(|d| (d, span)).collect()
}

/// The data a logged decision's drive holds (none when not known).
pub(crate) fn held_by_decision(d: &DecisionRow) -> Held<'_> {
    let span = d.t_start_s.map(|t| (t, t + d.drive_time_s));
    d.source_digest.as_deref().map(|digest| vec![(digest, span)]).unwrap_or_default()
}

/// True when `a` and `b` hold some of the same recorded data: a drive of
/// each read from the same files (equal source digests) over overlapping
/// times (their spans share more than an instant; a span not known
/// overlaps every other). Two windows of one log that do not overlap are
/// two drives.
pub(crate) fn same_data(a: &Held<'_>, b: &Held<'_>) -> bool {
    let overlap = |x: Option<(f64, f64)>, y: Option<(f64, f64)>| match (x, y) {
        (Some(x), Some(y)) => x.0.max(y.0) < x.1.min(y.1),
        _ => true,
    };
    a.iter().any(|(da, sa)| b.iter().any(|(db, sb)| !da.is_empty() && da == db && overlap(*sa, *sb)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{follow, FollowEvent, FollowOptions, History, Recorded};
    use odocal::Theta;

    fn record(fingerprint: &str, digest: &str, span: (f64, f64)) -> CalibrationRecord {
        CalibrationRecord {
            source_digest: Some(digest.into()),
            t_start_s: span.0,
            t_end_s: span.1,
            sigma: Theta { c_e: 1e-3, c_d: 1e-4, t_r: 1e-3, d: 1e-4 }.into(),
            verdict: Some("accepted".into()),
            ..CalibrationRecord::new("van", fingerprint, "eiv", odocal::sim::SimOptions::default().theta_true)
        }
    }

    /// A manifest's digest is of its stream files: a comment added to the
    /// manifest keeps it, one byte of a data file changed changes it, and
    /// it is not the digest of a file alone.
    #[test]
    fn a_manifests_digest_is_of_its_data_files_not_its_text() {
        let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../odocal/tests/data/comma2k19-rav4");
        let dir = tempfile::tempdir().expect("tempdir");
        for f in ["manifest.toml", "wheel_speeds.csv", "pose_camera_enu.csv", "imu_accel.csv", "pose_origin.txt"] {
            std::fs::copy(shipped.join(f), dir.path().join(f)).expect("copy");
        }
        let manifest = dir.path().join("manifest.toml");
        let before = source_digest(&manifest).expect("digest");
        assert_eq!(before.len(), 64);
        let text = std::fs::read_to_string(&manifest).expect("read");
        std::fs::write(&manifest, format!("# a comment\n{text}")).expect("write");
        assert_eq!(source_digest(&manifest).expect("digest"), before);
        let wheels = dir.path().join("wheel_speeds.csv");
        assert_ne!(source_digest(&wheels).expect("digest"), before);
        let mut bytes = std::fs::read(&wheels).expect("read");
        let last = bytes.len() - 2;
        bytes[last] = if bytes[last] == b'1' { b'2' } else { b'1' };
        std::fs::write(&wheels, bytes).expect("write");
        assert_ne!(source_digest(&manifest).expect("digest"), before);
        let e = source_digest(&dir.path().join("missing.csv")).expect_err("no file");
        assert!(e.to_string().contains("missing.csv"), "{e}");
    }

    /// Rows of the same files over overlapping times are one drive, counted
    /// once; over disjoint times (two windows of one log) they are two.
    #[test]
    fn rows_of_the_same_files_over_the_same_time_count_once() {
        let dir = tempfile::tempdir().expect("tempdir");
        let mut db = History::open(dir.path().join("h.sqlite")).expect("open");
        let digest = "d".repeat(64);
        db.record(&record("a", &digest, (0.0, 600.0))).expect("a");
        db.record(&record("b", &digest, (4.8, 590.0))).expect("b");
        db.record(&record("c", &digest, (600.0, 900.0))).expect("c");
        db.record(&record("e", &"e".repeat(64), (0.0, 600.0))).expect("e");
        let h = db.vehicle("van", None).expect("history");
        let aside: Vec<(i64, i64)> = h.set_aside.iter().map(|s| (s.id, s.by_id)).collect();
        assert_eq!(aside, [(1, 2)], "{h}");
        assert!(!same_data(&vec![("", None)], &vec![("", None)]), "an empty digest matches nothing");
    }

    /// `follow` skips a drive whose files and time a calibration row or a
    /// logged decision holds, though its fingerprint differs (the same
    /// manifest imported whole with another clock offset), and follows
    /// the same files over another time.
    #[test]
    fn follow_skips_the_same_files_over_the_same_time_imported_another_way() {
        let dir = tempfile::tempdir().expect("tempdir");
        let csv = dir.path().join("a.csv");
        let sim = odocal::sim::SimOptions {
            length_km: 1.0,
            noise: "off".parse().expect("the off preset"),
            ..odocal::sim::SimOptions::paper(3)
        };
        odocal::sim::simulate(&sim).expect("sim").drive.write_csv(&csv).expect("csv");
        let digest = source_digest(&csv).expect("digest");
        let other = "f".repeat(64);
        let run = |db: &mut History| {
            let mut events = Vec::new();
            follow(db, "van", std::slice::from_ref(&csv), &FollowOptions::default(), |e| {
                events.push(e);
                Ok::<(), Error>(())
            })
            .expect("follow");
            events
        };
        let mut db = History::open(dir.path().join("a.sqlite")).expect("open");
        let Recorded::New(id) = db.record(&record(&other, &digest, (1.0, 30.0))).expect("row") else {
            panic!("new row")
        };
        let events = run(&mut db);
        assert!(matches!(&events[..], [FollowEvent::Skipped { row: Some((r, _)), .. }] if *r == id), "{events:?}");
        // The same files, a window of the log after the drive: followed,
        // and the decision logged with the digest and the drive's start.
        let mut db = History::open(dir.path().join("b.sqlite")).expect("open");
        db.record(&record(&other, &digest, (1e6, 1e6 + 60.0))).expect("row");
        let events = run(&mut db);
        assert!(events.iter().any(|e| matches!(e, FollowEvent::Followed { .. })), "{events:?}");
        let decisions = db.decisions("van").expect("decisions");
        assert_eq!(decisions[0].source_digest.as_deref(), Some(digest.as_str()));
        assert!(decisions[0].t_start_s.is_some());
        // A decision logged for the same files over the same time, under
        // another fingerprint: skipped, as followed before.
        let mut db = History::open(dir.path().join("c.sqlite")).expect("open");
        let mut d = decisions[0].clone();
        d.fingerprint = other;
        db.record_followed(&d, None).expect("decision");
        let events = run(&mut db);
        assert!(matches!(&events[..], [FollowEvent::Skipped { row: None, .. }]), "{events:?}");
    }
}
