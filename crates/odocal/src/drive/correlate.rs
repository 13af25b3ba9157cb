//! Cross-correlation of two sampled signals: the lag between two clocks.

/// The clock offset found by cross-correlation.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Correlation {
    /// Offset τ, s: `a(t) ≈ b(t − τ)`.
    pub offset_s: f64,
    /// Pearson correlation at the integer peak.
    pub peak: f64,
    /// Sample pairs at the peak.
    pub pairs: usize,
    /// Sharpness of the peak: −d²r/dτ² from the peak and its neighbours,
    /// 1/s² (NaN at the edge of the search range).
    pub curvature: f64,
    /// The best other local maximum outside the peak's lobe (where r falls
    /// monotonically from the peak): offset, s, and correlation.
    pub second: Option<(f64, f64)>,
}

/// Finds τ maximizing the Pearson correlation of `a[k]` and `b[k − m]`,
/// `|m| ≤ max_lag`, with sub-sample resolution from a parabola through the
/// peak and its neighbours. NaN entries are skipped. `h` is the sample step.
pub(crate) fn cross_correlate(a: &[f64], b: &[f64], h: f64, max_lag: usize) -> Option<Correlation> {
    let n = a.len().min(b.len());
    let lags: Vec<i64> = (-(max_lag as i64)..=max_lag as i64).collect();
    let r: Vec<(f64, usize)> = lags
        .iter()
        .map(|&m| {
            let (mut sa, mut sb, mut saa, mut sbb, mut sab, mut c) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
            for (k, &x) in a.iter().enumerate().take(n) {
                let j = k as i64 - m;
                if j < 0 || j >= n as i64 {
                    continue;
                }
                let y = b[j as usize];
                if !(x.is_finite() && y.is_finite()) {
                    continue;
                }
                sa += x;
                sb += y;
                saa += x * x;
                sbb += y * y;
                sab += x * y;
                c += 1;
            }
            if c < 10 {
                return (f64::NAN, c);
            }
            let cf = c as f64;
            let cov = sab - sa * sb / cf;
            let va = saa - sa * sa / cf;
            let vb = sbb - sb * sb / cf;
            // A variance at rounding level is a constant signal: nothing to correlate.
            if va <= 1e-12 * saa || vb <= 1e-12 * sbb {
                return (f64::NAN, c);
            }
            (cov / (va * vb).sqrt(), c)
        })
        .collect();
    let (best, _) = r.iter().enumerate().filter(|(_, v)| v.0.is_finite()).max_by(|x, y| x.1 .0.total_cmp(&y.1 .0))?;
    let mut frac = 0.0;
    if best > 0 && best + 1 < r.len() {
        let (y0, y1, y2) = (r[best - 1].0, r[best].0, r[best + 1].0);
        let den = y0 - 2.0 * y1 + y2;
        if y0.is_finite() && y2.is_finite() && den < 0.0 {
            frac = (0.5 * (y0 - y2) / den).clamp(-0.5, 0.5);
        }
    }
    let mut curvature = f64::NAN;
    if best > 0 && best + 1 < r.len() {
        curvature = -(r[best - 1].0 - 2.0 * r[best].0 + r[best + 1].0) / (h * h);
    }
    // The main lobe: r falls monotonically on both sides of the peak.
    let (mut lo, mut hi) = (best, best);
    while lo > 0 && r[lo - 1].0.is_finite() && r[lo - 1].0 <= r[lo].0 {
        lo -= 1;
    }
    while hi + 1 < r.len() && r[hi + 1].0.is_finite() && r[hi + 1].0 <= r[hi].0 {
        hi += 1;
    }
    let second = (0..r.len())
        .filter(|&i| i < lo || i > hi)
        .filter(|&i| r[i].0.is_finite())
        .filter(|&i| {
            (i == 0 || r[i - 1].0 <= r[i].0 || r[i - 1].0.is_nan())
                && (i + 1 == r.len() || r[i + 1].0 <= r[i].0 || r[i + 1].0.is_nan())
        })
        .max_by(|&a, &b| r[a].0.total_cmp(&r[b].0))
        .map(|i| (lags[i] as f64 * h, r[i].0));
    Some(Correlation { offset_s: (lags[best] as f64 + frac) * h, peak: r[best].0, pairs: r[best].1, curvature, second })
}
