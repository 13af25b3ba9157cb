//! Signal helpers of the import: de-jittering, interpolation, interval means,
//! smoothing and the clock-offset cross-correlation.

/// Result of de-jittering one stream's time stamps.
#[derive(Debug, Clone)]
pub(crate) struct Dejittered {
    /// The corrected stamps, s (strictly increasing).
    pub t: Vec<f64>,
    /// RMS of the correction (corrected − raw), s.
    pub rms_correction_s: f64,
    /// Largest absolute correction, s.
    pub max_correction_s: f64,
    /// Samples missing from the nominal sequence (skipped indices) inside runs.
    pub missing_samples: u64,
}

/// Removes time-stamp jitter of a stream sampled at a nominal period.
///
/// Runs of samples are split where the stamps jump by more than `max_gap_s`.
/// Within a run each sample gets an integer index `k` (a missing sample skips
/// an index): a tracker predicts the next stamp from the smoothed previous one,
/// so that one late stamp followed by an early one does not skip an index.
/// Each stamp is then replaced by a local least-squares line `t = a + b·k`
/// fitted over the samples within ±`half_window` indices, which follows slow
/// clock drift and removes the jitter. Falls back to the raw stamps of a run
/// when the corrected stamps would not increase strictly.
pub(crate) fn dejitter(t: &[f64], period_s: f64, half_window: usize, max_gap_s: f64) -> Dejittered {
    let n = t.len();
    let mut out = t.to_vec();
    let mut missing = 0u64;
    let mut start = 0;
    while start < n {
        let mut end = start + 1;
        while end < n && t[end] - t[end - 1] <= max_gap_s {
            end += 1;
        }
        // Index assignment with a smoothed tracker (gain 0.1).
        let run = &t[start..end];
        let mut k = vec![0i64; run.len()];
        let mut s = run[0];
        for i in 1..run.len() {
            let m = ((run[i] - s) / period_s).round().max(1.0);
            k[i] = k[i - 1] + m as i64;
            missing += (m as u64).saturating_sub(1);
            s += m * period_s;
            s += 0.1 * (run[i] - s);
        }
        // Local linear fits, centred on each sample's window.
        let fitted: Vec<f64> = (0..run.len())
            .map(|i| {
                let lo = i.saturating_sub(half_window);
                let hi = (i + half_window + 1).min(run.len());
                let cnt = (hi - lo) as f64;
                if hi - lo < 3 {
                    return run[i];
                }
                let (mut mk, mut mt) = (0.0, 0.0);
                for j in lo..hi {
                    mk += k[j] as f64;
                    mt += run[j] - run[i];
                }
                mk /= cnt;
                mt /= cnt;
                let (mut skk, mut skt) = (0.0, 0.0);
                for j in lo..hi {
                    let dk = k[j] as f64 - mk;
                    skk += dk * dk;
                    skt += dk * (run[j] - run[i] - mt);
                }
                if skk <= 0.0 {
                    return run[i];
                }
                let b = skt / skk;
                run[i] + mt + b * (k[i] as f64 - mk)
            })
            .collect();
        if fitted.windows(2).all(|w| w[1] > w[0]) && fitted.iter().all(|v| v.is_finite()) {
            out[start..end].copy_from_slice(&fitted);
        }
        start = end;
    }
    // Joins between runs must stay increasing too.
    if !out.windows(2).all(|w| w[1] > w[0]) {
        out = t.to_vec();
    }
    let (mut ss, mut mx) = (0.0, 0.0f64);
    for (a, b) in out.iter().zip(t) {
        let d = a - b;
        ss += d * d;
        mx = mx.max(d.abs());
    }
    Dejittered {
        t: out,
        rms_correction_s: (ss / n.max(1) as f64).sqrt(),
        max_correction_s: mx,
        missing_samples: missing,
    }
}

/// Linear interpolation of `(ts, ys)` at sorted query times `tq`, clamped at
/// the ends (validity is checked separately).
pub(crate) fn interp_sorted(ts: &[f64], ys: &[f64], tq: &[f64]) -> Vec<f64> {
    let mut j = 0;
    let n = ts.len();
    tq.iter()
        .map(|&q| {
            if n == 0 {
                return f64::NAN;
            }
            if q <= ts[0] {
                return ys[0];
            }
            if q >= ts[n - 1] {
                return ys[n - 1];
            }
            while j + 1 < n && ts[j + 1] < q {
                j += 1;
            }
            let (t0, t1) = (ts[j], ts[j + 1]);
            let w = (q - t0) / (t1 - t0);
            ys[j] + w * (ys[j + 1] - ys[j])
        })
        .collect()
}

/// Cumulative trapezoid integral of `(ts, ys)`, starting at 0.
pub(crate) fn cumulative_integral(ts: &[f64], ys: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(ts.len());
    let mut acc = 0.0;
    for i in 0..ts.len() {
        if i > 0 {
            acc += 0.5 * (ys[i] + ys[i - 1]) * (ts[i] - ts[i - 1]);
        }
        out.push(acc);
    }
    out
}

/// Means over the output intervals `[g_k, g_k + h]` of a signal whose
/// cumulative value (integral, or count) is `cum` at times `ts`.
pub(crate) fn interval_rates(ts: &[f64], cum: &[f64], grid: &[f64], h: f64) -> Vec<f64> {
    let ends: Vec<f64> = grid.iter().map(|g| g + h).collect();
    let a = interp_sorted(ts, cum, grid);
    let b = interp_sorted(ts, cum, &ends);
    a.iter().zip(&b).map(|(a, b)| (b - a) / h).collect()
}

/// The odd number of samples a centred moving average over `span_s` spans
/// at sample interval `h` (1: no smoothing).
pub(crate) fn odd_width(span_s: f64, h: f64) -> usize {
    2 * ((span_s / h / 2.0).round() as usize) + 1
}

/// [`moving_average`] over `span_s` within each of `parts` (smoothing never
/// crosses a part's ends).
pub(crate) fn smooth_parts(x: &mut [f64], parts: &[std::ops::Range<usize>], span_s: f64, h: f64) {
    let width = odd_width(span_s, h);
    for r in parts {
        moving_average(x, r.clone(), width);
    }
}

pub(crate) use crate::drive::plausibility::moving_average;

pub(crate) use crate::drive::correlate::{cross_correlate, Correlation};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn dejitter_recovers_uniform_stamps_with_drops() {
        // 100 Hz, a dropped sample, ±1.5 ms deterministic jitter.
        let mut truth = Vec::new();
        for i in 0..3000 {
            if i != 1234 {
                truth.push(10.0 + i as f64 * 0.010_001);
            }
        }
        let jit: Vec<f64> = truth.iter().enumerate().map(|(i, t)| t + 0.0015 * ((i as f64 * 1.7).sin())).collect();
        let d = dejitter(&jit, 0.01, 100, 0.5);
        assert_eq!(d.missing_samples, 1);
        let worst = d.t.iter().zip(&truth).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
        // The local fit over ±100 samples averages the jitter down to ~0.2 ms.
        assert!(worst < 2e-4, "worst {worst}");
        assert!(d.rms_correction_s > 5e-4);
    }

    #[test]
    fn correlation_finds_sub_sample_offset() {
        let h = 0.025;
        let tau = 0.137;
        let f = |t: f64| (0.3 * t).sin() + 0.5 * (0.71 * t).sin();
        let a: Vec<f64> = (0..4000).map(|k| f(k as f64 * h)).collect();
        let b: Vec<f64> = (0..4000).map(|k| f(k as f64 * h + tau)).collect();
        let c = cross_correlate(&a, &b, h, 80).expect("corr");
        assert!((c.offset_s - tau).abs() < 0.2 * h, "{}", c.offset_s);
    }

    #[test]
    fn interval_rates_of_linear_count() {
        let ts: Vec<f64> = (0..100).map(|i| i as f64 * 0.01).collect();
        let cum: Vec<f64> = ts.iter().map(|t| 3.0 * t).collect();
        let r = interval_rates(&ts, &cum, &[0.1, 0.5], 0.025);
        assert!(r.iter().all(|v| (v - 3.0).abs() < 1e-9), "{r:?}");
    }
}
