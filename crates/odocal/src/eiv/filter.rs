//! The augmented extended Kalman filter of SPEC §10 over one window, with
//! its exact sensitivity recursion.
//!
//! State `z = [p_x, p_y, ψ, s_c, s_l, s_r, b_x, b_y, b_ψ, w_l, w_r]`; the
//! last two are the encoder remainders of the previous sample (rev/s, only
//! with [`Variances::quant_counting`]: the filter runs with 11 states then, 9 otherwise). The covariance
//! recursion (P, S, K) is linearised along the *reference* (the reference
//! heading, the measured wheel rotations and the reference θ of the pass),
//! so it depends on the noise scales η but not on θ; the mean recursion runs
//! the nonlinear model at the current θ. The parameter vector of the
//! sensitivities is `p = [c_e, c_d, t_r, d, η_0 … η_5]`:
//!
//! ```text
//! mean:        D⁻_{k+1} = F_k D⁺_k + [∂f/∂θ | 0]        (F_k at the current mean)
//!              D⁺_k     = (I − K_k H) D⁻_k + [0 | ∂K_k/∂η · ν_k]
//! covariance:  ∂P⁻_{k+1}/∂η_j = F̄_k ∂P⁺_k F̄_kᵀ + ∂Q_k/∂η_j   (F̄_k: reference)
//!              ∂S_k = H ∂P⁻_k Hᵀ + ∂R_k,  ∂K_k = (∂P⁻_k Hᵀ − K_k ∂S_k) S_k⁻¹
//!              ∂P⁺_k = ∂P⁻_k − K_k H ∂P⁻_k − (K_k H ∂P⁻_k)ᵀ + K_k ∂S_k K_kᵀ
//! innovation:  ∂ν_k/∂p = −H D⁻_k,   ∂S_k/∂θ = 0.
//! ```

use nalgebra::{Matrix3, Matrix3x4, SMatrix, SVector, Vector3};

use super::{EivInput, InputJacobian, Window};
use crate::error::{Error, Result};
use crate::model::{step_jacobians, wrap_angle, Input, State, Theta};

/// Number of filter states (the two remainder states w_l, w_r included).
pub(crate) const NZ: usize = 12;
/// Index of the sideslip error state `e_β` (the measured β's Gauss-Markov
/// error: the true sideslip is `β̃ − e_β`).
const IB: usize = 9;
/// Index of the first remainder state `w_l` (`w_r` follows).
const IW: usize = 10;
/// Number of sensitivity parameters: 4 θ + 6 η.
pub(crate) const NP: usize = 10;
/// Number of noise scale factors η.
pub(crate) const NETA: usize = 6;

/// A state × state matrix (S = NZ with counting quantisation, else IW).
pub(crate) type MZ<const S: usize> = SMatrix<f64, S, S>;
type DZ<const S: usize> = SMatrix<f64, S, NP>;
pub(crate) type V9 = SVector<f64, NP>;
pub(crate) type M5 = SMatrix<f64, NETA, NETA>;
/// `[θ, η]` × `[θ, η]` (information matrices).
pub(crate) type MP = SMatrix<f64, NP, NP>;
type M3xZ<const S: usize> = SMatrix<f64, 3, S>;
/// The pose rows of the remainder columns of F (`−∂f/∂n_w` of turning wheels).
type M3x2 = SMatrix<f64, 3, 2>;
type MZx3<const S: usize> = SMatrix<f64, S, 3>;

/// Heading measurement noise floor (SPEC §10): keeps S regular on a perfect
/// reference (the position floor is [`Variances::position_floor_m`]).
const HEADING_FLOOR_RAD: f64 = 1e-5;

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
    /// Stationary variance of s_c, σ_c² · e^{η1}.
    pub common: f64,
    /// Stationary variance of s_l and s_r, σ_w² · e^{η2}.
    pub wheel: f64,
    /// Pose white variances `[σ_p²·e^{η3}, σ_p²·e^{η3}, σ_ψ²·e^{η5}]` (floors not included).
    pub pose: [f64; 3],
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
    /// ([`super::WheelNoiseScale::FittedInput`]).
    pub fitted_input: bool,
    /// The log-Jacobian term of the relative white wheel noise in J
    /// ([`super::InputJacobian`]).
    pub input_jacobian: InputJacobian,
    /// With `fitted_input`: the rotation that scales the relative wheel
    /// noise is the moving average of ñ over ±this many samples (0: ñ
    /// itself; [`super::WheelNoiseScale::SmoothedFittedInput`]).
    pub noise_input_half_width: usize,
    /// With `noise_input_half_width > 0`: the rotations come from the
    /// reference's speed and yaw rate (central differences over ±K samples)
    /// at θ_ref instead of from the moving average of ñ
    /// ([`super::WheelNoiseScale::ReferenceInput`]).
    pub noise_input_from_reference: bool,
    /// Floor of the position measurement σ, m ([`super::EivOptions::position_floor_m`]).
    pub position_floor_m: f64,
    /// Also run the null recursion of the innovation diagnostics: the
    /// covariance of the filter's error when the data follow the model
    /// *without* the measurement floors (the floors are regularisation, not
    /// noise the data are assumed to have), giving the expected lag-1
    /// correlation and NIS of the innovations ([`WindowSums::lag1_null`]).
    pub null_without_floors: bool,
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
    /// Gradient of the profile cost `J = ½ quad + correction` over p.
    pub grad_profile: V9,
    /// Outer products of the per-update θ-scores of `½ νᵀS⁻¹ν`, Σ g_k g_kᵀ
    /// (the "meat" of a sandwich covariance).
    pub opg: nalgebra::Matrix4<f64>,
    /// The per-update θ-scores of [`WindowSums::opg`] summed over blocks of
    /// [`SCORE_BLOCK_S`] within the window (a batch-means sandwich that
    /// holds under serially correlated scores).
    pub blocks: BlockScores,
    /// Scoring metric of θ: with the covariance held, the Fisher information
    /// Σ (∂ν/∂θ)ᵀ S⁻¹ (∂ν/∂θ); with the covariance following θ, the
    /// Gauss-Newton matrix Σ (∂r/∂θ)ᵀ(∂r/∂θ) of the whitened innovations.
    pub h_theta: nalgebra::Matrix4<f64>,
    /// Fisher information of η: Σ (∂ν/∂η)ᵀS⁻¹(∂ν/∂η) + ½ tr(S⁻¹∂S S⁻¹∂S).
    pub i_eta: M5,
    /// Gaussian Fisher information of `p = [θ, η]` with both terms,
    /// `Σ (∂ν/∂p_i)ᵀS⁻¹(∂ν/∂p_j) + ½ tr(S⁻¹∂S_i S⁻¹∂S_j)` (the trace term
    /// only over the columns whose `∂S` is propagated: θ when the covariance
    /// follows θ, η when η derivatives are on).
    pub info: MP,
    /// Mean-only information of θ, `Σ (∂ν/∂θ)ᵀS⁻¹(∂ν/∂θ)` (no `∂S/∂θ` term).
    pub info_mean_theta: nalgebra::Matrix4<f64>,
    /// Measurement updates.
    pub updates: usize,
    /// Per component of the whitened innovation: Σ e_k e_{k−1}.
    pub lag1: [f64; 3],
    /// Per component: Σ e_k².
    pub e2: [f64; 3],
    /// Per component: Σ E₀[e_k e_{k−1}], the expectation of [`WindowSums::lag1`]
    /// under the null of [`Variances::null_without_floors`] (zero unless it is on).
    pub lag1_null: [f64; 3],
    /// Per component: Σ E₀[e_k²] under the same null.
    pub e2_null: [f64; 3],
    /// Σ E₀[νᵀS⁻¹ν] = Σ tr(S⁻¹S₀) under the same null (S₀ the innovation
    /// covariance without the floors, with the filter's gain).
    pub quad_null: f64,
    /// Expected gradient of the profile cost caused by the input noise,
    /// `Σ_k −tr(S_k⁻¹ H X_k,i Hᵀ)` (the corrected-score term, see [`run_window`]).
    pub bias: nalgebra::Vector4<f64>,
    /// θ-gradient of the coloured-noise correction `−Σ m log(1 − ŝ)` alone.
    pub grad_correction: nalgebra::Vector4<f64>,
    /// θ-gradient of `½ Σ log det S` alone (zero with the covariance held).
    pub grad_logdet: nalgebra::Vector4<f64>,
    /// The input log-Jacobian term `T = −Σ u ln(C(θ)/C(θ_ref))`
    /// ([`super::InputJacobian`]; part of J, not of M).
    pub jacobian: f64,
    /// ∂T/∂θ with the weights u held (already included in `grad_profile`).
    pub grad_jacobian: nalgebra::Vector4<f64>,
    /// ∂²T/∂θ² = Σ u ∇C∇Cᵀ/C² with u held (already included in `h_theta`).
    pub hess_jacobian: nalgebra::Matrix4<f64>,
    /// `∂(grad_jacobian)/∂η_j` per noise scale: how the θ-score's input
    /// log-Jacobian term moves with η through its weights u (exact, for
    /// [`super::InputJacobian::FilterShare`] and its second-order variant,
    /// whose u depends on η through the white variance and S; zero for the
    /// other modes and without η derivatives).
    pub grad_jacobian_eta: [nalgebra::Vector4<f64>; NETA],
    /// Σ u per wheel `[left, right]`.
    pub jacobian_weight: [f64; 2],
    /// Samples where each wheel turns `[left, right]` (Σ m).
    pub turning: [f64; 2],
}

/// Length of the blocks over which the per-update θ-scores are summed for
/// the block sandwich ([`BlockScores`]), s: several correlation times of
/// the slowest wheel noise a production-car model or the simulator has (5 s).
pub(crate) const SCORE_BLOCK_S: f64 = 20.0;

/// Sums of the block θ-scores `G_b` of one or more windows (blocks never
/// span two windows: each window's filter starts afresh).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BlockScores {
    /// Σ G_b.
    pub sum: nalgebra::Vector4<f64>,
    /// Σ G_b G_bᵀ.
    pub outer: nalgebra::Matrix4<f64>,
    /// Σ over neighbouring blocks of the same window of `G_b G_{b+1}ᵀ + G_{b+1} G_bᵀ`.
    pub cross: nalgebra::Matrix4<f64>,
    /// Blocks.
    pub n: usize,
    /// Neighbouring pairs.
    pub pairs: usize,
    /// Σ over neighbouring pairs of `G_b + G_{b+1}` (for the centring).
    pub pair_sum: nalgebra::Vector4<f64>,
}

impl BlockScores {
    pub(crate) fn zero() -> Self {
        BlockScores {
            sum: nalgebra::Vector4::zeros(),
            outer: nalgebra::Matrix4::zeros(),
            cross: nalgebra::Matrix4::zeros(),
            n: 0,
            pairs: 0,
            pair_sum: nalgebra::Vector4::zeros(),
        }
    }

    fn add(&mut self, o: &BlockScores) {
        self.sum += o.sum;
        self.outer += o.outer;
        self.cross += o.cross;
        self.n += o.n;
        self.pairs += o.pairs;
        self.pair_sum += o.pair_sum;
    }

    /// Closes a block with score sum `g` (`prev`: the window's previous block).
    fn push(&mut self, g: &nalgebra::Vector4<f64>, prev: Option<&nalgebra::Vector4<f64>>) {
        self.sum += g;
        self.outer += g * g.transpose();
        self.n += 1;
        if let Some(p) = prev {
            self.cross += p * g.transpose() + g * p.transpose();
            self.pairs += 1;
            self.pair_sum += p + g;
        }
    }

    /// [`BlockScores::push`] for the unit tests.
    #[cfg(test)]
    pub(crate) fn push_for_test(&mut self, g: &nalgebra::Vector4<f64>, prev: Option<&nalgebra::Vector4<f64>>) {
        self.push(g, prev);
    }

    /// [`BlockScores::add`] for the unit tests.
    #[cfg(test)]
    pub(crate) fn add_for_test(&mut self, o: &BlockScores) {
        self.add(o);
    }

    /// The "meat" of the block sandwich: the centred outer products of the
    /// block scores plus the lag-1 cross products with Bartlett weight ½
    /// (Newey–West with one block of lag), scaled by n/(n − 1). None with
    /// fewer than two blocks.
    pub(crate) fn meat(&self) -> Option<nalgebra::Matrix4<f64>> {
        if self.n < 2 {
            return None;
        }
        let n = self.n as f64;
        let mean = self.sum / n;
        let mm = mean * mean.transpose();
        let centred = self.outer - mm * n;
        let cross = self.cross - (self.pair_sum * mean.transpose() + mean * self.pair_sum.transpose())
            + mm * (2.0 * self.pairs as f64);
        Some((centred + cross * 0.5) * (n / (n - 1.0)))
    }
}

impl WindowSums {
    pub(crate) fn zero() -> Self {
        WindowSums {
            quad: 0.0,
            logdet: 0.0,
            correction: 0.0,
            grad: V9::zeros(),
            grad_profile: V9::zeros(),
            opg: nalgebra::Matrix4::zeros(),
            blocks: BlockScores::zero(),
            h_theta: nalgebra::Matrix4::zeros(),
            i_eta: M5::zeros(),
            info: MP::zeros(),
            info_mean_theta: nalgebra::Matrix4::zeros(),
            updates: 0,
            lag1: [0.0; 3],
            e2: [0.0; 3],
            lag1_null: [0.0; 3],
            e2_null: [0.0; 3],
            quad_null: 0.0,
            bias: nalgebra::Vector4::zeros(),
            grad_correction: nalgebra::Vector4::zeros(),
            grad_logdet: nalgebra::Vector4::zeros(),
            jacobian: 0.0,
            grad_jacobian: nalgebra::Vector4::zeros(),
            hess_jacobian: nalgebra::Matrix4::zeros(),
            grad_jacobian_eta: [nalgebra::Vector4::zeros(); NETA],
            jacobian_weight: [0.0; 2],
            turning: [0.0; 2],
        }
    }

    pub(crate) fn add(&mut self, o: &WindowSums) {
        self.quad += o.quad;
        self.logdet += o.logdet;
        self.correction += o.correction;
        self.grad += o.grad;
        self.grad_profile += o.grad_profile;
        self.opg += o.opg;
        self.blocks.add(&o.blocks);
        self.h_theta += o.h_theta;
        self.i_eta += o.i_eta;
        self.info += o.info;
        self.info_mean_theta += o.info_mean_theta;
        self.updates += o.updates;
        self.bias += o.bias;
        self.grad_correction += o.grad_correction;
        self.grad_logdet += o.grad_logdet;
        self.jacobian += o.jacobian;
        self.grad_jacobian += o.grad_jacobian;
        self.hess_jacobian += o.hess_jacobian;
        for (a, b) in self.grad_jacobian_eta.iter_mut().zip(&o.grad_jacobian_eta) {
            *a += b;
        }
        for w in 0..2 {
            self.jacobian_weight[w] += o.jacobian_weight[w];
            self.turning[w] += o.turning[w];
        }
        self.quad_null += o.quad_null;
        for c in 0..3 {
            self.lag1[c] += o.lag1[c];
            self.e2[c] += o.e2[c];
            self.lag1_null[c] += o.lag1_null[c];
            self.e2_null[c] += o.e2_null[c];
        }
    }

    /// The objective `M = ½ Σ(νᵀS⁻¹ν + log det S) − Σ m log(1 − ŝ)`.
    pub(crate) fn merit(&self) -> f64 {
        0.5 * (self.quad + self.logdet) + self.correction
    }

    /// The profile cost `J = ½ Σ νᵀS⁻¹ν − Σ m log(1 − ŝ)` (SPEC §10), plus
    /// the input log-Jacobian term when it is on.
    pub(crate) fn profile(&self) -> f64 {
        0.5 * self.quad + self.correction + self.jacobian
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
    /// ∂S/∂p_j (zero where not propagated).
    pub ds: [Matrix3<f64>; NP],
    /// Whitened innovation `r = L⁻¹ν` (S = LLᵀ).
    pub r: Vector3<f64>,
    /// ∂r/∂θ (3×4; zero with the covariance held).
    pub dr: SMatrix<f64, 3, 4>,
}

/// The structured transition of one step,
/// `F = [[F_x, F_xs, 0, F_xβ, F_xw], [0, diag(a_s), 0, 0, 0], [0, 0, a_b I, 0, 0], [0, 0, 0, a_β, 0],
/// [0, 0, 0, 0, diag(a_w)]]`, `F_x = I + e_0 f02 e_2ᵀ + e_1 f12 e_2ᵀ`, `F_xβ = −(f02, f12, 0)ᵀ` (the
/// sideslip enters the step as the heading does, `φ = ψ + ωt_s/2 + β`), `diag` the diagonal of rows 3..S.
#[derive(Clone, Copy)]
struct Transition<'a, const S: usize> {
    f02: f64,
    f12: f64,
    fxs: &'a Matrix3<f64>,
    fxw: &'a M3x2,
    diag: &'a [f64; S],
}

impl<const S: usize> Transition<'_, S> {
    /// Rows 0..3 of `F v` for the vector with entries `v(k)` (the dense rows
    /// of F; [`propagate`] writes the same sums out column-wise).
    #[inline(always)]
    fn top(&self, v: impl Fn(usize) -> f64) -> [f64; 3] {
        let (fxs, fxw) = (self.fxs, self.fxw);
        let fr = [self.f02, self.f12, 0.0];
        let (v2, v3, v4, v5, vb) = (v(2), v(3), v(4), v(5), v(IB));
        let (v9, v10) = if S > IW { (v(IW), v(IW + 1)) } else { (0.0, 0.0) };
        std::array::from_fn(|i| {
            v(i) + fr[i] * v2 + fxs[(i, 0)] * v3 + fxs[(i, 1)] * v4 + fxs[(i, 2)] * v5 - fr[i] * vb
                + if S > IW { fxw[(i, 0)] * v9 + fxw[(i, 1)] * v10 } else { 0.0 }
        })
    }
}

/// `F P Fᵀ` for the structured transition `t` ([`Transition`]) and a
/// symmetric `P`.
///
/// Only the lower triangle is computed (through `W = P F_topᵀ`, NZ×3, `F_top`
/// the first three rows of F) and mirrored, so the result is exactly
/// symmetric. (The filter calls [`propagate_in_place`]; this copy is for the
/// kernel tests.)
#[cfg(test)]
fn propagate<const S: usize>(p: &MZ<S>, t: &Transition<'_, S>) -> MZ<S> {
    let mut out = *p;
    propagate_in_place(&mut out, t);
    out
}

/// [`propagate`] overwriting `p` (no S×S temporary, no copy of the result).
///
/// Safe in place: the pose rows and columns of the result depend on P only
/// through `W`, computed first, and every other lower-triangle entry
/// `diag_c·diag_i·P[i, c]` only on the same entry of P.
#[inline(always)]
fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<'_, S>) {
    // W = P F_topᵀ: row r of W is F_top applied to row r of P. Computed
    // column by column (`W[:, c] = Σ_k F[c, k] P[:, k]`, the sum in the order
    // of [`Transition::top`], so every entry is the same to the bit): the
    // inner loop runs down contiguous columns of P and vectorises.
    let mut w = MZx3::<S>::zeros();
    let fr = [t.f02, t.f12, 0.0];
    for c in 0..3 {
        let (a2, a3, a4, a5) = (fr[c], t.fxs[(c, 0)], t.fxs[(c, 1)], t.fxs[(c, 2)]);
        let (a9, a10) = (t.fxw[(c, 0)], t.fxw[(c, 1)]);
        let (pc, p2, p3, p4, p5) = (p.column(c), p.column(2), p.column(3), p.column(4), p.column(5));
        let pb = p.column(IB);
        let mut wc = w.column_mut(c);
        if S > IW {
            let (p9, p10) = (p.column(IW), p.column(IW + 1));
            for r in 0..S {
                wc[r] = pc[r] + a2 * p2[r] + a3 * p3[r] + a4 * p4[r] + a5 * p5[r] - a2 * pb[r]
                    + (a9 * p9[r] + a10 * p10[r]);
            }
        } else {
            for r in 0..S {
                wc[r] = pc[r] + a2 * p2[r] + a3 * p3[r] + a4 * p4[r] + a5 * p5[r] - a2 * pb[r] + 0.0;
            }
        }
    }
    let out = p;
    // Pose block: F_top W (lower triangle).
    for c in 0..3 {
        let col = t.top(|k| w[(k, c)]);
        for i in c..3 {
            out[(i, c)] = col[i];
        }
    }
    // Rows 3..S: diagonal rows of F.
    // (Column by column, down contiguous memory.)
    let diag = t.diag;
    for c in 0..3 {
        for i in 3..S {
            out[(i, c)] = diag[i] * w[(i, c)];
        }
    }
    for c in 3..S {
        for i in c..S {
            out[(i, c)] = diag[c] * (diag[i] * out[(i, c)]);
        }
    }
    mirror_lower(out);
}

/// Copies the strict lower triangle onto the upper one.
#[inline(always)]
fn mirror_lower<const S: usize>(m: &mut MZ<S>) {
    for c in 1..S {
        for r in 0..c {
            m[(r, c)] = m[(c, r)];
        }
    }
}

/// `H A` for `H = [I₃ 0 I₃]`: rows 0..3 plus rows 6..9.
#[inline(always)]
fn h_rows<const S: usize, const C: usize>(a: &SMatrix<f64, S, C>) -> SMatrix<f64, 3, C> {
    let mut out = SMatrix::<f64, 3, C>::zeros();
    for r in 0..3 {
        for c in 0..C {
            out[(r, c)] = a[(r, c)] + a[(r + 6, c)];
        }
    }
    out
}

/// `B Hᵀ` for a 3×9 `B`: columns 0..3 plus columns 6..9.
#[inline(always)]
fn h_cols<const S: usize>(b: &M3xZ<S>) -> Matrix3<f64> {
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

/// `(I − K H) A (I − K H)ᵀ` for `H = [I₃ 0 I₃]` and a symmetric `A`.
///
/// In the factored order of the Joseph form (`X = A − K(HA)`, then
/// `X − (XHᵀ)Kᵀ`; the expanded `A − KHA − (KHA)ᵀ + K(HAHᵀ)Kᵀ` is
/// numerically unstable here), but only the entries of X that the lower
/// triangle of the result needs, and only that triangle, mirrored.
///
/// (The filter calls [`joseph_in_place`]; this copy is for the kernel tests.)
#[cfg(test)]
fn joseph<const S: usize>(a: &MZ<S>, k: &MZx3<S>) -> MZ<S> {
    let mut out = *a;
    joseph_in_place(&mut out, k, None);
    out
}

/// [`joseph`] overwriting `a` (no S×S temporaries, no copy of the result).
///
/// Safe in place: `HA` is taken first; then every entry of X depends on A
/// only through the same entry, and every lower-triangle entry of the result
/// on X only through the same entry and `XHᵀ` (taken before them); the upper
/// triangle is mirrored last.
///
/// With `d`, `K D Kᵀ` is added as well ([`add_kdk`]) before the one mirror:
/// the same to the bit as [`add_kdk`] after the mirrored Joseph form.
#[inline(always)]
fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>) {
    // HA (3×9): rows 0..3 plus rows 6..9.
    let ha = h_rows(a);
    joseph_in_place_with(a, k, d, &ha);
}

/// [`joseph_in_place`] given `ha = HA` (`h_rows(a)`), which the filter has
/// already formed for the innovation covariance.
#[inline(always)]
fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>) {
    debug_assert!(*ha == h_rows(a), "joseph_in_place_with: ha is not HA");
    // X = A − K HA: every row of columns 0..3 and 6..9 (for XHᵀ), and the
    // lower triangle of the other columns (the rest of A is left as it is:
    // the mirror overwrites it).
    let x = a;
    for c in 0..S {
        let first = if c < 3 || (6..9).contains(&c) { 0 } else { c };
        let (h0, h1, h2) = (ha[(0, c)], ha[(1, c)], ha[(2, c)]);
        for r in first..S {
            x[(r, c)] -= k[(r, 0)] * h0 + k[(r, 1)] * h1 + k[(r, 2)] * h2;
        }
    }
    // XHᵀ (9×3).
    let mut xh = MZx3::<S>::zeros();
    for m in 0..3 {
        for r in 0..S {
            xh[(r, m)] = x[(r, m)] + x[(r, m + 6)];
        }
    }
    // Lower triangle of X − (XHᵀ)Kᵀ.
    for c in 0..S {
        let (k0, k1, k2) = (k[(c, 0)], k[(c, 1)], k[(c, 2)]);
        for r in c..S {
            x[(r, c)] -= xh[(r, 0)] * k0 + xh[(r, 1)] * k1 + xh[(r, 2)] * k2;
        }
    }
    if let Some(d) = d {
        add_kdk_lower(x, k, d);
    }
    mirror_lower(x);
}

/// `(I − K H) A (I − K H)ᵀ` for `H = [I₃ 0 I₃]` and any `A` (the
/// cross-covariances X of the corrected score are not symmetric).
#[inline(always)]
fn joseph_general<const S: usize>(a: &MZ<S>, k: &MZx3<S>) -> MZ<S> {
    let x = a - k * h_rows(a);
    let mut xh = MZx3::<S>::zeros();
    for r in 0..S {
        for c in 0..3 {
            xh[(r, c)] = x[(r, c)] + x[(r, c + 6)];
        }
    }
    x - xh * k.transpose()
}

/// `F A Fᵀ` as [`propagate`] for any `A` (not only symmetric ones).
#[inline(always)]
fn propagate_general<const S: usize>(p: &MZ<S>, t: &Transition<'_, S>) -> MZ<S> {
    // M = F P (row operations).
    let mut m = MZ::<S>::zeros();
    for j in 0..S {
        let col = t.top(|k| p[(k, j)]);
        for (r, v) in col.into_iter().enumerate() {
            m[(r, j)] = v;
        }
        for r in 3..S {
            m[(r, j)] = t.diag[r] * p[(r, j)];
        }
    }
    // F P Fᵀ = M Fᵀ (column operations).
    let mut out = MZ::<S>::zeros();
    for i in 0..S {
        let row = t.top(|k| m[(i, k)]);
        for (c, v) in row.into_iter().enumerate() {
            out[(i, c)] = v;
        }
        for c in 3..S {
            out[(i, c)] = t.diag[c] * m[(i, c)];
        }
    }
    out
}

/// `F C` for an S×3 `C` and the structured transition of [`propagate`].
#[inline(always)]
fn propagate_cols<const S: usize>(c: &MZx3<S>, t: &Transition<'_, S>) -> MZx3<S> {
    let mut out = MZx3::<S>::zeros();
    for j in 0..3 {
        let col = t.top(|k| c[(k, j)]);
        for (r, v) in col.into_iter().enumerate() {
            out[(r, j)] = v;
        }
        for r in 3..S {
            out[(r, j)] = t.diag[r] * c[(r, j)];
        }
    }
    out
}

/// `dst += K D Kᵀ` for a symmetric 3×3 `D` and an exactly symmetric `dst`
/// (every covariance and covariance derivative of the filter), exactly
/// symmetric: the lower triangle is added ([`add_kdk_lower`]) and mirrored,
/// which for a symmetric `dst` is the same to the bit as adding the same
/// product to both triangles. (The filter adds it inside
/// [`joseph_in_place`]; this copy is for the kernel tests.)
#[cfg(test)]
fn add_kdk<const S: usize>(dst: &mut MZ<S>, k: &MZx3<S>, d: &Matrix3<f64>) {
    debug_assert!(*dst == dst.transpose(), "add_kdk: dst not exactly symmetric");
    add_kdk_lower(dst, k, d);
    mirror_lower(dst);
}

/// The lower triangle of `dst += K D Kᵀ` (down contiguous columns).
#[inline(always)]
fn add_kdk_lower<const S: usize>(dst: &mut MZ<S>, k: &MZx3<S>, d: &Matrix3<f64>) {
    let kd = k * d;
    for c in 0..S {
        let (k0, k1, k2) = (k[(c, 0)], k[(c, 1)], k[(c, 2)]);
        for r in c..S {
            dst[(r, c)] += kd[(r, 0)] * k0 + kd[(r, 1)] * k1 + kd[(r, 2)] * k2;
        }
    }
}

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

/// A number with its gradient over θ (forward-mode differentiation of the
/// covariance-recursion terms; exact to rounding). `N = 4` carries the
/// gradient; `N = 0` only the value (the same operations on it, so the
/// value is the same to the bit), for passes that do not need `∂P/∂θ`.
#[derive(Debug, Clone, Copy)]
struct Dual<const N: usize> {
    v: f64,
    d: [f64; N],
}

impl<const N: usize> Dual<N> {
    fn cst(v: f64) -> Self {
        Dual { v, d: [0.0; N] }
    }
    fn var(v: f64, i: usize) -> Self {
        let mut d = [0.0; N];
        if let Some(x) = d.get_mut(i) {
            *x = 1.0;
        }
        Dual { v, d }
    }
    fn sin_cos(self) -> (Self, Self) {
        let (s, c) = self.v.sin_cos();
        (Dual { v: s, d: self.d.map(|x| c * x) }, Dual { v: c, d: self.d.map(|x| -s * x) })
    }
}

impl<const N: usize> std::ops::Add for Dual<N> {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Dual { v: self.v + o.v, d: std::array::from_fn(|i| self.d[i] + o.d[i]) }
    }
}
impl<const N: usize> std::ops::Sub for Dual<N> {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Dual { v: self.v - o.v, d: std::array::from_fn(|i| self.d[i] - o.d[i]) }
    }
}
impl<const N: usize> std::ops::Mul for Dual<N> {
    type Output = Self;
    // The product rule adds.
    #[allow(clippy::suspicious_arithmetic_impl)]
    fn mul(self, o: Self) -> Self {
        Dual { v: self.v * o.v, d: std::array::from_fn(|i| self.d[i] * o.v + self.v * o.d[i]) }
    }
}
impl<const N: usize> std::ops::Mul<f64> for Dual<N> {
    type Output = Self;
    fn mul(self, o: f64) -> Self {
        Dual { v: self.v * o, d: self.d.map(|x| x * o) }
    }
}
impl<const N: usize> std::ops::Div for Dual<N> {
    type Output = Self;
    fn div(self, o: Self) -> Self {
        let inv = 1.0 / o.v;
        let q = self.v * inv;
        Dual { v: q, d: std::array::from_fn(|i| (self.d[i] - q * o.d[i]) * inv) }
    }
}
impl<const N: usize> std::ops::Neg for Dual<N> {
    type Output = Self;
    fn neg(self) -> Self {
        Dual { v: -self.v, d: self.d.map(|x| -x) }
    }
}

/// The terms of the covariance recursion at one step, evaluated on the
/// reference (reference heading ψ, measured inputs) at θ, with their
/// θ-gradients when `N = 4`: `F̄[0,2], F̄[1,2]`, `∂f/∂n_l`, `∂f/∂n_r`,
/// `∂f/∂a_y` (as [`step_jacobians`] and the module docs).
struct ReferenceTerms<const N: usize> {
    f02: Dual<N>,
    f12: Dual<N>,
    fn_l: [Dual<N>; 3],
    fn_r: [Dual<N>; 3],
    f_a: [Dual<N>; 3],
}

fn reference_terms<const N: usize>(psi: f64, u: &Input, th: &Theta, ts: f64) -> ReferenceTerms<N> {
    let (c_e, c_d, t_r, d) =
        (Dual::<N>::var(th.c_e, 0), Dual::<N>::var(th.c_d, 1), Dual::<N>::var(th.t_r, 2), Dual::<N>::var(th.d, 3));
    let (nl, nr) = (u.n_rl, u.n_rr);
    let c_rl = c_e + c_d * 0.5 + d * u.a_y;
    let c_rr = c_e - c_d * 0.5 - d * u.a_y;
    let v = (c_rl * nl + c_rr * nr) * 0.5;
    let num = c_rr * nr - c_rl * nl;
    let omega = num / t_r;
    let phi = omega * (ts / 2.0) + Dual::cst(psi + u.beta);
    let (s, c) = phi.sin_cos();
    let row = |dv: Dual<N>, domega: Dual<N>| -> [Dual<N>; 3] {
        let dphi = domega * (ts / 2.0);
        [(c * dv - v * s * dphi) * ts, (s * dv + v * c * dphi) * ts, domega * ts]
    };
    let fn_l = row(c_rl * 0.5, -(c_rl / t_r));
    let fn_r = row(c_rr * 0.5, c_rr / t_r);
    // ∂f/∂a_y = ∂f/∂c_rl·d − ∂f/∂c_rr·d with ∂f/∂c_w = (∂v/∂c_w, ∂ω/∂c_w) through `row`.
    let f_a = {
        let a = row(Dual::cst(nl * 0.5), Dual::cst(-nl) / t_r);
        let b = row(Dual::cst(nr * 0.5), Dual::cst(nr) / t_r);
        std::array::from_fn(|r| (a[r] - b[r]) * d)
    };
    ReferenceTerms { f02: -(v * s) * ts, f12: v * c * ts, fn_l, fn_r, f_a }
}

fn vec_of<const N: usize>(a: &[Dual<N>; 3]) -> Vector3<f64> {
    Vector3::new(a[0].v, a[1].v, a[2].v)
}

fn dvec_of(a: &[Dual<4>; 3], j: usize) -> Vector3<f64> {
    Vector3::new(a[0].d[j], a[1].d[j], a[2].d[j])
}

/// `C_w(θ_ref)/C_w(θ)` per wheel `[left, right]` with its θ-gradient: the
/// factor that turns the measured wheel rotation into the true rotation
/// fitted at θ, `n̂ = ñ·C(θ_ref)/C(θ)` (the distance `ñ·C(θ_ref)` is held,
/// so the relative wheel noise in metres no longer grows with C(θ)).
fn fitted_input_factors(a_y: f64, th: &Theta, th_ref: &Theta) -> [Dual<4>; 2] {
    let (c_e, c_d, d) = (Dual::var(th.c_e, 0), Dual::var(th.c_d, 1), Dual::var(th.d, 3));
    let c_rl = c_e + c_d * 0.5 + d * a_y;
    let c_rr = c_e - c_d * 0.5 - d * a_y;
    let (r_rl, r_rr) = th_ref.wheel_circumferences(a_y);
    [Dual::cst(r_rl) / c_rl, Dual::cst(r_rr) / c_rr]
}

/// The values of [`ReferenceTerms`]: `F̄[0,2], F̄[1,2]`, `∂f/∂n_l`, `∂f/∂n_r`, `∂f/∂a_y`.
struct ReferenceValues {
    f02: f64,
    f12: f64,
    fn_l: Vector3<f64>,
    fn_r: Vector3<f64>,
    f_a: Vector3<f64>,
}

impl<const N: usize> ReferenceTerms<N> {
    fn values(&self) -> ReferenceValues {
        ReferenceValues {
            f02: self.f02.v,
            f12: self.f12.v,
            fn_l: vec_of(&self.fn_l),
            fn_r: vec_of(&self.fn_r),
            f_a: vec_of(&self.f_a),
        }
    }
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
}

impl Mode {
    /// Objective only.
    pub(crate) fn cost(follows_theta: bool) -> Self {
        Mode { follows_theta, derivs: false, eta: false, theta: false, eta_skip: 0 }
    }
    /// Objective and derivatives (η derivatives when `eta`).
    pub(crate) fn full(follows_theta: bool, eta: bool) -> Self {
        Mode { follows_theta, derivs: true, eta, theta: true, eta_skip: 0 }
    }
    /// Objective and the η derivatives only (see [`Mode::theta`]).
    pub(crate) fn eta_only(follows_theta: bool) -> Self {
        Mode { follows_theta, derivs: true, eta: true, theta: false, eta_skip: 0 }
    }
    /// The same without the covariance derivatives of the η in `skip`
    /// (bit j = η_j; see [`Mode::eta_skip`]).
    pub(crate) fn skipping_eta(self, skip: u8) -> Self {
        Mode { eta_skip: skip, ..self }
    }
}

/// `A + Aᵀ` added to `dst` for a 3×9 `A` occupying rows 0..3.
#[inline(always)]
fn add_sym_rows<const S: usize>(dst: &mut MZ<S>, a: &M3xZ<S>) {
    for r in 0..3 {
        for c in 0..S {
            dst[(r, c)] += a[(r, c)];
            dst[(c, r)] += a[(r, c)];
        }
    }
}

/// `ln(C_w(θ)/C_w(θ_ref))` per wheel `[left, right]` at lateral
/// acceleration `a_y` and its θ-gradient `∇C_w/C_w` (θ order
/// `[c_e, c_d, t_r, d]`; the Hessian of the log is `−∇ln C ∇ln Cᵀ`, C being
/// linear in θ).
fn log_circumference_ratio(a_y: f64, th: &Theta, th_ref: &Theta) -> [(f64, nalgebra::Vector4<f64>); 2] {
    let (cl, cr) = th.wheel_circumferences(a_y);
    let (rl, rr) = th_ref.wheel_circumferences(a_y);
    let gl = nalgebra::Vector4::new(1.0, 0.5, 0.0, a_y) / cl;
    let gr = nalgebra::Vector4::new(1.0, -0.5, 0.0, -a_y) / cr;
    [((cl / rl).ln(), gl), ((cr / rr).ln(), gr)]
}

/// A wheel input waiting for the next measurement update (FilterShare):
/// wheel index, relative white variance `σ²n̂²`, `f_w = ∂f/∂n_w` (pose rows),
/// `ln(C_w(θ)/C_w(θ_ref))` and its θ-gradient.
type PendingInput = (usize, f64, Vector3<f64>, f64, nalgebra::Vector4<f64>);

/// FilterShare: adds every pending input's log-Jacobian term with its
/// weight u, the share `var·f_wᵀS⁻¹f_w` of its white variance that this
/// update removes (`u = share·(1 − 2·share)` with `second_order`), and
/// clears `pending`. With `eta_ds` (the propagated columns and their ∂S),
/// also the weights' η-derivatives: u depends on η through the white
/// variance (∝ e^η₀) and S, so the θ-score's term −Σ u ∇L moves with η,
/// `∂share/∂η_j = [j = 0]·share − var·(S⁻¹f)ᵀ ∂S_j (S⁻¹f)`
/// ([`WindowSums::grad_jacobian_eta`]).
#[inline(always)]
fn add_filter_share_terms(
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
fn add_jacobian_term(out: &mut WindowSums, u: f64, l: f64, g: &nalgebra::Vector4<f64>) {
    out.jacobian -= u * l;
    out.grad_jacobian -= g * u;
    out.hess_jacobian += g * g.transpose() * u;
}

/// Runs the filter over one window at θ (mean). The covariance recursion
/// is linearised along the reference (reference heading, measured wheel
/// rotations) at `theta_ref`, or at θ when `mode.follows_theta` (then
/// `theta_ref` is ignored). Accumulates the objective and, with
/// `mode.derivs`, its gradient and the Fisher information. With `record`,
/// every innovation and its derivatives are returned.
///
/// Speed: P and every `∂P/∂p_j` are symmetric and are propagated as such
/// (lower triangle, mirrored; [`propagate`], [`joseph`]); a sensitivity
/// column whose covariance derivative is identically zero (η_5 when the
/// heading noise is tied to the position noise) is not propagated; the
/// θ-gradients of the covariance terms are differentiated only when
/// `∂P/∂θ` is propagated; nothing is allocated per sample.
pub(crate) fn run_window(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    #[cfg(target_arch = "x86_64")]
    if kernels() == Kernels::Avx2 {
        // SAFETY: `kernels()` returns `Avx2` only when the running CPU reports
        // both AVX2 and FMA (`is_x86_feature_detected!`), the features
        // `run_window_avx2` is compiled for.
        #[allow(unsafe_code)]
        return unsafe { run_window_avx2(input, window, theta, theta_ref, v, mode, record) };
    }
    run_window_baseline(input, window, theta, theta_ref, v, mode, record)
}

/// The instruction set the filter's kernels run with ([`kernels`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Kernels {
    /// The build's target features (SSE2 on a default x86-64 build).
    Baseline,
    /// AVX2 and FMA, detected at run time (x86-64 only).
    Avx2,
}

/// The kernels [`run_window`] uses: AVX2 where the CPU has AVX2 and FMA
/// (x86-64), unless the environment variable `ODOCAL_SIMD=baseline` asks
/// for the build's baseline instruction set. Decided once per process.
///
/// Both compile the same Rust code; Rust never contracts a multiply and an
/// add into a fused one on its own, so the two give results identical to
/// the bit (test `avx2_kernels_equal_the_baseline_to_the_bit`). AVX2's
/// four-wide registers make the covariance kernels about 1.3× faster
/// (docs/performance.md, stop 22).
pub(crate) fn kernels() -> Kernels {
    static CHOICE: std::sync::OnceLock<Kernels> = std::sync::OnceLock::new();
    *CHOICE.get_or_init(|| {
        let forced = std::env::var("ODOCAL_SIMD").is_ok_and(|s| s.eq_ignore_ascii_case("baseline"));
        if !forced && avx2_available() {
            Kernels::Avx2
        } else {
            Kernels::Baseline
        }
    })
}

/// Whether the running CPU has AVX2 and FMA.
pub(crate) fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// [`run_window_baseline`] compiled for AVX2 and FMA: the window loop and
/// every kernel it calls are inlined ([`Inlined`]), so all of it is
/// compiled for them.
///
/// # Safety
/// The running CPU must support AVX2 and FMA ([`avx2_available`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
pub(crate) fn run_window_avx2(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    // One function per state size: two smaller functions for the compiler
    // (they can be optimised in parallel) than one with both inlined.
    if v.quant_counting {
        run_window_avx2_s::<NZ>(input, window, theta, theta_ref, v, mode, record)
    } else {
        run_window_avx2_s::<IW>(input, window, theta, theta_ref, v, mode, record)
    }
}

/// [`run_window_avx2`] at the state size `S`.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[inline(never)]
fn run_window_avx2_s<const S: usize>(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    run_window_s::<S, Inlined>(input, window, theta, theta_ref, v, mode, record)
}

/// [`run_window`] with the build's baseline target features.
pub(crate) fn run_window_baseline(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    run_window_sized::<OutOfLine>(input, window, theta, theta_ref, v, mode, record)
}

/// [`run_window_s`] at the state size of `v`, the big kernels called as `K` says.
#[inline(always)]
fn run_window_sized<K: KernelCalls>(
    input: &EivInput<'_>,
    window: &Window,
    theta: &Theta,
    theta_ref: &Theta,
    v: &Variances,
    mode: Mode,
    record: Option<&mut Vec<InnovationRecord>>,
) -> Result<WindowSums> {
    // The remainder states exist only with counting quantisation: the other
    // models run the 9-state filter (the same arithmetic, no 11-row storage).
    if v.quant_counting {
        run_window_s::<NZ, K>(input, window, theta, theta_ref, v, mode, record)
    } else {
        run_window_s::<IW, K>(input, window, theta, theta_ref, v, mode, record)
    }
}

/// How the window loop calls its three big covariance kernels (the
/// propagation and the two Joseph updates).
///
/// The AVX2 copy inlines them ([`Inlined`]), so that they are compiled for
/// AVX2 with it. The baseline copy calls one out-of-line instance of each
/// ([`OutOfLine`]), as before the AVX2 copy existed: inlined at their eight
/// call sites they made the baseline 5–10 % slower and every build of the
/// crate slower to compile.
trait KernelCalls {
    fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<'_, S>);
    fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>);
    fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>);
}

/// [`KernelCalls`] inlining the kernels (the AVX2 copy).
struct Inlined;

/// [`KernelCalls`] calling out-of-line kernels (the baseline copy).
struct OutOfLine;

impl KernelCalls for Inlined {
    #[inline(always)]
    fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<'_, S>) {
        propagate_in_place(p, t);
    }
    #[inline(always)]
    fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>) {
        joseph_in_place(a, k, d);
    }
    #[inline(always)]
    fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>) {
        joseph_in_place_with(a, k, d, ha);
    }
}

impl KernelCalls for OutOfLine {
    #[inline(never)]
    fn propagate_in_place<const S: usize>(p: &mut MZ<S>, t: &Transition<'_, S>) {
        propagate_in_place(p, t);
    }
    #[inline(never)]
    fn joseph_in_place<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>) {
        joseph_in_place(a, k, d);
    }
    #[inline(never)]
    fn joseph_in_place_with<const S: usize>(a: &mut MZ<S>, k: &MZx3<S>, d: Option<&Matrix3<f64>>, ha: &M3xZ<S>) {
        joseph_in_place_with(a, k, d, ha);
    }
}

/// [`run_window`] with the state size `S` (`NZ` or `IW`). Always inlined,
/// so that [`run_window_avx2`] compiles it (and the kernels it inlines) for
/// AVX2.
#[inline(always)]
fn run_window_s<const S: usize, K: KernelCalls>(
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

#[cfg(test)]
mod kernel_tests {
    //! The structured, symmetric kernels against the plain dense formulas.
    use super::*;

    /// Rounding of ~100 products of O(1) numbers: far above it would be a
    /// wrong index, far below any effect on a fit.
    const KERNEL_REL_TOL: f64 = 1e-13;

    /// A deterministic pseudo-random number in [−1, 1).
    fn lcg(state: &mut u64) -> f64 {
        *state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        ((*state >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
    }

    fn random_symmetric(state: &mut u64) -> MZ<NZ> {
        let a = MZ::<NZ>::from_fn(|_, _| lcg(state));
        a * a.transpose() + MZ::<NZ>::identity()
    }

    fn h() -> SMatrix<f64, 3, NZ> {
        let mut h = SMatrix::<f64, 3, NZ>::zeros();
        for i in 0..3 {
            h[(i, i)] = 1.0;
            h[(i, i + 6)] = 1.0;
        }
        h
    }

    fn assert_close(a: &MZ<NZ>, b: &MZ<NZ>, what: &str) {
        let scale = b.amax().max(1.0);
        assert!((a - b).amax() <= KERNEL_REL_TOL * scale, "{what}: {a} vs {b}");
    }

    #[test]
    fn structured_kernels_match_dense_formulas() {
        let mut st = 7u64;
        for _ in 0..20 {
            let p = random_symmetric(&mut st);
            let (f02, f12) = (lcg(&mut st), lcg(&mut st));
            let fxs = Matrix3::from_fn(|_, _| lcg(&mut st));
            let diag = [1.0, 1.0, 1.0, 0.9, 0.8, 0.8, 0.99, 0.99, 0.99, 0.95, 0.0, 1.0];
            let fxw = M3x2::from_fn(|_, _| lcg(&mut st));
            let mut f = MZ::<NZ>::zeros();
            for i in 0..NZ {
                f[(i, i)] = diag[i];
            }
            f[(0, 2)] = f02;
            f[(1, 2)] = f12;
            f[(0, IB)] = -f02;
            f[(1, IB)] = -f12;
            f.fixed_view_mut::<3, 3>(0, 3).copy_from(&fxs);
            f.fixed_view_mut::<3, 2>(0, IW).copy_from(&fxw);
            let dense = f * p * f.transpose();
            let t = Transition { f02, f12, fxs: &fxs, fxw: &fxw, diag: &diag };
            let fast = propagate(&p, &t);
            assert_close(&fast, &dense, "propagate");
            assert_eq!(fast, fast.transpose(), "propagate is not exactly symmetric");
            assert_close(&propagate_general(&p, &t), &dense, "propagate_general");
            let c = MZx3::<NZ>::from_fn(|_, _| lcg(&mut st));
            let fc = propagate_cols(&c, &t);
            let want = f * c;
            for (r, (a, b)) in fc.iter().zip(want.iter()).enumerate() {
                assert!((a - b).abs() <= 1e-12 * b.abs().max(1.0), "propagate_cols entry {r}: {a} vs {b}");
            }
            // A non-symmetric A through the general kernels.
            let x = MZ::<NZ>::from_fn(|_, _| lcg(&mut st));
            assert_close(&propagate_general(&x, &t), &(f * x * f.transpose()), "general, asym");

            let k = MZx3::<NZ>::from_fn(|_, _| lcg(&mut st));
            let ikh = MZ::<NZ>::identity() - k * h();
            let dense = ikh * p * ikh.transpose();
            let fast = joseph(&p, &k);
            assert_close(&fast, &dense, "joseph");
            assert_eq!(fast, fast.transpose(), "joseph is not exactly symmetric");
            assert_close(&joseph_general(&x, &k), &(ikh * x * ikh.transpose()), "joseph_general, asym");

            let dm = Matrix3::from_fn(|_, _| lcg(&mut st));
            let dm = dm + dm.transpose();
            let mut acc = p;
            add_kdk(&mut acc, &k, &dm);
            assert_close(&acc, &(p + k * dm * k.transpose()), "add_kdk");
            assert_eq!(acc, acc.transpose(), "add_kdk is not exactly symmetric");

            // The fused Joseph form + K D Kᵀ the filter runs: the same to the
            // bit as the two steps (stop 14; a reordering would break this).
            let mut fused = p;
            joseph_in_place(&mut fused, &k, Some(&dm));
            let mut two = joseph(&p, &k);
            add_kdk(&mut two, &k, &dm);
            assert_eq!(fused, two, "joseph_in_place with K D Kᵀ is not bitwise joseph then add_kdk");
            // The column-wise propagation: the same to the bit as the
            // row-wise formulation it replaced.
            assert_eq!(propagate(&p, &t), propagate_rowwise(&p, &t), "propagate is not bitwise the row-wise one");
        }
    }

    /// The row-wise `F P Fᵀ` of stop 13 (through [`Transition::top`]), the
    /// bitwise reference of [`propagate`].
    fn propagate_rowwise<const S: usize>(p: &MZ<S>, t: &Transition<'_, S>) -> MZ<S> {
        let mut w = MZx3::<S>::zeros();
        for r in 0..S {
            let row = t.top(|k| p[(r, k)]);
            for (c, v) in row.into_iter().enumerate() {
                w[(r, c)] = v;
            }
        }
        let mut out = MZ::<S>::zeros();
        for c in 0..3 {
            let col = t.top(|k| w[(k, c)]);
            for i in c..3 {
                out[(i, c)] = col[i];
            }
        }
        for i in 3..S {
            for c in 0..3 {
                out[(i, c)] = t.diag[i] * w[(i, c)];
            }
            for c in 3..=i {
                out[(i, c)] = t.diag[c] * (t.diag[i] * p[(i, c)]);
            }
        }
        mirror_lower(&mut out);
        out
    }

    /// The value-only reference terms are the values of the differentiated
    /// ones, to the bit (the same operations on the value).
    #[test]
    // Compared exactly on purpose.
    #[allow(clippy::float_cmp)]
    fn value_only_reference_terms_equal_the_differentiated_values() {
        let th = Theta::SIM_DEFAULT_TRUE;
        let u = Input { n_rl: 5.1, n_rr: 5.4, beta: 0.01, a_y: 1.3 };
        let a = reference_terms::<4>(0.7, &u, &th, 0.025).values();
        let b = reference_terms::<0>(0.7, &u, &th, 0.025).values();
        assert_eq!((a.f02, a.f12, a.fn_l, a.fn_r, a.f_a), (b.f02, b.f12, b.fn_l, b.fn_r, b.f_a));
    }
}
