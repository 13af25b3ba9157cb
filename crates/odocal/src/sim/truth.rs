//! A simulator sidecar bound to its drive: the truth beside a drive CSV
//! counts only when the sidecar records that drive's fingerprint.

use std::path::{Path, PathBuf};

use super::{sidecar_path, SimSidecar};
use crate::drive::Drive;

/// What lies beside a drive CSV where its simulator sidecar would be
/// ([`sidecar_path`]).
#[derive(Debug, Clone, PartialEq)]
pub enum SidecarMatch {
    /// No sidecar: no file, or one that is not a simulator sidecar.
    None,
    /// The sidecar of this drive: its recorded fingerprint is the drive's.
    Bound(Box<SimSidecar>),
    /// A simulator sidecar of another drive (or one that records no
    /// fingerprint): its truth must not be shown for this drive.
    Other {
        /// The sidecar file.
        path: PathBuf,
        /// Why it does not belong to the drive, in words.
        reason: String,
    },
}

impl SidecarMatch {
    /// The sidecar when it belongs to the drive.
    pub fn bound(self) -> Option<SimSidecar> {
        match self {
            SidecarMatch::Bound(s) => Some(*s),
            _ => None,
        }
    }

    /// A note for the user when a sidecar lies beside the drive but belongs
    /// to another one.
    pub fn note(&self) -> Option<String> {
        match self {
            SidecarMatch::Other { path, reason } => {
                Some(format!("{} is not the truth of this drive ({reason}); it is ignored", path.display()))
            }
            _ => None,
        }
    }

    /// The sidecar file, when one lies beside the drive (bound or not).
    pub fn path(drive_csv: &Path) -> Option<PathBuf> {
        let p = sidecar_path(drive_csv);
        SimSidecar::read_json(&p).is_ok().then_some(p)
    }
}

/// The simulator sidecar beside `drive_csv`, checked against `drive` (read
/// from that file): bound when it records the drive's
/// [`Drive::fingerprint`], [`SidecarMatch::Other`] when it records another
/// one or none, [`SidecarMatch::None`] when there is no sidecar.
pub fn sidecar_for(drive_csv: &Path, drive: &Drive) -> SidecarMatch {
    let path = sidecar_path(drive_csv);
    if path == drive_csv {
        return SidecarMatch::None;
    }
    let Ok(sidecar) = SimSidecar::read_json(&path) else { return SidecarMatch::None };
    match &sidecar.drive_fingerprint {
        Some(fp) if *fp == drive.fingerprint() => SidecarMatch::Bound(Box::new(sidecar)),
        Some(_) => SidecarMatch::Other {
            path,
            reason: format!(
                "it is the simulator sidecar of another drive: the samples of {} differ",
                drive_csv.display()
            ),
        },
        None => SidecarMatch::Other {
            path,
            reason: "it records no drive fingerprint, so it cannot be matched to the drive; simulate again to get \
                     one"
            .into(),
        },
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
        assert_eq!(sidecar_for(&csv, &a.drive), SidecarMatch::None);
        a.sidecar.write_json(&sidecar_path(&csv)).expect("json");
        let read = Drive::read_csv(&csv).expect("read").0;
        assert_eq!(sidecar_for(&csv, &read).bound(), Some(a.sidecar.clone()));
        // Another drive written over the CSV: the sidecar is not its truth.
        b.drive.write_csv(&csv).expect("csv");
        let other = sidecar_for(&csv, &Drive::read_csv(&csv).expect("read").0);
        assert!(other.note().is_some_and(|n| n.contains("another drive")), "{other:?}");
        // A sidecar without a fingerprint is not bound either.
        let mut old = a.sidecar.clone();
        old.drive_fingerprint = None;
        old.write_json(&sidecar_path(&csv)).expect("json");
        let m = sidecar_for(&csv, &read);
        assert!(m.note().is_some_and(|n| n.contains("no drive fingerprint")), "{m:?}");
        // A JSON file that is not a sidecar is no sidecar.
        std::fs::write(sidecar_path(&csv), "{\"method\": \"eiv\"}\n").expect("write");
        assert_eq!(sidecar_for(&csv, &read), SidecarMatch::None);
    }
}
