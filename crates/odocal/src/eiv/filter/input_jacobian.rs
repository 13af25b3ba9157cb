//! The input log-Jacobian term of J
//! ([`InputJacobian`]): per wheel
//! `−Σ u·ln(C(θ)/C(θ_ref))` with the weights u of the chosen mode.

use nalgebra::{Matrix3, Vector3};

use super::dispatch::KernelCalls;
use super::kernels::{h_cols, h_rows};
use super::sums::WindowSums;
use super::update::Innovation;
use super::window::{Linearisation, WindowSetup};
use super::{MZ, NP};
use crate::eiv::InputJacobian;
use crate::model::Theta;

/// What the input log-Jacobian term of one window carries from sample to
/// sample: the per-wheel sums at unit weight (Unit, SmoothedShare), the
/// wheel inputs waiting for the next update (FilterShare), and for the
/// smoothed shares `∂P/∂λ` with the weights it gives.
pub(super) struct InputJacobianState<const S: usize> {
    unit_sums: [WindowSums; 2],
    pending: Vec<PendingInput>,
    /// `∂P/∂λ` for [left, right, common]: left/right = that wheel's white
    /// relative noise (and, with SmoothedShareAll, its Gauss-Markov s_w),
    /// common = s_c (SmoothedShareAll only; half to each wheel).
    dp_lambda: [MZ<S>; 3],
    /// `Σ tr(S⁻¹ H ∂P/∂λ Hᵀ)` per entry of `dp_lambda`.
    w_smoothed: [f64; 3],
}

impl<const S: usize> InputJacobianState<S> {
    /// The state at the start of the window.
    #[inline(always)]
    pub(super) fn new(setup: &WindowSetup<'_, S>) -> Self {
        let v = setup.v;
        let mut dp_lambda = [MZ::<S>::zeros(); 3];
        if setup.all_sources {
            dp_lambda[0][(4, 4)] = v.wheel;
            dp_lambda[1][(5, 5)] = v.wheel;
            dp_lambda[2][(3, 3)] = v.common;
        }
        InputJacobianState {
            unit_sums: [WindowSums::zero(), WindowSums::zero()],
            pending: Vec::new(),
            dp_lambda,
            w_smoothed: [0.0; 3],
        }
    }

    /// The prediction step at one sample: each turning wheel's term (at unit
    /// weight, or waiting for the update's share) and the propagation of
    /// `∂P/∂λ`.
    #[inline(always)]
    pub(super) fn predict<K: KernelCalls>(&mut self, setup: &WindowSetup<'_, S>, lin: &Linearisation<S>) {
        let (v, gw, nls, nrs) = (setup.v, &lin.gw, lin.nls, lin.nrs);
        let lc = log_circumference_ratio(lin.uref.a_y, setup.theta, setup.theta_ref);
        // The relative white noise variance of each wheel (rev², the
        // fitted-input factor included; quantisation excluded).
        let g2 = if setup.fitted { [gw[0].v * gw[0].v, gw[1].v * gw[1].v] } else { [1.0, 1.0] };
        let rel = [v.white_rel * nls * nls * g2[0], v.white_rel * nrs * nrs * g2[1]];
        for (w, (n_w, f_w)) in [(lin.nl, lin.fn_l), (lin.nr, lin.fn_r)].into_iter().enumerate() {
            if n_w == 0.0 {
                continue;
            }
            self.unit_sums[w].turning[w] += 1.0;
            match setup.jac_mode {
                InputJacobian::FilterShare | InputJacobian::FilterShareSecondOrder => {
                    if rel[w] > 0.0 {
                        self.pending.push((w, rel[w], f_w, lc[w].0, lc[w].1));
                    }
                }
                _ => add_jacobian_term(&mut self.unit_sums[w], 1.0, lc[w].0, &lc[w].1),
            }
        }
        if !setup.smoothed {
            return;
        }
        let ft = lin.transition();
        for (w, f_w) in [lin.fn_l, lin.fn_r].into_iter().enumerate() {
            let dpl = &mut self.dp_lambda[w];
            K::propagate_in_place(dpl, &ft);
            let q = f_w * f_w.transpose() * rel[w];
            for r_ in 0..3 {
                for c_ in 0..3 {
                    dpl[(r_, c_)] += q[(r_, c_)];
                }
            }
            if setup.all_sources {
                dpl[(4 + w, 4 + w)] += setup.q_s[1 + w];
            }
        }
        if setup.all_sources {
            let dpc = &mut self.dp_lambda[2];
            K::propagate_in_place(dpc, &ft);
            dpc[(3, 3)] += setup.q_s[0];
        }
    }

    /// FilterShare with η derivatives: its terms wait for `∂S/∂η`
    /// ([`InputJacobianState::add_share_eta_terms`]).
    #[inline(always)]
    fn share_eta(setup: &WindowSetup<'_, S>) -> bool {
        let filter_share = matches!(setup.jac_mode, InputJacobian::FilterShare | InputJacobian::FilterShareSecondOrder);
        filter_share && setup.mode.derivs && setup.mode.eta
    }

    /// The measurement update: FilterShare's pending terms (without η
    /// derivatives), or the smoothed shares' weights and the Joseph update
    /// of `∂P/∂λ`.
    #[inline(always)]
    pub(super) fn update<K: KernelCalls>(
        &mut self,
        setup: &WindowSetup<'_, S>,
        inn: &Innovation<S>,
        out: &mut WindowSums,
    ) {
        let second_order = setup.jac_mode == InputJacobian::FilterShareSecondOrder;
        let filter_share = second_order || setup.jac_mode == InputJacobian::FilterShare;
        if filter_share && !Self::share_eta(setup) {
            add_filter_share_terms(out, &mut self.pending, &inn.sinv, second_order, None);
        } else if setup.smoothed {
            let n_l = if setup.all_sources { 3 } else { 2 };
            for (w, dpl) in self.dp_lambda.iter_mut().take(n_l).enumerate() {
                let ds_l = h_cols(&h_rows(dpl));
                self.w_smoothed[w] += (inn.sinv * ds_l).trace();
                K::joseph_in_place(dpl, &inn.k, None);
            }
        }
    }

    /// FilterShare with η derivatives: the pending terms with their
    /// η-derivatives, given the update's `∂S/∂p_j`.
    #[inline(always)]
    pub(super) fn add_share_eta_terms(
        &mut self,
        setup: &WindowSetup<'_, S>,
        inn: &Innovation<S>,
        ds: &[Matrix3<f64>; NP],
        out: &mut WindowSums,
    ) {
        if Self::share_eta(setup) {
            let second_order = setup.jac_mode == InputJacobian::FilterShareSecondOrder;
            add_filter_share_terms(out, &mut self.pending, &inn.sinv, second_order, Some((setup.cols(), ds)));
        }
    }

    /// Adds the window's input log-Jacobian terms to `out` once every sample
    /// has been filtered: Unit and SmoothedShare put the same weight on
    /// every turning sample of the window (FilterShare was added update by
    /// update).
    #[inline(always)]
    pub(super) fn finish(&self, setup: &WindowSetup<'_, S>, out: &mut WindowSums) {
        if setup.all_sources {
            // The smoothed share of the Gauss-Markov noise replaces the ŝ
            // correction in J (kept in M): `jacobian` carries −correction.
            out.jacobian -= out.correction;
        }
        if setup.jac_mode == InputJacobian::None {
            return;
        }
        for (w, u) in self.unit_sums.iter().enumerate() {
            let m = u.turning[w];
            out.turning[w] += m;
            let scale = match setup.jac_mode {
                InputJacobian::Unit => 1.0,
                InputJacobian::SmoothedShare if m > 0.0 => self.w_smoothed[w] / m,
                InputJacobian::SmoothedShareAll if m > 0.0 => (self.w_smoothed[w] + 0.5 * self.w_smoothed[2]) / m,
                _ => 0.0,
            };
            if scale > 0.0 {
                out.jacobian += scale * u.jacobian;
                out.grad_jacobian += u.grad_jacobian * scale;
                out.hess_jacobian += u.hess_jacobian * scale;
                out.jacobian_weight[w] += scale * m;
            }
        }
        if setup.mode.derivs {
            for c in 0..4 {
                out.grad_profile[c] += out.grad_jacobian[c];
            }
            out.h_theta += out.hess_jacobian;
        }
    }
}

/// `ln(C_w(θ)/C_w(θ_ref))` per wheel `[left, right]` at lateral
/// acceleration `a_y` and its θ-gradient `∇C_w/C_w` (θ order
/// `[c_e, c_d, t_r, d]`; the Hessian of the log is `−∇ln C ∇ln Cᵀ`, C being
/// linear in θ).
pub(super) fn log_circumference_ratio(a_y: f64, th: &Theta, th_ref: &Theta) -> [(f64, nalgebra::Vector4<f64>); 2] {
    let (cl, cr) = th.wheel_circumferences(a_y);
    let (rl, rr) = th_ref.wheel_circumferences(a_y);
    let gl = nalgebra::Vector4::new(1.0, 0.5, 0.0, a_y) / cl;
    let gr = nalgebra::Vector4::new(1.0, -0.5, 0.0, -a_y) / cr;
    [((cl / rl).ln(), gl), ((cr / rr).ln(), gr)]
}

/// A wheel input waiting for the next measurement update (FilterShare):
/// wheel index, relative white variance `σ²n̂²`, `f_w = ∂f/∂n_w` (pose rows),
/// `ln(C_w(θ)/C_w(θ_ref))` and its θ-gradient.
pub(super) type PendingInput = (usize, f64, Vector3<f64>, f64, nalgebra::Vector4<f64>);

/// FilterShare: adds every pending input's log-Jacobian term with its
/// weight u, the share `var·f_wᵀS⁻¹f_w` of its white variance that this
/// update removes (`u = share·(1 − 2·share)` with `second_order`), and
/// clears `pending`. With `eta_ds` (the propagated columns and their ∂S),
/// also the weights' η-derivatives: u depends on η through the white
/// variance (∝ e^η₀) and S, so the θ-score's term −Σ u ∇L moves with η,
/// `∂share/∂η_j = [j = 0]·share − var·(S⁻¹f)ᵀ ∂S_j (S⁻¹f)`
/// ([`WindowSums::grad_jacobian_eta`]).
#[inline(always)]
pub(super) fn add_filter_share_terms(
    out: &mut WindowSums,
    pending: &mut Vec<PendingInput>,
    sinv: &Matrix3<f64>,
    second_order: bool,
    eta_ds: Option<(&[usize], &[Matrix3<f64>; NP])>,
) {
    for (w, var, f_w, lc, g) in pending.drain(..) {
        let sf = sinv * f_w;
        let share = var * f_w.dot(&sf);
        let u = if second_order { share * (1.0 - 2.0 * share) } else { share };
        out.jacobian_weight[w] += u;
        add_jacobian_term(out, u, lc, &g);
        if let Some((cols, ds)) = eta_ds {
            let chain = if second_order { 1.0 - 4.0 * share } else { 1.0 };
            for &jj in cols.iter().filter(|c| **c >= 4) {
                let mut dshare = -var * sf.dot(&(ds[jj] * sf));
                if jj == 4 {
                    dshare += share;
                }
                out.grad_jacobian_eta[jj - 4] -= g * (dshare * chain);
            }
        }
    }
}

/// Adds `−u·L` to the value, `−u·∇L` to the gradient and `u·∇L∇Lᵀ` to the
/// Hessian of the input log-Jacobian term.
#[inline(always)]
pub(super) fn add_jacobian_term(out: &mut WindowSums, u: f64, l: f64, g: &nalgebra::Vector4<f64>) {
    out.jacobian -= u * l;
    out.grad_jacobian -= g * u;
    out.hess_jacobian += g * g.transpose() * u;
}
