//! Cross-run checks: calibrate on each of several drives of one vehicle and
//! validate on the others.
//!
//! A calibration that only fits the drive it came from is no calibration.
//! [`cross_run`] calibrates every drive on its own and validates each θ on
//! every other drive ([`odocal::CalibrationReport::validate_on_drives`]),
//! beside θ_0; [`CrossRunTable::criteria`] sums the table up: never worse
//! than θ_0 on another drive, the mean cross-run Ē_p within a ratio of the
//! mean of the drives' own fits, and how many calibrations were rejected.

use serde::{Deserialize, Serialize};

use odocal::{
    Calibration, CalibrationOptions, Drive, DriveValidation, Error, MultiValidation, Progress, Theta, ValidationDrive,
};
use odocal::{Verdict, VerdictLevel};

type Result<T> = std::result::Result<T, Error>;

/// The ratio of the acceptance criterion: the mean over runs of the
/// cross-run Ē_p should stay within this multiple of the mean of the runs'
/// own fits.
pub const CROSS_RUN_OWN_FIT_RATIO: f64 = 1.5;

/// One drive's calibration and its validation on the others.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossRunRow {
    /// The drive calibrated on.
    pub name: String,
    /// The calibration, or why it failed.
    pub fit: std::result::Result<CrossRunFit, String>,
}

/// A drive's calibration and its validation on the other drives.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossRunFit {
    /// The calibrated θ.
    pub theta: Theta,
    /// Its verdict.
    pub verdict: Verdict,
    /// Ē_p of θ on the drive it was fitted on, m.
    pub own_m: f64,
    /// Ē_p of θ_0 on that drive, m.
    pub initial_own_m: f64,
    /// θ and θ_0 on every other drive.
    pub others: MultiValidation,
}

/// Every drive's row, in the order given.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossRunTable {
    /// The rows.
    pub rows: Vec<CrossRunRow>,
}

/// The cross-run criteria, measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrossRunCriteria {
    /// `(calibrated on, validated on, Ē_p of θ, Ē_p of θ_0)` wherever the
    /// calibrated θ is worse than θ_0 on another drive.
    pub worse_than_initial: Vec<(String, String, f64, f64)>,
    /// Mean over rows of the mean cross-run Ē_p, m.
    pub mean_cross_m: f64,
    /// Mean over rows of the own-fit Ē_p, m.
    pub mean_own_m: f64,
    /// Mean over rows of θ_0's mean Ē_p on the same other drives, m.
    pub mean_initial_cross_m: f64,
    /// `mean_cross_m / mean_own_m`.
    pub ratio: f64,
    /// The allowed ratio.
    pub max_ratio: f64,
    /// Calibrations whose verdict is `rejected`.
    pub rejected: usize,
    /// Calibrations that ended in an error (no θ; left out of the means).
    pub failed: usize,
    /// Rows.
    pub runs: usize,
}

impl CrossRunCriteria {
    /// True when every calibration produced a θ, no θ is worse than θ_0
    /// on another drive and the ratio is within `max_ratio` (the rejected
    /// count is for the caller to judge).
    pub fn pass(&self) -> bool {
        self.failed == 0 && self.worse_than_initial.is_empty() && self.ratio <= self.max_ratio
    }
}

impl CrossRunTable {
    /// The criteria with the allowed ratio `max_ratio` (e.g. [`CROSS_RUN_OWN_FIT_RATIO`]).
    pub fn criteria(&self, max_ratio: f64) -> CrossRunCriteria {
        let fits: Vec<(&str, &CrossRunFit)> =
            self.rows.iter().filter_map(|r| r.fit.as_ref().ok().map(|f| (r.name.as_str(), f))).collect();
        let n = fits.len().max(1) as f64;
        let worse_than_initial = fits
            .iter()
            .flat_map(|(name, r)| {
                worse_than_initial(&r.others).map(|d| {
                    (name.to_string(), d.name.clone(), d.mean_position_error_m, d.initial_mean_position_error_m)
                })
            })
            .collect();
        let mean_cross_m = fits.iter().map(|(_, r)| r.others.mean_over_drives_m).sum::<f64>() / n;
        let mean_own_m = fits.iter().map(|(_, r)| r.own_m).sum::<f64>() / n;
        CrossRunCriteria {
            worse_than_initial,
            mean_cross_m,
            mean_own_m,
            mean_initial_cross_m: fits.iter().map(|(_, r)| r.others.initial_mean_over_drives_m).sum::<f64>() / n,
            ratio: mean_cross_m / mean_own_m,
            max_ratio,
            rejected: fits.iter().filter(|(_, r)| r.verdict.level == VerdictLevel::Rejected).count(),
            failed: self.rows.len() - fits.len(),
            runs: self.rows.len(),
        }
    }
}

/// The drives on which θ is worse than θ_0.
fn worse_than_initial(m: &MultiValidation) -> impl Iterator<Item = &DriveValidation> {
    m.drives
        .iter()
        .filter(|d| d.mean_position_error_m.is_nan() || d.mean_position_error_m > d.initial_mean_position_error_m)
}

impl std::fmt::Display for CrossRunTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "| run | c_e (m) | c_d (mm) | t_r (m) | d (mm/(m/s²)) | verdict | own Ē_p (m) | θ_0 own (m) | \
             mean Ē_p on others (m) | θ_0 on others (m) | worst other / θ_0 |"
        )?;
        writeln!(f, "|---|---|---|---|---|---|---|---|---|---|---|")?;
        for row in &self.rows {
            let r = match &row.fit {
                Ok(r) => r,
                Err(e) => {
                    writeln!(f, "| {} | failed: {e} |||||||||||", row.name)?;
                    continue;
                }
            };
            let worst = r
                .others
                .drives
                .iter()
                .map(|d| d.mean_position_error_m / d.initial_mean_position_error_m)
                .fold(f64::NEG_INFINITY, f64::max);
            writeln!(
                f,
                "| {} | {:.4} | {:+.2} | {:.3} | {:+.2} | {} | {:.2} | {:.2} | {:.2} | {:.2} | {:.2} |",
                row.name,
                r.theta.c_e,
                r.theta.c_d * 1e3,
                r.theta.t_r,
                r.theta.d * 1e3,
                r.verdict.level,
                r.own_m,
                r.initial_own_m,
                r.others.mean_over_drives_m,
                r.others.initial_mean_over_drives_m,
                worst
            )?;
        }
        Ok(())
    }
}

impl std::fmt::Display for CrossRunCriteria {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(
            f,
            "mean cross-run Ē_p {:.3} m, mean own-fit Ē_p {:.3} m: ratio {:.2} (allowed {}); θ_0 on the same \
             drives {:.3} m",
            self.mean_cross_m, self.mean_own_m, self.ratio, self.max_ratio, self.mean_initial_cross_m
        )?;
        writeln!(f, "rejected: {} of {}; failed (no θ): {}", self.rejected, self.runs, self.failed)?;
        if self.worse_than_initial.is_empty() {
            write!(f, "never worse than θ_0 on another run")
        } else {
            write!(f, "worse than θ_0:")?;
            for (a, b, e, e0) in &self.worse_than_initial {
                write!(f, " [{a} on {b}: {e:.3} m vs {e0:.3} m]")?;
            }
            Ok(())
        }
    }
}

/// Calibrates each of `drives` with `opts` and validates each θ (and θ_0)
/// on all the other drives.
///
/// A calibration that fails is recorded in its row (the error's text) and
/// left out of the means.
///
/// # Errors
/// Fewer than two drives; a validation's error, naming the drive.
pub fn cross_run(
    drives: &[(&str, &Drive)],
    opts: &CalibrationOptions,
    progress: Option<&(dyn Fn(Progress) + Sync)>,
) -> Result<CrossRunTable> {
    let groups: Vec<Vec<usize>> = (0..drives.len()).map(|i| vec![i]).collect();
    cross_run_groups(drives, &groups, opts, progress)
}

/// Calibrates each group of `drives` jointly (indices into `drives`; the
/// drives of a group are concatenated with [`Drive::concat`], so no
/// segment spans two of them) and validates each θ (and θ_0) on every drive
/// outside the group. A row's name joins its drives' names with `+`; its
/// own Ē_p is the group's validation.
///
/// On the van's test track a group of one counter-clockwise and one
/// clockwise run calibrates where single runs cannot (README, "Cross-run
/// check on the test track").
///
/// A calibration that fails is recorded in its row (the error's text) and
/// left out of the means.
///
/// # Errors
/// Fewer than two drives, an empty group, an index out of range or a group
/// that covers every drive (nothing left to validate on); a validation's
/// error, naming the group.
pub fn cross_run_groups(
    drives: &[(&str, &Drive)],
    groups: &[Vec<usize>],
    opts: &CalibrationOptions,
    progress: Option<&(dyn Fn(Progress) + Sync)>,
) -> Result<CrossRunTable> {
    if drives.len() < 2 {
        return Err(Error::InvalidOption {
            field: "drives",
            reason: format!("a cross-run check needs at least two drives, got {}", drives.len()),
        });
    }
    for g in groups {
        if g.is_empty() || g.iter().any(|&i| i >= drives.len()) || (0..drives.len()).all(|i| g.contains(&i)) {
            return Err(Error::InvalidOption {
                field: "groups",
                reason: format!(
                    "group {g:?}: a group needs at least one of the {} drives and must leave one out",
                    drives.len()
                ),
            });
        }
    }
    let mut rows = Vec::with_capacity(groups.len());
    for g in groups {
        let name = g.iter().map(|&i| drives[i].0).collect::<Vec<_>>().join("+");
        let joint;
        let drive = if let [i] = g.as_slice() {
            drives[*i].1
        } else {
            let members: Vec<&Drive> = g.iter().map(|&i| drives[i].1).collect();
            joint = match Drive::concat(&members) {
                Ok(d) => d,
                Err(e) => {
                    rows.push(CrossRunRow { name, fit: Err(e.to_string()) });
                    continue;
                }
            };
            &joint
        };
        let r = match (Calibration { progress, ..Calibration::new(drive, opts) }).run() {
            Ok(r) => r,
            Err(e) => {
                rows.push(CrossRunRow { name, fit: Err(e.to_string()) });
                continue;
            }
        };
        let others: Vec<ValidationDrive> = drives
            .iter()
            .enumerate()
            .filter(|(j, _)| !g.contains(j))
            .map(|(_, (name, drive))| ValidationDrive { name, drive, reference: None })
            .collect();
        // The calibration's extrinsics (estimated or held) on every other drive.
        let others = r
            .validate_on_drives(&others, false)
            .map_err(|e| Error::Numerical(format!("cross-run, θ of {name}: {e}")))?;
        let fit = CrossRunFit {
            theta: r.theta,
            verdict: r.verdict,
            own_m: r.validation.mean_position_error_m,
            initial_own_m: r.initial.mean_position_error_m,
            others,
        };
        rows.push(CrossRunRow { name, fit: Ok(fit) });
    }
    Ok(CrossRunTable { rows })
}

#[cfg(test)]
mod tests {
    use super::*;
    use odocal::Signals;

    fn tiny_drive() -> Drive {
        let s: Signals = (0..3).map(|i| [i as f64 * 0.25, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]).collect();
        odocal::DriveBuilder { t: vec![0.0, 0.025, 0.05], measured: s, ..Default::default() }.build().expect("drive")
    }

    #[test]
    fn groups_that_leave_nothing_to_validate_on_or_are_malformed_are_refused() {
        let (a, b) = (tiny_drive(), tiny_drive());
        let drives = [("a", &a), ("b", &b)];
        let o = CalibrationOptions::default();
        for groups in [vec![vec![0, 1]], vec![vec![]], vec![vec![2]]] {
            let e = cross_run_groups(&drives, &groups, &o, None).expect_err("refused");
            assert!(matches!(e, Error::InvalidOption { field: "groups", .. }), "{groups:?}: {e}");
        }
        let e = cross_run(&drives[..1], &o, None).expect_err("one drive");
        assert!(matches!(e, Error::InvalidOption { field: "drives", .. }), "{e}");
    }

    #[test]
    fn a_failed_calibration_is_a_row_with_its_error() {
        // far too short for a segment: the row records NoSegments, no θ
        let (a, b) = (tiny_drive(), tiny_drive());
        let t =
            cross_run_groups(&[("a", &a), ("b", &b)], &[vec![0]], &CalibrationOptions::default(), None).expect("table");
        assert_eq!(t.rows.len(), 1);
        assert_eq!(t.rows[0].name, "a");
        assert!(t.rows[0].fit.as_ref().is_err_and(|e| e.contains("segment")), "{:?}", t.rows[0].fit);
        let c = t.criteria(CROSS_RUN_OWN_FIT_RATIO);
        assert_eq!((c.failed, c.runs), (1, 1));
        assert!(!c.pass());
    }
}
