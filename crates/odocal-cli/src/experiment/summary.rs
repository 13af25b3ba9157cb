//! The summary rows of `odocal experiment`'s per-segment and batch
//! estimates (report.md's table, experiment.json's `summary_*`): each set's
//! count, its smallest, median and largest Ē_p, and its median absolute
//! error against θ_true.

use odocal::experiment::{Experiment, Scored};
use odocal::Theta;
use serde::Serialize;

/// Summary statistics of a set of estimates.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Summary {
    /// Estimates.
    pub count: usize,
    /// Smallest Ē_p, m.
    pub min_mean_position_error_m: f64,
    /// Median Ē_p, m.
    pub median_mean_position_error_m: f64,
    /// Largest Ē_p, m.
    pub max_mean_position_error_m: f64,
    /// Median |θ − θ_true| per parameter, SI.
    pub median_abs_error_vs_true: Option<Theta>,
}

/// The four sets: experiment.json's key, report.md's row name and the
/// summary, in the table's order.
pub fn summaries(e: &Experiment) -> [(&'static str, &'static str, Summary); 4] {
    [
        ("summary_segments_raw", "segments, raw", summarize(e.per_segment.iter().filter_map(|s| s.raw.as_ref()))),
        (
            "summary_segments_compensated",
            "segments, compensated",
            summarize(e.per_segment.iter().filter_map(|s| s.compensated.as_ref())),
        ),
        ("summary_batches_raw", "batches, raw", summarize(e.batches.iter().map(|b| &b.raw))),
        (
            "summary_batches_compensated",
            "batches, compensated",
            summarize(e.batches.iter().filter_map(|b| b.compensated.as_ref())),
        ),
    ]
}

/// Median of the finite values (NaN when there are none).
fn median(values: &[f64]) -> f64 {
    let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// The summary of `items`.
fn summarize<'a>(items: impl Iterator<Item = &'a Scored>) -> Summary {
    let items: Vec<&Scored> = items.collect();
    let mut e: Vec<f64> = items.iter().map(|s| s.mean_position_error_m).collect();
    let med = median(&e);
    e.sort_by(f64::total_cmp);
    let err = if items.iter().all(|s| s.error_vs_true.is_some()) && !items.is_empty() {
        let col = |f: fn(&Theta) -> f64| {
            let v: Vec<f64> = items.iter().filter_map(|s| s.error_vs_true.as_ref().map(|t| f(t).abs())).collect();
            median(&v)
        };
        Some(Theta { c_e: col(|t| t.c_e), c_d: col(|t| t.c_d), t_r: col(|t| t.t_r), d: col(|t| t.d) })
    } else {
        None
    };
    Summary {
        count: items.len(),
        min_mean_position_error_m: e.first().copied().unwrap_or(f64::NAN),
        median_mean_position_error_m: med,
        max_mean_position_error_m: e.last().copied().unwrap_or(f64::NAN),
        median_abs_error_vs_true: err,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_skips_values_that_are_not_finite() {
        assert_eq!(median(&[3.0, f64::NAN, 1.0, 2.0]).to_bits(), 2.0f64.to_bits());
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]).to_bits(), 2.5f64.to_bits());
        assert!(median(&[f64::INFINITY]).is_nan());
    }

    #[test]
    fn a_set_without_truth_has_no_error_column() {
        let s = Scored {
            theta: Theta::PAPER_NOMINAL,
            mean_position_error_m: 1.5,
            error_vs_true: None,
            error_over_crb: None,
        };
        let sum = summarize([s, Scored { mean_position_error_m: 0.5, ..s }].iter());
        let bits = |x: f64| x.to_bits();
        assert_eq!(sum.count, 2);
        assert_eq!(bits(sum.min_mean_position_error_m), bits(0.5));
        assert_eq!(bits(sum.max_mean_position_error_m), bits(1.5));
        assert_eq!(bits(sum.median_mean_position_error_m), bits(1.0));
        assert!(sum.median_abs_error_vs_true.is_none());
    }
}
