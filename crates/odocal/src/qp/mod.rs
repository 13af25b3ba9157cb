//! The stage-wise, box-constrained QP of input compensation (SPEC §5), in
//! deviation variables, and the solvers for it.
//!
//! Variables are deviations from the measurements: `w_k = n_k − ñ_k ∈ ℝ²`
//! (k = 0..K−1, wheel rotations) and `z_k = x_k − ỹ_k ∈ ℝ³` (k = 1..K,
//! poses), with `z_0 = 0` (the segment starts at the reference pose). In
//! absolute variables the large constant in the cost would make relative
//! solver tolerances meaningless; in deviations the optimum is O(noise).
//!
//! ```text
//! min  Σ_{k=1..K} z_kᵀ Q z_k + Σ_{k=1..K−1} (w_k − w_{k−1} + δ_k)ᵀ R (w_k − w_{k−1} + δ_k)
//! s.t. z_k = A_k z_{k−1} + B_k w_{k−1} + c_k,   k = 1..K,  z_0 = 0
//!      z_lo_k ≤ z_k ≤ z_hi_k,   w_lo_k ≤ w_k ≤ w_hi_k
//! ```
//!
//! with `Q = diag(q)`, `R = diag(r)` and `δ_k = ñ_k − ñ_{k−1}`.

use nalgebra::{Matrix3, Matrix3x2, Vector2, Vector3};
use serde::{Deserialize, Serialize};

/// One instance of the compensation QP. Vectors indexed by stage hold, at
/// index `i`, the quantity of step `k = i + 1` (dynamics, state bounds) or
/// of input `i` (input bounds), as documented per field.
#[derive(Debug, Clone, PartialEq)]
pub struct StageQp {
    /// `A_k` for k = 1..K (index k−1), 3×3.
    pub a: Vec<Matrix3<f64>>,
    /// `B_k` for k = 1..K (index k−1), 3×2.
    pub b: Vec<Matrix3x2<f64>>,
    /// Affine term `c_k` for k = 1..K (index k−1).
    pub c: Vec<Vector3<f64>>,
    /// Diagonal of the state weight Q.
    pub q: Vector3<f64>,
    /// Diagonal of the input-rate weight R.
    pub r: Vector2<f64>,
    /// `δ_k = ñ_k − ñ_{k−1}` for k = 1..K−1 (index k−1), K−1 values.
    pub delta: Vec<Vector2<f64>>,
    /// Lower state bounds for k = 1..K (index k−1).
    pub z_lo: Vec<Vector3<f64>>,
    /// Upper state bounds for k = 1..K (index k−1).
    pub z_hi: Vec<Vector3<f64>>,
    /// Lower input bounds for k = 0..K−1.
    pub w_lo: Vec<Vector2<f64>>,
    /// Upper input bounds for k = 0..K−1.
    pub w_hi: Vec<Vector2<f64>>,
}

impl StageQp {
    /// Number of stages K.
    pub fn stages(&self) -> usize {
        self.a.len()
    }

    /// Checks that every vector has the right length and bounds are ordered.
    pub fn check(&self) -> Result<(), QpError> {
        let k = self.stages();
        let ok = k >= 1
            && self.b.len() == k
            && self.c.len() == k
            && self.delta.len() == k - 1
            && self.z_lo.len() == k
            && self.z_hi.len() == k
            && self.w_lo.len() == k
            && self.w_hi.len() == k;
        if !ok {
            return Err(QpError::Malformed("inconsistent stage counts".into()));
        }
        for i in 0..k {
            if (0..3).any(|j| self.z_lo[i][j] > self.z_hi[i][j]) || (0..2).any(|j| self.w_lo[i][j] > self.w_hi[i][j]) {
                return Err(QpError::Infeasible(format!("empty box at stage {i}")));
            }
        }
        Ok(())
    }

    /// States `z_1..z_K` produced by inputs `w_0..w_{K−1}` through the dynamics.
    pub fn rollout(&self, w: &[Vector2<f64>]) -> Vec<Vector3<f64>> {
        let mut z = Vector3::zeros();
        (0..self.stages())
            .map(|i| {
                z = self.a[i] * z + self.b[i] * w[i] + self.c[i];
                z
            })
            .collect()
    }

    /// The objective at (w, z).
    pub fn objective(&self, w: &[Vector2<f64>], z: &[Vector3<f64>]) -> f64 {
        let mut f = 0.0;
        for zk in z {
            f += zk.component_mul(zk).dot(&self.q);
        }
        for k in 1..w.len() {
            let d = w[k] - w[k - 1] + self.delta[k - 1];
            f += d.component_mul(&d).dot(&self.r);
        }
        f
    }

    /// Largest violation of any bound by (w, z) (0 when all hold).
    pub fn max_bound_violation(&self, w: &[Vector2<f64>], z: &[Vector3<f64>]) -> f64 {
        let mut v: f64 = 0.0;
        for i in 0..self.stages() {
            for j in 0..3 {
                v = v.max(self.z_lo[i][j] - z[i][j]).max(z[i][j] - self.z_hi[i][j]);
            }
            for j in 0..2 {
                v = v.max(self.w_lo[i][j] - w[i][j]).max(w[i][j] - self.w_hi[i][j]);
            }
        }
        v
    }
}

/// A solution of a [`StageQp`].
#[derive(Debug, Clone, PartialEq)]
pub struct QpSolution {
    /// Input deviations `w_0..w_{K−1}`.
    pub w: Vec<Vector2<f64>>,
    /// State deviations `z_1..z_K`.
    pub z: Vec<Vector3<f64>>,
    /// Objective value.
    pub objective: f64,
    /// Solver iterations.
    pub iterations: usize,
    /// Number of bounds active at the solution (within a small tolerance).
    pub active_bounds: usize,
    /// Dual variables of the dynamics constraints (λ_k, k = 1..K), when the
    /// solver provides them (used for KKT checks and warm starts).
    pub dynamics_duals: Option<Vec<Vector3<f64>>>,
}

/// Why a QP was not solved.
#[derive(Debug, Clone, PartialEq, thiserror::Error, Serialize, Deserialize)]
pub enum QpError {
    /// The problem has no feasible point.
    #[error("infeasible: {0}")]
    Infeasible(String),
    /// The iteration limit was reached before convergence.
    #[error("iteration limit reached after {iterations} iterations (residual {residual:.2e})")]
    MaxIterations {
        /// Iterations taken.
        iterations: usize,
        /// Residual at the last iterate.
        residual: f64,
    },
    /// A numerical failure (factorisation, non-finite values).
    #[error("numerical failure: {0}")]
    Numerical(String),
    /// The problem data are inconsistent.
    #[error("malformed problem: {0}")]
    Malformed(String),
}

/// A solver for [`StageQp`].
pub trait QpSolver: Send + Sync {
    /// Short name (`"clarabel"`, `"structured"`).
    fn name(&self) -> &'static str;
    /// Solves the QP; `warm_start` may be a previous solution of a nearby problem.
    fn solve(&self, qp: &StageQp, warm_start: Option<&QpSolution>) -> Result<QpSolution, QpError>;
}
