//! The filter's measurement update where the reference was really
//! measured: the innovation and its likelihood terms, the innovation
//! diagnostics, and the accumulation of the gradients and information.

use nalgebra::{Matrix3, SMatrix, Vector3, Vector4};

use super::dispatch::KernelCalls;
use super::input_jacobian::add_filter_share_terms;
use super::kernels::{h_cols, h_rows, joseph_general};
use super::sums::{InnovationRecord, SCORE_BLOCK_S};
use super::window::{Linearisation, WindowFilter};
use super::{M3xZ, MZx3, IB, IW, NETA};
use crate::error::{Error, Result};
use crate::model::wrap_angle;

/// One innovation and the quantities of its update.
pub(super) struct Innovation<const S: usize> {
    /// `ν = ỹ − (x̂ + b̂)` (heading wrapped).
    nu: Vector3<f64>,
    /// `H P⁻`.
    hp: M3xZ<S>,
    /// `R + R_q`.
    r_k: Matrix3<f64>,
    /// `S = H P⁻ Hᵀ + R_k`.
    s_mat: Matrix3<f64>,
    sinv: Matrix3<f64>,
    /// The Cholesky factor of S (S = LLᵀ).
    l: Matrix3<f64>,
    /// The whitened innovation `L⁻¹ν`.
    e: Vector3<f64>,
    sinv_nu: Vector3<f64>,
    /// The gain `K = P⁻Hᵀ S⁻¹`.
    k: MZx3<S>,
}

impl<const S: usize> WindowFilter<'_, '_, S> {
    /// The measurement update at sample `k1`; with `record`, the innovation
    /// and its derivatives are pushed to it.
    ///
    /// # Errors
    /// [`Error::Numerical`] when S is not positive definite or the
    /// innovation is not finite.
    #[inline(always)]
    pub(super) fn update<K: KernelCalls>(
        &mut self,
        k1: usize,
        lin: &Linearisation<S>,
        record: Option<&mut Vec<InnovationRecord>>,
    ) -> Result<()> {
        let input = self.input;
        let y = Vector3::new(input.px[k1], input.py[k1], input.psi[k1]);
        let yhat = self.x + self.b;
        let nu = Vector3::new(y[0] - yhat[0], y[1] - yhat[1], wrap_angle(y[2] - yhat[2]));
        let hp: M3xZ<S> = h_rows(self.p);
        let r_k = self.r + lin.r_q;
        let s_mat = super::kernels::h_cols(&hp) + r_k;
        let Some(chol) = s_mat.cholesky() else {
            return Err(Error::Numerical(format!(
                "EIV filter: innovation covariance not positive definite in window {} at sample {k1}",
                self.window.index
            )));
        };
        let sinv = chol.inverse();
        let l = chol.l();
        let logdet = 2.0 * (l[(0, 0)].ln() + l[(1, 1)].ln() + l[(2, 2)].ln());
        let e = l.solve_lower_triangular(&nu).unwrap_or_else(Vector3::zeros);
        let sinv_nu = sinv * nu;
        // With η derivatives the FilterShare terms wait for ∂S/∂η (in `accumulate`).
        let share_eta = self.jacobian.filter_share() && self.mode.derivs && self.mode.eta;
        self.jacobian.update::<K>(self.out, &hp, &sinv, share_eta);
        let quad = nu.dot(&sinv_nu);
        if !(quad.is_finite() && logdet.is_finite()) {
            return Err(Error::Numerical(format!(
                "EIV filter: non-finite innovation in window {} at sample {k1}",
                self.window.index
            )));
        }
        let out = &mut self.out;
        out.quad += quad;
        out.logdet += logdet;
        out.updates += 1;
        for c in 0..3 {
            out.e2[c] += e[c] * e[c];
            if let Some(pe) = self.prev_e {
                out.lag1[c] += e[c] * pe[c];
            }
        }
        self.prev_e = Some(e);
        let k: MZx3<S> = hp.transpose() * sinv;
        let inn = Innovation { nu, hp, r_k, s_mat, sinv, l, e, sinv_nu, k };
        if self.null {
            self.null_moments::<K>(&inn, lin);
        }
        if self.mode.derivs {
            self.accumulate::<K>(k1, &inn, lin, share_eta, record);
        }
        // State and covariance updates.
        let dz = k * nu;
        for r in 0..3 {
            self.x[r] += dz[r];
            self.s[r] += dz[r + 3];
            self.b[r] += dz[r + 6];
        }
        self.eb += dz[IB];
        if S > IW {
            self.wq[0] += dz[IW];
            self.wq[1] += dz[IW + 1];
        }
        K::joseph_in_place_with(self.p, &k, Some(&inn.r_k), &inn.hp);
        Ok(())
    }

    /// Expected moments of the whitened innovations when the data have the
    /// model's noise but not the floors (R₀ = R − floors), and the null
    /// recursion's update.
    #[inline(always)]
    fn null_moments<K: KernelCalls>(&mut self, inn: &Innovation<S>, lin: &Linearisation<S>) {
        let (l, sinv, k) = (&inn.l, &inn.sinv, &inn.k);
        let out = &mut self.out;
        let r0 = Matrix3::from_diagonal(&self.r_white) + lin.r_q;
        let hp0: M3xZ<S> = h_rows(self.p0);
        let s0 = h_cols(&hp0) + r0;
        let m1 = l.solve_lower_triangular(&s0).unwrap_or_else(Matrix3::zeros);
        let e_cov = l.solve_lower_triangular(&m1.transpose()).unwrap_or_else(Matrix3::zeros);
        out.quad_null += (sinv * s0).trace();
        if let Some((c, l_prev)) = &self.c0 {
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
        // C₀ = E[ε⁺ νᵀ] = P₀Hᵀ − K S₀; P₀⁺ = (I−KH)P₀(I−KH)ᵀ + K R₀ Kᵀ.
        *self.c0 = Some((hp0.transpose() - k * s0, *l));
        K::joseph_in_place(self.p0, k, Some(&r0));
    }

    /// With derivatives: the gradients (`∂ν/∂p = −H D⁻` and `∂S/∂p`), the
    /// information matrices and the scoring metric of θ, the θ-scores'
    /// outer products and blocks, the corrected score's bias, and the
    /// updates of the sensitivities D and the covariance derivatives.
    #[inline(always)]
    fn accumulate<K: KernelCalls>(
        &mut self,
        k1: usize,
        inn: &Innovation<S>,
        lin: &Linearisation<S>,
        share_eta: bool,
        record: Option<&mut Vec<InnovationRecord>>,
    ) {
        let (sinv, k) = (inn.sinv, inn.k);
        let hd = h_rows(self.d); // ∂ν/∂p = −H D⁻
                                 // Gradient of ½νᵀS⁻¹ν through ν: νᵀS⁻¹ ∂ν = −(HD)ᵀ S⁻¹ ν.
        let gnu = hd.transpose() * inn.sinv_nu;
        self.out.grad -= gnu;
        self.out.grad_profile -= gnu;
        let sh = sinv * hd;
        let mut info = hd.transpose() * sh;
        self.out.info_mean_theta += info.fixed_view::<4, 4>(0, 0);
        let mut g_t = Vector4::<f64>::zeros();
        let mut dr = SMatrix::<f64, 3, 4>::zeros();
        for c in 0..4 {
            g_t[c] = -gnu[c];
        }
        self.score_columns(inn, lin, &mut g_t);
        if share_eta {
            let second_order = self.jacobian.second_order();
            let cols = self.cols;
            add_filter_share_terms(
                self.out,
                &mut self.jacobian.pending,
                &inn.sinv,
                second_order,
                Some((cols.as_slice(), self.ds)),
            );
        }
        self.add_trace_information(&mut info);
        if self.theta_cols {
            dr = self.whitened_derivatives(&hd, inn);
            self.out.h_theta += dr.transpose() * dr;
        } else if !self.mode.follows_theta {
            self.out.h_theta += info.fixed_view::<4, 4>(0, 0);
        }
        self.out.i_eta += info.fixed_view::<NETA, NETA>(4, 4);
        self.out.info += info;
        self.out.opg += g_t * g_t.transpose();
        self.add_block_score(k1, &g_t);
        if self.corrected {
            for (ci, xi) in self.xcov.iter_mut().enumerate() {
                self.out.bias[ci] -= (inn.sinv * h_cols(&h_rows(xi))).trace();
                *xi = joseph_general(xi, &inn.k);
            }
        }
        if let Some(rec) = record {
            rec.push(InnovationRecord { nu: inn.nu, s: inn.s_mat, dnu: -hd, ds: *self.ds, r: inn.e, dr });
        }
        // Sensitivity update: D⁺ = (I − KH) D⁻ + ∂K ν with
        // ∂K = (∂P⁻Hᵀ − K ∂S) S⁻¹.
        *self.d -= k * hd;
        let cols = self.cols;
        for &jj in cols.as_slice() {
            for r_ in 0..S {
                self.d[(r_, jj)] += self.dkn[(r_, jj)];
            }
        }
        // Joseph form (I−KH)∂P(I−KH)ᵀ + K ∂R Kᵀ: the algebraically equal
        // ∂P − KH∂P − (KH∂P)ᵀ + K ∂S Kᵀ is numerically unstable here.
        for &jj in cols.as_slice() {
            let dr = self.d_r(jj, &lin.r_q);
            K::joseph_in_place_with(&mut self.dp[jj], &inn.k, (dr != Matrix3::zeros()).then_some(&dr), &self.hdps[jj]);
        }
    }

    /// `∂R_k/∂p_j`: quantisation (η_0; θ through ∂f/∂n when following),
    /// position white (η_3), heading white (η_5).
    #[inline(always)]
    fn d_r(&self, jj: usize, r_q: &Matrix3<f64>) -> Matrix3<f64> {
        match jj {
            0..=3 => self.r_q_theta[jj],
            4 if self.v.quant_scaled => *r_q,
            7 => self.dr_position,
            9 => self.dr_heading,
            _ => Matrix3::zeros(),
        }
    }

    /// Per propagated column: `∂S_j = H ∂P⁻_j Hᵀ + ∂R_j`, the gradient terms
    /// of `½νᵀS⁻¹ν` and `½ log det S` through S, and the column of `∂K ν`.
    #[inline(always)]
    fn score_columns(&mut self, inn: &Innovation<S>, lin: &Linearisation<S>, g_t: &mut Vector4<f64>) {
        let cols = self.cols;
        for &jj in cols.as_slice() {
            self.hdps[jj] = h_rows(&self.dp[jj]);
            let hdp = &self.hdps[jj];
            self.ds[jj] = h_cols(hdp) + self.d_r(jj, &lin.r_q);
            self.a[jj] = inn.sinv * self.ds[jj];
            let ds_snu = self.ds[jj] * inn.sinv_nu;
            let gq = -0.5 * inn.sinv_nu.dot(&ds_snu);
            let gl = 0.5 * self.a[jj].trace();
            self.out.grad[jj] += gq + gl;
            self.out.grad_profile[jj] += gq;
            if jj < 4 {
                g_t[jj] += gq;
                self.out.grad_logdet[jj] += gl;
            }
            // Column of ∂K ν = (∂P⁻Hᵀ − K ∂S) S⁻¹ ν.
            let col = hdp.transpose() * inn.sinv_nu - inn.k * ds_snu;
            self.dkn.set_column(jj, &col);
        }
    }

    /// `½ tr(S⁻¹∂S_i S⁻¹∂S_j)` added to `info`, symmetric in (i, j):
    /// `tr(AB) = Σ A_rc B_cr`.
    #[inline(always)]
    fn add_trace_information(&self, info: &mut super::MP) {
        let cols = self.cols.as_slice();
        for (n1, &i1) in cols.iter().enumerate() {
            for &i2 in &cols[n1..] {
                let (a1, a2) = (&self.a[i1], &self.a[i2]);
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

    /// `∂r/∂θ` of the whitened innovation `r = L⁻¹ν` (S = LLᵀ), the rows of
    /// the Gauss-Newton metric of the profile cost `J = ½Σ‖r‖²`:
    /// `∂r_j = L⁻¹∂ν_j − Φ(L⁻¹ ∂S_j L⁻ᵀ) r`, Φ the lower triangle with halved
    /// diagonal (the derivative of the Cholesky factor). It is the expected
    /// Hessian of J, not the Fisher information of the marginal likelihood,
    /// which overstates the curvature when the input noise is comparable to
    /// the turning signal.
    #[inline(always)]
    fn whitened_derivatives(&self, hd: &SMatrix<f64, 3, { super::NP }>, inn: &Innovation<S>) -> SMatrix<f64, 3, 4> {
        let (l, r_w) = (&inn.l, inn.e);
        let mut dr = SMatrix::<f64, 3, 4>::zeros();
        for jt in 0..4 {
            let dnu_j = -Vector3::new(hd[(0, jt)], hd[(1, jt)], hd[(2, jt)]);
            let a1 = l.solve_lower_triangular(&dnu_j).unwrap_or_else(Vector3::zeros);
            let m1 = l.solve_lower_triangular(&self.ds[jt]).unwrap_or_else(Matrix3::zeros);
            let m = l.solve_lower_triangular(&m1.transpose()).unwrap_or_else(Matrix3::zeros);
            let mut phi = m.lower_triangle();
            for q in 0..3 {
                phi[(q, q)] *= 0.5;
            }
            dr.set_column(jt, &(a1 - phi * r_w));
        }
        dr
    }

    /// Adds the update's θ-score to the open block of [`super::BlockScores`]
    /// (closing the block before when `k1` starts a new one).
    #[inline(always)]
    fn add_block_score(&mut self, k1: usize, g_t: &Vector4<f64>) {
        let b = ((k1 - self.window.start) as f64 * self.ts / SCORE_BLOCK_S) as usize;
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
    }
}
