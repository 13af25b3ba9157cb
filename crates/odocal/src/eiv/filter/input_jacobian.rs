//! The input log-Jacobian term of J
//! ([`InputJacobian`](crate::eiv::InputJacobian)): per wheel
//! `−Σ u·ln(C(θ)/C(θ_ref))` with the weights u of the chosen mode.

use nalgebra::{Matrix3, Vector3};

use super::sums::WindowSums;
use super::NP;
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
