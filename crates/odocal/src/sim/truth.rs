//! A simulator sidecar bound to its drive: the truth beside a drive CSV
//! counts only when the sidecar records that drive's fingerprint.

use std::path::{Path, PathBuf};

use super::{sidecar_path, SimSidecar};
use crate::drive::Drive;

/// The simulator sidecar file beside `drive_csv` ([`sidecar_path`]), when
/// one lies there (bound to the drive or not).
pub fn sidecar_file(drive_csv: &Path) -> Option<PathBuf> {
    let p = sidecar_path(drive_csv);
    SimSidecar::read_json(&p).is_ok().then_some(p)
}

/// The simulator sidecar beside `drive_csv`, checked against `drive` (read
/// from that file): `(sidecar, note)`. The sidecar counts when it records
/// the drive's [`Drive::fingerprint`]; a sidecar that records another
/// drive or none is ignored, with a note for the user saying so; both are
/// `None` when there is no sidecar.
pub fn sidecar_for(drive_csv: &Path, drive: &Drive) -> (Option<SimSidecar>, Option<String>) {
    let path = sidecar_path(drive_csv);
    if path == drive_csv {
        return (None, None);
    }
    let Ok(sidecar) = SimSidecar::read_json(&path) else { return (None, None) };
    let reason = match &sidecar.drive_fingerprint {
        Some(fp) if *fp == drive.fingerprint() => return (Some(sidecar), None),
        Some(_) => {
            format!("it is the simulator sidecar of another drive: the samples of {} differ", drive_csv.display())
        }
        None => {
            "it records no drive fingerprint, so it cannot be matched to the drive; simulate again to get one".into()
        }
    };
    let note = format!("{} is not the truth of this drive ({reason}); it is ignored", path.display());
    (None, Some(note))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{simulate, SimOptions};

    #[test]
    fn a_sidecar_counts_only_beside_its_own_drive() {
        let dir = tempfile::tempdir().expect("tmp");
        let o = |seed| SimOptions { length_km: 0.3, ..SimOptions::paper(seed) };
        let (a, b) = (simulate(&o(1)).expect("sim"), simulate(&o(2)).expect("sim"));
        let csv = dir.path().join("drive.csv");
        a.drive.write_csv(&csv).expect("csv");
        assert_eq!(sidecar_for(&csv, &a.drive), (None, None));
        a.sidecar.write_json(&sidecar_path(&csv)).expect("json");
        let read = Drive::read_csv(&csv).expect("read").0;
        assert_eq!(sidecar_for(&csv, &read), (Some(a.sidecar.clone()), None));
        assert_eq!(sidecar_file(&csv), Some(sidecar_path(&csv)));
        // Another drive written over the CSV: the sidecar is not its truth.
        b.drive.write_csv(&csv).expect("csv");
        let other = sidecar_for(&csv, &Drive::read_csv(&csv).expect("read").0);
        assert!(other.0.is_none() && other.1.as_ref().is_some_and(|n| n.contains("another drive")), "{other:?}");
        // A sidecar without a fingerprint is not bound either.
        let mut old = a.sidecar.clone();
        old.drive_fingerprint = None;
        old.write_json(&sidecar_path(&csv)).expect("json");
        let m = sidecar_for(&csv, &read);
        assert!(m.0.is_none() && m.1.as_ref().is_some_and(|n| n.contains("no drive fingerprint")), "{m:?}");
        // A JSON file that is not a sidecar is no sidecar.
        std::fs::write(sidecar_path(&csv), "{\"method\": \"eiv\"}\n").expect("write");
        assert_eq!(sidecar_for(&csv, &read), (None, None));
        assert_eq!(sidecar_file(&csv), None);
    }
}
