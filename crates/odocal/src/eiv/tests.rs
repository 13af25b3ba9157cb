use super::filter::{run_window, InnovationRecord};
use super::*;
use crate::drive::segment::{calibration_segments, SegmentData, SegmentOptions};
use crate::drive::Drive;
use crate::identify::{batch_gauss_newton, IdentifyOptions};
use crate::sim::{simulate, NoiseOptions, SimOptions};

fn input_of(d: &Drive) -> EivInput<'_> {
    EivInput::from_drive(d)
}

/// Batch Gauss-Newton on every cut segment (no yaw-rate selection).
fn batch_gn_all(d: &Drive) -> Theta {
    let sel = calibration_segments(d, &SegmentOptions::default()).expect("segments");
    let data: Vec<SegmentData> = sel.all.iter().map(|s| SegmentData::new(d, s)).collect();
    let opts = IdentifyOptions { max_iterations: 20, ..Default::default() };
    batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("batch G-N").theta
}

fn records(
    input: &EivInput<'_>,
    w: &Window,
    th: &Theta,
    th_ref: &Theta,
    eta: &[f64; 6],
    follows: bool,
) -> Vec<InnovationRecord> {
    records_with(input, w, th, th_ref, eta, follows, (false, false))
}

fn records_with(
    input: &EivInput<'_>,
    w: &Window,
    th: &Theta,
    th_ref: &Theta,
    eta: &[f64; 6],
    follows: bool,
    // (fitted input, counting quantisation)
    (fitted_input, counting): (bool, bool),
) -> Vec<InnovationRecord> {
    records_quant(input, w, th, th_ref, eta, follows, (fitted_input, counting), Held::NONE)
}

/// Which variances η_0 leaves alone in a derivative test: the quantisation
/// ([`QuantisationLevel::Given`]) and a_y and β ([`LateralNoise::Stated`]).
#[derive(Clone, Copy)]
struct Held {
    quant: bool,
    lateral: bool,
}

impl Held {
    const NONE: Held = Held { quant: false, lateral: false };
    const QUANT: Held = Held { quant: true, lateral: false };
    const LATERAL: Held = Held { quant: false, lateral: true };
}

/// [`records_with`]; `given`: the variances η_0 does not scale ([`Held`]).
#[allow(clippy::too_many_arguments)]
fn records_quant(
    input: &EivInput<'_>,
    w: &Window,
    th: &Theta,
    th_ref: &Theta,
    eta: &[f64; 6],
    follows: bool,
    (fitted_input, counting): (bool, bool),
    given: Held,
) -> Vec<InnovationRecord> {
    let mut v = variances_quant(eta, input.sample_time_s, given);
    v.fitted_input = fitted_input;
    v.quant_counting = counting;
    let mut rec = Vec::new();
    run_window(input, w, th, th_ref, &v, filter::Mode::full(follows, true), Some(&mut rec)).expect("window");
    rec
}

/// The default model's variances at η; with `given.quant` the quantisation
/// is held at q²/12, with `given.lateral` a_y and β at the model's σ (as
/// `Problem::evaluate_with` does for [`QuantisationLevel::Given`] and
/// [`LateralNoise::Stated`]).
fn variances_quant(eta: &[f64; 6], ts: f64, given: Held) -> filter::Variances {
    let m = NoiseModel::default();
    let mut v = m.variances(eta, ts);
    if given.quant {
        v.quant = m.quantisation_step_rev_per_s * m.quantisation_step_rev_per_s / 12.0;
        v.quant_scaled = false;
    }
    if given.lateral {
        let unscaled = m.variances(&[0.0; 6], ts);
        (v.a_y, v.beta, v.lateral_scaled) = (unscaled.a_y, unscaled.beta, false);
    }
    v
}

fn perturb(th: &Theta, i: usize, h: f64) -> Theta {
    let mut a = th.to_vector();
    a[i] += h;
    Theta::from_vector(&a)
}

/// Central differences with h ~1e-6 relative on a ~1000-step filter: the
/// truncation error is ~1e-10 relative, round-off amplified by the
/// recursion stays below ~1e-6 of the column scale.
const FD_REL_TOL: f64 = 2e-5;

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
fn check_objective_gradient_quant(follows: bool, fitted: bool, counting: bool, (given, measurement): (Held, bool)) {
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
        let (tp, tm, ep, em, h) = if p < 4 {
            let h = 1e-6 * [th.c_e, 1.0, th.t_r, 1.0][p];
            (perturb(&th, p, h), perturb(&th, p, -h), eta, eta, h)
        } else {
            let h = 1e-5;
            let (mut ep, mut em) = (eta, eta);
            ep[p - 4] += h;
            em[p - 4] -= h;
            (th, th, ep, em, h)
        };
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
        // SPEC's 1 mm floor: with 5 mm, R dominates S_xx on this short window.
        v.position_floor_m = SPEC_POSITION_FLOOR_M;
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

/// Noise-free, one substep: the model is exact; EIV must return θ_true to
/// rounding (the correction term with η at its lower clamp moves it by
/// ~1e-11) — the issue's bar.
const EXACT_REL_TOL: f64 = 1e-8;

#[test]
fn noise_free_recovers_theta_true_and_eta_at_lower_clamp() {
    let out = simulate(&SimOptions { length_km: 6.0, substeps: 1, ..SimOptions::noise_free(11) }).expect("sim");
    let truth = out.sidecar.theta_true;
    let input = input_of(&out.drive);
    let start = Theta { c_e: 1.96, c_d: -0.001, t_r: 1.55, d: 0.0005 };
    let opts = EivOptions::default();
    let r = estimate(&input, &start, &opts).expect("eiv");
    let (e, t) = (r.theta.to_array(), truth.to_array());
    for i in 0..4 {
        let rel = (e[i] - t[i]).abs() / t[i].abs();
        assert!(rel <= EXACT_REL_TOL, "{}: {} vs {} (rel {rel:.2e}); {r}", PARAMETERS[i], e[i], t[i]);
    }
    for j in 0..NETA {
        assert!(r.eta[j] <= opts.eta_bounds[0] + 1e-9, "η{j} = {} not at the lower clamp; {r}", r.eta[j]);
    }
    assert!(!r.warnings.iter().any(|w| matches!(w, EivWarning::NoiseAtUpperClamp { .. })), "{:?}", r.warnings);
}

/// [`LateralNoise::Stated`] on a noise-free straight drive: the tie drives
/// every noise scale to its lower clamp and returns c_e exactly; stated a_y
/// and β noise (the production car's) that the data do not have stays in
/// the model and costs c_e's information (its σ many times the tie's) —
/// why `Stated` is not the default (see its docs).
#[test]
fn stated_lateral_noise_costs_information_the_data_do_not_lack() {
    let (n, th) = (4000, Theta::SIM_DEFAULT_TRUE);
    let drive = StraightDrive::new(n, 0.025);
    let input = drive.input();
    let start = Theta { c_e: 1.96, ..th };
    let tied = estimate(&input, &start, &EivOptions::default()).expect("eiv");
    let stated = EivOptions { lateral_noise: LateralNoise::Stated, ..Default::default() };
    let stated = estimate(&input, &start, &stated).expect("eiv");
    assert!((tied.theta.c_e - th.c_e).abs() < 1e-6, "{tied}");
    assert!(stated.sigma[0] > 100.0 * tied.sigma[0], "σ c_e: stated {:e}, tied {:e}", stated.sigma[0], tied.sigma[0]);
    // Still an honest σ: the stated fit's c_e within 3 of its σ.
    assert!((stated.theta.c_e - th.c_e).abs() < 3.0 * stated.sigma[0], "{stated}");
    assert!((stated.noise.sideslip_sigma_rad - NoiseModel::default().sideslip_sigma_rad).abs() < 1e-15);
}

/// The same with encoder quantisation modelled by counting (remainder
/// states): θ_true to rounding. Ignored by default (a second 6 km fit is
/// too slow for the debug test budget; a 1.5 km drive leaves t_r
/// unobservable): `cargo test --release -p odocal --lib -- --ignored counting`.
#[test]
#[ignore = "slow in debug; run in release with --ignored"]
fn noise_free_recovers_theta_true_with_counting_quantisation() {
    let out = simulate(&SimOptions { length_km: 6.0, substeps: 1, ..SimOptions::noise_free(11) }).expect("sim");
    let truth = out.sidecar.theta_true;
    let input = input_of(&out.drive);
    let start = Theta { c_e: 1.96, c_d: -0.001, t_r: 1.55, d: 0.0005 };
    let opts = EivOptions { quantisation: QuantisationModel::Counting, ..Default::default() };
    let r = estimate(&input, &start, &opts).expect("eiv");
    let (e, t) = (r.theta.to_array(), truth.to_array());
    for i in 0..4 {
        let rel = (e[i] - t[i]).abs() / t[i].abs();
        assert!(rel <= EXACT_REL_TOL, "{}: {} vs {} (rel {rel:.2e}); {r}", PARAMETERS[i], e[i], t[i]);
    }
}

/// A white-noise drive (0.8 % per sample, the paper's size; seed 1 of the
/// study's `white` preset) where batch G-N's t_r is measurably off (+3.0 %):
/// EIV with the right (fixed) noise model is within 3 of its σ (+0.5 %)
/// and closer than G-N.
#[test]
fn white_noise_drive_beats_batch_gauss_newton_on_t_r() {
    let noise = NoiseOptions::white_wheel_only();
    let out = simulate(&SimOptions { length_km: 12.0, noise: noise.clone(), ..SimOptions::paper(1) }).expect("sim");
    let truth = out.sidecar.theta_true;
    let gn = batch_gn_all(&out.drive);
    let input = input_of(&out.drive);
    let known = EivOptions {
        noise: NoiseModel::from_sim(&noise, input.sample_time_s),
        fix_noise: true,
        ..EivOptions::default()
    };
    let r = estimate(&input, &gn, &known).expect("eiv");
    let gn_err = (gn.t_r - truth.t_r).abs();
    let eiv_err = (r.theta.t_r - truth.t_r).abs();
    eprintln!(
        "t_r: G-N {:.5} (err {gn_err:.2e}), EIV {:.5} ± {:.1e} (err {eiv_err:.2e}); {r}",
        gn.t_r, r.theta.t_r, r.sigma[2]
    );
    // G-N is measurably off: more than 3 of EIV's σ.
    assert!(gn_err > 3.0 * r.sigma[2], "G-N t_r error {gn_err:.2e} not measurable against σ {:.2e}", r.sigma[2]);
    assert!(eiv_err <= 3.0 * r.sigma[2], "EIV t_r error {eiv_err:.2e} > 3σ = {:.2e}", 3.0 * r.sigma[2]);
    assert!(eiv_err < gn_err);
}

/// With 2 % white wheel noise, η estimated from the production-car start
/// and the heading white noise on its own scale, the fit runs away
/// (measured: t_r +250 %, the per-wheel scale at its upper clamp; with the
/// tied scale it returned c_e +9 … +11 % on seeds 1–2 instead). It must say
/// so, so that `calibrate` falls back: a noise scale at its upper clamp or
/// no convergence.
#[test]
fn runaway_estimated_noise_is_flagged() {
    let noise = NoiseOptions { wheel_white_rel_sigma: 0.02, ..NoiseOptions::white_wheel_only() };
    let out = simulate(&SimOptions { length_km: 8.0, noise, ..SimOptions::paper(3) }).expect("sim");
    let truth = out.sidecar.theta_true;
    let gn = batch_gn_all(&out.drive);
    let opts = EivOptions { heading_scale: HeadingScale::Separate, ..EivOptions::default() };
    let est = estimate(&input_of(&out.drive), &gn, &opts).expect("eiv");
    let err = (est.theta.t_r - truth.t_r).abs();
    if err > 3.0 * est.sigma[2] {
        assert!(
            est.warnings.iter().any(|w| matches!(
                w,
                EivWarning::NoiseAtUpperClamp { .. }
                    | EivWarning::NotConverged { .. }
                    | EivWarning::FilterDiverged { .. }
            )),
            "estimated-η fit off by {err:.2e} (σ {:.1e}) without a warning: {est}",
            est.sigma[2]
        );
    }
}

#[test]
fn report_is_identical_for_one_and_two_threads() {
    let out = simulate(&SimOptions { length_km: 4.0, ..SimOptions::paper(21) }).expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions { window_samples: 1500, ..Default::default() };
    let start = Theta { c_e: 1.952, c_d: -0.0018, t_r: 1.54, d: 0.0007 };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let mut r = pool.install(|| estimate(&input, &start, &opts)).expect("eiv");
        r.timing_s = 0.0;
        serde_json::to_string(&r).expect("json")
    };
    assert_eq!(run(1), run(2));
}

#[test]
fn straight_drive_calibrates_c_e_and_names_the_rest() {
    // A straight, noise-free drive: heading never changes.
    let (n, ts) = (4000, 0.025);
    let th = Theta::SIM_DEFAULT_TRUE;
    let drive = StraightDrive::new(n, ts);
    let input = drive.input();
    let start = Theta { c_e: 1.96, ..th };
    let r = estimate(&input, &start, &EivOptions::default()).expect("eiv");
    assert!((r.theta.c_e - th.c_e).abs() < 1e-6, "{r}");
    assert!(r.observability.unobservable.contains(&Parameter::TR), "{:?}", r.observability);
    assert!(r.observability.unobservable.contains(&Parameter::D), "{:?}", r.observability);
    assert!(!r.free[2] && !r.free[3] && r.free[0]);
    assert!(r.warnings.iter().any(|w| matches!(w, EivWarning::Unobservable { .. })));

    // A start whose unobservable t_r and d are far off (batch G-N's value on
    // a straight drive is arbitrary): by default they stay at the start,
    // with `hold_unobservable_at` at the given θ_0; c_e is estimated either way.
    let bad_start = Theta { c_e: 1.96, t_r: 5.63, d: 0.01, ..th };
    let at_start = estimate(&input, &bad_start, &EivOptions::default()).expect("eiv");
    assert_eq!((at_start.theta.t_r, at_start.theta.d), (5.63, 0.01), "{at_start}");
    let held = EivOptions { hold_unobservable_at: Some(th), ..Default::default() };
    let at_theta0 = estimate(&input, &bad_start, &held).expect("eiv");
    assert_eq!((at_theta0.theta.t_r, at_theta0.theta.d), (th.t_r, th.d), "{at_theta0}");
    assert!((at_theta0.theta.c_e - th.c_e).abs() < 1e-6, "{at_theta0}");
    let invalid = EivOptions { hold_unobservable_at: Some(Theta { t_r: f64::NAN, ..th }), ..Default::default() };
    assert!(estimate(&input, &bad_start, &invalid).is_err());
}

#[test]
fn updates_only_where_the_reference_was_measured() {
    let out = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(2) }).expect("sim");
    let mut input = input_of(&out.drive);
    let mask: Vec<bool> = (0..input.len()).map(|k| k % 4 == 0).collect();
    input.reference_measured = Some(&mask);
    let w = Window { index: 0, part: 0, start: 0, end: input.len() - 1 };
    let v = NoiseModel::default().variances(&[0.0; 6], input.sample_time_s);
    let th = Theta::SIM_DEFAULT_TRUE;
    let s = run_window(&input, &w, &th, &th, &v, filter::Mode::full(false, false), None).expect("window");
    assert_eq!(s.updates, (1..input.len()).filter(|k| k % 4 == 0).count());
}

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

/// The bound at θ_true is linearised along the true inputs (stop 25):
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

fn known_noise_fit(km: f64, seed: u64) -> (crate::sim::SimOutput, EivOptions) {
    let out = simulate(&SimOptions { length_km: km, ..SimOptions::paper(seed) }).expect("sim");
    let noise = NoiseModel::from_sim(&out.sidecar.settings.noise, out.drive.sample_time_s());
    (out, EivOptions { noise, fix_noise: true, ..Default::default() })
}

#[test]
fn bootstrap_is_identical_for_one_and_two_threads() {
    let (out, opts) = known_noise_fit(2.0, 31);
    let input = input_of(&out.drive);
    let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let boot = BootstrapOptions { replicates: 4, seed: 9, ..Default::default() };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        let b = pool.install(|| bootstrap(&input, &r, &opts, &boot)).expect("bootstrap");
        serde_json::to_string(&b).expect("json")
    };
    let one = run(1);
    assert_eq!(one, run(2));
    // Another seed gives other replicates.
    let other = bootstrap(&input, &r, &opts, &BootstrapOptions { seed: 10, ..boot }).expect("bootstrap");
    assert_ne!(one, serde_json::to_string(&other).expect("json"));
}

/// Paper noise, 6 km, the true noise model fixed, 40 replicates.
/// Until stop 19 c_e θ̂ was off by +0.090 % here (2.6 reported σ), and the
/// bootstrap's bias estimate +0.077 % brought it to +0.013 %. With the
/// sideslip error a filter state ([`SideslipNoise::GaussMarkovState`])
/// c_e θ̂ is off by +0.009 % (0.2σ) and the bootstrap finds no c_e bias
/// beyond its Monte Carlo error: the bias was the white-equivalent
/// sideslip noise, which the bootstrap's replicates (simulated from the
/// same model) shared. t_r is −1.1 % off here (2.3σ, an unlucky draw), so
/// the assertion for every parameter is the 3σ one; 95 % coverage over
/// seeds is measured in `examples/study_eiv.rs`.
#[test]
fn bootstrap_brackets_the_truth_and_finds_no_c_e_bias_left() {
    let (out, opts) = known_noise_fit(6.0, 4);
    let truth = out.sidecar.theta_true.to_array();
    let input = input_of(&out.drive);
    let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let b = bootstrap(&input, &r, &opts, &BootstrapOptions { replicates: 40, seed: 1, ..Default::default() })
        .expect("bootstrap");
    assert!(b.failed.is_empty(), "{:?}", b.failed);
    for i in 0..4 {
        let [lo, hi] = b.interval_basic[i];
        eprintln!(
            "{}: truth {:.6e}, θ̂ {:.6e}, basic [{lo:.6e}, {hi:.6e}], percentile {:?}, bias {:.2e}, sd {:.2e}, σ {:.2e}",
            PARAMETERS[i],
            truth[i],
            r.theta.to_array()[i],
            b.interval[i],
            b.bias[i],
            b.sd[i],
            r.sigma[i]
        );
        let off = (b.theta_corrected.to_array()[i] - truth[i]).abs();
        assert!(
            off <= 3.0 * b.sd[i],
            "{}: bias-corrected error {off:.2e} > 3 sd = {:.2e}",
            PARAMETERS[i],
            3.0 * b.sd[i]
        );
        if i == 0 {
            assert!(lo <= truth[i] && truth[i] <= hi, "c_e: {} outside the basic [{lo}, {hi}]", truth[i]);
        }
        let ratio = (hi - lo) / (2.0 * 1.96 * r.sigma[i]);
        assert!((1.0 / 3.0..3.0).contains(&ratio), "{}: interval / reported ±1.96σ = {ratio}", PARAMETERS[i]);
    }
    let raw = (r.theta.c_e - truth[0]).abs();
    assert!(raw <= 2.0 * r.sigma[0], "c_e error {raw:.2e} > 2σ = {:.2e}", 2.0 * r.sigma[0]);
    let mc = 3.0 * b.sd[0] / (b.replicates.len() as f64).sqrt();
    assert!(b.bias[0].abs() <= mc, "c_e bootstrap bias {:.2e} beyond 3 Monte Carlo se {mc:.2e}", b.bias[0]);
}

/// The heading white noise has its own scale (η_5): scaling it leaves the
/// position noise alone, and η_3 leaves the heading alone.
#[test]
fn heading_and_position_white_noise_scale_separately() {
    let m = NoiseModel::PRODUCTION_CAR;
    let mut eta = [0.0; NETA];
    eta[5] = 2.0f64.ln() * 2.0; // σ × 2
    let s = m.scaled(&eta);
    assert!((s.position_white_sigma_m - m.position_white_sigma_m).abs() < 1e-15);
    assert!((s.heading_white_sigma_rad - 2.0 * m.heading_white_sigma_rad).abs() < 1e-15);
    let mut eta = [0.0; NETA];
    eta[3] = 2.0f64.ln() * 2.0;
    let s = m.scaled(&eta);
    assert!((s.heading_white_sigma_rad - m.heading_white_sigma_rad).abs() < 1e-15);
    assert!((s.position_white_sigma_m - 2.0 * m.position_white_sigma_m).abs() < 1e-15);
    assert_eq!(NOISE_SOURCES[5], NoiseSource::HeadingWhite);
}

/// `BiasCorrection::Bootstrap` subtracts exactly what [`bootstrap`] with the
/// same seed estimates (c_e only, or every parameter); the uncorrected
/// root is the plain fit's θ, whose first-order bias diagnostic is there.
/// Two replicates on 1 km keep it cheap (this checks the plumbing; the
/// correction's effect over seeds is measured in `examples/study_eiv.rs`).
#[test]
fn bootstrap_bias_correction_subtracts_the_bootstrap_bias() {
    let (out, opts) = known_noise_fit(1.0, 12);
    let input = input_of(&out.drive);
    let start = out.sidecar.theta_true;
    let plain = estimate(&input, &start, &opts).expect("eiv");
    assert_eq!(plain.theta, plain.theta_uncorrected);
    let bits = |a: [f64; 4]| a.map(f64::to_bits);
    assert_eq!(bits(plain.bias_subtracted), bits([0.0; 4]));
    let fo = plain.first_order_bias.expect("first-order bias with the covariance following θ");
    assert!(fo.bias.iter().all(|b| b.is_finite()), "{fo:?}");

    let boot = bootstrap(&input, &plain, &opts, &BootstrapOptions { replicates: 2, seed: 3, ..Default::default() })
        .expect("bootstrap");
    for all_parameters in [false, true] {
        let corr = BiasCorrection::Bootstrap { replicates: 2, seed: 3, all_parameters };
        let r = estimate(&input, &start, &EivOptions { bias_correction: corr, ..opts.clone() }).expect("eiv");
        assert_eq!(r.theta_uncorrected, plain.theta);
        let want = if all_parameters { boot.bias } else { [boot.bias[0], 0.0, 0.0, 0.0] };
        assert!(want[0] != 0.0, "the bootstrap found no c_e bias at all: {want:?}");
        assert_eq!(bits(r.bias_subtracted), bits(want));
        // Bit-exact: the correction is one subtraction.
        let p = plain.theta.to_array();
        let shifted: [f64; 4] = std::array::from_fn(|i| p[i] - want[i]);
        assert_eq!(bits(r.theta.to_array()), bits(shifted));
        // The σ of a corrected parameter carries the Monte Carlo error of the
        // subtracted mean (replicates' variance / B); the others are unchanged.
        let mc = boot.mean_covariance();
        for i in 0..4 {
            let corrected = plain.free[i] && (all_parameters || i == 0);
            let want_var = plain.sigma[i].powi(2) + if corrected { mc[i][i] } else { 0.0 };
            assert!(
                (r.sigma[i].powi(2) - want_var).abs() <= 1e-12 * want_var,
                "parameter {i}: σ² {} against {want_var}",
                r.sigma[i].powi(2)
            );
            let want_mc: f64 = if corrected { mc[i][i].sqrt() } else { 0.0 };
            assert_eq!(r.sigma_bias_correction[i].to_bits(), want_mc.to_bits(), "parameter {i}");
            assert!(!corrected || mc[i][i] > 0.0, "parameter {i}: no Monte Carlo variance");
        }
    }
    let one = BiasCorrection::Bootstrap { replicates: 1, seed: 0, all_parameters: false };
    let bad = EivOptions { bias_correction: one, ..opts };
    assert!(matches!(bad.validate(), Err(Error::InvalidOption { field: "bias_correction", .. })));
}

/// [`Problem::evaluate_many`] (the noise-estimate term's one sweep over
/// every (point, window) pair) gives each point's sums exactly as
/// [`Problem::evaluate`] one point at a time (a sweep of one point), with one
/// thread or two.
#[test]
fn evaluate_many_equals_evaluating_the_points_one_by_one() {
    let out = simulate(&SimOptions { length_km: 1.5, ..SimOptions::paper(8) }).expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions { window_samples: 700, ..EivOptions::default() };
    let windows = make_windows(input.parts, opts.window_samples);
    assert!(windows.len() >= 3, "{} windows", windows.len());
    let th = out.sidecar.theta_true;
    let points =
        [(th, [0.0; 6]), (Theta { t_r: th.t_r * 1.001, ..th }, [0.0; 6]), (th, [0.1, 0.0, 0.0, -0.2, 0.0, 0.3])];
    let mode = filter::Mode::full(true, false);
    // Per point: the window sums from the sweep and from `evaluate`.
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        pool.install(|| {
            let prob = Problem::new(&input, windows.clone(), &opts);
            let many = prob.evaluate_many(&points, &th, mode, false).expect("filter");
            let count = prob.evaluations.get();
            let pairs: Vec<_> = points
                .iter()
                .zip(many)
                .map(|((t, e), ev)| {
                    let one = prob.evaluate(t, &th, e, mode).expect("filter");
                    assert_eq!(ev.mode, one.mode);
                    ((ev.total, ev.windows), (one.total, one.windows))
                })
                .collect();
            (pairs, count)
        })
    };
    for threads in [1, 2] {
        let (pairs, count) = run(threads);
        assert_eq!(count, [points.len(), 0], "passes counted");
        assert_eq!(pairs.len(), points.len());
        for (i, (many, one)) in pairs.iter().enumerate() {
            assert_eq!(many, one, "point {i}, {threads} thread(s)");
        }
    }
}

/// With the noise scales estimated, [`BootstrapNoise::HeldAtFit`] fits the
/// replicates with the fitted noise model held (what `--correct-bias`
/// does): it subtracts exactly the bias of a bootstrap run with
/// `EivOptions { noise: fit.noise, fix_noise: true }`, and another bias
/// than the default re-estimating replicates. 2 km, 2 replicates: the
/// plumbing (the effect over seeds is in docs/study.md, stop 20).
#[test]
fn held_noise_bias_correction_fits_the_replicates_with_the_fitted_noise() {
    let out = simulate(&SimOptions { length_km: 2.0, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let start = out.sidecar.theta_true;
    let opts =
        EivOptions { bootstrap_inputs: BootstrapInputs::Smoothed { half_width_samples: 20 }, ..Default::default() };
    let plain = estimate(&input, &start, &opts).expect("eiv");
    assert!(plain.eta.iter().any(|e| *e != 0.0), "the noise scales were not estimated: {:?}", plain.eta);
    // ∂η̂/∂θ: rows of the estimated sources (σ > 0) only, columns of the free parameters only.
    let b = plain.eta_theta_sensitivity;
    for j in 0..NETA {
        for t in 0..4 {
            assert!(b[j][t].is_finite());
            if plain.eta_sigma[j] == 0.0 || !plain.free[t] {
                assert_eq!(b[j][t].to_bits(), 0.0f64.to_bits(), "source {j}, parameter {t}");
            }
        }
    }
    assert!(b.iter().flatten().any(|x| *x != 0.0), "{b:?}");
    let boot_opts = BootstrapOptions {
        replicates: 2,
        seed: 4,
        true_inputs: BootstrapInputs::Smoothed { half_width_samples: 20 },
        ..Default::default()
    };
    let held = EivOptions { noise: plain.noise, fix_noise: true, ..opts.clone() };
    let boot = bootstrap(&input, &plain, &held, &boot_opts).expect("bootstrap");
    let corr = BiasCorrection::Bootstrap { replicates: 2, seed: 4, all_parameters: true };
    let run = |noise: BootstrapNoise| {
        estimate(&input, &start, &EivOptions { bias_correction: corr, bootstrap_noise: noise, ..opts.clone() })
            .expect("eiv")
    };
    let r = run(BootstrapNoise::HeldAtFit);
    assert_eq!(r.theta_uncorrected, plain.theta);
    assert_eq!(r.bias_subtracted.map(f64::to_bits), boot.bias.map(f64::to_bits));
    let re = run(BootstrapNoise::Reestimated);
    assert_eq!(re.theta_uncorrected, plain.theta);
    assert_ne!(
        re.bias_subtracted.map(f64::to_bits),
        r.bias_subtracted.map(f64::to_bits),
        "re-estimating replicates gave the held-noise bias"
    );
}

/// Antithetic pairs ([`BootstrapOptions::antithetic`], what
/// [`EivOptions::correct_bias`] sets): the bias is the mean of the pairs'
/// means and its Monte Carlo covariance their spread over the number of
/// pairs; the pairs' means spread far less than single replicates (the odd
/// part of each replicate's error cancels); an odd B is refused; the
/// correction subtracts exactly that bootstrap's bias. 2 km, 8 replicates.
#[test]
fn antithetic_pairs_average_out_the_replicates_odd_error() {
    let out = simulate(&SimOptions { length_km: 2.0, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let start = out.sidecar.theta_true;
    let opts = EivOptions { fix_noise: true, ..Default::default() };
    let fit = estimate(&input, &start, &opts).expect("eiv");
    let smoothed = BootstrapInputs::Smoothed { half_width_samples: BIAS_BOOTSTRAP_SMOOTHING_SAMPLES };
    let boot_opts = |antithetic: bool, replicates: usize| BootstrapOptions {
        replicates,
        seed: 4,
        true_inputs: smoothed,
        antithetic,
        ..Default::default()
    };
    let anti = bootstrap(&input, &fit, &opts, &boot_opts(true, 8)).expect("bootstrap");
    let plain = bootstrap(&input, &fit, &opts, &boot_opts(false, 8)).expect("bootstrap");
    assert!(anti.failed.is_empty() && plain.failed.is_empty(), "{:?} {:?}", anti.failed, plain.failed);
    assert_eq!(anti.pair_means.len(), 4);
    assert!(plain.pair_means.is_empty());
    let hat = fit.theta.to_array();
    let pm: Vec<[f64; 4]> = anti.pair_means.iter().map(Theta::to_array).collect();
    for (j, m) in pm.iter().enumerate() {
        let (a, b) = (anti.replicates[2 * j].to_array(), anti.replicates[2 * j + 1].to_array());
        for i in 0..4 {
            assert_eq!(m[i].to_bits(), (0.5 * (a[i] + b[i])).to_bits(), "pair {j}, parameter {i}");
        }
    }
    let mc = anti.mean_covariance();
    for i in 0..4 {
        let mean = pm.iter().map(|m| m[i]).sum::<f64>() / 4.0;
        assert!((anti.mean.to_array()[i] - mean).abs() <= 1e-15 * mean.abs(), "parameter {i}");
        assert_eq!(anti.bias[i].to_bits(), (anti.mean.to_array()[i] - hat[i]).to_bits(), "parameter {i}");
        let var_pairs = pm.iter().map(|m| (m[i] - mean).powi(2)).sum::<f64>() / 3.0;
        assert!(
            (mc[i][i] - var_pairs / 4.0).abs() <= 1e-12 * var_pairs,
            "parameter {i}: {} {}",
            mc[i][i],
            var_pairs / 4.0
        );
        // The Monte Carlo variance of the bias at equal B: the pairs' against
        // single replicates' (sd² / 8). Measured here: 1/1300 (c_e), 1/1500
        // (c_d), 1/17 (t_r, the most even error), 1/75 (d).
        let plain_var = plain.mean_covariance()[i][i];
        eprintln!(
            "parameter {i}: Monte Carlo variance of the bias, antithetic {:.3e}, plain {plain_var:.3e}",
            mc[i][i]
        );
        assert!(mc[i][i] < 0.2 * plain_var, "parameter {i}: antithetic {} against plain {plain_var}", mc[i][i]);
    }
    let odd = bootstrap(&input, &fit, &opts, &boot_opts(true, 5));
    assert!(matches!(odd, Err(Error::InvalidOption { field: "replicates", .. })), "{odd:?}");
    let mut o = opts.clone();
    o.correct_bias(5, 4);
    assert!(matches!(o.validate(), Err(Error::InvalidOption { field: "bias_correction", .. })));
    // The correction (held noise: here the fixed model, as the fit's) subtracts that bootstrap's bias.
    let mut o = opts.clone();
    o.correct_bias(8, 4);
    assert!(o.bootstrap_antithetic);
    let r = estimate(&input, &start, &o).expect("eiv");
    assert_eq!(r.theta_uncorrected, fit.theta);
    assert_eq!(r.bias_subtracted.map(f64::to_bits), anti.bias.map(f64::to_bits));
    // Applied after the fit, the same to the bit; a second application is refused.
    let mut after = fit.clone();
    apply_bias_correction(&input, &mut after, &o).expect("correction");
    assert_eq!(after.theta, r.theta);
    assert_eq!(after.sigma.map(f64::to_bits), r.sigma.map(f64::to_bits));
    let twice = apply_bias_correction(&input, &mut after, &o);
    assert!(matches!(twice, Err(Error::InvalidOption { field: "bias_correction", .. })), "{twice:?}");
    for i in (0..4).filter(|i| fit.free[*i]) {
        let want = mc[i][i].sqrt();
        assert!((r.sigma_bias_correction[i] - want).abs() <= 1e-12 * want, "parameter {i}");
    }
}

/// The covariance recursion's speed-ups (symmetric kernels, skipped zero
/// columns, value-only reference terms, θ-step evaluations without ∂P/∂θ)
/// change only the rounding: every option set below gives the results that
/// the filter before them gave (recorded at commit 190c4e4 with the same
/// drive, start and options), θ and σ to [`GOLDEN_REL_TOL`], η to
/// [`GOLDEN_ETA_TOL`], with the same number of filter passes.
#[test]
fn results_match_the_recorded_results_of_the_unoptimised_filter() {
    // (case, θ, η, σ, σ_fisher, filter passes [with derivatives, objective only])
    #[allow(clippy::type_complexity)]
    let golden: [(&str, [f64; 4], [f64; 6], [f64; 4], [f64; 4], [usize; 2]); 5] = [
        (
            "follows-estimated",
            [1.9517221228746462, -0.002079871585151128, 1.5622634012964582, 0.000607946011927801],
            [
                -0.08757325592487535,
                0.79729676574084,
                0.677520072616239,
                -0.006961895455444829,
                1.0302776860718408,
                -0.006961895455444829,
            ],
            [0.001048223598634666, 0.00029167607905906446, 0.012851106003377495, 0.00013531789598289243],
            [0.001078694626330269, 0.00029048259828455395, 0.010913068993301283, 0.0001293380851742862],
            [10, 0], // 9 before stop 24's lean iteration starts (same θ, η, σ)
        ),
        (
            "follows-fixed",
            [1.9510784916035862, -0.0020554247723165563, 1.5553723206505459, 0.0006445878118950823],
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0006971472826100538, 0.00029261253469116573, 0.012620314131039565, 0.00013554949162042343],
            [0.0006971103626697929, 0.00029031651909707895, 0.00870883212334176, 0.0001238899036349334],
            [2, 0],
        ),
        (
            "follows-separate-measurement",
            [1.9517605103415996, -0.0019914988852835205, 1.5449359366878468, 0.0007090639079576904],
            [
                -0.06842186187407444,
                0.811046409089124,
                0.5555886423286271,
                -0.003996526827079905,
                1.025031414522649,
                -0.5093469771542682,
            ],
            [0.0010532494893682996, 0.00028983705185397655, 0.012583400085295009, 0.0001347993867926527],
            [0.0010849539925099454, 0.0002885763371857724, 0.010594344218814425, 0.00012849184497623625],
            [10, 0], // 9 before stop 24
        ),
        (
            "held-estimated",
            [1.9496229896194592, -0.0021462491413058163, 1.5796028831420352, 0.0005018695015733097],
            [
                -0.10189959150871294,
                0.768609333222542,
                0.9485201558661361,
                -0.006876857766691133,
                1.0334860763887939,
                -0.006876857766691133,
            ],
            [0.0010364206547086217, 0.0002964582660739425, 0.01117298095890374, 0.00013201669504880206],
            [0.0010367240643712695, 0.0002965391972877368, 0.01130743546550646, 0.00013254870461501878],
            [21, 0],
        ),
        (
            "held-fixed-measurement",
            [1.9499934415269828, -0.001936281489085759, 1.5330870221633592, 0.0007773895986003269],
            [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
            [0.0006966830379912104, 0.0002886046247743278, 0.01050599614949048, 0.00012880005599677619],
            [0.0006966830379912104, 0.0002886046247743278, 0.01050599614949048, 0.00012880005599677619],
            [10, 0],
        ),
    ];
    let out = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(5) }).expect("sim");
    let input = input_of(&out.drive);
    let start = Theta { c_e: 1.952, c_d: -0.0018, t_r: 1.54, d: 0.0007 };
    // Recorded with the options of the time (SPEC §10's cost and floor, the
    // heading tied to the position scale, quantisation as process noise; the
    // η step undamped and no null pass of the innovation checks, stop 12;
    // the σ of H_θ⁻¹ alone, stop 13; the quantisation step scaled with the
    // white noise, stop 14), spelt out so that a change of those defaults
    // does not change the cases.
    let base = EivOptions {
        window_samples: 2000,
        heading_scale: HeadingScale::TiedToPosition,
        quantisation: QuantisationModel::ProcessNoise,
        quantisation_level: QuantisationLevel::ScaledWithWhite,
        eta_secant_damping: false,
        innovation_null: InnovationNull::FittedModel,
        covariance_estimate: CovarianceEstimate::Model,
        // The recorded σ are H_θ⁻¹'s (before stop 16's η term).
        noise_estimate_in_covariance: false,
        // The sideslip error as white noise (before stop 19's state).
        sideslip_noise: SideslipNoise::WhiteEquivalent,
        // And the iteration limit of the time.
        max_iterations: 10,
        ..EivOptions::spec()
    };
    let options = |case: &str| match case {
        "follows-estimated" => base.clone(),
        "follows-fixed" => EivOptions { fix_noise: true, ..base.clone() },
        "follows-separate-measurement" => EivOptions {
            heading_scale: HeadingScale::Separate,
            quantisation: QuantisationModel::Measurement,
            ..base.clone()
        },
        "held-estimated" => EivOptions { covariance: CovarianceMode::HeldAtReference, ..base.clone() },
        _ => EivOptions {
            covariance: CovarianceMode::HeldAtReference,
            fix_noise: true,
            quantisation: QuantisationModel::Measurement,
            ..base.clone()
        },
    };
    let rel = |a: f64, b: f64| (a - b).abs() / b.abs().max(f64::MIN_POSITIVE);
    for (case, theta, eta, sigma, sigma_fisher, passes) in golden {
        let r = estimate(&input, &start, &options(case)).expect("eiv");
        let th = r.theta.to_array();
        for i in 0..4 {
            assert!(rel(th[i], theta[i]) <= GOLDEN_REL_TOL, "{case}: θ{i} {} vs {}", th[i], theta[i]);
            assert!(rel(r.sigma[i], sigma[i]) <= GOLDEN_REL_TOL, "{case}: σ{i} {} vs {}", r.sigma[i], sigma[i]);
            assert!(
                rel(r.sigma_fisher[i], sigma_fisher[i]) <= GOLDEN_REL_TOL,
                "{case}: σ_fisher{i} {} vs {}",
                r.sigma_fisher[i],
                sigma_fisher[i]
            );
        }
        for j in 0..6 {
            assert!((r.eta[j] - eta[j]).abs() <= GOLDEN_ETA_TOL, "{case}: η{j} {} vs {}", r.eta[j], eta[j]);
        }
        assert_eq!(r.evaluations, passes, "{case}: filter passes");
    }
    let c = cramer_rao_bound(&input, &out.sidecar.theta_true, &NoiseModel::default(), &base).expect("crb");
    let (crb, crb_mean) = (
        [0.0006964876124161222, 0.0002900334008815973, 0.008574121003326022, 0.00012340564246389902],
        [0.0006965744128967777, 0.0002911371042056862, 0.01068148829521026, 0.0001292392712234382],
    );
    for i in 0..4 {
        assert!(rel(c.sigma[i], crb[i]) <= GOLDEN_REL_TOL, "CRB σ{i} {} vs {}", c.sigma[i], crb[i]);
        assert!(rel(c.sigma_mean_only[i], crb_mean[i]) <= GOLDEN_REL_TOL, "CRB mean-only σ{i}");
    }
}

/// Relative tolerance of θ and σ against the recorded results: the changed
/// summation order moves them by ~1e-13 (measured); a real change of the
/// filter moves them by far more than 1e-9.
const GOLDEN_REL_TOL: f64 = 1e-9;
/// Absolute tolerance of η (log-scales, some near 0): measured differences ~2e-12.
const GOLDEN_ETA_TOL: f64 = 1e-8;

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
        let (tp, tm, ep, em, h) = if p < 4 {
            let h = 1e-6 * [th.c_e, 1.0, th.t_r, 1.0][p];
            (perturb(&th, p, h), perturb(&th, p, -h), eta, eta, h)
        } else {
            let h = 1e-5;
            let (mut ep, mut em) = (eta, eta);
            ep[p - 4] += h;
            em[p - 4] -= h;
            (th, th, ep, em, h)
        };
        let (sp, sm) = (run(&tp, &ep, filter::Mode::cost(true), 20), run(&tm, &em, filter::Mode::cost(true), 20));
        for (what, fd, g) in [
            ("M", (sp.merit() - sm.merit()) / (2.0 * h), base.grad[p]),
            ("J", (sp.profile() - sm.profile()) / (2.0 * h), base.grad_profile[p]),
        ] {
            assert!((g - fd).abs() <= 1e-4 * g.abs().max(fd.abs()).max(1e-6), "∂{what}/∂p{p}: {g} vs {fd}");
        }
    }
}

/// `EivOptions::position_floor_m` is the position σ floor of R: on a
/// perfect reference (the noise model's position white noise zero) the
/// position variance of every innovation covariance grows by exactly the
/// difference of the squared floors against the default 1 mm (heading
/// unchanged), and a non-positive floor is rejected.
#[test]
fn position_floor_enters_the_innovation_covariance() {
    let out = simulate(&SimOptions { length_km: 0.3, substeps: 1, ..SimOptions::noise_free(4) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 200.min(input.len() - 1) };
    let th = out.sidecar.theta_true;
    let noise = NoiseModel::from_sim(&NoiseOptions::white_wheel_only(), input.sample_time_s);
    let run = |floor: f64| {
        let mut v = noise.variances(&[0.0; 6], input.sample_time_s);
        v.position_floor_m = floor;
        let mut rec = Vec::new();
        run_window(&input, &w, &th, &th, &v, filter::Mode::full(true, false), Some(&mut rec)).expect("window");
        rec
    };
    let (a, b) = (run(SPEC_POSITION_FLOOR_M), run(0.005));
    assert!(!a.is_empty() && a.len() == b.len());
    // The first update: P⁻ = P₀ + Q with P₀ = R, so S = 2R + H Q Hᵀ.
    let want = 2.0 * (0.005f64.powi(2) - SPEC_POSITION_FLOOR_M.powi(2));
    for c in 0..2 {
        let got = b[0].s[(c, c)] - a[0].s[(c, c)];
        assert!((got - want).abs() <= 1e-12, "S[{c},{c}] grew by {got:e}, want {want:e}");
    }
    assert!((b[0].s[(2, 2)] - a[0].s[(2, 2)]).abs() <= 1e-15, "the heading variance moved");
    // Later updates: never less than the floor's share of R.
    assert!(b.iter().all(|r| r.s[(0, 0)] >= 0.005f64.powi(2) && r.s[(1, 1)] >= 0.005f64.powi(2)));
    for bad in [0.0, -1e-3, f64::NAN] {
        let opts = EivOptions { position_floor_m: bad, ..EivOptions::default() };
        assert!(opts.validate().is_err(), "floor {bad} accepted");
    }
}

/// A straight, noise-free drive (heading constant; 10 m/s) at
/// θ = [`Theta::SIM_DEFAULT_TRUE`], owning the signals an [`EivInput`]
/// borrows.
pub(crate) struct StraightDrive {
    ts: f64,
    parts: [std::ops::Range<usize>; 1],
    pub px: Vec<f64>,
    pub py: Vec<f64>,
    pub psi: Vec<f64>,
    pub n_rl: Vec<f64>,
    pub n_rr: Vec<f64>,
    pub zero: Vec<f64>,
}

impl StraightDrive {
    /// `n` samples of `ts` seconds.
    pub(crate) fn new(n: usize, ts: f64) -> Self {
        let th = Theta::SIM_DEFAULT_TRUE;
        let (n_rl, n_rr) = crate::model::wheel_rotations(10.0, 0.0, 0.0, &th);
        let (mut px, mut py, mut psi) = (vec![0.0], vec![0.0], vec![0.3]);
        for k in 1..n {
            let x = crate::model::step(
                &crate::model::State::new(px[k - 1], py[k - 1], psi[k - 1]),
                &crate::model::Input { n_rl, n_rr, beta: 0.0, a_y: 0.0 },
                &th,
                ts,
            );
            px.push(x[0]);
            py.push(x[1]);
            psi.push(x[2]);
        }
        StraightDrive { ts, parts: [0..n], px, py, psi, n_rl: vec![n_rl; n], n_rr: vec![n_rr; n], zero: vec![0.0; n] }
    }

    /// The drive as one part, β and a_y zero, the reference measured everywhere.
    fn input(&self) -> EivInput<'_> {
        EivInput {
            sample_time_s: self.ts,
            parts: &self.parts,
            px: &self.px,
            py: &self.py,
            psi: &self.psi,
            n_rl: &self.n_rl,
            n_rr: &self.n_rr,
            beta: &self.zero,
            a_y: &self.zero,
            reference_measured: None,
        }
    }
}

/// The separate heading scale, with every quantisation model, returns
/// c_e on the noise-free straight drive (the other options the defaults).
/// Regression: with the SPEC formulation's input log-Jacobian
/// ([`InputJacobian::None`]) the θ/η iteration stops after two iterations
/// at a second fixed point, c_e −0.057 % with η held well above its lower
/// clamp (docs/study.md, "Stop 12"); with [`InputJacobian::FilterShare`]
/// the profile cost's minimum at that η is +0.026 %, not −0.057 %, so the
/// point is no longer fixed and the fit reaches θ_true.
#[test]
fn separate_heading_scale_calibrates_c_e_on_the_noise_free_straight_drive() {
    let (n, ts) = (4000, 0.025);
    let th = Theta::SIM_DEFAULT_TRUE;
    let drive = StraightDrive::new(n, ts);
    let input = drive.input();
    let start = Theta { c_e: 1.96, ..th };
    for quantisation in [QuantisationModel::ProcessNoise, QuantisationModel::Measurement, QuantisationModel::Counting] {
        let opts = EivOptions { heading_scale: HeadingScale::Separate, quantisation, ..EivOptions::default() };
        let r = estimate(&input, &start, &opts).expect("eiv");
        assert!((r.theta.c_e - th.c_e).abs() < 1e-6, "{quantisation:?}: {r}");
        assert!(r.termination.converged(), "{quantisation:?}: {r}");
        assert!(!r.free[2] && !r.free[3] && r.free[0], "{quantisation:?}: {:?}", r.free);
    }
}

/// The η step is a descent direction of the marginal likelihood M, so step
/// halving can always lower M. Regression: at this point of the noise-free
/// straight drive (heading scale separate; where the fit from c_e = 1.96
/// stood after one iteration) the scoring step of the variances, mapped to
/// η by ln(1 + d) and clamped, pointed uphill (gᵀΔη = +249) and every
/// halving was rejected, so the fit stopped with c_e 0.06 % off.
#[test]
fn eta_step_descends_on_the_noise_free_straight_drive() {
    let (n, ts) = (4000, 0.025);
    let drive = StraightDrive::new(n, ts);
    let input = drive.input();
    let opts = EivOptions { heading_scale: HeadingScale::Separate, ..EivOptions::default() };
    let prob = Problem {
        input: &input,
        windows: make_windows(input.parts, opts.window_samples),
        noise: opts.noise,
        quantisation: opts.quantisation,
        quantisation_given: false,
        lateral_stated: false,
        sideslip_white: false,
        heading_separate: true,
        fitted_input: false,
        position_floor_m: opts.position_floor_m,
        noise_input_half_width: 0,
        noise_input_from_reference: false,
        input_jacobian: opts.input_jacobian,
        evaluations: std::cell::Cell::new([0; 2]),
        lean_iterations: true,
    };
    let theta = Theta { c_e: 1.9488978137579984, c_d: -0.001998869480161304, t_r: 1.53, d: 0.0008 };
    let eta = [-0.00903020194120505, 0.2628615557666504, 0.75, 0.1370901227620087, -2.5, -2.5];
    let ev = prob.evaluate(&theta, &theta, &eta, filter::Mode::full(true, true)).expect("filter");
    let step = eta_step(&ev.total, &eta, opts.eta_bounds, f64::INFINITY, &[false; 6]).step;
    let slope: f64 = (0..NETA).map(|j| ev.total.grad[4 + j] * step[j]).sum();
    assert!(slope < 0.0, "η step {step:?} is not a descent direction: gᵀΔη = {slope}");
    let m0 = ev.total.merit();
    let lowered = (0..=opts.max_halvings).any(|h| {
        let et = eta_add(&eta, &step, 0.5f64.powi(h as i32), opts.eta_bounds);
        let m = prob.evaluate(&theta, &theta, &et, filter::Mode::cost(true)).expect("filter").total.merit();
        m < m0
    });
    assert!(lowered, "no halving of the η step {step:?} lowers M = {m0}");
}

/// A white-noise drive on a perfect reference (1 km, the simulator's noise
/// model given) and the same drive with the reference 0.5 m ahead of the
/// rear axle, not modelled (stop 12).
fn white_drive_fit(lever_x: f64, null: InnovationNull) -> EivReport {
    let noise = NoiseOptions::white_wheel_only();
    let mount = crate::model::extrinsics::Extrinsics { lever_x, lever_y: 0.0, heading_offset: 0.0 };
    let out =
        simulate(&SimOptions { length_km: 1.0, noise: noise.clone(), reference_mount: mount, ..SimOptions::paper(4) })
            .expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions {
        noise: NoiseModel::from_sim(&noise, input.sample_time_s),
        fix_noise: true,
        window_samples: 1000,
        max_iterations: 3,
        innovation_null: null,
        ..Default::default()
    };
    estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv")
}

fn innovation_findings(r: &EivReport) -> Vec<&EivWarning> {
    r.warnings
        .iter()
        .filter(|w| matches!(w, EivWarning::CorrelatedInnovations { .. } | EivWarning::InconsistentInnovations { .. }))
        .collect()
}

/// On a perfect reference the 5 mm position floor is not in the data, so
/// the innovations of a correct model are correlated (lag-1 ≈ 0.6–0.7) and
/// small (NIS/dof ≈ 0.4): the stop-11 checks flag every window, the checks
/// against the floor-free null none, and that null predicts the lag-1.
#[test]
fn innovation_checks_pass_a_correct_model_on_a_perfect_reference() {
    let r = white_drive_fit(0.0, InnovationNull::FloorsAsRegularisation);
    assert!(innovation_findings(&r).is_empty(), "{r}");
    for w in &r.windows {
        assert!(w.lag1[0] > 0.5 && w.lag1[1] > 0.5, "the floor correlates the innovations: {w:?}");
        for c in 0..2 {
            assert!((w.lag1[c] - w.lag1_without_floors[c]).abs() < 0.1, "{w:?}");
        }
        assert!((w.nis / w.nis_without_floors - 1.0).abs() < 0.15, "{w:?}");
    }
    let before = white_drive_fit(0.0, InnovationNull::FittedModel);
    let correlated = before.warnings.iter().filter(|w| matches!(w, EivWarning::CorrelatedInnovations { .. })).count();
    assert!(correlated >= before.windows.len(), "{before}");
}

/// An unmodelled reference lever arm (0.5 m) is still flagged by the
/// whiteness check against the floor-free null.
#[test]
fn innovation_checks_flag_an_unmodelled_reference_lever_arm() {
    let r = white_drive_fit(0.5, InnovationNull::FloorsAsRegularisation);
    let flagged: Vec<_> = r
        .warnings
        .iter()
        .filter(|w| matches!(w, EivWarning::CorrelatedInnovations { lag1, expected, .. } if lag1 - expected > 0.5))
        .collect();
    assert!(flagged.len() >= r.windows.len(), "{r}");
}

/// Stop 13: the block sandwich's meat on a constructed case (three blocks
/// in one window, then one more window of two blocks), against the plain
/// formula: centred outer products plus half the centred lag-1 cross
/// products of neighbouring blocks of the same window, times n/(n − 1).
#[test]
fn block_sandwich_meat_matches_the_plain_formula() {
    use super::filter::BlockScores;
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

/// Stop 13: `CovarianceEstimate::LargerOfModelAndBlock` raises each σ to
/// the block sandwich's where that is larger and keeps the correlations.
#[test]
fn larger_of_model_and_block_inflates_only_where_the_blocks_are_wider() {
    use super::filter::BlockScores;
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

/// Stop 13, on a drive with coloured common-mode wheel noise (1.5 km, the
/// `coloured` preset): a noise model without the common-mode source (η₁ at
/// its clamp in effect) reports c_e's σ several times too small; the block
/// sandwich sees the spread of the block scores and is wider, and
/// `LargerOfModelAndBlock` reports it and judges the halves with it. The
/// estimated noise model started with η₁ at the lower clamp keeps it there
/// (its information reads as none) unless `eta_reentry_min_score` lets it
/// re-enter.
#[test]
fn coloured_common_mode_noise_block_sandwich_and_reentry() {
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
        covariance_estimate: CovarianceEstimate::Model,
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
        &EivOptions { covariance_estimate: CovarianceEstimate::LargerOfModelAndBlock, ..base.clone() },
    )
    .expect("fit");
    assert_eq!(robust.theta, model.theta, "the option changes the covariance only");
    assert!((robust.sigma[0] - model.sigma_block[0]).abs() <= 1e-12 * robust.sigma[0], "{robust}");
    assert!((robust.covariance[0][0].sqrt() - robust.sigma[0]).abs() <= 1e-12 * robust.sigma[0]);
    let (zm, zr) = (model.halves.expect("halves").z[0], robust.halves.expect("halves").z[0]);
    assert!(zr.abs() < zm.abs(), "halves z of c_e: robust {zr} vs model {zm}");

    // η₁ (common mode) starting at its lower clamp, η estimated.
    let est = EivOptions { noise: sim_noise, fix_noise: false, max_iterations: 4, ..base };
    let start = [0.0, est.eta_bounds[0], 0.0, est.eta_bounds[0], est.eta_bounds[0], est.eta_bounds[0]];
    let (stuck, _) = estimate_from(&input, &truth, &start, &est).expect("fit");
    assert!(stuck.eta[1] <= est.eta_bounds[0], "without re-entry η₁ stays at the clamp: {:?}", stuck.eta);
    let re = EivOptions { eta_reentry_min_score: Some(10.0), ..est };
    let (left, _) = estimate_from(&input, &truth, &start, &re).expect("fit");
    assert!(left.eta[1] > re.eta_bounds[0] + 1.0, "with re-entry η₁ leaves the clamp: {:?}", left.eta);
}

/// The 1 km white-noise drive of the stop-13 convergence tests, and the
/// options they share: η estimated, the heading scale separate, counting
/// quantisation.
fn separate_counting_white_drive() -> (crate::sim::SimOutput, EivOptions) {
    let out = simulate(&SimOptions { length_km: 1.0, noise: NoiseOptions::white_wheel_only(), ..SimOptions::paper(1) })
        .expect("sim");
    let opts = EivOptions {
        window_samples: 1000,
        heading_scale: HeadingScale::Separate,
        quantisation: QuantisationModel::Counting,
        ..Default::default()
    };
    (out, opts)
}

/// At the iteration limit the default test judges the steps just taken; the
/// fit of this drive takes n iterations (5 since stop 19, 6 before), and the
/// step remaining after the n-th is below the tolerance, so with
/// [`EivOptions::final_step_check`] an n-iteration limit ends converged, at
/// the same θ.
#[test]
fn final_step_check_converges_at_the_iteration_limit() {
    let (out, base) = separate_counting_white_drive();
    let input = input_of(&out.drive);
    let truth = out.sidecar.theta_true;
    let full = estimate(&input, &truth, &base).expect("eiv");
    let history = full.passes.last().map(|p| p.history.clone()).unwrap_or_default();
    let n = history.len();
    assert!((2..base.max_iterations).contains(&n), "{full}");
    // Without the option an n-iteration limit ends on this step: not converged.
    assert!(history[n - 1].step_over_sigma >= 0.05, "{full}");
    let opts = EivOptions { max_iterations: n, final_step_check: true, ..base };
    let r = estimate(&input, &truth, &opts).expect("eiv");
    assert!(r.termination.converged(), "{r}");
    assert_eq!(r.theta, full.theta);
    let without = estimate(&input, &truth, &EivOptions { final_step_check: false, ..opts }).expect("eiv");
    assert!(!without.termination.converged(), "{without}");
    assert_eq!(without.theta, full.theta);
}

/// With the heading scale separate, θ settles iterations before η does
/// (stop 13): on this 1 km white-noise drive (η estimated, counting
/// quantisation) the default test needs 6 iterations; judged on θ
/// ([`EivOptions::theta_convergence`]) the fit converges within 4 and θ
/// agrees with the fully converged one to 0.05 σ.
#[test]
fn theta_convergence_stops_when_theta_has_settled() {
    let (out, opts) = separate_counting_white_drive();
    let input = input_of(&out.drive);
    let full = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let p = full.passes.last().expect("a pass");
    assert!(full.termination.converged() && p.history.len() > 4, "{full}");
    let short = EivOptions { max_iterations: 4, theta_convergence: true, ..opts };
    let r = estimate(&input, &out.sidecar.theta_true, &short).expect("eiv");
    assert!(r.termination.converged(), "{r}");
    let eta_step = r.passes.last().and_then(|p| p.eta_step_over_sigma).expect("η step reported");
    assert!(eta_step > 0.05, "η had not settled: {eta_step}");
    let (a, b) = (r.theta.to_array(), full.theta.to_array());
    for i in (0..4).filter(|i| full.sigma[*i] > 0.0) {
        assert!((a[i] - b[i]).abs() < 0.05 * full.sigma[i], "θ_{i}: {} against {} (σ {})", a[i], b[i], full.sigma[i]);
    }
}

/// `EivOptions::eta_held`: a held noise scale stays at the starting model
/// (η_j = 0, the model's σ reported unchanged) while the others are
/// estimated; without the hold the same fit moves it (the production car's
/// heading σ 0.5 mrad against the simulator's 0.3 mrad), so the test can fail.
#[test]
fn held_noise_scale_stays_at_the_starting_model() {
    let sim = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(3) }).expect("simulate");
    let d = &sim.drive;
    let input = input_of(d);
    let start = batch_gn_all(d);
    let free = EivOptions { heading_scale: HeadingScale::Separate, max_iterations: 3, ..EivOptions::default() };
    let mut eta_held = [false; NETA];
    eta_held[5] = true;
    let held = EivOptions { eta_held, ..free.clone() };
    let r_free = estimate(&input, &start, &free).expect("eiv, η_5 free");
    let r_held = estimate(&input, &start, &held).expect("eiv, η_5 held");
    assert!(r_free.eta[5].abs() > 0.1, "η_5 free did not move: {:?}", r_free.eta);
    assert!(r_held.eta[5].abs() < 1e-15, "η_5 held moved: {:?}", r_held.eta);
    let start = NoiseModel::PRODUCTION_CAR.heading_white_sigma_rad;
    assert!((r_held.noise.heading_white_sigma_rad - start).abs() < 1e-15 * start);
    assert!(r_held.eta[..5] != [0.0; 5], "the other scales were not estimated: {:?}", r_held.eta);
}

/// A bootstrap of a `FromReadings` fit refits its replicates at the level
/// the fit resolved to on the drive, not at one re-read off the replicates'
/// readings: those are counted with the fitted step, so they lie on a
/// lattice even where the drive's did not (white wheel noise, no encoder:
/// the fit scales q; without the fix the replicates held it).
#[test]
fn bootstrap_refits_at_the_quantisation_level_of_the_fit() {
    let opts =
        SimOptions { length_km: 0.5, noise: crate::sim::NoiseOptions::white_wheel_only(), ..SimOptions::paper(5) };
    let out = simulate(&opts).expect("sim");
    let input = input_of(&out.drive);
    let fit = EivOptions { max_iterations: 2, ..EivOptions::default() };
    assert_eq!(fit.quantisation_level, QuantisationLevel::FromReadings);
    let r = estimate(&input, &out.sidecar.theta_true, &fit).expect("eiv");
    assert_eq!(r.quantisation_step_from_readings, None, "no lattice in white-noise readings");
    assert!(r.noise.quantisation_step_rev_per_s > 1e-3, "the replicates are counted: {:?}", r.noise);
    let boot = BootstrapOptions { replicates: 2, seed: 4, ..Default::default() };
    let replicates = |o: &EivOptions| bootstrap(&input, &r, o, &boot).expect("bootstrap").replicates;
    let from_readings = replicates(&fit);
    let scaled = EivOptions { quantisation_level: QuantisationLevel::ScaledWithWhite, ..fit.clone() };
    assert_eq!(from_readings, replicates(&scaled));
    let given = EivOptions { quantisation_level: QuantisationLevel::Given, noise: r.noise, ..fit.clone() };
    assert_ne!(from_readings, replicates(&given), "the test cannot tell the levels apart");
}

/// `BootstrapInputs::Smoothed`: the replicate worlds run on the moving
/// average of the measured inputs, so the same seed gives other replicates
/// than with the measured inputs; a half-width of 0 is rejected. (Its effect
/// on the bias estimate over seeds: `examples/study_eiv.rs --bootstrap-smooth`.)
#[test]
fn smoothed_bootstrap_inputs_change_the_replicate_worlds() {
    let (out, opts) = known_noise_fit(1.0, 31);
    let input = input_of(&out.drive);
    let r = estimate(&input, &out.sidecar.theta_true, &opts).expect("eiv");
    let boot = BootstrapOptions { replicates: 4, seed: 9, ..Default::default() };
    let smooth = BootstrapOptions { true_inputs: BootstrapInputs::Smoothed { half_width_samples: 20 }, ..boot };
    let measured = bootstrap(&input, &r, &opts, &boot).expect("bootstrap, measured inputs");
    let smoothed = bootstrap(&input, &r, &opts, &smooth).expect("bootstrap, smoothed inputs");
    assert_ne!(measured.replicates, smoothed.replicates);
    let zero = BootstrapOptions { true_inputs: BootstrapInputs::Smoothed { half_width_samples: 0 }, ..boot };
    assert!(bootstrap(&input, &r, &opts, &zero).is_err());
}

/// Stop 16: `∂θ̂/∂η` from the implicit function theorem at the estimate
/// (`EivReport::theta_eta_sensitivity`, a forward difference of the exact
/// θ-score) matches re-fitting θ with the noise model held at the fitted one
/// moved by ±h in that source; the reported covariance is H_θ⁻¹ (block
/// inflated) plus `A Σ_η Aᵀ`, θ itself unchanged; a fixed noise model adds
/// nothing.
#[test]
fn noise_estimate_sensitivity_matches_refits_and_widens_sigma() {
    let noise = NoiseOptions::high();
    let out = simulate(&SimOptions { length_km: 4.0, noise, ..SimOptions::paper(2) }).expect("sim");
    let input = input_of(&out.drive);
    let gn = batch_gn_all(&out.drive);
    let opts = EivOptions::default();
    let r = estimate(&input, &gn, &opts).expect("eiv");
    let off = estimate(&input, &gn, &EivOptions { noise_estimate_in_covariance: false, ..opts.clone() }).expect("eiv");
    assert_eq!(r.theta, off.theta, "the option changes the covariance only");
    assert!(off.sigma_noise_estimate.iter().all(|s| *s == 0.0), "option off: no η term");
    for i in 0..4 {
        let want = off.sigma[i].hypot(r.sigma_noise_estimate[i]);
        assert!((r.sigma[i] - want).abs() <= 1e-9 * want, "σ{i}: {} vs {want}", r.sigma[i]);
        assert!((r.covariance[i][i].sqrt() - r.sigma[i]).abs() <= 1e-12 * r.sigma[i]);
    }
    // t_r's most influential estimated source.
    let (j, _) = (0..6)
        .filter(|j| r.eta_sigma[*j] > 0.0)
        .map(|j| (j, (r.theta_eta_sensitivity[2][j] * r.eta_sigma[j]).abs()))
        .fold((usize::MAX, 0.0), |a, b| if b.1 > a.1 { b } else { a });
    assert!(j < 6, "some estimated scale moves t_r: {r}");
    assert!(
        r.sigma_noise_estimate[2] > 0.05 * off.sigma[2],
        "η term of t_r {:.3e} vs σ {:.3e}",
        r.sigma_noise_estimate[2],
        off.sigma[2]
    );
    let h = 0.1;
    let refit = |sign: f64| {
        let mut e = [0.0; 6];
        e[j] = sign * h;
        let o = EivOptions {
            noise: r.noise.scaled(&e),
            fix_noise: true,
            free: r.free,
            fix_unobservable: false,
            step_tolerance: 1e-4,
            max_iterations: 30,
            ..opts.clone()
        };
        estimate(&input, &r.theta, &o).expect("refit").theta.to_array()
    };
    let (a, b) = (refit(1.0), refit(-1.0));
    for i in 0..4 {
        let fd = (a[i] - b[i]) / (2.0 * h);
        let got = r.theta_eta_sensitivity[i][j];
        // Against the parameter's σ: entries that do not matter need not agree in relative terms.
        let scale = off.sigma[i];
        assert!(
            (got - fd).abs() <= 0.1 * fd.abs() + 0.05 * scale,
            "∂θ{i}/∂η{j}: implicit {got:.4e} vs refits {fd:.4e} (σ {scale:.2e})"
        );
    }
    let fixed = EivOptions { noise: r.noise, fix_noise: true, ..opts };
    let rf = estimate(&input, &r.theta, &fixed).expect("fixed");
    assert!(rf.sigma_noise_estimate.iter().all(|s| *s == 0.0), "fixed noise: no η term");
    assert!(rf.theta_eta_sensitivity.iter().flatten().all(|s| *s == 0.0));
}

/// Diagnostic (issue 9, why η̂_5 runs high on `high`): the η-scores of M
/// at the truth (θ_true, the simulator's noise model, η = 0), as
/// z = −g_j/√I_jj (z > 0: M falls as η_j grows, so the fit moves η_j up),
/// mean over seeds, and the heading-white score split by speed and yaw
/// rate. `cargo test --release -p odocal --lib eta_scores_at_the_truth -- --ignored --nocapture`
/// (env ODOCAL_DIAG_PRESETS, ODOCAL_DIAG_SEEDS, ODOCAL_DIAG_KM).
#[test]
#[ignore]
fn eta_scores_at_the_truth() {
    let presets = std::env::var("ODOCAL_DIAG_PRESETS").unwrap_or_else(|_| "high,whitehead".into());
    let seeds: u64 = std::env::var("ODOCAL_DIAG_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(10);
    let km: f64 = std::env::var("ODOCAL_DIAG_KM").ok().and_then(|s| s.parse().ok()).unwrap_or(12.0);
    for preset in presets.split(',') {
        let high = NoiseOptions::high();
        let noise = match preset {
            "high" => high,
            "paper" => NoiseOptions::paper(),
            // White wheel and heading white noise of `high` only.
            "whitehead" => NoiseOptions {
                wheel_white_rel_sigma: high.wheel_white_rel_sigma,
                heading_white_sigma_rad: high.heading_white_sigma_rad,
                ..NoiseOptions::off()
            },
            "whitepos" => NoiseOptions {
                wheel_white_rel_sigma: high.wheel_white_rel_sigma,
                heading_white_sigma_rad: high.heading_white_sigma_rad,
                position_white_sigma_m: high.position_white_sigma_m,
                ..NoiseOptions::off()
            },
            "high-noquant" => NoiseOptions { encoder_ticks_per_revolution: 0, ..high },
            "high-noslip" => NoiseOptions { wheel_slip_per_m_per_s2: 0.0, ..high },
            "high-nobeta" => NoiseOptions { sideslip_sigma_rad: 0.0, ..high },
            "high-noay" => NoiseOptions { lateral_acceleration_white_sigma_m_per_s2: 0.0, ..high },
            "high-nolat" => {
                NoiseOptions { lateral_acceleration_white_sigma_m_per_s2: 0.0, sideslip_sigma_rad: 0.0, ..high }
            }
            other => panic!("unknown preset {other}"),
        };
        let mut zs: Vec<[f64; 6]> = Vec::new();
        let mut steps: Vec<[f64; 6]> = Vec::new();
        // Bins: speed < 5, 5–10, 10–15, ≥ 15 m/s × |yaw rate| < 0.05, ≥ 0.05 rad/s.
        let mut bins = [[0.0f64; 3]; 8]; // [Σ score_5, Σ ½tr, count]
        for seed in 1..=seeds {
            let sim = SimOptions { length_km: km, noise: noise.clone(), ..SimOptions::paper(seed) };
            let out = simulate(&sim).expect("sim");
            let d = &out.drive;
            let input = input_of(d);
            let ts = input.sample_time_s;
            let opts = EivOptions { noise: NoiseModel::from_sim(&noise, ts), ..EivOptions::default() };
            let q = opts.quantisation_level.step_found(&input);
            let opts = opts.with_resolved_quantisation(q);
            let prob = Problem::new(&input, make_windows(input.parts, opts.window_samples), &opts);
            let th = out.sidecar.theta_true;
            let ev = prob.evaluate(&th, &th, &[0.0; 6], filter::Mode::full(true, true)).expect("filter");
            let z: [f64; 6] = std::array::from_fn(|j| {
                let i = ev.total.i_eta[(j, j)];
                if i > 0.0 {
                    -ev.total.grad[4 + j] / i.sqrt()
                } else {
                    0.0
                }
            });
            zs.push(z);
            let st = eta_step(&ev.total, &[0.0; 6], opts.eta_bounds, f64::INFINITY, &[false; 6]).step;
            steps.push(st);
            let v = prob.variances(&[0.0; 6], false);
            for w in &prob.windows {
                let mut rec = Vec::new();
                run_window(&input, w, &th, &th, &v, filter::Mode::full(true, true), Some(&mut rec)).expect("window");
                for (r, rc) in rec.iter().enumerate() {
                    let k = w.start + 1 + r;
                    let speed = 0.5 * (input.n_rl[k] + input.n_rr[k]) * th.c_e;
                    let yaw = crate::model::wrap_angle(input.psi[k] - input.psi[k - 1]) / ts;
                    let sb = ((speed / 5.0) as usize).min(3);
                    let b = sb * 2 + usize::from(yaw.abs() >= 0.05);
                    let sinv = rc.s.try_inverse().expect("S");
                    let sn = sinv * rc.nu;
                    let ds = rc.ds[9];
                    let half_tr = 0.5 * (sinv * ds).trace();
                    let g = -(rc.dnu.column(9).dot(&sn)) + half_tr - 0.5 * sn.dot(&(ds * sn));
                    bins[b][0] += g;
                    bins[b][1] += half_tr;
                    bins[b][2] += 1.0;
                }
            }
        }
        let n = zs.len() as f64;
        let names = ["white", "common", "diff", "pos", "drift", "head"];
        let cells: Vec<String> = (0..6)
            .map(|j| {
                let m = zs.iter().map(|z| z[j]).sum::<f64>() / n;
                let sd = (zs.iter().map(|z| (z[j] - m).powi(2)).sum::<f64>() / (n - 1.0).max(1.0)).sqrt();
                format!("{} z {:+.2} ± {:.2}", names[j], m, sd / n.sqrt())
            })
            .collect();
        println!("{preset} ({seeds} seeds × {km} km): {}", cells.join(", "));
        let st: Vec<String> =
            (0..6).map(|j| format!("{} {:+.3}", names[j], steps.iter().map(|z| z[j]).sum::<f64>() / n)).collect();
        println!("  first scoring step of η from the truth (mean): {}", st.join(", "));
        for (b, bin) in bins.iter().enumerate() {
            // −g / ½tr: the relative excess of ν's heading variance the bin shows (≈ 0 when the model fits).
            println!(
                "  speed bin {} yaw {}: updates {:>7}, Σ score_5 {:+10.2}, −score/½tr {:+.4}",
                b / 2,
                if b % 2 == 1 { "turning" } else { "straight" },
                bin[2],
                bin[0],
                -bin[0] / bin[1].max(1e-300)
            );
        }
    }
}

/// The AVX2 build of the filter (run-time dispatch, `filter::kernels`) and
/// the baseline build give the same window sums and innovations, to the bit,
/// in every pass mode, with and without counting quantisation and with the
/// wheel noise scaled by the fitted input. On a CPU without AVX2 only the
/// baseline runs (and the test says so).
#[test]
fn avx2_kernels_equal_the_baseline_to_the_bit() {
    let out =
        simulate(&SimOptions { length_km: 0.6, noise: NoiseOptions::high(), ..SimOptions::paper(11) }).expect("sim");
    let input = input_of(&out.drive);
    let w = Window { index: 0, part: 0, start: 0, end: 1500.min(input.len() - 1) };
    let th = Theta { c_e: 1.953, c_d: -0.0015, t_r: 1.52, d: 0.0009 };
    let th_ref = Theta { c_e: 1.96, c_d: -0.001, d: 0.0012, ..th };
    let eta = [0.3, -0.5, 0.2, -0.2, 0.4, 0.25];
    if !filter::avx2_available() {
        eprintln!("this CPU has no AVX2 + FMA: only the baseline kernels can run here");
        return;
    }
    let mut compared = 0;
    for (fitted, counting) in [(false, false), (false, true), (true, true)] {
        let mut v = variances_quant(&eta, input.sample_time_s, Held::NONE);
        v.fitted_input = fitted;
        v.quant_counting = counting;
        for follows in [false, true] {
            for mode in [
                filter::Mode::full(follows, true),
                filter::Mode::full(follows, false),
                filter::Mode::eta_only(follows),
                filter::Mode::cost(follows),
            ] {
                let (mut rb, mut ra) = (Vec::new(), Vec::new());
                let base =
                    filter::run_window_baseline(&input, &w, &th, &th_ref, &v, mode, Some(&mut rb)).expect("window");
                #[cfg(target_arch = "x86_64")]
                // SAFETY: `avx2_available()` was checked above.
                #[allow(unsafe_code)]
                let avx2 = unsafe { filter::run_window_avx2(&input, &w, &th, &th_ref, &v, mode, Some(&mut ra)) }
                    .expect("window");
                #[cfg(not(target_arch = "x86_64"))]
                let avx2 = base.clone();
                assert!(base.quad > 0.0 && base.quad.is_finite(), "{mode:?}: a real objective ({})", base.quad);
                assert_eq!(
                    format!("{base:?}"),
                    format!("{avx2:?}"),
                    "window sums, {mode:?}, fitted {fitted}, counting {counting}"
                );
                assert_eq!(
                    format!("{rb:?}"),
                    format!("{ra:?}"),
                    "innovations, {mode:?}, fitted {fitted}, counting {counting}"
                );
                compared += 1;
            }
        }
    }
    assert_eq!(compared, 24);
}

/// Stop 24: the θ-score's log-Jacobian term moves with η through its
/// FilterShare weights u = var·fᵀS⁻¹f; the filter sums that derivative
/// exactly (`grad_jacobian_eta`). Against central differences in η of the
/// term itself, on a short high-noise drive at a point off the fit.
#[test]
fn log_jacobian_eta_derivative_matches_finite_differences() {
    let out =
        simulate(&SimOptions { length_km: 1.0, noise: NoiseOptions::high(), ..SimOptions::paper(3) }).expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions::default();
    assert_eq!(opts.input_jacobian, InputJacobian::FilterShare, "the default this test is about");
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

/// Stop 24: `∂g_θ/∂η` by the symmetry of the mixed partials (the θ-displaced
/// passes with η derivatives plus the exact log-Jacobian term; 4 passes) and
/// by displacing η (one more pass per free η, the stop-16 formulation) give
/// the same `∂θ̂/∂η` and the same η term of the covariance.
#[test]
fn noise_estimate_term_by_symmetry_matches_displaced_eta() {
    let out =
        simulate(&SimOptions { length_km: 4.0, noise: NoiseOptions::high(), ..SimOptions::paper(2) }).expect("sim");
    let input = input_of(&out.drive);
    let gn = batch_gn_all(&out.drive);
    let opts = EivOptions::default();
    let r = estimate(&input, &gn, &opts).expect("eiv");
    let prob = Problem::new(&input, make_windows(input.parts, opts.window_samples), &opts);
    assert!(prob.mixed_partials_by_symmetry());
    let ev = prob.evaluate(&r.theta, &gn, &r.eta, filter::Mode::full(true, true)).expect("filter");
    let cov = free_inverse(&ev.total.h_theta, &r.free).expect("H_θ");
    let eta_free: [bool; 6] = std::array::from_fn(|j| r.eta_sigma[j] > 0.0);
    assert!(eta_free.iter().filter(|f| **f).count() >= 3, "η estimated: {:?}", r.eta_sigma);
    let run = |sym: bool| {
        noise_estimate_covariance(&prob, &r.theta, &gn, &r.eta, &eta_free, &ev.total, &cov, true, sym).expect("η term")
    };
    let before = prob.evaluations.get();
    let (c_sym, a_sym) = run(true);
    let mid = prob.evaluations.get();
    let (c_eta, a_eta) = run(false);
    let after = prob.evaluations.get();
    let free_theta = r.free.iter().filter(|f| **f).count();
    assert_eq!(mid[0] - before[0], free_theta, "one pass per free θ");
    assert_eq!(after[0] - mid[0], free_theta + eta_free.iter().filter(|f| **f).count());
    for i in 0..4 {
        let s = cov[(i, i)].sqrt();
        for j in 0..6 {
            // In units of θ_i's σ per unit of η_j's σ: what the covariance sees.
            let (x, y) = (a_sym[i][j] * r.eta_sigma[j] / s, a_eta[i][j] * r.eta_sigma[j] / s);
            // Two forward differences (1 % of σ_θ, 1e-4 in η): measured up to
            // 9e-4 σ apart on the small entries (4 km `high`, seed 2).
            assert!((x - y).abs() <= 1e-2 * x.abs().max(y.abs()) + 2e-3, "∂θ{i}/∂η{j}: {x:.6} vs {y:.6} (σ units)");
        }
        let (x, y) = (c_sym[(i, i)].sqrt(), c_eta[(i, i)].sqrt());
        // Measured: within 7e-4 relative.
        assert!((x - y).abs() <= 3e-3 * y + 1e-6 * s, "η term of σ{i}: {x:.6e} vs {y:.6e}");
    }
}

/// Stop 24: lean iteration starts (θ derivatives only until the θ step is
/// below the tolerance) give the scoring pass of full evaluations to the
/// bit: θ, η, η's σ, the termination, the remaining η step, every accepted
/// iteration's θ, η, cost and step factor, and the final evaluation's sums.
/// Also where the pass stops by the iteration limit, without the final step
/// check and from a start far from the estimate. Fewer covariance columns,
/// not fewer passes, is what it saves; the pass count is reported.
#[test]
#[allow(clippy::float_cmp)] // identity to the bit is the claim
fn lean_iteration_starts_give_the_full_evaluations_results_to_the_bit() {
    let cases: [(NoiseOptions, u64, f64); 2] = [(NoiseOptions::high(), 2, 2.0), (NoiseOptions::paper(), 7, 2.0)];
    for (noise, seed, km) in cases {
        let out = simulate(&SimOptions { length_km: km, noise, ..SimOptions::paper(seed) }).expect("sim");
        let input = input_of(&out.drive);
        let gn = batch_gn_all(&out.drive);
        let far = Theta { c_e: gn.c_e * 1.003, t_r: gn.t_r * 1.05, ..gn };
        let variants = [
            ("default", EivOptions::default(), gn),
            ("from afar", EivOptions::default(), far),
            ("iteration limit", EivOptions { max_iterations: 2, ..EivOptions::default() }, far),
            ("no final step check", EivOptions { final_step_check: false, ..EivOptions::default() }, gn),
        ];
        for (name, opts, start) in variants {
            let q = opts.quantisation_level.step_found(&input);
            let opts = opts.with_resolved_quantisation(q);
            let run = |lean: bool| {
                let prob = Problem {
                    lean_iterations: lean,
                    ..Problem::new(&input, make_windows(input.parts, opts.window_samples), &opts)
                };
                let out = scoring_pass(&prob, start, [0.0; 6], start, opts.free, true, &opts).expect("scoring pass");
                (out, prob.evaluations.get())
            };
            let ((full, full_passes), (lean, lean_passes)) = (run(false), run(true));
            let case = format!("seed {seed}, {name}");
            assert_eq!(lean.theta, full.theta, "{case}: θ");
            assert_eq!(lean.eta, full.eta, "{case}: η");
            assert_eq!(lean.eta_sigma, full.eta_sigma, "{case}: σ_η");
            assert_eq!(lean.report.termination, full.report.termination, "{case}: termination");
            assert_eq!(lean.report.eta_step_over_sigma, full.report.eta_step_over_sigma, "{case}: η step left");
            assert_eq!(lean.report.final_cost, full.report.final_cost, "{case}: cost");
            assert_eq!(lean.report.history.len(), full.report.history.len(), "{case}: iterations");
            for (a, b) in lean.report.history.iter().zip(&full.report.history) {
                assert_eq!((a.theta, a.eta, a.cost, a.step_factor), (b.theta, b.eta, b.cost, b.step_factor), "{case}");
                assert!(a.step_over_sigma <= b.step_over_sigma, "{case}: the lean start lacks only the η part");
            }
            assert_eq!(lean.eval.mode, full.eval.mode, "{case}: the final evaluation is in full");
            assert_eq!(lean.eval.total, full.eval.total, "{case}: the final evaluation's sums");
            eprintln!("{case}: {:?}, passes full {full_passes:?} lean {lean_passes:?}", full.report.termination);
        }
    }
}

/// Stop 24: skipping the covariance derivatives of some η columns (the η
/// term's displaced passes skip the scales at a clamp) leaves every other
/// entry of the sums the same to the bit, and the skipped η's gradient
/// differs (so the skip is real).
#[test]
#[allow(clippy::float_cmp)] // identity to the bit is the claim
fn skipping_eta_columns_leaves_the_other_entries_to_the_bit() {
    let out = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(4) }).expect("sim");
    let input = input_of(&out.drive);
    let opts = EivOptions::default();
    let prob = Problem::new(&input, make_windows(input.parts, opts.window_samples), &opts);
    let th = out.sidecar.theta_true;
    let eta = [0.1, -0.3, 0.2, 0.1, -0.2, 0.3];
    let full = prob.evaluate(&th, &th, &eta, filter::Mode::full(true, true)).expect("filter").total;
    let skip = (1u8 << 2) | (1 << 4);
    let lean = prob.evaluate(&th, &th, &eta, filter::Mode::full(true, true).skipping_eta(skip)).expect("filter").total;
    assert_eq!((lean.quad, lean.logdet, lean.correction), (full.quad, full.logdet, full.correction));
    assert_eq!(lean.h_theta, full.h_theta);
    for c in (0..filter::NP).filter(|c| *c < 4 || (skip >> (c - 4)) & 1 == 0) {
        assert_eq!(lean.grad_profile[c], full.grad_profile[c], "column {c}");
        assert_eq!(lean.grad[c], full.grad[c], "column {c}");
        for c2 in (0..filter::NP).filter(|c2| *c2 < 4 || (skip >> (c2 - 4)) & 1 == 0) {
            assert_eq!(lean.info[(c, c2)], full.info[(c, c2)], "information ({c}, {c2})");
        }
    }
    for j in [2usize, 4] {
        assert_ne!(lean.grad[4 + j], full.grad[4 + j], "η{j} was skipped");
        assert_eq!(lean.grad_jacobian_eta[j], nalgebra::Vector4::zeros(), "η{j}: no log-Jacobian derivative");
    }
}
