//! The augmented extended Kalman filter of SPEC §10 over one window, with
//! its exact sensitivity recursion.
//!
//! State `z = [p_x, p_y, ψ, s_c, s_l, s_r, b_x, b_y, b_ψ]`. The covariance
//! recursion (P, S, K) is linearised along the *reference* (the reference
//! heading, the measured wheel rotations and the reference θ of the pass),
//! so it depends on the noise scales η but not on θ; the mean recursion runs
//! the nonlinear model at the current θ. The parameter vector of the
//! sensitivities is `p = [c_e, c_d, t_r, d, η_0 … η_4]`:
//!
//! ```text
//! mean:        D⁻_{k+1} = F_k D⁺_k + [∂f/∂θ | 0]        (F_k at the current mean)
//!              D⁺_k     = (I − K_k H) D⁻_k + [0 | ∂K_k/∂η · ν_k]
//! covariance:  ∂P⁻_{k+1}/∂η_j = F̄_k ∂P⁺_k F̄_kᵀ + ∂Q_k/∂η_j   (F̄_k: reference)
//!              ∂S_k = H ∂P⁻_k Hᵀ + ∂R,  ∂K_k = (∂P⁻_k Hᵀ − K_k ∂S_k) S_k⁻¹
//!              ∂P⁺_k = ∂P⁻_k − K_k H ∂P⁻_k − (K_k H ∂P⁻_k)ᵀ + K_k ∂S_k K_kᵀ
//! innovation:  ∂ν_k/∂p = −H D⁻_k,   ∂S_k/∂θ = 0.
//! ```

use nalgebra::{Matrix3, Matrix3x4, SMatrix, SVector, Vector3};

use super::{EivInput, Window};
use crate::error::{Error, Result};
use crate::model::{step_jacobians, wrap_angle, Input, State, Theta};

/// Number of filter states.
pub(crate) const NZ: usize = 9;
/// Number of sensitivity parameters: 4 θ + 5 η.
pub(crate) const NP: usize = 9;
/// Number of noise scale factors η.
pub(crate) const NETA: usize = 5;

pub(crate) type M9 = SMatrix<f64, NZ, NZ>;
type D9 = SMatrix<f64, NZ, NP>;
pub(crate) type V9 = SVector<f64, NP>;
pub(crate) type M5 = SMatrix<f64, NETA, NETA>;
type M3x9 = SMatrix<f64, 3, NZ>;
type M9x3 = SMatrix<f64, NZ, 3>;

/// Measurement noise floors (SPEC §10): keep S regular on a perfect reference.
const POSITION_FLOOR_M: f64 = 1e-3;
const HEADING_FLOOR_RAD: f64 = 1e-5;

/// Per-sample noise quantities of one filter pass: the base variances of the
/// noise model already multiplied by `exp(η)`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Variances {
    /// Relative white wheel variance σ_white² · e^{η0}.
    pub white_rel: f64,
    /// Quantisation variance q²/12 · e^{η0}, (rev/s)².
    pub quant: f64,
    /// Stationary variance of s_c, σ_c² · e^{η1}.
    pub common: f64,
    /// Stationary variance of s_l and s_r, σ_w² · e^{η2}.
    pub wheel: f64,
    /// Pose white variances `[σ_p², σ_p², σ_ψ²] · e^{η3}` (floors not included).
    pub pose: [f64; 3],
    /// Drift stationary variances `[σ_d², σ_d², σ_dψ²] · e^{η4}`.
    pub drift: [f64; 3],
    /// Lateral acceleration variance (fixed), (m/s²)².
    pub a_y: f64,
    /// Equivalent white sideslip variance (fixed), rad².
    pub beta: f64,
    /// Gauss-Markov coefficients `a = exp(−t_s/τ)`: common, per-wheel, drift.
    pub a_common: f64,
    pub a_wheel: f64,
    pub a_drift: f64,
}

/// Everything one window contributes to the objective and its derivatives.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WindowSums {
    /// Σ νᵀS⁻¹ν.
    pub quad: f64,
    /// Σ log det S.
    pub logdet: f64,
    /// −Σ m log(1 − ŝ) (the coloured-noise correction).
    pub correction: f64,
    /// Gradient of `M = ½ quad + ½ logdet + correction` over p.
    pub grad: V9,
    /// Fisher information of θ, Σ (∂ν/∂θ)ᵀ S⁻¹ (∂ν/∂θ).
    pub h_theta: nalgebra::Matrix4<f64>,
    /// Fisher information of η: Σ (∂ν/∂η)ᵀS⁻¹(∂ν/∂η) + ½ tr(S⁻¹∂S S⁻¹∂S).
    pub i_eta: M5,
    /// Measurement updates.
    pub updates: usize,
    /// Per component of the whitened innovation: Σ e_k e_{k−1}.
    pub lag1: [f64; 3],
    /// Per component: Σ e_k².
    pub e2: [f64; 3],
    /// Expected gradient of the profile cost caused by the input noise,
    /// `Σ_k −tr(S_k⁻¹ H X_k,i Hᵀ)` (the corrected-score term, see [`run_window`]).
    pub bias: nalgebra::Vector4<f64>,
}

impl WindowSums {
    pub(crate) fn zero() -> Self {
        WindowSums {
            quad: 0.0,
            logdet: 0.0,
            correction: 0.0,
            grad: V9::zeros(),
            h_theta: nalgebra::Matrix4::zeros(),
            i_eta: M5::zeros(),
            updates: 0,
            lag1: [0.0; 3],
            e2: [0.0; 3],
            bias: nalgebra::Vector4::zeros(),
        }
    }

    pub(crate) fn add(&mut self, o: &WindowSums) {
        self.quad += o.quad;
        self.logdet += o.logdet;
        self.correction += o.correction;
        self.grad += o.grad;
        self.h_theta += o.h_theta;
        self.i_eta += o.i_eta;
        self.updates += o.updates;
        self.bias += o.bias;
        for c in 0..3 {
            self.lag1[c] += o.lag1[c];
            self.e2[c] += o.e2[c];
        }
    }

    /// The objective `M = ½ Σ(νᵀS⁻¹ν + log det S) − Σ m log(1 − ŝ)`.
    pub(crate) fn merit(&self) -> f64 {
        0.5 * (self.quad + self.logdet) + self.correction
    }

    /// The objective whose θ-gradient is the corrected score:
    /// `M − biasᵀ(θ − θ_ref)` (the bias term is evaluated at θ_ref).
    pub(crate) fn corrected_merit(&self, theta: &Theta, theta_ref: &Theta) -> f64 {
        let d = theta.to_vector() - theta_ref.to_vector();
        self.merit() - self.bias.dot(&d)
    }
}

/// One innovation of a window, kept only for the derivative tests.
#[cfg_attr(not(test), allow(dead_code))]
#[derive(Debug, Clone)]
pub(crate) struct InnovationRecord {
    pub nu: Vector3<f64>,
    pub s: Matrix3<f64>,
    /// ∂ν/∂p (3×9).
    pub dnu: SMatrix<f64, 3, NP>,
    /// ∂S/∂η_j.
    pub ds: [Matrix3<f64>; NETA],
}

/// `F P Fᵀ` for the structured transition
/// `F = [[F_x, F_xs, 0], [0, diag(a_s), 0], [0, 0, a_b I]]`,
/// `F_x = I + e_0 f02 e_2ᵀ + e_1 f12 e_2ᵀ`.
#[inline]
fn propagate(p: &M9, f02: f64, f12: f64, fxs: &Matrix3<f64>, diag: &[f64; 9]) -> M9 {
    // M = F P (row operations).
    let mut m = M9::zeros();
    for j in 0..NZ {
        let (p0, p1, p2) = (p[(0, j)], p[(1, j)], p[(2, j)]);
        let (p3, p4, p5) = (p[(3, j)], p[(4, j)], p[(5, j)]);
        m[(0, j)] = p0 + f02 * p2 + fxs[(0, 0)] * p3 + fxs[(0, 1)] * p4 + fxs[(0, 2)] * p5;
        m[(1, j)] = p1 + f12 * p2 + fxs[(1, 0)] * p3 + fxs[(1, 1)] * p4 + fxs[(1, 2)] * p5;
        m[(2, j)] = p2 + fxs[(2, 0)] * p3 + fxs[(2, 1)] * p4 + fxs[(2, 2)] * p5;
        for r in 3..NZ {
            m[(r, j)] = diag[r] * p[(r, j)];
        }
    }
    // F P Fᵀ = M Fᵀ (column operations).
    let mut out = M9::zeros();
    for i in 0..NZ {
        let (m0, m1, m2) = (m[(i, 0)], m[(i, 1)], m[(i, 2)]);
        let (m3, m4, m5) = (m[(i, 3)], m[(i, 4)], m[(i, 5)]);
        out[(i, 0)] = m0 + f02 * m2 + fxs[(0, 0)] * m3 + fxs[(0, 1)] * m4 + fxs[(0, 2)] * m5;
        out[(i, 1)] = m1 + f12 * m2 + fxs[(1, 0)] * m3 + fxs[(1, 1)] * m4 + fxs[(1, 2)] * m5;
        out[(i, 2)] = m2 + fxs[(2, 0)] * m3 + fxs[(2, 1)] * m4 + fxs[(2, 2)] * m5;
        for c in 3..NZ {
            out[(i, c)] = diag[c] * m[(i, c)];
        }
    }
    out
}

/// `H A` for `H = [I₃ 0 I₃]`: rows 0..3 plus rows 6..9.
#[inline]
fn h_rows<const C: usize>(a: &SMatrix<f64, NZ, C>) -> SMatrix<f64, 3, C> {
    let mut out = SMatrix::<f64, 3, C>::zeros();
    for r in 0..3 {
        for c in 0..C {
            out[(r, c)] = a[(r, c)] + a[(r + 6, c)];
        }
    }
    out
}

/// `B Hᵀ` for a 3×9 `B`: columns 0..3 plus columns 6..9.
#[inline]
fn h_cols(b: &M3x9) -> Matrix3<f64> {
    let mut out = Matrix3::zeros();
    for r in 0..3 {
        for c in 0..3 {
            out[(r, c)] = b[(r, c)] + b[(r, c + 6)];
        }
    }
    out
}

/// `∂(∂f/∂θ)/∂u` (3×4) for the noisy inputs `u = [n_rl, n_rr, a_y]` at
/// `(ψ, u, θ)`: how the noise on an input moves the θ-sensitivity of a step.
fn theta_jacobian_input_derivatives(psi: f64, u: &Input, th: &Theta, ts: f64) -> [(Matrix3x4<f64>, f64, f64); 3] {
    let (c_rl, c_rr) = th.wheel_circumferences(u.a_y);
    let (nl, nr, tr) = (u.n_rl, u.n_rr, th.t_r);
    let v = (nl * c_rl + nr * c_rr) / 2.0;
    let num = nr * c_rr - nl * c_rl;
    let omega = num / tr;
    let h = ts / 2.0;
    let phi = psi + omega * h + u.beta;
    let (s, c) = phi.sin_cos();
    let dcrl = [1.0, 0.5, 0.0, u.a_y];
    let dcrr = [1.0, -0.5, 0.0, -u.a_y];
    let dv: [f64; 4] = std::array::from_fn(|j| (nl * dcrl[j] + nr * dcrr[j]) / 2.0);
    let dw: [f64; 4] =
        std::array::from_fn(|j| (nr * dcrr[j] - nl * dcrl[j]) / tr - if j == 2 { num / (tr * tr) } else { 0.0 });
    // Per input: (∂v/∂u, ∂ω/∂u, ∂dv_j/∂u, ∂dω_j/∂u).
    let d = th.d;
    let inputs: [(f64, f64, [f64; 4], [f64; 4]); 3] = [
        (
            c_rl / 2.0,
            -c_rl / tr,
            std::array::from_fn(|j| dcrl[j] / 2.0),
            std::array::from_fn(|j| -dcrl[j] / tr + if j == 2 { c_rl / (tr * tr) } else { 0.0 }),
        ),
        (
            c_rr / 2.0,
            c_rr / tr,
            std::array::from_fn(|j| dcrr[j] / 2.0),
            std::array::from_fn(|j| dcrr[j] / tr - if j == 2 { c_rr / (tr * tr) } else { 0.0 }),
        ),
        (
            (nl * d - nr * d) / 2.0,
            (-nr * d - nl * d) / tr,
            std::array::from_fn(|j| if j == 3 { (nl - nr) / 2.0 } else { 0.0 }),
            std::array::from_fn(|j| match j {
                3 => (-nr - nl) / tr,
                2 => (nr * d + nl * d) / (tr * tr),
                _ => 0.0,
            }),
        ),
    ];
    inputs.map(|(v_u, w_u, dv_u, dw_u)| {
        let phi_u = w_u * h;
        let mut a = Matrix3x4::zeros();
        for j in 0..4 {
            a[(0, j)] =
                ts * (-s * phi_u * dv[j] + c * dv_u[j] - (v_u * s + v * c * phi_u) * h * dw[j] - v * s * h * dw_u[j]);
            a[(1, j)] =
                ts * (c * phi_u * dv[j] + s * dv_u[j] + (v_u * c - v * s * phi_u) * h * dw[j] + v * c * h * dw_u[j]);
            a[(2, j)] = ts * dw_u[j];
        }
        // ∂F_x[0,2]/∂u and ∂F_x[1,2]/∂u.
        (a, -ts * (v_u * s + v * c * phi_u), ts * (v_u * c - v * s * phi_u))
    })
}

/// `(I − K H) A (I − K H)ᵀ` for `H = [I₃ 0 I₃]`.
#[inline]
fn joseph(a: &M9, k: &M9x3) -> M9 {
    let x = a - k * h_rows(a);
    let mut xh = M9x3::zeros();
    for r in 0..NZ {
        for c in 0..3 {
            xh[(r, c)] = x[(r, c)] + x[(r, c + 6)];
        }
    }
    x - xh * k.transpose()
}

/// The initial covariance of a window and its η-derivatives (SPEC §10):
/// `P_xx = R + Σ_b, P_bb = Σ_b, P_xb = −Σ_b, P_ss = diag(σ²)`.
fn initial_covariance(v: &Variances, r_floor: &[f64; 3]) -> (M9, [M9; NETA]) {
    let mut p = M9::zeros();
    let mut dp = [M9::zeros(); NETA];
    p[(3, 3)] = v.common;
    dp[1][(3, 3)] = v.common;
    for i in 4..6 {
        p[(i, i)] = v.wheel;
        dp[2][(i, i)] = v.wheel;
    }
    for a in 0..3 {
        let (w, dr) = (v.pose[a], v.drift[a]);
        p[(a, a)] = w + r_floor[a] + dr;
        dp[3][(a, a)] = w;
        for m in [&mut p, &mut dp[4]] {
            m[(a + 6, a + 6)] = dr;
            m[(a, a + 6)] = -dr;
            m[(a + 6, a)] = -dr;
        }
        dp[4][(a, a)] = dr;
    }
    (p, dp)
}

/// Runs the filter over one window at θ (mean) with the covariance
/// linearised at `theta_ref`, accumulating the objective, its gradient and
/// the Fisher information. With `eta_derivs` false the η parts are zero.
/// With `record`, every innovation and its derivatives are returned.
pub(crate) fn run_window(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    eta_derivs: bool,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    let ts = input.sample_time_s;
    let mut record = record;
    let r_floor = [
        POSITION_FLOOR_M * POSITION_FLOOR_M,
        POSITION_FLOOR_M * POSITION_FLOOR_M,
        HEADING_FLOOR_RAD * HEADING_FLOOR_RAD,
    ];
    let r_white = Vector3::new(v.pose[0], v.pose[1], v.pose[2]);
    let r = Matrix3::from_diagonal(&(r_white + Vector3::from(r_floor)));
    let dr3 = Matrix3::from_diagonal(&r_white);

    let (mut p, mut dp) = initial_covariance(v, &r_floor);
    let a0 = window.start;
    let mut x = State::new(input.px[a0], input.py[a0], input.psi[a0]);
    let mut s = Vector3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    let mut d = D9::zeros();
    let diag = [1.0, 1.0, 1.0, v.a_common, v.a_wheel, v.a_wheel, v.a_drift, v.a_drift, v.a_drift];
    let q_s = [
        v.common * (1.0 - v.a_common * v.a_common),
        v.wheel * (1.0 - v.a_wheel * v.a_wheel),
        v.wheel * (1.0 - v.a_wheel * v.a_wheel),
    ];
    let q_b: [f64; 3] = std::array::from_fn(|a| v.drift[a] * (1.0 - v.a_drift * v.a_drift));
    // X_i = E[ε⁻ D̃_iᵀ]: cross-covariance of the estimation error and the
    // noise-driven part of the θ-sensitivity (corrected score).
    let mut xcov = [M9::zeros(); 4];
    let mut out = WindowSums::zero();
    let mut prev_e: Option<Vector3<f64>> = None;

    for i in window.start..window.end {
        let (nl, nr) = (input.n_rl[i], input.n_rr[i]);
        let (beta, a_y) = (input.beta[i], input.a_y[i]);

        // --- Reference linearisation: covariance Jacobians and Q (θ_ref).
        let uref = Input { n_rl: nl, n_rr: nr, beta, a_y };
        let jr = step_jacobians(&State::new(0.0, 0.0, input.psi[i]), &uref, theta_ref, ts);
        let (f02, f12) = (jr.f_x[(0, 2)], jr.f_x[(1, 2)]);
        let fn_l = jr.f_n.column(0).into_owned();
        let fn_r = jr.f_n.column(1).into_owned();
        let (crl, crr) = theta_ref.wheel_circumferences(a_y);
        let f_a = fn_l * (nl * theta_ref.d / crl) - fn_r * (nr * theta_ref.d / crr);
        let f_b = Vector3::new(f02, f12, 0.0);
        let (cl, cr) = (fn_l * nl, fn_r * nr);
        let fxs_ref = Matrix3::from_columns(&[-(cl + cr), -cl, -cr]);
        let white = |n: f64| {
            if n == 0.0 {
                0.0
            } else {
                v.white_rel * n * n + v.quant
            }
        };
        let q_white = fn_l * fn_l.transpose() * white(nl) + fn_r * fn_r.transpose() * white(nr);
        let q_x = q_white + f_b * f_b.transpose() * v.beta + f_a * f_a.transpose() * v.a_y;

        let d_post = d;
        // --- Mean prediction at θ, with its exact Jacobians.
        let (m_c, m_l, m_r) = (
            f64::from(u8::from(nl != 0.0 || nr != 0.0)),
            f64::from(u8::from(nl != 0.0)),
            f64::from(u8::from(nr != 0.0)),
        );
        let one_minus = [1.0 - s[0], 1.0 - s[1], 1.0 - s[2]];
        if one_minus.iter().any(|o| *o <= 0.0 || !o.is_finite()) {
            return Err(Error::Numerical(format!(
                "EIV filter diverged in window {} at sample {i}: estimated relative wheel error s = {:?} reached 1",
                window.index,
                [s[0], s[1], s[2]]
            )));
        }
        out.correction -= m_c * one_minus[0].ln() + m_l * one_minus[1].ln() + m_r * one_minus[2].ln();
        for (row, m) in [(3usize, m_c), (4, m_l), (5, m_r)] {
            if m > 0.0 {
                let w = m / one_minus[row - 3];
                for c in 0..NP {
                    out.grad[c] += w * d[(row, c)];
                }
            }
        }
        let ueff = Input { n_rl: nl * (1.0 - s[0] - s[1]), n_rr: nr * (1.0 - s[0] - s[2]), beta, a_y };
        let j = step_jacobians(&x, &ueff, theta, ts);
        let (gl, gr) = (j.f_n.column(0) * nl, j.f_n.column(1) * nr);
        let fxs = Matrix3::from_columns(&[-(gl + gr), -gl, -gr]);
        // D⁻ = F D⁺ + [f_θ | 0].
        let mut dn = D9::zeros();
        for c in 0..NP {
            let (d0, d1, d2) = (d[(0, c)], d[(1, c)], d[(2, c)]);
            let (d3, d4, d5) = (d[(3, c)], d[(4, c)], d[(5, c)]);
            for r in 0..3 {
                dn[(r, c)] = j.f_x[(r, 0)] * d0
                    + j.f_x[(r, 1)] * d1
                    + j.f_x[(r, 2)] * d2
                    + fxs[(r, 0)] * d3
                    + fxs[(r, 1)] * d4
                    + fxs[(r, 2)] * d5;
            }
            for r in 3..NZ {
                dn[(r, c)] = diag[r] * d[(r, c)];
            }
        }
        for c in 0..4 {
            for r in 0..3 {
                dn[(r, c)] += j.f_theta[(r, c)];
            }
        }
        d = dn;
        x = j.next;
        s = Vector3::new(v.a_common * s[0], v.a_wheel * s[1], v.a_wheel * s[2]);
        b *= v.a_drift;

        // --- Covariance prediction (reference Jacobians).
        p = propagate(&p, f02, f12, &fxs_ref, &diag);
        for r in 0..3 {
            for c in 0..3 {
                p[(r, c)] += q_x[(r, c)];
            }
            p[(r + 3, r + 3)] += q_s[r];
            p[(r + 6, r + 6)] += q_b[r];
        }
        if eta_derivs {
            for (jj, dpj) in dp.iter_mut().enumerate() {
                *dpj = propagate(dpj, f02, f12, &fxs_ref, &diag);
                match jj {
                    0 => {
                        // η_0 scales the white wheel, a_y and β noise together.
                        for r in 0..3 {
                            for c in 0..3 {
                                dpj[(r, c)] += q_x[(r, c)];
                            }
                        }
                    }
                    1 => dpj[(3, 3)] += q_s[0],
                    2 => {
                        dpj[(4, 4)] += q_s[1];
                        dpj[(5, 5)] += q_s[2];
                    }
                    3 => {}
                    _ => {
                        for r in 0..3 {
                            dpj[(r + 6, r + 6)] += q_b[r];
                        }
                    }
                }
            }
        }

        // Corrected score: X⁻ = F̄ X⁺ F̄ᵀ − Σ_u var(u) (∂f/∂u)(∂f_θ/∂u)ᵀ.
        let a_u = theta_jacobian_input_derivatives(input.psi[i], &uref, theta_ref, ts);
        // The noise moves the θ-sensitivity through ∂f/∂θ, through F_x (speed
        // in the heading column) and through the s-columns of F (−F_n ñ).
        let g_u = [(fn_l, white(nl)), (fn_r, white(nr)), (f_a, v.a_y)];
        let fs_u = [
            Matrix3::from_columns(&[-fn_l, -fn_l, Vector3::zeros()]),
            Matrix3::from_columns(&[-fn_r, Vector3::zeros(), -fn_r]),
            Matrix3::zeros(),
        ];
        for (ci, xi) in xcov.iter_mut().enumerate() {
            *xi = propagate(xi, f02, f12, &fxs_ref, &diag);
            let dx = Vector3::new(d_post[(0, ci)], d_post[(1, ci)], d_post[(2, ci)]);
            let ds_ = Vector3::new(d_post[(3, ci)], d_post[(4, ci)], d_post[(5, ci)]);
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

        // --- Measurement update where the reference was really measured.
        let k1 = i + 1;
        if let Some(m) = input.reference_measured {
            if !m[k1] {
                continue;
            }
        }
        let y = Vector3::new(input.px[k1], input.py[k1], input.psi[k1]);
        let yhat = x + b;
        let nu = Vector3::new(y[0] - yhat[0], y[1] - yhat[1], wrap_angle(y[2] - yhat[2]));
        let hp: M3x9 = h_rows(&p);
        let s_mat = h_cols(&hp) + r;
        let Some(chol) = s_mat.cholesky() else {
            return Err(Error::Numerical(format!(
                "EIV filter: innovation covariance not positive definite in window {} at sample {k1}",
                window.index
            )));
        };
        let sinv = chol.inverse();
        let l = chol.l();
        let logdet = 2.0 * (l[(0, 0)].ln() + l[(1, 1)].ln() + l[(2, 2)].ln());
        let e = l.solve_lower_triangular(&nu).unwrap_or_else(Vector3::zeros);
        let sinv_nu = sinv * nu;
        let quad = nu.dot(&sinv_nu);
        if !(quad.is_finite() && logdet.is_finite()) {
            return Err(Error::Numerical(format!(
                "EIV filter: non-finite innovation in window {} at sample {k1}",
                window.index
            )));
        }
        out.quad += quad;
        out.logdet += logdet;
        out.updates += 1;
        for c in 0..3 {
            out.e2[c] += e[c] * e[c];
            if let Some(pe) = prev_e {
                out.lag1[c] += e[c] * pe[c];
            }
        }
        prev_e = Some(e);

        let hd = h_rows(&d); // ∂ν/∂p = −H D⁻
                             // Gradient of ½νᵀS⁻¹ν: νᵀS⁻¹ ∂ν = −(HD)ᵀ S⁻¹ ν.
        out.grad -= hd.transpose() * sinv_nu;
        let hd_t = hd.fixed_columns::<4>(0).into_owned();
        out.h_theta += hd_t.transpose() * sinv * hd_t;
        let k: M9x3 = hp.transpose() * sinv;
        for (ci, xi) in xcov.iter_mut().enumerate() {
            out.bias[ci] -= (sinv * h_cols(&h_rows(xi))).trace();
            *xi = joseph(xi, &k);
        }

        let mut ds = [Matrix3::zeros(); NETA];
        let mut dk = [M9x3::zeros(); NETA];
        if eta_derivs {
            let hd_e = hd.fixed_columns::<NETA>(4).into_owned();
            out.i_eta += hd_e.transpose() * sinv * hd_e;
            let mut a = [Matrix3::zeros(); NETA];
            for jj in 0..NETA {
                let hdp: M3x9 = h_rows(&dp[jj]);
                ds[jj] = h_cols(&hdp);
                if jj == 3 {
                    ds[jj] += dr3;
                }
                a[jj] = sinv * ds[jj];
                out.grad[4 + jj] += -0.5 * sinv_nu.dot(&(ds[jj] * sinv_nu)) + 0.5 * a[jj].trace();
                dk[jj] = (hdp.transpose() - k * ds[jj]) * sinv;
            }
            for i1 in 0..NETA {
                for i2 in 0..NETA {
                    out.i_eta[(i1, i2)] += 0.5 * (a[i1] * a[i2]).trace();
                }
            }
        }
        if let Some(rec) = record.as_deref_mut() {
            rec.push(InnovationRecord { nu, s: s_mat, dnu: -hd, ds });
        }

        // State, sensitivity and covariance updates.
        let dz = k * nu;
        for r in 0..3 {
            x[r] += dz[r];
            s[r] += dz[r + 3];
            b[r] += dz[r + 6];
        }
        d -= k * hd;
        if eta_derivs {
            for jj in 0..NETA {
                let col = dk[jj] * nu;
                for r in 0..NZ {
                    d[(r, 4 + jj)] += col[r];
                }
            }
            // Joseph form (I−KH)∂P(I−KH)ᵀ + K ∂R Kᵀ: the algebraically equal
            // ∂P − KH∂P − (KH∂P)ᵀ + K ∂S Kᵀ is numerically unstable here.
            for jj in 0..NETA {
                dp[jj] = joseph(&dp[jj], &k);
                if jj == 3 {
                    dp[jj] += k * dr3 * k.transpose();
                }
            }
        }
        p = joseph(&p, &k) + k * r * k.transpose();
        p = (p + p.transpose()) * 0.5;
    }
    Ok(out)
}
