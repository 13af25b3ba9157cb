//! The reference solver: the compensation QP handed to the general sparse
//! conic solver [Clarabel](https://clarabel.org).
//!
//! The problem is assembled in CSC form over `x = [w_0..w_{K−1}, z_1..z_K]`
//! (`w_i` at `2i..2i+2`, `z_k` at `2K + 3(k−1)..`):
//!
//! ```text
//! min ½ xᵀ P x + pᵀ x        (P = ∇²f, p = ∇f(0); f = ½xᵀPx + pᵀx + Σ δᵀRδ)
//! s.t. z_k − A_k z_{k−1} − B_k w_{k−1} = c_k          (ZeroConeT, 3K rows)
//!      x ≤ x_hi,  −x ≤ −x_lo                          (NonnegativeConeT, 10K rows)
//! ```
//!
//! Clarabel's optimality conditions are `Px + p + Aᵀy = 0`, `y` in the dual
//! cone; its `y` of the dynamics rows is therefore exactly the λ of the
//! module's dual convention (see [`crate::compensate::qp`]).
//!
//! ## References
//! P. J. Goulart, Y. Chen, "Clarabel: An interior-point solver for conic
//! programs with quadratic objectives", arXiv:2405.12762, 2024.

use ::clarabel::algebra::CscMatrix;
use ::clarabel::solver::{
    DefaultSettings, DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};
use nalgebra::{Vector2, Vector3};

use super::{a_matrix, QpError, QpSolution, QpSolver, StageQp};

/// Settings of the Clarabel solver ([`SolverKind::Clarabel`](super::SolverKind::Clarabel),
/// and the structured solver's fallback).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct ClarabelOptions {
    /// Absolute and relative duality-gap tolerance (Clarabel `tol_gap_abs`,
    /// `tol_gap_rel`). Default 1e-10: this solver is the reference, and
    /// Clarabel's criteria are relative to the data scale (R = 1000).
    pub tol_gap: f64,
    /// Primal/dual feasibility tolerance (Clarabel `tol_feas`). Default 1e-10.
    pub tol_feas: f64,
    /// Iteration limit (Clarabel `max_iter`). Default 200.
    pub max_iterations: u32,
    /// Accept Clarabel's `AlmostSolved` (reduced accuracy, about 1e-5)
    /// instead of reporting an error. Default true.
    pub accept_almost_solved: bool,
}

impl Default for ClarabelOptions {
    fn default() -> Self {
        Self { tol_gap: 1e-10, tol_feas: 1e-10, max_iterations: 200, accept_almost_solved: true }
    }
}

impl ClarabelOptions {
    /// Checks every field; the error names the field.
    pub(crate) fn validate(&self) -> Result<(), QpError> {
        for (v, name) in [(self.tol_gap, "tol_gap"), (self.tol_feas, "tol_feas")] {
            if !(v.is_finite() && v > 0.0) {
                return Err(QpError::Malformed(format!(
                    "ClarabelOptions::{name} must be positive and finite, got {v}"
                )));
            }
        }
        if self.max_iterations == 0 {
            return Err(QpError::Malformed("ClarabelOptions::max_iterations must be at least 1".into()));
        }
        Ok(())
    }
}

/// The compensation QP solved by Clarabel (sparse LDLᵀ of the full KKT
/// system each iteration). Slower than [`super::riccati::StructuredSolver`]
/// but independent of it: the cross-check and the fallback.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct ClarabelSolver {
    /// Tolerances and limits.
    pub settings: ClarabelOptions,
}

/// The problem in Clarabel's form.
struct Assembled {
    p: CscMatrix<f64>,
    q: Vec<f64>,
    a: CscMatrix<f64>,
    b: Vec<f64>,
    cones: Vec<SupportedConeT<f64>>,
}

/// Builds `P, q, A, b` and the cones for `qp`.
fn assemble(qp: &StageQp) -> Assembled {
    let k = qp.stages();
    let n = 5 * k;
    let wi = |i: usize, j: usize| 2 * i + j;
    let zi = |i: usize, j: usize| 2 * k + 3 * i + j;

    // P = ∇²f, upper triangle only.
    let (mut pr, mut pc, mut pv) = (Vec::with_capacity(3 * n), Vec::with_capacity(3 * n), Vec::with_capacity(3 * n));
    let mut q = vec![0.0; n];
    for i in 0..k {
        for j in 0..2 {
            let terms = usize::from(i > 0) + usize::from(i + 1 < k);
            pr.push(wi(i, j));
            pc.push(wi(i, j));
            pv.push(2.0 * qp.r[j] * terms as f64);
            if i > 0 {
                pr.push(wi(i - 1, j));
                pc.push(wi(i, j));
                pv.push(-2.0 * qp.r[j]);
                let g = 2.0 * qp.r[j] * qp.delta[i - 1][j];
                q[wi(i, j)] += g;
                q[wi(i - 1, j)] -= g;
            }
        }
        for j in 0..3 {
            pr.push(zi(i, j));
            pc.push(zi(i, j));
            pv.push(2.0 * qp.q[j]);
        }
    }
    let p = CscMatrix::new_from_triplets(n, n, pr, pc, pv);

    // Rows 0..3K: dynamics; 3K..8K: x ≤ hi; 8K..13K: −x ≤ −lo.
    let m = 3 * k + 2 * n;
    let cap = 3 * k * 6 + 2 * n;
    let (mut ar, mut ac, mut av) = (Vec::with_capacity(cap), Vec::with_capacity(cap), Vec::with_capacity(cap));
    let mut b = vec![0.0; m];
    for i in 0..k {
        for r in 0..3 {
            let row = 3 * i + r;
            ar.push(row);
            ac.push(zi(i, r));
            av.push(1.0);
            for j in 0..2 {
                ar.push(row);
                ac.push(wi(i, j));
                av.push(-qp.b[i][(r, j)]);
            }
            if i > 0 {
                let a = a_matrix(&qp.a[i]);
                for j in 0..3 {
                    ar.push(row);
                    ac.push(zi(i - 1, j));
                    av.push(-a[(r, j)]);
                }
            }
            b[row] = qp.c[i][r];
        }
    }
    let mut bound = |col: usize, lo: f64, hi: f64| {
        ar.push(3 * k + col);
        ac.push(col);
        av.push(1.0);
        b[3 * k + col] = hi;
        ar.push(3 * k + n + col);
        ac.push(col);
        av.push(-1.0);
        b[3 * k + n + col] = -lo;
    };
    for i in 0..k {
        for j in 0..2 {
            bound(wi(i, j), qp.w_lo[i][j], qp.w_hi[i][j]);
        }
        for j in 0..3 {
            bound(zi(i, j), qp.z_lo[i][j], qp.z_hi[i][j]);
        }
    }
    let a = CscMatrix::new_from_triplets(m, n, ar, ac, av);
    Assembled { p, q, a, b, cones: vec![SupportedConeT::ZeroConeT(3 * k), SupportedConeT::NonnegativeConeT(2 * n)] }
}

impl ClarabelSolver {
    fn clarabel_settings(&self) -> Result<DefaultSettings<f64>, QpError> {
        let s = &self.settings;
        DefaultSettingsBuilder::default()
            .verbose(false)
            .tol_gap_abs(s.tol_gap)
            .tol_gap_rel(s.tol_gap)
            .tol_feas(s.tol_feas)
            .max_iter(s.max_iterations)
            .presolve_enable(false)
            .build()
            .map_err(|e| QpError::Malformed(format!("clarabel settings: {e}")))
    }
}

impl QpSolver for ClarabelSolver {
    fn name(&self) -> &'static str {
        "clarabel"
    }

    /// Solves with Clarabel. `warm_start` is ignored (Clarabel 0.11 has no
    /// warm start).
    fn solve(&self, qp: &StageQp, _warm_start: Option<&QpSolution>) -> Result<QpSolution, QpError> {
        qp.check()?;
        let k = qp.stages();
        let prob = assemble(qp);
        let mut solver = DefaultSolver::new(&prob.p, &prob.q, &prob.a, &prob.b, &prob.cones, self.clarabel_settings()?)
            .map_err(|e| QpError::Malformed(format!("clarabel setup: {e}")))?;
        solver.solve();
        let sol = &solver.solution;
        let iterations = sol.iterations as usize;
        match sol.status {
            SolverStatus::Solved => {}
            SolverStatus::AlmostSolved if self.settings.accept_almost_solved => {}
            SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
                return Err(QpError::Infeasible(format!(
                    "clarabel found a primal infeasibility certificate after {iterations} iterations"
                )))
            }
            SolverStatus::DualInfeasible | SolverStatus::AlmostDualInfeasible => {
                return Err(QpError::Numerical(format!(
                    "clarabel reports dual infeasibility (unbounded objective) after {iterations} iterations; \
                     impossible for a positive-definite Q, check the problem data"
                )))
            }
            SolverStatus::MaxIterations | SolverStatus::MaxTime => {
                return Err(QpError::MaxIterations { iterations, residual: sol.r_prim.max(sol.r_dual) })
            }
            other => {
                return Err(QpError::Numerical(format!(
                    "clarabel stopped with status {other:?} after {iterations} iterations"
                )))
            }
        }
        if sol.x.iter().any(|v| !v.is_finite()) {
            return Err(QpError::Numerical("clarabel returned non-finite values".into()));
        }
        let x = &sol.x;
        let w: Vec<Vector2<f64>> = (0..k).map(|i| Vector2::new(x[2 * i], x[2 * i + 1])).collect();
        let z: Vec<Vector3<f64>> =
            (0..k).map(|i| Vector3::new(x[2 * k + 3 * i], x[2 * k + 3 * i + 1], x[2 * k + 3 * i + 2])).collect();
        let lam = (0..k).map(|i| Vector3::new(sol.z[3 * i], sol.z[3 * i + 1], sol.z[3 * i + 2])).collect();
        Ok(QpSolution { objective: qp.objective(&w, &z), iterations, dynamics_duals: Some(lam), w, z })
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use crate::compensate::qp::{kkt_residual, random_instance, solve_equality_constrained};

    /// Clarabel stops at 1e-9 *relative* to gradients of O(100) (R = 1000):
    /// an absolute natural residual below 1e-6 is what that guarantees.
    const TOL: f64 = 1e-6;

    #[test]
    fn clarabel_matches_direct_kkt_solve_without_active_bounds() {
        let qp = random_instance(1, 30, 0.0);
        let direct = solve_equality_constrained(&qp).unwrap();
        assert_eq!(direct.active_bounds(&qp), 0, "instance must have no active bound");
        let sol = ClarabelSolver::default().solve(&qp, None).unwrap();
        assert_eq!(sol.active_bounds(&qp), 0);
        for (a, b) in sol.w.iter().zip(&direct.w) {
            assert!((a - b).amax() < 1e-6, "w {a} vs {b}");
        }
        assert!(
            (sol.objective - direct.objective).abs() <= 1e-7 * direct.objective,
            "{} vs {}",
            sol.objective,
            direct.objective
        );
        let lam = sol.dynamics_duals.as_ref().unwrap();
        for (a, b) in lam.iter().zip(direct.dynamics_duals.as_ref().unwrap()) {
            assert!((a - b).amax() < 1e-5 * (1.0 + b.amax()), "λ {a} vs {b}");
        }
    }

    #[test]
    fn clarabel_solution_satisfies_kkt_with_active_bounds() {
        let qp = random_instance(2, 40, 0.95);
        let sol = ClarabelSolver::default().solve(&qp, None).unwrap();
        assert!(sol.active_bounds(&qp) > 0, "tight instance must activate bounds");
        let r = kkt_residual(&qp, &sol).unwrap();
        assert!(r.max() < TOL, "{r:?}");
        assert!((sol.objective - qp.objective(&sol.w, &sol.z)).abs() < 1e-12 * sol.objective.max(1.0));
    }

    #[test]
    fn clarabel_reports_unfixable_state_offset_as_infeasible() {
        let mut qp = random_instance(3, 10, 0.0);
        qp.c[4][0] = 20.0; // 20 m jump; the inputs move z by ~1 mm per step
        let err = ClarabelSolver::default().solve(&qp, None).unwrap_err();
        assert!(matches!(err, QpError::Infeasible(_)), "{err}");
    }

    #[test]
    fn clarabel_reports_empty_input_box_as_infeasible() {
        let mut qp = random_instance(4, 10, 0.0);
        qp.w_lo[3][1] = qp.w_hi[3][1] + 0.01;
        assert!(matches!(ClarabelSolver::default().solve(&qp, None), Err(QpError::Infeasible(_))));
    }
}
