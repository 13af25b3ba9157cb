//! The Cramér–Rao bound and the Fisher information behind it.

use super::support::*;
use crate::eiv::*;
use crate::sim::{simulate, SimOptions};

/// The Fisher information with the `½ tr(S⁻¹∂S S⁻¹∂S)` term dominates the
/// mean-only information (their difference is positive semi-definite), so
/// the full bound is the smaller; the trace term is not negligible on a
/// noisy drive (it adds information about c_e through the noise size).
#[test]
fn full_fisher_information_dominates_the_mean_only_information() {
    let out = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(7) }).expect("sim");
    let input = input_of(&out.drive);
    let noise = NoiseModel::from_sim(&out.sidecar.settings.noise, input.sample_time_s);
    let c = cramer_rao_bound(&input, &out.sidecar.theta_true, &noise, &EivOptions::default()).expect("crb");
    let full = nalgebra::Matrix4::from_fn(|i, j| c.information[i][j]);
    let mean = nalgebra::Matrix4::from_fn(|i, j| c.information_mean_only[i][j]);
    let diff = full - mean;
    let eig = nalgebra::SymmetricEigen::new(diff).eigenvalues;
    let scale = nalgebra::SymmetricEigen::new(full).eigenvalues.amax();
    assert!(eig.min() >= -1e-9 * scale, "I_full − I_mean has eigenvalues {eig}");
    assert!(eig.max() > 1e-6 * scale, "the trace term vanished: {eig}");
    for i in 0..4 {
        assert!(c.sigma[i] > 0.0 && c.sigma[i] <= c.sigma_mean_only[i] * (1.0 + 1e-9), "{i}: {c:?}");
    }
    eprintln!("CRB σ full {:?}, mean-only {:?}", c.sigma, c.sigma_mean_only);
    // η as nuisance parameters can only widen the bound (the θ block of a
    // joint inverse dominates the inverse of the θ block), and it must
    // widen t_r's: its trace-term information is shared with the wheel
    // noise scale.
    let ne = c.sigma_noise_estimated.expect("joint θ, η information is regular");
    for i in 0..4 {
        assert!(ne[i] >= c.sigma[i] * (1.0 - 1e-9), "{i}: {ne:?} vs {:?}", c.sigma);
    }
    assert!(ne[2] > 1.01 * c.sigma[2], "t_r: η unknown {} vs known {}", ne[2], c.sigma[2]);
    eprintln!("CRB σ with η estimated {ne:?}");
}

/// The bound at θ_true is linearised along the true inputs:
/// along the measured ones the white wheel noise counts as yaw excitation
/// and t_r's bound comes out far too small on a high-noise drive, while
/// c_e's (set by the distance, not by the turning) hardly moves. On a
/// noise-free drive the two inputs are the same columns and so are the
/// bounds, to the bit.
#[test]
fn the_bound_at_the_truth_is_linearised_along_the_true_inputs() {
    let high = SimOptions { length_km: 3.0, noise: crate::sim::NoiseOptions::high(), ..SimOptions::paper(7) };
    let out = simulate(&high).expect("sim");
    let noise = NoiseModel::from_sim(&out.sidecar.settings.noise, out.drive.sample_time_s());
    let th = out.sidecar.theta_true;
    let opts = EivOptions::spec();
    let truth = EivInput::from_drive_truth(&out.drive).expect("simulated drive");
    let along_truth = cramer_rao_bound(&truth, &th, &noise, &opts).expect("crb");
    let along_measured = cramer_rao_bound(&input_of(&out.drive), &th, &noise, &opts).expect("crb");
    let ratio = |i: usize| along_truth.sigma_mean_only[i] / along_measured.sigma_mean_only[i];
    eprintln!("mean-only σ along the truth / along the measured inputs: {:?}", (0..4).map(ratio).collect::<Vec<_>>());
    assert!(ratio(2) > 1.4, "t_r: {}", ratio(2));
    assert!(ratio(3) > 1.2, "d: {}", ratio(3));
    assert!((ratio(0) - 1.0).abs() < 0.1, "c_e: {}", ratio(0));

    let off = simulate(&SimOptions { length_km: 1.0, ..SimOptions::noise_free(7) }).expect("sim");
    let paper = NoiseModel::from_sim(&crate::sim::NoiseOptions::paper(), off.drive.sample_time_s());
    let a = cramer_rao_bound(&EivInput::from_drive_truth(&off.drive).expect("truth"), &th, &paper, &opts).expect("crb");
    let b = cramer_rao_bound(&input_of(&off.drive), &th, &paper, &opts).expect("crb");
    assert_eq!(a.information, b.information);
}
