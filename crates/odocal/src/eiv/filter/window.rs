//! The filter over one window ([`run_window_s`]).
//!
//! Per sample: the linearisation along the reference
//! ([`WindowSetup::linearise`], a [`Linearisation`]), the prediction of the
//! mean and its sensitivities ([`MeanState::predict`]) and of the covariance
//! and its derivatives over `p = [θ, η]` ([`predict_covariance`]), and where
//! the reference was measured the measurement update
//! ([`update`](super::update)), which adds the sample's terms to the
//! window's sums ([`Accumulator`]).
//!
//! What is fixed over the window lives in a [`WindowSetup`], the mean in a
//! [`MeanState`], the sums in an [`Accumulator`]. The big arrays of the
//! recursion (P, the `∂P/∂p_j`, the sensitivities D, P₀ of the null pass,
//! the corrected score's X, the per-update work arrays) are locals of
//! [`run_window_s`], each passed to the step functions as its own `&mut` or
//! `&` argument, and every step function is `#[inline(always)]`. So the
//! whole window loop is one function for the optimiser, in which every array
//! is a distinct local: it can tell that a store to one leaves the others
//! unchanged and vectorises the covariance kernels that the AVX2 build
//! inlines (`dispatch::run_window_avx2`). Arrays held as fields of one
//! state struct, or borrowed through one, hide that from it and those
//! kernels stay scalar.

use nalgebra::{Matrix3, Vector3};

use super::dispatch::KernelCalls;
use super::dual::Dual;
use super::input_jacobian::InputJacobianState;
use super::kernels::{mul3, Transition};
use super::predict::{add_initial_count_offset, predict_corrected_score, predict_covariance, MeanState};
use super::reference::{dvec_of, fitted_input_factors, reference_terms, ReferenceTerms};
use super::sums::{InnovationRecord, WindowSums};
use super::update::{add_corrected_bias, null_moments, update_sensitivities, Accumulator, ColumnWork, Innovation};
use super::{M3x2, M3xZ, MZx3, Mode, Variances, DZ, HEADING_FLOOR_RAD, IB, IW, MZ, NP};
use crate::eiv::{EivInput, InputJacobian, Window};
use crate::error::Result;
use crate::model::{Input, Theta};

/// What stays fixed over one window: its inputs, the pass's settings and
/// the noise terms that do not depend on the sample.
pub(super) struct WindowSetup<'a, const S: usize> {
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
    pub(super) follows: bool,
    /// `∂P/∂θ` is propagated (covariance following θ, θ derivatives wanted).
    pub(super) theta_cols: bool,
    /// The sensitivity columns whose covariance derivatives are propagated
    /// (the first `ncols` entries).
    cols_buf: [usize; NP],
    ncols: usize,
    /// The corrected score (X recursion), needed only with the covariance held.
    pub(super) corrected: bool,
    /// The relative wheel noise is scaled by the fitted input (following θ only).
    pub(super) fitted: bool,
    /// The null recursion of the innovation diagnostics runs.
    pub(super) null: bool,
    /// The floors of the reference noise (position, position, heading variances).
    pub(super) r_floor: [f64; 3],
    /// The reference's white variances (floors not included) and R with the floors.
    pub(super) r_white: Vector3<f64>,
    pub(super) r: Matrix3<f64>,
    /// `∂R/∂η_3` (position white) and `∂R/∂η_5` (heading white).
    pub(super) dr_position: Matrix3<f64>,
    pub(super) dr_heading: Matrix3<f64>,
    /// The diagonal of rows 3..S of F̄ before the counting remainders.
    base_diag: [f64; S],
    /// Process noise of the sideslip error, of s (common, left, right) and of the drift.
    pub(super) q_beta: f64,
    pub(super) q_s: [f64; 3],
    pub(super) q_b: [f64; 3],
    /// The input log-Jacobian mode, and whether it propagates `∂P/∂λ`
    /// (`smoothed`) for every noise source (`all_sources`).
    pub(super) jac_mode: InputJacobian,
    pub(super) all_sources: bool,
    pub(super) smoothed: bool,
    /// The rotations that scale the relative wheel noise, per sample of the
    /// window (empty when they are the measured ones).
    smooth_l: Vec<f64>,
    smooth_r: Vec<f64>,
    /// With counting quantisation, per sample of the window and wheel:
    /// whether the wheel turns ([`turning_wheels`]; empty otherwise).
    turning: Vec<[bool; 2]>,
}

impl<'a, const S: usize> WindowSetup<'a, S> {
    /// The setup of `window` for a pass at θ (see [`super::run_window`]).
    #[inline(always)]
    pub(super) fn new(
        input: &'a EivInput<'a>,
        window: &'a Window,
        theta: &'a Theta,
        theta_ref: &'a Theta,
        v: &'a Variances,
        mode: Mode,
    ) -> Self {
        let follows = mode.follows_theta;
        let theta_cols = mode.derivs && mode.theta && follows;
        // With the heading white noise tied to the position's (η_3), ∂P/∂η_5 ≡ 0.
        let mut cols_buf = [0usize; NP];
        let mut ncols = 0;
        for c in 0..NP {
            let on = mode.derivs
                && if c < 4 {
                    theta_cols && (mode.theta_skip >> c) & 1 == 0
                } else {
                    mode.eta && (c != 9 || v.heading_separate) && (mode.eta_skip >> (c - 4)) & 1 == 0
                };
            if on {
                cols_buf[ncols] = c;
                ncols += 1;
            }
        }
        let pf2 = v.position_floor_m * v.position_floor_m;
        let r_floor = [pf2, pf2, HEADING_FLOOR_RAD * HEADING_FLOOR_RAD];
        // The heading readings' own white noise is noise of the data (in
        // the null too), with no η derivative.
        let r_white = Vector3::new(v.pose[0], v.pose[1], v.pose[2] + v.heading_white_floor);
        let (h_pos, h_head) = if v.heading_separate { (0.0, v.pose[2]) } else { (v.pose[2], 0.0) };
        let mut base_diag = [1.0; S];
        base_diag[3..IW].copy_from_slice(&[
            v.a_common,
            v.a_wheel,
            v.a_wheel,
            v.a_drift,
            v.a_drift,
            v.a_drift_heading,
            v.a_beta,
        ]);
        let all_sources = v.input_jacobian == InputJacobian::SmoothedShareAll;
        let half = if v.fitted_input && follows { v.noise_input_half_width } else { 0 };
        let (smooth_l, smooth_r) = noise_rotations(input, window, half);
        let turning = if v.quant_counting {
            turning_wheels(input, window, creep_max_gap_s(v, input.sample_time_s))
        } else {
            Vec::new()
        };
        WindowSetup {
            input,
            window,
            theta,
            theta_ref,
            theta_cov: if follows { theta } else { theta_ref },
            v,
            mode,
            ts: input.sample_time_s,
            follows,
            theta_cols,
            cols_buf,
            ncols,
            corrected: mode.derivs && mode.theta && !follows,
            fitted: v.fitted_input && follows,
            null: v.null_without_floors,
            r_floor,
            r_white,
            r: Matrix3::from_diagonal(&(r_white + Vector3::from(r_floor))),
            dr_position: Matrix3::from_diagonal(&Vector3::new(v.pose[0], v.pose[1], h_pos)),
            dr_heading: Matrix3::from_diagonal(&Vector3::new(0.0, 0.0, h_head)),
            base_diag,
            q_beta: v.beta * (1.0 - v.a_beta * v.a_beta),
            q_s: [
                v.common * (1.0 - v.a_common * v.a_common),
                v.wheel * (1.0 - v.a_wheel * v.a_wheel),
                v.wheel * (1.0 - v.a_wheel * v.a_wheel),
            ],
            q_b: std::array::from_fn(|a| {
                let ad = if a < 2 { v.a_drift } else { v.a_drift_heading };
                v.drift[a] * (1.0 - ad * ad)
            }),
            jac_mode: v.input_jacobian,
            all_sources,
            smoothed: all_sources || v.input_jacobian == InputJacobian::SmoothedShare,
            smooth_l,
            smooth_r,
            turning,
        }
    }

    /// The sensitivity columns whose covariance derivatives are propagated:
    /// θ when `∂P/∂θ` is, the η not skipped when η derivatives are on.
    #[inline(always)]
    pub(super) fn cols(&self) -> &[usize] {
        &self.cols_buf[..self.ncols]
    }

    /// The columns of the sensitivities D that the pass computes: all of
    /// them with η derivatives, else the θ columns (`∂ẑ/∂η` is then zero:
    /// η enters the mean only through the gains' derivatives, which are
    /// not propagated).
    #[inline(always)]
    pub(super) fn sensitivity_cols(&self) -> usize {
        if self.mode.eta {
            NP
        } else {
            4
        }
    }

    /// Writes the covariance recursion's terms at sample `i` over `lin`
    /// ([`Linearisation`]; in place, so that the window loop keeps one and
    /// never moves its arrays).
    #[inline(always)]
    pub(super) fn linearise(&self, i: usize, lin: &mut Linearisation<S>) {
        let (input, v) = (self.input, self.v);
        let (nl, nr) = (input.n_rl[i], input.n_rr[i]);
        let (nls, nrs) = if self.smooth_l.is_empty() {
            (nl, nr)
        } else {
            (self.smooth_l[i - self.window.start], self.smooth_r[i - self.window.start])
        };
        let (beta, a_y) = (input.beta[i], input.a_y[i]);
        let uref = Input { n_rl: nl, n_rr: nr, beta, a_y };
        lin.rt = self.theta_cols.then(|| reference_terms::<4>(input.psi[i], &uref, self.theta_cov, self.ts));
        let rv = match &lin.rt {
            Some(rt) => rt.values(),
            None => reference_terms::<0>(input.psi[i], &uref, self.theta_cov, self.ts).values(),
        };
        let (fn_l, fn_r, f_a) = (rv.fn_l, rv.fn_r, rv.f_a);
        // With `fitted_input` the relative wheel noise is scaled by the fitted
        // true input n̂ = ñ·g, g = C(θ_ref)/C(θ): the s-columns of F̄ are
        // −F_n n̂ and the white variance is σ²n̂² (g = 1 otherwise).
        let gw = if self.fitted { fitted_input_factors(a_y, self.theta, self.theta_ref) } else { [Dual::cst(1.0); 2] };
        lin.fxs_ref = if self.fitted {
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
        // error, no new draw (F row 1). A wheel that counts nothing between
        // counts is turning slower than a tick per sample ([`turning_wheels`]):
        // its remainder grows, and is drawn as when it counts.
        let counting = if v.quant_counting { self.turning[i - self.window.start] } else { [false; 2] };
        lin.diag = self.base_diag;
        lin.fxw_ref = M3x2::zeros();
        for (w, f_w) in [fn_l, fn_r].into_iter().enumerate() {
            if counting[w] {
                lin.diag[IW + w] = 0.0;
                lin.fxw_ref.set_column(w, &(-f_w));
            }
        }
        // Where the wheels' quantisation enters: the remainders' pose share
        // where counting, else (rate noise) where the wheel turns.
        let quant_on = if v.quant_counting { counting } else { [nl != 0.0, nr != 0.0] };
        let (wl, wr) = white_variances(v, self.fitted, (nl, nr), (nls, nrs), &gw, quant_on);
        lin.r_q = measurement_quantisation(v, &fn_l, &fn_r, lin.rt.as_ref(), &mut lin.r_q_theta);
        let f_b = Vector3::new(rv.f02, rv.f12, 0.0);
        (lin.q_x, lin.q_x_eta0) = process_noise(v, quant_on, (wl, wr), (&fn_l, &fn_r, &f_a, &f_b));
        (lin.i, lin.nl, lin.nr, lin.nls, lin.nrs, lin.uref) = (i, nl, nr, nls, nrs, uref);
        (lin.f02, lin.f12, lin.fn_l, lin.fn_r, lin.f_a, lin.f_b) = (rv.f02, rv.f12, fn_l, fn_r, f_a, f_b);
        (lin.gw, lin.counting, lin.wl, lin.wr) = (gw, counting, wl, wr);
    }
}

/// The rotations that scale the relative wheel noise with the fitted input
/// (`half > 0`), per sample of the window: ñ's moving average over ±`half`
/// samples within the window (nearly independent of the white error of the
/// sample). Empty vectors when `half == 0` (ñ itself).
fn noise_rotations(input: &EivInput<'_>, window: &Window, half: usize) -> (Vec<f64>, Vec<f64>) {
    let (a0, a1) = (window.start, window.end);
    if half == 0 {
        return (Vec::new(), Vec::new());
    }
    let smooth_of = |n: &[f64]| -> Vec<f64> {
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
    (smooth_of(input.n_rl), smooth_of(input.n_rr))
}

/// The covariance recursion's terms at one sample, linearised along the
/// reference at θ_cov.
pub(super) struct Linearisation<const S: usize> {
    /// The sample.
    pub(super) i: usize,
    /// Measured wheel rotations, and those that scale the relative noise.
    pub(super) nl: f64,
    pub(super) nr: f64,
    pub(super) nls: f64,
    pub(super) nrs: f64,
    /// The measured inputs.
    pub(super) uref: Input,
    /// The terms with their θ-gradients (when `∂P/∂θ` is propagated).
    pub(super) rt: Option<ReferenceTerms<4>>,
    /// `F̄[0,2], F̄[1,2]`, `∂f/∂n_l`, `∂f/∂n_r`, `∂f/∂a_y`, `∂f/∂β = (f02, f12, 0)`.
    pub(super) f02: f64,
    pub(super) f12: f64,
    pub(super) fn_l: Vector3<f64>,
    pub(super) fn_r: Vector3<f64>,
    pub(super) f_a: Vector3<f64>,
    pub(super) f_b: Vector3<f64>,
    /// The fitted-input factors g per wheel (1 without `fitted_input`).
    pub(super) gw: [Dual<4>; 2],
    /// The s-columns and remainder columns of F̄, the wheels counting, the
    /// diagonal of rows 3..S.
    pub(super) fxs_ref: Matrix3<f64>,
    pub(super) fxw_ref: M3x2,
    pub(super) counting: [bool; 2],
    pub(super) diag: [f64; S],
    /// White rate variances of the wheels ([`white_variances`]).
    pub(super) wl: f64,
    pub(super) wr: f64,
    /// Quantisation as measurement noise: `R_q` and `∂R_q/∂θ`.
    pub(super) r_q: Matrix3<f64>,
    pub(super) r_q_theta: [Matrix3<f64>; 4],
    /// The pose block of Q and the share of it that η_0 scales.
    pub(super) q_x: Matrix3<f64>,
    pub(super) q_x_eta0: Matrix3<f64>,
}

impl<const S: usize> Linearisation<S> {
    /// All zero, before the window's first sample.
    #[inline(always)]
    pub(super) fn zero() -> Self {
        let z3 = Vector3::zeros();
        Linearisation {
            i: 0,
            nl: 0.0,
            nr: 0.0,
            nls: 0.0,
            nrs: 0.0,
            uref: Input::default(),
            rt: None,
            f02: 0.0,
            f12: 0.0,
            fn_l: z3,
            fn_r: z3,
            f_a: z3,
            f_b: z3,
            gw: [Dual::cst(0.0); 2],
            fxs_ref: Matrix3::zeros(),
            fxw_ref: M3x2::zeros(),
            counting: [false; 2],
            diag: [0.0; S],
            wl: 0.0,
            wr: 0.0,
            r_q: Matrix3::zeros(),
            r_q_theta: [Matrix3::zeros(); 4],
            q_x: Matrix3::zeros(),
            q_x_eta0: Matrix3::zeros(),
        }
    }

    /// The structured transition F̄ of the sample.
    #[inline(always)]
    pub(super) fn transition(&self) -> Transition<S> {
        Transition { f02: self.f02, f12: self.f12, fxs: self.fxs_ref, fxw: self.fxw_ref, diag: self.diag }
    }
}

/// The shortest run of empty samples, s, in which a wheel that counts
/// nothing between counts is taken as standing rather than turning, for
/// encoders of [`CREEP_MIN_RATE_REV_PER_S`]'s resolution or finer.
pub(crate) const CREEP_MAX_GAP_S: f64 = 1.0;

/// The slowest creep, rev/s, told from a standstill (4 mm/s on a 2 m
/// wheel): a coarser encoder counts a tick of it less often than every
/// [`CREEP_MAX_GAP_S`], and its empty runs stand only from one tick's time
/// at this rate ([`creep_max_gap_s`]).
pub(crate) const CREEP_MIN_RATE_REV_PER_S: f64 = 0.002;

/// The run of empty samples, s, from which a counting wheel stands: the
/// time one tick takes at [`CREEP_MIN_RATE_REV_PER_S`], at least
/// [`CREEP_MAX_GAP_S`]. The tick is the given quantisation step's (`v.quant`
/// = q²/12, q in rev/s, a tick q·t_s rev); with a step scaled by η_0 (which
/// moves between passes) the mask keeps [`CREEP_MAX_GAP_S`].
pub(crate) fn creep_max_gap_s(v: &Variances, sample_time_s: f64) -> f64 {
    if v.quant_scaled {
        return CREEP_MAX_GAP_S;
    }
    let tick_rev = (12.0 * v.quant).sqrt() * sample_time_s;
    (tick_rev / CREEP_MIN_RATE_REV_PER_S).max(CREEP_MAX_GAP_S)
}

/// Per sample of `window` and wheel: whether the wheel turns. A wheel that
/// counts ticks turns; one that counts nothing turns when its run of empty
/// samples (within the window's part) is shorter than `max_gap_s`
/// ([`creep_max_gap_s`]).
///
/// A wheel creeping at less than a tick per sample counts nothing for a
/// few samples and then a tick: its rotation goes on in the empty samples
/// and its count's remainder grows there, as it does when it counts. Taken
/// as standing (no rotation, no error), the creep's rotation lands in the
/// sample of the next tick at once, a heading step of a tick's worth where
/// the reference sees a smooth turn, and the fit answers it by damping
/// every step: a wider track. On the lab's second simulator, whose stops
/// creep (500-tick encoders), that leaned t_r by +2.4 % (8 drives); drawn
/// as counting samples the lean is gone (−0.03 %). A longer run is a
/// standstill.
fn turning_wheels(input: &EivInput<'_>, window: &Window, max_gap_s: f64) -> Vec<[bool; 2]> {
    let part = input.parts.get(window.part).cloned().unwrap_or(0..input.len());
    // A run length that is a whole number of samples but for rounding (a
    // step read back from q²/12) is that number.
    let max_gap = (max_gap_s / input.sample_time_s * (1.0 - 1e-12)).ceil() as usize;
    let mut out = vec![[true; 2]; window.end - window.start];
    for (w, n) in [input.n_rl, input.n_rr].into_iter().enumerate() {
        let (lo, hi) = (window.start.saturating_sub(max_gap).max(part.start), (window.end + max_gap).min(part.end));
        let mut k = lo;
        while k < hi {
            if n[k] != 0.0 {
                k += 1;
                continue;
            }
            let run_start = k;
            while k < hi && n[k] == 0.0 {
                k += 1;
            }
            // A run cut by the scan's margin is at least `max_gap` long.
            let standing = k - run_start >= max_gap;
            for j in run_start.max(window.start)..k.min(window.end) {
                out[j - window.start][w] = !standing;
            }
        }
    }
    out
}

/// White rate variances of the wheels (rev/s)².
///
/// White relative noise accumulates into the pose (process noise).
/// Encoder quantisation does not (with `quant_in_measurement`, an
/// approximation; `quant_counting` models it exactly through the
/// remainder states): counting ticks carries the remainder
/// over, so the counted rotation is the true one to within one tick
/// at every sample, and the pose error it causes is bounded — white
/// in the *measurement*, `R_q = q²/12·(f_l f_lᵀ + f_r f_rᵀ)` with the
/// step's `∂f/∂n` (a tick of the wheel moves the pose by `∂f/∂n·q`).
/// As process noise it accumulates like a random walk and, on the
/// heading, makes the filter misread quantisation as reference noise
/// (docs/study.md, EIV section).
#[inline(always)]
fn white_variances(
    v: &Variances,
    fitted: bool,
    (nl, nr): (f64, f64),
    (nls, nrs): (f64, f64),
    gw: &[Dual<4>; 2],
    quant_on: [bool; 2],
) -> (f64, f64) {
    if fitted {
        let white = |ns: f64, g: f64, on: bool| {
            let q = if v.quant_in_measurement || !on { 0.0 } else { v.quant };
            v.white_rel * ns * ns * g * g + q
        };
        (white(nls, gw[0].v, quant_on[0]), white(nrs, gw[1].v, quant_on[1]))
    } else if v.quant_in_measurement {
        (v.white_rel * nl * nl, v.white_rel * nr * nr)
    } else {
        // Quantisation as white rate noise (or the counting remainder's
        // pose share) where the wheel turns.
        let white = |n: f64, on: bool| if on { v.white_rel * n * n + v.quant } else { 0.0 };
        (white(nl, quant_on[0]), white(nr, quant_on[1]))
    }
}

/// Quantisation as measurement noise (`quant_in_measurement`):
/// `R_q = q²/12·(f_l f_lᵀ + f_r f_rᵀ)` and, with the θ-gradients of the
/// terms, `∂R_q/∂θ` into `r_q_theta` (zeros otherwise).
#[inline(always)]
fn measurement_quantisation(
    v: &Variances,
    fn_l: &Vector3<f64>,
    fn_r: &Vector3<f64>,
    rt: Option<&ReferenceTerms<4>>,
    r_q_theta: &mut [Matrix3<f64>; 4],
) -> Matrix3<f64> {
    if !v.quant_in_measurement {
        *r_q_theta = [Matrix3::zeros(); 4];
        return Matrix3::zeros();
    }
    match rt {
        Some(rt) => {
            for (jt, d_rq) in r_q_theta.iter_mut().enumerate() {
                let (dfl, dfr) = (dvec_of(&rt.fn_l, jt), dvec_of(&rt.fn_r, jt));
                let a = fn_l * dfl.transpose() + fn_r * dfr.transpose();
                *d_rq = (a + a.transpose()) * v.quant;
            }
        }
        None => *r_q_theta = [Matrix3::zeros(); 4],
    }
    (fn_l * fn_l.transpose() + fn_r * fn_r.transpose()) * v.quant
}

/// The pose block of the process noise `Q_x` (white wheel noise, a_y's
/// white noise, β's white-equivalent noise) and the share of it that η_0
/// scales: not the quantisation's when its level is given, not a_y's and
/// β's when their noise is stated.
#[inline(always)]
fn process_noise(
    v: &Variances,
    quant_on: [bool; 2],
    (wl, wr): (f64, f64),
    (fn_l, fn_r, f_a, f_b): (&Vector3<f64>, &Vector3<f64>, &Vector3<f64>, &Vector3<f64>),
) -> (Matrix3<f64>, Matrix3<f64>) {
    let q_white = fn_l * fn_l.transpose() * wl + fn_r * fn_r.transpose() * wr;
    // The quantisation's share of q_white (rate noise or the counting
    // remainder's pose share): not scaled by η_0 when the level is given.
    let q_x_quant = if v.quant_scaled || v.quant_in_measurement {
        Matrix3::zeros()
    } else {
        let q_of = |on: bool| if on { v.quant } else { 0.0 };
        fn_l * fn_l.transpose() * q_of(quant_on[0]) + fn_r * fn_r.transpose() * q_of(quant_on[1])
    };
    // a_y's white noise; β's Gauss-Markov error is the state e_β (or,
    // with `SideslipNoise::WhiteEquivalent`, white noise: `beta_white`).
    let q_beta = f_b * f_b.transpose() * v.beta_white;
    let q_x = q_white + (q_beta + f_a * f_a.transpose() * v.a_y);
    let q_x_eta0 = match (v.lateral_scaled, v.a_y_scaled) {
        (true, true) => q_x - q_x_quant,
        (true, false) => q_white - q_x_quant + q_beta,
        (false, _) => q_white - q_x_quant,
    };
    (q_x, q_x_eta0)
}

/// The initial covariance of a window and its derivatives over
/// `p = [θ, η]` (docs/method.md §9): `P_xx = R + Σ_b, P_bb = Σ_b, P_xb = −Σ_b,
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
        let readings = if a == 2 { v.heading_white_floor } else { 0.0 };
        p[(a, a)] = w + readings + r_floor[a] + dr;
        // η_3 scales the position white noise, η_5 the heading white noise.
        let white = if a < 2 || !v.heading_separate { 7 } else { 9 };
        dp[white][(a, a)] = w;
        // η_4 scales the drift, the heading's with the heading white noise
        // when `heading_drift_on_white_scale`.
        let drift = if a == 2 && v.heading_drift_on_white_scale { white } else { 8 };
        p[(a + 6, a + 6)] = dr;
        p[(a, a + 6)] = -dr;
        p[(a + 6, a)] = -dr;
        if a == 2 && v.heading_drift_held {
            continue;
        }
        let m = &mut dp[drift];
        m[(a + 6, a + 6)] = dr;
        m[(a, a + 6)] = -dr;
        m[(a + 6, a)] = -dr;
        m[(a, a)] += dr;
    }
    (p, dp)
}

/// [`run_window`](super::run_window) with the state size `S` (`NZ` or
/// `IW`), the big covariance kernels called as `K` says. Always inlined, so
/// that [`run_window_avx2`](super::dispatch::run_window_avx2) compiles it
/// (and every step function and kernel it inlines) for AVX2.
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
    let setup = WindowSetup::<S>::new(input, window, theta, theta_ref, v, mode);
    let (mut p, mut dp) = initial_covariance(v, &setup.r_floor);
    // Null recursion of the innovation diagnostics (`null_without_floors`):
    // the true error covariance P₀ when the data have no floor noise, its
    // cross-covariance C₀ = E[ε ν_prevᵀ] with the previous innovation, and
    // the previous update's Cholesky factor of S (the whitening).
    let mut p0 = p;
    if setup.null {
        for (a, f) in setup.r_floor.iter().enumerate() {
            p0[(a, a)] -= f;
        }
    }
    let mut c0: Option<(MZx3<S>, Matrix3<f64>)> = None;
    let mut mean = MeanState::at_start(input, window);
    let mut d = DZ::<S>::zeros();
    // X_i = E[ε⁻ D̃_iᵀ]: cross-covariance of the estimation error and the
    // noise-driven part of the θ-sensitivity (corrected score).
    let mut xcov = [MZ::<S>::zeros(); 4];
    // ∂Q/∂θ_j and the θ-derivatives of F̄ applied to P⁺ (rows 0..3).
    let mut theta_terms = [M3xZ::<S>::zeros(); 4];
    // Per-update work arrays (only the entries of `cols` are written; the
    // rest stay zero, as the records expect).
    let mut ds = [Matrix3::<f64>::zeros(); NP];
    let mut a = [Matrix3::<f64>::zeros(); NP];
    let mut dkn = DZ::<S>::zeros();
    let mut hdps = [M3xZ::<S>::zeros(); NP];
    let mut dr_k = [Matrix3::<f64>::zeros(); NP];
    let mut jacobian = InputJacobianState::new(&setup);
    let mut acc = Accumulator::new();
    let mut lin = Linearisation::zero();
    let mut inn = Innovation::zero();
    for i in window.start..window.end {
        setup.linearise(i, &mut lin);
        // The prediction.
        if i == window.start && v.quant_in_measurement {
            add_initial_count_offset(&setup, &lin, &mut p, &mut p0, &mut dp);
        }
        if setup.jac_mode != InputJacobian::None {
            jacobian.predict::<K>(&setup, &lin);
        }
        if setup.corrected {
            predict_corrected_score(&setup, &lin, &d, &mut xcov);
        }
        mean.predict(&setup, &lin, &mut d, &mut acc.out)?;
        predict_covariance::<S, K>(&setup, &lin, &mut p, &mut p0, &mut c0, &mut dp, &mut theta_terms);

        // The measurement update where the reference was really measured.
        if input.reference_measured.is_some_and(|m| !m[i + 1]) {
            continue;
        }
        inn.update(&setup, &lin, &mean, &p, &d)?;
        jacobian.update::<K>(&setup, &inn, &mut acc.out);
        acc.add_innovation(&inn, window.index)?;
        if setup.null {
            null_moments::<S, K>(&setup, &lin, &inn, &mut p0, &mut c0, &mut acc.out);
        }
        if mode.derivs {
            let mut work = ColumnWork { ds: &mut ds, a: &mut a, dkn: &mut dkn, hdps: &mut hdps, dr: &mut dr_k };
            let dr = acc.add_derivatives(&setup, &lin, &inn, &dp, &mut work, &mut jacobian);
            if setup.corrected {
                add_corrected_bias(&inn, &mut xcov, &mut acc.out);
            }
            if let Some(rec) = record.as_deref_mut() {
                rec.push(InnovationRecord { nu: inn.nu, s: inn.s_mat, dnu: -inn.hd, ds: *work.ds, r: inn.e, dr });
            }
            update_sensitivities::<S, K>(&setup, &inn, &mut d, &mut dp, &work);
        }
        mean.correct(&mul3(&inn.k, &inn.nu));
        K::joseph_in_place_with(&mut p, &inn.k, Some(&inn.r_k), &inn.hp);
    }
    Ok(acc.finish(&setup, &jacobian))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A counting wheel stands from one tick's time at the slowest creep
    /// (at least a second): 5 s for a 100-tick encoder at 40 Hz, a second
    /// for 500 ticks and finer, and a second with a step scaled by η_0.
    #[test]
    fn the_standing_run_is_a_tick_at_the_slowest_creep() {
        let ts = 0.025;
        let with_ticks = |ticks: f64, scaled: bool| {
            let mut v = crate::eiv::NoiseModel::PRODUCTION_CAR.variances(&[0.0; 6], ts);
            let q = 1.0 / (ticks * ts);
            (v.quant, v.quant_scaled) = (q * q / 12.0, scaled);
            creep_max_gap_s(&v, ts)
        };
        assert!((with_ticks(100.0, false) - 5.0).abs() < 1e-9);
        assert!((with_ticks(250.0, false) - 2.0).abs() < 1e-9);
        assert!((with_ticks(500.0, false) - CREEP_MAX_GAP_S).abs() < 1e-9);
        assert!((with_ticks(4096.0, false) - CREEP_MAX_GAP_S).abs() < 1e-9);
        assert!((with_ticks(100.0, true) - CREEP_MAX_GAP_S).abs() < 1e-9);
    }

    /// Empty runs shorter than [`CREEP_MAX_GAP_S`] turn, longer ones stand,
    /// measured across the window's edges but not its part's.
    #[test]
    fn an_empty_run_turns_when_short_and_stands_when_long() {
        let ts = 0.025;
        let gap = (CREEP_MAX_GAP_S / ts).ceil() as usize;
        // Left: a tick, a short empty run, a tick, a long one, a tick. Right: always counting.
        let mut n_rl = vec![0.08];
        n_rl.extend(vec![0.0; 5]);
        n_rl.push(0.08);
        n_rl.extend(vec![0.0; gap]);
        n_rl.push(0.08);
        let len = n_rl.len();
        let n_rr = vec![0.16; len];
        let zero = vec![0.0; len];
        let parts = [0..len];
        let input = EivInput {
            sample_time_s: ts,
            parts: &parts,
            px: &zero,
            py: &zero,
            psi: &zero,
            n_rl: &n_rl,
            n_rr: &n_rr,
            beta: &zero,
            a_y: &zero,
            reference_measured: None,
        };
        let whole = turning_wheels(&input, &Window { index: 0, part: 0, start: 0, end: len }, CREEP_MAX_GAP_S);
        let left: Vec<bool> = whole.iter().map(|t| t[0]).collect();
        assert!(left[..7].iter().all(|t| *t), "the short run turns");
        assert!(left[7..7 + gap].iter().all(|t| !*t), "the long run stands");
        assert!(left[len - 1]);
        assert!(whole.iter().all(|t| t[1]), "the counting wheel turns");
        // A window that starts inside the long run sees its whole length.
        let part = turning_wheels(&input, &Window { index: 1, part: 0, start: 10, end: len }, CREEP_MAX_GAP_S);
        assert_eq!(part.iter().map(|t| t[0]).collect::<Vec<_>>(), left[10..]);
        // The part's start ends a run: a part that begins in the second half
        // of the long run holds a run shorter than the gap, which turns.
        let start = 7 + gap / 2;
        let parts = [start..len];
        let cut = EivInput { parts: &parts, ..input };
        let w = turning_wheels(&cut, &Window { index: 0, part: 0, start, end: len }, CREEP_MAX_GAP_S);
        assert!(w.iter().all(|t| t[0]), "{w:?}");
    }
}
