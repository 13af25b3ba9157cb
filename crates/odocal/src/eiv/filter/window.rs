//! The filter over one window ([`run_window_s`]): per sample the
//! linearisation along the reference, the prediction of the mean and the
//! covariance with their derivatives, and the measurement update.
//!
//! One function on purpose: every array of the recursion (P, the `∂P/∂p_j`,
//! the sensitivities D, the work arrays) is a local of it, so the optimiser
//! sees that they never overlap and vectorises the covariance kernels that
//! the AVX2 build inlines. The same recursion written as a window-state type
//! with `linearise`/`predict`/`update` methods, the arrays fields of the
//! type or borrowed from locals, gives the same results to the bit but the
//! kernels inlined into the AVX2 build stay scalar: +36 % instructions on
//! the AVX2 path (callgrind, `RAYON_NUM_THREADS=1 odocal calibrate` of
//! `odocal simulate --seed 1 --length-km 2`), +15 to +30 % CPU time on
//! 8 km. Helpers that take the arrays as explicit `&mut` arguments, not
//! through a struct, would keep them distinct for the optimiser; they are
//! not written.

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::dispatch::KernelCalls;
use super::dual::Dual;
use super::input_jacobian::{add_filter_share_terms, add_jacobian_term, log_circumference_ratio, PendingInput};
use super::kernels::{add_sym_rows, h_cols, h_rows, joseph_general, propagate_cols, propagate_general, Transition};
use super::reference::{dvec_of, fitted_input_factors, reference_terms, theta_jacobian_input_derivatives};
use super::sums::{InnovationRecord, WindowSums, SCORE_BLOCK_S};
use super::{M3x2, M3xZ, MZx3, Mode, Variances, DZ, HEADING_FLOOR_RAD, IB, IW, MZ, NETA, NP};
use crate::eiv::{EivInput, InputJacobian, Window};
use crate::error::{Error, Result};
use crate::model::{step_jacobians, wrap_angle, Input, State, Theta};

/// The initial covariance of a window and its derivatives over
/// `p = [θ, η]` (SPEC §10): `P_xx = R + Σ_b, P_bb = Σ_b, P_xb = −Σ_b,
/// P_ss = diag(σ²)`, with counting quantisation `P_ww = q²/12·I` (the
/// remainders before the first sample); it does not depend on θ.
fn initial_covariance<const S: usize>(v: &Variances, r_floor: &[f64; 3]) -> (MZ<S>, [MZ<S>; NP]) {
    let mut p = MZ::<S>::zeros();
    let mut dp = [MZ::<S>::zeros(); NP];
    if v.quant_counting {
        for i in IW..S {
            p[(i, i)] = v.quant;
            if v.quant_scaled {
                dp[4][(i, i)] = v.quant;
            }
        }
    }
    p[(3, 3)] = v.common;
    dp[5][(3, 3)] = v.common;
    // The sideslip error starts stationary (η_0 scales it unless stated).
    p[(IB, IB)] = v.beta;
    if v.lateral_scaled {
        dp[4][(IB, IB)] = v.beta;
    }
    for i in 4..6 {
        p[(i, i)] = v.wheel;
        dp[6][(i, i)] = v.wheel;
    }
    for a in 0..3 {
        let (w, dr) = (v.pose[a], v.drift[a]);
        p[(a, a)] = w + r_floor[a] + dr;
        // η_3 scales the position white noise, η_5 the heading white noise.
        dp[if a < 2 || !v.heading_separate { 7 } else { 9 }][(a, a)] = w;
        for m in [&mut p, &mut dp[8]] {
            m[(a + 6, a + 6)] = dr;
            m[(a, a + 6)] = -dr;
            m[(a + 6, a)] = -dr;
        }
        dp[8][(a, a)] = dr;
    }
    (p, dp)
}

/// [`run_window`](super::run_window) with the state size `S` (`NZ` or
/// `IW`), the big covariance kernels called as `K` says. Always inlined, so
/// that [`run_window_avx2`](super::dispatch::run_window_avx2) compiles it
/// (and the kernels it inlines) for AVX2.
#[inline(always)]
pub(super) fn run_window_s<const S: usize, K: KernelCalls>(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    let ts = input.sample_time_s;
    let mut record = record;
    let follows = mode.follows_theta;
    let theta_cov = if follows { theta } else { theta_ref };
    // ∂P/∂θ is propagated (covariance following θ, θ derivatives wanted).
    let theta_cols = mode.derivs && mode.theta && follows;
    // Sensitivity columns whose covariance derivatives are propagated. With
    // the heading white noise tied to the position's (η_3), ∂P/∂η_5 ≡ 0.
    let mut cols_buf = [0usize; NP];
    let mut ncols = 0;
    for c in 0..NP {
        let on = mode.derivs
            && if c < 4 {
                theta_cols
            } else {
                mode.eta && (c != 9 || v.heading_separate) && (mode.eta_skip >> (c - 4)) & 1 == 0
            };
        if on {
            cols_buf[ncols] = c;
            ncols += 1;
        }
    }
    let cols = &cols_buf[..ncols];
    // The corrected score (X recursion) is needed only with the covariance held.
    let corrected = mode.derivs && mode.theta && !follows;
    let r_floor = [
        v.position_floor_m * v.position_floor_m,
        v.position_floor_m * v.position_floor_m,
        HEADING_FLOOR_RAD * HEADING_FLOOR_RAD,
    ];
    let r_white = Vector3::new(v.pose[0], v.pose[1], v.pose[2]);
    let r = Matrix3::from_diagonal(&(r_white + Vector3::from(r_floor)));
    // ∂R/∂η_3 (position white) and ∂R/∂η_5 (heading white).
    let (h_pos, h_head) = if v.heading_separate { (0.0, v.pose[2]) } else { (v.pose[2], 0.0) };
    let dr_position = Matrix3::from_diagonal(&Vector3::new(v.pose[0], v.pose[1], h_pos));
    let dr_heading = Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, h_head));

    let (mut p, mut dp) = initial_covariance(v, &r_floor);
    // Null recursion of the innovation diagnostics (`null_without_floors`):
    // the true error covariance P₀ when the data have no floor noise, its
    // cross-covariance C₀ = E[ε ν_prevᵀ] with the previous innovation, and
    // the previous update's Cholesky factor of S (the whitening).
    let null = v.null_without_floors;
    let mut p0 = p;
    if null {
        for (a, f) in r_floor.iter().enumerate() {
            p0[(a, a)] -= f;
        }
    }
    let mut c0: Option<(MZx3<S>, Matrix3<f64>)> = None;
    let a0 = window.start;
    let mut x = State::new(input.px[a0], input.py[a0], input.psi[a0]);
    let mut s = Vector3::<f64>::zeros();
    let mut b = Vector3::<f64>::zeros();
    // The estimated sideslip error e_β (rad).
    let mut eb = 0.0f64;
    // Counting quantisation: the estimated remainders w_{k−1} (rev/s).
    let mut wq = [0.0f64; 2];
    let mut d = DZ::<S>::zeros();
    let mut base_diag = [1.0; S];
    base_diag[3..IW].copy_from_slice(&[v.a_common, v.a_wheel, v.a_wheel, v.a_drift, v.a_drift, v.a_drift, v.a_beta]);
    let q_beta = v.beta * (1.0 - v.a_beta * v.a_beta);
    let q_s = [
        v.common * (1.0 - v.a_common * v.a_common),
        v.wheel * (1.0 - v.a_wheel * v.a_wheel),
        v.wheel * (1.0 - v.a_wheel * v.a_wheel),
    ];
    let q_b: [f64; 3] = std::array::from_fn(|a| v.drift[a] * (1.0 - v.a_drift * v.a_drift));
    // X_i = E[ε⁻ D̃_iᵀ]: cross-covariance of the estimation error and the
    // noise-driven part of the θ-sensitivity (corrected score).
    let mut xcov = [MZ::<S>::zeros(); 4];
    let mut out = WindowSums::zero();
    let mut prev_e: Option<Vector3<f64>> = None;
    // Per-sample work arrays (only the entries of `cols` are written; the
    // rest stay zero, as the records expect).
    let mut theta_terms: [M3xZ<S>; 4] = [M3xZ::<S>::zeros(); 4];
    let mut r_q_theta = [Matrix3::<f64>::zeros(); 4];
    let mut ds = [Matrix3::<f64>::zeros(); NP];
    let mut a = [Matrix3::<f64>::zeros(); NP];
    let mut dkn = DZ::<S>::zeros();
    // H ∂P⁻/∂p_j of the update (for ∂S and again in the Joseph form).
    let mut hdps = [M3xZ::<S>::zeros(); NP];
    // Input log-Jacobian term: per-wheel sums at unit weight (Unit,
    // SmoothedShare), samples waiting for the next update (FilterShare:
    // wheel, σ²n̂², f_w, ln C ratio, its gradient) and ∂P/∂λ_w (SmoothedShare).
    let jac_mode = v.input_jacobian;
    let mut unit_sums = [WindowSums::zero(), WindowSums::zero()];
    let mut pending: Vec<PendingInput> = Vec::new();
    // ∂P/∂λ for [left, right, common]: left/right = that wheel's white
    // relative noise (and, with SmoothedShareAll, its Gauss-Markov s_w),
    // common = s_c (SmoothedShareAll only; half to each wheel).
    let all_sources = jac_mode == InputJacobian::SmoothedShareAll;
    let smoothed = all_sources || jac_mode == InputJacobian::SmoothedShare;
    let mut dp_lambda = [MZ::<S>::zeros(); 3];
    if all_sources {
        dp_lambda[0][(4, 4)] = v.wheel;
        dp_lambda[1][(5, 5)] = v.wheel;
        dp_lambda[2][(3, 3)] = v.common;
    }
    let mut w_smoothed = [0.0; 3];
    // The rotations that scale the relative wheel noise with the fitted
    // input: ñ, or its moving average over ±K samples within the window
    // (nearly independent of the white error of sample i).
    let half = if v.fitted_input && follows { v.noise_input_half_width } else { 0 };
    let smooth_of = |n: &[f64]| -> Vec<f64> {
        if half == 0 {
            return Vec::new();
        }
        let (a0, a1) = (window.start, window.end);
        let mut prefix = Vec::with_capacity(a1 - a0 + 1);
        prefix.push(0.0);
        for k in a0..a1 {
            let last = prefix[prefix.len() - 1];
            prefix.push(last + n[k]);
        }
        (a0..a1)
            .map(|k| {
                let (lo, hi) = (k.saturating_sub(half).max(a0), (k + half + 1).min(a1));
                (prefix[hi - a0] - prefix[lo - a0]) / (hi - lo) as f64
            })
            .collect()
    };
    let (smooth_l, smooth_r) = if half > 0 && v.noise_input_from_reference {
        // Wheel rotations implied by the reference at θ_ref: speed and yaw
        // rate by central differences over ±K samples (within the window),
        // C_l n_l = v − ψ̇ t_r/2, C_r n_r = v + ψ̇ t_r/2 (rev/s), with the
        // sign of the measured rotation (independent of the wheel noise).
        let (a0, a1) = (window.start, window.end);
        let mut l = Vec::with_capacity(a1 - a0);
        let mut r = Vec::with_capacity(a1 - a0);
        for k in a0..a1 {
            let (lo, hi) = (k.saturating_sub(half).max(a0), (k + half).min(a1));
            let dt = (hi - lo).max(1) as f64 * ts;
            let speed = (input.px[hi] - input.px[lo]).hypot(input.py[hi] - input.py[lo]) / dt;
            let yaw_rate = wrap_angle(input.psi[hi] - input.psi[lo]) / dt;
            let (c_l, c_r) = theta_ref.wheel_circumferences(input.a_y[k]);
            let nl_ = (speed - 0.5 * yaw_rate * theta_ref.t_r) / c_l;
            let nr_ = (speed + 0.5 * yaw_rate * theta_ref.t_r) / c_r;
            l.push(nl_.abs() * input.n_rl[k].signum() * f64::from(u8::from(input.n_rl[k] != 0.0)));
            r.push(nr_.abs() * input.n_rr[k].signum() * f64::from(u8::from(input.n_rr[k] != 0.0)));
        }
        (l, r)
    } else {
        (smooth_of(input.n_rl), smooth_of(input.n_rr))
    };

    // The open block of θ-scores ([`BlockScores`]).
    let (mut block_index, mut block_open) = (0usize, false);
    let mut block_sum = nalgebra::Vector4::<f64>::zeros();
    let mut block_prev: Option<nalgebra::Vector4<f64>> = None;
    for i in window.start..window.end {
        let (nl, nr) = (input.n_rl[i], input.n_rr[i]);
        // The rotations scaling the relative noise (smoothed when asked).
        let (nls, nrs) = if half > 0 { (smooth_l[i - window.start], smooth_r[i - window.start]) } else { (nl, nr) };
        let (beta, a_y) = (input.beta[i], input.a_y[i]);

        // --- Covariance linearisation along the reference (at θ_cov).
        let uref = Input { n_rl: nl, n_rr: nr, beta, a_y };
        let (rv, rt) = if theta_cols {
            let rt = reference_terms::<4>(input.psi[i], &uref, theta_cov, ts);
            (rt.values(), Some(rt))
        } else {
            (reference_terms::<0>(input.psi[i], &uref, theta_cov, ts).values(), None)
        };
        let (f02, f12) = (rv.f02, rv.f12);
        let (fn_l, fn_r, f_a) = (rv.fn_l, rv.fn_r, rv.f_a);
        // With `fitted_input` the relative wheel noise is scaled by the fitted
        // true input n̂ = ñ·g, g = C(θ_ref)/C(θ): the s-columns of F̄ are
        // −F_n n̂ and the white variance is σ²n̂² (g = 1 otherwise).
        let fitted = v.fitted_input && follows;
        let gw = if fitted { fitted_input_factors(a_y, theta, theta_ref) } else { [Dual::cst(1.0); 2] };
        let fxs_ref = if fitted {
            let (sl, sr) = (fn_l * gw[0].v, fn_r * gw[1].v);
            Matrix3::from_columns(&[-sl * nls - sr * nrs, -sl * nls, -sr * nrs])
        } else {
            Matrix3::from_columns(&[-fn_l * nl - fn_r * nr, -fn_l * nl, -fn_r * nr])
        };
        // Counting quantisation (exact): the true rate of a turning wheel is
        // ñ_k − w_{k−1} + w_k, w the remainder of the count in rev/s
        // (`Encoder::measure` of the simulator: n_k·t_s·T = count + u_{k−1} − u_k,
        // w = q(u − ½)). So the pose rows of the remainder column are −∂f/∂n_w,
        // the new remainder w_k is fresh (F row 0, variance q²/12) and enters
        // the pose with +∂f/∂n_w (Q_xw = ∂f/∂n_w·q²/12). Where a wheel counts
        // nothing (standstill) the remainder is carried over unchanged: no
        // error, no new draw (F row 1).
        let counting = [v.quant_counting && nl != 0.0, v.quant_counting && nr != 0.0];
        let mut diag = base_diag;
        let mut fxw_ref = M3x2::zeros();
        for (w, f_w) in [fn_l, fn_r].into_iter().enumerate() {
            if counting[w] {
                diag[IW + w] = 0.0;
                fxw_ref.set_column(w, &(-f_w));
            }
        }
        let ft = Transition { f02, f12, fxs: &fxs_ref, fxw: &fxw_ref, diag: &diag };
        // White relative noise accumulates into the pose (process noise).
        // Encoder quantisation does not (with `quant_in_measurement`, an
        // approximation; `quant_counting` models it exactly through the
        // remainder states): counting ticks carries the remainder
        // over, so the counted rotation is the true one to within one tick
        // at every sample, and the pose error it causes is bounded — white
        // in the *measurement*, `R_q = q²/12·(f_l f_lᵀ + f_r f_rᵀ)` with the
        // step's `∂f/∂n` (a tick of the wheel moves the pose by `∂f/∂n·q`).
        // As process noise it accumulated like a random walk and, on the
        // heading, made the filter misread quantisation as reference noise
        // (docs/study.md, EIV section).
        let (wl, wr) = if fitted {
            let white = |n: f64, ns: f64, g: f64| {
                let q = if v.quant_in_measurement || n == 0.0 { 0.0 } else { v.quant };
                v.white_rel * ns * ns * g * g + q
            };
            (white(nl, nls, gw[0].v), white(nr, nrs, gw[1].v))
        } else if v.quant_in_measurement {
            (v.white_rel * nl * nl, v.white_rel * nr * nr)
        } else {
            // Quantisation as white rate noise where the wheel turns.
            let white = |n: f64| if n == 0.0 { 0.0 } else { v.white_rel * n * n + v.quant };
            (white(nl), white(nr))
        };
        let r_q = if v.quant_in_measurement {
            (fn_l * fn_l.transpose() + fn_r * fn_r.transpose()) * v.quant
        } else {
            Matrix3::zeros()
        };
        if v.quant_in_measurement {
            if let Some(rt) = &rt {
                for (jt, d_rq) in r_q_theta.iter_mut().enumerate() {
                    let (dfl, dfr) = (dvec_of(&rt.fn_l, jt), dvec_of(&rt.fn_r, jt));
                    let a = fn_l * dfl.transpose() + fn_r * dfr.transpose();
                    *d_rq = (a + a.transpose()) * v.quant;
                }
            }
        }
        if i == window.start && v.quant_in_measurement {
            // The window starts at the reference pose, but the counted wheel
            // rotations are off the true ones by the initial remainder: the
            // filter's pose is the count-propagated one, offset from the true
            // pose by one more draw of R_q (without it the innovations of a
            // quantisation-dominated drive were several times their variance).
            for r_ in 0..3 {
                for c_ in 0..3 {
                    p[(r_, c_)] += r_q[(r_, c_)];
                    p0[(r_, c_)] += r_q[(r_, c_)];
                    if mode.derivs && mode.eta && v.quant_scaled {
                        dp[4][(r_, c_)] += r_q[(r_, c_)];
                    }
                    if theta_cols {
                        for (jt, d_rq) in r_q_theta.iter().enumerate() {
                            dp[jt][(r_, c_)] += d_rq[(r_, c_)];
                        }
                    }
                }
            }
        }
        let q_white = fn_l * fn_l.transpose() * wl + fn_r * fn_r.transpose() * wr;
        // The quantisation's share of q_white (rate noise or the counting
        // remainder's pose share): not scaled by η_0 when the level is given.
        let q_x_quant = if v.quant_scaled || v.quant_in_measurement {
            Matrix3::zeros()
        } else {
            let q_of = |n: f64| if n == 0.0 { 0.0 } else { v.quant };
            fn_l * fn_l.transpose() * q_of(nl) + fn_r * fn_r.transpose() * q_of(nr)
        };
        // a_y's white noise; β's Gauss-Markov error is the state e_β (or,
        // with `SideslipNoise::WhiteEquivalent`, white noise: `beta_white`).
        let f_b = Vector3::new(f02, f12, 0.0);
        let q_lateral = f_b * f_b.transpose() * v.beta_white + f_a * f_a.transpose() * v.a_y;
        let q_x = q_white + q_lateral;
        // The share of Q_x that η_0 scales: not the quantisation's when its
        // level is given, not a_y's and β's when their noise is stated.
        let q_x_eta0 = if v.lateral_scaled { q_x - q_x_quant } else { q_white - q_x_quant };
        if jac_mode != InputJacobian::None {
            let lc = log_circumference_ratio(a_y, theta, theta_ref);
            // The relative white noise variance of each wheel (rev², the
            // fitted-input factor included; quantisation excluded).
            let g2 = if fitted { [gw[0].v * gw[0].v, gw[1].v * gw[1].v] } else { [1.0, 1.0] };
            let rel = [v.white_rel * nls * nls * g2[0], v.white_rel * nrs * nrs * g2[1]];
            for (w, (n_w, f_w)) in [(nl, fn_l), (nr, fn_r)].into_iter().enumerate() {
                if n_w == 0.0 {
                    continue;
                }
                unit_sums[w].turning[w] += 1.0;
                match jac_mode {
                    InputJacobian::FilterShare | InputJacobian::FilterShareSecondOrder => {
                        if rel[w] > 0.0 {
                            pending.push((w, rel[w], f_w, lc[w].0, lc[w].1));
                        }
                    }
                    _ => add_jacobian_term(&mut unit_sums[w], 1.0, lc[w].0, &lc[w].1),
                }
            }
            if smoothed {
                for (w, f_w) in [fn_l, fn_r].into_iter().enumerate() {
                    let dpl = &mut dp_lambda[w];
                    K::propagate_in_place(dpl, &ft);
                    let q = f_w * f_w.transpose() * rel[w];
                    for r_ in 0..3 {
                        for c_ in 0..3 {
                            dpl[(r_, c_)] += q[(r_, c_)];
                        }
                    }
                    if all_sources {
                        dpl[(4 + w, 4 + w)] += q_s[1 + w];
                    }
                }
                if all_sources {
                    let dpc = &mut dp_lambda[2];
                    K::propagate_in_place(dpc, &ft);
                    dpc[(3, 3)] += q_s[0];
                }
            }
        }

        // --- Corrected score (held covariance): X⁻ = F̄ X⁺ F̄ᵀ − Σ_u var(u) (∂f/∂u)(∂f_θ/∂u)ᵀ,
        // with the sensitivities D⁺ of the previous update (before the mean prediction).
        if corrected {
            let a_u = theta_jacobian_input_derivatives(input.psi[i], &uref, theta_ref, ts);
            // The noise moves the θ-sensitivity through ∂f/∂θ, through F_x (speed
            // in the heading column) and through the s-columns of F (−F_n ñ).
            let g_u = [(fn_l, wl), (fn_r, wr), (f_a, v.a_y)];
            let fs_u = [
                Matrix3::from_columns(&[-fn_l, -fn_l, Vector3::zeros()]),
                Matrix3::from_columns(&[-fn_r, Vector3::zeros(), -fn_r]),
                Matrix3::zeros(),
            ];
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
        // The remainder of the previous count is taken off the measured rate
        // (the new one has mean zero).
        let wsub = [if counting[0] { wq[0] } else { 0.0 }, if counting[1] { wq[1] } else { 0.0 }];
        let ueff = Input {
            n_rl: nl * (1.0 - s[0] - s[1]) - wsub[0],
            n_rr: nr * (1.0 - s[0] - s[2]) - wsub[1],
            beta: beta - eb,
            a_y,
        };
        if mode.derivs {
            for (row, m) in [(3usize, m_c), (4, m_l), (5, m_r)] {
                if m > 0.0 {
                    let w = m / one_minus[row - 3];
                    for c in 0..NP {
                        out.grad[c] += w * d[(row, c)];
                        if !all_sources {
                            out.grad_profile[c] += w * d[(row, c)];
                        }
                    }
                    for c in 0..4 {
                        out.grad_correction[c] += w * d[(row, c)];
                    }
                }
            }
            let j = step_jacobians(&x, &ueff, theta, ts);
            let (gl, gr) = (j.f_n.column(0) * nl, j.f_n.column(1) * nr);
            let fxs = Matrix3::from_columns(&[-(gl + gr), -gl, -gr]);
            // Remainder columns: −∂f/∂n_w at the mean for turning wheels.
            let mut fxw = M3x2::zeros();
            for w in 0..2 {
                if counting[w] {
                    fxw.set_column(w, &(-j.f_n.column(w)));
                }
            }
            // D⁻ = F D⁺ + [f_θ | 0], in place column by column.
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
            x = j.next;
        } else {
            x = crate::model::step(&x, &ueff, theta, ts);
        }
        s = Vector3::new(v.a_common * s[0], v.a_wheel * s[1], v.a_wheel * s[2]);
        b *= v.a_drift;
        eb *= v.a_beta;
        for w in 0..2 {
            if counting[w] {
                wq[w] = 0.0;
            }
        }

        // --- Covariance prediction and its derivatives.
        // ∂P⁻/∂θ_j = F̄ ∂P⁺ F̄ᵀ + (∂F̄ P⁺ F̄ᵀ + F̄ P⁺ ∂F̄ᵀ) + ∂Q/∂θ_j.
        if let Some(rt) = &rt {
            debug_assert!(p == MZ::<S>::transpose(&p), "P⁺ not exactly symmetric");
            // The s-columns −F_n n̂ with their θ-derivatives (n̂ = ñ·g, g = 1
            // without `fitted_input`).
            let (fs_l, fs_r) =
                if fitted { (rt.fn_l.map(|x| x * gw[0]), rt.fn_r.map(|x| x * gw[1])) } else { (rt.fn_l, rt.fn_r) };
            for (jt, tt) in theta_terms.iter_mut().enumerate() {
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
                        gt[(c, rr)] = a2 * p[(c, 2)] + a3 * p[(c, 3)] + a4 * p[(c, 4)] + a5 * p[(c, 5)]
                            - a2 * p[(c, IB)]
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
                let mut half_dq = fn_l * dfl.transpose() * wl
                    + fn_r * dfr.transpose() * wr
                    + f_b * dfb.transpose() * v.beta_white
                    + f_a * dfa.transpose() * v.a_y;
                if fitted {
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
        // The step's process noise, the same for the filter's P and the null pass's P₀.
        let add_q = |m: &mut MZ<S>| {
            for r in 0..3 {
                for c in 0..3 {
                    m[(r, c)] += q_x[(r, c)];
                }
                m[(r + 3, r + 3)] += q_s[r];
                m[(r + 6, r + 6)] += q_b[r];
            }
            m[(IB, IB)] += q_beta;
        };
        // Counting: the fresh remainder w_k (Q_ww) and its share of the pose step (Q_xw).
        let add_q_w = |m: &mut MZ<S>| {
            for (w, f_w) in [fn_l, fn_r].into_iter().enumerate() {
                if counting[w] {
                    m[(IW + w, IW + w)] += v.quant;
                    for r in 0..3 {
                        m[(r, IW + w)] += f_w[r] * v.quant;
                        m[(IW + w, r)] += f_w[r] * v.quant;
                    }
                }
            }
        };
        K::propagate_in_place(&mut p, &ft);
        add_q(&mut p);
        add_q_w(&mut p);
        if null {
            K::propagate_in_place(&mut p0, &ft);
            add_q(&mut p0);
            add_q_w(&mut p0);
            if let Some((c, _)) = &mut c0 {
                *c = propagate_cols(c, &ft);
            }
        }
        for &jj in cols {
            let dpj = &mut dp[jj];
            K::propagate_in_place(dpj, &ft);
            match jj {
                0..=3 => add_sym_rows(dpj, &theta_terms[jj]),
                4 => {
                    // η_0 scales the white wheel, quantisation, a_y and β noise together
                    // (quantisation not when it is given, a_y and β not when stated).
                    for r in 0..3 {
                        for c in 0..3 {
                            dpj[(r, c)] += q_x_eta0[(r, c)];
                        }
                    }
                    if v.quant_scaled {
                        add_q_w(dpj);
                    }
                    if v.lateral_scaled {
                        dpj[(IB, IB)] += q_beta;
                    }
                }
                5 => dpj[(3, 3)] += q_s[0],
                6 => {
                    dpj[(4, 4)] += q_s[1];
                    dpj[(5, 5)] += q_s[2];
                }
                8 => {
                    for r in 0..3 {
                        dpj[(r + 6, r + 6)] += q_b[r];
                    }
                }
                // η_3, η_5: the reference noise enters through R only.
                _ => {}
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
        let hp: M3xZ<S> = h_rows(&p);
        let r_k = r + r_q;
        // ∂R_k/∂p_j: quantisation (η_0; θ through ∂f/∂n when following),
        // position white (η_3), heading white (η_5).
        let d_r = |jj: usize| -> Matrix3<f64> {
            match jj {
                0..=3 => r_q_theta[jj],
                4 if v.quant_scaled => r_q,
                7 => dr_position,
                9 => dr_heading,
                _ => Matrix3::zeros(),
            }
        };
        let s_mat = h_cols(&hp) + r_k;
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
        let filter_share = matches!(jac_mode, InputJacobian::FilterShare | InputJacobian::FilterShareSecondOrder);
        let second_order = jac_mode == InputJacobian::FilterShareSecondOrder;
        // With η derivatives the FilterShare terms wait for ∂S/∂η (below).
        let share_eta = filter_share && mode.derivs && mode.eta;
        if filter_share && !share_eta {
            add_filter_share_terms(&mut out, &mut pending, &sinv, second_order, None);
        } else if smoothed {
            let k_l: MZx3<S> = hp.transpose() * sinv;
            let n_l = if all_sources { 3 } else { 2 };
            for (w, dpl) in dp_lambda.iter_mut().take(n_l).enumerate() {
                let ds_l = h_cols(&h_rows(dpl));
                w_smoothed[w] += (sinv * ds_l).trace();
                K::joseph_in_place(dpl, &k_l, None);
            }
        }
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
        let k: MZx3<S> = hp.transpose() * sinv;
        if null {
            // Expected moments of the whitened innovations when the data have
            // the model's noise but not the floors (R₀ = R − floors).
            let r0 = Matrix3::from_diagonal(&r_white) + r_q;
            let hp0: M3xZ<S> = h_rows(&p0);
            let s0 = h_cols(&hp0) + r0;
            let m1 = l.solve_lower_triangular(&s0).unwrap_or_else(Matrix3::zeros);
            let e_cov = l.solve_lower_triangular(&m1.transpose()).unwrap_or_else(Matrix3::zeros);
            out.quad_null += (sinv * s0).trace();
            if let Some((c, l_prev)) = &c0 {
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
            c0 = Some((hp0.transpose() - k * s0, l));
            K::joseph_in_place(&mut p0, &k, Some(&r0));
        }

        if mode.derivs {
            let hd = h_rows(&d); // ∂ν/∂p = −H D⁻
                                 // Gradient of ½νᵀS⁻¹ν through ν: νᵀS⁻¹ ∂ν = −(HD)ᵀ S⁻¹ ν.
            let gnu = hd.transpose() * sinv_nu;
            out.grad -= gnu;
            out.grad_profile -= gnu;
            let sh = sinv * hd;
            let mut info = hd.transpose() * sh;
            out.info_mean_theta += info.fixed_view::<4, 4>(0, 0);
            let mut g_t = nalgebra::Vector4::<f64>::zeros();
            let mut dr = SMatrix::<f64, 3, 4>::zeros();
            for c in 0..4 {
                g_t[c] = -gnu[c];
            }
            for &jj in cols {
                hdps[jj] = h_rows(&dp[jj]);
                let hdp = &hdps[jj];
                ds[jj] = h_cols(hdp) + d_r(jj);
                a[jj] = sinv * ds[jj];
                let ds_snu = ds[jj] * sinv_nu;
                let gq = -0.5 * sinv_nu.dot(&ds_snu);
                let gl = 0.5 * a[jj].trace();
                out.grad[jj] += gq + gl;
                out.grad_profile[jj] += gq;
                if jj < 4 {
                    g_t[jj] += gq;
                    out.grad_logdet[jj] += gl;
                }
                // Column of ∂K ν = (∂P⁻Hᵀ − K ∂S) S⁻¹ ν.
                let col = hdp.transpose() * sinv_nu - k * ds_snu;
                dkn.set_column(jj, &col);
            }
            if share_eta {
                add_filter_share_terms(&mut out, &mut pending, &sinv, second_order, Some((cols, &ds)));
            }
            // ½ tr(S⁻¹∂S_i S⁻¹∂S_j), symmetric in (i, j): tr(AB) = Σ A_rc B_cr.
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
            if theta_cols {
                // Gauss-Newton metric of the profile cost J = ½Σ‖r‖², r = L⁻¹ν
                // (S = LLᵀ): ∂r_j = L⁻¹∂ν_j − Φ(L⁻¹ ∂S_j L⁻ᵀ) r, Φ the lower triangle
                // with halved diagonal (the derivative of the Cholesky factor).
                // It is the expected Hessian of J, not the Fisher information of
                // the marginal likelihood, which overstates the curvature when the
                // input noise is comparable to the turning signal.
                let r_w = e;
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
                out.h_theta += dr.transpose() * dr;
            } else if !follows {
                out.h_theta += info.fixed_view::<4, 4>(0, 0);
            }
            out.i_eta += info.fixed_view::<NETA, NETA>(4, 4);
            out.info += info;
            out.opg += g_t * g_t.transpose();
            let b = ((k1 - window.start) as f64 * ts / SCORE_BLOCK_S) as usize;
            if b != block_index {
                if block_open {
                    out.blocks.push(&block_sum, block_prev.as_ref());
                    block_prev = Some(block_sum);
                }
                block_index = b;
                block_sum = nalgebra::Vector4::zeros();
            }
            block_open = true;
            block_sum += g_t;
            if corrected {
                for (ci, xi) in xcov.iter_mut().enumerate() {
                    out.bias[ci] -= (sinv * h_cols(&h_rows(xi))).trace();
                    *xi = joseph_general(xi, &k);
                }
            }
            if let Some(rec) = record.as_deref_mut() {
                rec.push(InnovationRecord { nu, s: s_mat, dnu: -hd, ds, r: e, dr });
            }
            // Sensitivity update: D⁺ = (I − KH) D⁻ + ∂K ν with
            // ∂K = (∂P⁻Hᵀ − K ∂S) S⁻¹.
            d -= k * hd;
            for &jj in cols {
                for r_ in 0..S {
                    d[(r_, jj)] += dkn[(r_, jj)];
                }
            }
            // Joseph form (I−KH)∂P(I−KH)ᵀ + K ∂R Kᵀ: the algebraically equal
            // ∂P − KH∂P − (KH∂P)ᵀ + K ∂S Kᵀ is numerically unstable here.
            for &jj in cols {
                let dr = d_r(jj);
                K::joseph_in_place_with(&mut dp[jj], &k, (dr != Matrix3::zeros()).then_some(&dr), &hdps[jj]);
            }
        }

        // State and covariance updates.
        let dz = k * nu;
        for r in 0..3 {
            x[r] += dz[r];
            s[r] += dz[r + 3];
            b[r] += dz[r + 6];
        }
        eb += dz[IB];
        if S > IW {
            wq[0] += dz[IW];
            wq[1] += dz[IW + 1];
        }
        K::joseph_in_place_with(&mut p, &k, Some(&r_k), &hp);
    }
    if block_open {
        out.blocks.push(&block_sum, block_prev.as_ref());
    }
    if all_sources {
        // The smoothed share of the Gauss-Markov noise replaces the ŝ
        // correction in J (kept in M): `jacobian` carries −correction.
        out.jacobian -= out.correction;
    }
    if jac_mode != InputJacobian::None {
        for (w, u) in unit_sums.iter().enumerate() {
            let m = u.turning[w];
            out.turning[w] += m;
            // Unit and SmoothedShare: the same weight on every turning sample
            // of the window (FilterShare was added update by update).
            let scale = match jac_mode {
                InputJacobian::Unit => 1.0,
                InputJacobian::SmoothedShare if m > 0.0 => w_smoothed[w] / m,
                InputJacobian::SmoothedShareAll if m > 0.0 => (w_smoothed[w] + 0.5 * w_smoothed[2]) / m,
                _ => 0.0,
            };
            if scale > 0.0 {
                out.jacobian += scale * u.jacobian;
                out.grad_jacobian += u.grad_jacobian * scale;
                out.hess_jacobian += u.hess_jacobian * scale;
                out.jacobian_weight[w] += scale * m;
            }
        }
        if mode.derivs {
            for c in 0..4 {
                out.grad_profile[c] += out.grad_jacobian[c];
            }
            out.h_theta += out.hess_jacobian;
        }
    }
    Ok(out)
}
