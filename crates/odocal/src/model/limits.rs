//! Physical plausibility of the numbers odocal is given: one place, one
//! documented table of limits.
//!
//! A drive whose numbers are physically absurd is bad input, not a drive to
//! calibrate: a time column in milliseconds, a position column holding ECEF
//! metres, a heading in degrees, a wheel speed of 1e300 all produce a
//! confident wrong answer if they are let through. Every
//! [`Drive`](crate::drive::Drive) is checked against [`PhysicalLimits`] when
//! it is built ([`crate::drive::plausibility`]; the canonical CSV, the
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

use crate::error::{Error, Result};
use crate::model::Theta;

/// Limits on the numbers of a drive. `Default` holds the limits listed in
/// docs/reference.md: sample time 1 ms … 1 s, |n| ≤ 250 rev/s, reference
/// speed ≤ 100 m/s and yaw rate ≤ 5 rad/s, |a_y| ≤ 40 m/s², |β| ≤ 1 rad.
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
    pub(crate) const NONE: PhysicalLimits = PhysicalLimits {
        min_sample_time_s: 0.0,
        max_sample_time_s: f64::INFINITY,
        max_wheel_rev_per_s: f64::INFINITY,
        max_speed_m_per_s: f64::INFINITY,
        max_yaw_rate_rad_per_s: f64::INFINITY,
        max_lateral_acceleration_m_per_s2: f64::INFINITY,
        max_sideslip_rad: f64::INFINITY,
    };

    /// Checks the limits themselves (positive, min ≤ max).
    pub(crate) fn validate(&self) -> Result<()> {
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
pub(crate) fn check_theta(theta: &Theta) -> Result<()> {
    theta.validate()?;
    const SI: &str = "θ is in SI units: c_e, c_d, t_r in metres (2 mm = 0.002), d in metres per m/s²";
    let fail = |what: String| Err(Error::InvalidTheta(format!("{what} ({SI})")));
    let [c_e, c_d, t_r, d] = [theta.c_e, theta.c_d.abs(), theta.t_r, theta.d.abs()].map(echo_num);
    if !(0.05..=20.0).contains(&theta.c_e) {
        return fail(format!("c_e = {c_e} m is outside 0.05 … 20 m"));
    }
    if !(0.05..=10.0).contains(&theta.t_r) {
        return fail(format!("t_r = {t_r} m is outside 0.05 … 10 m"));
    }
    if theta.c_d.abs() > 0.05 * theta.c_e {
        return fail(format!("|c_d| = {c_d} m is more than 5 % of c_e = {c_e} m"));
    }
    if theta.d.abs() > 0.05 {
        return fail(format!("|d| = {d} m/(m/s²) exceeds 0.05"));
    }
    Ok(())
}

/// A number as echoed in a message: in exponent notation outside
/// 10⁻⁶ … 10⁹ (`1e300`, which Rust prints with 301 digits, stays short),
/// else as Rust prints it.
pub(crate) fn echo_num(v: f64) -> String {
    if v.is_finite() && v != 0.0 && !(1e-6..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}

/// Largest plausible lever arm component of the pose reference, m.
pub(crate) const MAX_LEVER_ARM_M: f64 = 20.0;

/// Absolute physical sanity of reference extrinsics read from a user's
/// file (a parameter file; a manifest's `[reference]` is checked alike):
/// each lever-arm component finite and within ±[`MAX_LEVER_ARM_M`], the
/// heading offset finite and within ±π rad.
///
/// # Errors
/// The key (`lever_x`, `lever_y`, `heading_offset`) and the reason.
pub(crate) fn check_extrinsics(x: &crate::Extrinsics) -> std::result::Result<(), (&'static str, String)> {
    for (key, v) in [("lever_x", x.lever_x), ("lever_y", x.lever_y)] {
        if !(v.is_finite() && v.abs() <= MAX_LEVER_ARM_M) {
            let v = echo_num(v);
            return Err((key, format!("{v} m is not within ±{MAX_LEVER_ARM_M} m (the lever arm is in metres)")));
        }
    }
    let h = x.heading_offset;
    if !(h.is_finite() && h.abs() <= std::f64::consts::PI) {
        let h = echo_num(h);
        return Err(("heading_offset", format!("{h} rad is not within ±π rad (the heading offset is in radians)")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

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
