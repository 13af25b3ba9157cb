//! A calibration report's method part (the 3-step method's steps, the EIV
//! fit and its fallback), read from the report's JSON as any user of
//! `odocal calibrate --json` reads it: these fields stand at the report's
//! top level (`identification`, `initial_step`, `uncertainty`, `eiv`,
//! `eiv_result`, ...). The studies read nothing of the report beyond its
//! public fields and this JSON.

use odocal::eiv::{EivReport, NoiseModel};
use odocal::identify::{IdentifyReport, RobustCovariance};
use odocal::{CalibrationReport, Param, Theta, ThetaScore};
use serde::de::DeserializeOwned;
use serde::Deserialize;

/// The EIV method's part of a report.
#[derive(Debug, Clone, Deserialize)]
pub struct EivPart {
    /// The starting batch Gauss-Newton over all cut segments (also the
    /// fallback result).
    pub identification: IdentifyReport,
    /// Parameters held at θ_0 for the start only.
    pub start_held: Vec<Param>,
    /// The EIV fit; `None` when the filter failed (`eiv_error`).
    pub eiv: Option<Box<EivReport>>,
    /// The filter's error, when it failed.
    pub eiv_error: Option<String>,
    /// The starting noise model.
    pub noise_start: NoiseModel,
    /// Which estimate the report's θ is: `eiv` or `batch-gn-fallback`.
    pub eiv_result: String,
    /// The EIV fit is the refit with the noise sources released.
    #[serde(default)]
    pub refit: bool,
    /// The refit after a noise scale at its upper clamp
    /// (`clamp_refit_hold_scale`, `clamp_refit_common_mode_eta`), when it
    /// is the result: the first fit's θ (`first_theta`) and η (`first_eta`).
    #[serde(default)]
    pub clamp_refit: Option<serde_json::Value>,
}

impl EivPart {
    /// The report's θ is the batch Gauss-Newton start, not the EIV fit.
    pub fn fell_back(&self) -> bool {
        self.eiv_result == "batch-gn-fallback"
    }
}

/// Step 1 of the 3-step method: the picked estimates.
#[derive(Debug, Clone, Deserialize)]
pub struct InitialStepPart {
    /// The picked θ_B,I (best first).
    pub picked: Vec<ThetaScore>,
}

/// The spread of step 1's plausible batch estimates, as a covariance.
#[derive(Debug, Clone, Deserialize)]
pub struct BatchSpreadPart {
    /// Covariance of θ, 4×4, row-major.
    pub covariance: [[f64; 4]; 4],
}

/// Covariances of the 3-step result beyond step 3's own.
#[derive(Debug, Clone, Default, Deserialize)]
pub struct UncertaintyPart {
    /// Cluster-robust covariance with the measured inputs.
    #[serde(default)]
    pub measured_inputs: Option<RobustCovariance>,
    /// The spread of step 1's batch estimates.
    #[serde(default)]
    pub batch_spread: Option<BatchSpreadPart>,
}

/// The 3-step method's part of a report.
#[derive(Debug, Clone, Deserialize)]
pub struct ThreeStepPart {
    /// Step 1.
    pub initial_step: InitialStepPart,
    /// Step 3.
    pub identification: IdentifyReport,
    /// The further candidate covariances.
    #[serde(default)]
    pub uncertainty: UncertaintyPart,
}

/// One-σ of a covariance (square roots of the diagonal).
pub fn std_dev_of(c: &[[f64; 4]; 4]) -> Theta {
    Theta { c_e: c[0][0].sqrt(), c_d: c[1][1].sqrt(), t_r: c[2][2].sqrt(), d: c[3][3].sqrt() }
}

/// The report's JSON read as `T`; panics when it does not parse (a study
/// must not silently lose a fit).
fn part<T: DeserializeOwned>(r: &CalibrationReport) -> T {
    match serde_json::to_value(r).and_then(serde_json::from_value) {
        Ok(p) => p,
        Err(e) => panic!("the {} report's JSON does not read as its method part: {e}", r.method),
    }
}

/// The EIV part of `r`; `None` for the other methods.
pub fn eiv_part(r: &CalibrationReport) -> Option<EivPart> {
    (r.method == "eiv").then(|| part(r))
}

/// The 3-step part of `r`; `None` for the other methods.
pub fn three_step_part(r: &CalibrationReport) -> Option<ThreeStepPart> {
    (r.method == "three-step").then(|| part(r))
}

/// The final Gauss-Newton identification of `r` (batch-gn: the only one;
/// three-step: step 3; eiv: the starting batch G-N).
pub fn identification(r: &CalibrationReport) -> IdentifyReport {
    #[derive(Deserialize)]
    struct Id {
        identification: IdentifyReport,
    }
    part::<Id>(r).identification
}
