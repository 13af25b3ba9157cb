//! Cross-correlation of two sampled signals: the lag between two clocks.

use rayon::prelude::*;

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

/// A signal with its non-finite samples set to 0 and a weight of 1 for a
/// finite sample, 0 for one that is not: the sums over pairs then need no
/// branch, and a pair with a non-finite side adds exact zeros, so they
/// equal the sums over the finite pairs alone to the bit.
struct Finite {
    value: Vec<f64>,
    weight: Vec<f64>,
}

impl Finite {
    fn of(x: &[f64]) -> Finite {
        let value = x.iter().map(|&v| if v.is_finite() { v } else { 0.0 }).collect();
        let weight = x.iter().map(|&v| if v.is_finite() { 1.0 } else { 0.0 }).collect();
        Finite { value, weight }
    }
}

/// The Pearson correlation of `a[k]` and `b[k − m]` over the pairs where
/// both are finite, and their number; NaN for fewer than 10 pairs or a
/// constant signal.
fn pearson_at_lag(a: &Finite, b: &Finite, m: i64) -> (f64, usize) {
    let n = a.value.len() as i64;
    // The pairs: k in lo..hi, so that k − m is in 0..n.
    let (lo, hi) = (m.clamp(0, n), (n + m).clamp(0, n));
    if hi <= lo {
        return (f64::NAN, 0);
    }
    let (lo, hi, j0, j1) = (lo as usize, hi as usize, (lo - m) as usize, (hi - m) as usize);
    let (mut sa, mut sb, mut saa, mut sbb, mut sab, mut c) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    let pairs = a.value[lo..hi].iter().zip(&a.weight[lo..hi]).zip(b.value[j0..j1].iter().zip(&b.weight[j0..j1]));
    for ((&x, &wx), (&y, &wy)) in pairs {
        let w = wx * wy;
        sa += w * x;
        sb += w * y;
        saa += w * x * x;
        sbb += w * y * y;
        sab += x * y;
        c += w;
    }
    let c = c as usize;
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
}

/// Finds τ maximizing the Pearson correlation of `a[k]` and `b[k − m]`,
/// `|m| ≤ max_lag`, with sub-sample resolution from a parabola through the
/// peak and its neighbours. NaN entries are skipped. `h` is the sample step.
pub(crate) fn cross_correlate(a: &[f64], b: &[f64], h: f64, max_lag: usize) -> Option<Correlation> {
    let n = a.len().min(b.len());
    let lags: Vec<i64> = (-(max_lag as i64)..=max_lag as i64).collect();
    let (a, b) = (Finite::of(&a[..n]), Finite::of(&b[..n]));
    // Each lag's sums run in sample order whatever the thread count.
    let r: Vec<(f64, usize)> = lags.par_iter().map(|&m| pearson_at_lag(&a, &b, m)).collect();
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

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The sums of one lag as a loop over every k that skips the pairs
    /// with a non-finite side.
    fn pearson_skipping(a: &[f64], b: &[f64], m: i64) -> (f64, usize) {
        let n = a.len().min(b.len());
        let (mut sa, mut sb, mut saa, mut sbb, mut sab, mut c) = (0.0, 0.0, 0.0, 0.0, 0.0, 0usize);
        for (k, &x) in a.iter().enumerate().take(n) {
            let j = k as i64 - m;
            if j < 0 || j >= n as i64 || !(x.is_finite() && b[j as usize].is_finite()) {
                continue;
            }
            let y = b[j as usize];
            (sa, sb, saa, sbb, sab, c) = (sa + x, sb + y, saa + x * x, sbb + y * y, sab + x * y, c + 1);
        }
        if c < 10 {
            return (f64::NAN, c);
        }
        let cf = c as f64;
        let (cov, va, vb) = (sab - sa * sb / cf, saa - sa * sa / cf, sbb - sb * sb / cf);
        if va <= 1e-12 * saa || vb <= 1e-12 * sbb {
            return (f64::NAN, c);
        }
        (cov / (va * vb).sqrt(), c)
    }

    /// The branch-free sums equal the skipping loop's to the bit, with
    /// NaN and infinite samples on either side, at every lag including
    /// lags longer than the signals.
    #[test]
    fn branch_free_sums_equal_the_skipping_loop_to_the_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for n in [0usize, 5, 12, 300] {
            let mut sample = |shift: f64| -> Vec<f64> {
                (0..n)
                    .map(|k| match rng.random_range(0..20) {
                        0 => f64::NAN,
                        1 => f64::INFINITY,
                        2 => -0.0,
                        _ => (k as f64 * 0.05 + shift).sin() * 3.0 - 1.0 + rng.random_range(-0.1..0.1),
                    })
                    .collect()
            };
            let (a, b) = (sample(0.0), sample(0.4));
            let (fa, fb) = (Finite::of(&a), Finite::of(&b));
            for m in -(n as i64) - 3..=n as i64 + 3 {
                let (r, c) = pearson_at_lag(&fa, &fb, m);
                let (r0, c0) = pearson_skipping(&a, &b, m);
                assert_eq!((r.to_bits(), c), (r0.to_bits(), c0), "n {n}, lag {m}: {r} against {r0}");
            }
        }
    }

    /// A shifted copy is found at its shift, and the same on one thread
    /// as on two.
    #[test]
    fn a_shifted_copy_is_found_at_its_shift_on_any_thread_count() {
        let a: Vec<f64> = (0..2000).map(|k| (k as f64 * 0.031).sin() + (k as f64 * 0.0071).cos()).collect();
        let b: Vec<f64> = (0..2000).map(|k| a.get(k + 7).copied().unwrap_or(f64::NAN)).collect();
        let run = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| cross_correlate(&a, &b, 0.01, 20)).expect("a peak")
        };
        let (one, two) = (run(1), run(2));
        assert!((one.offset_s - 0.07).abs() < 1e-3, "offset {}", one.offset_s);
        assert_eq!((one.offset_s.to_bits(), one.peak.to_bits()), (two.offset_s.to_bits(), two.peak.to_bits()));
    }
}
