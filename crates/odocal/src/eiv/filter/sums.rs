//! What one window contributes: the objective, its derivatives and the
//! information matrices ([`WindowSums`]), the block θ-scores of the block
//! sandwich ([`BlockScores`]) and, for the derivative tests, every
//! innovation ([`InnovationRecord`]).

use nalgebra::{Matrix3, SMatrix, Vector3};

use super::{MEta, MP, NETA, NP, VP};
use crate::model::Theta;

/// Everything one window contributes to the objective and its derivatives.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct WindowSums {
    /// Σ νᵀS⁻¹ν.
    pub quad: f64,
    /// Σ log det S.
    pub logdet: f64,
    /// −Σ m log(1 − ŝ) (the coloured-noise correction).
    pub correction: f64,
    /// The part of `correction` that the marginal likelihood M leaves out
    /// (`Variances::coloured_jacobian_in_marginal` off; 0 otherwise).
    pub correction_profile_only: f64,
    /// Gradient of `M = ½ quad + ½ logdet + correction` over p.
    pub grad: VP,
    /// Gradient of the profile cost `J = ½ quad + correction` over p.
    pub grad_profile: VP,
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
    pub i_eta: MEta,
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
    /// under the null of [`Variances::null_without_floors`](super::Variances::null_without_floors)
    /// (zero unless it is on).
    pub lag1_null: [f64; 3],
    /// Per component: Σ E₀\[e_k²\] under the same null.
    pub e2_null: [f64; 3],
    /// Σ E₀[νᵀS⁻¹ν] = Σ tr(S⁻¹S₀) under the same null (S₀ the innovation
    /// covariance without the floors, with the filter's gain).
    pub quad_null: f64,
    /// Expected gradient of the profile cost caused by the input noise,
    /// `Σ_k −tr(S_k⁻¹ H X_k,i Hᵀ)` (the corrected-score term,
    /// [`add_corrected_bias`](super::update::add_corrected_bias)).
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

    pub(super) fn add(&mut self, o: &BlockScores) {
        self.sum += o.sum;
        self.outer += o.outer;
        self.cross += o.cross;
        self.n += o.n;
        self.pairs += o.pairs;
        self.pair_sum += o.pair_sum;
    }

    /// Closes a block with score sum `g` (`prev`: the window's previous block).
    pub(super) fn push(&mut self, g: &nalgebra::Vector4<f64>, prev: Option<&nalgebra::Vector4<f64>>) {
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
            correction_profile_only: 0.0,
            grad: VP::zeros(),
            grad_profile: VP::zeros(),
            opg: nalgebra::Matrix4::zeros(),
            blocks: BlockScores::zero(),
            h_theta: nalgebra::Matrix4::zeros(),
            i_eta: MEta::zeros(),
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

    /// Takes the values that are not derivatives (the objective's terms,
    /// the whiteness sums, the input log-Jacobian's weights) from `o`, an
    /// evaluation at another point; the derivatives and information stay.
    pub(crate) fn take_values(&mut self, o: &WindowSums) {
        self.quad = o.quad;
        self.logdet = o.logdet;
        self.correction = o.correction;
        self.correction_profile_only = o.correction_profile_only;
        self.updates = o.updates;
        self.jacobian = o.jacobian;
        self.jacobian_weight = o.jacobian_weight;
        self.turning = o.turning;
        self.lag1 = o.lag1;
        self.e2 = o.e2;
    }

    pub(crate) fn add(&mut self, o: &WindowSums) {
        self.quad += o.quad;
        self.logdet += o.logdet;
        self.correction += o.correction;
        self.correction_profile_only += o.correction_profile_only;
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
        0.5 * (self.quad + self.logdet) + self.correction - self.correction_profile_only
    }

    /// The profile cost `J = ½ Σ νᵀS⁻¹ν − Σ m log(1 − ŝ)` (docs/method.md §9), plus
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
    /// ∂ν/∂p (3×10).
    pub dnu: SMatrix<f64, 3, NP>,
    /// ∂S/∂p_j (zero where not propagated).
    pub ds: [Matrix3<f64>; NP],
    /// Whitened innovation `r = L⁻¹ν` (S = LLᵀ).
    pub r: Vector3<f64>,
    /// ∂r/∂θ (3×4; zero with the covariance held).
    pub dr: SMatrix<f64, 3, 4>,
}
