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
//!   forward rollout, with no heap traffic (per-thread buffers, one record
//!   per stage); the products are written out for the model's step
//!   Jacobian, the identity but for its heading column ([`StageQp::a`]),
//!   and the diagonal `Q`, `R` and Σ;
//! - the Mehrotra corrector reuses the factorisation (only the vector pass
//!   is repeated); the factorisation runs in one backward pass with the
//!   predictor's vector pass.
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
//! complementarity are all below [`StructuredOptions`]' tolerances, or when
//! the dynamics multipliers certify that the problem has no feasible point.
//!
//! ## References
//! - C. V. Rao, S. J. Wright, J. B. Rawlings, "Application of interior-point
//!   methods to model predictive control", JOTA 99 (1998) 723–757.
//! - G. Frison, M. Diehl, "HPIPM: a high-performance quadratic programming
//!   framework for model predictive control", IFAC-PapersOnLine 2020.
//! - S. Mehrotra, "On the implementation of a primal-dual interior point
//!   method", SIAM J. Optim. 2 (1992) 575–601.

use nalgebra::{Vector2, Vector3};

use super::{QpError, QpSolution, QpSolver, StageQp};

mod stage;
use stage::{
    a_mul, at_mul, bt_mul, factor_stage, rollout_stage, stage_ab, vector_stage, CostToGo, StageFactor, S2, S3, S5,
};

/// Options of the structured solver ([`SolverKind::Structured`](super::SolverKind::Structured)).
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub(crate) struct StructuredOptions {
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
/// On an infeasible problem it returns `QpError::Infeasible` when its
/// dynamics multipliers certify the infeasibility (a Farkas certificate,
/// looked for from the fourth iteration while the primal residual has not
/// converged) or a bound multiplier diverges while the primal residual
/// stalls; on
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

/// Relative margin of the infeasibility certificate
/// (`StructuredSolver::farkas_certificate`): the sums it compares carry a
/// rounding error below 1e-12 of their magnitude on QPs of 10⁴ stages.
const INFEASIBILITY_MARGIN: f64 = 1e-9;

/// The first iteration at which a solve that has not reached primal
/// feasibility looks for an infeasibility certificate.
const CERTIFICATE_FROM_ITERATION: usize = 4;

/// The mask of free variables of stage `s` ([`Stage::free`]); all ones
/// when no variable of the problem is `PINNED`, so that the products with
/// it fold away.
#[inline(always)]
fn free<const PINNED: bool>(s: &Stage) -> S5 {
    if PINNED {
        s.free
    } else {
        [1.0; 5]
    }
}

/// Raises `m` to `r` when `r` is larger (a NaN ratio is skipped).
#[inline(always)]
fn raise(m: &mut f64, r: f64) {
    if r > *m {
        *m = r;
    }
}

/// Buffers of one solve, allocated once per thread and size.
/// Everything the iteration keeps for one stage, side by side: every pass
/// walks the stages in order and reads or writes most of these.
#[derive(Debug, Clone, Copy, Default)]
struct Stage {
    /// 1 for a variable of the interior-point iteration, 0 for one pinned
    /// by a zero-width box (see [`StructuredOptions::fixed_width`]).
    free: S5,
    /// Primal iterate.
    x: S5,
    lo: S5,
    hi: S5,
    t_lo: S5,
    t_hi: S5,
    l_lo: S5,
    l_hi: S5,
    /// Dynamics multiplier λ_{i+1}.
    y: S3,
    /// Dual residual ∇f + Gᵀy − μ_lo + μ_hi.
    r_d: S5,
    /// Dynamics residual of z_{i+1}.
    r_p: S3,
    /// `x − lo − t_lo`, `hi − x − t_hi`.
    r_lo: S5,
    r_hi: S5,
    /// `1/t_lo`, `1/t_hi` of the current iterate.
    inv_t_lo: S5,
    inv_t_hi: S5,
    /// State part of the barrier Hessian diagonal `Σ = μ_lo/t_lo + μ_hi/t_hi`.
    sigma_z: S3,
    /// Reduced linear term r̃_d of the Newton LQ problem (predictor, then corrector).
    rt: S5,
    /// The affine step's `Δt·Δμ`, for the corrector's complementarity targets.
    prod_lo: S5,
    prod_hi: S5,
    /// Riccati factors and feed-forward term.
    factor: StageFactor,
    kff: S2,
    /// The corrector's Newton direction.
    dx: S5,
    dt_lo: S5,
    dt_hi: S5,
    dl_lo: S5,
    dl_hi: S5,
}

/// Buffers of one solve, allocated once per thread and size.
struct Work {
    st: Vec<Stage>,
    /// Number of free variables (each has two bounds).
    n_free: usize,
}

impl Work {
    fn new(k: usize) -> Self {
        Self { st: vec![Stage { t_lo: [1.0; 5], t_hi: [1.0; 5], ..Stage::default() }; k], n_free: 5 * k }
    }
}

/// Norms of the current residuals.
#[derive(Debug, Clone, Copy, Default)]
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
    /// Fills r_d, r_p, r_lo, r_hi and returns their norms, in one pass.
    #[inline(always)]
    fn residuals<const PINNED: bool>(qp: &StageQp, wk: &mut Work) -> Residuals {
        let k = qp.stages();
        let (q, r) = (&qp.q.data.0[0], &qp.r.data.0[0]);
        let (q2, r2) = ([2.0 * q[0], 2.0 * q[1], 2.0 * q[2]], [2.0 * r[0], 2.0 * r[1]]);
        let (delta, c, st) = (&qp.delta[..k - 1], &qp.c[..k], &mut wk.st[..k]);
        let mut res = Residuals::default();
        let mut zprev = [0.0; 3];
        // The input-rate difference w_i − w_{i−1} + δ_i (0 for i = 0).
        let mut d = [0.0; 2];
        for i in 0..k {
            let (d_next, ay) = if i + 1 < k {
                let (wn, yn) = (&st[i + 1].x, &st[i + 1].y);
                let xi = &st[i].x;
                ([wn[0] - xi[0] + delta[i].x, wn[1] - xi[1] + delta[i].y], at_mul(stage_ab(qp, i + 1).0, yn))
            } else {
                ([0.0; 2], [0.0; 3])
            };
            let s = &mut st[i];
            let xi = s.x;
            let mut grad = [0.0; 5];
            for j in 0..2 {
                grad[j] = (0.0 + r2[j] * d[j]) - r2[j] * d_next[j];
                raise(&mut res.grad_scale, grad[j].abs());
            }
            for j in 0..3 {
                grad[2 + j] = q2[j] * xi[2 + j];
                raise(&mut res.grad_scale_z, grad[2 + j].abs());
            }
            res.objective += xi[2] * xi[2] * q[0] + xi[3] * xi[3] * q[1] + xi[4] * xi[4] * q[2];
            if i > 0 {
                res.objective += d[0] * d[0] * r[0] + d[1] * d[1] * r[1];
            }
            d = d_next;
            // Gᵀy: z_{i+1} gets y_{i+1} − A_{i+2}ᵀ y_{i+2}; w_i gets −B_{i+1}ᵀ y_{i+1}.
            let (a, b) = stage_ab(qp, i);
            let btl = bt_mul(b, &s.y);
            let gy = [-btl[0], -btl[1], s.y[0] - ay[0], s.y[1] - ay[1], s.y[2] - ay[2]];
            // A pinned variable's stationarity is absorbed by the multiplier
            // of its equality `x = v`.
            let mut primal = res.primal;
            for j in 0..5 {
                let f = free::<PINNED>(s)[j];
                s.r_d[j] = (grad[j] + gy[j] - s.l_lo[j] + s.l_hi[j]) * f;
                s.r_lo[j] = (xi[j] - s.lo[j] - s.t_lo[j]) * f;
                s.r_hi[j] = (s.hi[j] - xi[j] - s.t_hi[j]) * f;
                raise(&mut primal, s.r_lo[j].abs());
                raise(&mut primal, s.r_hi[j].abs());
                res.gap += s.t_lo[j] * s.l_lo[j] + s.t_hi[j] * s.l_hi[j];
            }
            raise(&mut res.dual, s.r_d[0].abs());
            raise(&mut res.dual, s.r_d[1].abs());
            raise(&mut res.dual_z, s.r_d[2].abs());
            raise(&mut res.dual_z, s.r_d[3].abs());
            raise(&mut res.dual_z, s.r_d[4].abs());
            let z = [xi[2], xi[3], xi[4]];
            let az = a_mul(a, &zprev);
            let bw = [
                b[0][0] * xi[0] + b[1][0] * xi[1],
                b[0][1] * xi[0] + b[1][1] * xi[1],
                b[0][2] * xi[0] + b[1][2] * xi[1],
            ];
            for j in 0..3 {
                s.r_p[j] = z[j] - az[j] - bw[j] - c[i][j];
                raise(&mut primal, s.r_p[j].abs());
            }
            res.primal = primal;
            zprev = z;
        }
        res.mu = if wk.n_free > 0 { res.gap / (2 * wk.n_free) as f64 } else { 0.0 };
        res
    }

    /// The largest bound multiplier.
    #[inline(always)]
    fn max_multiplier(wk: &Work) -> f64 {
        let mut m = 0.0;
        for s in &wk.st {
            for j in 0..5 {
                raise(&mut m, s.l_lo[j]);
                raise(&mut m, s.l_hi[j]);
            }
        }
        m
    }

    /// Whether the current dynamics multipliers `y` certify that no point
    /// of the boxes satisfies the dynamics (Farkas): every such point has
    /// `vᵀx = yᵀc` for `v = Gᵀy` (`Gx = c` the dynamics), so a `yᵀc` outside
    /// the range of `vᵀx` over the boxes proves infeasibility. The margin,
    /// `INFEASIBILITY_MARGIN` times the sums' magnitude, is far above their
    /// rounding error, so a feasible problem is never certified whatever
    /// the iterate.
    #[inline(always)]
    fn farkas_certificate(qp: &StageQp, wk: &Work) -> Option<f64> {
        let k = qp.stages();
        let st = &wk.st[..k];
        let (mut yc, mut lo_sum, mut hi_sum, mut scale) = (0.0, 0.0, 0.0, 0.0);
        for i in 0..k {
            let y = &st[i].y;
            let ay = if i + 1 < k { at_mul(stage_ab(qp, i + 1).0, &st[i + 1].y) } else { [0.0; 3] };
            let btl = bt_mul(stage_ab(qp, i).1, y);
            let v = [-btl[0], -btl[1], y[0] - ay[0], y[1] - ay[1], y[2] - ay[2]];
            let (wl, wh, zl, zh) = (&qp.w_lo[i], &qp.w_hi[i], &qp.z_lo[i], &qp.z_hi[i]);
            let lo = [wl[0], wl[1], zl[0], zl[1], zl[2]];
            let hi = [wh[0], wh[1], zh[0], zh[1], zh[2]];
            for j in 0..5 {
                let (a, b) = (v[j] * lo[j], v[j] * hi[j]);
                lo_sum += a.min(b);
                hi_sum += a.max(b);
                scale += a.abs().max(b.abs());
            }
            for r in 0..3 {
                let t = y[r] * qp.c[i][r];
                yc += t;
                scale += t.abs();
            }
        }
        let margin = INFEASIBILITY_MARGIN * scale;
        let gap = (lo_sum - yc).max(yc - hi_sum);
        (gap > margin && scale.is_finite()).then_some(gap / scale)
    }

    /// Backward pass: the Riccati factorisation of the Newton LQ problem for
    /// the current Σ (shared by predictor and corrector), fused with the
    /// predictor's vector pass (complementarity target `t·μ`, so
    /// `r̃_d = r_d + μ_lo + Σ_lo r_lo − μ_hi − Σ_hi r_hi`).
    #[inline(always)]
    fn factorize_predict<const PINNED: bool>(qp: &StageQp, wk: &mut Work) -> Result<(), QpError> {
        let k = qp.stages();
        let (q2, r2) = (2.0 * qp.q, 2.0 * qp.r);
        let (q2, r2) = (&q2.data.0[0], &r2.data.0[0]);
        let st = &mut wk.st[..k];
        let mut ctg = CostToGo::default();
        let (mut pz, mut pw) = ([0.0; 3], [0.0; 2]);
        for i in (0..k).rev() {
            let s = &mut st[i];
            let mut sigma = [0.0; 5];
            for j in 0..5 {
                let (a, b) = (1.0 / s.t_lo[j], 1.0 / s.t_hi[j]);
                let (s_lo, s_hi) = (s.l_lo[j] * a, s.l_hi[j] * b);
                sigma[j] = s_lo + s_hi;
                s.rt[j] = s.r_d[j] + s.l_lo[j] + s_lo * s.r_lo[j] - s.l_hi[j] - s_hi * s.r_hi[j];
                s.inv_t_lo[j] = a;
                s.inv_t_hi[j] = b;
            }
            s.sigma_z = [sigma[2], sigma[3], sigma[4]];
            let ab = stage_ab(qp, i);
            ctg = factor_stage(i, &ctg, (q2, r2), &sigma, &free::<PINNED>(s), ab, &mut s.factor)?;
            s.kff = vector_stage(&s.factor, &s.rt, &s.r_p, ab, r2, (&mut pz, &mut pw));
        }
        Ok(())
    }

    /// Forward pass of the predictor: rolls out the affine direction, keeps
    /// its `Δt·Δμ`, and returns the complementarity `Σ (t + αΔt)(μ + αΔμ)`
    /// after the largest step `α ≤ 1` that keeps slacks and multipliers
    /// non-negative.
    ///
    /// With the affine target, `Δμ = −μ (1 + ρ)` for `ρ = Δt/t`: the slack
    /// limits α by `−ρ`, the multiplier by `1 + ρ`, and
    /// `Σ (t Δμ + μ Δt) = −Σ t μ = −gap`, so the complementarity after the
    /// step is `(1 − α) gap + α² Σ Δt Δμ`.
    #[inline(always)]
    fn predict_forward<const PINNED: bool>(qp: &StageQp, wk: &mut Work, gap: f64) -> f64 {
        let k = qp.stages();
        let r2 = 2.0 * qp.r;
        let r2 = &r2.data.0[0];
        let st = &mut wk.st[..k];
        let (mut m, mut s2) = (1.0f64, 0.0);
        let (mut sz, mut sw) = ([0.0; 3], [0.0; 2]);
        for i in 0..k {
            let s = &mut st[i];
            let dx = rollout_stage(i, &s.factor, &s.kff, stage_ab(qp, i), r2, &s.r_p, (&sz, &sw));
            for j in 0..5 {
                let (dtl, dth) = (dx[j] + s.r_lo[j], s.r_hi[j] - dx[j]);
                let (rho_lo, rho_hi) = (dtl * s.inv_t_lo[j], dth * s.inv_t_hi[j]);
                let f = free::<PINNED>(s)[j];
                let (f_lo, f_hi) = ((1.0 + rho_lo) * f, (1.0 + rho_hi) * f);
                raise(&mut m, -rho_lo);
                raise(&mut m, -rho_hi);
                raise(&mut m, f_lo);
                raise(&mut m, f_hi);
                s.prod_lo[j] = -(dtl * s.l_lo[j] * f_lo);
                s.prod_hi[j] = -(dth * s.l_hi[j] * f_hi);
                s2 += s.prod_lo[j] + s.prod_hi[j];
            }
            sz = [dx[2], dx[3], dx[4]];
            sw = [dx[0], dx[1]];
        }
        let alpha = 1.0 / m;
        (1.0 - alpha) * gap + alpha * alpha * s2
    }

    /// Backward vector pass of the corrector: complementarity target
    /// `t·μ + Δt_aff·Δμ_aff − σμ` (`target` = σμ).
    #[inline(always)]
    fn correct_backward(qp: &StageQp, wk: &mut Work, target: f64) {
        let k = qp.stages();
        let r2 = 2.0 * qp.r;
        let r2 = &r2.data.0[0];
        let st = &mut wk.st[..k];
        let (mut pz, mut pw) = ([0.0; 3], [0.0; 2]);
        for i in (0..k).rev() {
            let s = &mut st[i];
            for j in 0..5 {
                s.rt[j] += (s.prod_lo[j] - target) * s.inv_t_lo[j] - (s.prod_hi[j] - target) * s.inv_t_hi[j];
            }
            s.kff = vector_stage(&s.factor, &s.rt, &s.r_p, stage_ab(qp, i), r2, (&mut pz, &mut pw));
        }
    }

    /// Forward pass of the corrector: rolls out the direction, recovers
    /// `Δt`, `Δμ` and returns the largest step `α ≤ 1` keeping slacks and
    /// multipliers non-negative.
    #[inline(always)]
    fn correct_forward<const PINNED: bool>(qp: &StageQp, wk: &mut Work, target: f64) -> f64 {
        let k = qp.stages();
        let r2 = 2.0 * qp.r;
        let r2 = &r2.data.0[0];
        let st = &mut wk.st[..k];
        let mut m = 1.0f64;
        let (mut sz, mut sw) = ([0.0; 3], [0.0; 2]);
        for i in 0..k {
            let s = &mut st[i];
            let dx = rollout_stage(i, &s.factor, &s.kff, stage_ab(qp, i), r2, &s.r_p, (&sz, &sw));
            for j in 0..5 {
                let (dtl, dth) = (dx[j] + s.r_lo[j], s.r_hi[j] - dx[j]);
                let (ll, lh) = (s.l_lo[j], s.l_hi[j]);
                // Pinned variables keep slacks and (zero) multipliers unchanged.
                let f = free::<PINNED>(s)[j];
                let dll = -(ll + (s.prod_lo[j] - target + ll * dtl) * s.inv_t_lo[j]) * f;
                let dlh = -(lh + (s.prod_hi[j] - target + lh * dth) * s.inv_t_hi[j]) * f;
                raise(&mut m, -dtl * s.inv_t_lo[j]);
                raise(&mut m, -dth * s.inv_t_hi[j]);
                raise(&mut m, -dll / ll);
                raise(&mut m, -dlh / lh);
                (s.dt_lo[j], s.dt_hi[j], s.dl_lo[j], s.dl_hi[j]) = (dtl, dth, dll, dlh);
            }
            s.dx = dx;
            sz = [dx[2], dx[3], dx[4]];
            sw = [dx[0], dx[1]];
        }
        1.0 / m
    }

    /// Backward pass: the multiplier step from stationarity in z,
    /// `Δy_k = −(2Q + Σ_z)Δz_k − r̃_z,k + A_{k+1}ᵀ Δy_{k+1}`, and the step of
    /// `alpha` along the whole direction.
    #[inline(always)]
    fn take_step(qp: &StageQp, wk: &mut Work, alpha: f64) {
        let k = qp.stages();
        let q2 = 2.0 * qp.q;
        let st = &mut wk.st[..k];
        let mut next = [0.0; 3];
        for i in (0..k).rev() {
            let an = if i + 1 < k { at_mul(stage_ab(qp, i + 1).0, &next) } else { [0.0; 3] };
            let s = &mut st[i];
            let mut dy = [0.0; 3];
            for r in 0..3 {
                dy[r] = -(q2[r] + s.sigma_z[r]) * s.dx[2 + r] - s.rt[2 + r] + an[r];
                s.y[r] += alpha * dy[r];
            }
            for j in 0..5 {
                s.x[j] += alpha * s.dx[j];
                s.t_lo[j] += alpha * s.dt_lo[j];
                s.t_hi[j] += alpha * s.dt_hi[j];
                s.l_lo[j] += alpha * s.dl_lo[j];
                s.l_hi[j] += alpha * s.dl_hi[j];
            }
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
        for (i, s) in wk.st[..k].iter_mut().enumerate() {
            let (wl, wh, zl, zh) = (&qp.w_lo[i], &qp.w_hi[i], &qp.z_lo[i], &qp.z_hi[i]);
            s.lo = [wl[0], wl[1], zl[0], zl[1], zl[2]];
            s.hi = [wh[0], wh[1], zh[0], zh[1], zh[2]];
            for j in 0..5 {
                let fixed = s.hi[j] - s.lo[j] <= tol;
                if fixed && j >= 2 {
                    return Err(QpError::Numerical(format!(
                        "zero-width state box at stage {i}, component {}: pinned states are not supported by \
                         the structured solver (use Clarabel)",
                        j - 2
                    )));
                }
                s.free[j] = if fixed { 0.0 } else { 1.0 };
                wk.n_free -= usize::from(fixed);
            }
        }
        Ok(())
    }

    /// Puts pinned variables at their box midpoint `v` with a unit fake box
    /// `[v − 1, v + 1]`, unit slacks and zero multipliers: their slack
    /// residuals are 0 and stay so, and they add nothing to the gap.
    fn pin_fixed(wk: &mut Work) {
        for s in &mut wk.st {
            for j in 0..5 {
                if s.free[j] == 0.0 {
                    let v = 0.5 * (s.lo[j] + s.hi[j]);
                    s.x[j] = v;
                    s.lo[j] = v - 1.0;
                    s.hi[j] = v + 1.0;
                    s.t_lo[j] = 1.0;
                    s.t_hi[j] = 1.0;
                    s.l_lo[j] = 0.0;
                    s.l_hi[j] = 0.0;
                }
            }
        }
    }

    /// Warm starting point: the previous solution moved into the interior
    /// of the boxes, its dynamics duals, and bound multipliers recovered
    /// from stationarity there.
    fn initialize_warm(&self, qp: &StageQp, wk: &mut Work, sol: &QpSolution) {
        let k = qp.stages();
        let shift = self.options.warm_start_shift;
        let duals = sol.dynamics_duals.as_ref().filter(|l| l.len() == k);
        for (i, s) in wk.st[..k].iter_mut().enumerate() {
            let (w, z) = (&sol.w[i], &sol.z[i]);
            let x = [w[0], w[1], z[0], z[1], z[2]];
            for j in 0..5 {
                let m = shift * (s.hi[j] - s.lo[j]);
                s.x[j] = x[j].clamp(s.lo[j] + m, s.hi[j] - m);
            }
            s.y = duals.map_or([0.0; 3], |l| [l[i][0], l[i][1], l[i][2]]);
            // Bound multipliers recovered from stationarity at this point
            // (next): ν = ∇f + Gᵀy = μ_lo − μ_hi.
            s.l_lo = [0.0; 5];
            s.l_hi = [0.0; 5];
        }
        Self::residuals::<true>(qp, wk); // r_d = ν with zero bound multipliers
        let mu = self.options.warm_start_mu;
        for s in &mut wk.st[..k] {
            for j in 0..5 {
                let width = s.hi[j] - s.lo[j];
                let floor = (shift * width).max(f64::MIN_POSITIVE.sqrt());
                let t_lo = (s.x[j] - s.lo[j]).max(floor);
                let t_hi = (s.hi[j] - s.x[j]).max(floor);
                let nu = s.r_d[j];
                s.t_lo[j] = t_lo;
                s.t_hi[j] = t_hi;
                s.l_lo[j] = nu.max(0.0).max(mu / t_lo);
                s.l_hi[j] = (-nu).max(0.0).max(mu / t_hi);
            }
        }
    }

    /// Cold or warm starting point.
    fn initialize(&self, qp: &StageQp, wk: &mut Work, warm: Option<&QpSolution>) -> Result<(), QpError> {
        let k = qp.stages();
        self.mark_fixed(qp, wk)?;
        match warm.filter(|s| s.w.len() == k && s.z.len() == k) {
            Some(sol) => self.initialize_warm(qp, wk, sol),
            None => {
                // Inputs 0 (the measurements) pulled into their boxes, states
                // by rollout; slacks at least a quarter of the box width,
                // multipliers 1.
                let mut zprev = [0.0; 3];
                for (i, s) in wk.st[..k].iter_mut().enumerate() {
                    let mut w = [0.0; 2];
                    for j in 0..2 {
                        let (lo, hi) = (qp.w_lo[i][j], qp.w_hi[i][j]);
                        w[j] = if s.free[j] == 0.0 {
                            0.5 * (lo + hi)
                        } else {
                            0.0f64.clamp(lo + 0.25 * (hi - lo), hi - 0.25 * (hi - lo))
                        };
                    }
                    let (a, b) = stage_ab(qp, i);
                    let az = a_mul(a, &zprev);
                    let z = [0, 1, 2].map(|r| az[r] + (b[0][r] * w[0] + b[1][r] * w[1]) + qp.c[i][r]);
                    zprev = z;
                    s.x = [w[0], w[1], z[0], z[1], z[2]];
                    s.y = [0.0; 3];
                    for j in 0..5 {
                        let floor = (0.25 * (s.hi[j] - s.lo[j])).max(1e-8);
                        s.t_lo[j] = (s.x[j] - s.lo[j]).max(floor);
                        s.t_hi[j] = (s.hi[j] - s.x[j]).max(floor);
                    }
                    s.l_lo = [1.0; 5];
                    s.l_hi = [1.0; 5];
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
        let mut wk = WORK.with(|c| c.borrow_mut().take()).filter(|w| w.st.len() == k).unwrap_or_else(|| Work::new(k));
        let result = self.solve_dispatch(qp, warm_start, &mut wk);
        WORK.with(|c| *c.borrow_mut() = Some(wk));
        result
    }
}

/// Whether the solver's iteration runs the build compiled for AVX2
/// ([`StructuredSolver::solve_in_avx2`]): where the running CPU has AVX2
/// (x86-64), unless the environment variable `ODOCAL_SIMD=baseline` asks
/// for the build's baseline instruction set. Decided once per process.
///
/// Both compile the same Rust code, and Rust never contracts a multiply
/// and an add into a fused one on its own, so both give results identical
/// to the bit (test `avx2_build_equals_the_baseline_to_the_bit`); AVX2's
/// three-operand, four-wide instructions need fewer register copies.
fn use_avx2() -> bool {
    crate::simd::use_avx2(false)
}

impl StructuredSolver {
    /// [`StructuredSolver::solve_in`] in the build [`use_avx2`] picks.
    fn solve_dispatch(
        &self,
        qp: &StageQp,
        warm_start: Option<&QpSolution>,
        wk: &mut Work,
    ) -> Result<QpSolution, QpError> {
        #[cfg(target_arch = "x86_64")]
        if use_avx2() {
            // SAFETY: `use_avx2()` is true only when the running CPU reports
            // AVX2 (`is_x86_feature_detected!`), the feature
            // `solve_in_avx2` is compiled for.
            #[allow(unsafe_code)]
            return unsafe { self.solve_in_avx2(qp, warm_start, wk) };
        }
        self.solve_in(qp, warm_start, wk)
    }

    /// [`StructuredSolver::solve_in`] compiled for AVX2: it and every pass
    /// of the iteration are inlined (`#[inline(always)]`), so all of them
    /// are compiled for it.
    ///
    /// # Safety
    /// The running CPU must support AVX2.
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn solve_in_avx2(
        &self,
        qp: &StageQp,
        warm_start: Option<&QpSolution>,
        wk: &mut Work,
    ) -> Result<QpSolution, QpError> {
        self.solve_in(qp, warm_start, wk)
    }
}

thread_local! {
    /// Per-thread solver buffers, kept between solves.
    static WORK: std::cell::RefCell<Option<Work>> = const { std::cell::RefCell::new(None) };
}

impl StructuredSolver {
    #[inline(always)]
    fn solve_in(&self, qp: &StageQp, warm_start: Option<&QpSolution>, wk: &mut Work) -> Result<QpSolution, QpError> {
        let k = qp.stages();
        self.initialize(qp, wk, warm_start)?;

        let mut scale_p: f64 = 1.0;
        for (i, s) in wk.st[..k].iter().enumerate() {
            let amax = |v: &S5| v.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            scale_p = scale_p.max(1.0 + qp.c[i].amax()).max(1.0 + amax(&s.lo)).max(1.0 + amax(&s.hi));
        }
        if wk.n_free == 5 * k {
            self.iterate::<false>(qp, wk, scale_p)
        } else {
            self.iterate::<true>(qp, wk, scale_p)
        }
    }

    /// The interior-point iteration from the initialised `wk`. `PINNED`:
    /// whether some variable is pinned ([`StructuredOptions::fixed_width`]);
    /// without, the passes leave out the masks of pinned variables (a
    /// product with 1, so the results are the same to the bit).
    #[inline(always)]
    fn iterate<const PINNED: bool>(&self, qp: &StageQp, wk: &mut Work, scale_p: f64) -> Result<QpSolution, QpError> {
        let opt = &self.options;
        let mut last_residual = f64::NAN;
        for iteration in 0..=opt.max_iterations {
            let res = Self::residuals::<PINNED>(qp, wk);
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
            if !primal_ok {
                // Feasible instances converge in about 5 iterations; the
                // certificate (one pass) is looked for from the fourth on.
                if iteration >= CERTIFICATE_FROM_ITERATION {
                    if let Some(gap) = Self::farkas_certificate(qp, wk) {
                        return Err(QpError::Infeasible(format!(
                            "the dynamics multipliers at iteration {iteration} certify that no input sequence keeps \
                             the states within their bounds (Farkas gap {gap:.2e} of the sums' magnitude)"
                        )));
                    }
                }
                let l_max = Self::max_multiplier(wk);
                if l_max > opt.infeasibility_multiplier * (1.0 + res.grad_scale) {
                    return Err(QpError::Infeasible(format!(
                        "primal residual stalled at {:.2e} while a bound multiplier grew to {l_max:.2e} \
                         (iteration {iteration}): no input sequence keeps the states within their bounds",
                        res.primal
                    )));
                }
            }

            // Predictor (affine scaling): target t·μ = 0.
            Self::factorize_predict::<PINNED>(qp, wk)?;
            let gap_aff = Self::predict_forward::<PINNED>(qp, wk, res.gap);
            let sigma_c = (gap_aff / res.gap).clamp(0.0, 1.0).powi(3);
            let target = sigma_c * res.mu;

            // Corrector: target t·μ = σμ, with the second-order term.
            Self::correct_backward(qp, wk, target);
            let alpha = (opt.step_fraction * Self::correct_forward::<PINNED>(qp, wk, target)).min(1.0);
            Self::take_step(qp, wk, alpha);
        }
        Err(QpError::MaxIterations { iterations: opt.max_iterations, residual: last_residual })
    }

    /// Packs the converged iterate into a [`QpSolution`].
    fn finish(&self, qp: &StageQp, wk: &Work, iterations: usize) -> QpSolution {
        let w: Vec<Vector2<f64>> = wk.st.iter().map(|s| Vector2::new(s.x[0], s.x[1])).collect();
        let z: Vec<Vector3<f64>> = wk.st.iter().map(|s| Vector3::new(s.x[2], s.x[3], s.x[4])).collect();
        QpSolution {
            objective: qp.objective(&w, &z),
            iterations,
            dynamics_duals: Some(wk.st.iter().map(|s| Vector3::new(s.y[0], s.y[1], s.y[2])).collect()),
            w,
            z,
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use rand::{Rng, SeedableRng};

    use super::*;
    use crate::compensate::qp::random_instance;

    /// A work buffer for `qp` holding the dynamics multipliers `y`.
    fn work_with_duals(qp: &StageQp, y: &[S3]) -> Work {
        let mut wk = Work::new(qp.stages());
        for (s, y) in wk.st.iter_mut().zip(y) {
            s.y = *y;
        }
        wk
    }

    /// No multipliers whatever certify a feasible problem (the solution of
    /// which is a feasible point): the certificate's sums and margin hold
    /// against any `y`, from small to huge.
    #[test]
    fn feasible_problems_are_never_certified() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for seed in 0..6 {
            let qp = random_instance(seed, 80, 0.9);
            StructuredSolver::default().solve(&qp, None).unwrap();
            for scale in [1e-3, 1.0, 1e6, 1e12] {
                for _ in 0..20 {
                    let y: Vec<S3> =
                        (0..qp.stages()).map(|_| [0; 3].map(|_| scale * (rng.random::<f64>() - 0.5))).collect();
                    let gap = StructuredSolver::farkas_certificate(&qp, &work_with_duals(&qp, &y));
                    assert_eq!(gap, None, "seed {seed}, scale {scale}");
                }
            }
        }
    }

    /// The build for AVX2 and the baseline one give the same solutions to
    /// the bit (cold and warm starts, loose and tight boxes, pinned inputs)
    /// and the same errors.
    #[test]
    fn avx2_build_equals_the_baseline_to_the_bit() {
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") {
            let solver = StructuredSolver::default();
            let run = |qp: &StageQp, warm: Option<&QpSolution>, avx2: bool| {
                let mut wk = Work::new(qp.stages());
                // SAFETY: the CPU reports AVX2 (checked above).
                #[allow(unsafe_code)]
                let r = if avx2 {
                    unsafe { solver.solve_in_avx2(qp, warm, &mut wk) }
                } else {
                    solver.solve_in(qp, warm, &mut wk)
                };
                r.map_err(|e| e.to_string())
            };
            let mut pinned = random_instance(5, 120, 0.0);
            for i in 40..60 {
                pinned.w_lo[i] = nalgebra::Vector2::zeros();
                pinned.w_hi[i] = nalgebra::Vector2::zeros();
            }
            let mut jump = random_instance(30, 40, 0.0);
            jump.c[15][0] = 20.0;
            let mut instances: Vec<StageQp> =
                (0..6).map(|seed| random_instance(seed, 150, [0.0, 0.9, 0.97][seed as usize % 3])).collect();
            instances.extend([pinned, jump]);
            for qp in &instances {
                let cold = run(qp, None, false);
                assert_eq!(cold, run(qp, None, true));
                if let Ok(sol) = &cold {
                    let mut moved = qp.clone();
                    moved.c.iter_mut().for_each(|c| c[0] += 1e-3);
                    assert_eq!(run(&moved, Some(sol), false), run(&moved, Some(sol), true));
                }
            }
        }
    }

    /// A jump of 20 m in the reference that the inputs (about 1 mm per
    /// step) cannot follow within the ±5 m box: the multiplier of that
    /// step's x row certifies it by itself, and the solver finds a
    /// certificate well before its iteration limit.
    #[test]
    fn an_unreachable_jump_is_certified() {
        let mut qp = random_instance(30, 40, 0.0);
        qp.c[15][0] = 20.0;
        let mut y = vec![[0.0; 3]; qp.stages()];
        y[15] = [1.0, 0.0, 0.0];
        assert!(StructuredSolver::farkas_certificate(&qp, &work_with_duals(&qp, &y)).is_some());
        // The same multiplier one step earlier sees only that step's
        // centimetres: no certificate.
        y.swap(14, 15);
        assert_eq!(StructuredSolver::farkas_certificate(&qp, &work_with_duals(&qp, &y)), None);
        match StructuredSolver::default().solve(&qp, None) {
            Err(QpError::Infeasible(why)) => assert!(why.contains("certify"), "{why}"),
            other => panic!("expected a certified infeasibility, got {other:?}"),
        }
    }
}
