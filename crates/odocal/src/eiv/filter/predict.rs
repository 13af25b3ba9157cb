//! The filter's prediction step: the mean at θ with its exact
//! sensitivities, the covariance along the reference with its derivatives,
//! and the corrected score's cross-covariances.

use nalgebra::{Matrix3, Vector3};

use super::dispatch::KernelCalls;
use super::kernels::{add_sym_rows, propagate_cols, propagate_general};
use super::quantisation::add_remainder_noise;
use super::reference::{dvec_of, theta_jacobian_input_derivatives, ReferenceTerms};
use super::window::{Linearisation, WindowFilter};
use super::{M3x2, MZx3, IB, IW, MZ, NP};
use crate::eiv::InputJacobian;
use crate::error::{Error, Result};
use crate::model::{step_jacobians, Input, StepJacobians};

/// The step's process noise (pose block, s, drift, sideslip error), the
/// same for the filter's P and the null pass's P₀.
#[inline(always)]
fn add_process_noise<const S: usize>(m: &mut MZ<S>, q_x: &Matrix3<f64>, q_s: &[f64; 3], q_b: &[f64; 3], q_beta: f64) {
    for r in 0..3 {
        for c in 0..3 {
            m[(r, c)] += q_x[(r, c)];
        }
        m[(r + 3, r + 3)] += q_s[r];
        m[(r + 6, r + 6)] += q_b[r];
    }
    m[(IB, IB)] += q_beta;
}

impl<const S: usize> WindowFilter<'_, '_, S> {
    /// Predicts from sample `lin.i` to the next: the input log-Jacobian
    /// term, the corrected score's X (with the sensitivities of the last
    /// update, before the mean prediction), the mean, the Gauss-Markov
    /// states and the covariance.
    ///
    /// # Errors
    /// [`Error::Numerical`] when the estimated relative wheel error reaches 1.
    #[inline(always)]
    pub(super) fn predict<K: KernelCalls>(&mut self, lin: &Linearisation<S>) -> Result<()> {
        if lin.i == self.window.start && self.v.quant_in_measurement {
            self.add_initial_count_offset(lin);
        }
        if self.jacobian.mode != InputJacobian::None {
            self.jacobian.predict::<K>(lin, self.v, (self.theta, self.theta_ref), self.fitted, &self.q_s);
        }
        if self.corrected {
            self.predict_corrected_score(lin);
        }
        self.predict_mean(lin)?;
        let (v, s) = (self.v, self.s);
        self.s = Vector3::new(v.a_common * s[0], v.a_wheel * s[1], v.a_wheel * s[2]);
        self.b *= v.a_drift;
        self.eb *= v.a_beta;
        for w in 0..2 {
            if lin.counting[w] {
                self.wq[w] = 0.0;
            }
        }
        self.predict_covariance::<K>(lin);
        Ok(())
    }

    /// Corrected score (held covariance): `X⁻ = F̄ X⁺ F̄ᵀ − Σ_u var(u) (∂f/∂u)(∂f_θ/∂u)ᵀ`.
    #[inline(always)]
    fn predict_corrected_score(&mut self, lin: &Linearisation<S>) {
        let (fn_l, fn_r, f_a) = (lin.fn_l, lin.fn_r, lin.f_a);
        let a_u = theta_jacobian_input_derivatives(self.input.psi[lin.i], &lin.uref, self.theta_ref, self.ts);
        // The noise moves the θ-sensitivity through ∂f/∂θ, through F_x (speed
        // in the heading column) and through the s-columns of F (−F_n ñ).
        let g_u = [(fn_l, lin.wl), (fn_r, lin.wr), (f_a, self.v.a_y)];
        let fs_u = [
            Matrix3::from_columns(&[-fn_l, -fn_l, Vector3::zeros()]),
            Matrix3::from_columns(&[-fn_r, Vector3::zeros(), -fn_r]),
            Matrix3::zeros(),
        ];
        let ft = lin.transition();
        let d = &self.d;
        for (ci, xi) in self.xcov.iter_mut().enumerate() {
            *xi = propagate_general(xi, &ft);
            let dx = Vector3::new(d[(0, ci)], d[(1, ci)], d[(2, ci)]);
            let ds_ = Vector3::new(d[(3, ci)], d[(4, ci)], d[(5, ci)]);
            for (u, (g, var)) in g_u.iter().enumerate() {
                if *var > 0.0 {
                    let (a, df02, df12) = &a_u[u];
                    let col = a.column(ci) + Vector3::new(df02 * dx[2], df12 * dx[2], 0.0) + fs_u[u] * ds_;
                    for r in 0..3 {
                        for c in 0..3 {
                            xi[(r, c)] -= var * g[r] * col[c];
                        }
                    }
                }
            }
        }
    }

    /// The mean prediction at θ, with its exact Jacobians (`D⁻ = F D⁺ + [f_θ | 0]`),
    /// and the coloured-noise correction `−m log(1 − ŝ)` with its gradient.
    #[inline(always)]
    fn predict_mean(&mut self, lin: &Linearisation<S>) -> Result<()> {
        let (nl, nr, s) = (lin.nl, lin.nr, self.s);
        let (m_c, m_l, m_r) = (
            f64::from(u8::from(nl != 0.0 || nr != 0.0)),
            f64::from(u8::from(nl != 0.0)),
            f64::from(u8::from(nr != 0.0)),
        );
        let one_minus = [1.0 - s[0], 1.0 - s[1], 1.0 - s[2]];
        if one_minus.iter().any(|o| *o <= 0.0 || !o.is_finite()) {
            return Err(Error::Numerical(format!(
                "EIV filter diverged in window {} at sample {}: estimated relative wheel error s = {:?} reached 1",
                self.window.index,
                lin.i,
                [s[0], s[1], s[2]]
            )));
        }
        self.out.correction -= m_c * one_minus[0].ln() + m_l * one_minus[1].ln() + m_r * one_minus[2].ln();
        // The remainder of the previous count is taken off the measured rate
        // (the new one has mean zero).
        let counting = lin.counting;
        let wsub = [if counting[0] { self.wq[0] } else { 0.0 }, if counting[1] { self.wq[1] } else { 0.0 }];
        let ueff = Input {
            n_rl: nl * (1.0 - s[0] - s[1]) - wsub[0],
            n_rr: nr * (1.0 - s[0] - s[2]) - wsub[1],
            beta: lin.beta - self.eb,
            a_y: lin.a_y,
        };
        if self.mode.derivs {
            for (row, m) in [(3usize, m_c), (4, m_l), (5, m_r)] {
                if m > 0.0 {
                    let w = m / one_minus[row - 3];
                    for c in 0..NP {
                        self.out.grad[c] += w * self.d[(row, c)];
                        if !self.jacobian.all_sources {
                            self.out.grad_profile[c] += w * self.d[(row, c)];
                        }
                    }
                    for c in 0..4 {
                        self.out.grad_correction[c] += w * self.d[(row, c)];
                    }
                }
            }
            let j = step_jacobians(&self.x, &ueff, self.theta, self.ts);
            self.predict_sensitivities(&j, lin);
            self.x = j.next;
        } else {
            self.x = crate::model::step(&self.x, &ueff, self.theta, self.ts);
        }
        Ok(())
    }

    /// `D⁻ = F D⁺ + [f_θ | 0]` with F at the mean, in place column by column.
    #[inline(always)]
    fn predict_sensitivities(&mut self, j: &StepJacobians, lin: &Linearisation<S>) {
        let (nl, nr, counting, diag) = (lin.nl, lin.nr, lin.counting, &lin.diag);
        let d = &mut self.d;
        let (gl, gr) = (j.f_n.column(0) * nl, j.f_n.column(1) * nr);
        let fxs = Matrix3::from_columns(&[-(gl + gr), -gl, -gr]);
        // Remainder columns: −∂f/∂n_w at the mean for turning wheels.
        let mut fxw = M3x2::zeros();
        for w in 0..2 {
            if counting[w] {
                fxw.set_column(w, &(-j.f_n.column(w)));
            }
        }
        for c in 0..NP {
            let (d0, d1, d2) = (d[(0, c)], d[(1, c)], d[(2, c)]);
            let (d3, d4, d5) = (d[(3, c)], d[(4, c)], d[(5, c)]);
            let (d9, d10) = if S > IW { (d[(IW, c)], d[(IW + 1, c)]) } else { (0.0, 0.0) };
            let db = d[(IB, c)];
            for r in 0..3 {
                // ∂f/∂β = ∂f/∂ψ on the position rows, 0 on the heading row.
                let fb = if r < 2 { j.f_x[(r, 2)] } else { 0.0 };
                d[(r, c)] = j.f_x[(r, 0)] * d0
                    + j.f_x[(r, 1)] * d1
                    + j.f_x[(r, 2)] * d2
                    + fxs[(r, 0)] * d3
                    + fxs[(r, 1)] * d4
                    + fxs[(r, 2)] * d5
                    - fb * db
                    + fxw[(r, 0)] * d9
                    + fxw[(r, 1)] * d10;
            }
            for r in 3..S {
                d[(r, c)] *= diag[r];
            }
        }
        for c in 0..4 {
            for r in 0..3 {
                d[(r, c)] += j.f_theta[(r, c)];
            }
        }
    }

    /// The covariance prediction and its derivatives:
    /// `∂P⁻/∂θ_j = F̄ ∂P⁺ F̄ᵀ + (∂F̄ P⁺ F̄ᵀ + F̄ P⁺ ∂F̄ᵀ) + ∂Q/∂θ_j`,
    /// `∂P⁻/∂η_j = F̄ ∂P⁺ F̄ᵀ + ∂Q/∂η_j`.
    #[inline(always)]
    fn predict_covariance<K: KernelCalls>(&mut self, lin: &Linearisation<S>) {
        if let Some(rt) = &lin.rt {
            self.theta_covariance_terms(lin, rt);
        }
        let v = self.v;
        let ft = lin.transition();
        K::propagate_in_place(self.p, &ft);
        add_process_noise(self.p, &lin.q_x, &self.q_s, &self.q_b, self.q_beta);
        add_remainder_noise(self.p, v, lin);
        if self.null {
            K::propagate_in_place(self.p0, &ft);
            add_process_noise(self.p0, &lin.q_x, &self.q_s, &self.q_b, self.q_beta);
            add_remainder_noise(self.p0, v, lin);
            if let Some((c, _)) = &mut self.c0 {
                *c = propagate_cols(c, &ft);
            }
        }
        let cols = self.cols;
        for &jj in cols.as_slice() {
            let dpj = &mut self.dp[jj];
            K::propagate_in_place(dpj, &ft);
            match jj {
                0..=3 => add_sym_rows(dpj, &self.theta_terms[jj]),
                4 => {
                    // η_0 scales the white wheel, quantisation, a_y and β noise together
                    // (quantisation not when it is given, a_y and β not when stated).
                    for r in 0..3 {
                        for c in 0..3 {
                            dpj[(r, c)] += lin.q_x_eta0[(r, c)];
                        }
                    }
                    if v.quant_scaled {
                        add_remainder_noise(dpj, v, lin);
                    }
                    if v.lateral_scaled {
                        dpj[(IB, IB)] += self.q_beta;
                    }
                }
                5 => dpj[(3, 3)] += self.q_s[0],
                6 => {
                    dpj[(4, 4)] += self.q_s[1];
                    dpj[(5, 5)] += self.q_s[2];
                }
                8 => {
                    for r in 0..3 {
                        dpj[(r + 6, r + 6)] += self.q_b[r];
                    }
                }
                // η_3, η_5: the reference noise enters through R only.
                _ => {}
            }
        }
    }

    /// The θ terms of `∂P⁻/∂θ_j` that do not come from `∂P⁺`:
    /// `∂F̄ P⁺ F̄ᵀ` (rows 0..3; added with its mirror) and half of `∂Q/∂θ_j`,
    /// written to `theta_terms[j]`.
    #[inline(always)]
    fn theta_covariance_terms(&mut self, lin: &Linearisation<S>, rt: &ReferenceTerms<4>) {
        let (v, p) = (self.v, &*self.p);
        debug_assert!(*p == MZ::<S>::transpose(p), "P⁺ not exactly symmetric");
        let (nls, nrs, gw, counting) = (lin.nls, lin.nrs, &lin.gw, lin.counting);
        let (f02, f12, fxs_ref, fxw_ref, diag) = (lin.f02, lin.f12, &lin.fxs_ref, &lin.fxw_ref, &lin.diag);
        let (fn_l, fn_r, f_a, f_b) = (lin.fn_l, lin.fn_r, lin.f_a, lin.f_b);
        // The s-columns −F_n n̂ with their θ-derivatives (n̂ = ñ·g, g = 1
        // without `fitted_input`).
        let (fs_l, fs_r) =
            if self.fitted { (rt.fn_l.map(|x| x * gw[0]), rt.fn_r.map(|x| x * gw[1])) } else { (rt.fn_l, rt.fn_r) };
        for (jt, tt) in self.theta_terms.iter_mut().enumerate() {
            let dfl = dvec_of(&rt.fn_l, jt);
            let dfr = dvec_of(&rt.fn_r, jt);
            let (dsl, dsr) = (dvec_of(&fs_l, jt), dvec_of(&fs_r, jt));
            let dfxs = Matrix3::from_columns(&[-dsl * nls - dsr * nrs, -dsl * nls, -dsr * nrs]);
            let (d02, d12) = (rt.f02.d[jt], rt.f12.d[jt]);
            // ∂F̄_xw/∂θ_j = −∂(∂f/∂n_w)/∂θ_j for turning wheels (counting).
            let mut dfxw = M3x2::zeros();
            for (w, df) in [dfl, dfr].into_iter().enumerate() {
                if counting[w] {
                    dfxw.set_column(w, &(-df));
                }
            }
            // G = ∂F̄ P⁺ (rows 0..3 only), stored transposed (Gᵀ, S×3):
            // row rr of G is a combination of rows of P⁺, read as its
            // columns (P⁺ is exactly symmetric), so the inner loop runs
            // down contiguous memory; the sums are the same to the bit.
            let mut gt = MZx3::<S>::zeros();
            let dfr2 = [d02, d12, 0.0];
            for rr in 0..3 {
                let (a2, a3, a4, a5) = (dfr2[rr], dfxs[(rr, 0)], dfxs[(rr, 1)], dfxs[(rr, 2)]);
                let (a9, a10) = (dfxw[(rr, 0)], dfxw[(rr, 1)]);
                for c in 0..S {
                    let (p9, p10) = if S > IW { (p[(c, IW)], p[(c, IW + 1)]) } else { (0.0, 0.0) };
                    gt[(c, rr)] = a2 * p[(c, 2)] + a3 * p[(c, 3)] + a4 * p[(c, 4)] + a5 * p[(c, 5)] - a2 * p[(c, IB)]
                        + a9 * p9
                        + a10 * p10;
                }
            }
            // G F̄ᵀ.
            for rr in 0..3 {
                for ci in 0..S {
                    tt[(rr, ci)] = if ci < 3 {
                        let fr = [f02, f12, 0.0];
                        gt[(ci, rr)]
                            + fr[ci] * gt[(2, rr)]
                            + fxs_ref[(ci, 0)] * gt[(3, rr)]
                            + fxs_ref[(ci, 1)] * gt[(4, rr)]
                            + fxs_ref[(ci, 2)] * gt[(5, rr)]
                            - fr[ci] * gt[(IB, rr)]
                            + if S > IW {
                                fxw_ref[(ci, 0)] * gt[(IW, rr)] + fxw_ref[(ci, 1)] * gt[(IW + 1, rr)]
                            } else {
                                0.0
                            }
                    } else {
                        diag[ci] * gt[(ci, rr)]
                    };
                }
            }
            // ∂Q_x/∂θ_j (symmetric part added as half of A + Aᵀ).
            let dfa = dvec_of(&rt.f_a, jt);
            let dfb = Vector3::new(d02, d12, 0.0);
            let mut half_dq = fn_l * dfl.transpose() * lin.wl
                + fn_r * dfr.transpose() * lin.wr
                + f_b * dfb.transpose() * v.beta_white
                + f_a * dfa.transpose() * v.a_y;
            if self.fitted {
                // ∂(σ²ñ²g²)/∂θ_j = 2σ²ñ²g ∂g/∂θ_j; half of it in the half.
                let dwl = v.white_rel * nls * nls * gw[0].v * gw[0].d[jt];
                let dwr = v.white_rel * nrs * nrs * gw[1].v * gw[1].d[jt];
                half_dq += fn_l * fn_l.transpose() * dwl + fn_r * fn_r.transpose() * dwr;
            }
            for rr in 0..3 {
                for ci in 0..3 {
                    tt[(rr, ci)] += half_dq[(ci, rr)];
                }
            }
            // ∂Q_xw/∂θ_j (the off-diagonal block, added with its mirror).
            for (w, df) in [dfl, dfr].into_iter().enumerate() {
                if counting[w] {
                    for rr in 0..3 {
                        tt[(rr, IW + w)] += df[rr] * v.quant;
                    }
                }
            }
        }
    }
}
