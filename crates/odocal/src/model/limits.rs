//! Physical plausibility of the numbers odocal is given: one place, one
//! documented table of limits.
//!
//! A drive whose numbers are physically absurd is bad input, not a drive to
//! calibrate: a time column in milliseconds, a position column holding ECEF
//! metres, a heading in degrees, a wheel speed of 1e300 all produce a
//! confident wrong answer if they are let through. Every [`Drive`] is checked
//! against [`PhysicalLimits`] when it is built (the canonical CSV, the
//! importer, the simulator and the Python package all build through
//! [`DriveBuilder`](crate::drive::DriveBuilder)); a θ typed by a user is
//! checked by [`check_theta`].
//!
//! | quantity | default limit | why |
//! |---|---|---|
//! | sample time t_s | 1 ms … 1 s | odometry logs run at 1–1000 Hz; outside, t is in the wrong unit |
//! | wheel rotation speed \|n\| | ≤ 250 rev/s | a 2 m tyre at 500 m/s, a 0.3 m robot wheel at 75 m/s |
//! | reference speed (position increments / t_s) | ≤ 100 m/s | 360 km/h; more is a unit or frame mistake |
//! | reference yaw rate (heading increments / t_s) | ≤ 5 rad/s | a car at full lock turns < 1.5 rad/s; a heading in degrees or a π jump exceeds it |
//! | \|a_y\| | ≤ 40 m/s² | 4 g |
//! | \|β\| | ≤ 1 rad | sideslip beyond 57° is not driving |
//!
//! Vehicles that really exceed a limit (a fast robot turning on the spot, a
//! race car) set their own [`PhysicalLimits`] (`DriveBuilder::limits`).

use serde::{Deserialize, Serialize};

use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::model::Theta;

/// Limits on the numbers of a drive. `Default` holds the documented table
/// in the [module docs](self).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct PhysicalLimits {
    /// Smallest plausible sample time, s. Default 1e-3.
    pub min_sample_time_s: f64,
    /// Largest plausible sample time, s. Default 1.
    pub max_sample_time_s: f64,
    /// Largest |wheel rotation speed|, rev/s. Default 250.
    pub max_wheel_rev_per_s: f64,
    /// Largest reference speed (from position increments), m/s. Default 100.
    pub max_speed_m_per_s: f64,
    /// Largest reference yaw rate (from heading increments), rad/s. Default 5.
    pub max_yaw_rate_rad_per_s: f64,
    /// Largest |lateral acceleration|, m/s². Default 40.
    pub max_lateral_acceleration_m_per_s2: f64,
    /// Largest |sideslip|, rad. Default 1.
    pub max_sideslip_rad: f64,
}

impl Default for PhysicalLimits {
    fn default() -> Self {
        PhysicalLimits {
            min_sample_time_s: 1e-3,
            max_sample_time_s: 1.0,
            max_wheel_rev_per_s: 250.0,
            max_speed_m_per_s: 100.0,
            max_yaw_rate_rad_per_s: 5.0,
            max_lateral_acceleration_m_per_s2: 40.0,
            max_sideslip_rad: 1.0,
        }
    }
}

impl PhysicalLimits {
    /// No limits at all (every check passes): for synthetic tests of the
    /// numerics only.
    pub const NONE: PhysicalLimits = PhysicalLimits {
        min_sample_time_s: 0.0,
        max_sample_time_s: f64::INFINITY,
        max_wheel_rev_per_s: f64::INFINITY,
        max_speed_m_per_s: f64::INFINITY,
        max_yaw_rate_rad_per_s: f64::INFINITY,
        max_lateral_acceleration_m_per_s2: f64::INFINITY,
        max_sideslip_rad: f64::INFINITY,
    };

    /// Checks the limits themselves (positive, min ≤ max).
    pub fn validate(&self) -> Result<()> {
        let fields = [
            ("limits.min_sample_time_s", self.min_sample_time_s),
            ("limits.max_sample_time_s", self.max_sample_time_s),
            ("limits.max_wheel_rev_per_s", self.max_wheel_rev_per_s),
            ("limits.max_speed_m_per_s", self.max_speed_m_per_s),
            ("limits.max_yaw_rate_rad_per_s", self.max_yaw_rate_rad_per_s),
            ("limits.max_lateral_acceleration_m_per_s2", self.max_lateral_acceleration_m_per_s2),
            ("limits.max_sideslip_rad", self.max_sideslip_rad),
        ];
        for (field, v) in fields {
            if v.is_nan() || v < 0.0 {
                return Err(Error::InvalidOption { field, reason: format!("{v} must be a non-negative number") });
            }
        }
        if self.min_sample_time_s > self.max_sample_time_s {
            return Err(Error::InvalidOption {
                field: "limits.min_sample_time_s",
                reason: "must not exceed limits.max_sample_time_s".into(),
            });
        }
        Ok(())
    }

    /// Checks a built drive; the error names the column and the sample.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] for the sample time, [`Error::InvalidSample`]
    /// for a value out of range.
    pub fn check(&self, drive: &Drive, context: &str) -> Result<()> {
        let ts = drive.sample_time_s();
        if !(self.min_sample_time_s..=self.max_sample_time_s).contains(&ts) {
            let hint = if ts > self.max_sample_time_s && ts <= 1e3 * self.max_sample_time_s {
                "; is the time column in milliseconds? It must be in seconds"
            } else if ts > 1e3 * self.max_sample_time_s {
                "; is the time column in microseconds or nanoseconds? It must be in seconds"
            } else {
                "; is the time column in seconds? (a t_s this small is a unit mistake or a log of repeated rows)"
            };
            return Err(Error::InvalidDrive {
                context: context.to_string(),
                reason: format!(
                    "sample time {ts:.3e} s is outside the plausible {} … {} s{hint}",
                    self.min_sample_time_s, self.max_sample_time_s
                ),
            });
        }
        let bad = |column: &str, sample: usize, reason: String| Error::InvalidSample {
            context: context.to_string(),
            column: column.to_string(),
            sample,
            reason,
        };
        for (name, col) in [("n_rl", drive.n_rl()), ("n_rr", drive.n_rr())] {
            if let Some(i) = col.iter().position(|v| v.abs() > self.max_wheel_rev_per_s) {
                return Err(bad(
                    name,
                    i,
                    format!(
                        "wheel rotation speed {:.4e} rev/s exceeds {} rev/s (wheel speeds are in revolutions per \
                         second)",
                        col[i], self.max_wheel_rev_per_s
                    ),
                ));
            }
        }
        if let Some(i) = drive.a_y().iter().position(|v| v.abs() > self.max_lateral_acceleration_m_per_s2) {
            return Err(bad(
                "a_y",
                i,
                format!(
                    "lateral acceleration {:.4e} m/s² exceeds {} m/s²",
                    drive.a_y()[i],
                    self.max_lateral_acceleration_m_per_s2
                ),
            ));
        }
        if let Some(i) = drive.beta().iter().position(|v| v.abs() > self.max_sideslip_rad) {
            return Err(bad(
                "beta",
                i,
                format!(
                    "sideslip {:.4e} rad exceeds {} rad (sideslip is in radians)",
                    drive.beta()[i],
                    self.max_sideslip_rad
                ),
            ));
        }
        let (px, py, psi) = (drive.px(), drive.py(), drive.psi());
        for r in drive.parts() {
            for i in r.start + 1..r.end {
                let v = (px[i] - px[i - 1]).hypot(py[i] - py[i - 1]) / ts;
                if v.is_nan() || v > self.max_speed_m_per_s {
                    return Err(bad(
                        if (px[i] - px[i - 1]).abs() >= (py[i] - py[i - 1]).abs() { "px" } else { "py" },
                        i,
                        format!(
                            "the reference moves {:.4e} m in one step ({v:.4e} m/s > {} m/s): positions must be \
                             metres in a local frame",
                            v * ts,
                            self.max_speed_m_per_s
                        ),
                    ));
                }
                let w = (psi[i] - psi[i - 1]).abs() / ts;
                if w.is_nan() || w > self.max_yaw_rate_rad_per_s {
                    return Err(bad(
                        "psi",
                        i,
                        format!(
                            "the heading changes by {:.4} rad in one step ({w:.3} rad/s > {} rad/s): is the heading \
                             in degrees, or does it jump? It must be radians, continuous",
                            psi[i] - psi[i - 1],
                            self.max_yaw_rate_rad_per_s
                        ),
                    ));
                }
            }
        }
        Ok(())
    }
}

/// Checks the wheel and heading conventions of a drive against its own
/// reference at θ_0, so that a wrong sign or convention is named instead of
/// calibrated into a confident wrong θ:
///
/// - the wheel speed at θ_0 must move the same way as the reference and be
///   within ×0.5 … ×2 of its speed (negated wheels, one wheel's sign flipped,
///   wheel speeds in the wrong unit);
/// - the heading must point along the direction of travel within 0.3 rad
///   (a heading measured clockwise from north, in degrees, or with a large
///   mounting offset);
/// - the wheel-derived yaw rate must turn the same way as the reference's
///   (left and right wheels swapped, a clockwise heading).
///
/// Only samples where the reference moves faster than 2 m/s count; a drive
/// with too few of them is not judged (returns `Ok`).
///
/// # Errors
/// [`Error::InvalidDrive`] naming the convention to check.
pub fn check_conventions(drive: &Drive, theta0: &Theta, context: &str) -> Result<()> {
    use crate::model::{kinematics, wrap_angle};
    let ts = drive.sample_time_s();
    let (px, py, psi) = (drive.px(), drive.py(), drive.psi());
    let (mut ratios, mut offsets, mut yaw) = (Vec::new(), Vec::new(), Vec::new());
    for r in drive.parts() {
        for i in r.start..r.end.saturating_sub(1) {
            let (dx, dy) = (px[i + 1] - px[i], py[i + 1] - py[i]);
            let v_ref = dx.hypot(dy) / ts;
            if v_ref < 2.0 {
                continue;
            }
            let k = kinematics(&drive.input(i), theta0);
            ratios.push(k.speed_m_per_s / v_ref);
            offsets.push(wrap_angle(psi[i] - dy.atan2(dx)));
            let w_ref = (psi[i + 1] - psi[i]) / ts;
            if w_ref.abs() > 0.05 {
                yaw.push((k.yaw_rate_rad_per_s, w_ref));
            }
        }
    }
    if ratios.len() < 200 {
        return Ok(());
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let fail = |reason: String| Err(Error::InvalidDrive { context: context.to_string(), reason });
    let ratio = median(&mut ratios);
    if ratio < 0.0 {
        return fail(format!(
            "the wheels turn backwards while the reference moves (wheel speed / reference speed, median {ratio:.3}):              flip the sign of n_rl and n_rr"
        ));
    }
    if !(0.5..=2.0).contains(&ratio) {
        return fail(format!(
            "the wheel speed at θ_0 is {ratio:.3} × the reference speed (median): one wheel's sign flipped, wheel              speeds not in rev/s, or θ_0's c_e far off"
        ));
    }
    let offset = median(&mut offsets);
    if offset.abs() > 0.3 {
        return fail(format!(
            "the heading differs from the direction of travel by {offset:.3} rad (median): psi must be radians,              counter-clockwise from the x axis (ENU), pointing forward"
        ));
    }
    if yaw.len() >= 100 {
        let agree = yaw.iter().filter(|(a, b)| a * b > 0.0).count() as f64 / yaw.len() as f64;
        if agree < 0.25 {
            return fail(format!(
                "the wheel-derived yaw rate turns against the reference's on {:.0} % of turning samples: left and                  right wheels swapped, or the heading is clockwise",
                100.0 * (1.0 - agree)
            ));
        }
    }
    Ok(())
}

/// Absolute physical sanity of a θ given by a user (the CLI's `--theta`, a
/// Python call): c_e and t_r positive and within 0.05 … 20 m and
/// 0.05 … 10 m, |c_d| at most 5 % of c_e, |d| at most 0.05 m per m/s². A
/// robot's 0.3 m wheel passes; a c_d typed in millimetres does not.
///
/// Calibration *results* are judged against θ_0 by the trust checks, not
/// here.
///
/// # Errors
/// [`Error::InvalidTheta`] naming the parameter, with a hint that θ is in SI
/// units.
pub fn check_theta(theta: &Theta) -> Result<()> {
    theta.validate()?;
    const SI: &str = "θ is in SI units: c_e, c_d, t_r in metres (2 mm = 0.002), d in metres per m/s²";
    let fail = |what: String| Err(Error::InvalidTheta(format!("{what} ({SI})")));
    if !(0.05..=20.0).contains(&theta.c_e) {
        return fail(format!("c_e = {} m is outside 0.05 … 20 m", theta.c_e));
    }
    if !(0.05..=10.0).contains(&theta.t_r) {
        return fail(format!("t_r = {} m is outside 0.05 … 10 m", theta.t_r));
    }
    if theta.c_d.abs() > 0.05 * theta.c_e {
        return fail(format!("|c_d| = {} m is more than 5 % of c_e = {} m", theta.c_d.abs(), theta.c_e));
    }
    if theta.d.abs() > 0.05 {
        return fail(format!("|d| = {} m/(m/s²) exceeds 0.05", theta.d.abs()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::Signals;

    fn drive_with(ts: f64, edit: impl Fn(&mut Signals)) -> Result<Drive> {
        let n = 50;
        let mut s = Signals::with_capacity(n);
        for k in 0..n {
            s.push([k as f64 * 10.0 * ts, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]);
        }
        edit(&mut s);
        Drive::builder((0..n).map(|k| k as f64 * ts).collect(), s).context("d").build()
    }

    #[test]
    fn plausible_drive_passes() {
        drive_with(0.025, |_| {}).expect("plausible");
        drive_with(0.001, |_| {}).expect("1 kHz");
    }

    #[test]
    fn time_units_are_named() {
        let m = drive_with(25.0, |_| {}).expect_err("ms").to_string();
        assert!(m.contains("milliseconds"), "{m}");
        let m = drive_with(2.5e7, |_| {}).expect_err("ns").to_string();
        assert!(m.contains("microseconds or nanoseconds"), "{m}");
        let m = drive_with(1e-9, |_| {}).expect_err("tiny").to_string();
        assert!(m.contains("outside the plausible"), "{m}");
    }

    #[test]
    fn absurd_values_name_column_and_sample() {
        let m = drive_with(0.025, |s| s.n_rr[9] = 1e300).expect_err("wheel").to_string();
        assert!(m.contains("column 'n_rr', sample 9") && m.contains("rev/s"), "{m}");
        let m = drive_with(0.025, |s| s.px[20] = 1e308).expect_err("px").to_string();
        assert!(m.contains("column 'px', sample 20"), "{m}");
        let m = drive_with(0.025, |s| s.psi[30] = 3.0).expect_err("psi").to_string();
        assert!(m.contains("column 'psi', sample 30") && m.contains("degrees"), "{m}");
        let m = drive_with(0.025, |s| s.a_y[3] = 100.0).expect_err("a_y").to_string();
        assert!(m.contains("column 'a_y', sample 3"), "{m}");
    }

    #[test]
    fn conventions_are_checked_against_the_reference() {
        let sim = crate::sim::simulate(&crate::sim::SimOptions { length_km: 2.0, ..crate::sim::SimOptions::paper(4) })
            .expect("sim");
        let d = &sim.drive;
        let th = Theta::PAPER_INITIAL;
        check_conventions(d, &th, "sim").expect("a simulated drive is consistent");
        let edit = |f: &dyn Fn(&mut Signals)| {
            let mut s = d.measured().clone();
            f(&mut s);
            Drive::builder(d.t().to_vec(), s).build().expect("drive")
        };
        let neg = edit(&|s| {
            s.n_rl.iter_mut().for_each(|v| *v = -*v);
            s.n_rr.iter_mut().for_each(|v| *v = -*v);
        });
        let m = check_conventions(&neg, &th, "d").expect_err("negated").to_string();
        assert!(m.contains("backwards"), "{m}");
        let one = edit(&|s| s.n_rr.iter_mut().for_each(|v| *v = -*v));
        let m = check_conventions(&one, &th, "d").expect_err("one flipped").to_string();
        assert!(m.contains("one wheel's sign"), "{m}");
        let swapped = edit(&|s| std::mem::swap(&mut s.n_rl, &mut s.n_rr));
        let m = check_conventions(&swapped, &th, "d").expect_err("swapped").to_string();
        assert!(m.contains("swapped"), "{m}");
        let ned = edit(&|s| s.psi.iter_mut().for_each(|v| *v = std::f64::consts::FRAC_PI_2 - *v));
        let m = check_conventions(&ned, &th, "d").expect_err("ned").to_string();
        assert!(m.contains("direction of travel"), "{m}");
    }

    #[test]
    fn theta_sanity() {
        check_theta(&Theta::PAPER_INITIAL).expect("paper");
        check_theta(&Theta { c_e: 0.3, c_d: 0.001, t_r: 0.4, d: 0.0 }).expect("robot");
        let m = check_theta(&Theta { c_e: 2.0, c_d: 5.0, t_r: 1.6, d: 0.0 }).expect_err("mm").to_string();
        assert!(m.contains("c_d") && m.contains("SI units"), "{m}");
        assert!(check_theta(&Theta { c_e: 2.0, c_d: 0.0, t_r: 1e308, d: 0.0 }).is_err());
        assert!(check_theta(&Theta { c_e: 2.0, c_d: 0.0, t_r: 1.6, d: 1.0 }).is_err());
    }
}
