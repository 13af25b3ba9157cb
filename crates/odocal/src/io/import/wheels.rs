//! Wheel rotation: ticks, counters and speeds to a cumulative rotation per
//! wheel, its output speeds, and what de-jittering did to them.

use std::ops::Range;

use super::manifest::{Manifest, WheelColumn, WheelSignal};
use super::report::JitterReport;
use super::signal;
use super::source::Stream;
use crate::error::Result;

/// Cumulative rotation (revolutions, forward positive) of one wheel.
pub(crate) fn wheel_revolutions(m: &Manifest, s: &Stream, wheel: &WheelColumn, key: &str) -> Result<Vec<f64>> {
    let w = &m.wheels;
    let col = s.col(&wheel.column);
    if let Some(i) = col.iter().position(|v| !v.is_finite()) {
        return Err(s.error_at(i, Some(&wheel.column), format!("value is not finite ({key})")));
    }
    let sign = wheel.sign;
    let per_rev = |v: Option<f64>| v.unwrap_or(1.0);
    Ok(match w.signal {
        WheelSignal::RevPerS => signal::cumulative_integral(&s.t, &col.iter().map(|v| sign * v).collect::<Vec<_>>()),
        WheelSignal::RadPerS => {
            signal::cumulative_integral(&s.t, &col.iter().map(|v| sign * v / std::f64::consts::TAU).collect::<Vec<_>>())
        }
        WheelSignal::MPerS => {
            let c = per_rev(w.circumference_m);
            signal::cumulative_integral(&s.t, &col.iter().map(|v| sign * v / c).collect::<Vec<_>>())
        }
        WheelSignal::TicksCumulative => {
            let tpr = per_rev(w.ticks_per_rev);
            col.iter().map(|v| sign * (v - col[0]) / tpr).collect()
        }
        WheelSignal::RadCumulative => col.iter().map(|v| sign * (v - col[0]) / std::f64::consts::TAU).collect(),
        WheelSignal::TicksRaw => {
            let tpr = per_rev(w.ticks_per_rev);
            let bits = w.counter_bits.unwrap_or(32);
            let modulus: i128 = 1i128 << bits;
            let half = modulus / 2;
            let mut acc: i128 = 0;
            let mut out = Vec::with_capacity(col.len());
            out.push(0.0);
            let mut wide = 0usize;
            for pair in col.windows(2) {
                let d = ((pair[1] as i128) - (pair[0] as i128)).rem_euclid(modulus);
                let d = if d >= half { d - modulus } else { d };
                wide += usize::from(d.abs() > half / 2);
                acc += d;
                out.push(sign * acc as f64 / tpr);
            }
            // A counter sampled often enough moves far less than a quarter
            // of its range per sample; steps spread over the whole range
            // mean the counter is wider than counter_bits (aliasing).
            if col.len() > 10 && wide as f64 > MAX_WIDE_STEP_FRACTION * (col.len() - 1) as f64 {
                return Err(m.error(
                    "wheels.counter_bits",
                    format!(
                        "{bits}: {wide} of {} steps of column '{}' in {} are above a quarter of the {bits}-bit \
                         range, so the counter wraps between samples or is wider; set counter_bits to the \
                         counter's width (e.g. 32)",
                        col.len() - 1,
                        wheel.column,
                        s.path.display()
                    ),
                ));
            }
            out
        }
    })
}

/// Noise of wheel speeds from second differences (see [`JitterReport`]).
pub(crate) fn speed_noise_pct(n: &[f64], parts: &[std::ops::Range<usize>]) -> f64 {
    let (mut s2, mut sn, mut c) = (0.0, 0.0, 0usize);
    for r in parts {
        for k in r.start + 1..r.end.saturating_sub(1) {
            if n[k].abs() > 1.0 {
                let d2 = n[k + 1] - 2.0 * n[k] + n[k - 1];
                s2 += d2 * d2 / 6.0;
                sn += n[k] * n[k];
                c += 1;
            }
        }
    }
    if c == 0 {
        return f64::NAN;
    }
    100.0 * (s2 / sn).sqrt()
}

/// Largest fraction of counter steps above a quarter of the counter range
/// for a `ticks_raw` counter of the declared width.
const MAX_WIDE_STEP_FRACTION: f64 = 0.05;

/// Rows a corrupt counter value may span (a jump out and back).
pub(super) const MAX_CORRUPT_ROWS: usize = 5;
/// Stamp slack of the corrupt-row test, s: a jump is impossible when it
/// needs more than `limits.max_speed_m_per_s` over the stamp difference
/// plus this.
pub(super) const CORRUPT_SLACK_S: f64 = 0.05;

/// Both wheels' cumulative rotation on the wheel stream's stamps, corrupt
/// rows removed (the stream itself stays in the import's map of streams,
/// replaced by its rows without the corrupt ones when there were some).
pub(crate) struct Wheels {
    /// Rear-left, rev.
    pub cum_l: Vec<f64>,
    /// Rear-right, rev.
    pub cum_r: Vec<f64>,
}

impl Wheels {
    /// Reads both wheels of the wheel stream `s` and drops its corrupt
    /// rows: a row whose count jumps further than the vehicle can drive
    /// (`limits.max_speed_m_per_s` at θ_0) and whose following rows, within
    /// [`MAX_CORRUPT_ROWS`], return to a reachable count (e.g. a counter
    /// read as 0 for one sample). Such a row, kept, makes two output wheel
    /// speeds of ± thousands of rev/s. A jump that does not return is left
    /// for the speed check to report. Returns the wheels and, when rows
    /// were dropped, the stream without them (which replaces `s`); the
    /// stream is not copied otherwise: a 1 kHz wheel log is most of an
    /// import's memory.
    pub(super) fn new(m: &Manifest, s: &Stream, warnings: &mut Vec<String>) -> Result<(Wheels, Option<Stream>)> {
        let w = &m.wheels;
        speed_glitches(m, s, warnings);
        let cum_l = wheel_revolutions(m, s, &w.rear_left, "wheels.rear_left")?;
        let cum_r = wheel_revolutions(m, s, &w.rear_right, "wheels.rear_right")?;
        let keep = corrupt_rows(m, &s.t, &cum_l, &cum_r);
        let dropped: Vec<usize> = (0..keep.len()).filter(|&i| !keep[i]).collect();
        if dropped.is_empty() {
            return Ok((Wheels { cum_l, cum_r }, None));
        }
        let at: Vec<String> =
            dropped.iter().take(3).map(|&i| format!("{} (t = {:.3} s)", s.row_label(i), s.t[i])).collect();
        warnings.push(format!(
            "streams.{}: {} corrupt wheel row(s) dropped (a count jump beyond limits.max_speed_m_per_s that \
             returns), at {}{}",
            w.stream,
            dropped.len(),
            at.join(", "),
            if dropped.len() > 3 { ", …" } else { "" }
        ));
        let mut stream = s.without_rows(&keep);
        stream.report.corrupt_rows_dropped = dropped.len();
        let cum_l = wheel_revolutions(m, &stream, &w.rear_left, "wheels.rear_left")?;
        let cum_r = wheel_revolutions(m, &stream, &w.rear_right, "wheels.rear_right")?;
        Ok((Wheels { cum_l, cum_r }, Some(stream)))
    }
}

/// Most a rear wheel's speed can differ from the other's, m/s: the track
/// (1.6 m) times the yaw rate, which the steering (a turn radius of 4 m
/// or more) and the grip (15 m/s²) hold to about 3 m/s.
pub(super) const MAX_WHEEL_SPEED_DIFFERENCE_M_PER_S: f64 = 10.0;

/// A wheel stream of speeds (`rev_per_s`, `rad_per_s`, `m_per_s`) with a
/// row where a wheel's speed at θ_0 is impossible (above
/// `limits.max_speed_m_per_s`, or more than
/// [`MAX_WHEEL_SPEED_DIFFERENCE_M_PER_S`] from the other wheel's) gets a
/// warning naming the first such row: a one-sample glitch averages out
/// below the output speed check, but the calibration still fits it.
fn speed_glitches(m: &Manifest, s: &Stream, warnings: &mut Vec<String>) {
    let w = &m.wheels;
    let c_e = m.output.theta0[0];
    let per_rev = match w.signal {
        WheelSignal::RevPerS => 1.0,
        WheelSignal::RadPerS => std::f64::consts::TAU,
        WheelSignal::MPerS => w.circumference_m.unwrap_or(1.0),
        _ => return,
    };
    let speed = |wheel: &WheelColumn| -> Vec<f64> {
        s.col(&wheel.column).iter().map(|v| wheel.sign * v / per_rev * c_e).collect()
    };
    let (l, r) = (speed(&w.rear_left), speed(&w.rear_right));
    let vmax = m.limits.max_speed_m_per_s;
    let bad =
        |i: usize| l[i].abs() > vmax || r[i].abs() > vmax || (l[i] - r[i]).abs() > MAX_WHEEL_SPEED_DIFFERENCE_M_PER_S;
    let rows: Vec<usize> = (0..l.len().min(r.len())).filter(|&i| bad(i)).collect();
    let Some(&i) = rows.first() else { return };
    let at = s.row_label(i);
    warnings.push(format!(
        "streams.{}: {} row(s) of {} hold an impossible wheel speed, first {at} (t = {:.3} s): rear_left ('{}') \
         {:.2} m/s, rear_right ('{}') {:.2} m/s at θ_0, above limits.max_speed_m_per_s = {vmax} or more than \
         {MAX_WHEEL_SPEED_DIFFERENCE_M_PER_S} m/s apart: a glitch the calibration would fit; fix or drop the row(s)",
        w.stream,
        rows.len(),
        s.path.display(),
        s.t[i],
        w.rear_left.column,
        l[i],
        w.rear_right.column,
        r[i]
    ));
}

/// `keep[i]` false for the corrupt rows (see [`Wheels::new`]).
fn corrupt_rows(m: &Manifest, t: &[f64], cum_l: &[f64], cum_r: &[f64]) -> Vec<bool> {
    let n = t.len();
    let c_e = m.output.theta0[0];
    let vmax = m.limits.max_speed_m_per_s;
    let reachable = |a: usize, b: usize| {
        let d = vmax * ((t[b] - t[a]).abs() + CORRUPT_SLACK_S);
        (cum_l[b] - cum_l[a]).abs() * c_e <= d && (cum_r[b] - cum_r[a]).abs() * c_e <= d
    };
    let mut keep = vec![true; n];
    if n < 3 {
        return keep;
    }
    let (mut a, mut i) = (0, 1);
    if !reachable(0, 1) && reachable(1, 2) {
        keep[0] = false;
        (a, i) = (1, 2);
    }
    while i < n {
        if reachable(a, i) {
            a = i;
            i += 1;
            continue;
        }
        match (i + 1..(i + 1 + MAX_CORRUPT_ROWS).min(n)).find(|&j| reachable(a, j)) {
            Some(j) => {
                keep[i..j].iter_mut().for_each(|k| *k = false);
                a = j;
                i = j + 1;
            }
            None => {
                a = i;
                i += 1;
            }
        }
    }
    keep
}

/// The wheel speed noise with the raw stamps against the de-jittered ones
/// (`n_rl`, `n_rr`), on the same grid and parts; `None` when the stream was
/// not de-jittered. A noise that cannot be computed (no wheel faster than
/// 1 rev/s) is an error naming the stream.
pub(crate) fn jitter_report(
    m: &Manifest,
    ws: &Stream,
    grid: &[f64],
    h: f64,
    kept: &[Range<usize>],
    n_rl: &[f64],
    n_rr: &[f64],
) -> Result<Option<JitterReport>> {
    if ws.report.dejitter.is_none() {
        return Ok(None);
    }
    let w = &m.wheels;
    // The wheel columns on the raw stamps (only those: the stream may hold
    // other columns, e.g. an IMU's).
    let wheel_cols = [&w.rear_left.column, &w.rear_right.column];
    let raw_stream = Stream {
        path: ws.path.clone(),
        t: ws.t_raw.clone(),
        t_raw: Vec::new(),
        cols: ws.cols.iter().filter(|(c, _)| wheel_cols.contains(c)).map(|(c, v)| (c.clone(), v.clone())).collect(),
        lines: ws.lines.clone(),
        report: ws.report.clone(),
    };
    let raw = |wheel: &WheelColumn, key: &str| -> Result<Vec<f64>> {
        let cum = wheel_revolutions(m, &raw_stream, wheel, key)?;
        Ok(signal::interval_rates(&raw_stream.t, &cum, grid, h))
    };
    let nl_raw = raw(&w.rear_left, "wheels.rear_left")?;
    let nr_raw = raw(&w.rear_right, "wheels.rear_right")?;
    let noise = |n: &[f64]| speed_noise_pct(n, kept);
    jitter_of(m, [noise(&nl_raw), noise(&nr_raw)], [noise(n_rl), noise(n_rr)]).map(Some)
}

/// The jitter report from each wheel's speed noise (per cent, left and
/// right) with the raw and the de-jittered stamps.
pub(crate) fn jitter_of(m: &Manifest, raw: [f64; 2], dejittered: [f64; 2]) -> Result<JitterReport> {
    let w = &m.wheels;
    let both = |[x, y]: [f64; 2]| ((x * x + y * y) / 2.0).sqrt();
    let r = JitterReport { wheel_speed_noise_raw_pct: both(raw), wheel_speed_noise_dejittered_pct: both(dejittered) };
    if !(r.wheel_speed_noise_raw_pct.is_finite() && r.wheel_speed_noise_dejittered_pct.is_finite()) {
        return Err(m.error(
            &format!("streams.{}", w.stream),
            "the wheel speed noise is not finite: no wheel turns faster than 1 rev/s in the kept parts; check \
             wheels.signal, ticks_per_rev and counter_bits",
        ));
    }
    Ok(r)
}

/// What one model "revolution" is, i.e. how to read c_e.
pub(crate) fn wheel_scale(m: &Manifest) -> String {
    let w = &m.wheels;
    match w.signal {
        WheelSignal::TicksCumulative | WheelSignal::TicksRaw => format!(
            "ticks, one model revolution = ticks_per_rev = {} ticks: c_e is metres per {} ticks (t_r, c_d in m)",
            w.ticks_per_rev.unwrap_or(1.0),
            w.ticks_per_rev.unwrap_or(1.0)
        ),
        WheelSignal::MPerS => format!(
            "m/s divided by the nominal circumference {} m: c_e is metres per nominal revolution, c_e / {} is \
             the scale factor of the recorded speed",
            w.circumference_m.unwrap_or(1.0),
            w.circumference_m.unwrap_or(1.0)
        ),
        WheelSignal::RevPerS => "rev/s: c_e is the effective circumference, m".into(),
        WheelSignal::RadPerS => "rad/s / 2π: c_e is the effective circumference, m".into(),
        WheelSignal::RadCumulative => "rad / 2π: c_e is the effective circumference, m".into(),
    }
}
