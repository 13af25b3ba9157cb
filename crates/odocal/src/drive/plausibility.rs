//! Plausibility checks of a drive: its numbers against the
//! [`PhysicalLimits`] (every [`Drive`] is checked when it is built) and
//! its wheel and heading conventions against its own reference.

use rayon::prelude::*;

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

/// Checks the wheel, heading and lateral-acceleration conventions of a
/// drive against its own reference at θ_0 (validate: at the θ validated), so that a wrong sign or convention is named instead of
/// calibrated into a confident wrong θ:
///
/// - the wheel speed at θ_0 must move the same way as the reference and be
///   within ×0.5 … ×2 of its speed (negated wheels, one wheel's sign flipped,
///   wheel speeds in the wrong unit);
/// - the heading must point along the direction of travel within 0.3 rad
///   (a heading measured clockwise from north, in degrees, or with a large
///   mounting offset);
/// - the wheel-derived yaw rate must turn the same way as the reference's
///   (left and right wheels swapped, a clockwise heading);
/// - a_y must follow the reference's v·ω with a slope from −0.15 to 2
///   ([`LateralFit`]: a_y negated, or in ft/s²).
///
/// Only samples where the reference moves faster than 2 m/s count; a drive
/// with too few of them is not judged (returns `Ok`).
///
/// Before those, [`stalled_signal`]: a wheel that reads (almost) nothing
/// while the reference moves, or a reference that stands still while the
/// wheels turn, for 2 s or more, and a drive whose reference never moves.
///
/// # Errors
/// [`Error::InvalidDrive`] naming the convention to check, or the signal
/// that stalls and where.
pub(crate) fn check_conventions(drive: &Drive, theta0: &Theta, context: &str) -> Result<()> {
    conventions(drive, (theta0, "θ_0"), context, 0)
}

/// [`check_conventions`] at the θ `validate` is given, the messages
/// calling it θ.
pub(crate) fn check_conventions_at_theta(drive: &Drive, theta: &Theta, context: &str) -> Result<()> {
    conventions(drive, (theta, "θ"), context, 0)
}

/// [`check_conventions`] of a block of a longer drive whose first sample
/// is the drive's sample `first` (the samples a message names count from
/// the drive's start).
pub(crate) fn check_conventions_from(drive: &Drive, theta0: &Theta, context: &str, first: usize) -> Result<()> {
    conventions(drive, (theta0, "θ_0"), context, first)
}

/// Per moving sample ([`conventions`]): the wheel/reference speed ratio,
/// the heading's offset from the direction of travel, and on turns the
/// wheels' and the reference's yaw rates.
type Moving = (f64, f64, Option<(f64, f64)>);

/// [`check_conventions_from`] at `theta`, which the messages call `name`.
fn conventions(drive: &Drive, (theta0, name): (&Theta, &str), context: &str, first: usize) -> Result<()> {
    // The checks are independent: pairs of them run at once, and they are
    // judged in the order written, each pair only where the checks before
    // it passed.
    let (stalled, moving) =
        rayon::join(|| stalled_signal(drive, (theta0, name), first), || moving_samples(drive, theta0));
    // The upper median: the value a full sort puts at len / 2.
    let median = |v: &mut Vec<f64>| {
        let mid = v.len() / 2;
        *v.select_nth_unstable_by(mid, f64::total_cmp).1
    };
    let fail = |reason: String| Err(Error::InvalidDrive { context: context.to_string(), reason });
    let mut ratios: Vec<f64> = moving.iter().map(|m| m.0).collect();
    let ratio = (moving.len() >= 200).then(|| median(&mut ratios));
    if let Some(reason) = stalled {
        // A stall is judged at θ_0: with θ_0's c_e far off (or the wheels in
        // other units) the whole drive looks like one. Say that first.
        return match ratio.filter(|r| !(0.5..=2.0).contains(r)) {
            Some(r) => fail(format!(
                "the wheel speed at {name} is {r:.3} × the reference speed (median over the drive): wheel speeds \
                 not in rev/s, or the c_e of {name} far off (check the θ given: --theta0, --theta or a parameter file); at {name} {reason}"
            )),
            None => fail(reason),
        };
    }
    let Some(ratio) = ratio else {
        return Ok(());
    };
    let mut offsets: Vec<f64> = moving.iter().map(|m| m.1).collect();
    let yaw: Vec<(f64, f64)> = moving.iter().filter_map(|m| m.2).collect();
    if ratio < 0.0 {
        return fail(format!(
            "the wheels turn backwards while the reference moves (wheel speed / reference speed, median {ratio:.3}): \
             flip the sign of n_rl and n_rr"
        ));
    }
    if !(0.5..=2.0).contains(&ratio) {
        return fail(format!(
            "the wheel speed at {name} is {ratio:.3} × the reference speed (median): one wheel's sign flipped, wheel \
             speeds not in rev/s, or the c_e of {name} far off"
        ));
    }
    let offset = median(&mut offsets);
    if offset.abs() > 0.3 {
        return fail(format!(
            "the heading differs from the direction of travel by {offset:.3} rad (median): psi must be radians, \
             counter-clockwise from the x axis (ENU), pointing forward"
        ));
    }
    if yaw.len() >= 100 {
        let agree = yaw.iter().filter(|(a, b)| a * b > 0.0).count() as f64 / yaw.len() as f64;
        if agree < 0.25 {
            return fail(format!(
                "the wheel-derived yaw rate turns against the reference's on {:.0} % of turning samples: left and \
                 right wheels swapped, or the heading is clockwise",
                100.0 * (1.0 - agree)
            ));
        }
    }
    let (lateral, lag) =
        rayon::join(|| lateral_fit(drive).and_then(|f| f.problem("column 'a_y'")), || clock_lag(drive, theta0));
    if let Some(reason) = lateral {
        return fail(reason.1);
    }
    if let Some(reason) = lag {
        return fail(reason);
    }
    Ok(())
}

/// [`Moving`] of every sample of `drive` where the reference moves faster
/// than 2 m/s, the wheels read at `theta0`, in sample order. The samples
/// are independent (and the medians and the share [`conventions`] takes
/// of them do not depend on their order): computed by rayon's threads.
fn moving_samples(drive: &Drive, theta0: &Theta) -> Vec<Moving> {
    use crate::model::{kinematics, wrap_angle};
    let ts = drive.sample_time_s();
    let (px, py, psi) = (drive.px(), drive.py(), drive.psi());
    drive
        .parts()
        .par_iter()
        .flat_map(|r| (r.start..r.end.saturating_sub(1)).into_par_iter())
        .filter_map(|i| {
            let (dx, dy) = (px[i + 1] - px[i], py[i + 1] - py[i]);
            let v_ref = dx.hypot(dy) / ts;
            if v_ref < 2.0 {
                return None;
            }
            let k = kinematics(&drive.input(i), theta0);
            let w_ref = (psi[i + 1] - psi[i]) / ts;
            let yaw = (w_ref.abs() > 0.05).then_some((k.yaw_rate_rad_per_s, w_ref));
            Some((k.speed_m_per_s / v_ref, wrap_angle(psi[i] - dy.atan2(dx)), yaw))
        })
        .collect()
}

/// Largest lag between the wheels and the reference [`clock_lag`] lets
/// pass, s: at 0.2 s batch Gauss-Newton takes t_r 3 % too wide and d 55 %
/// too small on a simulated 12 km drive, with an accepted verdict.
const MAX_CLOCK_LAG_S: f64 = 0.15;
/// Search range of [`clock_lag`], ± s.
const CLOCK_LAG_RANGE_S: f64 = 2.0;
/// Lowest speed correlation at which [`clock_lag`] judges a lag.
const MIN_LAG_CORRELATION: f64 = 0.9;
/// Lowest yaw-rate correlation at which [`clock_lag`] judges a lag.
const MIN_LAG_YAW_CORRELATION: f64 = 0.8;

/// The wheels' lag behind the reference, found by cross-correlating the
/// wheel speed at θ_0 with the reference's centrally differenced speed over
/// ±[`CLOCK_LAG_RANGE_S`], named when it is clear (correlation of
/// [`MIN_LAG_CORRELATION`] or more, not at the edge of the search, and the
/// yaw rates', of [`MIN_LAG_YAW_CORRELATION`] or more, within two samples
/// of it) and more than [`MAX_CLOCK_LAG_S`] and two samples: the two clocks
/// are offset, and the offset would be calibrated into θ.
fn clock_lag(drive: &Drive, theta0: &Theta) -> Option<String> {
    let ts = drive.sample_time_s();
    let (px, py) = (drive.px(), drive.py());
    let n = px.len();
    let psi = drive.psi();
    let [mut wheel, mut reference, mut wheel_yaw, mut reference_yaw] = [(); 4].map(|_| vec![f64::NAN; n]);
    for r in drive.parts() {
        for i in r.start + 1..r.end.saturating_sub(1) {
            let k = crate::model::kinematics(&drive.input(i), theta0);
            (wheel[i], wheel_yaw[i]) = (k.speed_m_per_s, k.yaw_rate_rad_per_s);
            reference[i] = (px[i + 1] - px[i - 1]).hypot(py[i + 1] - py[i - 1]) / (2.0 * ts);
            reference_yaw[i] = crate::model::wrap_angle(psi[i + 1] - psi[i - 1]) / (2.0 * ts);
        }
    }
    let max_lag = (CLOCK_LAG_RANGE_S / ts).ceil() as usize;
    let c = crate::drive::correlate::cross_correlate(&wheel, &reference, ts, max_lag)?;
    let yaw = crate::drive::correlate::cross_correlate(&wheel_yaw, &reference_yaw, ts, max_lag)?;
    let at_edge = c.offset_s.abs() >= (max_lag as f64 - 2.0) * ts;
    let clear = c.peak >= MIN_LAG_CORRELATION && yaw.peak >= MIN_LAG_YAW_CORRELATION;
    if !clear || at_edge || (c.offset_s - yaw.offset_s).abs() > 2.0 * ts {
        return None;
    }
    if c.offset_s.abs() <= MAX_CLOCK_LAG_S.max(2.0 * ts) {
        return None;
    }
    let (who, by, to) = if c.offset_s > 0.0 { ("lag", c.offset_s, "earlier") } else { ("lead", -c.offset_s, "later") };
    Some(format!(
        "the wheel speeds {who} the reference's by {by:.3} s (speed cross-correlation {:.3} at that offset): the wheel \
         and reference clocks are offset; move n_rl and n_rr {by:.3} s {to} against px, py, psi, or import the \
         streams with a manifest, whose output.clock_offset = \"auto\" aligns them",
        c.peak
    ))
}

/// The span over which [`stalled_signal`] compares distances, s.
const STALL_WINDOW_S: f64 = 1.0;
/// The shortest stall [`stalled_signal`] reports, s: a wheel or a
/// reference that lags for a moment is jitter, not a lost signal.
const STALL_MIN_S: f64 = 2.0;
/// Speed of the moving side from which a stall counts, m/s.
const STALL_MIN_SPEED_M_PER_S: f64 = 2.0;
/// The stalled side covers less than this fraction of the moving side's
/// distance over each window.
const STALL_FRACTION: f64 = 0.1;

/// Samples two blocks of a drive judged one at a time must share for
/// every stall [`stalled_signal`] reports in the whole drive to lie whole
/// in one of them: the shortest stall and a window on either side.
pub(crate) fn stall_overlap_samples(sample_time_s: f64) -> usize {
    ((STALL_MIN_S + 2.0 * STALL_WINDOW_S) / sample_time_s).ceil() as usize
}

/// A signal that stalls while the drive moves, in words, or `None`:
///
/// - a wheel (`n_rl`, `n_rr`) that covers less than a tenth of the
///   reference's distance for [`STALL_MIN_S`] or more while the reference
///   moves faster than 2 m/s (an encoder drop-out logged as zeros, a
///   disconnected wheel);
/// - a reference (`px`, `py`) that covers less than a tenth of the wheels'
///   distance at θ_0 for as long while the wheels turn faster than 2 m/s
///   (a position held through a GNSS outage);
/// - a reference that does not move at all while the wheels cover 200 m or
///   more (a constant or missing position).
///
/// Distances are compared over windows of [`STALL_WINDOW_S`] (the
/// reference's noise over one sample would hide nothing and flag much), each
/// window within one part; c_d is left out (a wheel's circumference is c_e to
/// within a few per mille). Samples are named counting from `offset`.
fn stalled_signal(drive: &Drive, (theta0, name): (&Theta, &str), offset: usize) -> Option<String> {
    let ts = drive.sample_time_s();
    let w = ((STALL_WINDOW_S / ts).round() as usize).max(1);
    // A run of windows covers the run plus one window of samples.
    let min_windows = ((STALL_MIN_S / ts).round() as usize).saturating_sub(w).max(1);
    let (px, py, t) = (drive.px(), drive.py(), drive.t());
    let m = drive.measured();
    let (mut wheel_total, mut reference_total) = (0.0, 0.0);
    for part in drive.parts() {
        // Prefix sums of each wheel's distance at θ_0.
        let prefix = |n: &[f64]| {
            let mut acc = vec![0.0; part.len() + 1];
            for (k, i) in part.clone().enumerate() {
                acc[k + 1] = acc[k] + wheel_distance(theta0, n, i, ts);
            }
            acc
        };
        let (left, right) = (prefix(&m.n_rl), prefix(&m.n_rr));
        wheel_total += 0.5 * (left[part.len()] + right[part.len()]);
        reference_total +=
            (part.start..part.end.saturating_sub(1)).map(|i| (px[i + 1] - px[i]).hypot(py[i + 1] - py[i])).sum::<f64>();
        if part.len() <= w {
            continue;
        }
        let min_distance = STALL_MIN_SPEED_M_PER_S * w as f64 * ts;
        let reference_distance = |k: usize| {
            let (a, b) = (part.start + k, part.start + k + w);
            (px[b] - px[a]).hypot(py[b] - py[a])
        };
        let wheel_stalled = |acc: &[f64], k: usize| {
            let r = reference_distance(k);
            r >= min_distance && acc[k + w] - acc[k] < STALL_FRACTION * r
        };
        let checks: [(Stall<'_>, &dyn Fn(usize) -> bool); 3] = [
            (Stall::Wheel("n_rl", &m.n_rl), &|k| wheel_stalled(&left, k)),
            (Stall::Wheel("n_rr", &m.n_rr), &|k| wheel_stalled(&right, k)),
            (Stall::Reference, &|k| {
                let wheels = 0.5 * (left[k + w] - left[k] + right[k + w] - right[k]);
                wheels >= min_distance && reference_distance(k) < STALL_FRACTION * wheels
            }),
        ];
        for (stall, stalled) in checks {
            let Some((first, last)) = first_run(part.len() - w, min_windows, stalled) else { continue };
            let (a, b) = stall.trim(drive, theta0, part.start + first, part.start + last + w);
            let what = match stall {
                Stall::Reference => "the reference position (px, py) stands still while the wheels turn".to_string(),
                Stall::Wheel(column, _) => {
                    format!("column '{column}' reads (almost) no rotation while the reference moves")
                }
            };
            return Some(format!(
                "{what}: samples {}–{} (t = {:.3} … {:.3} s, {:.1} s); a signal lost there (a drop-out \
                 logged as zeros or a held value) would be calibrated as data: drop those rows and mark \
                 the gap with a 'part' column, or import the log with a manifest",
                offset + a,
                offset + b,
                t[a],
                t[b],
                t[b] - t[a]
            ));
        }
    }
    if wheel_total >= 200.0 && reference_total < STALL_FRACTION * wheel_total {
        return Some(format!(
            "the reference position (px, py) moves {reference_total:.1} m in all while the wheels cover \
             {wheel_total:.0} m at {name}: give the reference's position columns (a constant or missing position \
             cannot be calibrated against)"
        ));
    }
    None
}

/// The distance wheel reading `n[i]` covers over one sample at θ_0.
fn wheel_distance(theta0: &Theta, n: &[f64], i: usize, ts: f64) -> f64 {
    theta0.c_e * n[i].abs() * ts
}

/// The first run of at least `min` consecutive indices in `0..n` for which
/// `stalled` holds: its first and last index.
fn first_run(n: usize, min: usize, stalled: &dyn Fn(usize) -> bool) -> Option<(usize, usize)> {
    let mut start = None;
    for k in 0..=n {
        match (k < n && stalled(k), start) {
            (true, None) => start = Some(k),
            (false, Some(s)) if k - s >= min => return Some((s, k - 1)),
            (false, Some(_)) => start = None,
            _ => {}
        }
    }
    None
}

/// What [`stalled_signal`] found stalled: a wheel (its column and
/// readings) or the reference position.
#[derive(Clone, Copy)]
enum Stall<'a> {
    Wheel(&'static str, &'a [f64]),
    Reference,
}

impl Stall<'_> {
    /// The samples of a stall found in the windows over samples `a..=b`:
    /// from the first to the last sample whose own distance (the wheel's
    /// rotation at θ_0, or the reference's step to the next sample, counted
    /// to that next sample) is below the stall fraction of the moving side's
    /// mean over `a..=b`; `(a, b)` when none is.
    fn trim(self, drive: &Drive, theta0: &Theta, a: usize, b: usize) -> (usize, usize) {
        let (px, py, ts) = (drive.px(), drive.py(), drive.sample_time_s());
        let m = drive.measured();
        let step = |i: usize| (px[i + 1] - px[i]).hypot(py[i + 1] - py[i]);
        let mean = |f: &dyn Fn(usize) -> f64| (a..b).map(f).sum::<f64>() / (b - a).max(1) as f64;
        let stalled: Vec<usize> = match self {
            Stall::Wheel(_, n) => {
                let moving = mean(&step);
                (a..=b).filter(|&i| wheel_distance(theta0, n, i, ts) < STALL_FRACTION * moving).collect()
            }
            Stall::Reference => {
                let wheels =
                    |i| 0.5 * (wheel_distance(theta0, &m.n_rl, i, ts) + wheel_distance(theta0, &m.n_rr, i, ts));
                let moving = mean(&wheels);
                (a..b).filter(|&i| step(i) < STALL_FRACTION * moving).flat_map(|i| [i, i + 1]).collect()
            }
        };
        match (stalled.iter().min(), stalled.iter().max()) {
            (Some(&first), Some(&last)) => (first, last),
            _ => (a, b),
        }
    }
}

/// Smoothing of a_y and of the reference's v·ω for [`lateral_fit`], s.
const LATERAL_SMOOTHING_S: f64 = 1.0;
/// Least RMS of the reference's smoothed v·ω for [`lateral_fit`] to judge, m/s².
const LATERAL_MIN_RMS_M_PER_S2: f64 = 0.03;
/// Least |correlation| of a_y and v·ω for [`lateral_fit`] to judge.
const LATERAL_MIN_CORRELATION: f64 = 0.3;
/// Most negative slope of a_y on v·ω accepted (a wrong sign gives ≈ −1; a
/// road banked more than its turns need can give a slightly negative one).
const LATERAL_MIN_SLOPE: f64 = -0.15;
/// Largest slope of a_y on v·ω accepted (ft/s² gives ≈ 3.28).
const LATERAL_MAX_SLOPE: f64 = 2.0;

/// The regression of a drive's a_y on the reference's lateral acceleration
/// v·ω (speed and yaw rate from central differences of the pose), both
/// smoothed over [`LATERAL_SMOOTHING_S`] within the parts, over the samples
/// where the reference moves faster than 2 m/s. The canonical convention
/// (m/s², positive to the left) gives a slope near +1; the sideslip's rate,
/// noise and a road bank move it (a banked test track's a_y, the lateral
/// specific force, gives 0.2 … 0.6).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LateralFit {
    /// Slope of a_y on v·ω (centred least squares).
    pub slope: f64,
    /// Pearson correlation of a_y and v·ω.
    pub correlation: f64,
    /// RMS of the centred v·ω, m/s².
    pub rms_m_per_s2: f64,
    /// Samples used.
    pub samples: usize,
}

/// Which way a_y disagrees with the reference.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LateralProblem {
    /// a_y has the opposite sign of v·ω.
    Sign,
    /// a_y is many times v·ω: another unit.
    Scale,
}

impl LateralFit {
    /// What is wrong with the a_y named `what`, with the reason to show;
    /// `None` when the fit cannot judge (too few moving samples, too little
    /// turning, too weak a correlation) or finds the convention right.
    pub(crate) fn problem(&self, what: &str) -> Option<(LateralProblem, String)> {
        let judged = self.samples >= 200
            && self.rms_m_per_s2 >= LATERAL_MIN_RMS_M_PER_S2
            && self.correlation.abs() >= LATERAL_MIN_CORRELATION;
        let stats = format!(
            "slope {:+.3} of a_y on the reference's v·ω over {} moving samples, correlation {:+.2}; the canonical \
             convention, m/s² positive to the left, gives ≈ +1",
            self.slope, self.samples, self.correlation
        );
        if !judged || !self.slope.is_finite() {
            None
        } else if self.slope < LATERAL_MIN_SLOPE {
            Some((
                LateralProblem::Sign,
                format!("the lateral acceleration has the wrong sign ({stats}): negate {what}"),
            ))
        } else if self.slope > LATERAL_MAX_SLOPE {
            Some((
                LateralProblem::Scale,
                format!(
                    "the lateral acceleration is {:.2} × the reference's v·ω ({stats}; ft/s² gives 3.28): convert \
                     {what} to m/s²",
                    self.slope
                ),
            ))
        } else {
            None
        }
    }
}

/// [`LateralFit`] of a drive; `None` when no moving sample has neighbours.
pub(crate) fn lateral_fit(drive: &Drive) -> Option<LateralFit> {
    let ts = drive.sample_time_s();
    let (px, py, psi, a_y) = (drive.px(), drive.py(), drive.psi(), drive.a_y());
    let n = drive.len();
    let (mut x, mut a, mut v) = (vec![0.0; n], a_y.to_vec(), vec![0.0; n]);
    let width = 2 * ((LATERAL_SMOOTHING_S / ts / 2.0).round() as usize) + 1;
    let mut inner = Vec::new();
    for r in drive.parts() {
        if r.len() < 3 {
            continue;
        }
        for i in r.start + 1..r.end - 1 {
            v[i] = (px[i + 1] - px[i - 1]).hypot(py[i + 1] - py[i - 1]) / (2.0 * ts);
            x[i] = v[i] * (psi[i + 1] - psi[i - 1]) / (2.0 * ts);
        }
        let range = r.start + 1..r.end - 1;
        for s in [&mut x, &mut a, &mut v] {
            moving_average(s, range.clone(), width);
        }
        inner.extend(range.filter(|&i| v[i] > 2.0));
    }
    if inner.is_empty() {
        return None;
    }
    let c = inner.len() as f64;
    let (mx, ma) = (inner.iter().map(|&i| x[i]).sum::<f64>() / c, inner.iter().map(|&i| a[i]).sum::<f64>() / c);
    let (mut sxx, mut saa, mut sxa) = (0.0, 0.0, 0.0);
    for &i in &inner {
        let (dx, da) = (x[i] - mx, a[i] - ma);
        sxx += dx * dx;
        saa += da * da;
        sxa += dx * da;
    }
    Some(LateralFit {
        slope: sxa / sxx,
        correlation: sxa / (sxx * saa).sqrt(),
        rms_m_per_s2: (sxx / c).sqrt(),
        samples: inner.len(),
    })
}

/// Centred moving average over `width` samples (odd, ≥ 1) within `range`,
/// truncated at its ends.
pub(crate) fn moving_average(x: &mut [f64], range: std::ops::Range<usize>, width: usize) {
    let half = width / 2;
    if half == 0 || range.len() < 2 {
        return;
    }
    let src: Vec<f64> = x[range.clone()].to_vec();
    let mut pre = vec![0.0; src.len() + 1];
    for (i, v) in src.iter().enumerate() {
        pre[i + 1] = pre[i] + v;
    }
    for i in 0..src.len() {
        let (lo, hi) = (i.saturating_sub(half), (i + half + 1).min(src.len()));
        x[range.start + i] = (pre[hi] - pre[lo]) / (hi - lo) as f64;
    }
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
        crate::drive::DriveBuilder {
            t: (0..n).map(|k| k as f64 * ts).collect(),
            measured: s,
            context: "d".into(),
            ..Default::default()
        }
        .build()
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
            crate::drive::DriveBuilder { t: d.t().to_vec(), measured: s, ..Default::default() }.build().expect("drive")
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
    fn wheels_offset_in_time_from_the_reference_are_named() {
        let sim = crate::sim::simulate(&crate::sim::SimOptions { length_km: 3.0, ..crate::sim::SimOptions::paper(4) })
            .expect("sim");
        let d = &sim.drive;
        let th = Theta::PAPER_INITIAL;
        let shifted = |k: isize| {
            let mut s = d.measured().clone();
            let n = s.n_rl.len() as isize;
            let at = |v: &[f64], i: isize| v[(i - k).clamp(0, n - 1) as usize];
            let (l, r) = (s.n_rl.clone(), s.n_rr.clone());
            s.n_rl = (0..n).map(|i| at(&l, i)).collect();
            s.n_rr = (0..n).map(|i| at(&r, i)).collect();
            crate::drive::DriveBuilder { t: d.t().to_vec(), measured: s, ..Default::default() }.build().expect("drive")
        };
        for k in [-2, 0, 3] {
            check_conventions(&shifted(k), &th, "d").unwrap_or_else(|e| panic!("{k} samples: {e}"));
        }
        let named = |k: isize, who: &str, lag_s: f64| {
            let m = check_conventions(&shifted(k), &th, "d").expect_err("offset clocks").to_string();
            let by = format!("wheel speeds {who} the reference's by ");
            let at = m.find(&by).unwrap_or_else(|| panic!("{m}")) + by.len();
            let v: f64 = m[at..].split(' ').next().and_then(|v| v.parse().ok()).expect("a lag in s");
            assert!((v - lag_s).abs() < 0.02, "{m}");
            assert!(m.contains("clock_offset"), "{m}");
        };
        named(8, "lag", 0.2);
        named(-40, "lead", 1.0);
    }

    /// A θ_0 whose c_e is ten times off (or a tenth) makes the whole drive
    /// look like a stall of the reference (or of the wheels); the message
    /// names the wheel-speed ratio and θ_0's c_e first.
    #[test]
    fn a_c_e_far_off_is_named_before_a_stall() {
        let sim = crate::sim::simulate(&crate::sim::SimOptions { length_km: 3.0, ..crate::sim::SimOptions::paper(1) })
            .expect("sim");
        for (c_e, ratio) in [(20.0, "10.1"), (0.2, "0.10")] {
            let th = Theta { c_e, ..Theta::PAPER_INITIAL };
            assert!(stalled_signal(&sim.drive, (&th, "θ_0"), 0).is_some(), "c_e {c_e} looks like a stall");
            let m = check_conventions(&sim.drive, &th, "d").expect_err("c_e far off").to_string();
            assert!(m.contains(&format!("the wheel speed at θ_0 is {ratio}")), "{m}");
            assert!(m.contains("the c_e of θ_0 far off (check the θ given"), "{m}");
        }
    }

    #[test]
    fn a_signal_that_stalls_while_the_drive_moves_is_named() {
        let sim = crate::sim::simulate(&crate::sim::SimOptions { length_km: 3.0, ..crate::sim::SimOptions::paper(1) })
            .expect("sim");
        let d = &sim.drive;
        let th = Theta::PAPER_INITIAL;
        assert_eq!(stalled_signal(d, (&th, "θ_0"), 0), None);
        let edit = |f: &dyn Fn(&mut Signals)| {
            let mut s = d.measured().clone();
            f(&mut s);
            crate::drive::DriveBuilder { t: d.t().to_vec(), measured: s, ..Default::default() }.build().expect("drive")
        };
        // Both wheels logged as zeros for 100 s of driving (the rest of the
        // drive keeps the median wheel speed right, so no other check sees it).
        let zeros = edit(&|s| s.n_rl[2000..6000].iter_mut().chain(&mut s.n_rr[2000..6000]).for_each(|v| *v = 0.0));
        let m = check_conventions(&zeros, &th, "d").expect_err("wheels at zero").to_string();
        assert!(m.contains("column 'n_rl' reads (almost) no rotation while the reference moves: samples 2000–"), "{m}");
        // One wheel for 3 s.
        let one = edit(&|s| s.n_rr[3000..3120].iter_mut().for_each(|v| *v = 0.0));
        let m = check_conventions(&one, &th, "d").expect_err("one wheel").to_string();
        assert!(m.contains("column 'n_rr'") && m.contains("samples 3000–3119"), "{m}");
        // A wheel at zero for 1 s is not reported (shorter than 2 s).
        let blip = edit(&|s| s.n_rr[3000..3040].iter_mut().for_each(|v| *v = 0.0));
        assert_eq!(stalled_signal(&blip, (&th, "θ_0"), 0), None);
        // A position held for the last 10 s while the wheels turn (held
        // within the drive, it would jump back at its end, which the
        // physical limits refuse).
        let n = d.len();
        let held = edit(&|s| {
            let (x, y) = (s.px[n - 400], s.py[n - 400]);
            s.px[n - 400..].iter_mut().for_each(|v| *v = x);
            s.py[n - 400..].iter_mut().for_each(|v| *v = y);
        });
        let m = check_conventions(&held, &th, "d").expect_err("held").to_string();
        // Within the held samples, where the wheels also turn at 2 m/s or
        // faster (the drive ends slowing down), and for longer than 2 s.
        let range = m.split("turn: samples ").nth(1).and_then(|r| r.split(' ').next()).expect("samples");
        let (a, b) = range.split_once('–').expect("a–b");
        let (a, b): (usize, usize) = (a.parse().expect("a"), b.parse().expect("b"));
        assert!(a >= n - 400 && b < n && b - a >= 80, "{m}");
        // A reference that never moves.
        let frozen = edit(&|s| {
            s.px.iter_mut().for_each(|v| *v = 0.0);
            s.py.iter_mut().for_each(|v| *v = 0.0);
        });
        let m = stalled_signal(&frozen, (&th, "θ_0"), 0).expect("frozen");
        assert!(m.contains("(px, py) stands still"), "{m}");
    }
}
