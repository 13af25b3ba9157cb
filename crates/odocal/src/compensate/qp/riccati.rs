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

/// Options of [`StructuredSolver`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct StructuredOptions {
    /// Relative tolerance on the primal residuals (dynamics and slack
    /// definitions), scaled by `1 + max|c_k|, |bounds|`. Default 1e-9.
    pub tol_primal: f64,
    /// Relative tolerance on the dual (stationarity) residual, scaled by
    /// `1 + max|∇f|` separately over inputs and states (input gradients
    /// carry R = 1000 and would otherwise swamp the states'). Default 1e-9.
    pub tol_dual: f64,
    /// Relative tolerance on the total complementarity `Σ t·μ`, scaled by
    /// `max(1, f)`; it bounds the objective error, and at 1e-12 puts
    /// iterates within ~1e-9 (m, rad, rev/s) of active bounds' optimum, for
    /// about one extra iteration over 1e-10. Default 1e-12.
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
            tol_primal: 1e-9,
            tol_dual: 1e-9,
            tol_gap: 1e-12,
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
pub struct StructuredSolver {
    /// Tolerances, limits and warm-start settings.
    pub options: StructuredOptions,
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
    /// Affine directions kept for the corrector term.
    aff_t_lo: Vec<V5>,
    aff_t_hi: Vec<V5>,
    aff_l_lo: Vec<V5>,
    aff_l_hi: Vec<V5>,
    /// Riccati factors: P_{i+1}, H_uu⁻¹, H_us, feed-forward.
    p_next: Vec<Matrix5<f64>>,
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
            aff_t_lo: v5(),
            aff_t_hi: v5(),
            aff_l_lo: v5(),
            aff_l_hi: v5(),
            p_next: vec![Matrix5::zeros(); k],
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
        let r2 = 2.0 * qp.r;
        for i in 0..k {
            let gz = 2.0 * qp.q.component_mul(&zpart(&x[i]));
            out[i] = pack(&Vector2::zeros(), &gz);
        }
        for i in 1..k {
            let d = r2.component_mul(&(wpart(&x[i]) - wpart(&x[i - 1]) + qp.delta[i - 1]));
            out[i][0] += d[0];
            out[i][1] += d[1];
            out[i - 1][0] -= d[0];
            out[i - 1][1] -= d[1];
        }
    }

    /// Fills r_d, r_p, r_lo, r_hi and returns their norms.
    fn residuals(qp: &StageQp, wk: &mut Work) -> Residuals {
        let k = qp.stages();
        Self::gradient(qp, &wk.x, &mut wk.r_d);
        let mut grad_scale: f64 = 0.0;
        let mut grad_scale_z: f64 = 0.0;
        let mut objective = 0.0;
        for i in 0..k {
            grad_scale = grad_scale.max(wpart(&wk.r_d[i]).amax());
            grad_scale_z = grad_scale_z.max(zpart(&wk.r_d[i]).amax());
            let z = zpart(&wk.x[i]);
            objective += z.component_mul(&z).dot(&qp.q);
            if i > 0 {
                let d = wpart(&wk.x[i]) - wpart(&wk.x[i - 1]) + qp.delta[i - 1];
                objective += d.component_mul(&d).dot(&qp.r);
            }
        }
        let mut primal: f64 = 0.0;
        let mut dual: f64 = 0.0;
        let mut dual_z: f64 = 0.0;
        let mut gap = 0.0;
        let mut zprev = Vector3::zeros();
        for i in 0..k {
            let w = wpart(&wk.x[i]);
            let z = zpart(&wk.x[i]);
            // Gᵀy: z_{i+1} gets y_{i+1} − A_{i+2}ᵀ y_{i+2}; w_i gets −B_{i+1}ᵀ y_{i+1}.
            let mut gy_z = wk.y[i];
            if i + 1 < k {
                gy_z -= qp.a[i + 1].transpose() * wk.y[i + 1];
            }
            let gy_w = -(qp.b[i].transpose() * wk.y[i]);
            wk.r_d[i] += pack(&gy_w, &gy_z) - wk.l_lo[i] + wk.l_hi[i];
            // A pinned variable's stationarity is absorbed by the multiplier
            // of its equality `x = v`.
            wk.r_d[i].component_mul_assign(&wk.free[i]);
            dual = dual.max(wpart(&wk.r_d[i]).amax());
            dual_z = dual_z.max(zpart(&wk.r_d[i]).amax());
            wk.r_p[i] = z - qp.a[i] * zprev - qp.b[i] * w - qp.c[i];
            zprev = z;
            wk.r_lo[i] = (wk.x[i] - wk.lo[i] - wk.t_lo[i]).component_mul(&wk.free[i]);
            wk.r_hi[i] = (wk.hi[i] - wk.x[i] - wk.t_hi[i]).component_mul(&wk.free[i]);
            primal = primal.max(wk.r_p[i].amax()).max(wk.r_lo[i].amax()).max(wk.r_hi[i].amax());
            gap += wk.t_lo[i].dot(&wk.l_lo[i]) + wk.t_hi[i].dot(&wk.l_hi[i]);
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
        let mut p = Matrix5::zeros();
        p.fixed_view_mut::<3, 3>(0, 0).copy_from(&(q2 + Matrix3::from_diagonal(&zpart(&wk.sigma[k - 1]))));
        for i in (0..k).rev() {
            wk.p_next[i] = p;
            let p11: Matrix3<f64> = p.fixed_view::<3, 3>(0, 0).into_owned();
            let p12: Matrix3x2<f64> = p.fixed_view::<3, 2>(0, 3).into_owned();
            let p22: Matrix2<f64> = p.fixed_view::<2, 2>(3, 3).into_owned();
            let a = &qp.a[i];
            let b = &qp.b[i];
            let g = p11 * b + p12;
            let mut huu = b.transpose() * g + p12.transpose() * b + p22 + Matrix2::from_diagonal(&wpart(&wk.sigma[i]));
            if i > 0 {
                huu += r2;
            }
            // Closed-form inverse of the symmetric 2×2 H_uu; positive
            // definiteness checked on the leading minors. A pinned input is
            // no decision variable: H_uu is inverted on the free inputs only
            // and padded with zeros, so its step (and feedback) is 0.
            let huu_inv = match (wk.free[i][0] > 0.0, wk.free[i][1] > 0.0) {
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
            wk.huu_inv[i] = huu_inv;
            if i == 0 {
                break; // s_0 = 0: P_0 is never used.
            }
            let mut hus = SMatrix::<f64, 2, 5>::zeros();
            hus.fixed_view_mut::<2, 3>(0, 0).copy_from(&(g.transpose() * a));
            hus.fixed_view_mut::<2, 2>(0, 3).copy_from(&(-r2));
            wk.hus[i] = hus;
            // P_i = blockdiag(2Q + Σ_z + AᵀP11A, 2R) − H_usᵀ H_uu⁻¹ H_us.
            let mut pn = Matrix5::zeros();
            pn.fixed_view_mut::<3, 3>(0, 0)
                .copy_from(&(q2 + Matrix3::from_diagonal(&zpart(&wk.sigma[i - 1])) + a.transpose() * p11 * a));
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
        // Backward vector pass: cost-to-go gradient p.
        let mut p = V5::zeros();
        p.fixed_rows_mut::<3>(0).copy_from(&zpart(&wk.rt[k - 1]));
        for i in (0..k).rev() {
            let pm = &wk.p_next[i];
            let chat = -wk.r_p[i];
            let e1 = pm.fixed_view::<3, 3>(0, 0) * chat + p.fixed_rows::<3>(0);
            let e2 = pm.fixed_view::<3, 2>(0, 3).transpose() * chat + p.fixed_rows::<2>(3);
            let hu = wpart(&wk.rt[i]) + qp.b[i].transpose() * e1 + e2;
            let kff = -(wk.huu_inv[i] * hu);
            wk.kff[i] = kff;
            if i == 0 {
                break;
            }
            let hs_z = zpart(&wk.rt[i - 1]) + qp.a[i].transpose() * e1;
            let mut pn = V5::zeros();
            pn.fixed_rows_mut::<3>(0).copy_from(&hs_z);
            p = pn + wk.hus[i].transpose() * kff;
        }
        // Forward rollout: u_i = −H_uu⁻¹ H_us s_i + kff_i.
        let mut s = V5::zeros();
        for i in 0..k {
            let u = if i == 0 { wk.kff[0] } else { wk.kff[i] - wk.huu_inv[i] * (wk.hus[i] * s) };
            let dz = qp.a[i] * s.fixed_rows::<3>(0) + qp.b[i] * u - wk.r_p[i];
            wk.dx[i] = pack(&u, &dz);
            s = V5::new(dz[0], dz[1], dz[2], u[0], u[1]);
        }
    }

    /// Sets `rt` from the complementarity targets `rc_lo`, `rc_hi`
    /// (given per element by the closure), solves for `dx`, and recovers
    /// `dt`, `dl`.
    fn newton_direction(qp: &StageQp, wk: &mut Work, rc: impl Fn(&Work, usize) -> (V5, V5)) {
        let k = qp.stages();
        for i in 0..k {
            let (rc_lo, rc_hi) = rc(wk, i);
            let a = (rc_lo + wk.l_lo[i].component_mul(&wk.r_lo[i])).component_div(&wk.t_lo[i]);
            let b = (rc_hi + wk.l_hi[i].component_mul(&wk.r_hi[i])).component_div(&wk.t_hi[i]);
            wk.rt[i] = wk.r_d[i] + a - b;
        }
        Self::solve_lq(qp, wk);
        for i in 0..k {
            let (rc_lo, rc_hi) = rc(wk, i);
            let dx = wk.dx[i];
            wk.dt_lo[i] = dx + wk.r_lo[i];
            wk.dt_hi[i] = wk.r_hi[i] - dx;
            // Pinned variables keep slacks and (zero) multipliers unchanged.
            let f = &wk.free[i];
            wk.dl_lo[i] = -(rc_lo + wk.l_lo[i].component_mul(&wk.dt_lo[i])).component_div(&wk.t_lo[i]).component_mul(f);
            wk.dl_hi[i] = -(rc_hi + wk.l_hi[i].component_mul(&wk.dt_hi[i])).component_div(&wk.t_hi[i]).component_mul(f);
        }
    }

    /// Largest α ≤ 1 keeping all slacks and multipliers non-negative.
    ///
    /// Branch-free: with every `a > 0`, `α_max = 1 / max(1, max(−d/a))`.
    fn max_step(wk: &Work) -> f64 {
        fn worst(v: &[V5], dv: &[V5]) -> f64 {
            let mut m = [0.0f64; 5];
            for (a, d) in v.iter().zip(dv) {
                for j in 0..5 {
                    m[j] = m[j].max(-d[j] / a[j]);
                }
            }
            m.iter().fold(0.0f64, |x, &y| x.max(y))
        }
        let r = worst(&wk.t_lo, &wk.dt_lo)
            .max(worst(&wk.t_hi, &wk.dt_hi))
            .max(worst(&wk.l_lo, &wk.dl_lo))
            .max(worst(&wk.l_hi, &wk.dl_hi));
        1.0 / r.max(1.0)
    }

    /// Multiplier step from stationarity in z (backward recursion):
    /// `Δy_k = −(2Q + Σ_z)Δz_k − r̃_z,k + A_{k+1}ᵀ Δy_{k+1}`.
    fn dual_direction(qp: &StageQp, wk: &mut Work) {
        let k = qp.stages();
        let mut next = Vector3::zeros();
        for i in (0..k).rev() {
            let dz = zpart(&wk.dx[i]);
            let h = (2.0 * qp.q + zpart(&wk.sigma[i])).component_mul(&dz);
            let mut dy = -h - zpart(&wk.rt[i]);
            if i + 1 < k {
                dy += qp.a[i + 1].transpose() * next;
            }
            wk.dy[i] = dy;
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

            for i in 0..k {
                wk.sigma[i] = wk.l_lo[i].component_div(&wk.t_lo[i]) + wk.l_hi[i].component_div(&wk.t_hi[i]);
            }
            Self::factorize(qp, wk)?;

            // Predictor (affine scaling): target t·μ = 0.
            Self::newton_direction(qp, wk, |w, i| {
                (w.t_lo[i].component_mul(&w.l_lo[i]), w.t_hi[i].component_mul(&w.l_hi[i]))
            });
            let alpha_aff = Self::max_step(wk);
            let mut gap_aff = 0.0;
            for i in 0..k {
                gap_aff += (wk.t_lo[i] + alpha_aff * wk.dt_lo[i]).dot(&(wk.l_lo[i] + alpha_aff * wk.dl_lo[i]))
                    + (wk.t_hi[i] + alpha_aff * wk.dt_hi[i]).dot(&(wk.l_hi[i] + alpha_aff * wk.dl_hi[i]));
            }
            let sigma_c = (gap_aff / res.gap).clamp(0.0, 1.0).powi(3);
            let target = sigma_c * res.mu;
            std::mem::swap(&mut wk.aff_t_lo, &mut wk.dt_lo);
            std::mem::swap(&mut wk.aff_t_hi, &mut wk.dt_hi);
            std::mem::swap(&mut wk.aff_l_lo, &mut wk.dl_lo);
            std::mem::swap(&mut wk.aff_l_hi, &mut wk.dl_hi);

            // Corrector: target t·μ = σμ, with the second-order term.
            Self::newton_direction(qp, wk, |w, i| {
                (
                    w.t_lo[i].component_mul(&w.l_lo[i]) + w.aff_t_lo[i].component_mul(&w.aff_l_lo[i])
                        - V5::repeat(target),
                    w.t_hi[i].component_mul(&w.l_hi[i]) + w.aff_t_hi[i].component_mul(&w.aff_l_hi[i])
                        - V5::repeat(target),
                )
            });
            Self::dual_direction(qp, wk);
            let alpha = (opt.step_fraction * Self::max_step(wk)).min(1.0);
            for i in 0..k {
                wk.x[i] += alpha * wk.dx[i];
                wk.y[i] += alpha * wk.dy[i];
                wk.t_lo[i] += alpha * wk.dt_lo[i];
                wk.t_hi[i] += alpha * wk.dt_hi[i];
                wk.l_lo[i] += alpha * wk.dl_lo[i];
                wk.l_hi[i] += alpha * wk.dl_hi[i];
            }
        }
        Err(QpError::MaxIterations { iterations: opt.max_iterations, residual: last_residual })
    }
}

impl StructuredSolver {
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
