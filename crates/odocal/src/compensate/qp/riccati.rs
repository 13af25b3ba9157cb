//! The structured solver: a primal-dual interior-point method whose Newton
//! steps are Riccati recursions, O(K) per iteration.
//!
//! ## Why hand-written
//!
//! The compensation QP is an optimal-control problem: 5 variables per stage,
//! coupled only to the neighbouring stage through the dynamics and the
//! input-rate penalty, and only *box* constraints. A general solver such as
//! Clarabel sees a 5K-variable sparse problem with 13K constraint rows and
//! factorises the whole (13K+5K)-sized KKT matrix by a sparse LDLᵀ with
//! symbolic analysis, pivoting and iterative refinement every iteration. Here
//! the stage structure is used directly:
//!
//! - box constraints give a *diagonal* barrier Hessian Σ, so every Newton
//!   step is an equality-constrained LQ problem with the same dynamics;
//! - that LQ problem is solved exactly by a backward Riccati recursion and a
//!   forward rollout, with fixed-size 5×5/2×2 matrices and no heap traffic
//!   (all buffers are allocated once per solve);
//! - the Mehrotra corrector reuses the factorisation (only the vector pass
//!   is repeated).
//!
//! The input-rate term `(w_k − w_{k−1} + δ_k)ᵀR(…)` couples consecutive
//! inputs; augmenting the state with the previous input,
//! `s_k = [z_k; w_{k−1}] ∈ ℝ⁵`, makes it an ordinary stage cost with a
//! state–input cross term, and the augmented dynamics
//! `s_{k+1} = [[A_{k+1}, 0], [0, 0]] s_k + [B_{k+1}; I] w_k + [c_{k+1}; 0]`.
//! The block structure of these matrices is written out by hand below.
//!
//! ## Algorithm
//!
//! Each bounded variable `x` has slacks `t_lo = x − x_lo`, `t_hi = x_hi − x`
//! and multipliers `μ_lo, μ_hi ≥ 0` (named `l_lo`, `l_hi` in the code). The
//! iteration is the infeasible-start Mehrotra predictor-corrector method
//! (Nocedal & Wright, *Numerical Optimization*, §16.6) on the KKT system of
//! [`crate::compensate::qp`]'s dual convention; steps use one common primal-dual step
//! length. It stops when the primal residual, the dual residual and the mean
//! complementarity are all below [`StructuredOptions`]' tolerances.
//!
//! ## References
//! - C. V. Rao, S. J. Wright, J. B. Rawlings, "Application of interior-point
//!   methods to model predictive control", JOTA 99 (1998) 723–757.
//! - G. Frison, M. Diehl, "HPIPM: a high-performance quadratic programming
//!   framework for model predictive control", IFAC-PapersOnLine 2020.
//! - S. Mehrotra, "On the implementation of a primal-dual interior point
//!   method", SIAM J. Optim. 2 (1992) 575–601.

use nalgebra::{Matrix2, Matrix3, Matrix3x2, Matrix5, SMatrix, Vector2, Vector3, Vector5};

use super::{QpError, QpSolution, QpSolver, StageQp, ACTIVE_BOUND_TOL};

/// Options of the structured solver ([`SolverKind::Structured`](super::SolverKind::Structured)).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StructuredOptions {
    /// Relative tolerance on the primal residuals (dynamics and slack
    /// definitions), scaled by `1 + max|c_k|, |bounds|`. Default 1e-6.
    pub tol_primal: f64,
    /// Relative tolerance on the dual (stationarity) residual, scaled by
    /// `1 + max|∇f|` separately over inputs and states (input gradients
    /// carry R = 1000 and would otherwise swamp the states'). Default 1e-6.
    pub tol_dual: f64,
    /// Relative tolerance on the total complementarity `Σ t·μ`, scaled by
    /// `max(1, f)`; it bounds the objective error. Default 1e-7.
    ///
    /// The defaults solve the compensation QP far more precisely than the
    /// re-linearization around its solution needs
    /// ([`CompensateOptions::input_tolerance_rev_per_s`](crate::compensate::CompensateOptions::input_tolerance_rev_per_s)):
    /// on the 24 km paper drive they move the 3-step θ by less than 1e-4
    /// of its σ against 1e-9/1e-9/1e-12, with 30 % fewer iterations.
    /// Tighten all three (e.g. 1e-9, 1e-9, 1e-12) to compare solutions
    /// with another solver's to ~1e-9.
    pub tol_gap: f64,
    /// Iteration limit. Default 50.
    pub max_iterations: usize,
    /// Fraction of the step to the boundary of the positive orthant that is
    /// taken (keeps iterates strictly interior). Default 0.995.
    pub step_fraction: f64,
    /// A bound multiplier above this times `1 + max|∇f|` while the primal
    /// residual has not converged is taken as a certificate that no feasible
    /// point exists. Default 1e8.
    pub infeasibility_multiplier: f64,
    /// Warm start: distance, as a fraction of each box's width, by which a
    /// previous solution is moved into the interior of the box. Default 1e-3.
    pub warm_start_shift: f64,
    /// Warm start: target mean complementarity `t·μ` of the starting point,
    /// in objective units. Default 1e-3.
    pub warm_start_mu: f64,
    /// A box narrower than this (`hi − lo ≤ fixed_width`, in the variable's
    /// unit: rev/s for inputs) pins its variable at the box midpoint: the
    /// variable is eliminated from the interior-point iteration instead of
    /// being squeezed between two slacks that cannot both stay positive
    /// (standstill: `ñ = 0` gives `0.95ñ ≤ n ≤ 1.05ñ` zero width). Pinning
    /// at the midpoint moves it at most `fixed_width / 2` from any point of
    /// the box, far inside `ACTIVE_BOUND_TOL`. Default 1e-10.
    pub fixed_width: f64,
}

impl Default for StructuredOptions {
    fn default() -> Self {
        Self {
            tol_primal: 1e-6,
            tol_dual: 1e-6,
            tol_gap: 1e-7,
            max_iterations: 50,
            step_fraction: 0.995,
            infeasibility_multiplier: 1e8,
            warm_start_shift: 1e-3,
            warm_start_mu: 1e-3,
            fixed_width: 1e-10,
        }
    }
}

impl StructuredOptions {
    /// Checks every field; the error names the field.
    pub(crate) fn validate(&self) -> Result<(), QpError> {
        let pos = |v: f64, name: &str| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(QpError::Malformed(format!("StructuredOptions::{name} must be positive and finite, got {v}")))
            }
        };
        pos(self.tol_primal, "tol_primal")?;
        pos(self.tol_dual, "tol_dual")?;
        pos(self.tol_gap, "tol_gap")?;
        pos(self.infeasibility_multiplier, "infeasibility_multiplier")?;
        pos(self.warm_start_mu, "warm_start_mu")?;
        if !(self.step_fraction > 0.0 && self.step_fraction < 1.0) {
            return Err(QpError::Malformed(format!(
                "StructuredOptions::step_fraction must be in (0, 1), got {}",
                self.step_fraction
            )));
        }
        if !(self.warm_start_shift >= 0.0 && self.warm_start_shift < 0.5) {
            return Err(QpError::Malformed(format!(
                "StructuredOptions::warm_start_shift must be in [0, 0.5), got {}",
                self.warm_start_shift
            )));
        }
        if !(self.fixed_width.is_finite() && self.fixed_width >= 0.0) {
            return Err(QpError::Malformed(format!(
                "StructuredOptions::fixed_width must be non-negative and finite, got {}",
                self.fixed_width
            )));
        }
        if self.max_iterations == 0 {
            return Err(QpError::Malformed("StructuredOptions::max_iterations must be at least 1".into()));
        }
        Ok(())
    }
}

/// The structured interior-point solver (see the module docs for the
/// method and why it exists). Typically 10–20 iterations; each costs two
/// O(K) passes over fixed-size stage matrices.
///
/// On an infeasible problem it returns `QpError::Infeasible` with the
/// stalled primal residual and the diverging multiplier; on
/// `QpError::MaxIterations` or `QpError::Numerical` a caller may fall
/// back to [`super::clarabel::ClarabelSolver`].
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct StructuredSolver {
    /// Tolerances, limits and warm-start settings.
    pub options: StructuredOptions,
}

#[cfg(test)]
impl StructuredSolver {
    /// Tolerances 1e-9 (primal, dual) and 1e-12 (gap): solutions within
    /// ~1e-9 of the optimum, to compare with another solver's.
    pub(crate) fn tight() -> Self {
        let options = StructuredOptions { tol_primal: 1e-9, tol_dual: 1e-9, tol_gap: 1e-12, ..Default::default() };
        Self { options }
    }
}

/// `[w_i; z_{i+1}]` packed per stage: rows 0..2 input, rows 2..5 state.
type V5 = Vector5<f64>;

fn wpart(v: &V5) -> Vector2<f64> {
    Vector2::new(v[0], v[1])
}

fn zpart(v: &V5) -> Vector3<f64> {
    Vector3::new(v[2], v[3], v[4])
}

fn pack(w: &Vector2<f64>, z: &Vector3<f64>) -> V5 {
    V5::new(w[0], w[1], z[0], z[1], z[2])
}

/// Buffers of one solve, allocated once.
struct Work {
    /// 1 for a variable of the interior-point iteration, 0 for one pinned
    /// by a zero-width box (see [`StructuredOptions::fixed_width`]).
    free: Vec<V5>,
    /// Number of free variables (each has two bounds).
    n_free: usize,
    /// Primal iterate per stage.
    x: Vec<V5>,
    /// Dynamics multipliers λ_{i+1}.
    y: Vec<Vector3<f64>>,
    lo: Vec<V5>,
    hi: Vec<V5>,
    t_lo: Vec<V5>,
    t_hi: Vec<V5>,
    l_lo: Vec<V5>,
    l_hi: Vec<V5>,
    /// Dual residual ∇f + Gᵀy − μ_lo + μ_hi.
    r_d: Vec<V5>,
    /// Dynamics residual of z_{i+1}.
    r_p: Vec<Vector3<f64>>,
    /// `x − lo − t_lo`, `hi − x − t_hi`.
    r_lo: Vec<V5>,
    r_hi: Vec<V5>,
    /// Barrier Hessian diagonal Σ.
    sigma: Vec<V5>,
    /// Reduced linear term r̃_d of the Newton LQ problem.
    rt: Vec<V5>,
    /// Newton direction (affine, then combined).
    dx: Vec<V5>,
    dy: Vec<Vector3<f64>>,
    dt_lo: Vec<V5>,
    dt_hi: Vec<V5>,
    dl_lo: Vec<V5>,
    dl_hi: Vec<V5>,
    /// Complementarity targets of the current Newton step, per stage.
    rc: Vec<(V5, V5)>,
    /// Affine directions kept for the corrector term.
    aff_t_lo: Vec<V5>,
    aff_t_hi: Vec<V5>,
    aff_l_lo: Vec<V5>,
    aff_l_hi: Vec<V5>,
    /// Riccati factors: the blocks `P11`, `P12` of P_{i+1} (the vector
    /// pass reads no other), H_uu⁻¹, H_us, feed-forward.
    p11: Vec<Matrix3<f64>>,
    p12: Vec<Matrix3x2<f64>>,
    huu_inv: Vec<Matrix2<f64>>,
    hus: Vec<SMatrix<f64, 2, 5>>,
    kff: Vec<Vector2<f64>>,
}

impl Work {
    fn new(k: usize) -> Self {
        let v5 = || vec![V5::zeros(); k];
        let v3 = || vec![Vector3::zeros(); k];
        Self {
            free: vec![V5::repeat(1.0); k],
            n_free: 5 * k,
            x: v5(),
            y: v3(),
            lo: v5(),
            hi: v5(),
            t_lo: v5(),
            t_hi: v5(),
            l_lo: v5(),
            l_hi: v5(),
            r_d: v5(),
            r_p: v3(),
            r_lo: v5(),
            r_hi: v5(),
            sigma: v5(),
            rt: v5(),
            dx: v5(),
            dy: v3(),
            dt_lo: v5(),
            dt_hi: v5(),
            dl_lo: v5(),
            dl_hi: v5(),
            rc: vec![(V5::zeros(), V5::zeros()); k],
            aff_t_lo: v5(),
            aff_t_hi: v5(),
            aff_l_lo: v5(),
            aff_l_hi: v5(),
            p11: vec![Matrix3::zeros(); k],
            p12: vec![Matrix3x2::zeros(); k],
            huu_inv: vec![Matrix2::zeros(); k],
            hus: vec![SMatrix::<f64, 2, 5>::zeros(); k],
            kff: vec![Vector2::zeros(); k],
        }
    }
}

/// Norms of the current residuals.
#[derive(Debug, Clone, Copy)]
struct Residuals {
    primal: f64,
    dual: f64,
    /// Σ t·μ.
    gap: f64,
    /// Mean complementarity.
    mu: f64,
    objective: f64,
    /// Largest |∇f| over the inputs and over the states (the dual
    /// residual is scaled per block: input gradients carry R = 1000).
    grad_scale: f64,
    /// Dual residual over the states (`dual` is over the inputs).
    dual_z: f64,
    grad_scale_z: f64,
}

impl StructuredSolver {
    /// Gradient of f at the packed iterate into `out` (w and z parts).
    fn gradient(qp: &StageQp, x: &[V5], out: &mut [V5]) {
        let k = x.len();
        let (out, delta) = (&mut out[..k], &qp.delta[..k - 1]);
        let r2 = 2.0 * qp.r;
        for i in 0..k {
            let gz = 2.0 * qp.q.component_mul(&zpart(&x[i]));
            out[i] = pack(&Vector2::zeros(), &gz);
        }
        for i in 1..k {
            let d = r2.component_mul(&(wpart(&x[i]) - wpart(&x[i - 1]) + delta[i - 1]));
            out[i][0] += d[0];
            out[i][1] += d[1];
            out[i - 1][0] -= d[0];
            out[i - 1][1] -= d[1];
        }
    }

    /// Fills r_d, r_p, r_lo, r_hi and returns their norms.
    fn residuals(qp: &StageQp, wk: &mut Work) -> Residuals {
        let k = qp.stages();
        Self::gradient(qp, &wk.x[..k], &mut wk.r_d);
        let (x, y, free) = (&wk.x[..k], &wk.y[..k], &wk.free[..k]);
        let (a, b, c, delta) = (&qp.a[..k], &qp.b[..k], &qp.c[..k], &qp.delta[..k - 1]);
        let (r_d, r_p, r_lo, r_hi) = (&mut wk.r_d[..k], &mut wk.r_p[..k], &mut wk.r_lo[..k], &mut wk.r_hi[..k]);
        let (lo, hi, t_lo, t_hi) = (&wk.lo[..k], &wk.hi[..k], &wk.t_lo[..k], &wk.t_hi[..k]);
        let (l_lo, l_hi) = (&wk.l_lo[..k], &wk.l_hi[..k]);
        let mut grad_scale: f64 = 0.0;
        let mut grad_scale_z: f64 = 0.0;
        let mut objective = 0.0;
        for i in 0..k {
            grad_scale = grad_scale.max(wpart(&r_d[i]).amax());
            grad_scale_z = grad_scale_z.max(zpart(&r_d[i]).amax());
            let z = zpart(&x[i]);
            objective += z.component_mul(&z).dot(&qp.q);
            if i > 0 {
                let d = wpart(&x[i]) - wpart(&x[i - 1]) + delta[i - 1];
                objective += d.component_mul(&d).dot(&qp.r);
            }
        }
        let mut primal: f64 = 0.0;
        let mut dual: f64 = 0.0;
        let mut dual_z: f64 = 0.0;
        let mut gap = 0.0;
        let mut zprev = Vector3::zeros();
        for i in 0..k {
            let w = wpart(&x[i]);
            let z = zpart(&x[i]);
            // Gᵀy: z_{i+1} gets y_{i+1} − A_{i+2}ᵀ y_{i+2}; w_i gets −B_{i+1}ᵀ y_{i+1}.
            let mut gy_z = y[i];
            if i + 1 < k {
                gy_z -= a[i + 1].transpose() * y[i + 1];
            }
            let gy_w = -(b[i].transpose() * y[i]);
            r_d[i] += pack(&gy_w, &gy_z) - l_lo[i] + l_hi[i];
            // A pinned variable's stationarity is absorbed by the multiplier
            // of its equality `x = v`.
            r_d[i].component_mul_assign(&free[i]);
            dual = dual.max(wpart(&r_d[i]).amax());
            dual_z = dual_z.max(zpart(&r_d[i]).amax());
            r_p[i] = z - a[i] * zprev - b[i] * w - c[i];
            zprev = z;
            r_lo[i] = (x[i] - lo[i] - t_lo[i]).component_mul(&free[i]);
            r_hi[i] = (hi[i] - x[i] - t_hi[i]).component_mul(&free[i]);
            primal = primal.max(r_p[i].amax()).max(r_lo[i].amax()).max(r_hi[i].amax());
            gap += t_lo[i].dot(&l_lo[i]) + t_hi[i].dot(&l_hi[i]);
        }
        let mu = if wk.n_free > 0 { gap / (2 * wk.n_free) as f64 } else { 0.0 };
        Residuals { primal, dual, gap, mu, objective, grad_scale, dual_z, grad_scale_z }
    }

    /// Backward Riccati factorisation of the Newton LQ problem for the
    /// current Σ (depends on Σ only; shared by predictor and corrector).
    fn factorize(qp: &StageQp, wk: &mut Work) -> Result<(), QpError> {
        let k = qp.stages();
        let q2 = Matrix3::from_diagonal(&(2.0 * qp.q));
        let r2 = Matrix2::from_diagonal(&(2.0 * qp.r));
        // Terminal cost-to-go: P_K = blockdiag(2Q + Σ_z, 0).
        let (sigma, free, qa, qb) = (&wk.sigma[..k], &wk.free[..k], &qp.a[..k], &qp.b[..k]);
        let (p11s, p12s) = (&mut wk.p11[..k], &mut wk.p12[..k]);
        let (huu_invs, huss) = (&mut wk.huu_inv[..k], &mut wk.hus[..k]);
        let mut p = Matrix5::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&(q2 + Matrix3::from_diagonal(&zpart(&sigma[k - 1]))));
        for i in (0..k).rev() {
            let p11: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
            let p12: Matrix3x2<f64> = p.fixed_view::<3, 2>(0, 3).into_owned();
            p11s[i] = p11;
            p12s[i] = p12;
            let p22: Matrix2<f64> = p.fixed_view::<2, 2>(3, 3).into_owned();
            let a = &qa[i];
            let b = &qb[i];
            let g = p11 * b + p12;
            let mut huu = b.transpose() * g + p12.transpose() * b + p22 + Matrix2::from_diagonal(&wpart(&sigma[i]));
            if i > 0 {
                huu += r2;
            }
            // Closed-form inverse of the symmetric 2×2 H_uu; positive
            // definiteness checked on the leading minors. A pinned input is
            // no decision variable: H_uu is inverted on the free inputs only
            // and padded with zeros, so its step (and feedback) is 0.
            let huu_inv = match (free[i][0] > 0.0, free[i][1] > 0.0) {
                (true, true) => {
                    let (h00, h01, h11) = (huu[(0, 0)], 0.5 * (huu[(0, 1)] + huu[(1, 0)]), huu[(1, 1)]);
                    let det = h00 * h11 - h01 * h01;
                    if !(h00 > 0.0 && det > f64::EPSILON * h00 * h11) {
                        return Err(QpError::Numerical(format!(
                            "Riccati recursion: input Hessian not positive definite at stage {i} (det {det:.3e})"
                        )));
                    }
                    Matrix2::new(h11, -h01, -h01, h00) / det
                }
                (f0, f1) => {
                    let mut inv = Matrix2::zeros();
                    for (j, free) in [(0, f0), (1, f1)] {
                        if free {
                            let h = huu[(j, j)];
                            if h.is_nan() || h <= 0.0 {
                                return Err(QpError::Numerical(format!(
                                    "Riccati recursion: input Hessian not positive at stage {i} (h {h:.3e})"
                                )));
                            }
                            inv[(j, j)] = 1.0 / h;
                        }
                    }
                    inv
                }
            };
            huu_invs[i] = huu_inv;
            if i == 0 {
                break; // s_0 = 0: P_0 is never used.
            }
            let mut hus = SMatrix::<f64, 2, 5>::zeros();
            hus.fixed_view_mut::<2, 3>(0, 0).copy_from(&(g.transpose() * a));
            hus.fixed_view_mut::<2, 2>(0, 3).copy_from(&(-r2));
            huss[i] = hus;
            // P_i = blockdiag(2Q + Σ_z + AᵀP11A, 2R) − H_usᵀ H_uu⁻¹ H_us.
            let mut pn = Matrix5::zeros();
            pn.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(q2 + Matrix3::from_diagonal(&zpart(&sigma[i - 1])) + a.transpose() * p11 * a));
            pn.fixed_view_mut::<2, 2>(3, 3).copy_from(&r2);
            pn -= hus.transpose() * (huu_inv * hus);
            p = 0.5 * (pn + pn.transpose());
        }
        Ok(())
    }

    /// Solves the Newton LQ problem for the linear term `wk.rt` and the
    /// dynamics offset `−r_p` with the current factorisation; writes `dx`.
    fn solve_lq(qp: &StageQp, wk: &mut Work) {
        let k = qp.stages();
        let (a, b, r_p, rt) = (&qp.a[..k], &qp.b[..k], &wk.r_p[..k], &wk.rt[..k]);
        let (p11, p12, huu_inv, hus) = (&wk.p11[..k], &wk.p12[..k], &wk.huu_inv[..k], &wk.hus[..k]);
        let (kffs, dx) = (&mut wk.kff[..k], &mut wk.dx[..k]);
        // Backward vector pass: cost-to-go gradient p.
        let mut p = V5::zeros();
        p.fixed_rows_mut::<3>(0).copy_from(&zpart(&rt[k - 1]));
        for i in (0..k).rev() {
            let chat = -r_p[i];
            let e1 = p11[i] * chat + p.fixed_rows::<3>(0);
            let e2 = p12[i].transpose() * chat + p.fixed_rows::<2>(3);
            let hu = wpart(&rt[i]) + b[i].transpose() * e1 + e2;
            let kff = -(huu_inv[i] * hu);
            kffs[i] = kff;
            if i == 0 {
                break;
            }
            let hs_z = zpart(&rt[i - 1]) + a[i].transpose() * e1;
            let mut pn = V5::zeros();
            pn.fixed_rows_mut::<3>(0).copy_from(&hs_z);
            p = pn + hus[i].transpose() * kff;
        }
        // Forward rollout: u_i = −H_uu⁻¹ H_us s_i + kff_i.
        let mut s = V5::zeros();
        for i in 0..k {
            let u = if i == 0 { kffs[0] } else { kffs[i] - huu_inv[i] * (hus[i] * s) };
            let dz = a[i] * s.fixed_rows::<3>(0) + b[i] * u - r_p[i];
            dx[i] = pack(&u, &dz);
            s = V5::new(dz[0], dz[1], dz[2], u[0], u[1]);
        }
    }

    /// The complementarity residuals `rc_lo`, `rc_hi` of every stage that
    /// the Newton step targets, into `rc`: `t·μ` for the predictor
    /// (`target` None); `t·μ + Δt_aff·Δμ_aff − σμ` for the corrector
    /// (`target` σμ).
    fn complementarity(wk: &Work, target: Option<f64>, rc: &mut [(V5, V5)]) {
        let k = rc.len();
        let (t_lo, t_hi, l_lo, l_hi) = (&wk.t_lo[..k], &wk.t_hi[..k], &wk.l_lo[..k], &wk.l_hi[..k]);
        match target {
            None => {
                for i in 0..k {
                    rc[i] = (t_lo[i].component_mul(&l_lo[i]), t_hi[i].component_mul(&l_hi[i]));
                }
            }
            Some(target) => {
                let (at_lo, at_hi, al_lo, al_hi) =
                    (&wk.aff_t_lo[..k], &wk.aff_t_hi[..k], &wk.aff_l_lo[..k], &wk.aff_l_hi[..k]);
                for i in 0..k {
                    rc[i] = (
                        t_lo[i].component_mul(&l_lo[i]) + at_lo[i].component_mul(&al_lo[i]) - V5::repeat(target),
                        t_hi[i].component_mul(&l_hi[i]) + at_hi[i].component_mul(&al_hi[i]) - V5::repeat(target),
                    );
                }
            }
        }
    }

    /// Sets `rt` from the complementarity targets ([`Self::complementarity`]),
    /// solves for `dx`, and recovers `dt`, `dl`.
    fn newton_direction(qp: &StageQp, wk: &mut Work, target: Option<f64>) {
        let k = qp.stages();
        let mut rc = std::mem::take(&mut wk.rc);
        Self::complementarity(wk, target, &mut rc[..k]);
        {
            let (rc, r_d, rt) = (&rc[..k], &wk.r_d[..k], &mut wk.rt[..k]);
            let (t_lo, t_hi, l_lo, l_hi) = (&wk.t_lo[..k], &wk.t_hi[..k], &wk.l_lo[..k], &wk.l_hi[..k]);
            let (r_lo, r_hi) = (&wk.r_lo[..k], &wk.r_hi[..k]);
            for i in 0..k {
                let (rc_lo, rc_hi) = rc[i];
                let a = (rc_lo + l_lo[i].component_mul(&r_lo[i])).component_div(&t_lo[i]);
                let b = (rc_hi + l_hi[i].component_mul(&r_hi[i])).component_div(&t_hi[i]);
                rt[i] = r_d[i] + a - b;
            }
        }
        Self::solve_lq(qp, wk);
        {
            let (rc, dx, free) = (&rc[..k], &wk.dx[..k], &wk.free[..k]);
            let (t_lo, t_hi, l_lo, l_hi) = (&wk.t_lo[..k], &wk.t_hi[..k], &wk.l_lo[..k], &wk.l_hi[..k]);
            let (r_lo, r_hi) = (&wk.r_lo[..k], &wk.r_hi[..k]);
            let (dt_lo, dt_hi) = (&mut wk.dt_lo[..k], &mut wk.dt_hi[..k]);
            let (dl_lo, dl_hi) = (&mut wk.dl_lo[..k], &mut wk.dl_hi[..k]);
            for i in 0..k {
                let (rc_lo, rc_hi) = rc[i];
                let dx = dx[i];
                dt_lo[i] = dx + r_lo[i];
                dt_hi[i] = r_hi[i] - dx;
                // Pinned variables keep slacks and (zero) multipliers unchanged.
                let f = &free[i];
                dl_lo[i] = -(rc_lo + l_lo[i].component_mul(&dt_lo[i])).component_div(&t_lo[i]).component_mul(f);
                dl_hi[i] = -(rc_hi + l_hi[i].component_mul(&dt_hi[i])).component_div(&t_hi[i]).component_mul(f);
            }
        }
        wk.rc = rc;
    }

    /// Largest α ≤ 1 keeping all slacks and multipliers non-negative.
    ///
    /// With every `a > 0`, `α_max = 1 / max(1, max(−d/a))`; the maximum is
    /// exact in any order (a NaN ratio is skipped, as by `f64::max`).
    fn max_step(wk: &Work) -> f64 {
        let k = wk.t_lo.len();
        let pairs = [(&wk.t_lo[..k], &wk.dt_lo[..k]), (&wk.t_hi[..k], &wk.dt_hi[..k])];
        let pairs_l = [(&wk.l_lo[..k], &wk.dl_lo[..k]), (&wk.l_hi[..k], &wk.dl_hi[..k])];
        let mut m = [1.0f64; 5];
        for (v, dv) in pairs.into_iter().chain(pairs_l) {
            for i in 0..k {
                let (a, d) = (&v[i], &dv[i]);
                for j in 0..5 {
                    let r = -d[j] / a[j];
                    if r > m[j] {
                        m[j] = r;
                    }
                }
            }
        }
        1.0 / m.iter().fold(1.0f64, |x, &y| if y > x { y } else { x })
    }

    /// Multiplier step from stationarity in z (backward recursion):
    /// `Δy_k = −(2Q + Σ_z)Δz_k − r̃_z,k + A_{k+1}ᵀ Δy_{k+1}`.
    fn dual_direction(qp: &StageQp, wk: &mut Work) {
        let k = qp.stages();
        let (dx, sigma, rt, a, dys) = (&wk.dx[..k], &wk.sigma[..k], &wk.rt[..k], &qp.a[..k], &mut wk.dy[..k]);
        let mut next = Vector3::zeros();
        for i in (0..k).rev() {
            let dz = zpart(&dx[i]);
            let h = (2.0 * qp.q + zpart(&sigma[i])).component_mul(&dz);
            let mut dy = -h - zpart(&rt[i]);
            if i + 1 < k {
                dy += a[i + 1].transpose() * next;
            }
            dys[i] = dy;
            next = dy;
        }
    }

    /// Marks the variables pinned by a zero-width box (inputs only; a
    /// pinned state component is an equality constraint on the dynamics,
    /// which the Riccati recursion does not eliminate).
    fn mark_fixed(&self, qp: &StageQp, wk: &mut Work) -> Result<(), QpError> {
        let k = qp.stages();
        let tol = self.options.fixed_width;
        wk.n_free = 5 * k;
        for i in 0..k {
            wk.lo[i] = pack(&qp.w_lo[i], &qp.z_lo[i]);
            wk.hi[i] = pack(&qp.w_hi[i], &qp.z_hi[i]);
            for j in 0..5 {
                let fixed = wk.hi[i][j] - wk.lo[i][j] <= tol;
                if fixed && j >= 2 {
                    return Err(QpError::Numerical(format!(
                        "zero-width state box at stage {i}, component {}: pinned states are not supported by \
                         the structured solver (use Clarabel)",
                        j - 2
                    )));
                }
                wk.free[i][j] = if fixed { 0.0 } else { 1.0 };
                wk.n_free -= usize::from(fixed);
            }
        }
        Ok(())
    }

    /// Puts pinned variables at their box midpoint `v` with a unit fake box
    /// `[v − 1, v + 1]`, unit slacks and zero multipliers: their slack
    /// residuals are 0 and stay so, and they add nothing to the gap.
    fn pin_fixed(wk: &mut Work) {
        for i in 0..wk.x.len() {
            for j in 0..5 {
                if wk.free[i][j] == 0.0 {
                    let v = 0.5 * (wk.lo[i][j] + wk.hi[i][j]);
                    wk.x[i][j] = v;
                    wk.lo[i][j] = v - 1.0;
                    wk.hi[i][j] = v + 1.0;
                    wk.t_lo[i][j] = 1.0;
                    wk.t_hi[i][j] = 1.0;
                    wk.l_lo[i][j] = 0.0;
                    wk.l_hi[i][j] = 0.0;
                }
            }
        }
    }

    /// Cold or warm starting point.
    fn initialize(&self, qp: &StageQp, wk: &mut Work, warm: Option<&QpSolution>) -> Result<(), QpError> {
        let k = qp.stages();
        self.mark_fixed(qp, wk)?;
        let warm = warm.filter(|s| s.w.len() == k && s.z.len() == k);
        match warm {
            Some(sol) => {
                let shift = self.options.warm_start_shift;
                for i in 0..k {
                    let x = pack(&sol.w[i], &sol.z[i]);
                    for j in 0..5 {
                        let (lo, hi) = (wk.lo[i][j], wk.hi[i][j]);
                        let m = shift * (hi - lo);
                        wk.x[i][j] = x[j].clamp(lo + m, hi - m);
                    }
                    wk.y[i] = sol.dynamics_duals.as_ref().filter(|l| l.len() == k).map_or(Vector3::zeros(), |l| l[i]);
                }
                // Bound multipliers recovered from stationarity at the
                // previous point: ν = ∇f + Gᵀy = μ_lo − μ_hi.
                for v in wk.l_lo.iter_mut().chain(wk.l_hi.iter_mut()) {
                    *v = V5::zeros();
                }
                Self::residuals(qp, wk); // r_d = ν with zero bound multipliers
                let mu = self.options.warm_start_mu;
                for i in 0..k {
                    for j in 0..5 {
                        let width = wk.hi[i][j] - wk.lo[i][j];
                        let floor = (shift * width).max(f64::MIN_POSITIVE.sqrt());
                        let t_lo = (wk.x[i][j] - wk.lo[i][j]).max(floor);
                        let t_hi = (wk.hi[i][j] - wk.x[i][j]).max(floor);
                        let nu = wk.r_d[i][j];
                        wk.t_lo[i][j] = t_lo;
                        wk.t_hi[i][j] = t_hi;
                        wk.l_lo[i][j] = nu.max(0.0).max(mu / t_lo);
                        wk.l_hi[i][j] = (-nu).max(0.0).max(mu / t_hi);
                    }
                }
            }
            None => {
                // Inputs 0 (the measurements) pulled into their boxes, states
                // by rollout; slacks at least a quarter of the box width,
                // multipliers 1.
                let mut zprev = Vector3::zeros();
                for i in 0..k {
                    let mut w = Vector2::zeros();
                    for j in 0..2 {
                        let (lo, hi) = (qp.w_lo[i][j], qp.w_hi[i][j]);
                        w[j] = if wk.free[i][j] == 0.0 {
                            0.5 * (lo + hi)
                        } else {
                            0.0f64.clamp(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo))
                        };
                    }
                    let z = qp.a[i] * zprev + qp.b[i] * w + qp.c[i];
                    zprev = z;
                    wk.x[i] = pack(&w, &z);
                    wk.y[i] = Vector3::zeros();
                    for j in 0..5 {
                        let floor = (0.25 * (wk.hi[i][j] - wk.lo[i][j])).max(1e-8);
                        wk.t_lo[i][j] = (wk.x[i][j] - wk.lo[i][j]).max(floor);
                        wk.t_hi[i][j] = (wk.hi[i][j] - wk.x[i][j]).max(floor);
                    }
                    wk.l_lo[i] = V5::repeat(1.0);
                    wk.l_hi[i] = V5::repeat(1.0);
                }
            }
        }
        Self::pin_fixed(wk);
        Ok(())
    }
}

impl QpSolver for StructuredSolver {
    fn name(&self) -> &'static str {
        "structured"
    }

    fn solve(&self, qp: &StageQp, warm_start: Option<&QpSolution>) -> Result<QpSolution, QpError> {
        qp.check()?;
        self.options.validate()?;
        let k = qp.stages();
        // Reuse this thread's buffers when the size matches (every solve
        // overwrites each buffer before reading it): the compensation runs
        // thousands of same-K solves per thread.
        let mut wk = WORK.with(|c| c.borrow_mut().take()).filter(|w| w.x.len() == k).unwrap_or_else(|| Work::new(k));
        let result = self.solve_in(qp, warm_start, &mut wk);
        WORK.with(|c| *c.borrow_mut() = Some(wk));
        result
    }
}

thread_local! {
    /// Per-thread solver buffers, kept between solves.
    static WORK: std::cell::RefCell<Option<Work>> = const { std::cell::RefCell::new(None) };
}

impl StructuredSolver {
    fn solve_in(&self, qp: &StageQp, warm_start: Option<&QpSolution>, wk: &mut Work) -> Result<QpSolution, QpError> {
        let opt = &self.options;
        let k = qp.stages();
        self.initialize(qp, wk, warm_start)?;

        let mut scale_p: f64 = 1.0;
        for i in 0..k {
            scale_p = scale_p.max(1.0 + qp.c[i].amax()).max(1.0 + wk.lo[i].amax()).max(1.0 + wk.hi[i].amax());
        }
        let mut last_residual = f64::NAN;
        for iteration in 0..=opt.max_iterations {
            let res = Self::residuals(qp, wk);
            last_residual = res.primal.max(res.dual).max(res.dual_z);
            if !(res.primal.is_finite() && res.dual.is_finite() && res.dual_z.is_finite() && res.gap.is_finite()) {
                return Err(QpError::Numerical(format!("non-finite residuals at iteration {iteration}")));
            }
            let primal_ok = res.primal <= opt.tol_primal * scale_p;
            let dual_ok = res.dual <= opt.tol_dual * (1.0 + res.grad_scale)
                && res.dual_z <= opt.tol_dual * (1.0 + res.grad_scale_z);
            let gap_ok = res.gap <= opt.tol_gap * res.objective.max(1.0);
            if primal_ok && dual_ok && gap_ok {
                return Ok(self.finish(qp, wk, iteration));
            }
            if iteration == opt.max_iterations {
                break;
            }
            // Infeasibility: primal residual stuck while multipliers diverge.
            let lmax = wk.l_lo.iter().chain(&wk.l_hi).fold(0.0f64, |m, v| m.max(v.amax()));
            if !primal_ok && lmax > opt.infeasibility_multiplier * (1.0 + res.grad_scale) {
                return Err(QpError::Infeasible(format!(
                    "primal residual stalled at {:.2e} while a bound multiplier grew to {lmax:.2e} \
                     (iteration {iteration}): no input sequence keeps the states within their bounds",
                    res.primal
                )));
            }

            Self::barrier_hessian(wk);
            Self::factorize(qp, wk)?;

            // Predictor (affine scaling): target t·μ = 0.
            Self::newton_direction(qp, wk, None);
            let alpha_aff = Self::max_step(wk);
            let gap_aff = Self::affine_gap(wk, alpha_aff);
            let sigma_c = (gap_aff / res.gap).clamp(0.0, 1.0).powi(3);
            let target = sigma_c * res.mu;
            std::mem::swap(&mut wk.aff_t_lo, &mut wk.dt_lo);
            std::mem::swap(&mut wk.aff_t_hi, &mut wk.dt_hi);
            std::mem::swap(&mut wk.aff_l_lo, &mut wk.dl_lo);
            std::mem::swap(&mut wk.aff_l_hi, &mut wk.dl_hi);

            // Corrector: target t·μ = σμ, with the second-order term.
            Self::newton_direction(qp, wk, Some(target));
            Self::dual_direction(qp, wk);
            let alpha = (opt.step_fraction * Self::max_step(wk)).min(1.0);
            Self::take_step(wk, alpha);
        }
        Err(QpError::MaxIterations { iterations: opt.max_iterations, residual: last_residual })
    }
}

impl StructuredSolver {
    /// The barrier Hessian's diagonal `Σ = μ_lo/t_lo + μ_hi/t_hi`.
    fn barrier_hessian(wk: &mut Work) {
        let k = wk.sigma.len();
        let (t_lo, t_hi, l_lo, l_hi) = (&wk.t_lo[..k], &wk.t_hi[..k], &wk.l_lo[..k], &wk.l_hi[..k]);
        for (i, sigma) in wk.sigma.iter_mut().enumerate() {
            *sigma = l_lo[i].component_div(&t_lo[i]) + l_hi[i].component_div(&t_hi[i]);
        }
    }

    /// The total complementarity `Σ t·μ` after a step of `alpha` along the
    /// current direction.
    fn affine_gap(wk: &Work, alpha: f64) -> f64 {
        let k = wk.t_lo.len();
        let (t_lo, t_hi, l_lo, l_hi) = (&wk.t_lo[..k], &wk.t_hi[..k], &wk.l_lo[..k], &wk.l_hi[..k]);
        let (dt_lo, dt_hi, dl_lo, dl_hi) = (&wk.dt_lo[..k], &wk.dt_hi[..k], &wk.dl_lo[..k], &wk.dl_hi[..k]);
        let mut gap = 0.0;
        for i in 0..k {
            gap += (t_lo[i] + alpha * dt_lo[i]).dot(&(l_lo[i] + alpha * dl_lo[i]))
                + (t_hi[i] + alpha * dt_hi[i]).dot(&(l_hi[i] + alpha * dl_hi[i]));
        }
        gap
    }

    /// Moves the iterate a step of `alpha` along the current direction.
    fn take_step(wk: &mut Work, alpha: f64) {
        fn axpy<T: Copy + std::ops::AddAssign>(x: &mut [T], d: &[T], alpha: f64)
        where
            f64: std::ops::Mul<T, Output = T>,
        {
            for (x, d) in x.iter_mut().zip(d) {
                *x += alpha * *d;
            }
        }
        axpy(&mut wk.x, &wk.dx, alpha);
        axpy(&mut wk.y, &wk.dy, alpha);
        axpy(&mut wk.t_lo, &wk.dt_lo, alpha);
        axpy(&mut wk.t_hi, &wk.dt_hi, alpha);
        axpy(&mut wk.l_lo, &wk.dl_lo, alpha);
        axpy(&mut wk.l_hi, &wk.dl_hi, alpha);
    }

    /// Packs the converged iterate into a [`QpSolution`].
    fn finish(&self, qp: &StageQp, wk: &Work, iterations: usize) -> QpSolution {
        let w: Vec<Vector2<f64>> = wk.x.iter().map(wpart).collect();
        let z: Vec<Vector3<f64>> = wk.x.iter().map(zpart).collect();
        QpSolution {
            objective: qp.objective(&w, &z),
            iterations,
            active_bounds: qp.count_active_bounds(&w, &z, ACTIVE_BOUND_TOL),
            dynamics_duals: Some(wk.y.clone()),
            w,
            z,
        }
    }
}
