//! The options of the EIV calibration and the covariance it reports.

use super::{BootstrapInputs, BootstrapRefit};

use serde::{Deserialize, Serialize};

use super::{
    BiasCorrection, HeadingScale, InnovationNull, InputJacobian, LateralNoise, NoiseModel, NoiseSource,
    QuantisationLevel, QuantisationModel, SideslipNoise, WheelNoiseScale, BASE_POSITION_FLOOR_M,
    BIAS_BOOTSTRAP_SMOOTHING_SAMPLES, DEFAULT_POSITION_FLOOR_M, NOISE_SOURCES,
};
use crate::error::{Error, Result};
use crate::model::param::ParamSet;
use crate::model::Theta;

research_pub! {
    /// How the filter's covariance recursion (P, S, K) depends on θ.
    ///
    /// The base formulation (docs/method.md, Notes) asks for both the profile cost `½ Σ νᵀS(θ)⁻¹ν` with S depending
    /// on θ through `F_n Σ_n F_nᵀ` and for Q held at a reference θ; the two
    /// differ exactly in whether `∂S/∂θ` is zero. See the module docs for the
    /// measured consequences.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
    #[serde(rename_all = "snake_case")]
    enum CovarianceMode {
        /// The covariance recursion is linearised at a reference θ (batch G-N's
        /// result, then each pass's result): `∂S/∂θ = 0` and θ solves the
        /// corrected score of the module docs.
        HeldAtReference,
        /// The covariance recursion is evaluated at θ: S depends on θ, `∂P/∂θ`
        /// is propagated exactly, and θ minimises the profile (joint-MAP over
        /// the latent true inputs; Deming / total least squares) cost.
        FollowsTheta,
    }
}

research_pub! {
    /// What estimating the noise scales η from the same drive adds to θ's
    /// reported covariance ([`ResearchOptions::noise_estimate_term`]): `A Σ_η
    /// Aᵀ` with `A = ∂θ̂/∂η = −J⁻¹ ∂g_θ/∂η` (implicit function theorem at the
    /// estimate; `g_θ` the θ-score, `J = ∂g_θ/∂θ`) and `Σ_η` the inverse of
    /// η's information over the estimated scales. `A` is
    /// [`EivReport::theta_eta_sensitivity`](crate::eiv::EivReport::theta_eta_sensitivity),
    /// the added σ [`EivReport::sigma_noise_estimate`](crate::eiv::EivReport::sigma_noise_estimate).
    /// No effect with [`EivOptions::fix_noise`](crate::eiv::EivOptions::fix_noise).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
    #[serde(rename_all = "snake_case")]
    enum NoiseEstimateTerm {
        /// No term: θ's covariance at the fitted η. The default.
        Omitted,
        /// Observed derivatives: forward differences (1 % of σ) in θ of exact
        /// filter derivatives: J's columns of t_r and d of the θ-score
        /// (those of c_e and c_d are the scoring metric `H_θ`'s), `∂g_θ/∂η`
        /// of the η-gradient of the profile cost (the mixed partials are
        /// symmetric; the FilterShare log-Jacobian weights' own
        /// η-dependence is summed exactly by the filter): one more filter
        /// pass per free parameter, with the η derivatives, and for t_r and
        /// d the θ derivatives too, instead of a second-order sensitivity
        /// recursion through the filter. With the smoothed-share weights or
        /// the covariance held, `∂g_θ/∂η` comes from one more pass per
        /// estimated scale, displaced by 1e-4 in η (`ETA_SENSITIVITY_STEP`
        /// of the module `eiv::covariance`), and only t_r and d are
        /// displaced in θ. On the `high` preset t_r moves by ≈ 7–15 % per
        /// unit of the heading white-noise scale η_5, whose own σ there is
        /// 0.04–0.12, so the σ at a fixed η understates t_r's by up to
        /// 1.8×. Its four passes cost about a sixth of the default
        /// method's instructions (crates/odocal-lab/PERFORMANCE.md).
        Observed,
    }
}

research_pub! {
    /// The covariance of θ reported by [`estimate`](fn@crate::eiv::estimate) ([`EivReport::covariance`](crate::eiv::EivReport::covariance),
    /// [`EivReport::sigma`](crate::eiv::EivReport::sigma)) and used by the halves check.
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
    #[serde(rename_all = "snake_case")]
    enum CovarianceEstimate {
        /// `H_θ⁻¹`, the inverse of the scoring metric at the fitted noise model:
        /// right when the noise model is (the fitted scales of the right
        /// processes). On the `coloured` preset, η estimated from the
        /// production-car model (whose common-mode wheel noise has τ_c = 2 s
        /// against the simulator's 5 s), c_e's σ is 0.0062 % against an actual
        /// spread of 0.023 % (coverage 35 %), so the halves check rejects 7 of
        /// 20 good fits. Where the model is right the two agree (the
        /// simulator's noise model given: mean σ 0.0194 % against the block
        /// sandwich's 0.0197 %).
        Model,
        /// The default.
        /// Per parameter the larger of the `H_θ⁻¹` σ and the block sandwich σ
        /// ([`EivReport::sigma_block`](crate::eiv::EivReport::sigma_block)): `C = D H_θ⁻¹ D` with
        /// `D = diag(max(1, σ_block,i/σ_i))`, so the correlations are the
        /// model's. The block sandwich sums the per-update θ-scores over 20 s
        /// blocks (several correlation times of the wheel noise) and so stays
        /// honest when the noise model's time constants are wrong; the larger
        /// of the two keeps the model's σ where the blocks are few (a short
        /// drive) and their estimate noisy. Measured against [`CovarianceEstimate::Model`]
        /// (12 km, seeds 1–20): `coloured` c_e coverage 35 → 90 %, halves
        /// fallbacks 7 → 0, what a user gets c_e 2.82× → 1.62× the Cramér–Rao
        /// bound; `white` identical; on `paper` the halves check does not
        /// reject two fits with t_r +4.7 and +3.9 % that it rejects with the
        /// model's σ (it measures spread, not bias).
        #[default]
        LargerOfModelAndBlock,
    }
}

/// Default of [`ResearchOptions::heading_drift_min_eta`]: `−ln 9`, the
/// heading drift's σ at least a third of the starting model's.
const HEADING_DRIFT_MIN_ETA: f64 = -2.197_224_577_336_219_6;

/// Options of the EIV calibration. Defaults as docs/method.md §9 states them.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EivOptions {
    /// Filter window length, samples (each part is cut into windows of about
    /// this length). Default 6000 (150 s at 40 Hz).
    pub window_samples: usize,
    /// Fisher-scoring iterations per pass. Default 20 (a test-track run
    /// converges in 12; the simulated studies converge in ≤ 10).
    pub max_iterations: usize,
    /// Stop when `max |step_i|/σ_i` (free θ and η not at a clamp) is below
    /// this, tested on the step taken and on the step that remains at the
    /// new point (so the last iteration can end converged). Default 0.05.
    pub step_tolerance: f64,
    /// Step halvings tried before giving up on an iteration. Default 10.
    pub max_halvings: usize,
    /// Which parameters are estimated (`[c_e, c_d, t_r, d]`). Default all.
    pub free: [bool; 4],
    /// Hold parameters that the data cannot determine (σ above their
    /// resolution at the start) at their starting value and name them.
    /// Default true.
    pub fix_unobservable: bool,
    /// The starting noise model. Default a production car's
    /// (`NoiseModel::default()`).
    pub noise: NoiseModel,
    /// Use [`EivOptions::noise`] as is (do not estimate η). Default false.
    pub fix_noise: bool,
    /// Clamp range of the log-scale factors η. Default [−20, 6]: variances
    /// between 2e-9 and 400 times the starting model's. A scale that reached
    /// its lower clamp stays there (its information there is ~1e-17 of its
    /// start); `calibrate` refits a fit that fails its checks with a scale
    /// there with the lower clamp at −8, where a source can return.
    pub eta_bounds: [f64; 2],
    /// Noise sources (in `NOISE_SOURCES` order) whose level is *known*:
    /// their scale is held at the starting model (η_j = 0) while the others
    /// are estimated; ignored with [`EivOptions::fix_noise`]. Set it from a
    /// datasheet (e.g. the INS's heading σ) with `EivOptions::hold_known`,
    /// `--known-noise`, or a noise model's `known = [...]`. Measured
    /// (docs/validation.md, "Known noise levels"; 20 × 12 km, `high`):
    /// holding the heading white noise at its true σ took t_r's bias from
    /// +1.10 % to +0.52 %. A wrong stated level biases instead. Default none.
    pub eta_held: [bool; 6],
    /// Parameter resolutions `[c_e, c_d, t_r, d]`, SI units: a parameter
    /// whose standard deviation exceeds its resolution is not observable.
    /// Default `[0.01, 0.001, 0.015, 0.0005]` (as batch G-N).
    pub resolution: [f64; 4],
    /// Parameters in an eigenvector of the equilibrated `H_θ` with eigenvalue
    /// below this fraction of the largest are named collinear. Default 1e-2.
    pub min_rcond: f64,
    /// Acceptable band of the per-window NIS per degree of freedom. Default [0.5, 2].
    pub nis_band: [f64; 2],
    /// A window whose NIS per degree of freedom exceeds this has diverged. Default 10.
    pub divergence_nis: f64,
    /// Largest acceptable |lag-1 autocorrelation| of whitened innovations per
    /// window, beyond the interval that the innovation checks' null allows
    /// (the measurement floors taken as regularisation: the lag-1 and NIS a
    /// window would have without them). Default 0.5.
    pub max_lag1: f64,
    /// Largest acceptable lag-1 autocorrelation *below* the interval that
    /// the innovation checks' null allows (`min(0, ρ₀) − lag-1`). Default
    /// 0.2. Negative correlation is what a filter shows when the data have
    /// measurement noise the model lacks (it follows the noise and corrects
    /// back); the floors and surplus process noise only lag the filter
    /// behind the measurements (positive correlation). Measured: heading
    /// lag-1 of good fits on the simulated presets ≥ −0.15; on the six
    /// test-track runs (heading white noise held near zero by the tied
    /// scale) −0.26 … −0.45, where EIV loses to batch G-N.
    pub max_lag1_below: f64,
    /// Largest acceptable |z| of the difference between θ from the two
    /// halves of the windows. Default 4.
    pub max_half_z: f64,
    /// How encoder quantisation enters the filter. Default
    /// [`QuantisationModel::Counting`] (see its docs for the measured
    /// trade-off).
    pub quantisation: QuantisationModel,
    /// Whether η_0 scales the encoder quantisation with the white wheel
    /// noise or the quantisation step is taken as known. Default
    /// [`QuantisationLevel::FromReadings`] (see its docs).
    pub quantisation_level: QuantisationLevel,
    /// Whether η_0 scales the a_y and β noise with the white wheel noise or
    /// they are held at the noise model's σ. Default
    /// [`LateralNoise::TiedToWheelWhite`] (see its docs for the measured
    /// trade-off).
    pub lateral_noise: LateralNoise,
    /// Whether the reference's heading white noise has its own scale η_5.
    /// Default [`HeadingScale::Separate`] (see its docs).
    pub heading_scale: HeadingScale,
    /// Where the heading readings' own white noise is read
    /// (`EivReport::heading_noise_floor`),
    /// the reference heading's white noise is that and nothing more: the
    /// starting model's heading white noise is dropped and its scale η_5
    /// held, so no fitted level above the readings' can take up the
    /// wheels' unmodelled error (the errors-in-variables balance tipped
    /// toward the reference leaves t_r too large; docs/validation.md, "The
    /// heading's white noise: the readings' own first"). No effect where
    /// no floor is read (the noise held, the heading's level known, or
    /// readings too smooth to show one). `calibrate`'s EIV method fits at
    /// the readings' level first ([`EivMethodOptions::heading_white_readings_first`](crate::calibrate::EivMethodOptions::heading_white_readings_first)).
    /// Default false.
    pub heading_white_at_floor: bool,
    /// The estimator's modelling alternatives; public with the cargo
    /// feature `research` (the studies of crates/odocal-lab), otherwise
    /// always their defaults (`EivOptions::spec` aside).
    #[serde(flatten)]
    #[cfg_attr(not(feature = "research"), doc(hidden))]
    pub research: ResearchOptions,
}

/// Declares [`ResearchOptions`] with its fields at visibility `$vis`:
/// public with the `research` feature, crate-private without it.
macro_rules! research_options {
    ($vis:vis) => {
        /// The estimator's modelling alternatives ([`EivOptions::research`]),
        /// with the cargo feature `research`. Each default is the formulation
        /// the product uses; the alternatives are what the studies compare
        /// it with, and what the bootstrap's replicate fits and
        /// [`EivOptions::spec`] (the Cramér–Rao bound's formulation) set.
        #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
        #[serde(default)]
        pub struct ResearchOptions {
            /// Correction of the profile cost's bias applied to the estimate.
            /// Default `BiasCorrection::None` (see its docs).
            $vis bias_correction: BiasCorrection,
            /// The true inputs of the replicate worlds of
            /// `BiasCorrection::Bootstrap`. Default `BootstrapInputs::Measured`;
            /// `EivOptions::correct_bias` sets `Smoothed { half_width_samples: 20 }`,
            /// which removes the t_r bias on `high` (docs/validation.md, "Simulated
            /// drives against the Cramér–Rao bound").
            $vis bootstrap_inputs: BootstrapInputs,
            /// The replicates of `BiasCorrection::Bootstrap` come in antithetic
            /// pairs (`BootstrapOptions::antithetic`; B must be even). Default
            /// false; `EivOptions::correct_bias` sets it.
            $vis bootstrap_antithetic: bool,
            /// Values at which parameters that the filter names unobservable (with
            /// [`EivOptions::fix_unobservable`]) are held. `None` (the default)
            /// holds them at the start θ given to `estimate`. `calibrate` passes
            /// the calibration's θ_0: the start is batch G-N's estimate, which for
            /// a parameter the data cannot determine can be far off (on the RAV4
            /// drive, t_r = 5.63 m, so the result was rejected as implausible).
            $vis hold_unobservable_at: Option<Theta>,
            /// How the covariance recursion depends on θ. Default
            /// [`CovarianceMode::FollowsTheta`].
            $vis covariance: CovarianceMode,
            /// Passes with [`CovarianceMode::HeldAtReference`], each with the
            /// covariance reference θ at the previous result (one pass when
            /// the covariance follows θ). Default 2.
            $vis passes: usize,
            /// Which covariance of θ the report carries (`covariance`,
            /// `sigma`) and the halves check uses. Default
            /// [`CovarianceEstimate::LargerOfModelAndBlock`] (see both for the
            /// measurements).
            $vis covariance_estimate: CovarianceEstimate,
            /// Damp the η step of the θ/η iteration by a secant estimate of
            /// its overshoot (with the covariance following θ and η
            /// estimated; see `secant_eta_factor` in the source for the
            /// measurements). Default true.
            $vis eta_secant_damping: bool,
            /// Near the estimate, step θ and η together from one evaluation
            /// with all derivatives instead of one after the other (with the
            /// covariance following θ and η estimated; see
            /// `SIMULTANEOUS_BELOW` in the source for the rule and the
            /// measurements). Default true.
            $vis simultaneous_steps: bool,
            /// After a kept simultaneous step, take the last step without
            /// evaluating the derivatives after it where the step shrinking
            /// as it did predicts a remainder below the tolerance (see
            /// `Pass::final_step` in the source for the rule and the
            /// measurements); the heading-drift test's η profiles end the
            /// same way (`PROFILE_LAST`). Default true.
            $vis final_step: bool,
            /// On a drive of at least twice 12 windows, fit every `k`-th
            /// window first and start the fit over all windows from that
            /// estimate (with the covariance following θ and η estimated;
            /// see `first_pass` in the source for the rule and the
            /// measurements). The estimate is the same within the step
            /// tolerance. Default true.
            $vis coarse_start: bool,
            /// What the innovation checks (NIS band, whiteness) take as
            /// consistent. Default [`InnovationNull::FloorsAsRegularisation`]
            /// (see its docs for the measurements); the bootstrap's replicate
            /// fits, whose warnings are not read, use
            /// [`InnovationNull::FittedModel`] (no extra filter pass).
            $vis innovation_null: InnovationNull,
            /// What estimating the noise scales η from the same drive adds to
            /// θ's reported covariance ([`NoiseEstimateTerm`]). Default
            /// [`NoiseEstimateTerm::Omitted`]: the term takes four more filter
            /// passes, about a sixth of the default method's instructions, and
            /// the σ for the next drive, which stands for a result, does not
            /// need it (docs/validation.md, "EIV's σ at the fitted noise
            /// scales").
            $vis noise_estimate_term: NoiseEstimateTerm,
            /// How the filter models the error of the measured sideslip β.
            /// Default [`SideslipNoise::GaussMarkovState`] (see its docs).
            $vis sideslip_noise: SideslipNoise,
            /// Which wheel rotation scales the relative wheel noise in the
            /// covariance. Default
            /// [`WheelNoiseScale::SmoothedFittedInput`] with ±20 samples (see
            /// its docs for the measured alternatives).
            $vis wheel_noise_scale: WheelNoiseScale,
            /// Log-Jacobian term of the relative white wheel noise added to
            /// the θ cost. Default [`InputJacobian::FilterShare`] (see its
            /// docs).
            $vis input_jacobian: InputJacobian,
            /// Floor of the reference's position noise σ in the filter's
            /// `R`, m (added in quadrature to the noise model's position
            /// white noise; it is not scaled by η). Default
            /// [`DEFAULT_POSITION_FLOOR_M`], 5 mm (the base formulation: 1 mm).
            ///
            /// Measured (12 km, seeds 1–20, the simulator's noise model
            /// fixed): on a perfect reference with 2 % white wheel noise the
            /// 1 mm floor leaves t_r +2.90 ± 1.56 % (bias t 8.3) and d −0.58
            /// (t 8.2); with 5 mm, t_r +0.23 ± 0.61 % (t 1.7) and d −0.04 (t
            /// 1.0), as the filter-free heading-channel Deming estimator on
            /// the same drives (+0.22 ± 0.58 %). The wheel noise is rank 2 in
            /// the 3-dof pose, so on a near-perfect position reference one
            /// direction of the innovation is known to the floor and the
            /// filter carries it from step to step (windows of 10 samples
            /// remove the bias too). On the `coloured` preset 5 mm also
            /// lowers the c_e bias (+0.098 → +0.047 %); where the reference
            /// has centimetres of position noise (`paper`, `high`) the floor
            /// changes nothing. `eiv_white_bias` in crates/odocal-lab
            /// measures it.
            $vis position_floor_m: f64,
            /// Test the tie of the heading drift to the pose-drift scale η_4
            /// after the fit, and fit the heading drift on a scale of its own
            /// where the test rejects the tie
            /// ([`HeadingDriftTest`](crate::eiv::HeadingDriftTest)). Default true.
            $vis heading_drift_test: bool,
            /// The score statistic from which the separate heading-drift
            /// scale is fitted. Default 3.84 (the χ²₁ quantile at 5 %).
            $vis heading_drift_score_gate: f64,
            /// The likelihood ratio above which the separate heading-drift
            /// scale is the result. Default 10.83 (the χ²₁ quantile at 0.1 %).
            $vis heading_drift_lr_threshold: f64,
            /// Release the heading drift in both directions; by default only
            /// towards a heading drift smaller than the tie grants (see
            /// [`HeadingDriftTest`](crate::eiv::HeadingDriftTest) for why).
            /// Default false.
            $vis heading_drift_two_sided: bool,
            /// Whether the objective M (the η step; θ's too with the
            /// covariance held) keeps the Gauss-Markov wheel states'
            /// log-Jacobian `−Σ m log(1 − ŝ)` (the profile cost J keeps it
            /// either way). Without it the noise scales are fitted on the
            /// filter's Gaussian likelihood `½ Σ(νᵀS⁻¹ν + log det S)` alone.
            /// Measured on heavy common-mode wheel noise (crates/odocal-lab/STUDIES.md,
            /// "Heavy wheel noise: what puts the common-mode scale at its
            /// clamp"): fewer fallbacks, no better t_r. Default true.
            $vis coloured_jacobian_in_marginal: bool,
            /// Whether the common-mode wheel state's log-Jacobian
            /// `−Σ m log(1 − ŝ_c)` is in the θ cost J and in M at all (the
            /// per-wheel states' stays). Measured on heavy common-mode wheel
            /// noise (the same section): t_r biased by several per cent
            /// without it. Default true.
            $vis common_mode_jacobian: bool,
            /// The pose-drift scale η_4 scales the reference's position
            /// drift only; the heading drift is scaled with the heading white
            /// noise (η_5; η_3 with [`HeadingScale::TiedToPosition`]), whose
            /// sensor it comes from. Tied to the position drift (false), a
            /// large position drift can only be granted with a heading drift
            /// the heading data refuse. Default false.
            $vis position_drift_own_scale: bool,
            /// The lowest scale of the heading drift's variance under the tie
            /// to the pose-drift scale η_4: the heading drift is
            /// `σ_ψd² · e^{max(η_4, m)}` (σ_ψd the starting model's), the
            /// position drift follows η_4 all the way. A reference whose
            /// position drifts by centimetres (RTK-grade) says little about
            /// its heading, which comes from the INS; tied all the way, η_4
            /// fitted to such a position (−5) took the heading drift to a
            /// tenth of the simulated one and t_r +2.55 % (t 10.6) on 20
            /// drives of the `paper` preset with the position noise at a
            /// tenth; with this floor +1.13 % (docs/validation.md, "An
            /// RTK-grade position reference"). The floor lies below the η_4
            /// of every shipped real drive (−1.3 … −0.5), which keep their
            /// results; a floor at the start (0) moved them. Default
            /// `−ln 9` (−2.20: a third of the starting σ, 1 mrad for the
            /// production car's 3); `eta_bounds[0]` or lower is the tie all
            /// the way. A heading that drifts less is still
            /// granted less by the heading-drift test
            /// ([`ResearchOptions::heading_drift_test`]). No effect with
            /// [`ResearchOptions::position_drift_own_scale`].
            $vis heading_drift_min_eta: f64,
            /// Correlation time of the reference's position drift, s, where
            /// it differs from the heading drift's
            /// ([`NoiseModel::drift_time_constant_s`], which the heading
            /// drift keeps). Default `None` (both the model's). The bias
            /// correction's replicate drives simulate the position drift
            /// with the model's time constant.
            $vis position_drift_time_constant_s: Option<f64>,
            /// a_y's white noise σ held at this value, m/s², while β's
            /// stays as [`EivOptions::lateral_noise`] says (tied to the
            /// white wheel noise by default). Default `None`: a_y as β.
            $vis a_y_sigma_held: Option<f64>,
            /// With a_y's noise tied to the white wheel noise
            /// ([`LateralNoise::TiedToWheelWhite`]), a_y's σ is never below
            /// the white noise of the drive's own a_y readings (their
            /// sample noise, `EivReport::a_y_noise_floor`): a fit whose
            /// wheels are clean would otherwise take a noisy a_y as exact,
            /// and d, which multiplies a_y, toward 0. Default true
            /// (docs/validation.md, "a_y's noise floor").
            $vis a_y_floor_from_readings: bool,
            /// The floor of a_y's σ, m/s², where it is given rather than
            /// read off the readings (the bias correction's replicates hold
            /// the drive's). Default `None`: read off the readings when
            /// [`ResearchOptions::a_y_floor_from_readings`].
            $vis a_y_sigma_floor: Option<f64>,
            /// Where the reference heading's white noise is estimated, its
            /// variance is the white noise of the drive's own heading
            /// readings (their sample noise, `EivReport::heading_noise_floor`)
            /// plus what the scale η_5 (η_3 when tied) fits: a fit would
            /// otherwise take the heading as exact where the wheels' noise
            /// explains its scatter, which leans d and t_r (docs/validation.md,
            /// "The heading's noise floor"). Default true.
            $vis heading_floor_from_readings: bool,
            /// The reference heading's white noise from the readings, rad,
            /// where it is given rather than read off them (a bootstrap's
            /// replicates hold the drive's). Default `None`: read off the
            /// readings when [`ResearchOptions::heading_floor_from_readings`].
            $vis heading_white_sigma_floor: Option<f64>,
            /// Set by the fit where [`EivOptions::heading_white_at_floor`]
            /// took effect: the starting model's heading white noise it
            /// dropped, rad (the scale is then held at the readings' level,
            /// not by the user, whose held level has no floor). Not an
            /// input.
            #[serde(skip)]
            $vis heading_white_held_at_floor: Option<f64>,
            /// After a fit that fails its checks with a noise scale at its
            /// upper clamp (the runaway of heavy common-mode wheel noise and
            /// slip: the common-mode scale at its clamp, c_e several per cent
            /// low), `calibrate`'s EIV method fits once more from the same
            /// start with c_e held at the start's value (batch Gauss-Newton's
            /// c_e, which that noise leaves nearly unbiased), the filter
            /// estimating the other parameters and the noise; the refit is the
            /// result when it passes the checks and its t_r is not above the
            /// start's (batch G-N's errors-in-variables bias on t_r points
            /// up, so a refit above it corrects nothing). Its covariance carries the
            /// start's σ of c_e, and each other parameter's share of it along
            /// its regression on c_e in the first fit's covariance. Default
            /// true (docs/validation.md, "Heavy wheel noise: a refit with
            /// c_e held").
            $vis clamp_refit_hold_scale: bool,
            /// Where the fit leaves a noise source at its lower clamp, fit
            /// the drive once more with the wheel noise's correlation times
            /// slow (the starting model's common-mode τ_c × 10, per-wheel
            /// τ_w × 20: 20 s and 5 s from the production car's defaults)
            /// and keep the fit with the lower M (`EivReport::time_constant_costs`).
            /// Default false: on the second simulator's `paper` drives,
            /// whose wheel noise has those correlation times, it cuts t_r's
            /// RMS error by a third (0.62 → 0.43 % on the 20 drives it was
            /// designed on, 0.62 → 0.52 % on 20 others), but on its `heavy`
            /// drives and on odocal's random noise worlds M prefers the slow
            /// model where it is wrong (random worlds 1–100: c_e RMS 0.048 →
            /// 0.159 %, t_r 0.57 → 0.72 %); docs/validation.md, "The wheel
            /// noise's correlation times". No effect with
            /// [`EivOptions::fix_noise`].
            $vis choose_time_constants: bool,
            /// In the refit after a noise scale at its upper clamp (as
            /// [`ResearchOptions::clamp_refit_hold_scale`]), hold the
            /// common-mode wheel noise scale η_1 at this value (its variance
            /// e^η times the starting model's) instead of estimating it.
            /// The refit runs when this or `clamp_refit_hold_scale` is set.
            /// Default `None`.
            $vis clamp_refit_common_mode_eta: Option<f64>,
            /// Propagate the covariance derivative `∂P/∂c_d` in the filter's
            /// passes. c_d enters the covariance recursion only through the
            /// wheels' circumferences `c_e ± c_d/2`, a relative change of
            /// about 1e-3, so the terms through `∂S/∂c_d` in c_d's score and
            /// metric are negligible beside its mean part (the heading rate,
            /// of first order). Default false: the passes leave the column
            /// out (one of their 4–10 covariance derivatives), which moved
            /// θ by at most 0.002 σ and σ by at most 0.03 %
            /// (crates/odocal-lab/PERFORMANCE.md). The Cramér–Rao bound propagates it.
            $vis c_d_covariance_derivative: bool,
            /// How the bias correction ([`EivOptions::correct_bias`]) re-fits
            /// its replicates. Default [`BootstrapRefit::OneStep`]: one
            /// scoring step from θ̂, a single filter pass per replicate;
            /// [`BootstrapRefit::Converged`] fits each to convergence.
            $vis bias_correction_refit: BootstrapRefit,
        }
    };
}

#[cfg(feature = "research")]
research_options!(pub);
#[cfg(not(feature = "research"))]
research_options!(pub(crate));

impl Default for ResearchOptions {
    fn default() -> Self {
        ResearchOptions {
            bias_correction: BiasCorrection::None,
            bootstrap_inputs: BootstrapInputs::Measured,
            bootstrap_antithetic: false,
            hold_unobservable_at: None,
            covariance: CovarianceMode::FollowsTheta,
            passes: 2,
            covariance_estimate: CovarianceEstimate::LargerOfModelAndBlock,
            eta_secant_damping: true,
            simultaneous_steps: true,
            final_step: true,
            coarse_start: true,
            innovation_null: InnovationNull::FloorsAsRegularisation,
            noise_estimate_term: NoiseEstimateTerm::Omitted,
            sideslip_noise: SideslipNoise::GaussMarkovState,
            wheel_noise_scale: WheelNoiseScale::SmoothedFittedInput { half_width_samples: 20 },
            input_jacobian: InputJacobian::FilterShare,
            position_floor_m: DEFAULT_POSITION_FLOOR_M,
            heading_drift_test: true,
            heading_drift_score_gate: super::HEADING_DRIFT_SCORE_GATE,
            heading_drift_lr_threshold: super::HEADING_DRIFT_LR_THRESHOLD,
            heading_drift_two_sided: false,
            coloured_jacobian_in_marginal: true,
            common_mode_jacobian: true,
            position_drift_own_scale: false,
            heading_drift_min_eta: HEADING_DRIFT_MIN_ETA,
            position_drift_time_constant_s: None,
            a_y_sigma_held: None,
            a_y_floor_from_readings: true,
            a_y_sigma_floor: None,
            heading_floor_from_readings: true,
            heading_white_sigma_floor: None,
            heading_white_held_at_floor: None,
            clamp_refit_hold_scale: true,
            choose_time_constants: false,
            clamp_refit_common_mode_eta: None,
            c_d_covariance_derivative: false,
            bias_correction_refit: BootstrapRefit::OneStep,
        }
    }
}

impl ResearchOptions {
    /// Checks the options, naming the offending field.
    fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: &str| Err(Error::InvalidOption { field, reason: reason.into() });
        if self.passes == 0 {
            return bad("passes", "must be at least 1");
        }
        if !(self.position_floor_m.is_finite() && self.position_floor_m > 0.0) {
            return bad("position_floor_m", "must be positive (it keeps S regular on a perfect reference)");
        }
        if !self.heading_drift_min_eta.is_finite() {
            return bad("heading_drift_min_eta", "must be finite (the eta lower bound or below ties all the way)");
        }
        if self.position_drift_time_constant_s.is_some_and(|t| !(t.is_finite() && t > 0.0)) {
            return bad("position_drift_time_constant_s", "must be positive");
        }
        if self.a_y_sigma_held.is_some_and(|v| !(v.is_finite() && v >= 0.0)) {
            return bad("a_y_sigma_held", "must be finite and not negative");
        }
        if self.a_y_sigma_floor.is_some_and(|v| !(v.is_finite() && v >= 0.0)) {
            return bad("a_y_sigma_floor", "must be finite and not negative");
        }
        if self.heading_white_sigma_floor.is_some_and(|v| !(v.is_finite() && v >= 0.0)) {
            return bad("heading_white_sigma_floor", "must be finite and not negative");
        }
        if self.clamp_refit_common_mode_eta.is_some_and(|e| !e.is_finite()) {
            return bad("clamp_refit_common_mode_eta", "must be finite");
        }
        if self.wheel_noise_scale == (WheelNoiseScale::SmoothedFittedInput { half_width_samples: 0 }) {
            return bad("wheel_noise_scale", "the smoothed scale needs half_width_samples >= 1");
        }
        if self.wheel_noise_scale != WheelNoiseScale::MeasuredInput && self.covariance != CovarianceMode::FollowsTheta {
            return bad("wheel_noise_scale", "the fitted input needs covariance = follows_theta");
        }
        Ok(())
    }
}

impl Default for EivOptions {
    fn default() -> Self {
        EivOptions {
            window_samples: 6000,
            eta_held: [false; 6],
            max_iterations: 20,
            step_tolerance: 0.05,
            max_halvings: 10,
            free: [true; 4],
            fix_unobservable: true,
            noise: NoiseModel::PRODUCTION_CAR,
            fix_noise: false,
            eta_bounds: [-20.0, 6.0],
            resolution: [0.01, 0.001, 0.015, 0.0005],
            min_rcond: 1e-2,
            nis_band: [0.5, 2.0],
            divergence_nis: 10.0,
            max_lag1: 0.5,
            max_lag1_below: 0.2,
            max_half_z: 4.0,
            quantisation: QuantisationModel::Counting,
            heading_scale: HeadingScale::Separate,
            heading_white_at_floor: false,
            quantisation_level: QuantisationLevel::FromReadings,
            lateral_noise: LateralNoise::TiedToWheelWhite,
            research: ResearchOptions::default(),
        }
    }
}

impl EivOptions {
    /// These options without the bias correction (`BiasCorrection::None`).
    pub(crate) fn without_bias_correction(&self) -> EivOptions {
        let mut o = self.clone();
        o.research.bias_correction = BiasCorrection::None;
        o
    }

    /// Whether the heading white noise is held as known while its scale is
    /// tied to the position white noise's, which is estimated: a
    /// contradiction (with pose_white held too, the tied scale is held with
    /// it). The noise scales' check and the settings' message share it.
    pub(crate) fn heading_known_but_tied(&self) -> bool {
        let held = |s: NoiseSource| self.eta_held[s.index()];
        let tied = self.heading_scale == HeadingScale::TiedToPosition;
        held(NoiseSource::HeadingWhite) && !held(NoiseSource::PoseWhite) && tied && !self.fix_noise
    }

    /// Holds the scales of `sources` at the starting model
    /// ([`EivOptions::eta_held`]): their levels in [`EivOptions::noise`] are
    /// known.
    pub(crate) fn hold_known(&mut self, sources: &[NoiseSource]) {
        for s in sources {
            self.eta_held[s.index()] = true;
        }
    }

    /// The sources [`EivOptions::eta_held`] holds, in η order.
    pub(crate) fn known_sources(&self) -> Vec<NoiseSource> {
        NOISE_SOURCES.into_iter().filter(|s| self.eta_held[s.index()]).collect()
    }

    /// These options with [`QuantisationLevel::FromReadings`] replaced by what
    /// it resolves to where the readings gave the step `found`: `Given` at
    /// that step, or `Given` at a step of zero (no quantisation) for `None`.
    /// Other levels are kept.
    pub(crate) fn with_resolved_quantisation(&self, found: Option<f64>) -> EivOptions {
        let mut o = self.clone();
        if o.quantisation_level == QuantisationLevel::FromReadings {
            o.quantisation_level = QuantisationLevel::Given;
            o.noise.quantisation_step_rev_per_s = found.unwrap_or(0.0);
        }
        o
    }

    /// Whether a_y's σ follows the white wheel noise's scale η_0
    /// ([`LateralNoise::TiedToWheelWhite`], a_y's σ not held): where a
    /// floor on it applies.
    pub(crate) fn a_y_tied(&self) -> bool {
        self.lateral_noise == LateralNoise::TiedToWheelWhite && self.research.a_y_sigma_held.is_none()
    }

    /// Whether a_y's σ has a floor read off the readings
    /// ([`ResearchOptions::a_y_floor_from_readings`]): a_y tied
    /// ([`EivOptions::a_y_tied`]) and not given a floor.
    pub(crate) fn reads_a_y_floor(&self) -> bool {
        self.research.a_y_floor_from_readings && self.a_y_tied() && self.research.a_y_sigma_floor.is_none()
    }

    /// Whether the reference heading's white noise is estimated, so that
    /// the readings' own white noise is part of its variance: the noise is
    /// not held ([`EivOptions::fix_noise`]), the heading's scale not known
    /// ([`EivOptions::eta_held`]), nor tied to a known position scale.
    pub(crate) fn heading_floor_applies(&self) -> bool {
        let held = |s: NoiseSource| self.eta_held[s.index()];
        let tied = self.heading_scale == HeadingScale::TiedToPosition;
        let held_with_position = tied && held(NoiseSource::PoseWhite);
        let held_by_user = held(NoiseSource::HeadingWhite) && self.research.heading_white_held_at_floor.is_none();
        !(self.fix_noise || held_by_user || held_with_position)
    }

    /// Whether the heading's white noise has the readings' as its floor:
    /// it applies ([`EivOptions::heading_floor_applies`]) and was given.
    pub(crate) fn heading_floor_given(&self) -> bool {
        self.heading_floor_applies() && self.research.heading_white_sigma_floor.is_some()
    }

    /// Whether the heading's white noise is read off its readings
    /// ([`ResearchOptions::heading_floor_from_readings`]): it applies
    /// ([`EivOptions::heading_floor_applies`]) and is not given.
    pub(crate) fn reads_heading_floor(&self) -> bool {
        self.research.heading_floor_from_readings
            && self.heading_floor_applies()
            && self.research.heading_white_sigma_floor.is_none()
    }

    /// Whether [`EivOptions::heading_white_at_floor`] takes effect on these
    /// options: the readings' floor is read (the noise not held, the
    /// heading's level not known) and the heading's white noise has its
    /// own scale. The floor is then always read (R's own where the readings
    /// show less).
    pub(crate) fn can_hold_heading_at_floor(&self) -> bool {
        self.reads_heading_floor() && self.heading_scale == HeadingScale::Separate
    }

    /// These options with the heading readings' white noise `floor` given
    /// where one was read and it applies.
    /// With [`EivOptions::heading_white_at_floor`], the floor is the
    /// whole of the heading's white noise: the starting model's level
    /// dropped and its scale held.
    pub(crate) fn with_heading_floor(mut self, floor: Option<f64>) -> EivOptions {
        if floor.is_some() && self.reads_heading_floor() {
            let hold = self.heading_white_at_floor && self.can_hold_heading_at_floor();
            self.research.heading_white_sigma_floor = floor;
            if hold {
                self.research.heading_white_held_at_floor = Some(self.noise.heading_white_sigma_rad);
                self.noise.heading_white_sigma_rad = 0.0;
                self.eta_held[NoiseSource::HeadingWhite.index()] = true;
            }
        }
        self
    }

    /// These options with the readings' findings given: the quantisation
    /// step ([`EivOptions::with_resolved_quantisation`]) and a_y's noise
    /// floor `a_y_floor` where one was read. What a fit of other data as
    /// if it were this drive holds (the bias correction's replicates, a
    /// bootstrap).
    pub(crate) fn with_resolved_readings(&self, found: Option<f64>, a_y_floor: Option<f64>) -> EivOptions {
        let mut o = self.with_resolved_quantisation(found);
        if a_y_floor.is_some() && o.reads_a_y_floor() {
            o.research.a_y_sigma_floor = a_y_floor;
        }
        o
    }

    research_pub! {
        /// Subtracts the estimator's own bias from the `parameters` of θ,
        /// estimated by a parametric bootstrap of `replicates` re-simulations (seed `seed`;
        /// an even number: antithetic pairs, [`ResearchOptions::bootstrap_antithetic`])
        /// on the smoothed trajectory (`BIAS_BOOTSTRAP_SMOOTHING_SAMPLES`),
        /// each holding the fitted noise model:
        /// what the EIV method of `calibrate` applies by default (B = 4), the
        /// CLI's `--correct-bias B` and Python's `correct_bias=B`, measured in
        /// [`BiasCorrection`]'s docs. A program asks for it with
        /// [`EivMethodOptions::correct_bias`](crate::EivMethodOptions::correct_bias).
        ///
        /// ```
        /// # #[cfg(feature = "research")] {
        /// use odocal::eiv::{BiasCorrection, EivOptions};
        /// use odocal::{Param, ParamSet};
        /// let c_e: ParamSet = [Param::CE].into_iter().collect();
        /// let mut o = EivOptions::default();
        /// o.correct_bias(10, 0, c_e);
        /// assert_eq!(o.research.bias_correction, BiasCorrection::Bootstrap { replicates: 10, seed: 0, parameters: c_e });
        /// assert!(o.research.bootstrap_antithetic);
        /// assert!(o.validate().is_ok());
        /// o.correct_bias(5, 0, c_e); // an odd B cannot be paired
        /// assert!(o.validate().is_err());
        /// o.correct_bias(4, 0, ParamSet::EXTRINSICS); // only θ's parameters are corrected
        /// assert!(o.validate().is_err());
        /// # }
        /// ```
        fn correct_bias(&mut self, replicates: usize, seed: u64, parameters: ParamSet) {
            self.research.bias_correction = BiasCorrection::Bootstrap { replicates, seed, parameters };
            self.research.bootstrap_inputs =
                BootstrapInputs::Smoothed { half_width_samples: BIAS_BOOTSTRAP_SMOOTHING_SAMPLES };
            self.research.bootstrap_antithetic = true;
        }
    }

    research_pub! {
        /// The defaults with the base formulation's cost and `R` (docs/method.md, Notes): the
        /// relative wheel noise scaled by the measured rotation, no input
        /// log-Jacobian term, the 1 mm position floor. The Cramér–Rao bound
        /// ([`cramer_rao_bound`](crate::eiv::cramer_rao_bound), the experiment's
        /// and the studies') is computed with it, so that it depends on the noise
        /// model only, not on the estimator's bias corrections.
        fn spec() -> Self {
            EivOptions {
                research: ResearchOptions {
                    wheel_noise_scale: WheelNoiseScale::MeasuredInput,
                    input_jacobian: InputJacobian::None,
                    position_floor_m: BASE_POSITION_FLOOR_M,
                    ..ResearchOptions::default()
                },
                ..EivOptions::default()
            }
        }
    }

    research_pub! {
        /// Checks the options, naming the offending field.
        fn validate(&self) -> Result<()> {
            let bad = |field: &'static str, reason: &str| Err(Error::InvalidOption { field, reason: reason.into() });
            if self.window_samples < 10 {
                return bad("window_samples", "must be at least 10");
            }
            if !self.free.iter().any(|f| *f) {
                return bad("free", "at least one parameter must be free");
            }
            if !(self.step_tolerance.is_finite() && self.step_tolerance > 0.0) {
                return bad("step_tolerance", "must be positive");
            }
            let [lo, hi] = self.eta_bounds;
            if !(lo.is_finite() && hi.is_finite() && lo <= 0.0 && hi >= 0.0) {
                return bad("eta_bounds", "must be finite with lower <= 0 <= upper");
            }
            if self.resolution.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
                return bad("resolution", "must be positive");
            }
            if !(self.min_rcond.is_finite() && (0.0..1.0).contains(&self.min_rcond)) {
                return bad("min_rcond", "must be in [0, 1)");
            }
            if !(self.nis_band[0] >= 0.0 && self.nis_band[1] > self.nis_band[0]) {
                return bad("nis_band", "must be [lower, upper] with 0 <= lower < upper");
            }
            if self.heading_known_but_tied() {
                return bad(
                    "eta_held",
                    "heading_white is known but its scale is tied to pose_white (heading noise `tied`): \
                     use the separate heading scale, or state pose_white as known",
                );
            }
            if let Some(t) = &self.research.hold_unobservable_at {
                t.validate().map_err(|e| Error::InvalidOption {
                    field: "hold_unobservable_at",
                    reason: format!("{e}; give a usable θ (or None to hold at the start)"),
                })?;
            }
            if let BiasCorrection::Bootstrap { replicates, parameters, .. } = self.research.bias_correction {
                if let Some(problem) = correctable_problem(parameters) {
                    return bad("bias_correction", &problem);
                }
                if replicates < 2 {
                    return bad("bias_correction", "the bootstrap needs at least 2 replicates");
                }
                if self.research.bootstrap_antithetic && !replicates.is_multiple_of(2) {
                    return bad(
                        "bias_correction",
                        "antithetic pairs (bootstrap_antithetic) need an even number of replicates",
                    );
                }
            }
            self.research.validate()?;
            // The model may be a fitted one (the bias correction's replicates
            // start from it), so only finiteness here; a user's stated model
            // meets the ceilings where it is read (`noise_model_from_table`).
            self.noise.validate_fitted()
        }
    }
}

/// What is wrong with `parameters` as the parameters a bias correction
/// corrects: an extrinsic among them, or none at all.
pub(crate) fn correctable_problem(parameters: ParamSet) -> Option<String> {
    let extrinsics = parameters.intersection(ParamSet::EXTRINSICS);
    if !extrinsics.is_empty() {
        return Some(format!("corrects parameters of θ (c_e, c_d, t_r, d), not {extrinsics}"));
    }
    parameters.is_empty().then(|| "names no parameter to correct (give c_e, c_d, t_r or d)".to_string())
}
