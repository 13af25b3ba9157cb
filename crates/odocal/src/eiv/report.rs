//! What a fit reports: parameters, warnings, diagnostics, passes, the bound.

use serde::{Deserialize, Serialize};

use super::{FirstOrderBias, HeadingDriftTest, NoiseModel, NoiseSource, Window};
use crate::model::param::Param;
use crate::model::Theta;

/// The parameters of θ in θ order.
pub(crate) const PARAMETERS: [Param; 4] = Param::THETA;

/// Why a scoring pass stopped. Reaching the iteration limit is an outcome, not an error.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Termination {
    /// The proposed step was small against the standard errors (it is not taken).
    StepTolerance {
        /// `max |step_i|/σ_i` of the last step.
        step_over_sigma: f64,
        /// The tolerance.
        threshold: f64,
    },
    /// The last step was taken without evaluating the derivatives after it:
    /// the steps shrank fast enough that the remainder, predicted from the
    /// step before, is below the tolerance.
    FinalStep {
        /// `max |step_i|/σ_i` of the step taken.
        step_over_sigma: f64,
        /// The remainder predicted, `step_over_sigma²` over the step before's.
        predicted_over_sigma: f64,
        /// The tolerance.
        threshold: f64,
    },
    /// `max_iterations` steps were taken; the last one was still this large.
    MaxIterations {
        /// The limit.
        iterations: usize,
        /// `max |step_i|/σ_i` of the last step.
        step_over_sigma: f64,
    },
    /// No step length along the scoring direction lowered the objective.
    CostIncreased {
        /// Objective at the shortest step tried.
        cost: f64,
        /// Objective at the kept estimate.
        previous: f64,
        /// Halvings tried.
        halvings: usize,
    },
}

impl Termination {
    /// True when the fit converged (step tolerance met, or predicted to be
    /// met after a final step).
    pub(crate) fn converged(&self) -> bool {
        matches!(self, Termination::StepTolerance { .. } | Termination::FinalStep { .. })
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Termination::StepTolerance { step_over_sigma, threshold } => {
                write!(f, "step tolerance: max|step|/σ {step_over_sigma:.2e} < {threshold}")
            }
            Termination::FinalStep { step_over_sigma, predicted_over_sigma, threshold } => write!(
                f,
                "final step: max|step|/σ {step_over_sigma:.2e} taken, remainder predicted {predicted_over_sigma:.2e} < {threshold}"
            ),
            Termination::MaxIterations { iterations, step_over_sigma } => {
                write!(f, "iteration limit: {iterations} (last max|step|/σ {step_over_sigma:.2e})")
            }
            Termination::CostIncreased { cost, previous, halvings } => {
                write!(f, "cost increased: {cost:.6e} > {previous:.6e} after {halvings} halvings (step rejected)")
            }
        }
    }
}

/// A component of the pose innovation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseComponent {
    /// p_x.
    X,
    /// p_y.
    Y,
    /// ψ.
    Heading,
}

/// A finding that makes the result less trustworthy: typed, with the
/// window or parameter it concerns.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum EivWarning {
    /// A noise scale reached its upper clamp: the noise model cannot explain
    /// the data (the lower clamp only means a source is absent).
    NoiseAtUpperClamp {
        /// The source.
        source: NoiseSource,
        /// Its η.
        eta: f64,
    },
    /// A window's NIS per degree of freedom is far above the divergence limit.
    FilterDiverged {
        /// Window index.
        window: usize,
        /// NIS per degree of freedom.
        nis: f64,
        /// The limit.
        threshold: f64,
    },
    /// A window's NIS per degree of freedom is outside the consistency band
    /// (with `InnovationNull::FloorsAsRegularisation`, the band widened to
    /// cover the NIS expected without the floors, see `ResearchOptions::innovation_null`).
    InconsistentInnovations {
        /// Window index.
        window: usize,
        /// NIS per degree of freedom.
        nis: f64,
        /// The band.
        band: [f64; 2],
    },
    /// A window's whitened innovations are correlated from one update to
    /// the next beyond what the noise model explains: the lag-1
    /// autocorrelation is more than `threshold` outside the interval
    /// between 0 and `expected` (see `ResearchOptions::innovation_null`;
    /// `threshold` is the limit on the side where it left the interval).
    CorrelatedInnovations {
        /// Window index.
        window: usize,
        /// The component.
        component: PoseComponent,
        /// Lag-1 autocorrelation.
        lag1: f64,
        /// Expected lag-1 autocorrelation when the data have none of the
        /// measurement floors (0 with `InnovationNull::FittedModel`).
        #[serde(default)]
        expected: f64,
        /// The limit.
        threshold: f64,
    },
    /// θ from the two halves of the windows differs by more than its uncertainty allows.
    UnstableAcrossHalves {
        /// The parameter.
        parameter: Param,
        /// Difference over its standard deviation.
        z: f64,
        /// The limit.
        threshold: f64,
    },
    /// The last pass did not converge.
    NotConverged {
        /// Why it stopped.
        termination: Termination,
    },
    /// Parameters the data cannot determine; held at their starting value.
    Unobservable {
        /// The parameters.
        parameters: Vec<Param>,
    },
}

impl std::fmt::Display for EivWarning {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            EivWarning::NoiseAtUpperClamp { source, eta } => {
                write!(f, "noise scale of {source:?} at its upper clamp (η = {eta:.2}): the noise model does not fit")
            }
            EivWarning::FilterDiverged { window, nis, threshold } => {
                write!(f, "filter diverged in window {window}: NIS/dof {nis:.2} > {threshold}")
            }
            EivWarning::InconsistentInnovations { window, nis, band } => {
                // Three decimals: a NIS just outside its band must not read as on its edge.
                write!(f, "window {window}: NIS/dof {nis:.3} outside [{:.3}, {:.3}]", band[0], band[1])
            }
            EivWarning::CorrelatedInnovations { window, component, lag1, expected, threshold } => {
                if *expected == 0.0 {
                    write!(
                        f,
                        "window {window}: {component:?} innovations lag-1 correlation {lag1:.2} beyond ±{threshold}"
                    )
                } else {
                    write!(
                        f,
                        "window {window}: {component:?} innovations lag-1 correlation {lag1:.2} more than {threshold} \
                         outside [0, {expected:.2}] (expected without the measurement floors)"
                    )
                }
            }
            EivWarning::UnstableAcrossHalves { parameter, z, threshold } => {
                write!(f, "{parameter} differs between the halves of the drive by {z:.1}σ (> {threshold})")
            }
            EivWarning::NotConverged { termination } => write!(f, "not converged: {termination}"),
            EivWarning::Unobservable { parameters } => {
                let names: Vec<String> = parameters.iter().map(|p| p.to_string()).collect();
                write!(f, "not observable from these data (held fixed): {}", names.join(", "))
            }
        }
    }
}

research_pub! {
    /// Observability from the information matrix `H_θ`.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct EivObservability {
        /// Reciprocal condition number of the equilibrated `H_θ` over the free parameters.
        pub rcond: f64,
        /// Standard deviation of each parameter over its resolution (∞ when
        /// singular; 0 for parameters not estimated).
        pub sigma_over_resolution: [f64; 4],
        /// The ratios that decided [`EivObservability::unobservable`]: σ
        /// over resolution from `H_θ` at the first pass's start (the start's
        /// θ, the starting noise model), a held parameter's when it was held
        /// (above 1), a free one's after the holds (0 for parameters not
        /// free). `None` when the check did not run (on later passes, or
        /// with [`EivOptions::fix_unobservable`](crate::eiv::EivOptions::fix_unobservable) off).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub start_sigma_over_resolution: Option<[f64; 4]>,
        /// Parameters held fixed because the data cannot determine them:
        /// σ over resolution above 1 at the start
        /// ([`EivObservability::start_sigma_over_resolution`]).
        pub unobservable: Vec<Param>,
        /// Parameters in a near-collinear combination of the free ones.
        pub collinear: Vec<Param>,
    }
}

research_pub! {
    /// Per-window consistency numbers.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct WindowDiagnostics {
        /// The window.
        pub window: Window,
        /// Measurement updates.
        pub updates: usize,
        /// NIS per degree of freedom, `Σ νᵀS⁻¹ν / (3·updates)` (1 when consistent).
        pub nis: f64,
        /// Lag-1 autocorrelation of the whitened innovations `[x, y, ψ]`.
        pub lag1: [f64; 3],
        /// Expected NIS per degree of freedom when the data have the fitted
        /// noise but none of the measurement floors
        /// (`InnovationNull::FloorsAsRegularisation`; 1 with
        /// `InnovationNull::FittedModel`).
        #[serde(default = "one")]
        pub nis_without_floors: f64,
        /// Expected lag-1 autocorrelation `[x, y, ψ]` of the whitened
        /// innovations under the same null (0 with `InnovationNull::FittedModel`).
        #[serde(default)]
        pub lag1_without_floors: [f64; 3],
    }
}

pub(super) fn one() -> f64 {
    1.0
}

research_pub! {
    /// θ re-estimated on each half of the windows (one scoring step from the estimate).
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct HalvesCheck {
        /// θ from the first half.
        pub first: Theta,
        /// θ from the second half.
        pub second: Theta,
        /// Difference over its standard deviation per parameter (0 for fixed ones).
        pub z: [f64; 4],
    }
}

research_pub! {
    /// One accepted scoring iteration.
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    struct IterationRecord {
        /// θ after the step.
        pub theta: Theta,
        /// η after the step.
        pub eta: [f64; 6],
        /// The objective M.
        pub cost: f64,
        /// `max |step|/σ` of the step.
        pub step_over_sigma: f64,
        /// Step length factor after halving (1 = full step).
        pub step_factor: f64,
    }
}

research_pub! {
    /// One scoring pass (covariance held at one reference θ).
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct PassReport {
        /// Reference θ of the covariance recursion.
        pub theta_reference: Theta,
        /// θ at the end of the pass.
        pub theta: Theta,
        /// Objective at the start and at the end.
        pub initial_cost: f64,
        /// Objective at the end.
        pub final_cost: f64,
        /// Why it stopped.
        pub termination: Termination,
        /// Accepted iterations.
        pub history: Vec<IterationRecord>,
        /// `max |Δη_j|/σ_j` of the η scoring step remaining at the end (η not at
        /// a clamp; `None` when η is fixed or the pass stopped before a step;
        /// predicted, as the whole remainder is, after a [`Termination::FinalStep`]).
        #[serde(default)]
        pub eta_step_over_sigma: Option<f64>,
        /// `Some(k)` for a long drive's coarse first stage, which ran on every
        /// `k`-th window of the drive; `None` for a pass over all windows.
        #[serde(default)]
        pub window_stride: Option<usize>,
    }
}

research_pub! {
    /// The result of an EIV calibration.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct EivReport {
        /// The starting θ.
        pub initial_theta: Theta,
        /// The estimate.
        pub theta: Theta,
        /// Which parameters were estimated.
        pub free: [bool; 4],
        /// θ's covariance at the estimate (zero rows for fixed parameters):
        /// `H_θ⁻¹`, or per parameter raised to the block sandwich's
        /// (`ResearchOptions::covariance_estimate`), plus what estimating η adds
        /// (`ResearchOptions::noise_estimate_term`).
        pub covariance: [[f64; 4]; 4],
        /// Standard deviations `sqrt(diag covariance)`.
        pub sigma: [f64; 4],
        /// Standard deviations of the sandwich `H_θ⁻¹ B H_θ⁻¹`, B the sum of the
        /// outer products of the per-update θ-scores (robust to a wrong noise scale).
        pub sigma_sandwich: [f64; 4],
        /// Standard deviations of the block sandwich `H_θ⁻¹ B_b H_θ⁻¹`, `B_b`
        /// from the per-update θ-scores summed over 20 s blocks within each
        /// window (centred, lag-1 Newey–West across neighbouring blocks): robust
        /// to a wrong noise model *and* to serially correlated scores, which the
        /// per-update [`EivReport::sigma_sandwich`] is not. NaN with
        /// fewer than two blocks.
        pub sigma_block: [f64; 4],
        /// Standard deviations from the Gaussian Fisher information at the
        /// estimate with both terms (`½ tr(S⁻¹∂S S⁻¹∂S)` included), jointly
        /// with the estimated η (θ block of the inverse): the Cramér–Rao form
        /// of [`cramer_rao_bound`](crate::eiv::cramer_rao_bound) at θ̂ and the fitted noise. Equal to the
        /// mean-only information with the covariance held. Linearised along the
        /// measured inputs (a fit has no other), whose noise counts as
        /// excitation: under heavy wheel noise it understates t_r's and d's σ
        /// (on the `high` preset t_r's by about half; it covered t_r in 22–25 %
        /// of drives). A diagnostic; [`EivReport::sigma`] is raised to the block
        /// sandwich, which measures the scores' actual spread.
        pub sigma_fisher: [f64; 4],
        /// The part of θ's σ that estimating η from the drive adds
        /// (`ResearchOptions::noise_estimate_term`): `sqrt(diag A Σ_η Aᵀ)`.
        /// Included in [`EivReport::covariance`] and [`EivReport::sigma`] with
        /// the observed term; 0 by default (the term left out) and with a
        /// fixed noise model.
        #[serde(default)]
        pub sigma_noise_estimate: [f64; 4],
        /// `∂θ̂/∂η_j` at the estimate (`[parameter][source]`, in θ's units per
        /// unit of η; `ResearchOptions::noise_estimate_term`): how far θ̂
        /// moves when a source's variance is e-fold. Zero for sources not
        /// estimated, with a fixed noise model and by default (the term left
        /// out).
        #[serde(default)]
        pub theta_eta_sensitivity: [[f64; 6]; 4],
        /// `∂η̂_j/∂θ_i` at the estimate (`[source][parameter]`, per unit of θ in
        /// SI), from the expected information of the marginal likelihood M:
        /// `−I_ηη⁻¹ I_ηθ` over the estimated sources. How the noise estimate
        /// follows θ; with [`EivReport::theta_eta_sensitivity`] it gives the
        /// feedback `A B` between θ̂ and η̂. Zero with a fixed noise model.
        #[serde(default)]
        pub eta_theta_sensitivity: [[f64; 4]; 6],
        /// Estimated log-scale factors η (0 with `fix_noise`).
        pub eta: [f64; 6],
        /// Standard deviations of η (0 when fixed or at a clamp).
        pub eta_sigma: [f64; 6],
        /// Filter passes over the drive: `[with derivatives, objective only]`.
        /// The passes of a coarse first stage over every `k`-th window
        /// ([`PassReport::window_stride`]) count as the passes over the whole
        /// drive they cost: their number divided by `k`, rounded up.
        pub evaluations: [usize; 2],
        /// The test of the heading drift's tie to the pose-drift scale η_4, and
        /// whether the result fitted the heading drift on a scale of its own
        /// (η_6; [`EivReport::noise`] then carries its σ). None where η is not
        /// estimated or the pose drift is held.
        #[serde(default)]
        pub heading_drift: Option<HeadingDriftTest>,
        /// The noise sources released from their lower clamp at the end of
        /// the fit, where the score test of the clamp said the data hold them
        /// (docs/method.md, "Released scales"); empty where none was.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        pub released: Vec<NoiseSource>,
        /// Whether the fit from the estimate with [`EivReport::released`]
        /// released is the estimate (it converged with a lower M).
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        pub release_kept: bool,
        /// The estimated noise model in physical units.
        pub noise: NoiseModel,
        /// Objective M at the start and the end of the last pass.
        pub final_cost: f64,
        /// Total accepted iterations over all passes.
        pub iterations: usize,
        /// Why the last pass stopped.
        pub termination: Termination,
        /// Every pass.
        pub passes: Vec<PassReport>,
        /// Observability at the estimate.
        pub observability: EivObservability,
        /// Per-window consistency.
        pub windows: Vec<WindowDiagnostics>,
        /// θ stability across halves (None with fewer than two windows).
        pub halves: Option<HalvesCheck>,
        /// Everything that makes the result less trustworthy.
        pub warnings: Vec<EivWarning>,
        /// The first-order bias of the profile cost's root at the estimate, a
        /// diagnostic (None with the covariance held or a singular `H_θ`).
        pub first_order_bias: Option<FirstOrderBias>,
        /// The root of the profile cost before any `BiasCorrection`.
        pub theta_uncorrected: Theta,
        /// The bias subtracted by [`ResearchOptions::bias_correction`](crate::eiv::ResearchOptions::bias_correction) (`theta =
        /// theta_uncorrected − bias_subtracted`; zero for a parameter the
        /// correction does not name, zeros without a correction).
        pub bias_subtracted: [f64; 4],
        /// What the bootstrap of [`ResearchOptions::bias_correction`](crate::eiv::ResearchOptions::bias_correction) adds to θ's σ
        /// (already in [`EivReport::sigma`] and the covariance): the Monte Carlo
        /// error of the subtracted bias, the replicates' covariance over the
        /// number of replicates fitted, for the corrected parameters (zero for
        /// the others, zeros without a correction).
        #[serde(default)]
        pub sigma_bias_correction: [f64; 4],
        /// The bias correction's replicates that could not be fitted: (index,
        /// error). The bias is then the mean over the complete antithetic pairs
        /// (or the replicates) that were fitted; empty without a correction or
        /// when every replicate was fitted.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        pub bias_replicates_failed: Vec<(usize, String)>,
        /// Measurement updates used.
        pub updates: usize,
        /// Wall time, s.
        pub timing_s: f64,
        /// The quantisation step read off the wheel readings' lattice, rev/s,
        /// with [`QuantisationLevel::FromReadings`](crate::eiv::QuantisationLevel::FromReadings) (None when the readings lie
        /// on no lattice or another level was asked for); then also
        /// [`EivReport::noise`]'s q, which is 0 where `FromReadings` found
        /// no lattice.
        #[serde(default)]
        pub quantisation_step_from_readings: Option<f64>,
        /// The floor of a_y's σ, m/s², the white noise of the drive's own
        /// a_y readings: with a_y's noise tied to the white wheel noise, the
        /// fit never grants a_y less (then also [`EivReport::noise`]'s
        /// `lateral_acceleration_sigma_m_per_s2`). None with a_y's noise
        /// stated or held.
        #[serde(default)]
        pub a_y_noise_floor: Option<f64>,
        /// The white noise of the reference heading's readings, rad, where
        /// the heading's white noise is estimated: part of its variance,
        /// the scale fitting only what lies above it, so
        /// [`EivReport::noise`]'s `heading_white_sigma_rad` is never below
        /// it. None with the noise held or the heading's level known.
        #[serde(default)]
        pub heading_noise_floor: Option<f64>,
        /// Whether the heading's white noise is the readings' level alone
        /// ([`EivOptions::heading_white_at_floor`](crate::eiv::EivOptions::heading_white_at_floor)
        /// took effect): [`EivReport::heading_noise_floor`] is then the
        /// whole of it, and its scale η_5 is held.
        #[serde(default)]
        pub heading_white_at_floor: bool,
        /// With the heading's white noise at its readings' level: twice the
        /// fall of the objective M from that level to one with a level above
        /// it (the starting model's, at least the readings' own), θ and η
        /// held at the estimate's (a lower bound of the
        /// likelihood ratio of a level above the readings'). Above 10.83
        /// (the χ²₁ quantile at 0.1 %) `calibrate` sets the fit aside for
        /// one with that level estimated.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub heading_white_above_floor: Option<f64>,
        /// The wheel noise's correlation times tried and the M each fit
        /// reached, `[τ_c s, τ_w s, M]`: the starting model's and the slow
        /// one's ([`ResearchOptions::choose_time_constants`](crate::eiv::ResearchOptions::choose_time_constants));
        /// the estimate's are [`EivReport::noise`]'s. Empty where the
        /// choice was not made (the default; noise held; no source at its
        /// lower clamp), and then not written to JSON.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        pub time_constant_costs: Vec<[f64; 3]>,
    }
}

impl std::fmt::Display for EivReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} | σ [{:.2e}, {:.2e}, {:.2e}, {:.2e}] | {} it ({}), {} window(s), {} warning(s)",
            self.theta,
            self.sigma[0],
            self.sigma[1],
            self.sigma[2],
            self.sigma[3],
            self.iterations,
            self.termination,
            self.windows.len(),
            self.warnings.len()
        )
    }
}

research_pub! {
    /// The Cramér–Rao bound of θ for one drive.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct CrbReport {
        /// θ at which the bound is evaluated (θ_true).
        pub theta: Theta,
        /// Which parameters were free.
        pub free: [bool; 4],
        /// The Gaussian Fisher information of θ with both terms (4×4):
        /// `Σ (∂ν/∂θ_i)ᵀS⁻¹(∂ν/∂θ_j) + ½ tr(S⁻¹ ∂S/∂θ_i S⁻¹ ∂S/∂θ_j)`, the
        /// covariance recursion following θ.
        pub information: [[f64; 4]; 4],
        /// Its inverse over the free parameters (zero rows for fixed ones).
        pub covariance: [[f64; 4]; 4],
        /// `sqrt(diag)` of the covariance: the smallest standard deviation an
        /// unbiased estimator can have.
        pub sigma: [f64; 4],
        /// The mean-only information `Σ (∂ν/∂θ)ᵀS⁻¹(∂ν/∂θ)` (no `∂S/∂θ` term;
        /// for comparison).
        pub information_mean_only: [[f64; 4]; 4],
        /// `sqrt(diag)` of the inverse of the mean-only information (≥ `sigma`).
        pub sigma_mean_only: [f64; 4],
        /// The bound when the noise scales are unknown too: `sqrt(diag)` of the
        /// θ block of the inverse of the joint Fisher information of θ and the
        /// log-scales η of the noise sources present in the model (η as
        /// nuisance parameters; ≥ `sigma`). This is the fair bound for EIV with
        /// η estimated (the library default): the information that the size of
        /// the innovations carries about θ (the trace term of `sigma`) is shared
        /// with η. `None` when the joint matrix is singular.
        pub sigma_noise_estimated: Option<[f64; 4]>,
    }
}
