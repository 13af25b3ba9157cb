//! The heading drift's own scale η_6, released from the pose-drift scale
//! only where the data reject the tie.

use super::support::*;
use crate::eiv::*;
use crate::sim::{simulate, NoiseOptions, SimOptions};
use crate::Theta;

/// The options with the heading-drift test off (the tied model alone).
fn tied_only() -> EivOptions {
    let mut o = EivOptions::default();
    o.research.heading_drift_test = false;
    o
}

/// A fit on `noise` (the paper preset's drive otherwise), `km` long: the
/// default and the tied model alone, and θ_true.
fn fits(noise: NoiseOptions, km: f64, seed: u64) -> (EivReport, EivReport, Theta) {
    let out = simulate(&SimOptions { length_km: km, noise, ..SimOptions::paper(seed) }).expect("sim");
    let input = input_of(&out.drive);
    let start = batch_gn_all(&out.drive);
    let default = estimate(&input, &start, &EivOptions::default()).expect("eiv");
    let tied = estimate(&input, &start, &tied_only()).expect("eiv");
    (default, tied, out.sidecar.theta_true)
}

/// Where the reference's heading drifts as the tied model expects, the
/// score test keeps the tie: the result is the tied fit's to the bit, and
/// the test's filter passes are not counted in `evaluations`.
#[test]
fn a_tie_that_holds_keeps_the_tied_fit_to_the_bit() {
    let (default, tied, _) = fits(NoiseOptions::paper(), 3.0, 5);
    let h = default.heading_drift.clone().expect("the test ran");
    assert!(!h.separate && h.score_statistic < HEADING_DRIFT_SCORE_GATE, "{h:?}");
    assert_eq!(h.likelihood_ratio, None);
    assert_eq!(h.evaluations, [0, 2], "two objective-only passes");
    assert_eq!(h.eta, default.eta[NoiseSource::PoseDrift.index()]);
    assert!(tied.heading_drift.is_none());
    assert_eq!(EivReport { heading_drift: None, timing_s: 0.0, ..default }, EivReport { timing_s: 0.0, ..tied });
}

/// A reference whose position drifts by a metre but whose heading barely
/// drifts: the tie grants the heading the position's drift, the test
/// rejects it and the separate fit gives the heading a far smaller drift
/// scale (r < 0), a lower objective by more than the threshold, and a t_r
/// closer to the truth.
#[test]
fn a_heading_that_drifts_less_than_the_position_gets_its_own_scale() {
    let noise = NoiseOptions { position_drift_sigma_m: 1.0, heading_drift_sigma_rad: 2e-4, ..NoiseOptions::paper() };
    let (default, tied, truth) = fits(noise, 6.0, 8);
    let h = default.heading_drift.clone().expect("the test ran");
    assert!(h.separate, "{h:?}");
    assert!(h.likelihood_ratio.expect("fitted") > HEADING_DRIFT_LR_THRESHOLD, "{h:?}");
    assert!(h.log_ratio < -1.0, "{h:?}");
    assert!((h.eta - default.eta[NoiseSource::PoseDrift.index()] - h.log_ratio).abs() < 1e-12);
    assert!(default.final_cost < tied.final_cost - 0.5 * HEADING_DRIFT_LR_THRESHOLD);
    let (e_sep, e_tied) = ((default.theta.t_r - truth.t_r).abs(), (tied.theta.t_r - truth.t_r).abs());
    assert!(e_sep < e_tied, "t_r error: separate {e_sep:e}, tied {e_tied:e}");
    // The reported noise carries the heading drift's own scale.
    let start = EivOptions::default().noise;
    let expected = start.heading_drift_sigma_rad * (0.5 * h.eta).exp();
    assert!((default.noise.heading_drift_sigma_rad / expected - 1.0).abs() < 1e-12);
}
