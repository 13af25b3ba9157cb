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
        WheelSignal::TicksRaw => {
            let tpr = per_rev(w.ticks_per_rev);
            let bits = w.counter_bits.unwrap_or(32);
            let modulus: i128 = 1i128 << bits;
            let half = modulus / 2;
            let mut acc: i128 = 0;
            let mut out = Vec::with_capacity(col.len());
            out.push(0.0);
            for pair in col.windows(2) {
                let d = ((pair[1] as i128) - (pair[0] as i128)).rem_euclid(modulus);
                acc += if d >= half { d - modulus } else { d };
                out.push(sign * acc as f64 / tpr);
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

/// Both wheels' cumulative rotation on the wheel stream's stamps.
pub(crate) struct Wheels {
    /// Rear-left, rev.
    pub cum_l: Vec<f64>,
    /// Rear-right, rev.
    pub cum_r: Vec<f64>,
}

impl Wheels {
    /// Reads both wheels of the wheel stream `s`.
    pub fn new(m: &Manifest, s: &Stream) -> Result<Wheels> {
        let w = &m.wheels;
        Ok(Wheels {
            cum_l: wheel_revolutions(m, s, &w.rear_left, "wheels.rear_left")?,
            cum_r: wheel_revolutions(m, s, &w.rear_right, "wheels.rear_right")?,
        })
    }
}

/// The wheel speed noise with the raw stamps against the de-jittered ones
/// (`n_rl`, `n_rr`), on the same grid and parts; `None` when the stream was
/// not de-jittered.
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
    let raw_stream = Stream { t: ws.t_raw.clone(), ..ws.clone() };
    let raw = |wheel: &WheelColumn, key: &str| -> Result<Vec<f64>> {
        let cum = wheel_revolutions(m, &raw_stream, wheel, key)?;
        Ok(signal::interval_rates(&raw_stream.t, &cum, grid, h))
    };
    let nl_raw = raw(&w.rear_left, "wheels.rear_left")?;
    let nr_raw = raw(&w.rear_right, "wheels.rear_right")?;
    let both = |a: &[f64], b: &[f64]| {
        let x = speed_noise_pct(a, kept);
        let y = speed_noise_pct(b, kept);
        ((x * x + y * y) / 2.0).sqrt()
    };
    Ok(Some(JitterReport {
        wheel_speed_noise_raw_pct: both(&nl_raw, &nr_raw),
        wheel_speed_noise_dejittered_pct: both(n_rl, n_rr),
    }))
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
    }
}
