//! The dead-reckoning error of θ (docs/method.md §7), the yardstick of validation,
//! of the reachable minimum and of the calibration's hold-out.
//!
//! On each validation segment the model runs with the *measured* wheel
//! rotations from the reference start pose, and the mean position error is
//!
//! ```text
//! E_p,s = (1/K_v) Σ_k sqrt((p̃_x,k − p_x,k(θ))² + (p̃_y,k − p_y,k(θ))²)
//! ```
//!
//! `Ē_p` is the mean over segments. With reference extrinsics
//! ([[`Extrinsics`]]) each segment starts from the axle pose the
//! reference implies and the model's reference point is compared with the
//! measured one.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::drive::segment::{Segment, SegmentData};
use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::model::extrinsics::{axle_pose, reference_pose, Extrinsics};
use crate::model::{step, Theta};

/// Mean position error of θ on the validation segments.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationReport {
    /// The θ validated.
    pub theta: Theta,
    /// Ē_p, the mean over segments of the per-segment mean position error, m.
    pub mean_position_error_m: f64,
    /// Number of validation segments.
    pub segments: usize,
    /// E_p,s per segment, m, in segment order.
    pub per_segment_m: Vec<f64>,
}

/// Mean position error E_p,s of one segment at θ.
pub(crate) fn segment_position_error(seg: &SegmentData<'_>, theta: &Theta) -> f64 {
    let mut x = seg.reference(0);
    let mut sum = 0.0;
    for k in 0..seg.steps() {
        x = step(&x, &seg.input(k), theta, seg.sample_time_s);
        sum += (seg.px[k + 1] - x[0]).hypot(seg.py[k + 1] - x[1]);
    }
    sum / seg.steps() as f64
}

/// Ē_p of θ over `segments` of `drive`, parallel over segments, deterministic.
pub fn mean_position_error(drive: &Drive, segments: &[Segment], theta: &Theta) -> Result<ValidationReport> {
    mean_position_error_with(drive, segments, theta, &Extrinsics::ZERO)
}

research_pub! {
    /// Ē_p of θ with the pose reference mounted at `extrinsics`: each segment
    /// starts from the axle pose the reference implies and the model's
    /// reference point is compared with the measured one
    /// (`segment_position_error_with`). With zero extrinsics
    /// this is [`mean_position_error`], bit for bit.
    fn mean_position_error_with(
        drive: &Drive,
        segments: &[Segment],
        theta: &Theta,
        extrinsics: &Extrinsics,
    ) -> Result<ValidationReport> {
        theta.validate()?;
        extrinsics.validate()?;
        mean_position_error_by(drive, segments, theta, |_| *extrinsics)
    }
}

/// [`mean_position_error_with`] with each segment's own extrinsics
/// `extrinsics(segment)` (a joint calibration's drives, each with its own
/// reference heading offset). A segment with zero extrinsics gets
/// `segment_position_error`, the same value bit for bit.
pub(crate) fn mean_position_error_by(
    drive: &Drive,
    segments: &[Segment],
    theta: &Theta,
    extrinsics: impl Fn(&Segment) -> Extrinsics + Sync,
) -> Result<ValidationReport> {
    theta.validate()?;
    if segments.is_empty() {
        return Err(Error::NoSegments(format!(
            "the drive ({} samples) is too short for one validation segment: give a longer drive or a shorter \
             validation_length (--validation-length)",
            drive.len()
        )));
    }
    let per_segment_m: Vec<f64> = segments
        .par_iter()
        .map(|s| {
            let (data, e) = (SegmentData::new(drive, s), extrinsics(s));
            if e.is_zero() {
                segment_position_error(&data, theta)
            } else {
                segment_position_error_with(&data, theta, &e)
            }
        })
        .collect();
    let mean = per_segment_m.iter().sum::<f64>() / per_segment_m.len() as f64;
    if !mean.is_finite() {
        return Err(Error::Numerical(format!("validation error is not finite at {theta}")));
    }
    Ok(ValidationReport { theta: *theta, mean_position_error_m: mean, segments: segments.len(), per_segment_m })
}

/// Mean position error E_p,s of one segment at (θ, e) (docs/method.md §7 with the
/// model's reference pose): the segment starts from the axle pose the
/// reference implies, and the model's reference point is compared with the
/// measured one. With `e` all 0 it is the plain E_p,s (docs/method.md §7), bit for bit
/// (outside the crate: [`dead_reckoning`], which gives the path too).
pub(crate) fn segment_position_error_with(seg: &SegmentData<'_>, theta: &Theta, e: &Extrinsics) -> f64 {
    let mut x = axle_pose(&seg.reference(0), e);
    let mut sum = 0.0;
    for k in 0..seg.steps() {
        x = step(&x, &seg.input(k), theta, seg.sample_time_s);
        let y = reference_pose(&x, e);
        sum += (seg.px[k + 1] - y[0]).hypot(seg.py[k + 1] - y[1]);
    }
    sum / seg.steps() as f64
}

/// Dead reckoning of one segment at (θ, e), from the axle pose the
/// segment's first reference pose implies: its mean position error E_p,s
/// (docs/method.md §7 with the model's reference pose: the model's reference point
/// compared with the measured one; with `e` all 0 the plain E_p,s, bit for
/// bit) and the dead-reckoned positions of the reference point (K+1
/// points), `(E_p,s in m, [(x, y)])`.
///
/// A segment of 0 steps has no error to average: the error is NaN (check
/// [`Segment::steps`](crate::segment::Segment::steps) first; the segments
/// [`crate::segment::cut`] gives have at least one step), where
/// [`mean_position_error`] refuses a non-finite Ē_p with
/// [`Error::Numerical`]. Non-finite inputs likewise give a non-finite value,
/// not an error.
pub fn dead_reckoning(seg: &SegmentData<'_>, theta: &Theta, e: &Extrinsics) -> (f64, Vec<(f64, f64)>) {
    let mut x = axle_pose(&seg.reference(0), e);
    let mut out = Vec::with_capacity(seg.steps() + 1);
    let y = reference_pose(&x, e);
    out.push((y[0], y[1]));
    let mut sum = 0.0;
    for k in 0..seg.steps() {
        x = step(&x, &seg.input(k), theta, seg.sample_time_s);
        let y = reference_pose(&x, e);
        sum += (seg.px[k + 1] - y[0]).hypot(seg.py[k + 1] - y[1]);
        out.push((y[0], y[1]));
    }
    (sum / seg.steps() as f64, out)
}

/// Lags of neighbouring validation segments whose errors
/// [`segment_log_ratio`] counts as correlated: the default validation
/// segments overlap by half (1300 steps every 650), so a segment shares
/// samples with its neighbour, and slow noise (wheel scale, reference
/// drift) reaches the one after.
const NEIGHBOUR_LAGS: usize = 2;

/// The mean of `x` (values along the drive) and its standard error: the
/// spread of the values, with the cross products of values up to
/// [`NEIGHBOUR_LAGS`] apart. The cross products only widen it: with a few
/// dozen values their sum is noisy, and a negative sum would claim a
/// precision the data do not show. `None` for fewer than three values.
fn mean_and_sigma(x: &[f64]) -> Option<(f64, f64)> {
    let n = x.len();
    if n < 3 {
        return None;
    }
    let mean = x.iter().sum::<f64>() / n as f64;
    let r: Vec<f64> = x.iter().map(|v| v - mean).collect();
    let own: f64 = r.iter().map(|v| v * v).sum();
    let lag = |l: usize| r.iter().zip(&r[l..]).map(|(a, b)| a * b).sum::<f64>();
    let cross: f64 = (1..=NEIGHBOUR_LAGS.min(n - 1)).map(lag).sum();
    let sigma = ((own + 2.0 * cross.max(0.0)) / (n as f64 * (n - 1) as f64)).sqrt();
    (mean.is_finite() && sigma.is_finite()).then_some((mean, sigma))
}

/// How two θ's dead reckoning compares segment by segment: the mean over
/// the validation segments of `ln(E_p,s(a) / E_p,s(b))`, `a` and `b` each
/// θ's E_p,s on the same segments in drive order, and its standard error
/// ([`mean_and_sigma`]). A θ that is wrong by a margin makes every segment
/// worse by a similar factor, so the log ratio separates it from noise
/// better than the difference of the means, whose segments' errors span a
/// wide range (a test-track segment a metre, a highway one tens). `None`
/// for fewer than three segments, lists of unequal length, or an error
/// that is not positive and finite.
pub(crate) fn segment_log_ratio(a: &[f64], b: &[f64]) -> Option<(f64, f64)> {
    let usable = |v: &f64| v.is_finite() && *v > 0.0;
    if a.len() != b.len() || !a.iter().chain(b).all(usable) {
        return None;
    }
    let logs: Vec<f64> = a.iter().zip(b).map(|(x, y)| (x / y).ln()).collect();
    mean_and_sigma(&logs)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::segment::validation_segments;
    use crate::sim::{simulate, SimOptions};

    /// Zero extrinsics give the plain E_p,s bit for bit, so a front end may
    /// always call `segment_position_error_with`.
    #[test]
    fn zero_extrinsics_are_the_plain_error_bit_for_bit() {
        let sim = simulate(&SimOptions { length_km: 2.0, substeps: 1, ..SimOptions::paper(5) }).expect("sim");
        let segs = validation_segments(&sim.drive, &Default::default()).expect("segments");
        let theta = Theta { c_e: 1.97, ..Theta::PAPER_NOMINAL };
        for s in &segs {
            let data = SegmentData::new(&sim.drive, s);
            let plain = segment_position_error(&data, &theta);
            let with = segment_position_error_with(&data, &theta, &Extrinsics::ZERO);
            assert_eq!(plain.to_bits(), with.to_bits());
        }
    }

    /// Independent values give the standard error of their mean; values
    /// that move together with their neighbours a wider one; alternating
    /// neighbours do not narrow it.
    #[test]
    fn the_standard_error_counts_correlated_neighbours_and_only_widens() {
        // Independent: √(Σ(x − x̄)² / (n (n − 1))). Alternating signs: the
        // lag-1 products (−11.25) outweigh the lag-2 ones (+7.5), nothing is added.
        let d = [1.0, -1.0, 2.0, -2.0, 0.5, -0.5, 1.5, -1.5];
        let plain = (d.iter().map(|x| x * x).sum::<f64>() / (8.0 * 7.0)).sqrt();
        let (m, s) = mean_and_sigma(&d).expect("σ");
        assert!(m.abs() < 1e-15, "{m}");
        assert!((s - plain).abs() < 1e-15, "{s} vs {plain}");
        // Runs of equal values: neighbours correlate (lag-1 products 5, lag-2
        // 2 against 8 of their own), σ grows by √(22/8).
        let runs = [1.0, 1.0, 1.0, 1.0, -1.0, -1.0, -1.0, -1.0];
        let plain_runs = (8.0f64 / (8.0 * 7.0)).sqrt();
        let (_, s) = mean_and_sigma(&runs).expect("σ");
        assert!((s / plain_runs - (22.0f64 / 8.0).sqrt()).abs() < 1e-12, "{s} vs {plain_runs}");
        assert_eq!(mean_and_sigma(&[1.0, 2.0]), None);
    }

    /// The log ratio of E_p,s: a θ twice as bad on every segment gives ln 2
    /// with no spread; unequal lists, too few segments or an error that is
    /// not positive give none.
    #[test]
    fn the_segment_log_ratio_compares_segment_by_segment() {
        let b = [1.0, 10.0, 3.0, 40.0];
        let a: Vec<f64> = b.iter().map(|x| 2.0 * x).collect();
        let (m, s) = segment_log_ratio(&a, &b).expect("ratio");
        assert!((m - 2f64.ln()).abs() < 1e-15 && s < 1e-15, "{m} {s}");
        let (m, _) = segment_log_ratio(&b, &a).expect("ratio");
        assert!((m + 2f64.ln()).abs() < 1e-15, "{m}");
        assert_eq!(segment_log_ratio(&a[..3], &b), None);
        assert_eq!(segment_log_ratio(&a[..2], &b[..2]), None);
        assert_eq!(segment_log_ratio(&[1.0, 0.0, 2.0], &[1.0, 1.0, 1.0]), None);
        assert_eq!(segment_log_ratio(&[1.0, f64::NAN, 2.0], &[1.0, 1.0, 1.0]), None);
    }
}
