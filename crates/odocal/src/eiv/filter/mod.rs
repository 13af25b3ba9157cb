//! The augmented extended Kalman filter of docs/method.md §9 over one window, with
//! its exact sensitivity recursion.
//!
//! State (12): `z = [p_x, p_y, ψ, s_c, s_l, s_r, b_x, b_y, b_ψ, e_β, w_l, w_r]`:
//! the pose, the wheel-rotation errors, the reference drift, the sideslip
//! error and the encoder remainders of the previous sample (rev/s). The
//! remainders exist only with [`Variances::quant_counting`]; the other
//! quantisation models run the first 10 states (the same arithmetic, no
//! 12-row storage). The covariance recursion (P, S, K) is linearised along
//! the *reference* (the reference heading, the measured wheel rotations and
//! θ_cov: the current θ when the covariance follows θ, else the pass's
//! reference θ); the mean recursion runs the nonlinear model at the current
//! θ. The parameter vector of the sensitivities is
//! `p = [c_e, c_d, t_r, d, η_0 … η_5]` (10 entries):
//!
//! ```text
//! mean:        D⁻_{k+1} = F_k D⁺_k + [∂f/∂θ | 0]        (F_k at the current mean)
//!              D⁺_k     = (I − K_k H) D⁻_k + ∂K_k · ν_k
//! covariance:  ∂P⁻_{k+1}/∂p_j = F̄_k ∂P⁺_k F̄_kᵀ + ∂F̄_k P⁺_k F̄_kᵀ + F̄_k P⁺_k ∂F̄_kᵀ + ∂Q_k/∂p_j
//!              ∂S_k = H ∂P⁻_k Hᵀ + ∂R_k,  ∂K_k = (∂P⁻_k Hᵀ − K_k ∂S_k) S_k⁻¹
//!              ∂P⁺_k = (I − K_k H) ∂P⁻_k (I − K_k H)ᵀ + K_k ∂R_k K_kᵀ
//! innovation:  ∂ν_k/∂p = −H D⁻_k
//! ```
//!
//! (`∂F̄/∂η = 0`; `∂F̄/∂θ ≠ 0` and `∂P/∂θ` is propagated only with the
//! covariance following θ, else `∂S/∂θ = 0`.)
//!
//! The modules: `window` holds the filter over one window, `kernels` the
//! structured covariance kernels, `dispatch` the choice between the AVX2
//! and the baseline build of the window loop, `reference` and `dual` the
//! linearisation along the reference with its θ-gradients,
//! `input_jacobian` the input log-Jacobian term, `sums` what a window
//! contributes.

mod dispatch;
mod dual;
mod input_jacobian;
mod kernels;
mod predict;
mod reference;
mod sums;
mod update;
mod window;

use nalgebra::{SMatrix, SVector};

use super::InputJacobian;
pub(crate) use dispatch::{kernels, run_window, Kernels};
#[cfg(test)]
pub(crate) use dispatch::{run_window_avx2, run_window_baseline};
#[cfg(test)]
pub(crate) use sums::InnovationRecord;
pub(crate) use sums::{BlockScores, WindowSums};

/// Number of filter states (the two remainder states w_l, w_r included).
pub(crate) const NZ: usize = 12;
/// Index of the sideslip error state `e_β` (the measured β's Gauss-Markov
/// error: the true sideslip is `β̃ − e_β`).
pub(super) const IB: usize = 9;
/// Index of the first remainder state `w_l` (`w_r` follows).
pub(super) const IW: usize = 10;
/// Number of sensitivity parameters: 4 θ + 6 η.
pub(crate) const NP: usize = 10;
/// Number of noise scale factors η.
pub(crate) const NETA: usize = 6;

/// A state × state matrix (S = NZ with counting quantisation, else IW).
pub(crate) type MZ<const S: usize> = SMatrix<f64, S, S>;
/// State × parameter (the sensitivities `∂ẑ/∂p`).
pub(super) type DZ<const S: usize> = SMatrix<f64, S, NP>;
/// A vector over the parameters `p = [θ, η]` (gradients).
pub(crate) type VP = SVector<f64, NP>;
/// η × η (the information of the noise scales).
pub(crate) type MEta = SMatrix<f64, NETA, NETA>;
/// `[θ, η]` × `[θ, η]` (information matrices).
pub(crate) type MP = SMatrix<f64, NP, NP>;
/// 3 × state (`H P`).
pub(super) type M3xZ<const S: usize> = SMatrix<f64, 3, S>;
/// The pose rows of the remainder columns of F (`−∂f/∂n_w` of turning wheels).
pub(super) type M3x2 = SMatrix<f64, 3, 2>;
/// State × 3 (gains, `P Hᵀ`).
pub(super) type MZx3<const S: usize> = SMatrix<f64, S, 3>;

/// Heading measurement noise floor (docs/method.md §9): keeps S regular on a perfect
/// reference (the position floor is [`Variances::position_floor_m`]).
pub(super) const HEADING_FLOOR_RAD: f64 = 1e-5;

/// Per-sample noise quantities of one filter pass: the base variances of the
/// noise model already multiplied by `exp(η)`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Variances {
    /// Relative white wheel variance σ_white² · e^{η0}.
    pub white_rel: f64,
    /// Quantisation variance q²/12 · e^{η0}, (rev/s)² (measurement noise, see [`run_window`]);
    /// q²/12 without the factor when not [`Variances::quant_scaled`].
    pub quant: f64,
    /// η_0 scales the quantisation variance with the white wheel noise
    /// (otherwise it is held at the model's q: [`super::QuantisationLevel::Given`]).
    pub quant_scaled: bool,
    /// η_0 scales the a_y and β variances with the white wheel noise
    /// (otherwise they are held: [`super::LateralNoise::Stated`]).
    pub lateral_scaled: bool,
    /// η_0 scales the a_y variance (with `lateral_scaled`; false where a_y's
    /// σ is held on its own, `ResearchOptions::a_y_sigma_held`).
    pub a_y_scaled: bool,
    /// Stationary variance of s_c, σ_c² · e^{η1}.
    pub common: f64,
    /// Stationary variance of s_l and s_r, σ_w² · e^{η2}.
    pub wheel: f64,
    /// Pose white variances `[σ_p²·e^{η3}, σ_p²·e^{η3}, σ_ψ²·e^{η5}]` (floors not included).
    pub pose: [f64; 3],
    /// The reference heading readings' white-noise variance, rad², added
    /// to the heading's white variance `pose[2]` in R (no η derivative).
    pub heading_white_floor: f64,
    /// Drift stationary variances `[σ_d², σ_d², σ_dψ²] · e^{η4}`.
    pub drift: [f64; 3],
    /// Lateral acceleration variance (fixed), (m/s²)².
    pub a_y: f64,
    /// Stationary variance of the sideslip error state e_β (Gauss-Markov), rad²
    /// (0 with [`super::SideslipNoise::WhiteEquivalent`]).
    pub beta: f64,
    /// The sideslip error as white process noise of this variance, rad²
    /// ([`super::SideslipNoise::WhiteEquivalent`]; else 0).
    pub beta_white: f64,
    /// Gauss-Markov coefficients `a = exp(−t_s/τ)`: common, per-wheel, drift, sideslip error.
    pub a_common: f64,
    pub a_wheel: f64,
    pub a_drift: f64,
    /// The heading drift's Gauss-Markov coefficient (`a_drift` unless the
    /// position drift has its own correlation time).
    pub a_drift_heading: f64,
    /// The heading drift is scaled with the heading white noise (η_5, or
    /// η_3 when tied) instead of the pose-drift scale η_4.
    pub heading_drift_on_white_scale: bool,
    /// The heading drift's variance is held at its floor (no η derivative):
    /// the pose-drift scale η_4 is below it and scales the position drift
    /// alone ([`super::ResearchOptions::heading_drift_min_eta`]).
    pub heading_drift_held: bool,
    pub a_beta: f64,
    /// Quantisation as measurement noise `R_q` (bounded count error) rather
    /// than as white rate noise in the process ([`super::QuantisationModel`]).
    pub quant_in_measurement: bool,
    /// Quantisation as the exact counting error: the measured rate is
    /// `ñ_k = n_k + w_{k−1} − w_k` (w the remainder of the count, in rev/s,
    /// variance q²/12), with `w_{k−1}` in the state ([`super::QuantisationModel::Counting`]).
    pub quant_counting: bool,
    /// The heading white noise has its own scale η_5 (otherwise η_3 scales
    /// it with the position white noise; [`super::EivOptions::heading_scale`]).
    pub heading_separate: bool,
    /// The relative wheel noise (white and Gauss-Markov) is scaled by the
    /// fitted true input `ñ·C(θ_ref)/C(θ)` instead of the measured `ñ`
    /// ([`super::WheelNoiseScale::SmoothedFittedInput`], with ñ there its
    /// moving average: `noise_input_half_width`).
    pub fitted_input: bool,
    /// The log-Jacobian term of the relative white wheel noise in J
    /// ([`super::InputJacobian`]).
    pub input_jacobian: InputJacobian,
    /// With `fitted_input`: the rotation that scales the relative wheel
    /// noise is the moving average of ñ over ±this many samples (0: ñ
    /// itself; [`super::WheelNoiseScale::SmoothedFittedInput`]).
    pub noise_input_half_width: usize,
    /// Floor of the position measurement σ, m ([`super::ResearchOptions::position_floor_m`]).
    pub position_floor_m: f64,
    /// Also run the null recursion of the innovation diagnostics: the
    /// covariance of the filter's error when the data follow the model
    /// *without* the measurement floors (the floors are regularisation, not
    /// noise the data are assumed to have), giving the expected lag-1
    /// correlation and NIS of the innovations ([`WindowSums::lag1_null`]).
    pub null_without_floors: bool,
    /// The marginal likelihood M (the η step) keeps the Gauss-Markov
    /// states' log-Jacobian `−Σ m log(1 − ŝ)` (`ResearchOptions::coloured_jacobian_in_marginal`).
    pub coloured_jacobian_in_marginal: bool,
    /// The common-mode state's log-Jacobian is in J and M (`ResearchOptions::common_mode_jacobian`).
    pub common_mode_jacobian: bool,
}

/// How the filter runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Mode {
    /// The covariance recursion is evaluated at θ (S depends on θ; `∂P/∂θ`
    /// is propagated); otherwise at the reference θ (`∂S/∂θ = 0`).
    pub follows_theta: bool,
    /// Compute the sensitivities (gradient and information); `false` gives
    /// the objective only.
    pub derivs: bool,
    /// With `derivs`: also the η derivatives.
    pub eta: bool,
    /// With `derivs`: also the θ derivatives that need `∂P/∂θ` (with the
    /// covariance following θ) or the corrected score (held). `false` (only
    /// with `eta`) leaves the θ entries of the gradients and information
    /// matrices incomplete, for an evaluation whose only use is an η step:
    /// its η entries are the same to the bit.
    pub theta: bool,
    /// With `eta`: η columns (bit j = η_j) whose covariance derivative is
    /// not propagated, for an evaluation that needs only the others (their
    /// gradient and information entries are then incomplete; the rest are
    /// the same to the bit).
    pub eta_skip: u8,
    /// With `theta` and the covariance following θ: θ columns (bit i = θ_i)
    /// whose covariance derivative `∂P/∂θ_i` is not propagated; their
    /// gradient and information entries then leave out the terms through
    /// `∂S/∂θ_i` (the estimator's choice for c_d, [`super::problem::Problem`]).
    pub theta_skip: u8,
    /// With `derivs`: also the information matrices (`info`, `i_eta`,
    /// `h_theta`, `info_mean_theta`), the outer products of the θ-scores
    /// (`opg`, `blocks`). `false` leaves them incomplete, for an evaluation
    /// whose only use is its gradients: the objective and the gradients are
    /// the same to the bit.
    pub info: bool,
}

impl Mode {
    /// Objective only.
    pub(crate) fn cost(follows_theta: bool) -> Self {
        Mode { follows_theta, derivs: false, eta: false, theta: false, eta_skip: 0, theta_skip: 0, info: true }
    }
    /// Objective and derivatives (η derivatives when `eta`).
    pub(crate) fn full(follows_theta: bool, eta: bool) -> Self {
        Mode { follows_theta, derivs: true, eta, theta: true, eta_skip: 0, theta_skip: 0, info: true }
    }
    /// Objective and the η derivatives only (see [`Mode::theta`]).
    pub(crate) fn eta_only(follows_theta: bool) -> Self {
        Mode { follows_theta, derivs: true, eta: true, theta: false, eta_skip: 0, theta_skip: 0, info: true }
    }
    /// The same without the covariance derivatives of the η in `skip`
    /// (bit j = η_j; see [`Mode::eta_skip`]).
    pub(crate) fn skipping_eta(self, skip: u8) -> Self {
        Mode { eta_skip: skip, ..self }
    }
    /// The same without the covariance derivatives of the θ in `skip`
    /// (bit i = θ_i; see [`Mode::theta_skip`]).
    pub(crate) fn skipping_theta(self, skip: u8) -> Self {
        Mode { theta_skip: skip, ..self }
    }
    /// The same without the information matrices (see [`Mode::info`]).
    pub(crate) fn gradients_only(self) -> Self {
        Mode { info: false, ..self }
    }
}
