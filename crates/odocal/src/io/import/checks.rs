//! Physical plausibility of the imported signals: wheel speeds, lateral
//! acceleration, and the sign and unit conventions of the wheels and the
//! heading (checked against each other). Limits are in the manifest's
//! `[limits]` table; each failure is an error naming the manifest key to
//! change and the drive time.

use std::ops::Range;

use super::limits::{echo_num, within};
use super::manifest::{LateralAccelerationSpec, Manifest, WheelSignal};
use super::signal;
use crate::error::Result;
use crate::model::{kinematics, Input, Theta};

/// The resampled signals the checks look at (full grid, kept parts).
pub(crate) struct Resampled<'a> {
    /// Output step, s.
    pub h: f64,
    /// Wheel-clock time of sample 0, s.
    pub origin_s: f64,
    /// The kept parts.
    pub kept: &'a [Range<usize>],
    /// Rear-left rotation speed, rev/s.
    pub n_rl: &'a [f64],
    /// Rear-right rotation speed, rev/s.
    pub n_rr: &'a [f64],
    /// Reference east, m.
    pub px: &'a [f64],
    /// Reference north, m.
    pub py: &'a [f64],
    /// Reference heading, rad.
    pub psi: &'a [f64],
}

impl Resampled<'_> {
    fn at(&self, k: usize) -> String {
        grid_time(k, self.h, self.origin_s)
    }

    /// Samples of the kept parts with a central difference: `(k0, k, k1)`.
    fn inner(&self) -> impl Iterator<Item = usize> + '_ {
        self.kept.iter().flat_map(|r| r.start + 1..r.end.saturating_sub(1))
    }

    /// Reference speed by central difference at `k`, m/s.
    fn pose_speed(&self, k: usize) -> f64 {
        (self.px[k + 1] - self.px[k - 1]).hypot(self.py[k + 1] - self.py[k - 1]) / (2.0 * self.h)
    }
}

/// Each wheel's speed at θ_0 within `limits.max_speed_m_per_s`.
pub(crate) fn wheel_speeds(m: &Manifest, x: &Resampled<'_>, theta0: &Theta) -> Result<()> {
    for (n, key) in [(x.n_rl, "wheels.rear_left"), (x.n_rr, "wheels.rear_right")] {
        for k in x.kept.iter().flat_map(|r| r.clone()) {
            wheel_speed(m, key, n[k], theta0.c_e, || x.at(k))?;
        }
    }
    Ok(())
}

/// One wheel reading `n` (rev/s) at θ_0's `c_e` within
/// `limits.max_speed_m_per_s`; else the error naming the wheel's `key`,
/// where it happened (`at`, built only then) and what to check for the
/// manifest's wheel signal.
pub(crate) fn wheel_speed(m: &Manifest, key: &str, n: f64, c_e: f64, at: impl FnOnce() -> String) -> Result<()> {
    let max = m.limits.max_speed_m_per_s;
    let v = n * c_e;
    if within(v, max) {
        return Ok(());
    }
    let hint = match m.wheels.signal {
        WheelSignal::RevPerS | WheelSignal::RadPerS | WheelSignal::MPerS => {
            "; if the column counts ticks, use signal = \"ticks_cumulative\" or \"ticks_raw\""
        }
        WheelSignal::TicksRaw => "; check wheels.counter_bits and wheels.ticks_per_rev",
        WheelSignal::TicksCumulative => "; check wheels.ticks_per_rev",
        WheelSignal::RadCumulative => "; check that the column is an angle in rad (not ticks)",
    };
    Err(m.error(
        key,
        format!(
            "{} rev/s at {} is {} m/s at θ_0 (c_e = {} m), above limits.max_speed_m_per_s = {max}{hint}",
            echo_num(n),
            at(),
            echo_num(v),
            c_e
        ),
    ))
}

/// Window of the moving average a derived a_y is judged on, s: the
/// limit is about motion, and the wheel-derived a_y of a highway drive has
/// single-sample noise of ±10 m/s² (speed noise × yaw-rate noise at 30 m/s).
pub(crate) const A_Y_CHECK_SMOOTHING_S: f64 = 0.5;

/// |a_y| within `limits.max_lateral_acceleration_m_per_s2`: an IMU's
/// interval means as they are, a derived a_y after a centred moving average
/// over [`A_Y_CHECK_SMOOTHING_S`] (a corrupt wheel sample still gives
/// thousands of m/s²).
pub(crate) fn lateral_acceleration(m: &Manifest, x: &Resampled<'_>, a_y: &[f64]) -> Result<()> {
    let max = m.limits.max_lateral_acceleration_m_per_s2;
    let mut judged = a_y.to_vec();
    if !matches!(m.lateral_acceleration, LateralAccelerationSpec::Imu { .. }) {
        signal::smooth_parts(&mut judged, x.kept, A_Y_CHECK_SMOOTHING_S, x.h);
    }
    let a_y = &judged;
    for k in x.kept.iter().flat_map(|r| r.clone()) {
        if !within(a_y[k], max) {
            return Err(lateral_acceleration_error(m, a_y[k], &x.at(k)));
        }
    }
    Ok(())
}

/// The error of a judged a_y above `limits.max_lateral_acceleration_m_per_s2`
/// at `at`, naming the manifest key and the likely cause for its source.
pub(crate) fn lateral_acceleration_error(m: &Manifest, a_y: f64, at: &str) -> crate::Error {
    let max = m.limits.max_lateral_acceleration_m_per_s2;
    let (key, hint) = match &m.lateral_acceleration {
        LateralAccelerationSpec::Imu { .. } => {
            ("lateral_acceleration.column", "; is the column in g or the wrong axis?")
        }
        LateralAccelerationSpec::FromWheels { .. } => {
            ("lateral_acceleration", "; the wheel speeds jump there (a corrupt encoder sample?)")
        }
        LateralAccelerationSpec::FromPose { .. } => {
            ("lateral_acceleration", "; the reference pose or heading jumps there")
        }
    };
    m.error(
        key,
        format!(
            "a_y = {} m/s² at {at} (judged over {A_Y_CHECK_SMOOTHING_S} s unless from an IMU) is above \
             limits.max_lateral_acceleration_m_per_s2 = {max}{hint}",
            echo_num(a_y)
        ),
    )
}

/// Where output sample `k` of a grid of step `h` (s) starting at
/// wheel-clock time `origin_s` is, for messages.
pub(crate) fn grid_time(k: usize, h: f64, origin_s: f64) -> String {
    let t = k as f64 * h;
    format!("t = {t:.3} s (wheel clock {:.3} s)", origin_s + t)
}

/// Moving samples (reference faster than this, m/s) the convention checks use.
const MOVING_M_PER_S: f64 = 2.0;
/// Fewest samples a convention check needs (else it is skipped and said so).
const MIN_CHECK_SAMPLES: usize = 80;
/// Least RMS wheel yaw rate for the heading check, rad/s.
const TURNING_RAD_PER_S: f64 = 0.02;
/// Smoothing of both yaw rates for the heading check, s.
const YAW_SMOOTHING_S: f64 = 1.0;
/// Least |correlation| of the yaw rates for the heading check to judge.
const MIN_YAW_CORRELATION: f64 = 0.7;

/// Median of `v` (sorted in place); `None` when empty.
fn median(v: &mut [f64]) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[v.len() / 2])
}

/// The wheels' signs against the reference speed, then the heading's unit
/// and convention against the wheels' yaw rate at θ_0. Errors name the key
/// to change; weaker disagreements become warnings.
pub(crate) fn conventions(m: &Manifest, x: &Resampled<'_>, theta0: &Theta, warnings: &mut Vec<String>) -> Result<()> {
    let moving: Vec<usize> = x.inner().filter(|&k| x.pose_speed(k) > MOVING_M_PER_S).collect();
    if moving.len() < MIN_CHECK_SAMPLES {
        warnings.push(format!(
            "wheel and heading conventions not checked: fewer than {MIN_CHECK_SAMPLES} samples faster than \
             {MOVING_M_PER_S} m/s"
        ));
        return Ok(());
    }
    wheel_signs(m, x, &moving, theta0, warnings)?;
    // The yaw rates' ratio is sign(r)·sd(ref)/sd(wheels) (symmetric in the
    // noise of both), judged only where they correlate.
    let (ww, wr) = smoothed_yaw_rates(x, theta0);
    let y = YawMoments::of(&ww, &wr, &moving);
    let (va, vb, c) = (y.va, y.vb, y.c);
    let corr = y.cov / (va * vb).sqrt();
    if let Some(why) = heading_check_refused((va / c).sqrt(), corr) {
        warnings.push(format!("heading unit and convention not checked: {why}"));
        return Ok(());
    }
    let r = corr.signum() * (vb / va).sqrt();
    heading_convention(m, r, warnings)
}

/// Why the heading check cannot judge a drive whose wheels' RMS yaw rate
/// is `rms_yaw_rate` (rad/s) and whose two yaw rates correlate with `r`:
/// each condition that fails, with its number (a NaN fails); `None` when
/// both hold.
fn heading_check_refused(rms_yaw_rate: f64, r: f64) -> Option<String> {
    let turns = rms_yaw_rate.is_finite() && rms_yaw_rate >= TURNING_RAD_PER_S;
    let correlate = r.abs() >= MIN_YAW_CORRELATION;
    let mut failed = Vec::new();
    if !turns {
        failed.push(format!(
            "the drive turns too little (RMS wheel yaw rate {rms_yaw_rate:.3} rad/s, needs {TURNING_RAD_PER_S})"
        ));
    }
    if !correlate {
        failed.push(format!("the yaw rates correlate too little (|r| = {:.2}, needs {MIN_YAW_CORRELATION})", r.abs()));
    }
    (!failed.is_empty()).then(|| failed.join(" and "))
}

/// Each wheel's speed over the (unsigned) reference speed while moving:
/// ≈ +1 when the vehicle mostly drives forwards and the sign is right. A
/// negative median is an error naming the sign to flip; another far from
/// 1 a warning.
fn wheel_signs(
    m: &Manifest,
    x: &Resampled<'_>,
    moving: &[usize],
    theta0: &Theta,
    warnings: &mut Vec<String>,
) -> Result<()> {
    let mut flipped = Vec::new();
    for (n, key) in [(x.n_rl, "wheels.rear_left.sign"), (x.n_rr, "wheels.rear_right.sign")] {
        let mut r: Vec<f64> = moving.iter().map(|&k| n[k] * theta0.c_e / x.pose_speed(k)).collect();
        let med = median(&mut r).unwrap_or(f64::NAN);
        if med < -0.3 {
            flipped.push((key, med));
        } else if !(0.5..=2.0).contains(&med) {
            warnings.push(format!(
                "{}: the wheel's speed at θ_0 is {med:.3} × the reference speed (median); check the column, \
                 ticks_per_rev or output.theta0",
                key.trim_end_matches(".sign")
            ));
        }
    }
    if flipped.is_empty() {
        return Ok(());
    }
    let keys: Vec<&str> = flipped.iter().map(|f| f.0).collect();
    let both = if flipped.len() == 2 { " (or the vehicle drove backwards throughout)" } else { "" };
    Err(m.error(
        keys[0],
        format!(
            "the wheel turns backwards while the reference moves (wheel speed / reference speed, median {:.3}); \
             flip {}{both}",
            flipped[0].1,
            keys.join(" and ")
        ),
    ))
}

/// The yaw rates of the wheels (the model at θ_0) and of the reference
/// (central heading differences), each smoothed over [`YAW_SMOOTHING_S`]
/// within the parts.
fn smoothed_yaw_rates(x: &Resampled<'_>, theta0: &Theta) -> (Vec<f64>, Vec<f64>) {
    let n = x.n_rl.len();
    let (mut ww, mut wr) = (vec![0.0; n], vec![0.0; n]);
    for k in x.inner() {
        ww[k] = kinematics(&Input { n_rl: x.n_rl[k], n_rr: x.n_rr[k], beta: 0.0, a_y: 0.0 }, theta0).yaw_rate_rad_per_s;
        wr[k] = (x.psi[k + 1] - x.psi[k - 1]) / (2.0 * x.h);
    }
    let width = signal::odd_width(YAW_SMOOTHING_S, x.h);
    for part in x.kept {
        let inner = part.start + 1..part.end.saturating_sub(1);
        if inner.len() > 1 {
            signal::moving_average(&mut ww, inner.clone(), width);
            signal::moving_average(&mut wr, inner, width);
        }
    }
    (ww, wr)
}

/// Centred second moments of the wheels' (a) and the reference's (b) yaw
/// rates over the moving samples, times their count.
struct YawMoments {
    /// Samples.
    c: f64,
    /// Σ(a − ā)².
    va: f64,
    /// Σ(b − b̄)².
    vb: f64,
    /// Σ(a − ā)(b − b̄).
    cov: f64,
}

impl YawMoments {
    /// The moments of `ww` (a) and `wr` (b) at the samples `moving`.
    fn of(ww: &[f64], wr: &[f64], moving: &[usize]) -> YawMoments {
        let (mut sa, mut sb, mut saa, mut sbb, mut sab) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for &k in moving {
            let (a, b) = (ww[k], wr[k]);
            sa += a;
            sb += b;
            saa += a * a;
            sbb += b * b;
            sab += a * b;
        }
        let c = moving.len() as f64;
        YawMoments { c, va: saa - sa * sa / c, vb: sbb - sb * sb / c, cov: sab - sa * sb / c }
    }
}

/// Judges the reference's yaw rate over the wheels' (`r`): about 1 is
/// right; about −1 is swapped wheel columns (a heading derived from the
/// track) or the other heading convention; about 180/π or π/180 the other
/// angle unit of a heading column. Anything else is a warning.
fn heading_convention(m: &Manifest, r: f64, warnings: &mut Vec<String>) -> Result<()> {
    let derived = m.pose.heading.is_none();
    let deg = 180.0 / std::f64::consts::PI;
    let swapped = "or the wheel columns are swapped (wheels.rear_left.column / wheels.rear_right.column)";
    let fail = |key: &str, what: String| Err(m.error(key, what));
    if (0.5..=2.0).contains(&r) {
        Ok(())
    } else if (-2.0..=-0.5).contains(&r) && derived {
        fail(
            "wheels.rear_left.column",
            format!(
                "the wheels' yaw rate has the opposite sign of the track's (ratio {r:.3}): the wheel columns \
                 are swapped (wheels.rear_left.column / wheels.rear_right.column)"
            ),
        )
    } else if (-2.0..=-0.5).contains(&r) {
        fail(
            "pose.heading.convention",
            format!(
                "the reference heading turns the other way than the wheels (yaw-rate ratio {r:.3}): enu is \
                 counter-clockwise from east, ned clockwise from north; {swapped}"
            ),
        )
    } else if (deg / 3.0..=deg * 3.0).contains(&r.abs()) && !derived {
        fail(
            "pose.heading.unit",
            format!(
                "the reference yaw rate is {r:.1} × the wheels' (≈ 180/π): the heading column is in degrees; \
                 set unit = \"deg\""
            ),
        )
    } else if (1.0 / deg / 3.0..=3.0 / deg).contains(&r.abs()) && !derived {
        fail(
            "pose.heading.unit",
            format!(
                "the reference yaw rate is {r:.4} × the wheels' (≈ π/180): the heading column is in radians; \
                 set unit = \"rad\""
            ),
        )
    } else {
        warnings.push(format!(
            "the reference yaw rate is {r:.3} × the wheels' at θ_0 (median over turns); check pose.heading, \
             the wheel columns and output.theta0 (t_r)"
        ));
        Ok(())
    }
}

/// An IMU's a_y against the reference's v·ω
/// ([`LateralFit`](crate::drive::plausibility::LateralFit)) on the imported
/// drive: a wrong sign or unit is an error naming the key and the column.
/// A derived a_y is v·ω by construction and is not judged here.
pub(crate) fn lateral_convention(m: &Manifest, d: &crate::Drive) -> Result<()> {
    use crate::drive::plausibility::{lateral_fit, LateralProblem};
    let LateralAccelerationSpec::Imu { stream, column, sign } = &m.lateral_acceleration else {
        return Ok(());
    };
    let what = format!("the column '{column}' of stream '{stream}'");
    match lateral_fit(d).and_then(|f| f.problem(&what)) {
        Some((LateralProblem::Sign, reason)) => {
            Err(m.error("lateral_acceleration.sign", format!("{reason} (set lateral_acceleration.sign = {})", -sign)))
        }
        Some((LateralProblem::Scale, reason)) => Err(m.error("lateral_acceleration.column", reason)),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The heading check's refusal names only the conditions that failed,
    /// each with its number.
    #[test]
    fn a_refused_heading_check_names_only_what_failed() {
        assert_eq!(heading_check_refused(0.05, 0.9), None);
        assert_eq!(heading_check_refused(0.05, -0.9), None, "the sign is judged afterwards");
        let straight = heading_check_refused(0.004, 0.85).expect("turns too little");
        assert_eq!(straight, "the drive turns too little (RMS wheel yaw rate 0.004 rad/s, needs 0.02)");
        let noisy = heading_check_refused(0.05, -0.31).expect("correlates too little");
        assert_eq!(noisy, "the yaw rates correlate too little (|r| = 0.31, needs 0.7)");
        let both = heading_check_refused(0.004, 0.31).expect("both");
        assert!(both.contains("turns too little") && both.contains(" and the yaw rates correlate"), "{both}");
        let nan = heading_check_refused(f64::NAN, f64::NAN).expect("NaN fails");
        assert!(nan.contains("turns too little") && nan.contains("correlate too little"), "{nan}");
    }
}
