//! The stage-wise, box-constrained QP of input compensation (docs/method.md §5), in
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
//!
//! Two solvers implement [`QpSolver`]:
//! - [`riccati::StructuredSolver`], a hand-written primal-dual interior-point
//!   method whose Newton steps are Riccati recursions, O(K) per iteration;
//! - [`clarabel::ClarabelSolver`], the general sparse conic solver Clarabel,
//!   the reference the structured solver is cross-checked against.
//!
//! Pick one at run time with [`SolverKind`].
//!
//! ## Dual convention
//!
//! Both solvers report `dynamics_duals` λ_k for the Lagrangian
//! `L = f(w, z) + Σ_k λ_kᵀ (z_k − A_k z_{k−1} − B_k w_{k−1} − c_k) − μ_loᵀ(x − x_lo) − μ_hiᵀ(x_hi − x)`
//! where `f` is `StageQp::objective` (no factor ½), so that at the optimum
//! `∇f + Gᵀλ = μ_lo − μ_hi` with `μ_lo, μ_hi ≥ 0` the bound multipliers
//! (see `kkt_residual`, which recovers them from λ).

// Stage loops index several parallel arrays and small fixed vectors at once;
// index loops read like the maths there.
#![allow(clippy::needless_range_loop)]

pub(crate) mod clarabel;
pub(crate) mod riccati;

use std::fmt;
use std::str::FromStr;

#[cfg(test)]
use nalgebra::{DMatrix, DVector};
use nalgebra::{Matrix3, Matrix3x2, Vector2, Vector3};
use serde::{Deserialize, Serialize};

pub(crate) use crate::error::QpError;
#[cfg(test)]
use crate::model::{step_jacobians, Input, Theta};

/// One instance of the compensation QP. Vectors indexed by stage hold, at
/// index `i`, the quantity of step `k = i + 1` (dynamics, state bounds) or
/// of input `i` (input bounds), as documented per field.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct StageQp {
    /// The heading column of `A_k` for k = 1..K (index k−1): the model's
    /// step Jacobian in the pose is `A_k = [[1, 0, a_k[0]], [0, 1, a_k[1]],
    /// [0, 0, 1]]` (`∂x/∂ψ`, `∂y/∂ψ`; position and heading enter a step
    /// additively), stored as these two entries. [`a_matrix`] rebuilds it.
    pub a: Vec<Vector2<f64>>,
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
    pub(crate) fn stages(&self) -> usize {
        self.a.len()
    }

    /// Checks that every vector has the right length and bounds are ordered.
    pub(crate) fn check(&self) -> Result<(), QpError> {
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

    /// The objective at (w, z).
    pub(crate) fn objective(&self, w: &[Vector2<f64>], z: &[Vector3<f64>]) -> f64 {
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
    #[cfg(test)]
    pub(crate) fn max_bound_violation(&self, w: &[Vector2<f64>], z: &[Vector3<f64>]) -> f64 {
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

/// The 3×3 step Jacobian `A_k` from its heading column `a` ([`StageQp::a`]).
pub(crate) fn a_matrix(a: &Vector2<f64>) -> Matrix3<f64> {
    Matrix3::new(1.0, 0.0, a[0], 0.0, 1.0, a[1], 0.0, 0.0, 1.0)
}

/// The heading column of a step Jacobian in the pose, the form
/// [`StageQp::a`] stores; `None` unless `f_x` is the identity but for
/// `∂x/∂ψ` and `∂y/∂ψ`.
pub(crate) fn heading_column(f_x: &Matrix3<f64>) -> Option<Vector2<f64>> {
    let a = Vector2::new(f_x[(0, 2)], f_x[(1, 2)]);
    (a_matrix(&a) == *f_x).then_some(a)
}

/// A solution of a [`StageQp`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct QpSolution {
    /// Input deviations `w_0..w_{K−1}`.
    pub w: Vec<Vector2<f64>>,
    /// State deviations `z_1..z_K`.
    pub z: Vec<Vector3<f64>>,
    /// Objective value.
    pub objective: f64,
    /// Solver iterations.
    pub iterations: usize,
    /// Dual variables of the dynamics constraints (λ_k, k = 1..K), when the
    /// solver provides them (used for KKT checks and warm starts).
    pub dynamics_duals: Option<Vec<Vector3<f64>>>,
}

/// A solver for [`StageQp`].
pub(crate) trait QpSolver: Send + Sync {
    /// Short name (`"clarabel"`, `"structured"`).
    fn name(&self) -> &'static str;
    /// Solves the QP; `warm_start` may be a previous solution of a nearby problem.
    fn solve(&self, qp: &StageQp, warm_start: Option<&QpSolution>) -> Result<QpSolution, QpError>;
}

/// Absolute distance (in the variable's unit: m, rad or rev/s) within which a
/// bound counts as active in [`QpSolution::active_bounds`]. Interior-point
/// iterates stop about `tolerance × scale` from an active bound, far inside
/// this; inactive bounds of realistic instances are ≥ 1e-3 away.
#[cfg(test)]
pub(crate) const ACTIVE_BOUND_TOL: f64 = 1e-7;

#[cfg(test)]
impl QpSolution {
    /// Number of bounds of `qp` active at the solution (within
    /// [`ACTIVE_BOUND_TOL`]).
    pub(crate) fn active_bounds(&self, qp: &StageQp) -> usize {
        qp.count_active_bounds(&self.w, &self.z, ACTIVE_BOUND_TOL)
    }
}

impl StageQp {
    /// Gradient of [`StageQp::objective`] at (w, z): `(∂f/∂w_k, ∂f/∂z_k)`.
    #[cfg(test)]
    pub(crate) fn gradient(&self, w: &[Vector2<f64>], z: &[Vector3<f64>]) -> (Vec<Vector2<f64>>, Vec<Vector3<f64>>) {
        let gz = z.iter().map(|zk| 2.0 * self.q.component_mul(zk)).collect();
        let mut gw = vec![Vector2::zeros(); w.len()];
        for k in 1..w.len() {
            let d = 2.0 * self.r.component_mul(&(w[k] - w[k - 1] + self.delta[k - 1]));
            gw[k] += d;
            gw[k - 1] -= d;
        }
        (gw, gz)
    }

    /// Largest absolute residual of the dynamics
    /// `z_k − A_k z_{k−1} − B_k w_{k−1} − c_k` (0 for a rollout).
    #[cfg(test)]
    pub(crate) fn dynamics_residual(&self, w: &[Vector2<f64>], z: &[Vector3<f64>]) -> f64 {
        let mut prev = Vector3::zeros();
        let mut r: f64 = 0.0;
        for i in 0..self.stages() {
            let e = z[i] - a_matrix(&self.a[i]) * prev - self.b[i] * w[i] - self.c[i];
            r = r.max(e.amax());
            prev = z[i];
        }
        r
    }

    /// Number of bounds within `tol` of (w, z) (a variable pinned by an
    /// equal lower and upper bound counts once).
    #[cfg(test)]
    pub(crate) fn count_active_bounds(&self, w: &[Vector2<f64>], z: &[Vector3<f64>], tol: f64) -> usize {
        let mut n = 0;
        for i in 0..self.stages() {
            for j in 0..3 {
                if z[i][j] - self.z_lo[i][j] <= tol || self.z_hi[i][j] - z[i][j] <= tol {
                    n += 1;
                }
            }
            for j in 0..2 {
                if w[i][j] - self.w_lo[i][j] <= tol || self.w_hi[i][j] - w[i][j] <= tol {
                    n += 1;
                }
            }
        }
        n
    }
}

/// How far a candidate solution is from satisfying the KKT conditions.
///
/// Bound multipliers are recovered from the dynamics duals: for every
/// variable `ν = ∂f/∂x + (Gᵀλ)` must equal `μ_lo − μ_hi`; the split
/// `μ_lo = max(ν, 0)`, `μ_hi = max(−ν, 0)` is dual feasible by construction,
/// so stationarity reduces to complementarity: ν may be non-zero only at a
/// bound of the right side.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg(test)]
pub(crate) struct KktResidual {
    /// Largest dynamics residual (m, rad).
    pub dynamics: f64,
    /// Largest bound violation (m, rad, rev/s).
    pub bounds: f64,
    /// Scaled natural (projected-gradient) residual
    /// `max |x − Π_box(x − ν/h)|`, with `h` the diagonal of `∇²f`: roughly
    /// the distance to the optimum in the variables' units (m, rad, rev/s);
    /// 0 exactly when stationarity and complementarity hold.
    pub stationarity: f64,
    /// Largest `μ·gap` over all bounds, in objective units.
    pub complementarity: f64,
}

#[cfg(test)]
impl KktResidual {
    /// The largest of the four residuals.
    pub(crate) fn max(&self) -> f64 {
        self.dynamics.max(self.bounds).max(self.stationarity).max(self.complementarity)
    }
}

/// KKT residuals of `sol` for `qp` (see [`KktResidual`]). Needs
/// `sol.dynamics_duals`; returns [`QpError::Malformed`] without them.
#[cfg(test)]
pub(crate) fn kkt_residual(qp: &StageQp, sol: &QpSolution) -> Result<KktResidual, QpError> {
    let lam =
        sol.dynamics_duals.as_ref().ok_or_else(|| QpError::Malformed("solution carries no dynamics duals".into()))?;
    let k = qp.stages();
    if sol.w.len() != k || sol.z.len() != k || lam.len() != k {
        return Err(QpError::Malformed("solution length does not match the problem".into()));
    }
    let (gw, gz) = qp.gradient(&sol.w, &sol.z);
    let mut stationarity: f64 = 0.0;
    let mut complementarity: f64 = 0.0;
    let mut check = |x: f64, lo: f64, hi: f64, nu: f64, h: f64| {
        stationarity = stationarity.max((x - (x - nu / h).clamp(lo, hi)).abs());
        complementarity = complementarity.max(nu.max(0.0) * (x - lo).abs()).max((-nu).max(0.0) * (hi - x).abs());
    };
    for i in 0..k {
        // ν_z_k = ∂f/∂z_k + λ_k − A_{k+1}ᵀ λ_{k+1}
        let mut nz = gz[i] + lam[i];
        if i + 1 < k {
            nz -= a_matrix(&qp.a[i + 1]).transpose() * lam[i + 1];
        }
        // ν_w_k = ∂f/∂w_k − B_{k+1}ᵀ λ_{k+1}
        let nw = gw[i] - qp.b[i].transpose() * lam[i];
        // Diagonal of ∇²f: 2q for z, 2r per rate term touching w_i (1 for
        // K = 1, where w has no curvature of its own).
        let terms = usize::from(i > 0) + usize::from(i + 1 < k);
        for j in 0..3 {
            check(sol.z[i][j], qp.z_lo[i][j], qp.z_hi[i][j], nz[j], 2.0 * qp.q[j]);
        }
        for j in 0..2 {
            let h = if terms == 0 { 1.0 } else { 2.0 * qp.r[j] * terms as f64 };
            check(sol.w[i][j], qp.w_lo[i][j], qp.w_hi[i][j], nw[j], h);
        }
    }
    Ok(KktResidual {
        dynamics: qp.dynamics_residual(&sol.w, &sol.z),
        bounds: qp.max_bound_violation(&sol.w, &sol.z),
        stationarity,
        complementarity,
    })
}

/// Solves the QP *ignoring every bound* by one dense LU factorisation of
/// its equality-constrained KKT system
/// `[[∇²f, Gᵀ], [G, 0]] [x; λ] = [−∇f(0); c]`, O((8K)³).
///
/// Meant for tests on small K: when no bound is active at the optimum, this
/// is the solution of the bounded problem too.
#[cfg(test)]
pub(crate) fn solve_equality_constrained(qp: &StageQp) -> Result<QpSolution, QpError> {
    qp.check()?;
    let k = qp.stages();
    let n = 5 * k;
    let m = 3 * k;
    let wi = |i: usize, j: usize| 2 * i + j;
    let zi = |i: usize, j: usize| 2 * k + 3 * i + j;
    let mut kkt = DMatrix::<f64>::zeros(n + m, n + m);
    let mut rhs = DVector::<f64>::zeros(n + m);
    for i in 0..k {
        for j in 0..3 {
            kkt[(zi(i, j), zi(i, j))] += 2.0 * qp.q[j];
        }
    }
    for i in 1..k {
        for j in 0..2 {
            let (a, b) = (wi(i, j), wi(i - 1, j));
            let r2 = 2.0 * qp.r[j];
            kkt[(a, a)] += r2;
            kkt[(b, b)] += r2;
            kkt[(a, b)] -= r2;
            kkt[(b, a)] -= r2;
            let g = r2 * qp.delta[i - 1][j];
            rhs[a] -= g;
            rhs[b] += g;
        }
    }
    for i in 0..k {
        for r in 0..3 {
            let row = n + 3 * i + r;
            let mut put = |col: usize, v: f64| {
                kkt[(row, col)] += v;
                kkt[(col, row)] += v;
            };
            put(zi(i, r), 1.0);
            for j in 0..2 {
                put(wi(i, j), -qp.b[i][(r, j)]);
            }
            if i > 0 {
                for j in 0..3 {
                    put(zi(i - 1, j), -a_matrix(&qp.a[i])[(r, j)]);
                }
            }
            rhs[row] = qp.c[i][r];
        }
    }
    let x = kkt.lu().solve(&rhs).ok_or_else(|| QpError::Numerical("singular KKT matrix".into()))?;
    let w: Vec<Vector2<f64>> = (0..k).map(|i| Vector2::new(x[wi(i, 0)], x[wi(i, 1)])).collect();
    let z: Vec<Vector3<f64>> = (0..k).map(|i| Vector3::new(x[zi(i, 0)], x[zi(i, 1)], x[zi(i, 2)])).collect();
    let lam = (0..k).map(|i| Vector3::new(x[n + 3 * i], x[n + 3 * i + 1], x[n + 3 * i + 2])).collect();
    Ok(QpSolution { objective: qp.objective(&w, &z), iterations: 1, dynamics_duals: Some(lam), w, z })
}

/// Which solver the compensation QP uses; parses from `"structured"` or
/// `"clarabel"`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SolverKind {
    /// The structured solver: a primal-dual interior-point method whose
    /// Newton steps are Riccati recursions, O(K) per iteration (the
    /// default), with Clarabel as its fallback.
    #[default]
    Structured,
    /// Clarabel, the general sparse conic solver (no fallback).
    Clarabel,
}

impl SolverKind {
    /// A solver of this kind with default settings.
    #[cfg(test)]
    pub(crate) fn solver(&self) -> Box<dyn QpSolver> {
        match self {
            SolverKind::Structured => Box::new(riccati::StructuredSolver::default()),
            SolverKind::Clarabel => Box::new(clarabel::ClarabelSolver::default()),
        }
    }

    /// The name used on the command line and in reports.
    pub(crate) fn as_str(&self) -> &'static str {
        match self {
            SolverKind::Structured => "structured",
            SolverKind::Clarabel => "clarabel",
        }
    }
}

impl fmt::Display for SolverKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for SolverKind {
    type Err = crate::error::Error;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "structured" => Ok(SolverKind::Structured),
            "clarabel" => Ok(SolverKind::Clarabel),
            _ => Err(crate::error::Error::Parse {
                what: "QP solver",
                input: s.to_string(),
                expected: "structured or clarabel",
            }),
        }
    }
}

/// A realistic, reproducible compensation QP of `stages` steps for tests
/// and benchmarks, built the way the compensation stage builds real ones.
///
/// - A drive at 40 Hz (`t_s = 0.025 s`) with speed 5–15 m/s (about 10 m/s)
///   and yaw rate up to ±0.3 rad/s; wheel speeds ñ ≈ 5 rev/s with 1 %
///   white measurement noise; θ = the paper's nominal `[1.98, 0, 1.55, 0]`.
/// - `A_k, B_k` are the model's analytic Jacobians along the dead-reckoned
///   trajectory (`A ≈ [[1,0,−v t_s sin ψ],[0,1,v t_s cos ψ],[0,0,1]]`,
///   `|B| ≈ t_s·c/2 ≈ 0.025 m per rev/s`).
/// - `c_k = A_k e_{k−1} − e_k + m_k`: the reference-pose noise `e_k`
///   (σ = 3 cm, 5 mrad) seen through the dynamics, plus a model mismatch
///   `m_k` along the heading of σ = 1 % of `v t_s`.
/// - `δ_k = ñ_k − ñ_{k−1}` from the noisy wheel speeds.
/// - Q = diag(1, 1, 10), R = diag(1000, 1000) (docs/method.md §5); bounds
///   `|z| ≤ [5, 5, 0.5]·s` and `|w| ≤ 0.05·|ñ_k|·s` with `s = 1 − tightness`.
///
/// `tightness = 0` gives the boxes of docs/method.md §5 (rarely a bound active);
/// `tightness ≈ 0.9` activates many input bounds, `≈ 0.97` state bounds
/// too; from about 0.98 on, some instances have no feasible point.
/// Values of `tightness` are clamped to [0, 0.999].
#[cfg(test)]
pub(crate) fn random_instance(seed: u64, stages: usize, tightness: f64) -> StageQp {
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};
    const T_S: f64 = 0.025;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut g = || -> f64 { StandardNormal.sample(&mut rng) };
    let theta = Theta { c_e: 1.98, c_d: 0.0, t_r: 1.55, d: 0.0 };
    let s = 1.0 - tightness.clamp(0.0, 0.999);
    let (speed_phase, yaw_phase, yaw_amp) = (g() * 3.0, g() * 3.0, 0.3 * g().abs().min(1.0));
    let mut n_meas = Vec::with_capacity(stages);
    let mut inputs = Vec::with_capacity(stages);
    for i in 0..stages {
        let t = i as f64 * T_S;
        let v = 10.0 + 4.0 * (0.15 * t + speed_phase).sin();
        let omega = yaw_amp * (0.4 * t + yaw_phase).sin();
        let n_rl = (v - omega * theta.t_r / 2.0) / theta.c_e;
        let n_rr = (v + omega * theta.t_r / 2.0) / theta.c_e;
        let meas = Vector2::new(n_rl * (1.0 + 0.01 * g()), n_rr * (1.0 + 0.01 * g()));
        n_meas.push(meas);
        inputs.push(Input { n_rl: meas[0], n_rr: meas[1], beta: 0.0, a_y: v * omega });
    }
    let mut x = Vector3::zeros();
    let mut e_prev = Vector3::zeros();
    let mut qp = StageQp {
        a: Vec::with_capacity(stages),
        b: Vec::with_capacity(stages),
        c: Vec::with_capacity(stages),
        q: Vector3::new(1.0, 1.0, 10.0),
        r: Vector2::new(1000.0, 1000.0),
        delta: (1..stages).map(|i| n_meas[i] - n_meas[i - 1]).collect(),
        z_lo: vec![-Vector3::new(5.0, 5.0, 0.5) * s; stages],
        z_hi: vec![Vector3::new(5.0, 5.0, 0.5) * s; stages],
        w_lo: n_meas.iter().map(|n| -0.05 * n.abs() * s).collect(),
        w_hi: n_meas.iter().map(|n| 0.05 * n.abs() * s).collect(),
    };
    for u in &inputs {
        let j = step_jacobians(&x, u, &theta, T_S);
        let v = (j.next - x).xy().norm();
        let e = Vector3::new(0.03 * g(), 0.03 * g(), 0.005 * g());
        let heading = Vector3::new(x[2].cos(), x[2].sin(), 0.0);
        qp.c.push(j.f_x * e_prev - e + heading * (0.01 * v * g()));
        qp.a.push(heading_column(&j.f_x).expect("the model's step Jacobian"));
        qp.b.push(j.f_n);
        e_prev = e;
        x = j.next;
    }
    qp
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests;
