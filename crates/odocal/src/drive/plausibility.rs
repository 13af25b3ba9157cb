//! Plausibility checks of a drive: its numbers against the
//! [`PhysicalLimits`] (every [`Drive`] is checked when it is built) and
//! its wheel and heading conventions against its own reference.

use crate::error::{Error, Result};
use crate::model::limits::PhysicalLimits;
use crate::model::Theta;

use super::Drive;

/// Checks a built drive; the error names the column and the sample.
///
/// # Errors
/// [`Error::InvalidDrive`] for the sample time, [`Error::InvalidSample`]
/// for a value out of range.
pub(crate) fn check_limits(drive: &Drive, limits: &PhysicalLimits, context: &str) -> Result<()> {
    let ts = drive.sample_time_s();
    if !(limits.min_sample_time_s..=limits.max_sample_time_s).contains(&ts) {
        let hint = if ts > limits.max_sample_time_s && ts <= 1e3 * limits.max_sample_time_s {
            "; is the time column in milliseconds? It must be in seconds"
        } else if ts > 1e3 * limits.max_sample_time_s {
            "; is the time column in microseconds or nanoseconds? It must be in seconds"
        } else {
            "; is the time column in seconds? (a t_s this small is a unit mistake or a log of repeated rows)"
        };
        return Err(Error::InvalidDrive {
            context: context.to_string(),
            reason: format!(
                "sample time {ts:.3e} s is outside the plausible {} … {} s{hint}",
                limits.min_sample_time_s, limits.max_sample_time_s
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
        if let Some(i) = col.iter().position(|v| v.abs() > limits.max_wheel_rev_per_s) {
            return Err(bad(
                name,
                i,
                format!(
                    "wheel rotation speed {:.4e} rev/s exceeds {} rev/s (wheel speeds are in revolutions per \
                     second)",
                    col[i], limits.max_wheel_rev_per_s
                ),
            ));
        }
    }
    if let Some(i) = drive.a_y().iter().position(|v| v.abs() > limits.max_lateral_acceleration_m_per_s2) {
        return Err(bad(
            "a_y",
            i,
            format!(
                "lateral acceleration {:.4e} m/s² exceeds {} m/s²",
                drive.a_y()[i],
                limits.max_lateral_acceleration_m_per_s2
            ),
        ));
    }
    if let Some(i) = drive.beta().iter().position(|v| v.abs() > limits.max_sideslip_rad) {
        return Err(bad(
            "beta",
            i,
            format!(
                "sideslip {:.4e} rad exceeds {} rad (sideslip is in radians)",
                drive.beta()[i],
                limits.max_sideslip_rad
            ),
        ));
    }
    let (px, py, psi) = (drive.px(), drive.py(), drive.psi());
    for r in drive.parts() {
        for i in r.start + 1..r.end {
            let v = (px[i] - px[i - 1]).hypot(py[i] - py[i - 1]) / ts;
            if v.is_nan() || v > limits.max_speed_m_per_s {
                return Err(bad(
                    if (px[i] - px[i - 1]).abs() >= (py[i] - py[i - 1]).abs() { "px" } else { "py" },
                    i,
                    format!(
                        "the reference moves {:.4e} m in one step ({v:.4e} m/s > {} m/s): positions must be \
                         metres in a local frame",
                        v * ts,
                        limits.max_speed_m_per_s
                    ),
                ));
            }
            let w = (psi[i] - psi[i - 1]).abs() / ts;
            if w.is_nan() || w > limits.max_yaw_rate_rad_per_s {
                return Err(bad(
                    "psi",
                    i,
                    format!(
                        "the heading changes by {:.4} rad in one step ({w:.3} rad/s > {} rad/s): is the heading \
                         in degrees, or does it jump? It must be radians, continuous",
                        psi[i] - psi[i - 1],
                        limits.max_yaw_rate_rad_per_s
                    ),
                ));
            }
        }
    }
    Ok(())
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
pub(crate) fn check_conventions(drive: &Drive, theta0: &Theta, context: &str) -> Result<()> {
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
}
