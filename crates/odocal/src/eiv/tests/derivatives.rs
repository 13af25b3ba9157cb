//! The filter's exact derivatives against central differences.

use super::support::*;
use crate::eiv::filter::NETA;
use crate::eiv::filter::{run_window, InnovationRecord};
use crate::eiv::input::make_windows;
use crate::eiv::problem::Problem;
use crate::eiv::*;
use crate::sim::{simulate, NoiseOptions, SimOptions};
use crate::Theta;

fn check_innovation_derivatives(follows: bool) {
    check_innovation_derivatives_with(follows, false, false);
}

fn check_innovation_derivatives_with(follows: bool, fitted: bool, counting: bool) {
    check_innovation_derivatives_quant(follows, fitted, counting, Held::NONE);
}

fn check_innovation_derivatives_quant(follows: bool, fitted: bool, counting: bool, given: Held) {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1200.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let th_ref = Theta { c_e: 1.96, ..th };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    let records = |input: &EivInput<'_>, w: &Window, th: &Theta, th_ref: &Theta, eta: &[f64; 6], follows: bool| {
        records_quant(input, w, th, th_ref, eta, follows, (fitted, counting), given)
    };
    let base = records(&input, &w, &th, &th_ref, &eta, follows);
    let check = |fd: Vec<(usize, nalgebra::Vector3<f64>, nalgebra::Matrix3<f64>)>, p: usize, what: &str| {
        // Scale: the largest derivative of this column over the window.
        let scale_nu = base.iter().map(|r| r.dnu.column(p).amax()).fold(0.0f64, f64::max).max(1e-12);
        let scale_s = base.iter().map(|r| r.ds[p].amax()).fold(0.0f64, f64::max).max(1e-300);
        for (k, dnu, ds) in fd {
            let a = base[k].dnu.column(p).into_owned();
            assert!((a - dnu).amax() <= FD_REL_TOL * scale_nu, "{what}: ∂ν/∂p{p} at update {k}: {a} vs {dnu}");
            let a = base[k].ds[p];
            assert!((a - ds).amax() <= FD_REL_TOL * scale_s, "{what}: ∂S/∂p{p} at update {k}: {a} vs {ds}");
        }
    };
    let picks = [1usize, 2, 10, 300, 700, base.len() - 1];
    for j in 0..NETA {
        // ν is a difference of positions of ~1 km: its rounding (~1e-13 m)
        // over 2h must stay well below the tolerance, so h is not tiny.
        let h = 1e-4;
        let (mut ep, mut em) = (eta, eta);
        ep[j] += h;
        em[j] -= h;
        let rp = records(&input, &w, &th, &th_ref, &ep, follows);
        let rm = records(&input, &w, &th, &th_ref, &em, follows);
        let fd =
            picks.iter().map(|&k| (k, (rp[k].nu - rm[k].nu) / (2.0 * h), (rp[k].s - rm[k].s) / (2.0 * h))).collect();
        check(fd, 4 + j, "η");
    }
    for p in 0..4 {
        // 1e-5 of each parameter's size: with the sideslip error a filter state,
        // ∂S/∂d has position entries of ~1e-11 next to ~1e-6 ones, and at 1e-6
        // the rounding of the differences reached the tolerance (at 1e-7 it
        // exceeds it for c_e; at 1e-5 every column agrees).
        let h = 1e-5 * [th.c_e, 1.0, th.t_r, 1.0][p];
        let rp = records(&input, &w, &perturb(&th, p, h), &th_ref, &eta, follows);
        let rm = records(&input, &w, &perturb(&th, p, -h), &th_ref, &eta, follows);
        let fd = picks
            .iter()
            .map(|&k| {
                if !follows {
                    // ∂S/∂θ is exactly zero by construction (covariance at θ_ref).
                    assert!((rp[k].s - rm[k].s).amax() == 0.0, "S depends on θ");
                } else {
                    assert!((rp[k].s - rm[k].s).amax() > 0.0, "S does not depend on θ");
                }
                (k, (rp[k].nu - rm[k].nu) / (2.0 * h), (rp[k].s - rm[k].s) / (2.0 * h))
            })
            .collect();
        check(fd, p, "θ");
    }
}

/// The whitened-innovation derivatives behind the Gauss-Newton metric
/// (covariance following θ): `Σ (∂r/∂θ)ᵀ r` is the gradient of ½Σ νᵀS⁻¹ν,
/// and each ∂r matches central differences of r.
#[test]
fn whitened_innovation_derivatives_match_central_differences() {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1200.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    let base = records(&input, &w, &th, &th, &eta, true);
    let picks = [1usize, 10, 300, 700, base.len() - 1];
    for p in 0..4 {
        let h = 1e-6 * [th.c_e, 1.0, th.t_r, 1.0][p];
        let rp = records(&input, &w, &perturb(&th, p, h), &th, &eta, true);
        let rm = records(&input, &w, &perturb(&th, p, -h), &th, &eta, true);
        let scale = base.iter().map(|r| r.dr.column(p).amax()).fold(0.0f64, f64::max);
        for &k in &picks {
            let fd = (rp[k].r - rm[k].r) / (2.0 * h);
            let a = base[k].dr.column(p).into_owned();
            assert!((a - fd).amax() <= FD_REL_TOL * scale, "∂r/∂θ{p} at update {k}: {a} vs {fd}");
        }
        let g: f64 = base.iter().map(|r| r.dr.column(p).dot(&r.r)).sum();
        let q = |rs: &[InnovationRecord]| rs.iter().map(|r| 0.5 * r.r.norm_squared()).sum::<f64>();
        let fd = (q(&rp) - q(&rm)) / (2.0 * h);
        assert!((g - fd).abs() <= 1e-4 * g.abs().max(fd.abs()), "Σ ∂rᵀr over θ{p}: {g} vs {fd}");
    }
}

#[test]
fn innovation_derivatives_match_central_differences_covariance_held() {
    check_innovation_derivatives(false);
}

#[test]
fn innovation_derivatives_match_central_differences_covariance_follows_theta() {
    check_innovation_derivatives(true);
}

fn check_objective_gradient(follows: bool) {
    check_objective_gradient_with(follows, false, false);
}

/// ∂M, ∂J and (covariance following θ) the parts `∂(½Σ log det S)/∂θ` and
/// `∂(−Σ m log(1 − ŝ))/∂θ` behind [`FirstOrderBias`] against central
/// differences; with `fitted` the wheel noise is scaled by the fitted true
/// input (the reference θ away from θ, so the factor is not 1).
fn check_objective_gradient_with(follows: bool, fitted: bool, counting: bool) {
    check_objective_gradient_quant(follows, fitted, counting, (Held::NONE, false));
}

/// [`check_objective_gradient_with`]; `given`: the quantisation level given
/// ([`QuantisationLevel::Given`]); `measurement`: quantisation as measurement
/// noise ([`QuantisationModel::Measurement`], not with `counting`).
fn check_objective_gradient_quant(follows: bool, fitted: bool, counting: bool, quant: (Held, bool)) {
    check_objective_gradient_jacobians(follows, (fitted, counting), quant, (true, true));
}

/// [`check_objective_gradient_quant`] with the Gauss-Markov log-Jacobian
/// in M or not (`in_marginal`, `Variances::coloured_jacobian_in_marginal`)
/// and the common-mode state's in J and M or not (`common`,
/// `Variances::common_mode_jacobian`).
fn check_objective_gradient_jacobians(
    follows: bool,
    (fitted, counting): (bool, bool),
    (given, measurement): (Held, bool),
    (in_marginal, common): (bool, bool),
) {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(6) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1500.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let th_ref = if fitted { Theta { c_e: 1.96, c_d: -0.001, d: 0.0012, ..th } } else { th };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    let variances = |e: &[f64; 6]| {
        let mut v = variances_quant(e, input.sample_time_s, given);
        v.fitted_input = fitted;
        v.quant_counting = counting;
        v.quant_in_measurement = measurement;
        v.coloured_jacobian_in_marginal = in_marginal;
        v.common_mode_jacobian = common;
        v
    };
    let sums = |t: &Theta, e: &[f64; 6]| {
        run_window(&input, &w, t, &th_ref, &variances(e), filter::Mode::full(follows, true), None).expect("window")
    };
    let cost_only = |t: &Theta, e: &[f64; 6]| {
        run_window(&input, &w, t, &th_ref, &variances(e), filter::Mode::cost(follows), None).expect("window")
    };
    let base = sums(&th, &eta);
    // The cost-only pass gives the same objective.
    let c = cost_only(&th, &eta);
    assert_eq!((c.quad, c.logdet, c.correction), (base.quad, base.logdet, base.correction));
    for p in 0..9 {
        let (tp, tm, ep, em, h) = perturbed_pair(&th, &eta, p);
        let (sp, sm) = (cost_only(&tp, &ep), cost_only(&tm, &em));
        for (what, fd, g) in [
            ("M", (sp.merit() - sm.merit()) / (2.0 * h), base.grad[p]),
            ("J", (sp.profile() - sm.profile()) / (2.0 * h), base.grad_profile[p]),
        ] {
            assert!((g - fd).abs() <= 1e-4 * g.abs().max(fd.abs()).max(1e-6), "∂{what}/∂p{p}: {g} vs {fd}");
        }
        if p < 4 && follows {
            // Σ log det S over 1500 updates is ~3e4 with a rounding error of
            // ~1e-10, which a 1e-6 relative step turns into ~1e-3 of a c_d
            // gradient of ~0.03: these parts get a 100× larger step (the
            // truncation error stays ~1e-8 relative).
            let h = 100.0 * h;
            let (sp, sm) = (cost_only(&perturb(&th, p, h), &eta), cost_only(&perturb(&th, p, -h), &eta));
            for (what, fd, g) in [
                ("½Σ log det S", 0.5 * (sp.logdet - sm.logdet) / (2.0 * h), base.grad_logdet[p]),
                ("−Σ m log(1 − ŝ)", (sp.correction - sm.correction) / (2.0 * h), base.grad_correction[p]),
            ] {
                assert!((g - fd).abs() <= 1e-4 * g.abs().max(fd.abs()).max(1e-6), "∂{what}/∂θ{p}: {g} vs {fd}");
            }
        }
    }
}

#[test]
fn objective_gradient_matches_central_differences_fitted_input() {
    check_objective_gradient_with(true, true, false);
}

/// ∂M and ∂J against central differences with the Gauss-Markov
/// log-Jacobian left out of M, and with the common-mode state's left out
/// of both; M then differs from the default's by exactly the terms left out.
#[test]
#[allow(clippy::float_cmp)] // identity to the bit is the claim
fn objective_gradient_matches_central_differences_without_log_jacobians() {
    check_objective_gradient_jacobians(true, (true, false), (Held::NONE, false), (false, true));
    check_objective_gradient_jacobians(true, (true, false), (Held::NONE, false), (true, false));
    check_objective_gradient_jacobians(false, (false, false), (Held::NONE, false), (false, false));
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(6) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1500.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let eta = [0.3, 1.5, 0.2, -0.2, 0.4, 0.25];
    let run = |in_marginal: bool| {
        let mut v = variances_quant(&eta, input.sample_time_s, Held::NONE);
        v.coloured_jacobian_in_marginal = in_marginal;
        run_window(&input, &w, &th, &th, &v, filter::Mode::full(true, true), None).expect("window")
    };
    let (with, without) = (run(true), run(false));
    assert!(with.correction.abs() > 0.0, "the term is present here: {}", with.correction);
    assert_eq!(with.correction_profile_only, 0.0);
    assert_eq!(without.correction_profile_only, without.correction);
    assert_eq!(without.merit(), with.merit() - with.correction);
    assert_eq!((without.profile(), without.grad_profile), (with.profile(), with.grad_profile));
}

/// The exact counting model of quantisation (remainder states): ∂M, ∂J
/// against central differences, covariance following θ with the fitted
/// input (the library's default filter) and covariance held.
#[test]
fn objective_gradient_matches_central_differences_counting_quantisation() {
    check_objective_gradient_with(true, true, true);
    check_objective_gradient_with(false, false, true);
}

/// ∂ν/∂p and ∂S/∂p of the counting model against central differences.
#[test]
fn innovation_derivatives_match_central_differences_counting_quantisation() {
    check_innovation_derivatives_with(true, true, true);
}

/// The quantisation level given (not scaled by η_0,
/// [`QuantisationLevel::Given`]): ∂M, ∂J, ∂ν/∂p and ∂S/∂p against central
/// differences with the counting model, and ∂M, ∂J with the rate-noise model
/// (fitted and measured input) and the measurement model (covariance following θ).
#[test]
fn derivatives_match_central_differences_quantisation_given() {
    check_objective_gradient_quant(true, true, true, (Held::QUANT, false));
    check_innovation_derivatives_quant(true, true, true, Held::QUANT);
    check_objective_gradient_quant(true, true, false, (Held::QUANT, false));
    check_objective_gradient_quant(true, false, false, (Held::QUANT, false));
    check_objective_gradient_quant(true, true, false, (Held::QUANT, true));
}

/// a_y and β noise held at the model's σ ([`LateralNoise::Stated`], not
/// scaled by η_0): ∂M, ∂J, ∂ν/∂p and ∂S/∂p against central differences
/// (counting quantisation, covariance following θ; and ∂M, ∂J with the
/// covariance held).
#[test]
fn derivatives_match_central_differences_lateral_noise_stated() {
    check_objective_gradient_quant(true, true, true, (Held::LATERAL, false));
    check_innovation_derivatives_quant(true, true, true, Held::LATERAL);
    check_objective_gradient_quant(false, false, true, (Held::LATERAL, false));
}

/// a_y's noise held on its own (`ResearchOptions::a_y_sigma_held`) while
/// η_0 still scales β's: ∂M, ∂J, ∂ν/∂p and ∂S/∂p against central
/// differences (counting quantisation, covariance following θ; and ∂M, ∂J
/// with the covariance held).
#[test]
fn derivatives_match_central_differences_a_y_held() {
    check_objective_gradient_quant(true, true, true, (Held::A_Y, false));
    check_innovation_derivatives_quant(true, true, true, Held::A_Y);
    check_objective_gradient_quant(false, false, true, (Held::A_Y, false));
}

#[test]
fn innovation_derivatives_match_central_differences_fitted_input() {
    check_innovation_derivatives_with(true, true, false);
}

/// With the fitted-input scale the relative wheel noise in metres does not
/// grow with c_e: at θ = θ_ref the filter is the measured-input filter, and
/// +1 % on c_e leaves S nearly unchanged where the measured-input S grows by
/// about 2 % (variance ∝ C²). Wheel noise only (no quantisation, reference,
/// a_y or β noise beyond the 1 mm floors), so S is the wheel part.
#[test]
fn fitted_input_scale_removes_the_growth_of_s_with_c_e() {
    let out = simulate(&SimOptions { length_km: 0.3, ..SimOptions::paper(7) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 600.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let wheels_only = NoiseModel {
        quantisation_step_rev_per_s: 0.0,
        position_white_sigma_m: 0.0,
        heading_white_sigma_rad: 0.0,
        position_drift_sigma_m: 0.0,
        heading_drift_sigma_rad: 0.0,
        lateral_acceleration_sigma_m_per_s2: 0.0,
        sideslip_sigma_rad: 0.0,
        ..NoiseModel::default()
    };
    let run = |t: &Theta, fitted: bool| {
        let mut v = wheels_only.variances(&[0.0; 6], input.sample_time_s);
        v.fitted_input = fitted;
        // The base formulation's 1 mm floor: with 5 mm, R dominates S_xx on this short window.
        v.position_floor_m = BASE_POSITION_FLOOR_M;
        let mut rec = Vec::new();
        run_window(&input, &w, t, &th, &v, filter::Mode::full(true, false), Some(&mut rec)).expect("window");
        rec
    };
    let (same, measured) = (run(&th, true), run(&th, false));
    // At θ = θ_ref the factor C(θ_ref)/C(θ) is 1 to rounding (the two
    // circumference formulas may differ by an ulp), so S agrees to rounding
    // amplified by the recursion.
    for (a, b) in same.iter().zip(&measured) {
        assert!((a.s - b.s).amax() <= 1e-10 * b.s.amax(), "θ = θ_ref: {} vs {}", a.s, b.s);
    }
    let big = Theta { c_e: th.c_e * 1.01, ..th };
    let (fitted_big, measured_big) = (run(&big, true), run(&big, false));
    let k = measured.len() - 1;
    let growth = |a: &InnovationRecord, b: &InnovationRecord| a.s[(0, 0)] / b.s[(0, 0)] - 1.0;
    let (g_meas, g_fit) = (growth(&measured_big[k], &measured[k]), growth(&fitted_big[k], &same[k]));
    assert!(g_meas > 0.015, "measured-input S_xx grew by {g_meas}");
    assert!(g_fit.abs() < 0.1 * g_meas, "fitted-input S_xx grew by {g_fit} (measured {g_meas})");
}

#[test]
fn objective_gradient_matches_central_differences_covariance_held() {
    check_objective_gradient(false);
}

#[test]
fn objective_gradient_matches_central_differences_covariance_follows_theta() {
    check_objective_gradient(true);
}

/// The input log-Jacobian term ([`InputJacobian`]): with unit weights (θ
/// independent) its value, gradient and Hessian and the profile gradient
/// that includes it match central differences; the smoothed-share weight
/// equals `∂(Σ ln det S)/∂ln σ_white²` (central differences over the white
/// relative variance) and is at least the filtered share.
#[test]
fn input_jacobian_derivatives_match_central_differences() {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(6) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1500.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let th_ref = Theta { c_e: 1.96, c_d: -0.001, d: 0.0012, ..th };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    let variances = |jac: InputJacobian, white_scale: f64| {
        let mut v = NoiseModel::default().variances(&eta, input.sample_time_s);
        v.fitted_input = true;
        v.input_jacobian = jac;
        v.white_rel *= white_scale;
        v
    };
    let run = |t: &Theta, jac: InputJacobian, mode: filter::Mode, white_scale: f64| {
        run_window(&input, &w, t, &th_ref, &variances(jac, white_scale), mode, None).expect("window")
    };
    let full = filter::Mode::full(true, false);
    let base = run(&th, InputJacobian::Unit, full, 1.0);
    let none = run(&th, InputJacobian::None, full, 1.0);
    assert!(base.jacobian != 0.0 && base.turning[0] > 1000.0, "term {} on {:?}", base.jacobian, base.turning);
    // Unit weight: Σ u is the count of turning samples, exactly.
    assert!(
        base.jacobian_weight.iter().zip(&base.turning).all(|(u, m)| (u - m).abs() < 0.5),
        "{:?}",
        base.jacobian_weight
    );
    // The term is part of J and its θ-derivatives, not of M.
    assert!((base.merit() - none.merit()).abs() <= 1e-12 * none.merit().abs(), "M changed");
    assert!((base.profile() - none.profile() - base.jacobian).abs() <= 1e-9 * base.profile().abs());
    let hess = base.hess_jacobian;
    assert!((base.h_theta - none.h_theta - hess).amax() <= 1e-9 * base.h_theta.amax());
    for p in 0..4 {
        let h = 1e-6 * [th.c_e, 1.0, th.t_r, 1.0][p];
        let (sp, sm) = (
            run(&perturb(&th, p, h), InputJacobian::Unit, full, 1.0),
            run(&perturb(&th, p, -h), InputJacobian::Unit, full, 1.0),
        );
        let fd = (sp.jacobian - sm.jacobian) / (2.0 * h);
        let g = base.grad_jacobian[p];
        assert!((g - fd).abs() <= 1e-6 * g.abs().max(fd.abs()).max(1e-6), "∂T/∂θ{p}: {g} vs {fd}");
        let fd_j = (sp.profile() - sm.profile()) / (2.0 * h);
        let g_j = base.grad_profile[p];
        assert!((g_j - fd_j).abs() <= 1e-4 * g_j.abs().max(fd_j.abs()).max(1e-6), "∂J/∂θ{p}: {g_j} vs {fd_j}");
        for q in 0..4 {
            let fd_h = (sp.grad_jacobian[q] - sm.grad_jacobian[q]) / (2.0 * h);
            let scale = hess[(p, p)].abs().max(hess[(q, q)].abs()).max(1e-6);
            assert!((hess[(p, q)] - fd_h).abs() <= 1e-6 * scale, "∂²T/∂θ{p}∂θ{q}: {} vs {fd_h}", hess[(p, q)]);
        }
    }
    // Smoothed share: Σ_w W_w = ∂(Σ ln det S)/∂ln(σ_white²).
    let smoothed = run(&th, InputJacobian::SmoothedShare, filter::Mode::cost(true), 1.0);
    let h: f64 = 1e-4;
    let (lp, lm) = (
        run(&th, InputJacobian::None, filter::Mode::cost(true), h.exp()).logdet,
        run(&th, InputJacobian::None, filter::Mode::cost(true), (-h).exp()).logdet,
    );
    let fd = (lp - lm) / (2.0 * h);
    let total = smoothed.jacobian_weight[0] + smoothed.jacobian_weight[1];
    assert!(total > 0.0 && (total - fd).abs() <= 1e-5 * fd.abs(), "smoothed weight {total} vs {fd}");
    let filtered = run(&th, InputJacobian::FilterShare, filter::Mode::cost(true), 1.0);
    for k in 0..2 {
        let (f, s) = (filtered.jacobian_weight[k], smoothed.jacobian_weight[k]);
        assert!(f > 0.0 && f <= s * (1.0 + 1e-9) && s < smoothed.turning[k], "wheel {k}: filtered {f}, smoothed {s}");
    }
}

/// With the relative noise scaled by the moving average of ñ
/// ([`WheelNoiseScale::SmoothedFittedInput`]) the gradients of M and of J
/// (with the unit-weight Jacobian term) still match central differences,
/// and the filter differs from the plain fitted-input one.
#[test]
fn smoothed_fitted_input_gradients_match_central_differences() {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(6) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1500.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let th_ref = Theta { c_e: 1.96, c_d: -0.001, d: 0.0012, ..th };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    let variances = |e: &[f64; 6], half: usize| {
        let mut v = NoiseModel::default().variances(e, input.sample_time_s);
        v.fitted_input = true;
        v.noise_input_half_width = half;
        v.input_jacobian = InputJacobian::Unit;
        v
    };
    let run = |t: &Theta, e: &[f64; 6], mode: filter::Mode, half: usize| {
        run_window(&input, &w, t, &th_ref, &variances(e, half), mode, None).expect("window")
    };
    let base = run(&th, &eta, filter::Mode::full(true, true), 20);
    let plain = run(&th, &eta, filter::Mode::full(true, true), 0);
    assert!((base.quad - plain.quad).abs() > 1e-6 * plain.quad.abs(), "smoothing changed nothing");
    for p in 0..9 {
        let (tp, tm, ep, em, h) = perturbed_pair(&th, &eta, p);
        let (sp, sm) = (run(&tp, &ep, filter::Mode::cost(true), 20), run(&tm, &em, filter::Mode::cost(true), 20));
        for (what, fd, g) in [
            ("M", (sp.merit() - sm.merit()) / (2.0 * h), base.grad[p]),
            ("J", (sp.profile() - sm.profile()) / (2.0 * h), base.grad_profile[p]),
        ] {
            assert!((g - fd).abs() <= 1e-4 * g.abs().max(fd.abs()).max(1e-6), "∂{what}/∂p{p}: {g} vs {fd}");
        }
    }
}

/// The θ-score's log-Jacobian term moves with η through its
/// FilterShare weights u = var·fᵀS⁻¹f; the filter sums that derivative
/// exactly (`grad_jacobian_eta`). Against central differences in η of the
/// term itself, on a short high-noise drive at a point off the fit.
#[test]
fn log_jacobian_eta_derivative_matches_finite_differences() {
    let out =
        simulate(&SimOptions { length_km: 1.0, noise: NoiseOptions::high(), ..SimOptions::paper(3) }).expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions::default();
    assert_eq!(opts.research.input_jacobian, InputJacobian::FilterShare, "the default this test is about");
    let prob = Problem::new(&input, make_windows(input.parts, opts.window_samples), &opts);
    let th = out.sidecar.theta_true;
    let th_ref = Theta { c_e: th.c_e * 1.002, t_r: th.t_r * 1.01, ..th };
    let eta = [0.3, -0.2, 0.1, 0.2, -0.5, 0.1];
    let ev = prob.evaluate(&th, &th_ref, &eta, filter::Mode::full(true, true)).expect("filter");
    let h = 1e-5;
    for j in 0..NETA {
        let at = |sign: f64| {
            let mut e = eta;
            e[j] += sign * h;
            prob.evaluate(&th, &th_ref, &e, filter::Mode::full(true, false)).expect("filter").total.grad_jacobian
        };
        let fd = (at(1.0) - at(-1.0)) / (2.0 * h);
        let got = ev.total.grad_jacobian_eta[j];
        let scale = fd.amax().max(got.amax());
        assert!(scale > 0.0 || j == 4, "η{j}: the weights do not move at all");
        assert!((got - fd).amax() <= 1e-5 * scale + 1e-9, "η{j}: exact {got:?} vs central differences {fd:?}");
    }
}

/// The reference drift untied (the research options
/// `position_drift_own_scale`, `position_drift_time_constant_s`): the heading
/// drift on the heading white noise's scale η_5, the position drift alone on
/// η_4 with its own correlation time. ∂ν, ∂S over η and ∂M, ∂J over θ and η
/// against central differences, with the heading white noise on its own
/// scale and tied to the position's (η_3).
#[test]
fn derivatives_match_central_differences_position_drift_own_scale() {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1200.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    let m = NoiseModel { heading_drift_sigma_rad: 0.004, ..NoiseModel::default() };
    for separate in [true, false] {
        let opts = EivOptions {
            noise: m,
            heading_scale: if separate { HeadingScale::Separate } else { HeadingScale::TiedToPosition },
            ..EivOptions::default()
        };
        let mut prob = Problem::new(&input, vec![w], &opts);
        prob.position_drift_own_scale = true;
        prob.position_drift_time_constant_s = Some(20.0);
        let v0 = prob.variances(&eta, false);
        let heading_eta = if separate { eta[5] } else { eta[3] };
        assert!((v0.drift[2] / (m.heading_drift_sigma_rad.powi(2) * heading_eta.exp()) - 1.0).abs() < 1e-12);
        assert!(v0.a_drift < v0.a_drift_heading, "the position drift's own, shorter correlation time");
        assert_window_derivatives(&prob, &input, &w, &th, &eta);
        // The heading drift responds to the heading white noise's scale, not η_4.
        let (mut e4, mut eh) = (eta, eta);
        e4[4] += 1.0;
        if separate {
            eh[5] += 1.0;
        } else {
            eh[3] += 1.0;
        }
        assert!((prob.variances(&e4, false).drift[2] - v0.drift[2]).abs() <= 1e-15 * v0.drift[2]);
        assert!(prob.variances(&eh, false).drift[2] > v0.drift[2]);
    }
}

/// The heading drift held at its floor below it
/// (`heading_drift_min_eta`, the default): there η_4 scales the position
/// drift alone; above it the tie holds. ∂ν, ∂S over η and ∂M, ∂J over θ and
/// η against central differences with η_4 below the floor.
#[test]
fn derivatives_match_central_differences_heading_drift_floor() {
    let out = simulate(&SimOptions { length_km: 0.6, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1200.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let eta = [0.3, -0.5, 0.2, -0.2, -4.0, 0.25];
    let opts = EivOptions::default();
    let floor = opts.research.heading_drift_min_eta;
    assert!(floor > eta[4] && floor < -1.0, "the default this test is about");
    let m = opts.noise;
    let prob = Problem::new(&input, vec![w], &opts);
    let v0 = prob.variances(&eta, false);
    assert!((v0.drift[2] / (m.heading_drift_sigma_rad.powi(2) * floor.exp()) - 1.0).abs() < 1e-12, "at the floor");
    assert!((v0.drift[0] / (m.position_drift_sigma_m.powi(2) * eta[4].exp()) - 1.0).abs() < 1e-12);
    // Above the floor the heading drift follows η_4 (the tie).
    let mut up = eta;
    up[4] = -1.0;
    let v_up = prob.variances(&up, false);
    assert!((v_up.drift[2] / (m.heading_drift_sigma_rad.powi(2) * up[4].exp()) - 1.0).abs() < 1e-12);
    assert!(!v_up.heading_drift_held && v0.heading_drift_held);
    assert_window_derivatives(&prob, &input, &w, &th, &eta);
}

/// ∂ν, ∂S over η at a few updates and ∂M, ∂J over θ and η against central
/// differences, for window `w` of `prob` at (θ, η).
fn assert_window_derivatives(prob: &Problem, input: &EivInput<'_>, w: &Window, th: &Theta, eta: &[f64; 6]) {
    let (th, eta) = (*th, *eta);
    let run = |t: &Theta, e: &[f64; 6], derivs: bool, rec: Option<&mut Vec<InnovationRecord>>| {
        let mode = if derivs { filter::Mode::full(true, true) } else { filter::Mode::cost(true) };
        run_window(input, w, t, &th, &prob.variances(e, false), mode, rec).expect("window")
    };
    let mut base_rec = Vec::new();
    let base = run(&th, &eta, true, Some(&mut base_rec));
    let picks = [1usize, 2, 10, 300, 700, base_rec.len() - 1];
    for j in 0..NETA {
        let h = 1e-4;
        let (mut ep, mut em) = (eta, eta);
        ep[j] += h;
        em[j] -= h;
        let (mut rp, mut rm) = (Vec::new(), Vec::new());
        run(&th, &ep, true, Some(&mut rp));
        run(&th, &em, true, Some(&mut rm));
        let p = 4 + j;
        let scale_nu = base_rec.iter().map(|r| r.dnu.column(p).amax()).fold(0.0f64, f64::max).max(1e-12);
        let scale_s = base_rec.iter().map(|r| r.ds[p].amax()).fold(0.0f64, f64::max).max(1e-300);
        for &k in &picks {
            let (dnu, ds) = ((rp[k].nu - rm[k].nu) / (2.0 * h), (rp[k].s - rm[k].s) / (2.0 * h));
            let a = base_rec[k].dnu.column(p).into_owned();
            assert!((a - dnu).amax() <= FD_REL_TOL * scale_nu, "∂ν/∂η{j} at update {k}: {a} vs {dnu}");
            let a = base_rec[k].ds[p];
            assert!((a - ds).amax() <= FD_REL_TOL * scale_s, "∂S/∂η{j} at update {k}: {a} vs {ds}");
        }
    }
    for p in 0..4 + NETA {
        let (tp, tm, ep, em, h) = perturbed_pair(&th, &eta, p);
        let (sp, sm) = (run(&tp, &ep, false, None), run(&tm, &em, false, None));
        for (what, fd, g) in [
            ("M", (sp.merit() - sm.merit()) / (2.0 * h), base.grad[p]),
            ("J", (sp.profile() - sm.profile()) / (2.0 * h), base.grad_profile[p]),
        ] {
            assert!((g - fd).abs() <= 1e-4 * g.abs().max(fd.abs()).max(1e-6), "∂{what}/∂p{p}: {g} vs {fd}");
        }
    }
}
