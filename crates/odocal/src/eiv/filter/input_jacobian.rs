//! The input log-Jacobian term of J ([`InputJacobian`]): per wheel
//! `−Σ u·ln(C(θ)/C(θ_ref))` with the weights u of the chosen mode, and the
//! sums the filter keeps for it over a window.

use nalgebra::{Matrix3, Vector3};

use super::dispatch::KernelCalls;
use super::kernels::{h_cols, h_rows};
use super::sums::WindowSums;
use super::window::Linearisation;
use super::{M3xZ, MZx3, Variances, MZ, NP};
use crate::eiv::InputJacobian;
use crate::model::Theta;

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

/// What a window keeps for the input log-Jacobian term.
pub(super) struct InputJacobianSums<const S: usize> {
    pub(super) mode: InputJacobian,
    /// [`InputJacobian::SmoothedShareAll`].
    pub(super) all_sources: bool,
    /// [`InputJacobian::SmoothedShare`] or [`InputJacobian::SmoothedShareAll`].
    pub(super) smoothed: bool,
    /// Per-wheel sums at unit weight (Unit, SmoothedShare).
    pub(super) unit_sums: [WindowSums; 2],
    /// Samples waiting for the next update (FilterShare).
    pub(super) pending: Vec<PendingInput>,
    /// `∂P/∂λ` for [left, right, common] (SmoothedShare): left/right = that
    /// wheel's white relative noise (and, with SmoothedShareAll, its
    /// Gauss-Markov s_w), common = s_c (SmoothedShareAll only; half to each wheel).
    pub(super) dp_lambda: [MZ<S>; 3],
    /// Σ tr(S⁻¹ ∂S/∂λ) per entry of `dp_lambda`.
    pub(super) w_smoothed: [f64; 3],
}

impl<const S: usize> InputJacobianSums<S> {
    pub(super) fn new(v: &Variances) -> Self {
        let mode = v.input_jacobian;
        let all_sources = mode == InputJacobian::SmoothedShareAll;
        let smoothed = all_sources || mode == InputJacobian::SmoothedShare;
        let mut dp_lambda = [MZ::<S>::zeros(); 3];
        if all_sources {
            dp_lambda[0][(4, 4)] = v.wheel;
            dp_lambda[1][(5, 5)] = v.wheel;
            dp_lambda[2][(3, 3)] = v.common;
        }
        InputJacobianSums {
            mode,
            all_sources,
            smoothed,
            unit_sums: [WindowSums::zero(), WindowSums::zero()],
            pending: Vec::new(),
            dp_lambda,
            w_smoothed: [0.0; 3],
        }
    }

    /// The prediction of sample `lin`: the term of every turning wheel (at
    /// unit weight, or pending for FilterShare) and, for the smoothed
    /// shares, the propagation of `∂P/∂λ`.
    #[inline(always)]
    pub(super) fn predict<K: KernelCalls>(
        &mut self,
        lin: &Linearisation<S>,
        v: &Variances,
        (theta, theta_ref): (&Theta, &Theta),
        fitted: bool,
        q_s: &[f64; 3],
    ) {
        let (nl, nr, nls, nrs, gw) = (lin.nl, lin.nr, lin.nls, lin.nrs, &lin.gw);
        let (fn_l, fn_r) = (lin.fn_l, lin.fn_r);
        let lc = log_circumference_ratio(lin.a_y, theta, theta_ref);
        // The relative white noise variance of each wheel (rev², the
        // fitted-input factor included; quantisation excluded).
        let g2 = if fitted { [gw[0].v * gw[0].v, gw[1].v * gw[1].v] } else { [1.0, 1.0] };
        let rel = [v.white_rel * nls * nls * g2[0], v.white_rel * nrs * nrs * g2[1]];
        for (w, (n_w, f_w)) in [(nl, fn_l), (nr, fn_r)].into_iter().enumerate() {
            if n_w == 0.0 {
                continue;
            }
            self.unit_sums[w].turning[w] += 1.0;
            match self.mode {
                InputJacobian::FilterShare | InputJacobian::FilterShareSecondOrder => {
                    if rel[w] > 0.0 {
                        self.pending.push((w, rel[w], f_w, lc[w].0, lc[w].1));
                    }
                }
                _ => add_jacobian_term(&mut self.unit_sums[w], 1.0, lc[w].0, &lc[w].1),
            }
        }
        if self.smoothed {
            let ft = lin.transition();
            for (w, f_w) in [fn_l, fn_r].into_iter().enumerate() {
                let dpl = &mut self.dp_lambda[w];
                K::propagate_in_place(dpl, &ft);
                let q = f_w * f_w.transpose() * rel[w];
                for r_ in 0..3 {
                    for c_ in 0..3 {
                        dpl[(r_, c_)] += q[(r_, c_)];
                    }
                }
                if self.all_sources {
                    dpl[(4 + w, 4 + w)] += q_s[1 + w];
                }
            }
            if self.all_sources {
                let dpc = &mut self.dp_lambda[2];
                K::propagate_in_place(dpc, &ft);
                dpc[(3, 3)] += q_s[0];
            }
        }
    }

    /// FilterShare: the weights are taken at the update; with η derivatives
    /// (`share_eta`) they wait for ∂S/∂η ([`add_filter_share_terms`] after
    /// the score columns). The smoothed shares: `tr(S⁻¹ ∂S/∂λ)` and the
    /// Joseph update of `∂P/∂λ`.
    #[inline(always)]
    pub(super) fn update<K: KernelCalls>(
        &mut self,
        out: &mut WindowSums,
        hp: &M3xZ<S>,
        sinv: &Matrix3<f64>,
        share_eta: bool,
    ) {
        if self.filter_share() && !share_eta {
            let second_order = self.second_order();
            add_filter_share_terms(out, &mut self.pending, sinv, second_order, None);
        } else if self.smoothed {
            let k_l: MZx3<S> = hp.transpose() * sinv;
            let n_l = if self.all_sources { 3 } else { 2 };
            for (w, dpl) in self.dp_lambda.iter_mut().take(n_l).enumerate() {
                let ds_l = h_cols(&h_rows(dpl));
                self.w_smoothed[w] += (sinv * ds_l).trace();
                K::joseph_in_place(dpl, &k_l, None);
            }
        }
    }

    /// [`InputJacobian::FilterShare`] or its second-order variant.
    #[inline(always)]
    pub(super) fn filter_share(&self) -> bool {
        matches!(self.mode, InputJacobian::FilterShare | InputJacobian::FilterShareSecondOrder)
    }

    /// [`InputJacobian::FilterShareSecondOrder`].
    #[inline(always)]
    pub(super) fn second_order(&self) -> bool {
        self.mode == InputJacobian::FilterShareSecondOrder
    }

    /// Adds the window's term to `out` (and, with `derivs`, its gradient to
    /// the profile gradient and its Hessian to the scoring metric).
    #[inline(always)]
    pub(super) fn finish(&self, out: &mut WindowSums, derivs: bool) {
        if self.all_sources {
            // The smoothed share of the Gauss-Markov noise replaces the ŝ
            // correction in J (kept in M): `jacobian` carries −correction.
            out.jacobian -= out.correction;
        }
        if self.mode == InputJacobian::None {
            return;
        }
        for (w, u) in self.unit_sums.iter().enumerate() {
            let m = u.turning[w];
            out.turning[w] += m;
            // Unit and SmoothedShare: the same weight on every turning sample
            // of the window (FilterShare was added update by update).
            let scale = match self.mode {
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
        if derivs {
            for c in 0..4 {
                out.grad_profile[c] += out.grad_jacobian[c];
            }
            out.h_theta += out.hess_jacobian;
        }
    }
}
