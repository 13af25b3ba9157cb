//! Cross-checks of the structured solver against Clarabel and a direct
//! dense KKT solve.

use nalgebra::Vector3;
use proptest::prelude::*;

use super::clarabel::ClarabelSolver;
use super::riccati::StructuredSolver;
use super::*;

/// Relative objective agreement of two solvers stopping at 1e-9-ish
/// relative tolerances.
const OBJ_RTOL: f64 = 1e-7;
/// Input agreement, rev/s (inputs are O(0.01..0.25)).
// Measured: seed 3020, k 54, tightness 0.9 gives 1.3e-6 and seed 5158, k 46,
// tightness 0 gives 5.3e-6 (both solvers stop at ~1e-9 relative objective;
// near-flat directions leave the inputs free at the 1e-6 level). The
// objective tolerance above is the sharp check.
const W_ATOL: f64 = 1e-5;
/// Bound violation allowed: interior-point iterates stay strictly inside,
/// up to rounding.
const BOUND_TOL: f64 = 1e-9;

fn max_w_diff(a: &QpSolution, b: &QpSolution) -> f64 {
    a.w.iter().zip(&b.w).map(|(x, y)| (x - y).amax()).fold(0.0, f64::max)
}

fn assert_agree(qp: &StageQp, s: &QpSolution, c: &QpSolution) {
    let rel = (s.objective - c.objective).abs() / c.objective.abs().max(1e-12);
    assert!(rel <= OBJ_RTOL, "objective {} vs {} (rel {rel:.1e})", s.objective, c.objective);
    let dw = max_w_diff(s, c);
    assert!(dw <= W_ATOL, "inputs differ by {dw:.1e}");
    assert!(qp.max_bound_violation(&s.w, &s.z) <= BOUND_TOL);
    assert!(qp.max_bound_violation(&c.w, &c.z) <= BOUND_TOL);
}

proptest! {
    // A fixed RNG seed: the same 24 instances on every run (plus the saved
    // regression cases), so the test cannot pass or fail by luck of the draw.
    #![proptest_config(ProptestConfig {
        cases: 24,
        rng_seed: proptest::test_runner::RngSeed::Fixed(0x0d0ca1),
        ..ProptestConfig::default()
    })]

    #[test]
    fn structured_agrees_with_clarabel(seed in 0u64..10_000, k in 5usize..60, tight in prop::sample::select(vec![0.0, 0.9, 0.97])) {
        let qp = random_instance(seed, k, tight);
        // At tightness 0.97 an occasional instance has no feasible point
        // (e.g. seed 8960, k 46): then both solvers must say so.
        let (s, c) = match (StructuredSolver::tight().solve(&qp, None), ClarabelSolver::default().solve(&qp, None)) {
            (Err(QpError::Infeasible(_)), Err(QpError::Infeasible(_))) => return Ok(()),
            // A numerical failure of the structured solver on a nearly
            // infeasible box (tightness 0.97; about 0.6 % of instances, see
            // `structured_failures_are_rare_...`) is what compensation's
            // fallback to Clarabel handles: allowed here, counted there.
            (Err(QpError::Numerical(_) | QpError::MaxIterations { .. }), Ok(_)) if tight > 0.95 => return Ok(()),
            (s, c) => (s.unwrap(), c.unwrap()),
        };
        assert_agree(&qp, &s, &c);
        prop_assert!((s.objective - qp.objective(&s.w, &s.z)).abs() <= 1e-12 * s.objective.max(1.0));
    }
}

/// An instance on which an input tolerance of 1e-6 is too loose: the tight
/// solver must still agree with Clarabel.
#[test]
fn known_flat_instance_agrees() {
    let qp = random_instance(3020, 54, 0.9);
    let s = StructuredSolver::tight().solve(&qp, None).unwrap();
    let c = ClarabelSolver::default().solve(&qp, None).unwrap();
    assert_agree(&qp, &s, &c);
}

#[test]
fn tight_instances_activate_bounds_and_still_agree() {
    for seed in 0..4 {
        let qp = random_instance(seed, 60, 0.97);
        let s = StructuredSolver::tight().solve(&qp, None).unwrap();
        let c = ClarabelSolver::default().solve(&qp, None).unwrap();
        assert!(s.active_bounds(&qp) > 0 && c.active_bounds(&qp) > 0, "seed {seed}: no active bound");
        assert_agree(&qp, &s, &c);
    }
}

#[test]
fn structured_solution_satisfies_kkt() {
    for (seed, k, tight) in [(11, 200, 0.0), (12, 200, 0.9), (13, 120, 0.97)] {
        let qp = random_instance(seed, k, tight);
        let s = StructuredSolver::tight().solve(&qp, None).unwrap();
        let r = kkt_residual(&qp, &s).unwrap();
        // Converged to 1e-9 relative: dynamics exact to rounding, distance
        // to the optimum (scaled natural residual) ~1e-9 of O(0.1) values,
        // complementarity ≤ tol_gap·f.
        assert!(r.dynamics < 1e-10, "{r:?}");
        assert!(r.bounds <= BOUND_TOL, "{r:?}");
        assert!(r.stationarity < 1e-8, "{r:?}");
        assert!(r.complementarity < 1e-8 * s.objective.max(1.0), "{r:?}");
    }
}

#[test]
fn kkt_residual_detects_wrong_duals() {
    let qp = random_instance(14, 30, 0.0);
    let mut s = StructuredSolver::tight().solve(&qp, None).unwrap();
    if let Some(l) = s.dynamics_duals.as_mut() {
        l[10] += Vector3::new(0.0, 1e-3, 0.0);
    }
    assert!(kkt_residual(&qp, &s).unwrap().stationarity > 1e-6);
}

#[test]
fn without_active_bounds_both_equal_the_direct_kkt_solve() {
    for seed in 20..24 {
        let qp = random_instance(seed, 25, 0.0);
        let d = solve_equality_constrained(&qp).unwrap();
        assert_eq!(d.active_bounds(&qp), 0, "seed {seed}: test needs an instance without active bounds");
        assert!(qp.max_bound_violation(&d.w, &d.z) <= 0.0);
        for s in
            [StructuredSolver::tight().solve(&qp, None).unwrap(), ClarabelSolver::default().solve(&qp, None).unwrap()]
        {
            assert_agree(&qp, &s, &d);
            let (ls, ld) = (s.dynamics_duals.as_ref().unwrap(), d.dynamics_duals.as_ref().unwrap());
            for (a, b) in ls.iter().zip(ld) {
                assert!((a - b).amax() <= 1e-5 * (1.0 + b.amax()), "λ {a} vs {b}");
            }
        }
    }
}

fn assert_both_infeasible(qp: &StageQp) {
    for solver in [SolverKind::Structured.solver(), SolverKind::Clarabel.solver()] {
        match solver.solve(qp, None) {
            Err(QpError::Infeasible(why)) => assert!(!why.is_empty()),
            other => panic!("{}: expected Infeasible, got {other:?}", solver.name()),
        }
    }
}

#[test]
fn state_offset_no_input_can_fix_is_infeasible() {
    let mut qp = random_instance(30, 40, 0.0);
    // A 20 m jump in p_x at step 15; inputs move z by ~1 mm per step and
    // the box is ±5 m.
    qp.c[15][0] = 20.0;
    assert_both_infeasible(&qp);
}

#[test]
fn heading_drift_beyond_box_is_infeasible() {
    let mut qp = random_instance(31, 80, 0.0);
    // 0.05 rad per step for 40 steps; the inputs turn by at most ~0.016 rad
    // per step, leaving > 1.3 rad against a 0.5 rad box.
    for c in qp.c.iter_mut().skip(20).take(40) {
        c[2] += 0.05;
    }
    assert_both_infeasible(&qp);
}

#[test]
fn empty_input_box_is_infeasible() {
    let mut qp = random_instance(32, 10, 0.0);
    qp.w_lo[3][1] = qp.w_hi[3][1] + 0.01;
    assert_both_infeasible(&qp);
}

/// The same instance with every `c_k` and `δ_k` moved by ~1 % of its size,
/// as between two re-linearisations.
fn perturbed(qp: &StageQp, seed: u64) -> StageQp {
    let other = random_instance(seed, qp.stages(), 0.0);
    let mut p = qp.clone();
    for (c, o) in p.c.iter_mut().zip(&other.c) {
        *c += 0.01 * o;
    }
    for (d, o) in p.delta.iter_mut().zip(&other.delta) {
        *d += 0.01 * o;
    }
    p
}

#[test]
fn warm_start_needs_no_more_iterations_and_gives_the_same_answer() {
    let solver = StructuredSolver::tight();
    for (seed, k, tight) in [(40, 650, 0.0), (41, 300, 0.9), (42, 200, 0.97)] {
        let qp0 = random_instance(seed, k, tight);
        let prev = solver.solve(&qp0, None).unwrap();
        let qp = perturbed(&qp0, seed + 100);
        let cold = solver.solve(&qp, None).unwrap();
        let warm = solver.solve(&qp, Some(&prev)).unwrap();
        assert!(warm.iterations <= cold.iterations, "seed {seed}: warm {} > cold {}", warm.iterations, cold.iterations);
        assert_agree(&qp, &warm, &cold);
        eprintln!("seed {seed} K {k} tightness {tight}: cold {} warm {} iterations", cold.iterations, warm.iterations);
    }
}

#[test]
fn solver_kind_parses_and_builds() {
    assert_eq!("structured".parse::<SolverKind>().unwrap(), SolverKind::Structured);
    assert_eq!("Clarabel".parse::<SolverKind>().unwrap(), SolverKind::Clarabel);
    assert!("osqp".parse::<SolverKind>().unwrap_err().to_string().contains("'osqp': use structured or clarabel"));
    assert_eq!(SolverKind::Structured.solver().name(), "structured");
    assert_eq!(SolverKind::Clarabel.solver().name(), "clarabel");
    assert_eq!(SolverKind::default().to_string(), "structured");
}

#[test]
fn random_instance_is_reproducible_and_realistic() {
    let a = random_instance(7, 50, 0.0);
    assert_eq!(a, random_instance(7, 50, 0.0));
    assert_ne!(a, random_instance(8, 50, 0.0));
    a.check().unwrap();
    for (m, b) in a.a.iter().zip(&a.b) {
        assert!(m[0].hypot(m[1]) > 0.1 && m[0].hypot(m[1]) < 0.5, "heading column {m}");
        assert!(b.amax() > 0.005 && b.amax() < 0.05, "B magnitude {}", b.amax());
    }
    assert!(a.w_hi.iter().all(|w| w.min() > 0.1 && w.max() < 0.4));
}

/// Standstill: the measured wheel rotation is 0, so the ±5 % input box has
/// zero width. Squeezed between two slacks that cannot both stay positive,
/// such inputs would hold the structured solver at its iteration limit; it
/// pins them instead. Same optimum as Clarabel, cold and warm.
#[test]
fn zero_width_input_boxes_are_pinned() {
    for (seed, tight) in [(21, 0.0), (22, 0.9)] {
        let mut qp = random_instance(seed, 400, tight);
        // A stop: both wheels at rest over stages 150..260, one wheel over 260..270.
        for i in 150..270 {
            let js: &[usize] = if i < 260 { &[0, 1] } else { &[0] };
            for &j in js {
                qp.w_lo[i][j] = 0.0;
                qp.w_hi[i][j] = 0.0;
            }
        }
        let s = StructuredSolver::tight().solve(&qp, None).unwrap();
        let c = ClarabelSolver::default().solve(&qp, None).unwrap();
        assert_agree(&qp, &s, &c);
        assert!(s.w[150..260].iter().all(|w| w.amax() == 0.0));
        assert!(s.iterations < 30, "{} iterations", s.iterations);
        let r = kkt_residual(&qp, &s).unwrap();
        assert!(r.stationarity < 1e-8 && r.complementarity < 1e-8 * s.objective.max(1.0), "{r:?}");
        // Warm start from Clarabel's solution (as after a fallback).
        let warm = StructuredSolver::tight().solve(&qp, Some(&c)).unwrap();
        assert_agree(&qp, &warm, &c);
    }
}

#[test]
fn zero_width_state_box_is_a_numerical_error() {
    let mut qp = random_instance(23, 20, 0.0);
    qp.z_lo[5][1] = 0.1;
    qp.z_hi[5][1] = 0.1;
    let e = StructuredSolver::tight().solve(&qp, None).unwrap_err();
    assert!(matches!(e, QpError::Numerical(ref m) if m.contains("zero-width state box")), "{e}");
}

/// How often the structured solver gives up (and compensation falls back to
/// Clarabel) on random instances. Measured over seeds 0..10 000 (k 5..59):
/// never at tightness 0 or 0.9; 61 of 10 000 at 0.97, all "input Hessian
/// not positive definite" on nearly infeasible boxes.
#[test]
fn structured_failures_are_rare_and_only_on_nearly_infeasible_boxes() {
    let mut failures = [0usize; 3];
    for seed in 0..1000u64 {
        let k = 5 + (seed as usize * 7919) % 55;
        for (i, tight) in [0.0, 0.9, 0.97].into_iter().enumerate() {
            let qp = random_instance(seed, k, tight);
            match StructuredSolver::tight().solve(&qp, None) {
                Ok(_) | Err(QpError::Infeasible(_)) => {}
                Err(_) => failures[i] += 1,
            }
        }
    }
    assert_eq!(failures[..2], [0, 0], "structured solver failed on a loose or moderately tight box");
    assert!(failures[2] <= 20, "{} of 1000 tight instances failed", failures[2]);
}
