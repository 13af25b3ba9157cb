//! θ's covariance: the block sandwich and the larger-of rule.

use super::support::*;
use crate::eiv::covariance::inflate_to_block;
use crate::eiv::*;
use crate::sim::{simulate, NoiseOptions, SimOptions};
use nalgebra::Matrix4;

/// The block sandwich's meat on a constructed case (three blocks
/// in one window, then one more window of two blocks), against the plain
/// formula: centred outer products plus half the centred lag-1 cross
/// products of neighbouring blocks of the same window, times n/(n − 1).
#[test]
fn block_sandwich_meat_matches_the_plain_formula() {
    use crate::eiv::filter::BlockScores;
    let g = |a: f64, b: f64| nalgebra::Vector4::new(a, b, 0.0, 0.0);
    let windows = [vec![g(1.0, 2.0), g(-3.0, 0.5), g(2.0, -1.0)], vec![g(0.5, 0.0), g(4.0, 1.0)]];
    let mut total = BlockScores::zero();
    for w in &windows {
        let mut s = BlockScores::zero();
        let mut prev = None;
        for b in w {
            s.push_for_test(b, prev.as_ref());
            prev = Some(*b);
        }
        total.add_for_test(&s);
    }
    let all: Vec<_> = windows.iter().flatten().copied().collect();
    let n = all.len() as f64;
    let mean = all.iter().fold(nalgebra::Vector4::zeros(), |a, b| a + b) / n;
    let mut want = nalgebra::Matrix4::zeros();
    for b in &all {
        want += (b - mean) * (b - mean).transpose();
    }
    for w in &windows {
        for p in w.windows(2) {
            let (x, y) = (p[0] - mean, p[1] - mean);
            want += (x * y.transpose() + y * x.transpose()) * 0.5;
        }
    }
    want *= n / (n - 1.0);
    let got = total.meat().expect("five blocks");
    assert!((got - want).amax() < 1e-12, "{got} vs {want}");
    let mut one = BlockScores::zero();
    one.push_for_test(&g(1.0, 1.0), None);
    assert!(one.meat().is_none(), "one block gives no sandwich");
}

/// `CovarianceEstimate::LargerOfModelAndBlock` raises each σ to
/// the block sandwich's where that is larger and keeps the correlations.
#[test]
fn larger_of_model_and_block_inflates_only_where_the_blocks_are_wider() {
    use crate::eiv::filter::BlockScores;
    // H_θ⁻¹ with a correlation of 0.5 between c_e and c_d.
    let cov = Matrix4::new(4.0, 1.0, 0.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0);
    // Block scores spread ±3 along c_e only: meat diag (36·2/1 …) ≫ H on c_e.
    let mut b = BlockScores::zero();
    b.push_for_test(&nalgebra::Vector4::new(3.0, 0.0, 0.0, 0.0), None);
    b.push_for_test(&nalgebra::Vector4::new(-3.0, 0.0, 0.0, 0.0), None);
    let meat = b.meat().expect("two blocks");
    let sandwich = cov * meat * cov;
    let got = inflate_to_block(&cov, &b);
    for i in 0..4 {
        let want = cov[(i, i)].max(sandwich[(i, i)]);
        assert!((got[(i, i)] - want).abs() < 1e-12 * want.max(1.0), "σ² {i}: {} vs {want}", got[(i, i)]);
    }
    assert!(got[(0, 0)] > 4.0 * cov[(0, 0)], "c_e is inflated: {got}");
    let corr = |m: &Matrix4<f64>| m[(0, 1)] / (m[(0, 0)] * m[(1, 1)]).sqrt();
    assert!((corr(&got) - corr(&cov)).abs() < 1e-12);
    assert_eq!(inflate_to_block(&cov, &BlockScores::zero()), cov, "no blocks: the model's covariance");
}

/// On a drive with coloured common-mode wheel noise (1.5 km, the
/// `coloured` preset): a noise model without the common-mode source (η₁ at
/// its clamp in effect) reports c_e's σ several times too small; the block
/// sandwich sees the spread of the block scores and is wider, and
/// `LargerOfModelAndBlock` reports it and judges the halves with it.
#[test]
fn coloured_common_mode_noise_block_sandwich() {
    let noise = NoiseOptions::coloured_wheels_only();
    let out = simulate(&SimOptions { length_km: 1.5, noise: noise.clone(), ..SimOptions::paper(3) }).expect("sim");
    let input = input_of(&out.drive);
    let truth = out.sidecar.theta_true;
    let sim_noise = NoiseModel::from_sim(&noise, input.sample_time_s);
    let without_common = NoiseModel { wheel_common_rel_sigma: 0.0, ..sim_noise };
    let base = EivOptions {
        noise: without_common,
        fix_noise: true,
        window_samples: 2000,
        research: ResearchOptions { covariance_estimate: CovarianceEstimate::Model, ..Default::default() },
        ..Default::default()
    };
    let model = estimate(&input, &truth, &base).expect("fit");
    assert!(
        model.sigma_block[0] > 2.0 * model.sigma[0],
        "block σ(c_e) {} vs H σ {}",
        model.sigma_block[0],
        model.sigma[0]
    );
    let robust = estimate(
        &input,
        &truth,
        &EivOptions {
            research: ResearchOptions {
                covariance_estimate: CovarianceEstimate::LargerOfModelAndBlock,
                ..base.research.clone()
            },
            ..base.clone()
        },
    )
    .expect("fit");
    assert_eq!(robust.theta, model.theta, "the option changes the covariance only");
    assert!((robust.sigma[0] - model.sigma_block[0]).abs() <= 1e-12 * robust.sigma[0], "{robust}");
    assert!((robust.covariance[0][0].sqrt() - robust.sigma[0]).abs() <= 1e-12 * robust.sigma[0]);
    let (zm, zr) = (model.halves.expect("halves").z[0], robust.halves.expect("halves").z[0]);
    assert!(zr.abs() < zm.abs(), "halves z of c_e: robust {zr} vs model {zm}");
}
