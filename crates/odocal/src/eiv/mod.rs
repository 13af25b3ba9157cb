//! Errors-in-variables calibration (docs/method.md §9): an augmented extended Kalman
//! filter that models the noise on the wheel inputs, fitted by Fisher
//! scoring with exact derivatives.
//!
//! The public items are the options of [`crate::Method::Eiv`] a user sets
//! ([`EivOptions`], the noise model, the bias correction and the
//! bootstrap's options); [`crate::calibrate()`] runs the estimator with the
//! fallback and the checks. The estimator itself, its report, its
//! Cramér–Rao bound, its bootstrap and its modelling alternatives are
//! public with the cargo feature `research` only (the studies of
//! crates/odocal-lab).
//!
//! ## The filter
//!
//! State (12): `z = [p_x, p_y, ψ, s_c, s_l, s_r, b_x, b_y, b_ψ, e_β, w_l, w_r]`:
//! the pose, the common-mode and per-wheel relative wheel-rotation errors
//! (first-order Gauss-Markov, `s' = a·s + w`, `a = exp(−t_s/τ)`,
//! `var w = σ²(1 − a²)`), the reference-pose drift (Gauss-Markov per axis
//! and heading), the sideslip error (a Gauss-Markov state) and the encoder
//! remainders of counting quantisation ([`QuantisationModel::Counting`];
//! without it the filter runs the first 10 states). The true
//! wheel rotations are `n_w = ñ_w·(1 − s_c − s_w) − e_w` with white
//! `e_w ~ N(0, (σ_white·ñ_w)² + q²/12·[w turns])` (a wheel turns where it
//! counts, and in runs of empty samples shorter than one tick's time at
//! 0.002 rev/s, at least a second: it creeps); the pose propagates with
//! the model step f at these effective inputs. a_y and β are noisy inputs:
//!
//! ```text
//! Q_x = F_n·diag(var e)·F_nᵀ + σ_β,eq²·f_β f_βᵀ + σ_a²·f_a f_aᵀ
//! ỹ_k = x_k + b_k + v_k,   R = diag(σ_p² + (1 mm)², σ_p² + (1 mm)², σ_ψ² + (1e-5 rad)²)
//! ```
//!
//! (`f_β = ∂f/∂β`, `f_a = ∂f/∂a_y`; with the research option `SideslipNoise::WhiteEquivalent`
//! the sideslip error, Gauss-Markov with correlation time τ_β, enters as the
//! white variance with the same long-run sum,
//! `σ_β,eq² = σ_β²·(1 + a_β)/(1 − a_β)`, else as the state e_β). σ_a and σ_β are settable in
//! [`NoiseModel`] and scaled together with the white wheel noise (η_0, the
//! "white input noise" group); they have no scale factor of their own.
//!
//! Measurement updates happen only at samples where the reference was really
//! measured (`EivInput::reference_measured`); between them the filter only
//! predicts. Each continuous part of the drive is cut into windows of about
//! [`EivOptions::window_samples`]; every window starts at `x = ỹ_0, s = 0,
//! b = 0` with `P_xx = R + Σ_b, P_bb = Σ_b, P_xb = −Σ_b, P_ss = diag(σ²)`.
//! Windows are independent, run in parallel and are summed in window order,
//! so the result does not depend on the number of threads.
//!
//! **Covariance mode** (`CovarianceMode`, a research option; the base formulation is ambiguous here).
//! The covariance recursion (P, S, K) is linearised along the reference
//! (reference heading, measured wheel rotations) at a θ:
//! - following θ (the product's): at the current θ. S depends
//!   on θ through `F_n Σ_n F_nᵀ`; `∂P/∂θ` is propagated exactly (the step
//!   terms `F̄`, `F_n`, `∂f/∂a_y` are differentiated in forward mode) and θ
//!   minimises the profile cost `J = ½Σ νᵀS(θ)⁻¹ν − Σ m log(1 − ŝ)`, the
//!   joint-MAP (Deming / total-least-squares) cost, which is consistent for
//!   noisy regressors. Its scoring metric is the Gauss-Newton matrix
//!   `Σ (∂r/∂θ)ᵀ(∂r/∂θ)` of the whitened innovations `r = L⁻¹ν` (the
//!   expected Hessian of J); θ steps are halved on J with objective-only
//!   filter passes, η steps on the marginal likelihood M (block coordinate;
//!   near the estimate both step together from one pass, the research
//!   option `simultaneous_steps`, and the last step is taken without the
//!   pass after it where the steps shrink fast, `final_step`).
//! - held at a reference (the research option `HeldAtReference`): at a reference θ (batch G-N's
//!   result, then each pass's): `∂S/∂θ = 0`, so the θ cost is weighted least
//!   squares on increments with a noisy regressor — attenuation bias, t_r
//!   too large — which the corrected score below only partly removes.
//!
//! Measured (`study_eiv` in crates/odocal-lab, 12 km, seeds 1–20, error mean ± sd;
//! CRB σ from `cramer_rao_bound`, full Fisher information; "known" = the
//! simulator's noise model from `NoiseModel::from_sim`, fixed; "est." =
//! η estimated from the default [`NoiseModel`] (a production car's); "boot" = known minus
//! the `bootstrap` bias, B = 10, seeds 1–20):
//!
//! | preset | batch G-N t_r % | follows, known | follows, est. | CRB | known c_e % | known + boot c_e % | c_e CRB |
//! |---|---|---|---|---|---|---|---|
//! | white | +1.11 ± 0.73 | +0.10 ± 0.24 | +0.01 ± 0.26 | 0.21 | +0.010 ± 0.003 | +0.0003 ± 0.0026 | 0.003 |
//! | paper | +1.37 ± 0.82 | +0.39 ± 0.30 | +4.04 ± 1.02 | 0.23 | +0.087 ± 0.029 | +0.005 ± 0.031 | 0.024 |
//! | high  | +8.2 ± 3.6   | +3.3 ± 1.2   | +122 ± 33    | 0.29 | +0.55 ± 0.07 | +0.013 ± 0.078 | 0.059 |
//! | coloured wheel, perfect reference | +1.32 ± 0.81 | +0.14 ± 0.26 | +0.05 ± 0.25 | 0.22 | +0.098 ± 0.026 | +0.004 ± 0.028 | 0.019 |
//!
//! (The table's fits tie the heading white noise to the position scale,
//! [`HeadingScale::TiedToPosition`], and model quantisation as rate noise,
//! [`QuantisationModel::ProcessNoise`]. The fits with the separate scale η_5
//! and the other quantisation models: `study_eiv` and `eiv_eta_diag` in
//! crates/odocal-lab; docs/validation.md measures the defaults. In short: the "est." failure on paper and
//! high comes from the tied position/heading scale — the heading keeps the
//! production car's ratio, 0.49 mrad against the simulator's 0.30 — not
//! from the time constants; and the known-noise t_r bias under high noise
//! comes mostly from encoder quantisation modelled as accumulating rate
//! noise.)
//! Following θ removes most of the t_r bias when the noise model is right
//! (white, coloured; RMS 1.2–1.3× the CRB), less under paper (+0.4 %) and
//! high (+3 %) noise, whose slip, drift and a_y/β noise the model holds
//! only approximately. It adds a c_e bias of about `2σ²` of the relative
//! input noise (the noise is scaled by the measured inputs; the
//! coloured-noise correction is about half effective in this mode), which
//! the bootstrap bias correction removes (paper +0.087 → +0.005 %, 20 seeds). With
//! the production-car starting model (τ_w = 0.25 s, τ_c = 2 s against the
//! simulator's 5 s) the estimated η absorbs the mismatch and t_r is biased
//! again (paper +4 %, high +122 %): estimating η from a wrong-τ start is
//! not safe.
//!
//! ## The objective
//!
//! One objective for θ and the noise scales η (6 log-scale factors on
//! [white + quantisation, common Gauss-Markov, per-wheel Gauss-Markov,
//! position white, pose drift, heading white] relative to the starting
//! [`NoiseModel`]):
//!
//! ```text
//! M(θ, η) = ½ Σ_k (ν_kᵀ S_k⁻¹ ν_k + log det S_k)
//!           − Σ_k [m_k log(1 − ŝ_c,k) + m_l,k log(1 − ŝ_l,k) + m_r,k log(1 − ŝ_r,k)]
//! ```
//!
//! (m: 1 where the wheel(s) turn). With the covariance held, S does not
//! depend on θ and `∂M/∂θ` is exactly the gradient of the base formulation's corrected
//! profile cost; with it following θ, θ uses `∂J/∂θ` (J = M without
//! `½Σ log det S`, which biases t_r by +7 to +8 % when included) and η
//! uses `∂M/∂η`.
//!
//! **Corrected score** (held mode only). With S held at the reference, the θ-gradient of the
//! profile cost is biased by the white input noise (wheels, quantisation,
//! a_y): the noise e_k enters both ν_{k+1} and the sensitivity ∂ν/∂θ
//! (attenuation, as in any errors-in-variables regression). Its expectation
//! `b = Σ_k −tr(S_k⁻¹ H X_k Hᵀ)`, with `X = E[ε D̃ᵀ]` propagated like P
//! (`X⁻ = F̄ X⁺ F̄ᵀ − Σ_u var(u)·(∂f/∂u)(∂(F D + f_θ)/∂u)ᵀ`,
//! `X⁺ = (I − KH) X⁻ (I − KH)ᵀ`), is subtracted: θ solves `∂M/∂θ − b = 0`
//! (Nakamura 1990). This prevents the collapse of t_r under white wheel
//! noise but leaves a bias of several per cent on t_r.
//!
//! ## Fisher scoring
//!
//! Exact derivatives come from a hand-written sensitivity recursion through
//! the filter (module `filter`): `∂ẑ/∂[θ, η]` (state × 10) for the mean and
//! `∂P/∂η_j` for the covariance. With
//! `H_θ = Σ (∂ν/∂θ)ᵀ S⁻¹ (∂ν/∂θ)` and
//! `I_η = Σ (∂ν/∂η)ᵀ S⁻¹ (∂ν/∂η) + ½ Σ tr(S⁻¹ ∂S_i S⁻¹ ∂S_j)` the steps are
//! `Δθ = −H_θ⁻¹ ∂M/∂θ` and `d = −I_η⁻¹ ∂M/∂η`, the latter taken as
//! `Δη = ln(1 + d)` (exact for a pure variance scale; a source that the data
//! show to be absent, `d ≤ −1`, goes straight to the lower clamp), η clamped
//! to [`EivOptions::eta_bounds`]. A step that raises its objective is
//! halved. The fit stops when the proposed `max |step|/σ < 0.05` (the step
//! is then not taken) or after 20 iterations; with the covariance held it
//! runs twice (the second pass with the reference at the first result).
//! At the end of the fit a source at its lower clamp whose score test says
//! the data hold it (z = `−∂M/∂η_j / √I_jj` > 3) and whose one-step
//! estimate is at least −10 is released: the fit runs again from its
//! estimate with the source there, and that fit is kept when it converges
//! with a lower M (a source sent to the clamp by an early step cannot
//! return on its own: its information there is e^−40 of the start's).
//!
//! Speed. The filter's cost is the covariance recursion and its
//! derivatives: per sample, P and up to 10 `∂P/∂p_j` (4 θ with the
//! covariance following θ, 6 η; η_5 only with a separate heading scale),
//! each a structured `F (·) Fᵀ` and a Joseph update, computed on the lower
//! triangle and mirrored (module `filter`). A θ step's evaluation, whose
//! only use is the η step after it, skips `∂P/∂θ`; the evaluation an
//! iteration starts from skips `∂P/∂η` until its θ step is below the
//! tolerance (then it is evaluated again in full for the convergence test;
//! steps and decisions are those of full evaluations; the start after an
//! iteration that was nearly converged is evaluated in full directly). A
//! fit with η estimated typically takes 1 + 2 × iterations derivative
//! passes (9 on the 24 km paper drive, 8 of them with the θ or the η
//! columns only), with the noise fixed 1 + iterations (3); the η term of
//! the covariance one more per free parameter (4). The bias correction's
//! replicates take one pass each (one scoring step from the estimate,
//! `BootstrapRefit::OneStep`). docs/performance.md and crates/odocal-lab/PERFORMANCE.md have the timings
//! (`eiv_speed` in crates/odocal-lab). Results agree with the straightforward dense
//! filter to ~1e-13 relative (test
//! `results_match_the_recorded_results_of_the_unoptimised_filter`).
//!
//! Uncertainty is `H_θ⁻¹` at the estimate (`EivReport::sigma`), the
//! sandwich `H_θ⁻¹ B H_θ⁻¹` (B the outer products of the per-update scores,
//! `EivReport::sigma_sandwich`) and the inverse of the Gaussian Fisher
//! information with both terms, jointly with the estimated η
//! (`EivReport::sigma_fisher`); observability comes from `H_θ`. The
//! Cramér–Rao bound (`cramer_rao_bound`) is the full Fisher information
//! `Σ (∂ν/∂θ)ᵀS⁻¹(∂ν/∂θ) + ½ tr(S⁻¹∂S/∂θ_i S⁻¹∂S/∂θ_j)` at θ_true with the
//! true noise model (the covariance following θ); its mean-only part is
//! reported alongside. The `½ tr` term is information that the size of the
//! innovations carries about θ when the noise model is known: the wheel
//! noise in metres scales with the circumferences, which bounds c_e far
//! below what the increments alone give (see the study table).
//!
//! **Parametric bootstrap** (`bootstrap`): B re-simulations of the fitted
//! noise model at θ̂ on the drive's own inputs, re-fitted with the same
//! options (each replicate seeded on its own, so thread-count independent),
//! giving percentile and basic intervals, the estimator's bias at θ̂ and the
//! bias-corrected θ̂ − bias. This is the measured cure of the c_e bias:
//! `ResearchOptions::bias_correction` = `BiasCorrection::Bootstrap` applies it
//! inside `estimate` (its table; the analytic alternatives measured
//! against it are `FirstOrderBias` and the fitted-input noise scale).
//!
//! ## Misspecification
//!
//! Every window reports its normalised innovation squared (NIS, expected 1
//! per degree of freedom) and the lag-1 autocorrelation of its whitened
//! innovations; θ is re-estimated on each half of the windows by one scoring
//! step. Failures, noise scales at their upper clamp and non-convergence are
//! typed [`EivWarning`]s carrying the window index or parameter.
//!
//! ## Code layout
//!
//! `input` (the drive's slices and its windows), `noise` (the noise model
//! and its scaled sources), `options` and `modelling` (the options and the
//! modelling choices they select), `report` (what a fit reports), `problem`
//! (the Fisher-scoring problem: a drive's windows and their summed filter
//! passes), `steps` (the θ and η scoring steps), `scoring` (one scoring
//! pass), `estimate` (the entry points and the per-window checks),
//! `covariance` (θ's covariance beyond `H_θ⁻¹`), `bias_correction` and
//! `bootstrap`, `crb` (the Cramér–Rao bound), `lattice` (the quantisation
//! step read off the readings) and
//! `filter` (the augmented filter over one window).
//!
//! ## References
//! - G. Fazekas, P. Gáspár, B. Németh, "Wheel Odometry Model Calibration with
//!   Input Compensation by Optimal Control", IFAC-PapersOnLine, 2022.
//! - R. H. Shumway, D. S. Stoffer, *Time Series Analysis and Its
//!   Applications*, ch. 6 (innovations likelihood of a state-space model).
//! - R. K. Mehra, "On the identification of variances and adaptive Kalman
//!   filtering", IEEE TAC 15(2), 1970.
//! - T. Nakamura, "Corrected score function for errors-in-variables models",
//!   Biometrika 77(1), 1990.
//! - N. K. Gupta, R. K. Mehra, "Computational aspects of maximum likelihood
//!   estimation and reduction in sensitivity function calculations", IEEE
//!   TAC 19(6), 1974 (filter sensitivity recursions, Fisher scoring).

mod bias_correction;
mod bootstrap;
mod covariance;
mod crb;
mod estimate;
pub(crate) mod filter;
mod heading_drift;
mod input;
mod lattice;
mod modelling;
mod noise;
mod options;
mod problem;
mod report;
mod scoring;
mod steps;
#[cfg(test)]
pub(crate) mod tests;

pub(crate) use bias_correction::first_order_bias;
#[cfg(test)]
pub(crate) use bootstrap::{FAIL_EVERY_REPLICATE_SEED, FAIL_ONE_REPLICATE_SEED};
pub(crate) use heading_drift::{HEADING_DRIFT_LR_THRESHOLD, HEADING_DRIFT_SCORE_GATE};
pub(crate) use modelling::BIAS_BOOTSTRAP_SMOOTHING_SAMPLES;
pub(crate) use noise::NOISE_SOURCES;
pub(crate) use options::correctable_problem;
pub(crate) use report::PARAMETERS;
// What a user sets (the options, the noise model and the bootstrap's
// options) and the EIV findings of the calibration's warnings.
pub use {
    bootstrap::BootstrapOptions,
    modelling::{HeadingScale, LateralNoise, QuantisationLevel, QuantisationModel},
    noise::{NoiseModel, NoiseSource},
    options::EivOptions,
    report::{EivWarning, PoseComponent, Termination},
};
// The estimator itself, its report and the modelling alternatives of
// `EivOptions::research`: public with the `research` feature (the studies of
// crates/odocal-lab), crate-internal (at their defaults) without it.
research_use! {
    bias_correction::apply_bias_correction,
    bootstrap::{bootstrap, BootstrapInputs, BootstrapRefit, BootstrapReport},
    crb::cramer_rao_bound,
    estimate::{estimate, kernel_instruction_set},
    heading_drift::HeadingDriftTest,
    input::{EivInput, Window},
    lattice::quantisation_step_of_readings,
    modelling::{
        BiasCorrection, FirstOrderBias, InnovationNull, InputJacobian, SideslipNoise, WheelNoiseScale, DEFAULT_POSITION_FLOOR_M, BASE_POSITION_FLOOR_M,
    },
    options::{CovarianceEstimate, CovarianceMode, NoiseEstimateTerm, ResearchOptions},
    report::{CrbReport, EivObservability, EivReport, HalvesCheck, IterationRecord, PassReport, WindowDiagnostics},
}
