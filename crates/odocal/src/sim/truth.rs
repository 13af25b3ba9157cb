//! A simulator sidecar bound to its drive: the truth beside a drive CSV
//! counts only when the sidecar records that drive's fingerprint.

use std::path::{Path, PathBuf};

use super::SimSidecar;
use crate::drive::Drive;
use crate::Result;

impl SimSidecar {
    /// The sidecar path of a drive CSV: `drive.csv` → `drive.json`. The
    /// one rule by which sidecars are written and found.
    pub fn path_beside(drive_csv: &Path) -> PathBuf {
        drive_csv.with_extension("json")
    }

    /// The simulator sidecar file beside `drive_csv`
    /// ([`SimSidecar::path_beside`]), when one lies there (bound to the
    /// drive or not).
    pub fn file_beside(drive_csv: &Path) -> Option<PathBuf> {
        let p = Self::path_beside(drive_csv);
        Self::read_json(&p).is_ok().then_some(p)
    }

    /// Writes the sidecar as pretty JSON beside `drive_csv`
    /// ([`SimSidecar::path_beside`]), atomically
    /// ([`crate::output::write_text`]).
    pub fn write_beside(&self, drive_csv: impl AsRef<Path>) -> Result<()> {
        self.write_json(&Self::path_beside(drive_csv.as_ref()))
    }

    /// The simulator sidecar beside `drive_csv`, checked against `drive`
    /// (read from that file): `(sidecar, note)`. The sidecar counts when it
    /// records the drive's [`Drive::fingerprint`]; a sidecar that records
    /// another drive or none is ignored, with a note for the user saying
    /// so; both are `None` when there is no sidecar.
    pub fn for_drive(drive_csv: &Path, drive: &Drive) -> (Option<Self>, Option<String>) {
        let path = Self::path_beside(drive_csv);
        if path == drive_csv {
            return (None, None);
        }
        let Ok(sidecar) = Self::read_json(&path) else { return (None, None) };
        let reason = match &sidecar.drive_fingerprint {
            Some(fp) if *fp == drive.fingerprint() => return (Some(sidecar), None),
            Some(_) => {
                format!("it is the simulator sidecar of another drive: the samples of {} differ", drive_csv.display())
            }
            None => "it records no drive fingerprint, so it cannot be matched to the drive; simulate again to get one"
                .into(),
        };
        let note = format!("{} is not the truth of this drive ({reason}); it is ignored", path.display());
        (None, Some(note))
    }
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
        assert_eq!(SimSidecar::for_drive(&csv, &a.drive), (None, None));
        a.sidecar.write_beside(&csv).expect("json");
        let read = Drive::read_csv(&csv).expect("read").0;
        assert_eq!(SimSidecar::for_drive(&csv, &read), (Some(a.sidecar.clone()), None));
        assert_eq!(SimSidecar::file_beside(&csv), Some(SimSidecar::path_beside(&csv)));
        // Another drive written over the CSV: the sidecar is not its truth.
        b.drive.write_csv(&csv).expect("csv");
        let other = SimSidecar::for_drive(&csv, &Drive::read_csv(&csv).expect("read").0);
        assert!(other.0.is_none() && other.1.as_ref().is_some_and(|n| n.contains("another drive")), "{other:?}");
        // A sidecar without a fingerprint is not bound either.
        let mut old = a.sidecar.clone();
        old.drive_fingerprint = None;
        old.write_beside(&csv).expect("json");
        let m = SimSidecar::for_drive(&csv, &read);
        assert!(m.0.is_none() && m.1.as_ref().is_some_and(|n| n.contains("no drive fingerprint")), "{m:?}");
        // A JSON file that is not a sidecar is no sidecar.
        std::fs::write(SimSidecar::path_beside(&csv), "{\"method\": \"eiv\"}\n").expect("write");
        assert_eq!(SimSidecar::for_drive(&csv, &read), (None, None));
        assert_eq!(SimSidecar::file_beside(&csv), None);
    }
}
