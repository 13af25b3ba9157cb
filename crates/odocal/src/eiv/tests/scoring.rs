//! Fisher scoring: what the fits return and how they converge.

use super::support::*;
use crate::eiv::filter::run_window;
use crate::eiv::filter::NETA;
use crate::eiv::input::make_windows;
use crate::eiv::problem::Problem;
use crate::eiv::steps::eta_add;
use crate::eiv::steps::eta_step;
use crate::eiv::*;
use crate::model::param::Param;
use crate::sim::{simulate, NoiseOptions, SimOptions};
use crate::Theta;

/// Noise-free, one substep: the model is exact; EIV must return θ_true to
/// rounding (the correction term with η at its lower clamp moves it by
/// ~1e-11).
const EXACT_REL_TOL: f64 = 1e-8;

#[test]
#[allow(clippy::float_cmp)] // a held scale's zeros are exact
fn noise_free_recovers_theta_true_and_eta_at_lower_clamp() {
    let out = simulate(&SimOptions { length_km: 6.0, substeps: 1, ..SimOptions::noise_free(11) }).expect("sim");
    let truth = out.sidecar.theta_true;
    let input = input_of(&out.drive);
    let start = Theta { c_e: 1.96, c_d: -0.001, t_r: 1.55, d: 0.0005 };
    // With the observed noise-estimate term, whose held scales must add nothing (θ is the default's).
    let opts = EivOptions {
        research: ResearchOptions { noise_estimate_term: NoiseEstimateTerm::Observed, ..Default::default() },
        ..EivOptions::default()
    };
    let r = estimate(&input, &start, &opts).expect("eiv");
    let (e, t) = (r.theta.to_array(), truth.to_array());
    for i in 0..4 {
        let rel = (e[i] - t[i]).abs() / t[i].abs();
        assert!(rel <= EXACT_REL_TOL, "{}: {} vs {} (rel {rel:.2e}); {r}", PARAMETERS[i], e[i], t[i]);
    }
    for j in 0..NETA {
        assert!(r.eta[j] <= opts.eta_bounds[0] + 1e-9, "η{j} = {} not at the lower clamp; {r}", r.eta[j]);
        // A scale at its clamp counts as held: no σ, no term in θ's σ.
        assert_eq!(r.eta_sigma[j], 0.0, "η{j} at its clamp has a σ; {r}");
        assert!((0..4).all(|i| r.theta_eta_sensitivity[i][j] == 0.0), "η{j} at its clamp in θ's noise term; {r}");
    }
    assert_eq!(r.sigma_noise_estimate, [0.0; 4], "no scale estimated, no noise-estimate term; {r}");
    assert!(!r.warnings.iter().any(|w| matches!(w, EivWarning::NoiseAtUpperClamp { .. })), "{:?}", r.warnings);
}

/// The same with encoder quantisation modelled by counting (remainder
/// states): θ_true to rounding. In the slow tier (a second 6 km fit; a
/// 1.5 km drive leaves t_r unobservable):
/// `cargo test -p odocal --lib -- --ignored counting`.
#[test]
#[ignore = "slow tier, a second 6 km fit: cargo test --workspace -- --ignored"]
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
    assert!(r.observability.unobservable.contains(&Param::TR), "{:?}", r.observability);
    assert!(r.observability.unobservable.contains(&Param::D), "{:?}", r.observability);
    assert!(!r.free[2] && !r.free[3] && r.free[0]);
    assert!(r.warnings.iter().any(|w| matches!(w, EivWarning::Unobservable { .. })));

    // A start whose unobservable t_r and d are far off (batch G-N's value on
    // a straight drive is arbitrary): by default they stay at the start,
    // with `hold_unobservable_at` at the given θ_0; c_e is estimated either way.
    let bad_start = Theta { c_e: 1.96, t_r: 5.63, d: 0.01, ..th };
    let at_start = estimate(&input, &bad_start, &EivOptions::default()).expect("eiv");
    assert_eq!((at_start.theta.t_r, at_start.theta.d), (5.63, 0.01), "{at_start}");
    let mut held = EivOptions::default();
    held.research.hold_unobservable_at = Some(th);
    let at_theta0 = estimate(&input, &bad_start, &held).expect("eiv");
    assert_eq!((at_theta0.theta.t_r, at_theta0.theta.d), (th.t_r, th.d), "{at_theta0}");
    assert!((at_theta0.theta.c_e - th.c_e).abs() < 1e-6, "{at_theta0}");
    let mut invalid = EivOptions::default();
    invalid.research.hold_unobservable_at = Some(Theta { t_r: f64::NAN, ..th });
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

/// `ResearchOptions::position_floor_m` is the position σ floor of R: on a
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
    let (a, b) = (run(BASE_POSITION_FLOOR_M), run(0.005));
    assert!(!a.is_empty() && a.len() == b.len());
    // The first update: P⁻ = P₀ + Q with P₀ = R, so S = 2R + H Q Hᵀ.
    let want = 2.0 * (0.005f64.powi(2) - BASE_POSITION_FLOOR_M.powi(2));
    for c in 0..2 {
        let got = b[0].s[(c, c)] - a[0].s[(c, c)];
        assert!((got - want).abs() <= 1e-12, "S[{c},{c}] grew by {got:e}, want {want:e}");
    }
    assert!((b[0].s[(2, 2)] - a[0].s[(2, 2)]).abs() <= 1e-15, "the heading variance moved");
    // Later updates: never less than the floor's share of R.
    assert!(b.iter().all(|r| r.s[(0, 0)] >= 0.005f64.powi(2) && r.s[(1, 1)] >= 0.005f64.powi(2)));
    for bad in [0.0, -1e-3, f64::NAN] {
        let opts = EivOptions {
            research: ResearchOptions { position_floor_m: bad, ..Default::default() },
            ..EivOptions::default()
        };
        assert!(opts.validate().is_err(), "floor {bad} accepted");
    }
}

/// The separate heading scale, with every quantisation model, returns
/// c_e on the noise-free straight drive (the other options the defaults).
/// Regression: with the base formulation's input log-Jacobian
/// ([`InputJacobian::None`]) the θ/η iteration stops after two iterations
/// at a second fixed point, c_e −0.057 % with η held well above its lower
/// clamp; with [`InputJacobian::FilterShare`]
/// the profile cost's minimum at that η is +0.026 %, not −0.057 %, so the
/// point is not fixed and the fit reaches θ_true.
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
/// stands after one iteration) the scoring step of the variances, mapped
/// to η by ln(1 + d) and clamped, points uphill (gᵀΔη = +249): every
/// halving would be rejected and the fit would stop with c_e 0.06 % off.
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
        a_y_sigma_held: None,
        a_y_sigma_floor: 0.0,
        heading_white_floor: 0.0,
        sideslip_white: false,
        heading_separate: true,
        fitted_input: false,
        position_floor_m: opts.research.position_floor_m,
        noise_input_half_width: 0,
        input_jacobian: opts.research.input_jacobian,
        coloured_jacobian_in_marginal: true,
        common_mode_jacobian: true,
        position_drift_own_scale: false,
        position_drift_time_constant_s: None,
        heading_drift_min_eta: -20.0,
        evaluations: std::cell::Cell::new([0; 2]),
        lean_iterations: true,
        c_d_covariance_derivative: false,
    };
    let theta = Theta { c_e: 1.9488978137579984, c_d: -0.001998869480161304, t_r: 1.53, d: 0.0008 };
    let eta = [-0.00903020194120505, 0.2628615557666504, 0.75, 0.1370901227620087, -2.5, -2.5];
    let ev = prob.evaluate(&theta, &theta, &eta, filter::Mode::full(true, true)).expect("filter");
    let step = eta_step(&ev.total, &eta, opts.eta_bounds, &[false; 6]).step;
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

/// Convergence is also tested on the step that remains at the end of an
/// iteration: the fit of this drive takes n iterations, the n-th step is
/// not below the tolerance but the step remaining after it is, so an
/// n-iteration limit ends converged, at the same θ.
#[test]
fn final_step_check_converges_at_the_iteration_limit() {
    let (out, base) = separate_counting_white_drive();
    let input = input_of(&out.drive);
    let truth = out.sidecar.theta_true;
    let full = estimate(&input, &truth, &base).expect("eiv");
    let history = full.passes.last().map(|p| p.history.clone()).unwrap_or_default();
    let n = history.len();
    assert!((2..base.max_iterations).contains(&n), "{full}");
    // The step taken in the n-th iteration is not below the tolerance.
    assert!(history[n - 1].step_over_sigma >= 0.05, "{full}");
    let opts = EivOptions { max_iterations: n, ..base };
    let r = estimate(&input, &truth, &opts).expect("eiv");
    assert!(r.termination.converged(), "{r}");
    assert_eq!(r.theta, full.theta);
}

/// A source at its lower clamp is released at the end of a fit when its
/// score points into the range by more than `REENTRY_SCORE_Z`, at its
/// one-step estimate (here η = −20 + ln(1 + 0.35·e^20) ≈ ln 0.35); not with a
/// weaker score, a one-step estimate below `REENTRY_MIN_ETA`, or held.
#[test]
fn a_source_at_its_lower_clamp_is_released_when_its_score_says_so() {
    use crate::eiv::filter::WindowSums;
    use crate::eiv::steps::{reentering_sources, REENTRY_MIN_ETA, REENTRY_SCORE_Z};
    let bounds = EivOptions::default().eta_bounds;
    let mut eta = [0.0; NETA];
    eta[4] = bounds[0];
    // Source 4 at the clamp with information i44 and score z; the others
    // interior, with no score.
    let sums = |z: f64, i44: f64| {
        let mut s = WindowSums::zero();
        for j in 0..NETA {
            s.i_eta[(j, j)] = 100.0;
        }
        s.i_eta[(4, 4)] = i44;
        s.grad[4 + 4] = -z * i44.sqrt();
        s
    };
    let at_clamp = 100.0 * (2.0 * bounds[0]).exp();
    let z = REENTRY_SCORE_Z + 0.5;
    let released = reentering_sources(&sums(z, at_clamp), &eta, bounds, &[false; NETA]);
    assert_eq!(released.len(), 1, "{released:?}");
    assert_eq!(released[0].0, 4);
    assert!((released[0].1 - (z / 10.0).ln()).abs() < 1e-6, "{released:?}");
    let weaker = reentering_sources(&sums(REENTRY_SCORE_Z - 0.5, at_clamp), &eta, bounds, &[false; NETA]);
    assert!(weaker.is_empty(), "{weaker:?}");
    // A one-step estimate 2 below REENTRY_MIN_ETA.
    let i44 = (z * (bounds[0] - REENTRY_MIN_ETA + 2.0).exp()).powi(2);
    let low = reentering_sources(&sums(z, i44), &eta, bounds, &[false; NETA]);
    assert!(low.is_empty(), "{low:?}");
    let mut held = [false; NETA];
    held[4] = true;
    assert!(reentering_sources(&sums(z, at_clamp), &eta, bounds, &held).is_empty());
}

/// Simultaneous θ/η steps near the estimate (`simultaneous_steps`, the
/// default; here without the final step) reach the alternating steps' estimate: both fits converge, θ
/// within [`SIMULTANEOUS_THETA_TOL`] of its σ and η within that fraction
/// of its σ plus rounding, with fewer filter passes with derivatives over
/// the drives (two `paper` drives save 2 and 3, a `high` drive whose
/// step grows again near the estimate loses 1).
#[test]
fn simultaneous_steps_reach_the_alternating_estimate_with_fewer_passes() {
    let cases: [(NoiseOptions, u64, f64); 3] =
        [(NoiseOptions::paper(), 1, 6.0), (NoiseOptions::paper(), 4, 6.0), (NoiseOptions::high(), 2, 6.0)];
    let mut saved = 0;
    for (noise, seed, km) in cases {
        let out = simulate(&SimOptions { length_km: km, noise, ..SimOptions::paper(seed) }).expect("sim");
        let input = input_of(&out.drive);
        let start = batch_gn_all(&out.drive);
        let default = EivOptions::default();
        let base =
            EivOptions { research: ResearchOptions { final_step: false, ..default.research.clone() }, ..default };
        let alternating = EivOptions {
            research: ResearchOptions { simultaneous_steps: false, ..base.research.clone() },
            ..base.clone()
        };
        let a = estimate(&input, &start, &alternating).expect("alternating");
        let s = estimate(&input, &start, &base).expect("simultaneous");
        let case = format!("seed {seed}, {km} km");
        assert!(a.termination.converged() && s.termination.converged(), "{case}: {a} {s}");
        let (ta, ts) = (a.theta.to_array(), s.theta.to_array());
        for i in 0..4 {
            let z = (ts[i] - ta[i]).abs() / a.sigma[i];
            eprintln!("{case}: θ{i} moved {z:.5} σ");
            assert!(z <= SIMULTANEOUS_THETA_TOL, "{case}: θ{i} moved {z} σ");
            assert!((s.sigma[i] / a.sigma[i] - 1.0).abs() < 1e-3, "{case}: σ{i} {} vs {}", s.sigma[i], a.sigma[i]);
        }
        for j in 0..NETA {
            let tol = SIMULTANEOUS_THETA_TOL * a.eta_sigma[j] + 1e-9;
            assert!((s.eta[j] - a.eta[j]).abs() <= tol, "{case}: η{j} {} vs {}", s.eta[j], a.eta[j]);
        }
        eprintln!("{case}: passes {:?} alternating, {:?} simultaneous", a.evaluations, s.evaluations);
        // A simultaneous step that does not shrink the step enough costs its
        // pass, and the alternating steps go on (the `high` drive).
        assert!(s.evaluations[0] <= a.evaluations[0] + 1, "{case}: {:?} vs {:?}", s.evaluations, a.evaluations);
        saved += a.evaluations[0] as i64 - s.evaluations[0] as i64;
    }
    assert!(saved >= 4, "passes saved {saved}");
}

/// The final step (`final_step`, the default) ends a fit whose
/// simultaneous steps shrink fast without the evaluation with derivatives
/// after its last step: against the same fit without it, θ within
/// [`SIMULTANEOUS_THETA_TOL`] of its σ (the same θ to the bit where the
/// evaluation it saves would have found the remainder below the
/// tolerance), σ within 0.5 % (the information is that of the point the
/// last step left, a fraction of σ away), the final cost that of the
/// estimate, and one pass with derivatives fewer for each final step.
#[test]
fn a_final_step_saves_the_last_pass_and_keeps_the_estimate() {
    let cases: [(NoiseOptions, u64, f64); 3] =
        [(NoiseOptions::paper(), 1, 12.0), (NoiseOptions::paper(), 2, 12.0), (NoiseOptions::paper(), 4, 6.0)];
    let (mut final_steps, mut costs_compared) = (0, 0);
    for (noise, seed, km) in cases {
        let out = simulate(&SimOptions { length_km: km, noise, ..SimOptions::paper(seed) }).expect("sim");
        let input = input_of(&out.drive);
        let start = batch_gn_all(&out.drive);
        let with = EivOptions::default();
        let without =
            EivOptions { research: ResearchOptions { final_step: false, ..with.research.clone() }, ..with.clone() };
        let a = estimate(&input, &start, &without).expect("without");
        let f = estimate(&input, &start, &with).expect("with");
        let case = format!("seed {seed}, {km} km");
        assert!(a.termination.converged() && f.termination.converged(), "{case}: {a} {f}");
        let (ta, tf) = (a.theta.to_array(), f.theta.to_array());
        for i in 0..4 {
            let z = (tf[i] - ta[i]).abs() / a.sigma[i];
            assert!(z <= SIMULTANEOUS_THETA_TOL, "{case}: θ{i} moved {z} σ");
            assert!((f.sigma[i] / a.sigma[i] - 1.0).abs() < 5e-3, "{case}: σ{i} {} vs {}", f.sigma[i], a.sigma[i]);
        }
        let steps = f.passes.iter().filter(|p| matches!(p.termination, Termination::FinalStep { .. })).count();
        eprintln!("{case}: passes {:?} without, {:?} with {steps} final steps", a.evaluations, f.evaluations);
        assert!(f.evaluations[0] + steps <= a.evaluations[0], "{case}: {:?} vs {:?}", f.evaluations, a.evaluations);
        let (last_a, last_f) = (a.passes.last().expect("a pass"), f.passes.last().expect("a pass"));
        let same = tf.iter().zip(&ta).all(|(x, y)| x.to_bits() == y.to_bits());
        if same && matches!(last_f.termination, Termination::FinalStep { .. }) {
            // The same point: the objective taken at the estimate is the
            // one the saved evaluation computed there.
            assert_eq!(last_f.final_cost.to_bits(), last_a.final_cost.to_bits(), "{case}");
            costs_compared += 1;
        }
        final_steps += steps;
    }
    assert!(final_steps >= 2 && costs_compared >= 1, "final steps {final_steps}, costs compared {costs_compared}");
}

/// How far [`simultaneous_steps_reach_the_alternating_estimate_with_fewer_passes`]
/// lets θ move, in its σ: both fits stop where the remaining step is below
/// 0.05 σ, and near the estimate each iteration shrinks it 3–55 ×
/// (`LIKELY_LAST` in the source), so the two estimates differ by a small
/// part of that.
const SIMULTANEOUS_THETA_TOL: f64 = 0.02;

/// How far [`a_long_drive_starts_from_a_coarse_fit_and_reaches_the_same_estimate`]
/// lets θ move, in its σ: both fits stop where the remaining step is below
/// the step tolerance (0.05 σ), from different sides of the path.
const COARSE_THETA_TOL: f64 = 0.05;

/// On a drive of at least 24 windows the first pass fits every `k`-th
/// window first (`coarse_start`, the default). Against the same fit from
/// the start over all windows: the same estimate within
/// [`COARSE_THETA_TOL`] of its σ, σ within 1 %, the same noise scales
/// within their tolerance, the coarse pass reported first with its
/// stride, and fewer passes over the drive in all. A drive of fewer
/// windows is fitted as with the option off, to the bit.
#[test]
fn a_long_drive_starts_from_a_coarse_fit_and_reaches_the_same_estimate() {
    // (seed, km, window samples, noise, d held): 24 km is about 65 000
    // samples, so windows of 2 500 make 26 (a coarse stride of 2), as the
    // default windows do on a 48 km drive. With d held, its resolution is
    // below its σ, so the observability decision holds it (at a value of
    // its own, as `calibrate` holds it at batch G-N's).
    let cases: [(u64, f64, usize, NoiseOptions, bool); 5] = [
        (1, 24.0, 2500, NoiseOptions::paper(), false),
        (2, 24.0, 2500, NoiseOptions::paper(), false),
        (3, 24.0, 2500, NoiseOptions::high(), false),
        (1, 24.0, 2500, NoiseOptions::paper(), true),
        (4, 3.0, 6000, NoiseOptions::paper(), false),
    ];
    let (mut coarse_fits, mut saved) = (0, 0i64);
    for (seed, km, window_samples, noise, hold_d) in cases {
        let out = simulate(&SimOptions { length_km: km, noise, ..SimOptions::paper(seed) }).expect("sim");
        let input = input_of(&out.drive);
        let start = batch_gn_all(&out.drive);
        let held = Theta { d: 0.0007, ..start };
        let mut with = EivOptions { window_samples, ..EivOptions::default() };
        if hold_d {
            with.resolution[3] = 1e-7;
            with.research.hold_unobservable_at = Some(held);
        }
        let without =
            EivOptions { research: ResearchOptions { coarse_start: false, ..with.research.clone() }, ..with.clone() };
        let a = estimate(&input, &start, &without).expect("without");
        let c = estimate(&input, &start, &with).expect("with");
        let case = format!("seed {seed}, {km} km, windows of {window_samples}, d held {hold_d}");
        assert!(a.termination.converged() && c.termination.converged(), "{case}: {a} {c}");
        let stride = c.passes.first().and_then(|p| p.window_stride);
        if a.windows.len() < 24 {
            assert_eq!(stride, None, "{case}");
            assert_eq!(a, EivReport { timing_s: a.timing_s, ..c.clone() }, "{case}: not the same fit");
            continue;
        }
        let k = stride.expect("a coarse pass first");
        assert_eq!(k, a.windows.len() / 12, "{case}");
        assert!(c.passes.iter().skip(1).all(|p| p.window_stride.is_none()), "{case}");
        let (ta, tc) = (a.theta.to_array(), c.theta.to_array());
        for i in (0..4).filter(|i| a.free[*i]) {
            let z = (tc[i] - ta[i]).abs() / a.sigma[i];
            assert!(z <= COARSE_THETA_TOL, "{case}: θ{i} moved {z} σ");
            assert!((c.sigma[i] / a.sigma[i] - 1.0).abs() < 1e-2, "{case}: σ{i} {} vs {}", c.sigma[i], a.sigma[i]);
        }
        for j in 0..6 {
            let tol = 0.1 * a.eta_sigma[j].max(1e-3);
            assert!((c.eta[j] - a.eta[j]).abs() <= tol, "{case}: η{j} {} vs {}", c.eta[j], a.eta[j]);
        }
        assert_eq!(a.free, c.free, "{case}");
        assert_eq!(a.observability.unobservable, c.observability.unobservable, "{case}");
        if hold_d {
            assert_eq!(c.observability.unobservable, vec![Param::D], "{case}");
            assert_eq!((a.theta.d, c.theta.d), (held.d, held.d), "{case}");
        }
        eprintln!("{case}: stride {k}, passes {:?} from the start, {:?} coarse first", a.evaluations, c.evaluations);
        saved += a.evaluations[0] as i64 - c.evaluations[0] as i64;
        coarse_fits += 1;
    }
    assert!(coarse_fits == 4 && saved >= 3, "coarse fits {coarse_fits}, passes saved {saved}");
}

#[test]
fn the_coarse_stride_keeps_about_twelve_windows() {
    use crate::eiv::estimate::coarse_stride;
    assert_eq!(coarse_stride(11), 0);
    assert_eq!(coarse_stride(23), 1);
    assert_eq!(coarse_stride(24), 2);
    assert_eq!(coarse_stride(55), 4);
}
