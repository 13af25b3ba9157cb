//! The filter over one window: its state, the per-sample linearisation
//! along the reference, and the loop that predicts and updates.

use nalgebra::{Matrix3, Vector3, Vector4};

use super::dispatch::KernelCalls;
use super::dual::Dual;
use super::input_jacobian::InputJacobianSums;
use super::kernels::Transition;
use super::noise_input::NoiseRotations;
use super::quantisation::{counting_transition, measurement_quantisation};
use super::reference::{fitted_input_factors, reference_terms, ReferenceTerms};
use super::sums::{InnovationRecord, WindowSums};
use super::{M3x2, M3xZ, MZx3, Mode, Variances, DZ, HEADING_FLOOR_RAD, IB, IW, MZ, NP};
use crate::eiv::{EivInput, Window};
use crate::error::Result;
use crate::model::{Input, State, Theta};

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

/// The sensitivity columns whose covariance derivatives a pass propagates.
#[derive(Clone, Copy)]
pub(super) struct Columns {
    buf: [usize; NP],
    n: usize,
}

impl Columns {
    /// The columns of `mode`: θ when `∂P/∂θ` is propagated (`theta_cols`),
    /// the η not skipped when η derivatives are on. With the heading white
    /// noise tied to the position's (η_3), `∂P/∂η_5 ≡ 0` and is left out.
    fn of(mode: Mode, v: &Variances, theta_cols: bool) -> Self {
        let mut buf = [0usize; NP];
        let mut n = 0;
        for c in 0..NP {
            let on = mode.derivs
                && if c < 4 {
                    theta_cols
                } else {
                    mode.eta && (c != 9 || v.heading_separate) && (mode.eta_skip >> (c - 4)) & 1 == 0
                };
            if on {
                buf[n] = c;
                n += 1;
            }
        }
        Columns { buf, n }
    }

    #[inline(always)]
    pub(super) fn as_slice(&self) -> &[usize] {
        &self.buf[..self.n]
    }
}

/// The covariance recursion's terms at one sample, linearised along the
/// reference (reference heading, measured wheel rotations) at θ_cov.
pub(super) struct Linearisation<const S: usize> {
    /// The sample.
    pub(super) i: usize,
    /// Measured wheel rotations.
    pub(super) nl: f64,
    pub(super) nr: f64,
    /// The rotations that scale the relative wheel noise ([`NoiseRotations`]).
    pub(super) nls: f64,
    pub(super) nrs: f64,
    pub(super) beta: f64,
    pub(super) a_y: f64,
    /// The reference input (measured rotations, β, a_y).
    pub(super) uref: Input,
    /// The terms with their θ-gradients, when `∂P/∂θ` is propagated.
    pub(super) rt: Option<ReferenceTerms<4>>,
    /// `F̄[0,2], F̄[1,2]`.
    pub(super) f02: f64,
    pub(super) f12: f64,
    /// `∂f/∂n_l`, `∂f/∂n_r`, `∂f/∂a_y`.
    pub(super) fn_l: Vector3<f64>,
    pub(super) fn_r: Vector3<f64>,
    pub(super) f_a: Vector3<f64>,
    /// The fitted-input factors `C(θ_ref)/C(θ)` per wheel (1 without `fitted_input`).
    pub(super) gw: [Dual<4>; 2],
    /// The s-columns of F̄ (`−F_n n̂`).
    pub(super) fxs_ref: Matrix3<f64>,
    /// Counting quantisation: the wheel turns (its remainder is fresh).
    pub(super) counting: [bool; 2],
    /// The diagonal of rows 3..S of F̄.
    pub(super) diag: [f64; S],
    /// The pose rows of the remainder columns of F̄.
    pub(super) fxw_ref: M3x2,
    /// White variance of each wheel's rotation (relative noise, and quantisation as rate noise).
    pub(super) wl: f64,
    pub(super) wr: f64,
    /// Quantisation as measurement noise `R_q` (zero otherwise).
    pub(super) r_q: Matrix3<f64>,
    /// `∂f/∂β` on the pose rows (`[F̄[0,2], F̄[1,2], 0]`).
    pub(super) f_b: Vector3<f64>,
    /// The pose block of the process noise.
    pub(super) q_x: Matrix3<f64>,
    /// The share of `q_x` that η_0 scales.
    pub(super) q_x_eta0: Matrix3<f64>,
}

impl<const S: usize> Linearisation<S> {
    /// The structured transition `F̄` of the sample.
    #[inline(always)]
    pub(super) fn transition(&self) -> Transition<'_, S> {
        Transition { f02: self.f02, f12: self.f12, fxs: &self.fxs_ref, fxw: &self.fxw_ref, diag: &self.diag }
    }
}

/// The floors of the reference noise: the position (both axes) and heading
/// variances.
#[inline(always)]
fn r_floor(v: &Variances) -> [f64; 3] {
    [
        v.position_floor_m * v.position_floor_m,
        v.position_floor_m * v.position_floor_m,
        HEADING_FLOOR_RAD * HEADING_FLOOR_RAD,
    ]
}

/// The arrays a [`WindowFilter`] works on, each borrowed from its own local
/// of [`run_window_s`]. As fields of one struct, indexed by loop variables,
/// they would be one block of memory to the optimiser, which then cannot
/// tell that a store to one leaves the others unchanged.
pub(super) struct WindowArrays<'w, const S: usize> {
    pub(super) p: &'w mut MZ<S>,
    pub(super) dp: &'w mut [MZ<S>; NP],
    pub(super) d: &'w mut DZ<S>,
    pub(super) p0: &'w mut MZ<S>,
    pub(super) c0: &'w mut Option<(MZx3<S>, Matrix3<f64>)>,
    pub(super) xcov: &'w mut [MZ<S>; 4],
    pub(super) out: &'w mut WindowSums,
    pub(super) theta_terms: &'w mut [M3xZ<S>; 4],
    pub(super) r_q_theta: &'w mut [Matrix3<f64>; 4],
    pub(super) ds: &'w mut [Matrix3<f64>; NP],
    pub(super) a: &'w mut [Matrix3<f64>; NP],
    pub(super) dkn: &'w mut DZ<S>,
    pub(super) hdps: &'w mut [M3xZ<S>; NP],
    pub(super) jacobian: &'w mut InputJacobianSums<S>,
}

/// The filter of one window: what is fixed for the window, the state
/// estimate with its covariance and sensitivities, and the sums it
/// accumulates ([`WindowSums`]).
pub(super) struct WindowFilter<'a, 'w, const S: usize> {
    pub(super) input: &'a EivInput<'a>,
    pub(super) window: &'a Window,
    /// θ of the mean recursion.
    pub(super) theta: &'a Theta,
    pub(super) theta_ref: &'a Theta,
    /// θ of the covariance recursion (θ when it follows θ, else θ_ref).
    pub(super) theta_cov: &'a Theta,
    pub(super) v: &'a Variances,
    pub(super) mode: Mode,
    pub(super) ts: f64,
    pub(super) cols: Columns,
    /// `∂P/∂θ` is propagated (covariance following θ, θ derivatives wanted).
    pub(super) theta_cols: bool,
    /// The corrected score (X recursion), needed only with the covariance held.
    pub(super) corrected: bool,
    /// The relative wheel noise is scaled by the fitted input (following θ only).
    pub(super) fitted: bool,
    /// The reference's white variances (floors not included).
    pub(super) r_white: Vector3<f64>,
    /// R with the floors.
    pub(super) r: Matrix3<f64>,
    /// `∂R/∂η_3` (position white) and `∂R/∂η_5` (heading white).
    pub(super) dr_position: Matrix3<f64>,
    pub(super) dr_heading: Matrix3<f64>,
    /// The diagonal of rows 3..S of F̄ before the counting remainders.
    pub(super) base_diag: [f64; S],
    /// Process noise of the sideslip error, of s (common, left, right) and of the drift.
    pub(super) q_beta: f64,
    pub(super) q_s: [f64; 3],
    pub(super) q_b: [f64; 3],
    pub(super) rotations: NoiseRotations,
    /// Pose, s, drift, sideslip error e_β (rad) and, with counting
    /// quantisation, the remainders w_{k−1} (rev/s).
    pub(super) x: State,
    pub(super) s: Vector3<f64>,
    pub(super) b: Vector3<f64>,
    pub(super) eb: f64,
    pub(super) wq: [f64; 2],
    /// P and `∂P/∂p_j`.
    pub(super) p: &'w mut MZ<S>,
    pub(super) dp: &'w mut [MZ<S>; NP],
    /// The mean's sensitivities `∂ẑ/∂p`.
    pub(super) d: &'w mut DZ<S>,
    /// Null recursion of the innovation diagnostics (`null_without_floors`):
    /// the true error covariance P₀ when the data have no floor noise, its
    /// cross-covariance C₀ = E[ε ν_prevᵀ] with the previous innovation, and
    /// the previous update's Cholesky factor of S (the whitening).
    pub(super) null: bool,
    pub(super) p0: &'w mut MZ<S>,
    pub(super) c0: &'w mut Option<(MZx3<S>, Matrix3<f64>)>,
    /// X_i = E[ε⁻ D̃_iᵀ]: cross-covariance of the estimation error and the
    /// noise-driven part of the θ-sensitivity (corrected score).
    pub(super) xcov: &'w mut [MZ<S>; 4],
    pub(super) out: &'w mut WindowSums,
    pub(super) prev_e: Option<Vector3<f64>>,
    /// Per-sample work arrays (only the entries of `cols` are written; the
    /// rest stay zero, as the records expect).
    pub(super) theta_terms: &'w mut [M3xZ<S>; 4],
    pub(super) r_q_theta: &'w mut [Matrix3<f64>; 4],
    pub(super) ds: &'w mut [Matrix3<f64>; NP],
    pub(super) a: &'w mut [Matrix3<f64>; NP],
    pub(super) dkn: &'w mut DZ<S>,
    /// H ∂P⁻/∂p_j of the update (for ∂S and again in the Joseph form).
    pub(super) hdps: &'w mut [M3xZ<S>; NP],
    pub(super) jacobian: &'w mut InputJacobianSums<S>,
    /// The open block of θ-scores ([`super::BlockScores`]).
    pub(super) block_index: usize,
    pub(super) block_open: bool,
    pub(super) block_sum: Vector4<f64>,
    pub(super) block_prev: Option<Vector4<f64>>,
}

impl<'a, 'w, const S: usize> WindowFilter<'a, 'w, S> {
    /// The filter at the start of `window`: `x = ỹ_0, s = 0, b = 0`, the
    /// initial covariance in `arrays`.
    #[inline(always)]
    pub(super) fn new(
        input: &'a EivInput<'a>,
        window: &'a Window,
        theta: &'a Theta,
        theta_ref: &'a Theta,
        v: &'a Variances,
        mode: Mode,
        arrays: WindowArrays<'w, S>,
    ) -> Self {
        let ts = input.sample_time_s;
        let follows = mode.follows_theta;
        let theta_cov = if follows { theta } else { theta_ref };
        let theta_cols = mode.derivs && mode.theta && follows;
        let cols = Columns::of(mode, v, theta_cols);
        let corrected = mode.derivs && mode.theta && !follows;
        let r_white = Vector3::new(v.pose[0], v.pose[1], v.pose[2]);
        let r = Matrix3::from_diagonal(&(r_white + Vector3::from(r_floor(v))));
        let (h_pos, h_head) = if v.heading_separate { (0.0, v.pose[2]) } else { (v.pose[2], 0.0) };
        let dr_position = Matrix3::from_diagonal(&Vector3::new(v.pose[0], v.pose[1], h_pos));
        let dr_heading = Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, h_head));
        let a0 = window.start;
        let mut base_diag = [1.0; S];
        base_diag[3..IW]
            .copy_from_slice(&[v.a_common, v.a_wheel, v.a_wheel, v.a_drift, v.a_drift, v.a_drift, v.a_beta]);
        let WindowArrays { p, dp, d, p0, c0, xcov, out, theta_terms, r_q_theta, ds, a, dkn, hdps, jacobian } = arrays;
        WindowFilter {
            input,
            window,
            theta,
            theta_ref,
            theta_cov,
            v,
            mode,
            ts,
            cols,
            theta_cols,
            corrected,
            fitted: v.fitted_input && follows,
            r_white,
            r,
            dr_position,
            dr_heading,
            base_diag,
            q_beta: v.beta * (1.0 - v.a_beta * v.a_beta),
            q_s: [
                v.common * (1.0 - v.a_common * v.a_common),
                v.wheel * (1.0 - v.a_wheel * v.a_wheel),
                v.wheel * (1.0 - v.a_wheel * v.a_wheel),
            ],
            q_b: std::array::from_fn(|a| v.drift[a] * (1.0 - v.a_drift * v.a_drift)),
            rotations: NoiseRotations::new(input, window, v, follows, theta_ref),
            x: State::new(input.px[a0], input.py[a0], input.psi[a0]),
            s: Vector3::zeros(),
            b: Vector3::zeros(),
            eb: 0.0,
            wq: [0.0; 2],
            p,
            dp,
            d,
            null: v.null_without_floors,
            p0,
            c0,
            xcov,
            out,
            prev_e: None,
            theta_terms,
            r_q_theta,
            ds,
            a,
            dkn,
            hdps,
            jacobian,
            block_index: 0,
            block_open: false,
            block_sum: Vector4::zeros(),
            block_prev: None,
        }
    }

    /// The covariance recursion's terms at sample `i` ([`Linearisation`]);
    /// with quantisation as measurement noise also `∂R_q/∂θ` (kept in
    /// `r_q_theta`).
    #[inline(always)]
    pub(super) fn linearise(&mut self, i: usize) -> Linearisation<S> {
        let (input, v, ts) = (self.input, self.v, self.ts);
        let (nl, nr) = (input.n_rl[i], input.n_rr[i]);
        // The rotations scaling the relative noise (smoothed when asked).
        let (nls, nrs) = self.rotations.at(i - self.window.start, nl, nr);
        let (beta, a_y) = (input.beta[i], input.a_y[i]);
        let uref = Input { n_rl: nl, n_rr: nr, beta, a_y };
        let (rv, rt) = if self.theta_cols {
            let rt = reference_terms::<4>(input.psi[i], &uref, self.theta_cov, ts);
            (rt.values(), Some(rt))
        } else {
            (reference_terms::<0>(input.psi[i], &uref, self.theta_cov, ts).values(), None)
        };
        let (f02, f12) = (rv.f02, rv.f12);
        let (fn_l, fn_r, f_a) = (rv.fn_l, rv.fn_r, rv.f_a);
        // With `fitted_input` the relative wheel noise is scaled by the fitted
        // true input n̂ = ñ·g, g = C(θ_ref)/C(θ): the s-columns of F̄ are
        // −F_n n̂ and the white variance is σ²n̂² (g = 1 otherwise).
        let fitted = self.fitted;
        let gw = if fitted { fitted_input_factors(a_y, self.theta, self.theta_ref) } else { [Dual::cst(1.0); 2] };
        let fxs_ref = if fitted {
            let (sl, sr) = (fn_l * gw[0].v, fn_r * gw[1].v);
            Matrix3::from_columns(&[-sl * nls - sr * nrs, -sl * nls, -sr * nrs])
        } else {
            Matrix3::from_columns(&[-fn_l * nl - fn_r * nr, -fn_l * nl, -fn_r * nr])
        };
        let (counting, diag, fxw_ref) = counting_transition(v, nl, nr, &fn_l, &fn_r, &self.base_diag);
        let (wl, wr) = white_variances(v, fitted, (nl, nr), (nls, nrs), &gw);
        let r_q = measurement_quantisation(v, &fn_l, &fn_r, rt.as_ref(), self.r_q_theta);
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
        Linearisation {
            i,
            nl,
            nr,
            nls,
            nrs,
            beta,
            a_y,
            uref,
            rt,
            f02,
            f12,
            fn_l,
            fn_r,
            f_a,
            gw,
            fxs_ref,
            counting,
            diag,
            fxw_ref,
            wl,
            wr,
            r_q,
            f_b,
            q_x,
            q_x_eta0,
        }
    }

    /// Closes the window's sums once every sample has been filtered.
    #[inline(always)]
    pub(super) fn finish(self) {
        if self.block_open {
            self.out.blocks.push(&self.block_sum, self.block_prev.as_ref());
        }
        self.jacobian.finish(self.out, self.mode.derivs);
    }
}

/// White variance of each wheel's rotation per sample: the relative white
/// noise (`σ²ñ²`, or `σ²n̂²` of the fitted input) and, unless it is
/// measurement noise or counted, the quantisation as white rate noise where
/// the wheel turns.
///
/// Encoder quantisation does not accumulate into the pose (with
/// `quant_in_measurement`, an approximation; `quant_counting` models it
/// exactly through the remainder states): counting ticks carries the
/// remainder over, so the counted rotation is the true one to within one
/// tick at every sample, and the pose error it causes is bounded — white in
/// the *measurement*, `R_q = q²/12·(f_l f_lᵀ + f_r f_rᵀ)` with the step's
/// `∂f/∂n` (a tick of the wheel moves the pose by `∂f/∂n·q`). As process
/// noise it accumulates like a random walk and, on the heading, makes the
/// filter misread quantisation as reference noise (docs/study.md, EIV section).
#[inline(always)]
fn white_variances(
    v: &Variances,
    fitted: bool,
    (nl, nr): (f64, f64),
    (nls, nrs): (f64, f64),
    gw: &[Dual<4>; 2],
) -> (f64, f64) {
    if fitted {
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
    }
}

/// The filter over one window with the state size `S` (`NZ` or `IW`), its
/// big covariance kernels called as `K` says. Always inlined, so that
/// [`super::dispatch::run_window_avx2`] compiles it (and the kernels it
/// inlines) for AVX2.
///
/// Per sample: the linearisation along the reference, the prediction
/// ([`WindowFilter::predict`]) and, where the reference was really
/// measured, the measurement update ([`WindowFilter::update`]).
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
    let mut record = record;
    // The initial covariance; P₀ of the null recursion without the floors.
    let (mut p, mut dp) = initial_covariance::<S>(v, &r_floor(v));
    let mut p0 = p;
    if v.null_without_floors {
        for (a, f) in r_floor(v).iter().enumerate() {
            p0[(a, a)] -= f;
        }
    }
    let mut d = DZ::<S>::zeros();
    let mut c0 = None;
    let mut xcov = [MZ::<S>::zeros(); 4];
    let mut out = WindowSums::zero();
    // Per-sample work arrays (only the entries of the propagated columns
    // are written; the rest stay zero, as the records expect).
    let mut theta_terms = [M3xZ::<S>::zeros(); 4];
    let mut r_q_theta = [Matrix3::zeros(); 4];
    let mut ds = [Matrix3::zeros(); NP];
    let mut a = [Matrix3::zeros(); NP];
    let mut dkn = DZ::<S>::zeros();
    let mut hdps = [M3xZ::<S>::zeros(); NP];
    let mut jacobian = InputJacobianSums::<S>::new(v);
    let arrays = WindowArrays {
        p: &mut p,
        dp: &mut dp,
        d: &mut d,
        p0: &mut p0,
        c0: &mut c0,
        xcov: &mut xcov,
        out: &mut out,
        theta_terms: &mut theta_terms,
        r_q_theta: &mut r_q_theta,
        ds: &mut ds,
        a: &mut a,
        dkn: &mut dkn,
        hdps: &mut hdps,
        jacobian: &mut jacobian,
    };
    let mut f = WindowFilter::<S>::new(input, window, theta, theta_ref, v, mode, arrays);
    for i in window.start..window.end {
        let lin = f.linearise(i);
        f.predict::<K>(&lin)?;
        let k1 = i + 1;
        if let Some(m) = input.reference_measured {
            if !m[k1] {
                continue;
            }
        }
        f.update::<K>(k1, &lin, record.as_deref_mut())?;
    }
    f.finish();
    Ok(out)
}
