//! Drift flags and the pooled estimate over a vehicle's history.

use serde::{Deserialize, Serialize};

use super::HistoryRow;
use odocal::model::THETA_NAMES;
use odocal::Theta;

/// Combined-σ multiple beyond which a change between two rows is flagged.
pub const DRIFT_SIGMAS: f64 = 3.0;

/// A parameter that changed between two consecutive rows by more than
/// [`DRIFT_SIGMAS`] combined σ: `|θ₂ − θ₁| > 3·sqrt(σ₁² + σ₂²)`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DriftFlag {
    /// `c_e`, `c_d`, `t_r` or `d`.
    pub parameter: String,
    /// The earlier row's id.
    pub from_id: i64,
    /// When the earlier row was recorded.
    pub from_recorded_at: String,
    /// The later row's id.
    pub to_id: i64,
    /// When the later row was recorded.
    pub to_recorded_at: String,
    /// The change, later minus earlier.
    pub change: f64,
    /// The combined σ, `sqrt(σ₁² + σ₂²)`.
    pub combined_sigma: f64,
    /// Either row's σ is the model's alone
    /// ([`CalibrationRecord::sigma_model_only`](crate::CalibrationRecord::sigma_model_only)):
    /// the σ is unchecked and can be several times smaller than the spread
    /// between drives, so the flag is no evidence of drift by itself.
    #[serde(default)]
    pub model_sigma_only: bool,
}

/// Flags every parameter change between consecutive rows (in the order
/// given) beyond [`DRIFT_SIGMAS`] combined σ. Pairs where either row has
/// no σ are skipped.
pub(crate) fn drift_between(rows: &[HistoryRow]) -> Vec<DriftFlag> {
    let mut out = Vec::new();
    for w in rows.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        let (Some(sa), Some(sb)) = (a.record.sigma, b.record.sigma) else { continue };
        let (ta, tb, sa, sb) =
            (<[_; 4]>::from(a.record.theta), <[_; 4]>::from(b.record.theta), <[_; 4]>::from(sa), <[_; 4]>::from(sb));
        for i in 0..4 {
            let change = tb[i] - ta[i];
            let combined = (sa[i] * sa[i] + sb[i] * sb[i]).sqrt();
            if change.abs() > DRIFT_SIGMAS * combined {
                out.push(DriftFlag {
                    parameter: THETA_NAMES[i].to_string(),
                    from_id: a.id,
                    from_recorded_at: a.recorded_at.clone(),
                    to_id: b.id,
                    to_recorded_at: b.recorded_at.clone(),
                    change,
                    combined_sigma: combined,
                    model_sigma_only: a.record.sigma_model_only == Some(true)
                        || b.record.sigma_model_only == Some(true),
                });
            }
        }
    }
    out
}

/// A pooled estimate over several rows of one vehicle's history.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pooled {
    /// Rows pooled.
    pub rows: usize,
    /// Per parameter: the inverse-variance weighted mean `Σ wᵢθᵢ / Σ wᵢ`,
    /// `wᵢ = 1/σᵢ²`, when every row has a positive σ that is not the
    /// model's alone ([`CalibrationRecord::sigma_model_only`](crate::CalibrationRecord::sigma_model_only));
    /// else the plain mean.
    pub mean: Theta,
    /// The standard error of `mean` from the rows' σ (`1/sqrt(Σ wᵢ)`), or
    /// from the spread (`sd/√n`) for a plain mean; whichever is larger when
    /// both are known, since a between-drive spread beyond the σ means the
    /// σ alone understate it. NaN for a single row without σ.
    pub sigma_of_mean: Theta,
    /// The between-drive standard deviation: the sample sd of the rows'
    /// θ (n − 1 in the denominator); NaN for a single row.
    pub between_drive_sd: Theta,
}

/// Pools `rows` ([`Pooled`]); `None` without rows.
pub(crate) fn pooled_estimate(rows: &[HistoryRow]) -> Option<Pooled> {
    if rows.is_empty() {
        return None;
    }
    let n = rows.len() as f64;
    let (mut mean, mut se, mut sd) = ([0.0; 4], [0.0; 4], [0.0; 4]);
    for i in 0..4 {
        let values: Vec<f64> = rows.iter().map(|r| <[_; 4]>::from(r.record.theta)[i]).collect();
        let plain = values.iter().sum::<f64>() / n;
        sd[i] = if rows.len() > 1 {
            (values.iter().map(|v| (v - plain) * (v - plain)).sum::<f64>() / (n - 1.0)).sqrt()
        } else {
            f64::NAN
        };
        // A σ of the model alone would weigh its row far above the others
        // on a σ nothing checked: the rows are pooled as without σ.
        let sigmas: Option<Vec<f64>> =
            rows.iter().map(|r| r.record.checked_sigma().map(|s| <[_; 4]>::from(s)[i]).filter(|s| *s > 0.0)).collect();
        let spread_se = sd[i] / n.sqrt();
        match sigmas {
            Some(s) => {
                let w: Vec<f64> = s.iter().map(|s| 1.0 / (s * s)).collect();
                let sw: f64 = w.iter().sum();
                mean[i] = w.iter().zip(&values).map(|(w, v)| w * v).sum::<f64>() / sw;
                let model_se = 1.0 / sw.sqrt();
                se[i] = if spread_se.is_nan() { model_se } else { model_se.max(spread_se) };
            }
            None => {
                mean[i] = plain;
                se[i] = spread_se;
            }
        }
    }
    Some(Pooled {
        rows: rows.len(),
        mean: Theta::from(mean),
        sigma_of_mean: Theta::from(se),
        between_drive_sd: Theta::from(sd),
    })
}
