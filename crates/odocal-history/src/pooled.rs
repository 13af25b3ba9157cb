//! Drift flags and the pooled estimate over a vehicle's history, each
//! drive counted once.

use serde::{Deserialize, Serialize};

use super::HistoryRow;
use crate::source::{held_by_record, same_data, Held};
use odocal::model::THETA_NAMES;
use odocal::Theta;

/// Combined-σ multiple beyond which a change between two rows is flagged.
pub const DRIFT_SIGMAS: f64 = 3.0;

/// The verdict reason kinds that name a bias of the estimate beyond its
/// σ: `input_noise_bias` (batch Gauss-Newton's errors-in-variables bias,
/// shared by every drive of the vehicle) and `heading_offset_held` (a held
/// heading offset that shifts θ). Pooling such rows would shrink the
/// pooled σ while their bias stays, so they are listed but not pooled
/// ([`Pooled::biased`]), and `follow` does not start from them.
pub const BIAS_REASONS: [&str; 2] = ["input_noise_bias", "heading_offset_held"];

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
    /// Either row's verdict names a bias of its estimate beyond its σ
    /// ([`BIAS_REASONS`]): the change may be that bias (one method's
    /// against another's), not the vehicle's, so the flag is no evidence
    /// of drift by itself.
    #[serde(default)]
    pub biased: bool,
}

/// A row left out of the drift flags or the pooled estimate because a
/// more recent row holds its drive (or one of its drives): two rows of one
/// drive (calibrated by two methods, or once alone and once jointly with
/// others) are two estimates from the same samples, not two measurements
/// of the vehicle. Counted twice they would shrink the pooled σ as if the
/// drive had been driven twice, and a difference between them (the
/// methods') would be flagged as drift.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SetAside {
    /// The row left out.
    pub id: i64,
    /// The more recent row that stands for its drive.
    pub by_id: i64,
}

/// The drives a row's fingerprint names: one, or those of a joint
/// calibration (comma separated).
pub(crate) fn drives_of(fingerprint: &str) -> impl Iterator<Item = &str> {
    fingerprint.split(',').map(str::trim).filter(|f| !f.is_empty())
}

/// `rows` (in recording order) with each drive counted once: walking from
/// the most recent row back, a row stands unless a row that stands already
/// holds one of its drives (the same fingerprint, or the same files over
/// overlapping times: [`crate::source_digest`]). Returns the rows that
/// stand, in recording order, and those set aside (in recording order),
/// each with the row that stands for its drive.
///
/// The most recent row stands because a drive calibrated again (by another
/// method, or jointly with other drives) is a choice made later, and
/// because `follow` starts from the vehicle's most recent row: the
/// history's pooled estimate and `follow`'s stored θ agree on which row
/// stands for a drive. `--pool IDS` picks other rows.
pub(crate) fn counted_once(rows: &[HistoryRow]) -> (Vec<&HistoryRow>, Vec<SetAside>) {
    let mut holder: std::collections::HashMap<&str, i64> = std::collections::HashMap::new();
    // The data each standing row holds, by source digest.
    let mut held: Vec<(Held<'_>, i64)> = Vec::new();
    let (mut stand, mut aside) = (Vec::new(), Vec::new());
    for r in rows.iter().rev() {
        let data = held_by_record(&r.record);
        let by = drives_of(&r.record.fingerprint)
            .find_map(|f| holder.get(f).copied())
            .or_else(|| held.iter().find(|(h, _)| same_data(h, &data)).map(|(_, id)| *id));
        match by {
            Some(by_id) => aside.push(SetAside { id: r.id, by_id }),
            None => {
                holder.extend(drives_of(&r.record.fingerprint).map(|f| (f, r.id)));
                held.push((data, r.id));
                stand.push(r);
            }
        }
    }
    stand.reverse();
    aside.reverse();
    (stand, aside)
}

/// Flags every parameter change between consecutive rows (in the order
/// given) beyond [`DRIFT_SIGMAS`] combined σ. A parameter is compared
/// between the consecutive rows that measured it (neither held nor named
/// not observable, [`CalibrationRecord::measured`](crate::CalibrationRecord::measured));
/// pairs where either row has no σ for it are skipped.
pub(crate) fn drift_between(rows: &[&HistoryRow]) -> Vec<DriftFlag> {
    let mut out = Vec::new();
    for (i, name) in THETA_NAMES.iter().enumerate() {
        let measured: Vec<&HistoryRow> = rows.iter().copied().filter(|r| r.record.measured(i)).collect();
        for w in measured.windows(2) {
            let (a, b) = (w[0], w[1]);
            let (Some(sa), Some(sb)) = (<[_; 4]>::from(a.record.sigma)[i], <[_; 4]>::from(b.record.sigma)[i]) else {
                continue;
            };
            let change = <[_; 4]>::from(b.record.theta)[i] - <[_; 4]>::from(a.record.theta)[i];
            let combined = sa.hypot(sb);
            if change.abs() > DRIFT_SIGMAS * combined {
                out.push(DriftFlag {
                    parameter: name.to_string(),
                    from_id: a.id,
                    from_recorded_at: a.recorded_at.clone(),
                    to_id: b.id,
                    to_recorded_at: b.recorded_at.clone(),
                    change,
                    combined_sigma: combined,
                    model_sigma_only: a.record.sigma_model_only == Some(true)
                        || b.record.sigma_model_only == Some(true),
                    biased: !a.record.bias_reasons().is_empty() || !b.record.bias_reasons().is_empty(),
                });
            }
        }
    }
    // In recording order of the later row, then parameter order.
    out.sort_by_key(|f| (f.to_id, THETA_NAMES.iter().position(|n| *n == f.parameter)));
    out
}

/// A pooled estimate over several rows of one vehicle's history, each
/// drive counted once ([`SetAside`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Pooled {
    /// Rows pooled (those asked for, less those set aside, rejected,
    /// online or biased).
    pub rows: usize,
    /// Drives they hold (a joint calibration holds several).
    #[serde(default)]
    pub drives: usize,
    /// Rows asked for but not pooled: a more recent row asked for holds
    /// their drive.
    #[serde(default)]
    pub set_aside: Vec<SetAside>,
    /// Rows asked for but not pooled because their verdict is `rejected`
    /// (ids, in recording order).
    #[serde(default)]
    pub rejected: Vec<i64>,
    /// Rows asked for but not pooled because they are online running
    /// estimates (method `online`, written by `odocal follow`): each holds
    /// the drives followed before it and the row its recursion started
    /// from, so pooling it with them, or with the other online rows of its
    /// sequence, would count those drives several times (ids, in recording
    /// order). They are listed and drift-flagged; the most recent stands for
    /// the drives it followed.
    #[serde(default)]
    pub online: Vec<i64>,
    /// Rows asked for but not pooled because their verdict names a bias of
    /// the estimate beyond its σ ([`BIAS_REASONS`]), in recording order.
    /// They are listed and drift-flagged as other rows.
    #[serde(default)]
    pub biased: Vec<Biased>,
    /// The pooled rows' parameters that are no measurement (held at θ_0,
    /// or named not observable): each left out of that parameter's pool.
    #[serde(default)]
    pub not_measured: Vec<NotMeasured>,
    /// Per parameter, over the pooled rows that measured it: the
    /// inverse-variance weighted mean `Σ wᵢθᵢ / Σ wᵢ`, `wᵢ = 1/σᵢ²`, when
    /// each of them has a positive σ that is not the model's alone
    /// ([`CalibrationRecord::sigma_model_only`](crate::CalibrationRecord::sigma_model_only));
    /// else the plain mean. NaN (JSON `null`) for a parameter no pooled
    /// row measured.
    pub mean: Theta,
    /// The standard error of `mean` from the rows' σ (`1/sqrt(Σ wᵢ)`), or
    /// from the spread (`sd/√n`) for a plain mean; whichever is larger when
    /// both are known, since a between-drive spread beyond the σ means the
    /// σ alone understate it. NaN (JSON `null`) for a single measured row
    /// without σ, or none.
    pub sigma_of_mean: Theta,
    /// The between-drive standard deviation: the sample sd of the measured
    /// rows' θ (n − 1 in the denominator); NaN (JSON `null`) for fewer
    /// than two.
    pub between_drive_sd: Theta,
}

/// A row left out of the pooled estimate because its verdict names a bias
/// of its estimate beyond its σ ([`BIAS_REASONS`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Biased {
    /// The row.
    pub id: i64,
    /// The verdict reason kinds among [`BIAS_REASONS`] it names.
    pub reasons: Vec<String>,
}

impl Biased {
    /// The row's entry when its verdict names a bias beyond its σ.
    pub(crate) fn of(r: &HistoryRow) -> Option<Biased> {
        let reasons = r.record.bias_reasons();
        (!reasons.is_empty()).then(|| Biased { id: r.id, reasons: reasons.into_iter().map(String::from).collect() })
    }
}

/// A parameter of a pooled row that is no measurement, and so left out of
/// that parameter's pool and drift flags.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NotMeasured {
    /// The row.
    pub id: i64,
    /// `c_e`, `c_d`, `t_r` or `d`.
    pub parameter: String,
    /// `held` (at θ_0) or `not observable`.
    pub why: String,
}

/// True for a row whose verdict is `rejected`: a result not to be
/// deployed (implausible, or its checks failed) is no evidence of the
/// vehicle's parameters, so it takes no part in the drift flags or the
/// pooled estimate (it is listed with every row).
pub(crate) fn is_rejected(r: &HistoryRow) -> bool {
    r.record.verdict.as_deref().is_some_and(|v| v == odocal::VerdictLevel::Rejected.to_string())
}

/// True for a row `odocal follow` wrote: an online running estimate
/// ([`Pooled::online`]).
pub(crate) fn is_online(r: &HistoryRow) -> bool {
    r.record.method == crate::ONLINE
}

/// True for a row whose verdict names a bias beyond its σ ([`BIAS_REASONS`]).
pub(crate) fn is_biased(r: &HistoryRow) -> bool {
    !r.record.bias_reasons().is_empty()
}

/// The rows among `rows` (in recording order) neither rejected nor online
/// whose verdict names a bias beyond its σ ([`Pooled::biased`]).
pub(crate) fn biased(rows: &[HistoryRow]) -> Vec<Biased> {
    rows.iter().filter(|r| !is_rejected(r) && !is_online(r)).filter_map(Biased::of).collect()
}

/// Pools `rows` (in recording order), each drive once ([`Pooled`],
/// [`counted_once`]), the rejected, the online and the biased ones left
/// out (before each drive is counted once: a biased row does not set aside
/// an unbiased row of its drive), each parameter over the rows that
/// measured it; `None` without a row to pool.
pub(crate) fn pooled_estimate(rows: &[HistoryRow]) -> Option<Pooled> {
    let rejected: Vec<i64> = rows.iter().filter(|r| is_rejected(r)).map(|r| r.id).collect();
    let online: Vec<i64> = rows.iter().filter(|r| !is_rejected(r) && is_online(r)).map(|r| r.id).collect();
    let biased = biased(rows);
    let judged: Vec<HistoryRow> =
        rows.iter().filter(|r| !is_rejected(r) && !is_online(r) && !is_biased(r)).cloned().collect();
    let (all_rows, set_aside) = counted_once(&judged);
    if all_rows.is_empty() {
        return None;
    }
    let drives = all_rows.iter().map(|r| drives_of(&r.record.fingerprint).count().max(1)).sum();
    let mut not_measured = Vec::new();
    for r in &all_rows {
        for (i, name) in THETA_NAMES.iter().enumerate() {
            if let Some(why) = r.record.not_measured(i) {
                not_measured.push(NotMeasured { id: r.id, parameter: name.to_string(), why: why.to_string() });
            }
        }
    }
    let (mut mean, mut se, mut sd) = ([f64::NAN; 4], [f64::NAN; 4], [f64::NAN; 4]);
    for i in 0..4 {
        let rows: Vec<&HistoryRow> = all_rows.iter().copied().filter(|r| r.record.measured(i)).collect();
        if rows.is_empty() {
            continue;
        }
        let n = rows.len() as f64;
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
            rows.iter().map(|r| <[_; 4]>::from(r.record.checked_sigma())[i].filter(|s| *s > 0.0)).collect();
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
        rows: all_rows.len(),
        drives,
        set_aside,
        rejected,
        online,
        biased,
        not_measured,
        mean: Theta::from(mean),
        sigma_of_mean: Theta::from(se),
        between_drive_sd: Theta::from(sd),
    })
}
