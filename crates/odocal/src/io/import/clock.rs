//! Clock alignment: the offset τ between the pose and the wheel clocks
//! (pose time + τ = wheel time), estimated by cross-correlating the wheel
//! speed at θ_0 with the speed differenced from the pose, and the yaw rates
//! as a cross-check.

use super::grid::{mark, BadInterval};
use super::manifest::{ClockOffset, Manifest};
use super::pose::Pose;
use super::report::ClockOffsetReport;
use super::signal::{self, Correlation};
use crate::error::Result;

use crate::model::{kinematics, Input, Kinematics, Theta};

/// The wheel stream as the clock estimate needs it.
pub(crate) struct WheelTrack<'a> {
    /// Stamps, s.
    pub t: &'a [f64],
    /// Cumulative rotation of the rear-left wheel, rev.
    pub cum_l: &'a [f64],
    /// Cumulative rotation of the rear-right wheel, rev.
    pub cum_r: &'a [f64],
    /// Wheel gaps.
    pub bad: &'a [BadInterval],
}

/// The speed and yaw-rate cross-correlations over ±`range_s`, on a grid of
/// step `h` over the wheel stream's span.
pub(crate) fn estimate(
    w: &WheelTrack<'_>,
    pose: &Pose,
    h: f64,
    theta0: &Theta,
    range_s: f64,
) -> (Option<Correlation>, Option<Correlation>) {
    let n_grid = ((w.t[w.t.len() - 1] - w.t[0]) / h).floor() as usize;
    super::limits::note_grid(n_grid);
    let grid: Vec<f64> = (0..n_grid).map(|k| w.t[0] + k as f64 * h).collect();
    let mut valid: Vec<Option<String>> = vec![None; grid.len()];
    mark(&mut valid, w.t[0], h, w.bad, true);
    let nl = signal::interval_rates(w.t, w.cum_l, &grid, h);
    let nr = signal::interval_rates(w.t, w.cum_r, &grid, h);
    let kin: Vec<Option<Kinematics>> = (0..grid.len())
        .map(|k| {
            valid[k].is_none().then(|| kinematics(&Input { n_rl: nl[k], n_rr: nr[k], beta: 0.0, a_y: 0.0 }, theta0))
        })
        .collect();
    let vw: Vec<f64> = kin.iter().map(|k| k.map_or(f64::NAN, |k| k.speed_m_per_s)).collect();
    let ww: Vec<f64> = kin.iter().map(|k| k.map_or(f64::NAN, |k| k.yaw_rate_rad_per_s)).collect();
    let mut tm = Vec::new();
    let mut vp = Vec::new();
    let mut wp = Vec::new();
    for j in 0..pose.t.len() - 1 {
        let (t0, t1) = (pose.t[j], pose.t[j + 1]);
        let bad = pose.bad.iter().any(|b| b.from < t1 && b.to > t0);
        tm.push(0.5 * (t0 + t1));
        let dt = t1 - t0;
        vp.push(if bad { f64::NAN } else { (pose.x[j + 1] - pose.x[j]).hypot(pose.y[j + 1] - pose.y[j]) / dt });
        wp.push(if bad { f64::NAN } else { (pose.psi[j + 1] - pose.psi[j]) / dt });
    }
    let centres: Vec<f64> = grid.iter().map(|g| g + 0.5 * h).collect();
    let on_grid = |y: &[f64]| {
        let mut v = signal::interp_sorted(&tm, y, &centres);
        for (v, c) in v.iter_mut().zip(&centres) {
            if tm.is_empty() || *c < tm[0] || *c > tm[tm.len() - 1] {
                *v = f64::NAN;
            }
        }
        v
    };
    let max_lag = (range_s / h).ceil() as usize;
    (signal::cross_correlate(&vw, &on_grid(&vp), h, max_lag), signal::cross_correlate(&ww, &on_grid(&wp), h, max_lag))
}

/// Lowest speed correlation at which `"auto"` applies its estimate (the
/// shipped examples' applied estimates reach 0.994 or more).
pub(super) const MIN_CLOCK_CORRELATION: f64 = 0.9;
/// Widest peak uncertainty (the ± of the peak's sharpness,
/// [`ClockOffsetReport::uncertainty_s`]) at which `"auto"` applies its
/// estimate, s (the shipped examples' applied estimates have ± 0.65 s or
/// less).
pub(super) const MAX_CLOCK_UNCERTAINTY_S: f64 = 1.0;
/// A second correlation peak within this of the best makes the estimate
/// ambiguous.
pub(super) const MIN_PEAK_MARGIN: f64 = 0.02;
/// The yaw-rate cross-check counts when its correlation reaches this.
pub(super) const MIN_YAW_CHECK_CORRELATION: f64 = 0.8;

/// Why the speed estimate is not clearly better than the manifest's offset
/// (the streams' `time_offset_s` alone), or `None` when it is: the speed
/// correlation is below [`MIN_CLOCK_CORRELATION`], its peak uncertainty is
/// wider than [`MAX_CLOCK_UNCERTAINTY_S`], a second peak comes within
/// [`MIN_PEAK_MARGIN`] of it, or the yaw-rate cross-check (when its
/// correlation reaches [`MIN_YAW_CHECK_CORRELATION`]) disagrees by more
/// than one output sample `h`.
pub(crate) fn doubt(est: Option<Correlation>, yaw: Option<Correlation>, h: f64) -> Option<String> {
    doubt_with(est, yaw, h, MIN_CLOCK_CORRELATION, MAX_CLOCK_UNCERTAINTY_S)
}

/// Lowest speed correlation at which an estimate at the edge of its search
/// is searched again over a wider range ([`searched`]); the wider
/// estimate must pass [`doubt`].
const MIN_EDGE_CORRELATION: f64 = 0.5;

/// [`doubt`] with the correlation floor `min_corr` and the widest peak
/// uncertainty `max_uncertainty_s`.
fn doubt_with(
    est: Option<Correlation>,
    yaw: Option<Correlation>,
    h: f64,
    min_corr: f64,
    max_uncertainty_s: f64,
) -> Option<String> {
    let Some(c) = est else {
        return Some("no moving wheel and pose data overlap within ±max_clock_offset_s".into());
    };
    if c.peak.is_nan() || c.peak < min_corr {
        return Some(format!("the speed correlation {:.3} is below {min_corr}", c.peak));
    }
    if let Some(u) = uncertainty_s(&c).filter(|u| *u > max_uncertainty_s) {
        return Some(format!("the correlation peak is too flat: ± {u:.3} s is wider than {max_uncertainty_s} s"));
    }
    if let Some((t2, r2)) = c.second {
        if r2 >= c.peak - MIN_PEAK_MARGIN {
            return Some(format!(
                "a second correlation peak at {t2:+.3} s ({r2:.4}) is within {MIN_PEAK_MARGIN} of the best ({:.4})",
                c.peak
            ));
        }
    }
    if let Some(y) = yaw {
        if y.peak >= MIN_YAW_CHECK_CORRELATION && (y.offset_s - c.offset_s).abs() > h {
            return Some(format!(
                "the yaw-rate cross-check gives {:+.4} s (correlation {:.3}), more than one sample from {:+.4} s",
                y.offset_s, y.peak, c.offset_s
            ));
        }
    }
    None
}

/// Estimates the offset, decides which offset to apply (for `"auto"`, the
/// estimate unless [`doubt`] finds it not clearly better than the
/// manifest's, then 0 s on top of the streams' `time_offset_s`, with a
/// warning; a number is applied as given), and reports both. A number's
/// estimate, only reported, is skipped (the report says why) when its
/// search would exceed the correlation budget. An `"auto"`
/// estimate at the edge of its search ([`searched`]) is searched again over
/// a wider range, once, and refused when it stays at the edge.
pub(crate) fn align(
    m: &Manifest,
    w: &WheelTrack<'_>,
    pose: &Pose,
    h: f64,
    theta0: &Theta,
    warnings: &mut Vec<String>,
) -> Result<ClockOffsetReport> {
    let o = &m.output;
    let grid_samples = ((w.t[w.t.len() - 1] - w.t[0]) / h).floor().max(0.0) as usize;
    let work = super::limits::correlation_work(o.max_clock_offset_s, o.rate_hz, grid_samples);
    let fixed_over_budget =
        matches!(o.clock_offset, ClockOffset::Seconds(_)) && work > super::limits::MAX_CORRELATION_WORK;
    let (est, est_yaw) = match o.clock_offset {
        ClockOffset::Auto => searched(m, w, pose, h, theta0, warnings)?,
        ClockOffset::Seconds(_) if fixed_over_budget => (None, None),
        ClockOffset::Seconds(_) => estimate(w, pose, h, theta0, o.max_clock_offset_s),
    };
    let not_estimated = fixed_over_budget.then(|| {
        format!(
            "searching ±{} s at {} Hz over {grid_samples} samples would take {work:.2e} multiply-adds, above the \
             budget of {:e}; lower output.max_clock_offset_s to have the offset estimated",
            o.max_clock_offset_s,
            o.rate_hz,
            super::limits::MAX_CORRELATION_WORK
        )
    });
    let doubt = (!fixed_over_budget).then(|| doubt(est, est_yaw, h)).flatten();
    let applied = match (o.clock_offset, &doubt) {
        (ClockOffset::Seconds(v), _) => v,
        (ClockOffset::Auto, None) => est.map_or(0.0, |c| c.offset_s),
        (ClockOffset::Auto, Some(why)) => {
            warnings.push(format!(
                "output.clock_offset = \"auto\": the estimate is not clearly better than the manifest's offset \
                 ({why}); kept the streams' time_offset_s (0 s added). Give output.clock_offset in seconds to \
                 fix it"
            ));
            0.0
        }
    };
    Ok(ClockOffsetReport {
        estimated_s: est.map(|c| c.offset_s),
        correlation: est.map(|c| c.peak),
        correlation_pairs: est.map(|c| c.pairs),
        peak_curvature_per_s2: est.map(|c| c.curvature).filter(|v| v.is_finite()),
        uncertainty_s: est.as_ref().and_then(uncertainty_s),
        second_peak_s: est.and_then(|c| c.second).map(|s| s.0),
        second_peak_correlation: est.and_then(|c| c.second).map(|s| s.1),
        yaw_rate_estimate_s: est_yaw.map(|c| c.offset_s),
        yaw_rate_correlation: est_yaw.map(|c| c.peak),
        applied_s: applied,
        doubt,
        not_estimated,
        mode: match o.clock_offset {
            ClockOffset::Auto => "auto".into(),
            ClockOffset::Seconds(_) => "fixed".into(),
        },
    })
}

/// Half-width of the offsets the peak of `c` cannot tell apart from its
/// top, `sqrt(2·(1 − r)/curvature)`, s, when finite.
fn uncertainty_s(c: &Correlation) -> Option<f64> {
    Some((2.0 * (1.0 - c.peak) / c.curvature).sqrt()).filter(|v| v.is_finite())
}

/// The widened search range for an estimate at the edge of the manifest's:
/// this many times it, at least [`WIDE_CLOCK_OFFSET_S`], at most the limit.
const WIDEN_FACTOR: f64 = 5.0;
/// Least widened search range, ± s.
const WIDE_CLOCK_OFFSET_S: f64 = 10.0;

/// Whether an estimate lies at the edge of the search over ±`range_s`
/// (within 5 % of the range or two samples `h`, whichever is more): the
/// correlation still rises beyond it, so the offset was not found.
fn at_edge(c: &Correlation, range_s: f64, h: f64) -> bool {
    c.offset_s.abs() >= range_s - (0.05 * range_s).max(2.0 * h)
}

/// The `"auto"` estimate: over ±`max_clock_offset_s`; when that one lies
/// [`at_edge`] with a speed correlation of [`MIN_EDGE_CORRELATION`] or more
/// and no other doubt, once more over the widened range (a
/// warning says so), and an error naming `output.clock_offset` when the
/// widened estimate is at its edge too or not clear.
fn searched(
    m: &Manifest,
    w: &WheelTrack<'_>,
    pose: &Pose,
    h: f64,
    theta0: &Theta,
    warnings: &mut Vec<String>,
) -> Result<(Option<Correlation>, Option<Correlation>)> {
    let range = m.output.max_clock_offset_s;
    let first = estimate(w, pose, h, theta0, range);
    let edge = match first.0 {
        Some(c)
            if doubt_with(first.0, first.1, h, MIN_EDGE_CORRELATION, f64::INFINITY).is_none()
                && at_edge(&c, range, h) =>
        {
            c.offset_s
        }
        _ => return Ok(first),
    };
    let wide = (WIDEN_FACTOR * range).clamp(WIDE_CLOCK_OFFSET_S, super::limits::MAX_CLOCK_OFFSET_S);
    let grid_samples = ((w.t[w.t.len() - 1] - w.t[0]) / h).floor().max(0.0) as usize;
    let fits = wide > range
        && super::limits::correlation_work(wide, m.output.rate_hz, grid_samples) <= super::limits::MAX_CORRELATION_WORK;
    let second = if fits { estimate(w, pose, h, theta0, wide) } else { (None, None) };
    let searched_s = if fits { wide } else { range };
    let found = second.0.filter(|c| doubt(second.0, second.1, h).is_none() && !at_edge(c, wide, h));
    let Some(c) = found else {
        let why = match second.0 {
            _ if !fits => "a wider search is beyond the search limits".to_string(),
            Some(c) if at_edge(&c, wide, h) => format!("it is {:+.4} s, at the edge again", c.offset_s),
            Some(_) => doubt(second.0, second.1, h).unwrap_or_default(),
            None => "no moving wheel and pose data overlap".to_string(),
        };
        return Err(m.error(
            "output.clock_offset",
            format!(
                "\"auto\" found no clock offset: the estimate {edge:+.4} s lies at the edge of the search \
                 (output.max_clock_offset_s = {range} s), and searching ±{searched_s} s did not find it ({why}). \
                 Set output.clock_offset to the offset in seconds (pose time + offset = wheel time), or correct \
                 the streams' time_offset_s"
            ),
        ));
    };
    warnings.push(format!(
        "output.clock_offset = \"auto\": the estimate {edge:+.4} s lay at the edge of the search (±{range} s), so \
         ±{wide} s was searched: {:+.4} s (correlation {:.4}) is applied. Set output.max_clock_offset_s above it, \
         or output.clock_offset in seconds, to say so in the manifest",
        c.offset_s, c.peak
    ));
    Ok(second)
}
