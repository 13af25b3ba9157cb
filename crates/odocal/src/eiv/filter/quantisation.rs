//! Encoder quantisation in the filter: as measurement noise `R_q`
//! ([`QuantisationModel::Measurement`](crate::eiv::QuantisationModel::Measurement))
//! or counted exactly through the remainder states
//! ([`QuantisationModel::Counting`](crate::eiv::QuantisationModel::Counting)).
//!
//! Counting: the true rate of a turning wheel is `ñ_k − w_{k−1} + w_k`, w
//! the remainder of the count in rev/s (`Encoder::measure` of the
//! simulator: `n_k·t_s·T = count + u_{k−1} − u_k`, `w = q(u − ½)`). So the
//! pose rows of the remainder column are `−∂f/∂n_w`, the new remainder w_k
//! is fresh (F row 0, variance q²/12) and enters the pose with `+∂f/∂n_w`
//! (`Q_xw = ∂f/∂n_w·q²/12`). Where a wheel counts nothing (standstill) the
//! remainder is carried over unchanged: no error, no new draw (F row 1).

use nalgebra::{Matrix3, Vector3};

use super::reference::{dvec_of, ReferenceTerms};
use super::window::{Linearisation, WindowFilter};
use super::{M3x2, Variances, IW, MZ};

/// Counting quantisation at one sample: which wheels turn (their remainder
/// is fresh), the diagonal of rows 3..S of F̄ (`base_diag` with 0 at a fresh
/// remainder) and the pose rows of the remainder columns (`−∂f/∂n_w`).
#[inline(always)]
pub(super) fn counting_transition<const S: usize>(
    v: &Variances,
    nl: f64,
    nr: f64,
    fn_l: &Vector3<f64>,
    fn_r: &Vector3<f64>,
    base_diag: &[f64; S],
) -> ([bool; 2], [f64; S], M3x2) {
    let counting = [v.quant_counting && nl != 0.0, v.quant_counting && nr != 0.0];
    let mut diag = *base_diag;
    let mut fxw_ref = M3x2::zeros();
    for (w, f_w) in [fn_l, fn_r].into_iter().enumerate() {
        if counting[w] {
            diag[IW + w] = 0.0;
            fxw_ref.set_column(w, &(-f_w));
        }
    }
    (counting, diag, fxw_ref)
}

/// Quantisation as measurement noise: `R_q = q²/12·(f_l f_lᵀ + f_r f_rᵀ)`
/// (zero for the other models) and, when `∂P/∂θ` is propagated (`rt`),
/// its θ-derivatives written to `r_q_theta`.
#[inline(always)]
pub(super) fn measurement_quantisation(
    v: &Variances,
    fn_l: &Vector3<f64>,
    fn_r: &Vector3<f64>,
    rt: Option<&ReferenceTerms<4>>,
    r_q_theta: &mut [Matrix3<f64>; 4],
) -> Matrix3<f64> {
    let r_q = if v.quant_in_measurement {
        (fn_l * fn_l.transpose() + fn_r * fn_r.transpose()) * v.quant
    } else {
        Matrix3::zeros()
    };
    if v.quant_in_measurement {
        if let Some(rt) = rt {
            for (jt, d_rq) in r_q_theta.iter_mut().enumerate() {
                let (dfl, dfr) = (dvec_of(&rt.fn_l, jt), dvec_of(&rt.fn_r, jt));
                let a = fn_l * dfl.transpose() + fn_r * dfr.transpose();
                *d_rq = (a + a.transpose()) * v.quant;
            }
        }
    }
    r_q
}

/// Counting: the fresh remainder w_k (`Q_ww`) and its share of the pose
/// step (`Q_xw`) added to `m`.
#[inline(always)]
pub(super) fn add_remainder_noise<const S: usize>(m: &mut MZ<S>, v: &Variances, lin: &Linearisation<S>) {
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

impl<const S: usize> WindowFilter<'_, '_, S> {
    /// Quantisation as measurement noise, at the window's first sample: the
    /// window starts at the reference pose, but the counted wheel rotations
    /// are off the true ones by the initial remainder, so the filter's pose
    /// (the count-propagated one) is offset from the true pose by one more
    /// draw of `R_q`, added to P (without it the innovations of a
    /// quantisation-dominated drive are several times their variance).
    #[inline(always)]
    pub(super) fn add_initial_count_offset(&mut self, lin: &Linearisation<S>) {
        let (v, mode, r_q) = (self.v, self.mode, &lin.r_q);
        for r_ in 0..3 {
            for c_ in 0..3 {
                self.p[(r_, c_)] += r_q[(r_, c_)];
                self.p0[(r_, c_)] += r_q[(r_, c_)];
                if mode.derivs && mode.eta && v.quant_scaled {
                    self.dp[4][(r_, c_)] += r_q[(r_, c_)];
                }
                if self.theta_cols {
                    for (jt, d_rq) in self.r_q_theta.iter().enumerate() {
                        self.dp[jt][(r_, c_)] += d_rq[(r_, c_)];
                    }
                }
            }
        }
    }
}
