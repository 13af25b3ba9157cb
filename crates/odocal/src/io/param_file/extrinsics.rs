//! What a parameter file says of the pose reference's extrinsics: which
//! the calibration estimated, the ones to validate its θ with on a drive,
//! and the heading offset it fitted for each drive it ran on.

use super::ParamFile;
use crate::model::extrinsics::Extrinsics;
use crate::model::param::{Param, ParamSet};

impl ParamFile {
    /// The reference extrinsics the file holds (0 for those it lacks) and
    /// which of them carry a σ, i.e. were estimated by the calibration that
    /// wrote it.
    pub(crate) fn extrinsics(&self) -> (Extrinsics, ParamSet) {
        let mut v = [0.0; 3];
        let mut estimated = ParamSet::EMPTY;
        for (i, p) in Param::EXTRINSICS.into_iter().enumerate() {
            if let Some(e) = self.params.iter().find(|e| e.name == p.name()) {
                v[i] = e.value;
                if e.sigma.is_some() {
                    estimated.insert(p);
                }
            }
        }
        (Extrinsics::from_array(v), estimated)
    }

    /// True when the calibration estimated the reference's heading offset
    /// (it has a σ): validation then re-estimates each drive's own
    /// ([`crate::ValidateOptions::set_extrinsics`]) unless told to carry it.
    pub(crate) fn estimated_heading_offset(&self) -> bool {
        self.extrinsics().1.contains(Param::HeadingOffset)
    }

    /// The heading offset this file's calibration estimated for each drive
    /// it ran on, rad, by the drive's [`Drive::fingerprint`](crate::Drive::fingerprint):
    /// the provenance's `fingerprint` lists them (comma separated, in the
    /// calibration's order, as `odocal calibrate` and the Python package
    /// write it); one drive's offset is the file's `heading_offset`,
    /// several drives' are each their own from `heading_offset_per_drive`
    /// (`drive K: δ ± σ rad; ...`). Empty when the calibration did not
    /// estimate the offset, the file names no fingerprint, or the two
    /// lists do not pair up (an entry that cannot be read, or a value
    /// beyond ±π rad, pairs with nothing).
    pub(crate) fn drive_heading_offsets(&self) -> Vec<(String, f64)> {
        let (x, estimated) = self.extrinsics();
        let provenance = |key: &str| self.provenance.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str());
        let Some(prints) = provenance("fingerprint").filter(|_| estimated.contains(Param::HeadingOffset)) else {
            return Vec::new();
        };
        let prints: Vec<&str> = prints.split(',').map(str::trim).filter(|p| !p.is_empty()).collect();
        let values = match provenance("heading_offset_per_drive") {
            None => vec![Some(x.heading_offset)],
            Some(per) => {
                let mut values = vec![None; prints.len()];
                for entry in per.split(';') {
                    let parsed =
                        entry.trim().strip_prefix("drive ").and_then(|e| e.split_once(':')).and_then(|(k, v)| {
                            let value = v.split('±').next()?.trim().parse::<f64>().ok()?;
                            Some((k.trim().parse::<usize>().ok()?, value))
                        });
                    match parsed {
                        // Within ±π, as the file's own heading offset must be.
                        Some((k, v)) if (1..=values.len()).contains(&k) && v.abs() <= std::f64::consts::PI => {
                            values[k - 1] = Some(v)
                        }
                        _ => return Vec::new(),
                    }
                }
                values
            }
        };
        if values.len() != prints.len() {
            return Vec::new();
        }
        let Some(values) = values.into_iter().collect::<Option<Vec<f64>>>() else { return Vec::new() };
        prints.into_iter().map(String::from).zip(values).collect()
    }

    /// The reference extrinsics to validate this file's θ with on a drive,
    /// by the rules of docs/guide.md, "Several drives of one vehicle": one the calibration estimated
    /// (it has a σ) is the sensor's, so it holds for every drive of the
    /// vehicle; a held one gives way to what the drive's own manifest states
    /// (`drive_reference`, its `[reference]`), else the file's value. Also
    /// returns the names of those taken from the file.
    pub(crate) fn extrinsics_for_drive(&self, drive_reference: Option<&Extrinsics>) -> (Extrinsics, Vec<&'static str>) {
        let (file, estimated) = self.extrinsics();
        let (file, mut v) = (file.to_array(), drive_reference.copied().unwrap_or(Extrinsics::ZERO).to_array());
        let mut from_file = Vec::new();
        for (i, p) in Param::EXTRINSICS.into_iter().enumerate() {
            if estimated.contains(p) || drive_reference.is_none() {
                v[i] = file[i];
                from_file.push(p.name());
            }
        }
        (Extrinsics::from_array(v), from_file)
    }
}
