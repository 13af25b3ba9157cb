//! The measurement update of the window filter: the innovation
//! ([`Innovation`]), the window's sums ([`Accumulator`]), the null pass's
//! moments ([`null_moments`]) and the update of the sensitivities and the
//! covariance derivatives ([`update_sensitivities`]).
//!
//! Every function here is `#[inline(always)]` and takes each array of the
//! recursion as its own argument (see [`super::window`]).

use nalgebra::{Matrix3, SMatrix, Vector3, Vector4};

use super::dispatch::KernelCalls;
use super::input_jacobian::InputJacobianState;
use super::kernels::{h_cols, h_rows, joseph_general, mul3, mul3_tn};
use super::predict::MeanState;
use super::sums::{WindowSums, SCORE_BLOCK_S};
use super::window::{Linearisation, WindowSetup};
use super::{M3xZ, MZx3, DZ, MP, MZ, NETA, NP};
use crate::error::{Error, Result};
use crate::model::wrap_angle;

/// The innovation of one measurement update at sample `k1` and what the
/// update derives from it.
pub(super) struct Innovation<const S: usize> {
    /// The sample of the measurement.
    pub(super) k1: usize,
    /// `ν = y − H ẑ⁻` (heading wrapped).
    pub(super) nu: Vector3<f64>,
    /// `H P⁻`.
    pub(super) hp: M3xZ<S>,
    /// `R_k = R + R_q`.
    pub(super) r_k: Matrix3<f64>,
    /// `S = H P⁻ Hᵀ + R_k`, its inverse, its Cholesky factor L and `log det S`.
    pub(super) s_mat: Matrix3<f64>,
    pub(super) sinv: Matrix3<f64>,
    pub(super) l: Matrix3<f64>,
    pub(super) logdet: f64,
    /// The whitened innovation `L⁻¹ν`.
    pub(super) e: Vector3<f64>,
    /// `S⁻¹ν`.
    pub(super) sinv_nu: Vector3<f64>,
    /// The gain `K = P⁻Hᵀ S⁻¹`.
    pub(super) k: MZx3<S>,
    /// `H D⁻ = −∂ν/∂p` (zeros without derivatives).
    pub(super) hd: SMatrix<f64, 3, NP>,
}

impl<const S: usize> Innovation<S> {
    /// All zero, before the window's first update.
    #[inline(always)]
    pub(super) fn zero() -> Self {
        Innovation {
            k1: 0,
            nu: Vector3::zeros(),
            hp: M3xZ::<S>::zeros(),
            r_k: Matrix3::zeros(),
            s_mat: Matrix3::zeros(),
            sinv: Matrix3::zeros(),
            l: Matrix3::zeros(),
            logdet: 0.0,
            e: Vector3::zeros(),
            sinv_nu: Vector3::zeros(),
            k: MZx3::<S>::zeros(),
            hd: SMatrix::zeros(),
        }
    }

    /// The innovation of the reference measured at sample `lin.i + 1`
    /// against the predicted mean, covariance P⁻ and sensitivities D⁻,
    /// written over `self` (in place: the window loop keeps one
    /// `Innovation` and never moves its arrays).
    #[inline(always)]
    pub(super) fn update(
        &mut self,
        setup: &WindowSetup<'_, S>,
        lin: &Linearisation<S>,
        mean: &MeanState,
        p: &MZ<S>,
        d: &DZ<S>,
    ) -> Result<()> {
        let (input, k1) = (setup.input, lin.i + 1);
        let y = Vector3::new(input.px[k1], input.py[k1], input.psi[k1]);
        let yhat = mean.x + mean.b;
        let nu = Vector3::new(y[0] - yhat[0], y[1] - yhat[1], wrap_angle(y[2] - yhat[2]));
        self.hp = h_rows(p);
        let r_k = setup.r + lin.r_q;
        let s_mat = h_cols(&self.hp) + r_k;
        let Some(chol) = s_mat.cholesky() else {
            return Err(Error::Numerical(format!(
                "EIV filter: innovation covariance not positive definite in window {} at sample {k1}",
                setup.window.index
            )));
        };
        let l = chol.l();
        let sinv = cholesky_inverse(&l);
        self.logdet = 2.0 * (l[(0, 0)].ln() + l[(1, 1)].ln() + l[(2, 2)].ln());
        self.e = l.solve_lower_triangular(&nu).unwrap_or_else(Vector3::zeros);
        self.sinv_nu = sinv * nu;
        self.k = mul3_tn(&self.hp, &sinv);
        self.hd = if setup.mode.derivs { h_rows(d) } else { SMatrix::zeros() };
        (self.k1, self.nu, self.r_k, self.s_mat, self.sinv, self.l) = (k1, nu, r_k, s_mat, sinv, l);
        Ok(())
    }

    /// `∂R_k/∂p_j`: quantisation (η_0; θ through ∂f/∂n when following),
    /// position white (η_3), heading white (η_5).
    #[inline(always)]
    fn d_r(setup: &WindowSetup<'_, S>, lin: &Linearisation<S>, jj: usize) -> Matrix3<f64> {
        match jj {
            0..=3 => lin.r_q_theta[jj],
            4 if setup.v.quant_scaled => lin.r_q,
            7 => setup.dr_position,
            9 => setup.dr_heading,
            _ => Matrix3::zeros(),
        }
    }
}

/// `S⁻¹` from the Cholesky factor `L` of S, written out so that it inlines
/// into the window loop: the operations of nalgebra's
/// `Cholesky::inverse` on a 3 × 3 matrix in its order (forward
/// substitution of each column of I with `b_r += −c·L_ri`, back substitution
/// with the dot products summed from 0), so the same bits.
#[inline(always)]
fn cholesky_inverse(l: &Matrix3<f64>) -> Matrix3<f64> {
    let mut out = Matrix3::<f64>::identity();
    for j in 0..3 {
        let mut b = [out[(0, j)], out[(1, j)], out[(2, j)]];
        // L y = e_j.
        let c0 = b[0] / l[(0, 0)];
        b[0] = c0;
        b[1] += -c0 * l[(1, 0)];
        b[2] += -c0 * l[(2, 0)];
        let c1 = b[1] / l[(1, 1)];
        b[1] = c1;
        b[2] += -c1 * l[(2, 1)];
        b[2] /= l[(2, 2)];
        // Lᵀ x = y.
        b[2] = (b[2] - 0.0) / l[(2, 2)];
        let dot1 = 0.0 + l[(2, 1)] * b[2];
        b[1] = (b[1] - dot1) / l[(1, 1)];
        let dot0 = 0.0 + l[(1, 0)] * b[1] + l[(2, 0)] * b[2];
        b[0] = (b[0] - dot0) / l[(0, 0)];
        for (r, v) in b.into_iter().enumerate() {
            out[(r, j)] = v;
        }
    }
    out
}

/// The per-update work arrays of the covariance-derivative columns (only
/// the entries of the propagated columns are written; the rest stay zero,
/// as the records expect).
pub(super) struct ColumnWork<'w, const S: usize> {
    /// `∂S/∂p_j`.
    pub(super) ds: &'w mut [Matrix3<f64>; NP],
    /// `S⁻¹ ∂S/∂p_j`.
    pub(super) a: &'w mut [Matrix3<f64>; NP],
    /// Columns of `∂K ν`.
    pub(super) dkn: &'w mut DZ<S>,
    /// `H ∂P⁻/∂p_j` (for ∂S and again in the Joseph form).
    pub(super) hdps: &'w mut [M3xZ<S>; NP],
    /// `∂R_k/∂p_j` ([`Innovation::d_r`]; for ∂S and again in the Joseph form).
    pub(super) dr: &'w mut [Matrix3<f64>; NP],
}

/// What the window accumulates: its sums ([`WindowSums`]), the previous
/// whitened innovation (for the lag-1 sums) and the open block of θ-scores
/// ([`super::BlockScores`]).
pub(super) struct Accumulator {
    pub(super) out: WindowSums,
    prev_e: Option<Vector3<f64>>,
    block_index: usize,
    block_open: bool,
    block_sum: Vector4<f64>,
    block_prev: Option<Vector4<f64>>,
}

impl Accumulator {
    /// Nothing accumulated.
    #[inline(always)]
    pub(super) fn new() -> Self {
        Accumulator {
            out: WindowSums::zero(),
            prev_e: None,
            block_index: 0,
            block_open: false,
            block_sum: Vector4::zeros(),
            block_prev: None,
        }
    }

    /// Adds the innovation's terms of the objective (`νᵀS⁻¹ν`, `log det S`)
    /// and of the whiteness diagnostics.
    #[inline(always)]
    pub(super) fn add_innovation<const S: usize>(&mut self, inn: &Innovation<S>, window_index: usize) -> Result<()> {
        let out = &mut self.out;
        let quad = inn.nu.dot(&inn.sinv_nu);
        if !(quad.is_finite() && inn.logdet.is_finite()) {
            return Err(Error::Numerical(format!(
                "EIV filter: non-finite innovation in window {window_index} at sample {}",
                inn.k1
            )));
        }
        out.quad += quad;
        out.logdet += inn.logdet;
        out.updates += 1;
        let e = inn.e;
        for c in 0..3 {
            out.e2[c] += e[c] * e[c];
            if let Some(pe) = self.prev_e {
                out.lag1[c] += e[c] * pe[c];
            }
        }
        self.prev_e = Some(e);
        Ok(())
    }

    /// Adds the update's derivative terms: the gradients, the information
    /// matrices, the θ-score (to its block) and, with the FilterShare input
    /// log-Jacobian and η derivatives, its η terms. Returns the whitened
    /// innovation's θ-derivatives `∂r/∂θ` (zeros unless `∂P/∂θ` is
    /// propagated). Fills `work` for [`update_sensitivities`].
    #[inline(always)]
    pub(super) fn add_derivatives<const S: usize>(
        &mut self,
        setup: &WindowSetup<'_, S>,
        lin: &Linearisation<S>,
        inn: &Innovation<S>,
        dp: &[MZ<S>; NP],
        work: &mut ColumnWork<'_, S>,
        jacobian: &mut InputJacobianState<S>,
    ) -> SMatrix<f64, 3, 4> {
        let g_t = score_columns(setup, lin, inn, dp, work, &mut self.out);
        jacobian.add_share_eta_terms(setup, inn, work.ds, &mut self.out);
        if !setup.mode.info {
            return SMatrix::zeros();
        }
        // The mean part of the information, (HD)ᵀ S⁻¹ (HD).
        let sh = mul3(&inn.sinv, &inn.hd);
        let mut info = mul3_tn(&inn.hd, &sh);
        self.out.info_mean_theta += info.fixed_view::<4, 4>(0, 0);
        add_trace_information(setup.cols(), work.a, &mut info);
        let out = &mut self.out;
        let mut dr = SMatrix::<f64, 3, 4>::zeros();
        if setup.theta_cols {
            dr = whitened_derivatives(inn, work.ds);
            out.h_theta += dr.transpose() * dr;
        } else if !setup.follows {
            out.h_theta += info.fixed_view::<4, 4>(0, 0);
        }
        out.i_eta += info.fixed_view::<NETA, NETA>(4, 4);
        out.info += info;
        out.opg += g_t * g_t.transpose();
        let b = ((inn.k1 - setup.window.start) as f64 * setup.ts / SCORE_BLOCK_S) as usize;
        if b != self.block_index {
            if self.block_open {
                self.out.blocks.push(&self.block_sum, self.block_prev.as_ref());
                self.block_prev = Some(self.block_sum);
            }
            self.block_index = b;
            self.block_sum = Vector4::zeros();
        }
        self.block_open = true;
        self.block_sum += g_t;
        dr
    }

    /// The window's sums once every sample has been filtered.
    #[inline(always)]
    pub(super) fn finish<const S: usize>(
        mut self,
        setup: &WindowSetup<'_, S>,
        jacobian: &InputJacobianState<S>,
    ) -> WindowSums {
        if self.block_open {
            self.out.blocks.push(&self.block_sum, self.block_prev.as_ref());
        }
        jacobian.finish(setup, &mut self.out);
        self.out
    }
}

/// The gradient of the objective through ν and through the propagated
/// `∂S/∂p_j`, and per propagated column `∂R_j`, `∂S_j`, `S⁻¹∂S_j` and the
/// column of `∂K ν` (in `work`). Returns the θ-score of `½ νᵀS⁻¹ν`.
#[inline(always)]
fn score_columns<const S: usize>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    inn: &Innovation<S>,
    dp: &[MZ<S>; NP],
    work: &mut ColumnWork<'_, S>,
    out: &mut WindowSums,
) -> Vector4<f64> {
    let (hd, sinv, sinv_nu) = (&inn.hd, inn.sinv, inn.sinv_nu);
    // Gradient of ½νᵀS⁻¹ν through ν: νᵀS⁻¹ ∂ν = −(HD)ᵀ S⁻¹ ν.
    let gnu = mul3_tn(hd, &sinv_nu);
    out.grad -= gnu;
    out.grad_profile -= gnu;
    let mut g_t = Vector4::<f64>::zeros();
    for c in 0..4 {
        g_t[c] = -gnu[c];
    }
    for &jj in setup.cols() {
        work.hdps[jj] = h_rows(&dp[jj]);
        let hdp = &work.hdps[jj];
        work.dr[jj] = Innovation::d_r(setup, lin, jj);
        work.ds[jj] = h_cols(hdp) + work.dr[jj];
        work.a[jj] = sinv * work.ds[jj];
        let ds_snu = work.ds[jj] * sinv_nu;
        let gq = -0.5 * sinv_nu.dot(&ds_snu);
        let gl = 0.5 * work.a[jj].trace();
        out.grad[jj] += gq + gl;
        out.grad_profile[jj] += gq;
        if jj < 4 {
            g_t[jj] += gq;
            out.grad_logdet[jj] += gl;
        }
        // Column of ∂K ν = (∂P⁻Hᵀ − K ∂S) S⁻¹ ν.
        let col = mul3_tn(hdp, &sinv_nu) - mul3(&inn.k, &ds_snu);
        work.dkn.set_column(jj, &col);
    }
    g_t
}

/// `½ tr(S⁻¹∂S_i S⁻¹∂S_j)` over the propagated columns, added to `info`;
/// symmetric in (i, j): `tr(AB) = Σ A_rc B_cr`.
#[inline(always)]
fn add_trace_information(cols: &[usize], a: &[Matrix3<f64>; NP], info: &mut MP) {
    for (n1, &i1) in cols.iter().enumerate() {
        for &i2 in &cols[n1..] {
            let (a1, a2) = (&a[i1], &a[i2]);
            let mut t = 0.0;
            for r_ in 0..3 {
                t += a1[(r_, 0)] * a2[(0, r_)] + a1[(r_, 1)] * a2[(1, r_)] + a1[(r_, 2)] * a2[(2, r_)];
            }
            info[(i1, i2)] += 0.5 * t;
            if i1 != i2 {
                info[(i2, i1)] += 0.5 * t;
            }
        }
    }
}

/// The θ-derivatives of the whitened innovation `r = L⁻¹ν` (S = LLᵀ):
/// `∂r_j = L⁻¹∂ν_j − Φ(L⁻¹ ∂S_j L⁻ᵀ) r`, Φ the lower triangle with halved
/// diagonal (the derivative of the Cholesky factor). `Σ ∂rᵀ∂r` is the
/// Gauss-Newton metric of the profile cost J = ½Σ‖r‖², the expected Hessian
/// of J, not the Fisher information of the marginal likelihood, which
/// overstates the curvature when the input noise is comparable to the
/// turning signal.
#[inline(always)]
fn whitened_derivatives<const S: usize>(inn: &Innovation<S>, ds: &[Matrix3<f64>; NP]) -> SMatrix<f64, 3, 4> {
    let (l, hd, r_w) = (inn.l, &inn.hd, inn.e);
    let mut dr = SMatrix::<f64, 3, 4>::zeros();
    for jt in 0..4 {
        let dnu_j = -Vector3::new(hd[(0, jt)], hd[(1, jt)], hd[(2, jt)]);
        let a1 = l.solve_lower_triangular(&dnu_j).unwrap_or_else(Vector3::zeros);
        let m1 = l.solve_lower_triangular(&ds[jt]).unwrap_or_else(Matrix3::zeros);
        let m = l.solve_lower_triangular(&m1.transpose()).unwrap_or_else(Matrix3::zeros);
        let mut phi = m.lower_triangle();
        for q in 0..3 {
            phi[(q, q)] *= 0.5;
        }
        dr.set_column(jt, &(a1 - phi * r_w));
    }
    dr
}

/// The corrected score's term `−tr(S⁻¹ H X_i Hᵀ)` ([`WindowSums::bias`]) and
/// the update of the cross-covariances, `X⁺ = (I − KH) X⁻ (I − KH)ᵀ`.
#[inline(always)]
pub(super) fn add_corrected_bias<const S: usize>(inn: &Innovation<S>, xcov: &mut [MZ<S>; 4], out: &mut WindowSums) {
    for (ci, xi) in xcov.iter_mut().enumerate() {
        out.bias[ci] -= (inn.sinv * h_cols(&h_rows(xi))).trace();
        *xi = joseph_general(xi, &inn.k);
    }
}

/// The expected moments of the whitened innovations when the data have the
/// model's noise but not the floors (R₀ = R − floors), and the null pass's
/// update: `C₀ = E[ε⁺ νᵀ] = P₀Hᵀ − K S₀`, `P₀⁺ = (I−KH)P₀(I−KH)ᵀ + K R₀ Kᵀ`.
#[inline(always)]
pub(super) fn null_moments<const S: usize, K: KernelCalls>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    inn: &Innovation<S>,
    p0: &mut MZ<S>,
    c0: &mut Option<(MZx3<S>, Matrix3<f64>)>,
    out: &mut WindowSums,
) {
    let (l, sinv, k) = (inn.l, &inn.sinv, &inn.k);
    let r0 = Matrix3::from_diagonal(&setup.r_white) + lin.r_q;
    let hp0: M3xZ<S> = h_rows(p0);
    let s0 = h_cols(&hp0) + r0;
    let m1 = l.solve_lower_triangular(&s0).unwrap_or_else(Matrix3::zeros);
    let e_cov = l.solve_lower_triangular(&m1.transpose()).unwrap_or_else(Matrix3::zeros);
    out.quad_null += (sinv * s0).trace();
    if let Some((c, l_prev)) = c0 {
        // E[ν_k ν_{k−1}ᵀ] = H C₀; whitened: L_k⁻¹ H C₀ L_{k−1}⁻ᵀ.
        let cross = h_rows(c);
        let m1 = l.solve_lower_triangular(&cross).unwrap_or_else(Matrix3::zeros);
        let m2 = l_prev.solve_lower_triangular(&m1.transpose()).unwrap_or_else(Matrix3::zeros);
        for q in 0..3 {
            out.lag1_null[q] += m2[(q, q)];
        }
    }
    for q in 0..3 {
        out.e2_null[q] += e_cov[(q, q)];
    }
    *c0 = Some((hp0.transpose() - k * s0, l));
    K::joseph_in_place(p0, k, Some(&r0));
}

/// The sensitivity update `D⁺ = (I − KH) D⁻ + ∂K ν` with
/// `∂K = (∂P⁻Hᵀ − K ∂S) S⁻¹`, and the covariance derivatives' Joseph form
/// `(I−KH)∂P(I−KH)ᵀ + K ∂R Kᵀ` (the algebraically equal
/// `∂P − KH∂P − (KH∂P)ᵀ + K ∂S Kᵀ` is numerically unstable here).
#[inline(always)]
pub(super) fn update_sensitivities<const S: usize, K: KernelCalls>(
    setup: &WindowSetup<'_, S>,
    inn: &Innovation<S>,
    d: &mut DZ<S>,
    dp: &mut [MZ<S>; NP],
    work: &ColumnWork<'_, S>,
) {
    if setup.sensitivity_cols() == NP {
        *d -= mul3(&inn.k, &inn.hd);
    } else {
        // Without η derivatives the η columns of D (and of HD) stay zero.
        let kh = mul3(&inn.k, &inn.hd.fixed_columns::<4>(0).into_owned());
        let mut dt = d.fixed_columns_mut::<4>(0);
        dt -= kh;
    }
    for &jj in setup.cols() {
        for r_ in 0..S {
            d[(r_, jj)] += work.dkn[(r_, jj)];
        }
    }
    for &jj in setup.cols() {
        let dr = &work.dr[jj];
        K::joseph_in_place_with(&mut dp[jj], &inn.k, (*dr != Matrix3::zeros()).then_some(dr), &work.hdps[jj]);
    }
}

#[cfg(test)]
mod inline_product_tests {
    //! The written-out products and inverse against nalgebra's, to the bit.
    use super::*;
    use crate::eiv::filter::NZ;

    /// A deterministic pseudo-random number in [−1, 1).
    fn lcg(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn bits<const R: usize, const C: usize>(m: &SMatrix<f64, R, C>) -> Vec<u64> {
        m.iter().map(|x| x.to_bits()).collect()
    }

    #[test]
    fn inline_products_and_inverse_equal_nalgebras_to_the_bit() {
        let mut st = 7u64;
        for _ in 0..200 {
            let k = MZx3::<NZ>::from_fn(|_, _| lcg(&mut st));
            let hp = M3xZ::<NZ>::from_fn(|_, _| lcg(&mut st));
            let hd = SMatrix::<f64, 3, NP>::from_fn(|_, _| lcg(&mut st));
            let a = Matrix3::from_fn(|_, _| lcg(&mut st));
            let s = a * a.transpose() + Matrix3::from_diagonal_element(1e-3 + lcg(&mut st).abs());
            let chol = s.cholesky().expect("positive definite");
            let sinv = chol.inverse();
            assert_eq!(bits(&cholesky_inverse(&chol.l())), bits(&sinv));
            assert_eq!(bits(&mul3_tn(&hp, &sinv)), bits(&(hp.transpose() * sinv)));
            assert_eq!(bits(&mul3(&k, &hd)), bits(&(k * hd)));
            assert_eq!(bits(&mul3(&k, &a)), bits(&(k * a)));
            assert_eq!(bits(&mul3_tn(&hd, &mul3(&sinv, &hd))), bits(&(hd.transpose() * (sinv * hd))));
        }
    }
}
