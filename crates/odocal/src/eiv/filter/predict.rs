//! The prediction step of the window filter: the mean with its
//! sensitivities D ([`MeanState::predict`]), the covariance with its
//! derivatives over `p = [θ, η]` ([`predict_covariance`]) and the
//! corrected score's cross-covariances X ([`predict_corrected_score`]).
//!
//! Every function here is `#[inline(always)]` and takes each array of the
//! recursion as its own argument (see [`super::window`]).

use nalgebra::{Matrix3, Vector3};

use super::dispatch::KernelCalls;
use super::dual::Dual;
use super::kernels::{add_sym_rows, propagate_cols, propagate_general};
use super::reference::{dvec_of, theta_jacobian_input_derivatives, ReferenceTerms};
use super::sums::WindowSums;
use super::window::{Linearisation, WindowSetup};
use super::{M3x2, M3xZ, MZx3, Variances, DZ, IB, IW, MZ, NP};
use crate::eiv::{EivInput, Window};
use crate::error::{Error, Result};
use crate::model::{step_jacobians, State, StepJacobians};

/// The mean of the filter: the pose, the wheel-rotation errors s, the
/// reference drift b, the sideslip error e_β (rad) and, with counting
/// quantisation, the remainders w_{k−1} (rev/s).
pub(super) struct MeanState {
    pub(super) x: State,
    pub(super) s: Vector3<f64>,
    pub(super) b: Vector3<f64>,
    pub(super) eb: f64,
    pub(super) wq: [f64; 2],
}

impl MeanState {
    /// The mean at the start of `window`: the reference pose, no errors.
    #[inline(always)]
    pub(super) fn at_start(input: &EivInput<'_>, window: &Window) -> Self {
        let a0 = window.start;
        MeanState {
            x: State::new(input.px[a0], input.py[a0], input.psi[a0]),
            s: Vector3::zeros(),
            b: Vector3::zeros(),
            eb: 0.0,
            wq: [0.0; 2],
        }
    }

    /// The mean prediction at θ with its exact Jacobians (and, with
    /// derivatives, `D⁻ = F D⁺ + [f_θ | 0]`); adds the coloured-noise
    /// correction `−m log(1 − ŝ)` and its gradient to `out`.
    #[inline(always)]
    pub(super) fn predict<const S: usize>(
        &mut self,
        setup: &WindowSetup<'_, S>,
        lin: &Linearisation<S>,
        d: &mut DZ<S>,
        out: &mut WindowSums,
    ) -> Result<()> {
        let (v, ts) = (setup.v, setup.ts);
        let (nl, nr, counting, s) = (lin.nl, lin.nr, lin.counting, self.s);
        let m = [
            f64::from(u8::from(v.common_mode_jacobian && (nl != 0.0 || nr != 0.0))),
            f64::from(u8::from(nl != 0.0)),
            f64::from(u8::from(nr != 0.0)),
        ];
        let one_minus = [1.0 - s[0], 1.0 - s[1], 1.0 - s[2]];
        if one_minus.iter().any(|o| *o <= 0.0 || !o.is_finite()) {
            return Err(Error::Numerical(format!(
                "EIV filter diverged in window {} at sample {}: estimated relative wheel error s = {:?} reached 1",
                setup.window.index,
                lin.i,
                [s[0], s[1], s[2]]
            )));
        }
        let correction = m[0] * one_minus[0].ln() + m[1] * one_minus[1].ln() + m[2] * one_minus[2].ln();
        out.correction -= correction;
        if !v.coloured_jacobian_in_marginal {
            out.correction_profile_only -= correction;
        }
        // The remainder of the previous count is taken off the measured rate
        // (the new one has mean zero).
        let wsub = [if counting[0] { self.wq[0] } else { 0.0 }, if counting[1] { self.wq[1] } else { 0.0 }];
        let ueff = crate::model::Input {
            n_rl: nl * (1.0 - s[0] - s[1]) - wsub[0],
            n_rr: nr * (1.0 - s[0] - s[2]) - wsub[1],
            beta: lin.uref.beta - self.eb,
            a_y: lin.uref.a_y,
        };
        if setup.mode.derivs {
            add_correction_gradient(out, d, &m, &one_minus, setup.all_sources, v.coloured_jacobian_in_marginal);
            let j = step_jacobians(&self.x, &ueff, setup.theta, ts);
            predict_sensitivities(&j, lin, d, setup.sensitivity_cols());
            self.x = j.next;
        } else {
            self.x = crate::model::step(&self.x, &ueff, setup.theta, ts);
        }
        self.s = Vector3::new(v.a_common * s[0], v.a_wheel * s[1], v.a_wheel * s[2]);
        self.b[0] *= v.a_drift;
        self.b[1] *= v.a_drift;
        self.b[2] *= v.a_drift_heading;
        self.eb *= v.a_beta;
        for w in 0..2 {
            if counting[w] {
                self.wq[w] = 0.0;
            }
        }
        Ok(())
    }

    /// The state update `ẑ⁺ = ẑ⁻ + dz` (`dz = K ν`).
    #[inline(always)]
    pub(super) fn correct<const S: usize>(&mut self, dz: &nalgebra::SVector<f64, S>) {
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
    }
}

/// The gradient of the coloured-noise correction `−Σ m log(1 − ŝ)` through
/// the sensitivities of ŝ (rows 3..6 of D).
#[inline(always)]
fn add_correction_gradient<const S: usize>(
    out: &mut WindowSums,
    d: &DZ<S>,
    m: &[f64; 3],
    one_minus: &[f64; 3],
    all_sources: bool,
    in_marginal: bool,
) {
    for (row, m) in [(3usize, m[0]), (4, m[1]), (5, m[2])] {
        if m > 0.0 {
            let w = m / one_minus[row - 3];
            for c in 0..NP {
                // M's gradient, without the term when M leaves it out.
                if in_marginal {
                    out.grad[c] += w * d[(row, c)];
                }
                if !all_sources {
                    out.grad_profile[c] += w * d[(row, c)];
                }
            }
            for c in 0..4 {
                out.grad_correction[c] += w * d[(row, c)];
            }
        }
    }
}

/// `D⁻ = F D⁺ + [f_θ | 0]` in place, column by column, F the Jacobian of
/// the step at the mean; only the first `ncols` columns (the others stay
/// zero, [`WindowSetup::sensitivity_cols`]).
#[inline(always)]
fn predict_sensitivities<const S: usize>(j: &StepJacobians, lin: &Linearisation<S>, d: &mut DZ<S>, ncols: usize) {
    let (nl, nr, counting, diag) = (lin.nl, lin.nr, lin.counting, &lin.diag);
    let (gl, gr) = (j.f_n.column(0) * nl, j.f_n.column(1) * nr);
    let fxs = Matrix3::from_columns(&[-(gl + gr), -gl, -gr]);
    // Remainder columns: −∂f/∂n_w at the mean for turning wheels.
    let mut fxw = M3x2::zeros();
    for w in 0..2 {
        if counting[w] {
            fxw.set_column(w, &(-j.f_n.column(w)));
        }
    }
    for c in 0..ncols {
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

/// The corrected score (held covariance): `X⁻ = F̄ X⁺ F̄ᵀ − Σ_u var(u)
/// (∂f/∂u)(∂f_θ/∂u)ᵀ`, with the sensitivities D⁺ of the previous update
/// (before the mean prediction).
#[inline(always)]
pub(super) fn predict_corrected_score<const S: usize>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    d: &DZ<S>,
    xcov: &mut [MZ<S>; 4],
) {
    let (fn_l, fn_r, f_a) = (lin.fn_l, lin.fn_r, lin.f_a);
    let a_u = theta_jacobian_input_derivatives(setup.input.psi[lin.i], &lin.uref, setup.theta_ref, setup.ts);
    // The noise moves the θ-sensitivity through ∂f/∂θ, through F_x (speed
    // in the heading column) and through the s-columns of F (−F_n ñ).
    let g_u = [(fn_l, lin.wl), (fn_r, lin.wr), (f_a, setup.v.a_y)];
    let fs_u = [
        Matrix3::from_columns(&[-fn_l, -fn_l, Vector3::zeros()]),
        Matrix3::from_columns(&[-fn_r, Vector3::zeros(), -fn_r]),
        Matrix3::zeros(),
    ];
    let ft = lin.transition();
    for (ci, xi) in xcov.iter_mut().enumerate() {
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

/// The window's first sample with quantisation as measurement noise: the
/// window starts at the reference pose, but the counted wheel rotations are
/// off the true ones by the initial remainder, so the filter's pose is the
/// count-propagated one, offset from the true pose by one more draw of R_q
/// (without it the innovations of a quantisation-dominated drive are several
/// times their variance). Adds R_q to P and P₀ and its derivatives to ∂P.
#[inline(always)]
pub(super) fn add_initial_count_offset<const S: usize>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    p: &mut MZ<S>,
    p0: &mut MZ<S>,
    dp: &mut [MZ<S>; NP],
) {
    let (v, mode, r_q) = (setup.v, setup.mode, &lin.r_q);
    for r_ in 0..3 {
        for c_ in 0..3 {
            p[(r_, c_)] += r_q[(r_, c_)];
            p0[(r_, c_)] += r_q[(r_, c_)];
            if mode.derivs && mode.eta && v.quant_scaled {
                dp[4][(r_, c_)] += r_q[(r_, c_)];
            }
            if setup.theta_cols {
                for (jt, d_rq) in lin.r_q_theta.iter().enumerate() {
                    dp[jt][(r_, c_)] += d_rq[(r_, c_)];
                }
            }
        }
    }
}

/// The covariance prediction `P⁻ = F̄ P⁺ F̄ᵀ + Q` with its derivatives
/// `∂P⁻/∂p_j = F̄ ∂P⁺ F̄ᵀ + (∂F̄ P⁺ F̄ᵀ + F̄ P⁺ ∂F̄ᵀ) + ∂Q/∂p_j` over the
/// propagated columns, and the null pass's P₀ and C₀.
#[inline(always)]
pub(super) fn predict_covariance<const S: usize, K: KernelCalls>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    p: &mut MZ<S>,
    p0: &mut MZ<S>,
    c0: &mut Option<(MZx3<S>, Matrix3<f64>)>,
    dp: &mut [MZ<S>; NP],
    theta_terms: &mut [M3xZ<S>; 4],
) {
    let v = setup.v;
    if let Some(rt) = &lin.rt {
        theta_covariance_terms(setup, lin, rt, p, theta_terms);
    }
    let ft = lin.transition();
    K::propagate_in_place(p, &ft);
    add_process_noise(setup, lin, p);
    add_remainder_noise(v, lin, p);
    if setup.null {
        K::propagate_in_place(p0, &ft);
        add_process_noise(setup, lin, p0);
        add_remainder_noise(v, lin, p0);
        if let Some((c, _)) = c0 {
            *c = propagate_cols(c, &ft);
        }
    }
    for &jj in setup.cols() {
        let dpj = &mut dp[jj];
        K::propagate_in_place(dpj, &ft);
        match jj {
            0..=3 => add_sym_rows(dpj, &theta_terms[jj]),
            4 => {
                // η_0 scales the white wheel, quantisation, a_y and β noise together
                // (quantisation not when it is given, a_y and β not when stated).
                for r in 0..3 {
                    for c in 0..3 {
                        dpj[(r, c)] += lin.q_x_eta0[(r, c)];
                    }
                }
                if v.quant_scaled {
                    add_remainder_noise(v, lin, dpj);
                }
                if v.lateral_scaled {
                    dpj[(IB, IB)] += setup.q_beta;
                }
            }
            5 => dpj[(3, 3)] += setup.q_s[0],
            6 => {
                dpj[(4, 4)] += setup.q_s[1];
                dpj[(5, 5)] += setup.q_s[2];
            }
            8 => {
                let axes = if v.heading_drift_on_white_scale || v.heading_drift_held { 2 } else { 3 };
                for r in 0..axes {
                    dpj[(r + 6, r + 6)] += setup.q_b[r];
                }
            }
            // η_3, η_5: the reference white noise enters through R; the
            // heading drift's process noise too when it is on the heading
            // white noise's scale.
            7 | 9 if v.heading_drift_on_white_scale && jj == if v.heading_separate { 9 } else { 7 } => {
                dpj[(8, 8)] += setup.q_b[2];
            }
            _ => {}
        }
    }
}

/// The step's process noise, the same for the filter's P and the null
/// pass's P₀.
#[inline(always)]
fn add_process_noise<const S: usize>(setup: &WindowSetup<'_, S>, lin: &Linearisation<S>, m: &mut MZ<S>) {
    for r in 0..3 {
        for c in 0..3 {
            m[(r, c)] += lin.q_x[(r, c)];
        }
        m[(r + 3, r + 3)] += setup.q_s[r];
        m[(r + 6, r + 6)] += setup.q_b[r];
    }
    m[(IB, IB)] += setup.q_beta;
}

/// Counting quantisation: the fresh remainder w_k (Q_ww) and its share of
/// the pose step (Q_xw).
#[inline(always)]
fn add_remainder_noise<const S: usize>(v: &Variances, lin: &Linearisation<S>, m: &mut MZ<S>) {
    for (w, f_w) in [lin.fn_l, lin.fn_r].into_iter().enumerate() {
        if lin.counting[w] {
            m[(IW + w, IW + w)] += v.quant;
            for r in 0..3 {
                m[(r, IW + w)] += f_w[r] * v.quant;
                m[(IW + w, r)] += f_w[r] * v.quant;
            }
        }
    }
}

/// The θ-terms of `∂P⁻/∂θ_j` besides `F̄ ∂P⁺ F̄ᵀ`, as the 3×S rows
/// `T_j` with `∂F̄ P⁺ F̄ᵀ + F̄ P⁺ ∂F̄ᵀ + ∂Q/∂θ_j = T_j + T_jᵀ` (rows 0..3).
#[inline(always)]
fn theta_covariance_terms<const S: usize>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    rt: &ReferenceTerms<4>,
    p: &MZ<S>,
    theta_terms: &mut [M3xZ<S>; 4],
) {
    debug_assert!(*p == MZ::<S>::transpose(p), "P⁺ not exactly symmetric");
    // The s-columns −F_n n̂ with their θ-derivatives (n̂ = ñ·g, g = 1
    // without `fitted_input`).
    let fitted_terms;
    let (fs_l, fs_r) = if setup.fitted {
        let gw = lin.gw;
        fitted_terms = (rt.fn_l.map(|x| x * gw[0]), rt.fn_r.map(|x| x * gw[1]));
        (&fitted_terms.0, &fitted_terms.1)
    } else {
        (&rt.fn_l, &rt.fn_r)
    };
    // The propagated θ columns only (`Mode::theta_skip`).
    for &jt in setup.cols().iter().filter(|c| **c < 4) {
        theta_term(setup, lin, rt, (fs_l, fs_r), jt, p, &mut theta_terms[jt]);
    }
}

/// `T_j` of [`theta_covariance_terms`] for θ_j.
#[inline(always)]
fn theta_term<const S: usize>(
    setup: &WindowSetup<'_, S>,
    lin: &Linearisation<S>,
    rt: &ReferenceTerms<4>,
    (fs_l, fs_r): (&[Dual<4>; 3], &[Dual<4>; 3]),
    jt: usize,
    p: &MZ<S>,
    tt: &mut M3xZ<S>,
) {
    let (v, nls, nrs, counting, gw) = (setup.v, lin.nls, lin.nrs, lin.counting, lin.gw);
    let dfl = dvec_of(&rt.fn_l, jt);
    let dfr = dvec_of(&rt.fn_r, jt);
    let (dsl, dsr) = (dvec_of(fs_l, jt), dvec_of(fs_r, jt));
    let dfxs = Matrix3::from_columns(&[-dsl * nls - dsr * nrs, -dsl * nls, -dsr * nrs]);
    let (d02, d12) = (rt.f02.d[jt], rt.f12.d[jt]);
    // ∂F̄_xw/∂θ_j = −∂(∂f/∂n_w)/∂θ_j for turning wheels (counting).
    let mut dfxw = M3x2::zeros();
    for (w, df) in [dfl, dfr].into_iter().enumerate() {
        if counting[w] {
            dfxw.set_column(w, &(-df));
        }
    }
    let mut gt = MZx3::<S>::zeros();
    d_transition_times_p(&[d02, d12, 0.0], &dfxs, &dfxw, p, &mut gt);
    times_transition_transpose(lin, &gt, tt);
    // ∂Q_x/∂θ_j (symmetric part added as half of A + Aᵀ).
    let dfa = dvec_of(&rt.f_a, jt);
    let dfb = Vector3::new(d02, d12, 0.0);
    let (fn_l, fn_r, f_a, f_b, wl, wr) = (lin.fn_l, lin.fn_r, lin.f_a, lin.f_b, lin.wl, lin.wr);
    let mut half_dq = fn_l * dfl.transpose() * wl
        + fn_r * dfr.transpose() * wr
        + f_b * dfb.transpose() * v.beta_white
        + f_a * dfa.transpose() * v.a_y;
    if setup.fitted {
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

/// `G = ∂F̄ P⁺` (rows 0..3 only; `∂F̄` has the heading, s, sideslip and
/// remainder columns `dfr2`, `dfxs`, `−dfr2`, `dfxw`), written transposed
/// into `gt` (Gᵀ, S×3): row rr of G is a combination of rows of P⁺, read as its
/// columns (P⁺ is exactly symmetric), so the inner loop runs down
/// contiguous memory; the sums are the same to the bit.
#[inline(always)]
fn d_transition_times_p<const S: usize>(
    dfr2: &[f64; 3],
    dfxs: &Matrix3<f64>,
    dfxw: &M3x2,
    p: &MZ<S>,
    gt: &mut MZx3<S>,
) {
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
}

/// `tt = G F̄ᵀ` for `gt = Gᵀ` ([`d_transition_times_p`]).
#[inline(always)]
fn times_transition_transpose<const S: usize>(lin: &Linearisation<S>, gt: &MZx3<S>, tt: &mut M3xZ<S>) {
    let (f02, f12, fxs_ref, fxw_ref, diag) = (lin.f02, lin.f12, lin.fxs_ref, lin.fxw_ref, lin.diag);
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
                    + if S > IW { fxw_ref[(ci, 0)] * gt[(IW, rr)] + fxw_ref[(ci, 1)] * gt[(IW + 1, rr)] } else { 0.0 }
            } else {
                diag[ci] * gt[(ci, rr)]
            };
        }
    }
}
