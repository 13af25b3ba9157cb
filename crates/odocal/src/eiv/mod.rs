//! Errors-in-variables calibration (SPEC §10): an augmented extended Kalman
//! filter that models the noise on the wheel inputs, fitted by Fisher
//! scoring with exact derivatives.
//!
//! ## The filter
//!
//! State (9): `z = [p_x, p_y, ψ, s_c, s_l, s_r, b_x, b_y, b_ψ]`: the pose,
//! the common-mode and per-wheel relative wheel-rotation errors (first-order
//! Gauss-Markov, `s' = a·s + w`, `a = exp(−t_s/τ)`, `var w = σ²(1 − a²)`) and
//! the reference-pose drift (Gauss-Markov per axis and heading). The true
//! wheel rotations are `n_w = ñ_w·(1 − s_c − s_w) − e_w` with white
//! `e_w ~ N(0, (σ_white·ñ_w)² + q²/12·[ñ_w ≠ 0])`; the pose propagates with
//! the model step f at these effective inputs. a_y and β are noisy inputs:
//!
//! ```text
//! Q_x = F_n·diag(var e)·F_nᵀ + σ_β,eq²·f_β f_βᵀ + σ_a²·f_a f_aᵀ
//! ỹ_k = x_k + b_k + v_k,   R = diag(σ_p² + (1 mm)², σ_p² + (1 mm)², σ_ψ² + (1e-5 rad)²)
//! ```
//!
//! (`f_β = ∂f/∂β`, `f_a = ∂f/∂a_y`; the sideslip error, Gauss-Markov with
//! correlation time τ_β, enters as the white variance with the same long-run
//! sum, `σ_β,eq² = σ_β²·(1 + a_β)/(1 − a_β)`). σ_a and σ_β are settable in
//! [`NoiseModel`] and scaled together with the white wheel noise (η_0, the
//! "white input noise" group); they have no scale factor of their own.
//!
//! Measurement updates happen only at samples where the reference was really
//! measured ([`EivInput::reference_measured`]); between them the filter only
//! predicts. Each continuous part of the drive is cut into windows of about
//! [`EivOptions::window_samples`]; every window starts at `x = ỹ_0, s = 0,
//! b = 0` with `P_xx = R + Σ_b, P_bb = Σ_b, P_xb = −Σ_b, P_ss = diag(σ²)`.
//! Windows are independent, run in parallel and are summed in window order,
//! so the result does not depend on the number of threads.
//!
//! **Covariance mode** ([`CovarianceMode`], SPEC §10 is ambiguous here).
//! The covariance recursion (P, S, K) is linearised along the reference
//! (reference heading, measured wheel rotations) at a θ:
//! - [`CovarianceMode::FollowsTheta`] (default): at the current θ. S depends
//!   on θ through `F_n Σ_n F_nᵀ`; `∂P/∂θ` is propagated exactly (the step
//!   terms `F̄`, `F_n`, `∂f/∂a_y` are differentiated in forward mode) and θ
//!   minimises the profile cost `J = ½Σ νᵀS(θ)⁻¹ν − Σ m log(1 − ŝ)`, the
//!   joint-MAP (Deming / total-least-squares) cost, which is consistent for
//!   noisy regressors. Its scoring metric is the Gauss-Newton matrix
//!   `Σ (∂r/∂θ)ᵀ(∂r/∂θ)` of the whitened innovations `r = L⁻¹ν` (the
//!   expected Hessian of J); θ steps are halved on J with objective-only
//!   filter passes, η steps on the marginal likelihood M (block coordinate).
//! - [`CovarianceMode::HeldAtReference`]: at a reference θ (batch G-N's
//!   result, then each pass's): `∂S/∂θ = 0`, so the θ cost is weighted least
//!   squares on increments with a noisy regressor — attenuation bias, t_r
//!   too large — which the corrected score below only partly removes.
//!
//! Measured (`examples/study_eiv.rs`, 12 km, seeds 1–20, error mean ± sd;
//! CRB σ from [`cramer_rao_bound`], full Fisher information; "known" = the
//! simulator's noise model from [`NoiseModel::from_sim`], fixed; "est." =
//! η estimated from [`NoiseModel::PRODUCTION_CAR`]; "boot" = known minus
//! the [`bootstrap`] bias, B = 10, seeds 1–20 (stop 10); docs/study.md has the rest):
//!
//! | preset | batch G-N t_r % | follows, known | follows, est. | CRB | known c_e % | known + boot c_e % | c_e CRB |
//! |---|---|---|---|---|---|---|---|
//! | white | +1.11 ± 0.73 | +0.10 ± 0.24 | +0.01 ± 0.26 | 0.21 | +0.010 ± 0.003 | +0.0003 ± 0.0026 | 0.003 |
//! | paper | +1.37 ± 0.82 | +0.39 ± 0.30 | +4.04 ± 1.02 | 0.23 | +0.087 ± 0.029 | +0.005 ± 0.031 | 0.024 |
//! | high  | +8.2 ± 3.6   | +3.3 ± 1.2   | +122 ± 33    | 0.29 | +0.55 ± 0.07 | +0.013 ± 0.078 | 0.059 |
//! | coloured wheel, perfect reference | +1.32 ± 0.81 | +0.14 ± 0.26 | +0.05 ± 0.25 | 0.22 | +0.098 ± 0.026 | +0.004 ± 0.028 | 0.019 |
//!
//! (Earlier, 5 seeds: the covariance held at a reference with the known
//! noise gave t_r +0.60 / +1.29 / +11.1 % on white / paper / high.)
//!
//! (The table is for the filter before the heading white noise got its own
//! scale η_5. Diagnosis and the numbers since, including the opt-in
//! [`QuantisationModel::Measurement`]: docs/study.md, EIV section, and
//! `examples/eiv_eta_diag.rs`. In short: the "est." failure on paper and
//! high came from the tied position/heading scale — the heading kept the
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
//! depend on θ and `∂M/∂θ` is exactly the gradient of SPEC's corrected
//! profile cost; with it following θ, θ uses `∂J/∂θ` (J = M without
//! `½Σ log det S`, which biased t_r by +7 to +8 % in the prototype) and η
//! uses `∂M/∂η`.
//!
//! **Corrected score** (held mode only). With S held at the reference, the θ-gradient of the
//! profile cost is biased by the white input noise (wheels, quantisation,
//! a_y): the noise e_k enters both ν_{k+1} and the sensitivity ∂ν/∂θ
//! (attenuation, as in any errors-in-variables regression). Its expectation
//! `b = Σ_k −tr(S_k⁻¹ H X_k Hᵀ)`, with `X = E[ε D̃ᵀ]` propagated like P
//! (`X⁻ = F̄ X⁺ F̄ᵀ − Σ_u var(u)·(∂f/∂u)(∂(F D + f_θ)/∂u)ᵀ`,
//! `X⁺ = (I − KH) X⁻ (I − KH)ᵀ`), is subtracted: θ solves `∂M/∂θ − b = 0`
//! (Nakamura 1990). This removed the collapse of t_r under white wheel
//! noise but leaves a bias of several per cent on t_r (see the branch report).
//!
//! ## Fisher scoring
//!
//! Exact derivatives come from a hand-written sensitivity recursion through
//! the filter (module `filter`): `∂ẑ/∂[θ, η]` (9×9) for the mean and
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
//!
//! Speed. The filter's cost is the covariance recursion and its
//! derivatives: per sample, P and up to 9 `∂P/∂p_j` (4 θ with the
//! covariance following θ, 5 η; η_5 only with a separate heading scale),
//! each a structured `F (·) Fᵀ` and a Joseph update, computed on the lower
//! triangle and mirrored (module `filter`). A θ step's evaluation, whose
//! only use is the η step after it, skips `∂P/∂θ`; since stop 24 the
//! evaluation an iteration starts from skips `∂P/∂η` until its θ step is
//! below the tolerance (then it is evaluated again in full for the
//! convergence test; steps and decisions are unchanged). A fit with η
//! estimated typically takes 2 + 2 × iterations derivative passes (10 on the 24 km
//! paper drive, 6 of them with the θ or the η columns only), with the noise
//! fixed 1 + iterations (3); the η term of the covariance one more per free
//! parameter (4). Stop 14's structured kernels, measured on that drive
//! through `odocal calibrate` (docs/performance.md, CPU seconds, since the
//! 2-core machine was shared): η estimated 3.3 s before, 2.2 s after;
//! fixed noise 0.82 → 0.72 s (of which batch G-N, the start, 0.2 s). Stop
//! 24's lean iteration starts and η term: 24 km `eiv_speed` wall time
//! 2.42–2.92 s → 1.78–2.45 s (interleaved rounds; docs/performance.md).
//! Results agree with the earlier filter to ~1e-13 relative (test
//! `results_match_the_recorded_results_of_the_unoptimised_filter`).
//!
//! Uncertainty is `H_θ⁻¹` at the estimate ([`EivReport::sigma`]), the
//! sandwich `H_θ⁻¹ B H_θ⁻¹` (B the outer products of the per-update scores,
//! [`EivReport::sigma_sandwich`]) and the inverse of the Gaussian Fisher
//! information with both terms, jointly with the estimated η
//! ([`EivReport::sigma_fisher`]); observability comes from `H_θ`. The
//! Cramér–Rao bound ([`cramer_rao_bound`]) is the full Fisher information
//! `Σ (∂ν/∂θ)ᵀS⁻¹(∂ν/∂θ) + ½ tr(S⁻¹∂S/∂θ_i S⁻¹∂S/∂θ_j)` at θ_true with the
//! true noise model (the covariance following θ); its mean-only part is
//! reported alongside. The `½ tr` term is information that the size of the
//! innovations carries about θ when the noise model is known: the wheel
//! noise in metres scales with the circumferences, which bounds c_e far
//! below what the increments alone give (see the study table).
//!
//! **Parametric bootstrap** ([`bootstrap`]): B re-simulations of the fitted
//! noise model at θ̂ on the drive's own inputs, re-fitted with the same
//! options (each replicate seeded on its own, so thread-count independent),
//! giving percentile and basic intervals, the estimator's bias at θ̂ and the
//! bias-corrected θ̂ − bias. This is the measured cure of the c_e bias:
//! [`EivOptions::bias_correction`] = [`BiasCorrection::Bootstrap`] applies it
//! inside [`estimate`] (its table; the analytic alternatives measured
//! against it are [`FirstOrderBias`] and [`WheelNoiseScale::FittedInput`]).
//!
//! ## Misspecification
//!
//! Every window reports its normalised innovation squared (NIS, expected 1
//! per degree of freedom) and the lag-1 autocorrelation of its whitened
//! innovations; θ is re-estimated on each half of the windows by one scoring
//! step. Failures, noise scales at their upper clamp and non-convergence are
//! typed [`EivWarning`]s carrying the window index or parameter.
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

mod bootstrap;
pub(crate) mod filter;
mod lattice;
mod tau;
#[cfg(test)]
pub(crate) mod tests;

use std::ops::Range;
use std::time::Instant;

use nalgebra::{DMatrix, DVector, Matrix4, SymmetricEigen};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::model::Theta;
pub use bootstrap::{bootstrap, BootstrapInputs, BootstrapOptions, BootstrapReport};
#[cfg(test)]
pub(crate) use bootstrap::{FAIL_EVERY_REPLICATE_SEED, FAIL_ONE_REPLICATE_SEED};
use filter::{run_window, Mode, Variances, WindowSums, NETA};
pub use lattice::{quantisation_step_of_readings, LATTICE_TOLERANCE_STEPS, MAX_LATTICE_INDEX, MIN_LATTICE_LEVELS};
pub use tau::{TimeConstantCandidate, TimeConstantFit, TimeConstantGrid, TIME_CONSTANT_RANGE_S};

/// The data of a drive as plain slices (all of length N, samples).
#[derive(Debug, Clone, Copy)]
pub struct EivInput<'a> {
    /// Sample time t_s, s.
    pub sample_time_s: f64,
    /// Continuous parts of the drive, sample index ranges; windows never span two.
    pub parts: &'a [Range<usize>],
    /// Reference x, m.
    pub px: &'a [f64],
    /// Reference y, m.
    pub py: &'a [f64],
    /// Reference heading, rad, unwrapped.
    pub psi: &'a [f64],
    /// Measured rear-left wheel rotation, rev/s.
    pub n_rl: &'a [f64],
    /// Measured rear-right wheel rotation, rev/s.
    pub n_rr: &'a [f64],
    /// Measured sideslip, rad.
    pub beta: &'a [f64],
    /// Measured lateral acceleration, m/s².
    pub a_y: &'a [f64],
    /// `true` where the reference pose was really measured (not
    /// interpolated or held); `None` means every sample.
    pub reference_measured: Option<&'a [bool]>,
}

impl<'a> EivInput<'a> {
    /// The columns of a checked [`Drive`](crate::Drive), its parts and its
    /// reference mask.
    pub fn from_drive(d: &'a crate::Drive) -> Self {
        EivInput {
            sample_time_s: d.sample_time_s(),
            parts: d.parts(),
            px: d.px(),
            py: d.py(),
            psi: d.psi(),
            n_rl: d.n_rl(),
            n_rr: d.n_rr(),
            beta: d.beta(),
            a_y: d.a_y(),
            reference_measured: d.reference_measured(),
        }
    }

    /// The noise-free truth columns of a simulated drive (its parts and
    /// reference mask as [`EivInput::from_drive`]): the trajectory along
    /// which [`cramer_rao_bound`] at θ_true is linearised.
    ///
    /// Why not the measured columns (stop 25): the bound's sensitivities
    /// are the filter's, linearised along the inputs it is given. Along the
    /// measured wheel rotations the white wheel noise appears as yaw and
    /// speed excitation the vehicle never had (on `high` about 5 mrad of
    /// yaw per 25 ms step), and the information about t_r and d, which grows
    /// with that excitation, is overstated: the bound came out about half
    /// the true one for t_r on `high` (docs/study.md, "Stop 25").
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] when the drive carries no truth (a recorded
    /// drive: its bound cannot be evaluated at the truth).
    ///
    /// ```
    /// use odocal::eiv::EivInput;
    /// use odocal::sim::{simulate, SimOptions};
    /// let sim = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) })?;
    /// let truth = EivInput::from_drive_truth(&sim.drive)?;
    /// let measured = EivInput::from_drive(&sim.drive);
    /// assert_eq!(truth.len(), measured.len());
    /// assert_ne!(truth.n_rl, measured.n_rl);
    /// # Ok::<(), odocal::Error>(())
    /// ```
    pub fn from_drive_truth(d: &'a crate::Drive) -> Result<Self> {
        let t = d.truth().ok_or_else(|| Error::InvalidDrive {
            context: "EIV input".into(),
            reason: "the drive carries no truth columns (*_true): the bound at the truth needs a simulated drive"
                .into(),
        })?;
        Ok(EivInput {
            px: &t.px,
            py: &t.py,
            psi: &t.psi,
            n_rl: &t.n_rl,
            n_rr: &t.n_rr,
            beta: &t.beta,
            a_y: &t.a_y,
            ..EivInput::from_drive(d)
        })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.px.len()
    }

    /// True when there are no samples.
    pub fn is_empty(&self) -> bool {
        self.px.is_empty()
    }

    fn validate(&self) -> Result<()> {
        let n = self.px.len();
        let bad = |reason: String| Error::InvalidDrive { context: "EIV input".into(), reason };
        if !(self.sample_time_s.is_finite() && self.sample_time_s > 0.0) {
            return Err(bad(format!("sample_time_s = {} must be positive", self.sample_time_s)));
        }
        for (name, len) in [
            ("py", self.py.len()),
            ("psi", self.psi.len()),
            ("n_rl", self.n_rl.len()),
            ("n_rr", self.n_rr.len()),
            ("beta", self.beta.len()),
            ("a_y", self.a_y.len()),
        ] {
            if len != n {
                return Err(bad(format!("column {name} has {len} samples, px has {n}")));
            }
        }
        if let Some(m) = self.reference_measured {
            if m.len() != n {
                return Err(bad(format!("reference_measured has {} samples, px has {n}", m.len())));
            }
        }
        for p in self.parts {
            if p.start > p.end || p.end > n {
                return Err(bad(format!("part {p:?} is outside 0..{n}")));
            }
        }
        Ok(())
    }
}

/// One filter window: steps `start..end` of one part (the state at `start`
/// is initialised from the reference, the last update is at `end`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Window {
    /// Index of the window in the drive (window order).
    pub index: usize,
    /// Index of the part it belongs to.
    pub part: usize,
    /// First sample.
    pub start: usize,
    /// Last sample.
    pub end: usize,
}

/// Cuts every part into windows of about `target` steps (equal lengths within a part).
fn make_windows(parts: &[Range<usize>], target: usize) -> Vec<Window> {
    let mut out = Vec::new();
    for (pi, p) in parts.iter().enumerate() {
        if p.end < p.start + 2 {
            continue;
        }
        let steps = p.end - p.start - 1;
        let count = ((steps as f64 / target as f64).round() as usize).max(1);
        for w in 0..count {
            let a = p.start + (w * steps) / count;
            let b = p.start + ((w + 1) * steps) / count;
            if b > a {
                out.push(Window { index: out.len(), part: pi, start: a, end: b });
            }
        }
    }
    out
}

/// The noise model of the filter, in physical units. The estimated noise
/// (`NoiseModel::scaled` by the estimated η) is reported in the same form.
///
/// Scale factor groups η: 0 = white + quantisation, 1 = common wheel
/// Gauss-Markov, 2 = per-wheel Gauss-Markov, 3 = position white, 4 = pose
/// drift (position and heading), 5 = heading white. σ_a and σ_β scale with
/// η_0 (white input noise); the time constants are fixed unless
/// [`EivOptions::estimate_time_constants`] (a grid profile, not a scale).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NoiseModel {
    /// White relative wheel-rotation error σ_white per wheel and sample. Default 0.008 (0.8 %).
    pub wheel_white_rel_sigma: f64,
    /// Encoder quantisation step q of the wheel-rotation reading, rev/s
    /// (variance q²/12 where the wheel turns). Default 0.02 (2048 ticks/rev at 40 Hz).
    pub quantisation_step_rev_per_s: f64,
    /// Common-mode coloured relative error σ_c (tyre radius with speed, load,
    /// temperature; slip). Default 0.002 (0.2 %).
    pub wheel_common_rel_sigma: f64,
    /// Correlation time τ_c of the common-mode error, s. Default 2.
    pub wheel_common_time_constant_s: f64,
    /// Per-wheel coloured relative error σ_w. Default 0.0005 (0.05 %).
    pub wheel_differential_rel_sigma: f64,
    /// Correlation time τ_w of the per-wheel error, s. Default 0.25.
    pub wheel_differential_time_constant_s: f64,
    /// White position noise of the reference σ_p, per axis, m. Default 0.02.
    pub position_white_sigma_m: f64,
    /// White heading noise of the reference σ_ψ, rad. Default 0.0005.
    pub heading_white_sigma_rad: f64,
    /// Position drift of the reference (Gauss-Markov), per axis, m. Default 0.25.
    pub position_drift_sigma_m: f64,
    /// Heading drift of the reference (Gauss-Markov), rad. Default 0.003.
    pub heading_drift_sigma_rad: f64,
    /// Correlation time of the drift, s. Default 100.
    pub drift_time_constant_s: f64,
    /// White noise of the lateral acceleration input σ_a, m/s². Default 0.05 (scaled by η_0).
    pub lateral_acceleration_sigma_m_per_s2: f64,
    /// Error of the sideslip input (Gauss-Markov) σ_β, rad. Default 0.002 (scaled by η_0).
    pub sideslip_sigma_rad: f64,
    /// Correlation time τ_β of the sideslip error, s. Default 1.
    pub sideslip_time_constant_s: f64,
}

impl Default for NoiseModel {
    fn default() -> Self {
        NoiseModel::PRODUCTION_CAR
    }
}

/// The six noise sources whose scale η is estimated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum NoiseSource {
    /// White relative wheel noise and quantisation (η_0).
    WheelWhite,
    /// Common-mode coloured wheel error (η_1).
    WheelCommon,
    /// Per-wheel coloured error (η_2).
    WheelDifferential,
    /// White reference-position noise (η_3; the heading has its own scale, η_5).
    PoseWhite,
    /// Reference-pose drift, position and heading (η_4).
    PoseDrift,
    /// White reference-heading noise (η_5). Its own scale because a
    /// reference's heading and position noise come from different sensors:
    /// tied to the position scale, a wrong starting ratio biased t_r
    /// (docs/study.md, EIV section).
    HeadingWhite,
}

impl NoiseSource {
    /// The source's name: `wheel_white`, `wheel_common`,
    /// `wheel_differential`, `pose_white`, `pose_drift`, `heading_white`.
    pub fn name(self) -> &'static str {
        match self {
            NoiseSource::WheelWhite => "wheel_white",
            NoiseSource::WheelCommon => "wheel_common",
            NoiseSource::WheelDifferential => "wheel_differential",
            NoiseSource::PoseWhite => "pose_white",
            NoiseSource::PoseDrift => "pose_drift",
            NoiseSource::HeadingWhite => "heading_white",
        }
    }

    /// The source's index in η ([`NOISE_SOURCES`] order, as
    /// [`EivOptions::eta_held`]): the declaration order.
    pub fn index(self) -> usize {
        self as usize
    }
}

impl std::fmt::Display for NoiseSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for NoiseSource {
    type Err = Error;
    /// A source by its [`NoiseSource::name`] (`-` for `_` accepted, as on
    /// the command line).
    ///
    /// ```
    /// use odocal::eiv::NoiseSource;
    /// assert_eq!("heading-white".parse::<NoiseSource>().unwrap(), NoiseSource::HeadingWhite);
    /// assert!("heading".parse::<NoiseSource>().is_err());
    /// ```
    fn from_str(s: &str) -> Result<Self> {
        let name = s.trim().to_ascii_lowercase().replace('-', "_");
        NOISE_SOURCES.into_iter().find(|x| x.name() == name).ok_or_else(|| Error::Parse {
            what: "noise source",
            input: s.to_string(),
            expected: "wheel_white, wheel_common, wheel_differential, pose_white, pose_drift or heading_white",
        })
    }
}

/// The sources in η order.
pub const NOISE_SOURCES: [NoiseSource; 6] = [
    NoiseSource::WheelWhite,
    NoiseSource::WheelCommon,
    NoiseSource::WheelDifferential,
    NoiseSource::PoseWhite,
    NoiseSource::PoseDrift,
    NoiseSource::HeadingWhite,
];

impl NoiseModel {
    /// Defaults for a production car: about 1 % relative wheel-rotation
    /// error on the CAN bus and a GNSS/INS reference good to decimetres.
    pub const PRODUCTION_CAR: NoiseModel = NoiseModel {
        wheel_white_rel_sigma: 0.008,
        quantisation_step_rev_per_s: 0.02,
        wheel_common_rel_sigma: 0.002,
        wheel_common_time_constant_s: 2.0,
        wheel_differential_rel_sigma: 0.0005,
        wheel_differential_time_constant_s: 0.25,
        position_white_sigma_m: 0.02,
        heading_white_sigma_rad: 0.0005,
        position_drift_sigma_m: 0.25,
        heading_drift_sigma_rad: 0.003,
        drift_time_constant_s: 100.0,
        lateral_acceleration_sigma_m_per_s2: 0.05,
        sideslip_sigma_rad: 0.002,
        sideslip_time_constant_s: 1.0,
    };

    /// The noise model that matches a simulator setting (the "true noise
    /// model" for [`cramer_rao_bound`]). Slip is not represented (it is
    /// absorbed by the common-mode error); the drift time constant is the
    /// position drift's.
    pub fn from_sim(n: &crate::sim::NoiseOptions, sample_time_s: f64) -> Self {
        let ticks = f64::from(n.encoder_ticks_per_revolution);
        NoiseModel {
            wheel_white_rel_sigma: n.wheel_white_rel_sigma,
            quantisation_step_rev_per_s: if ticks > 0.0 { 1.0 / (ticks * sample_time_s) } else { 0.0 },
            wheel_common_rel_sigma: n.wheel_coloured_rel_sigma,
            wheel_common_time_constant_s: n.wheel_coloured_time_constant_s,
            wheel_differential_rel_sigma: n.wheel_coloured_differential_rel_sigma,
            wheel_differential_time_constant_s: n.wheel_coloured_time_constant_s,
            position_white_sigma_m: n.position_white_sigma_m,
            heading_white_sigma_rad: n.heading_white_sigma_rad,
            position_drift_sigma_m: n.position_drift_sigma_m,
            heading_drift_sigma_rad: n.heading_drift_sigma_rad,
            drift_time_constant_s: n.position_drift_time_constant_s,
            lateral_acceleration_sigma_m_per_s2: n.lateral_acceleration_white_sigma_m_per_s2,
            sideslip_sigma_rad: n.sideslip_sigma_rad,
            sideslip_time_constant_s: n.sideslip_time_constant_s,
        }
    }

    /// The model with each group's standard deviations multiplied by
    /// `exp(η_j/2)` (variances by `exp(η_j)`).
    pub fn scaled(&self, eta: &[f64; 6]) -> Self {
        let f: [f64; 6] = std::array::from_fn(|j| (0.5 * eta[j]).exp());
        NoiseModel {
            wheel_white_rel_sigma: self.wheel_white_rel_sigma * f[0],
            quantisation_step_rev_per_s: self.quantisation_step_rev_per_s * f[0],
            lateral_acceleration_sigma_m_per_s2: self.lateral_acceleration_sigma_m_per_s2 * f[0],
            sideslip_sigma_rad: self.sideslip_sigma_rad * f[0],
            wheel_common_rel_sigma: self.wheel_common_rel_sigma * f[1],
            wheel_differential_rel_sigma: self.wheel_differential_rel_sigma * f[2],
            position_white_sigma_m: self.position_white_sigma_m * f[3],
            heading_white_sigma_rad: self.heading_white_sigma_rad * f[5],
            position_drift_sigma_m: self.position_drift_sigma_m * f[4],
            heading_drift_sigma_rad: self.heading_drift_sigma_rad * f[4],
            ..*self
        }
    }

    /// Checks the model, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        let sig = [
            ("noise.wheel_white_rel_sigma", self.wheel_white_rel_sigma),
            ("noise.quantisation_step_rev_per_s", self.quantisation_step_rev_per_s),
            ("noise.wheel_common_rel_sigma", self.wheel_common_rel_sigma),
            ("noise.wheel_differential_rel_sigma", self.wheel_differential_rel_sigma),
            ("noise.position_white_sigma_m", self.position_white_sigma_m),
            ("noise.heading_white_sigma_rad", self.heading_white_sigma_rad),
            ("noise.position_drift_sigma_m", self.position_drift_sigma_m),
            ("noise.heading_drift_sigma_rad", self.heading_drift_sigma_rad),
            ("noise.lateral_acceleration_sigma_m_per_s2", self.lateral_acceleration_sigma_m_per_s2),
            ("noise.sideslip_sigma_rad", self.sideslip_sigma_rad),
        ];
        for (field, v) in sig {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::InvalidOption { field, reason: format!("must be finite and >= 0, got {v}") });
            }
        }
        for (field, v) in [
            ("noise.wheel_common_time_constant_s", self.wheel_common_time_constant_s),
            ("noise.wheel_differential_time_constant_s", self.wheel_differential_time_constant_s),
            ("noise.drift_time_constant_s", self.drift_time_constant_s),
            ("noise.sideslip_time_constant_s", self.sideslip_time_constant_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidOption { field, reason: format!("must be positive, got {v}") });
            }
        }
        Ok(())
    }

    /// Per-sample filter variances of this model scaled by `exp(η)`.
    pub(crate) fn variances(&self, eta: &[f64; 6], ts: f64) -> Variances {
        let e: [f64; 6] = std::array::from_fn(|j| eta[j].exp());
        let gm = |tau: f64| (-ts / tau).exp();
        let a_beta = gm(self.sideslip_time_constant_s);
        let sq = |x: f64| x * x;
        Variances {
            white_rel: sq(self.wheel_white_rel_sigma) * e[0],
            quant: sq(self.quantisation_step_rev_per_s) / 12.0 * e[0],
            common: sq(self.wheel_common_rel_sigma) * e[1],
            wheel: sq(self.wheel_differential_rel_sigma) * e[2],
            pose: [
                sq(self.position_white_sigma_m) * e[3],
                sq(self.position_white_sigma_m) * e[3],
                // η_5 when the heading has its own scale (see `Problem::evaluate`).
                sq(self.heading_white_sigma_rad) * e[5],
            ],
            drift: [
                sq(self.position_drift_sigma_m) * e[4],
                sq(self.position_drift_sigma_m) * e[4],
                sq(self.heading_drift_sigma_rad) * e[4],
            ],
            a_y: sq(self.lateral_acceleration_sigma_m_per_s2) * e[0],
            beta: sq(self.sideslip_sigma_rad) * e[0],
            beta_white: 0.0,
            a_common: gm(self.wheel_common_time_constant_s),
            a_wheel: gm(self.wheel_differential_time_constant_s),
            a_drift: gm(self.drift_time_constant_s),
            a_beta,
            quant_scaled: true,
            lateral_scaled: true,
            quant_in_measurement: false,
            quant_counting: false,
            heading_separate: true,
            fitted_input: false,
            input_jacobian: InputJacobian::None,
            noise_input_half_width: 0,
            noise_input_from_reference: false,
            position_floor_m: DEFAULT_POSITION_FLOOR_M,
            null_without_floors: false,
        }
    }
}

/// One of the four calibrated parameters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Parameter {
    /// c_e.
    #[serde(rename = "c_e")]
    CE,
    /// c_d.
    #[serde(rename = "c_d")]
    CD,
    /// t_r.
    #[serde(rename = "t_r")]
    TR,
    /// d.
    #[serde(rename = "d")]
    D,
}

/// The parameters in θ order.
pub const PARAMETERS: [Parameter; 4] = [Parameter::CE, Parameter::CD, Parameter::TR, Parameter::D];

impl std::fmt::Display for Parameter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let i = PARAMETERS.iter().position(|p| p == self).unwrap_or(0);
        f.write_str(crate::model::THETA_NAMES[i])
    }
}

/// How the filter's covariance recursion (P, S, K) depends on θ.
///
/// SPEC §10 asks for both the profile cost `½ Σ νᵀS(θ)⁻¹ν` with S depending
/// on θ through `F_n Σ_n F_nᵀ` and for Q held at a reference θ; the two
/// differ exactly in whether `∂S/∂θ` is zero. See the module docs for the
/// measured consequences.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CovarianceMode {
    /// The covariance recursion is linearised at a reference θ (batch G-N's
    /// result, then each pass's result): `∂S/∂θ = 0` and θ solves the
    /// corrected score of the module docs.
    HeldAtReference,
    /// The covariance recursion is evaluated at θ: S depends on θ, `∂P/∂θ`
    /// is propagated exactly, and θ minimises the profile (joint-MAP over
    /// the latent true inputs; Deming / total least squares) cost.
    FollowsTheta,
}

/// The covariance of θ reported by [`estimate`] ([`EivReport::covariance`],
/// [`EivReport::sigma`]) and used by the halves check.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CovarianceEstimate {
    /// `H_θ⁻¹`, the inverse of the scoring metric at the fitted noise model:
    /// right when the noise model is (the fitted scales of the right
    /// processes). Stop 13 (`coloured` preset, η estimated from the
    /// production-car model, whose common-mode wheel noise has τ_c = 2 s
    /// against the simulator's 5 s): c_e's σ was 0.0062 % against an actual
    /// spread of 0.023 % (coverage 35 %), so the halves check rejected 7 of
    /// 20 good fits. Where the model is right the two agree (the
    /// simulator's noise model given: mean σ 0.0194 % against the block
    /// sandwich's 0.0197 %). The default until stop 13.
    Model,
    /// The default (since stop 13).
    /// Per parameter the larger of the `H_θ⁻¹` σ and the block sandwich σ
    /// ([`EivReport::sigma_block`]): `C = D H_θ⁻¹ D` with
    /// `D = diag(max(1, σ_block,i/σ_i))`, so the correlations are the
    /// model's. The block sandwich sums the per-update θ-scores over 20 s
    /// blocks (several correlation times of the wheel noise) and so stays
    /// honest when the noise model's time constants are wrong; the larger
    /// of the two keeps the model's σ where the blocks are few (a short
    /// drive) and their estimate noisy. Measured (docs/study.md "Stop 13";
    /// 12 km, seeds 1–20): `coloured` c_e coverage 35 → 90 %, halves
    /// fallbacks 7 → 0, what a user gets c_e 2.82× → 1.62× the Cramér–Rao
    /// bound; `white` identical; on `paper` the halves check no longer
    /// rejects two fits with t_r +4.7 and +3.9 % (it measures spread, not
    /// bias).
    #[default]
    LargerOfModelAndBlock,
}

/// Options of the EIV calibration. Defaults follow SPEC §10.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EivOptions {
    /// Filter window length, samples (each part is cut into windows of about
    /// this length). Default 6000 (150 s at 40 Hz).
    pub window_samples: usize,
    /// Fisher-scoring iterations per pass. Default 20 (10 until stop 19: a
    /// test-track run then stopped at the limit with a last step of 0.25σ and
    /// fell back; it converges in 12; the simulated studies converge in ≤ 10).
    pub max_iterations: usize,
    /// Stop when `max |step_i|/σ_i` (free θ and η not at a clamp) is below
    /// this. Default 0.05.
    pub step_tolerance: f64,
    /// Step halvings tried before giving up on an iteration. Default 10.
    pub max_halvings: usize,
    /// Damp the η step of the θ/η iteration by a secant estimate of its
    /// overshoot (with the covariance following θ and η estimated). Default
    /// true (stop 12; see the measurements at `secant_eta_factor` in the
    /// source and docs/study.md "Stop 12").
    pub eta_secant_damping: bool,
    /// Score-test level at which a noise scale at its lower clamp re-enters
    /// the fit: the source leaves the clamp when the score test of its scale
    /// against the data, `g²/I` (g = ∂M/∂η, I its Fisher information, both
    /// at the clamp), exceeds this and g < 0 (more of that noise lowers M).
    /// `None` = never: a scale that reached the clamp stays there (the
    /// stop-12 behaviour: at the clamp its information is ~e⁻⁴⁰ of the
    /// others' and it read as "no information"). Default `None`.
    ///
    /// Measured (docs/study.md "Stop 13"; `coloured` preset, 12 km, seeds
    /// 1–20): the production-car model's common-mode scale η₁ ended at the
    /// clamp on 16 of 20 drives; re-entered (level 10), the fits' M was
    /// 508–738 lower (seeds 2–6), but η₁ climbs back by about +3 per
    /// iteration and 14 of 20 fits hit the 10-iteration limit (2 of 20 on
    /// `white`), so it is not the default; c_e's σ stays too small with it
    /// (coverage 55 %: the production car's τ_c is wrong, see
    /// [`CovarianceEstimate::LargerOfModelAndBlock`]).
    pub eta_reentry_min_score: Option<f64>,
    /// Which covariance of θ the report carries (`covariance`, `sigma`) and
    /// the halves check uses. Default
    /// [`CovarianceEstimate::LargerOfModelAndBlock`] since stop 13
    /// ([`CovarianceEstimate::Model`] restores the earlier σ; see both for
    /// the stop-13 measurements).
    pub covariance_estimate: CovarianceEstimate,
    /// Add to θ's reported covariance what estimating the noise scales η
    /// from the same drive adds to it (stop 16): `A Σ_η Aᵀ` with
    /// `A = ∂θ̂/∂η = −J⁻¹ ∂g_θ/∂η` (implicit function theorem at the
    /// estimate; `g_θ` the θ-score, `J = ∂g_θ/∂θ`) and `Σ_η` the inverse of
    /// η's information over the estimated scales. Both derivatives are
    /// forward differences (1 % of σ) in θ of exact filter derivatives: J of
    /// the θ-score, `∂g_θ/∂η` of the η-gradient of the profile cost (the
    /// mixed partials are symmetric; the FilterShare log-Jacobian weights'
    /// own η-dependence is summed exactly by the filter), so one more filter
    /// pass with θ and η derivatives per free parameter (since stop 24;
    /// before, and still with the smoothed-share weights or the covariance
    /// held, one more pass per estimated scale too, displaced by
    /// [`ETA_SENSITIVITY_STEP`] in η), instead of a second-order sensitivity
    /// recursion through the filter.
    /// `A` is [`EivReport::theta_eta_sensitivity`], the added σ
    /// [`EivReport::sigma_noise_estimate`]. No effect with
    /// [`EivOptions::fix_noise`].
    ///
    /// Why: on the `high` preset t_r moves by ≈ 7–15 % per unit of the
    /// heading white-noise scale η_5, whose own σ there is 0.04–0.12, so
    /// the σ at a fixed η understated t_r's by up to 1.8×. Measured in
    /// docs/study.md "Stop 16". Default true.
    pub noise_estimate_in_covariance: bool,
    /// Judge convergence of the θ/η iteration by what the user gets, θ:
    /// also stop when θ's remaining scoring step is below
    /// [`EivOptions::step_tolerance`]·σ_θ *and* so is the θ change that the
    /// remaining η step would cause through the joint information,
    /// `dθ ≈ −I_θθ⁻¹ I_θη dη` (η wandering that does not move θ is no reason
    /// to distrust θ). The remaining η step is reported in
    /// [`PassReport::eta_step_over_sigma`]. Default false (stop 13; see
    /// docs/study.md "Stop 13: convergence of the η iteration").
    pub theta_convergence: bool,
    /// Test convergence at the end of each iteration on the step that
    /// *remains* at the new point (θ and η, the usual
    /// [`EivOptions::step_tolerance`] test; no extra filter evaluation: the
    /// point is already evaluated in full) instead of only on the steps just
    /// taken, so the last iteration of [`EivOptions::max_iterations`] can
    /// end converged. With the covariance following θ and η estimated.
    /// Default true since stop 13 (on `white` with the separate heading scale
    /// every `not_converged` fit had a remaining step of 0.001–0.002 σ; the
    /// option changed no θ on 80 simulated fits).
    pub final_step_check: bool,
    /// Passes, each with the covariance reference θ at the previous result.
    /// Default 2.
    pub passes: usize,
    /// Which parameters are estimated (`[c_e, c_d, t_r, d]`). Default all.
    pub free: [bool; 4],
    /// Hold parameters that the data cannot determine (σ above their
    /// resolution at the start) at their starting value and name them.
    /// Default true.
    pub fix_unobservable: bool,
    /// The starting noise model. Default [`NoiseModel::PRODUCTION_CAR`].
    pub noise: NoiseModel,
    /// Use [`EivOptions::noise`] as is (do not estimate η). Default false.
    pub fix_noise: bool,
    /// Clamp range of the log-scale factors η. Default [−20, 6]: variances
    /// between 2e-9 and 400 times the starting model's.
    pub eta_bounds: [f64; 2],
    /// Noise sources (in [`NOISE_SOURCES`] order) whose level is *known*:
    /// their scale is held at the starting model (η_j = 0) while the others
    /// are estimated; ignored with [`EivOptions::fix_noise`]. Set it from a
    /// datasheet (e.g. the INS's heading σ) with [`EivOptions::hold_known`],
    /// `--known-noise`, or a noise model's `known = [...]`. Measured (stop
    /// 14, 20 × 12 km, `high`): holding the heading white noise at its true
    /// σ took t_r's bias from +1.50 % to +0.54 %. A wrong stated level biases
    /// instead. Default none.
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
    /// window, beyond the interval that [`EivOptions::innovation_null`]
    /// allows. Default 0.5.
    pub max_lag1: f64,
    /// With [`InnovationNull::FloorsAsRegularisation`]: largest acceptable
    /// lag-1 autocorrelation *below* the interval that the null allows
    /// (`min(0, ρ₀) − lag-1`). Default 0.2 (stop 12). Negative correlation
    /// is what a filter shows when the data have measurement noise the
    /// model lacks (it follows the noise and corrects back); the floors and
    /// surplus process noise only lag the filter behind the measurements
    /// (positive correlation). Measured (docs/study.md "Stop 12"): heading
    /// lag-1 of good fits on the simulated presets ≥ −0.15; on the six
    /// test-track runs (heading white noise held near zero by the tied
    /// scale) −0.26 … −0.45, where EIV loses to batch G-N.
    pub max_lag1_below: f64,
    /// What the innovation checks (NIS band, whiteness) take as consistent.
    /// Default [`InnovationNull::FloorsAsRegularisation`] (stop 12; see its
    /// docs for the measurements).
    pub innovation_null: InnovationNull,
    /// Largest acceptable |z| of the difference between θ from the two
    /// halves of the windows. Default 4.
    pub max_half_z: f64,
    /// How the covariance recursion depends on θ. Default
    /// [`CovarianceMode::FollowsTheta`].
    pub covariance: CovarianceMode,
    /// How encoder quantisation enters the filter. Default
    /// [`QuantisationModel::Counting`] since stop 14 (see its docs for the
    /// measured trade-off).
    pub quantisation: QuantisationModel,
    /// Whether η_0 scales the encoder quantisation with the white wheel
    /// noise or the quantisation step is taken as known. Default
    /// [`QuantisationLevel::FromReadings`] since stop 14 (see its docs).
    pub quantisation_level: QuantisationLevel,
    /// Whether η_0 scales the a_y and β noise with the white wheel noise or
    /// they are held at the noise model's σ. Default
    /// [`LateralNoise::TiedToWheelWhite`] (see its docs for the measured
    /// trade-off).
    pub lateral_noise: LateralNoise,
    /// How the filter models the error of the measured sideslip β. Default
    /// [`SideslipNoise::GaussMarkovState`] since stop 19 (see its docs).
    pub sideslip_noise: SideslipNoise,
    /// Whether the reference's heading white noise has its own scale η_5.
    /// Default [`HeadingScale::Separate`] since stop 14 (see its docs).
    pub heading_scale: HeadingScale,
    /// Which wheel rotation scales the relative wheel noise in the
    /// covariance. Default [`WheelNoiseScale::MeasuredInput`] (see its docs
    /// for the measured alternatives).
    pub wheel_noise_scale: WheelNoiseScale,
    /// Correction of the profile cost's bias applied to the estimate.
    /// Default [`BiasCorrection::None`] (see its docs).
    pub bias_correction: BiasCorrection,
    /// The true inputs of the replicate worlds of
    /// [`BiasCorrection::Bootstrap`]. Default [`BootstrapInputs::Measured`];
    /// `Smoothed { half_width_samples: 20 }` removed the t_r bias on `high`
    /// (stop 14, docs/study.md "the remaining t_r bias on high").
    pub bootstrap_inputs: BootstrapInputs,
    /// The noise model of the replicates of [`BiasCorrection::Bootstrap`].
    /// Default [`BootstrapNoise::HeldAtFit`] (since stop 20; before, the
    /// replicates re-estimated the noise: the same c_e correction at three
    /// times the cost, and an over-correction of t_r).
    pub bootstrap_noise: BootstrapNoise,
    /// The replicates of [`BiasCorrection::Bootstrap`] come in antithetic
    /// pairs ([`BootstrapOptions::antithetic`]; B must be even). Default
    /// false; [`EivOptions::correct_bias`] sets it.
    pub bootstrap_antithetic: bool,
    /// Floor of the reference's position noise σ in the filter's `R`, m
    /// (added in quadrature to the noise model's position white noise; it is
    /// not scaled by η). Default 1e-3 (SPEC §10).
    ///
    /// Measured (docs/study.md, EIV section, "t_r under large white wheel
    /// noise"; 12 km, seeds 1–20, the simulator's noise model fixed): on a
    /// perfect reference with 2 % white wheel noise the 1 mm floor leaves
    /// t_r +2.90 ± 1.56 % (bias t 8.3) and d −0.58 (t 8.2); with 5 mm,
    /// t_r +0.23 ± 0.61 % (t 1.7) and d −0.04 (t 1.0), as the filter-free
    /// heading-channel Deming estimator on the same drives (+0.22 ± 0.58 %).
    /// The wheel noise is rank 2 in the 3-dof pose, so on a near-perfect
    /// position reference one direction of the innovation is known to the
    /// floor and the filter carries it from step to step (windows of 10
    /// samples remove the bias too). On the `coloured` preset 5 mm also
    /// lowers the c_e bias (+0.098 → +0.047 %); where the reference has
    /// centimetres of position noise (`paper`, `high`) the floor changes
    /// nothing.
    pub position_floor_m: f64,
    /// Values at which parameters that the filter names unobservable (with
    /// [`EivOptions::fix_unobservable`]) are held. `None` (the default)
    /// holds them at the start θ given to [`estimate`]. `calibrate` passes
    /// the calibration's θ_0: the start is batch G-N's estimate, which for
    /// a parameter the data cannot determine can be far off (on the RAV4
    /// drive, t_r = 5.63 m, so the result was rejected as implausible).
    pub hold_unobservable_at: Option<Theta>,
    /// Estimate the Gauss-Markov time constants (wheel τ_c, τ_w and the
    /// reference drift τ) with the noise scales, by a profile of the
    /// marginal likelihood over [`EivOptions::time_constant_grid`] (one fit
    /// per candidate; [`TimeConstantGrid`] has the method and its cost).
    /// The chosen values replace the starting model's in
    /// [`EivReport::noise`]. Default false (the time constants of
    /// [`EivOptions::noise`] are used as given).
    ///
    /// Measured (docs/study.md, EIV section; 12 km, η estimated from the
    /// production-car model): it does **not** help. Paper noise, separate
    /// heading scale, 20 seeds: t_r +0.87 ± 0.37 % against +0.83 ± 0.36 %
    /// without it and +0.85 ± 0.38 % with the simulator's τ given (known
    /// noise model: +0.39 ± 0.30 %); high noise (5 seeds) +22.9 % against
    /// +17.4 %; on a perfect reference (coloured preset) the likelihood
    /// prefers a degenerate τ_wheel → 0.06 s with t_r +40 … +70 % (flagged;
    /// the fallback returns batch G-N). About 4.5–7.5× the wall time of a fit.
    /// Kept as an opt-in diagnostic.
    pub estimate_time_constants: bool,
    /// Candidates of the time-constant search (used only with
    /// [`EivOptions::estimate_time_constants`]).
    pub time_constant_grid: TimeConstantGrid,
    /// Log-Jacobian term of the relative white wheel noise added to the θ
    /// cost. Default [`InputJacobian::None`] (see its docs).
    pub input_jacobian: InputJacobian,
}

/// A log-Jacobian term `−Σ_k Σ_w u_w,k·ln(C_w,k(θ)/C_w,k(θ_ref))` added to
/// the profile cost J of θ (issue 9 item 4: the c_e bias), with C_w,k the
/// wheel circumference at sample k (3a, 3b; θ_ref the start of the fit) and
/// weights u ≥ 0 per wheel and sample. Not part of the marginal likelihood
/// M of the η step. Meant with [`WheelNoiseScale::FittedInput`].
///
/// Why. A scalar model with exact increments `Δ_k = c·n_k·t_s` and relative
/// white input noise `ñ_k = n_k(1 + ε_k)` has the exact negative
/// log-likelihood `½Σ(c/r_k − 1)²/σ² − N·ln c` (r_k = Δ_k/(ñ_k t_s); the
/// `−N ln c` is the log-Jacobian of the density of ñ at the latent
/// `n = Δ/(c t_s)`), whose score has zero mean at the true c. The
/// fitted-input filter has the quadratic part (attenuation `−σ²` without
/// the Jacobian). With a noisy reference the latent input is only partly
/// determined by the data: in a linear Gaussian model `y = A(θ)ñ − A(θ)e + v`
/// the expected score of the quadratic part at the truth is
/// `Σ_w (∂ln C_w/∂θ)·tr(S⁻¹ A_w Σ_e,w A_wᵀ)`, and
/// `tr(S⁻¹ A_w Σ_e,w A_wᵀ) = Σ_j (1 − posterior/prior variance of e_j)`
/// over wheel w's inputs (the smoothed share of each input's noise that
/// the data remove) `= ∂(Σ_k ln det S_k)/∂λ_w`, λ_w scaling wheel w's
/// white relative noise variance. So the weight that makes the score
/// unbiased (to first order in the noise variance) is that share, 1 only
/// where the increments are exact. That holds only when S does not depend
/// on the noise: [`WheelNoiseScale::FittedInput`] scales the noise by the
/// *measured* rotation (its own c_e bias is `+σ²` on white noise, not
/// `−σ²`), so use [`WheelNoiseScale::SmoothedFittedInput`].
///
/// Measured (`examples/study_eiv.rs`, 12 km, seeds 1–20, known noise; c_e
/// error mean, bias t, RMS/CRB; docs/study.md "The c_e bias" has the rest):
///
/// | variant | white | coloured | paper | high |
/// |---|---|---|---|---|
/// | none (measured input) | +0.0099 %, t 16, 3.7× | +0.098 %, t 17, 5.3× | +0.087 %, t 14, 3.8× | +0.55 %, t 35, 9.4× |
/// | `SmoothedFittedInput` (±20) + `SmoothedShare` | +0.0006 %, t 0.9, 0.97× | +0.078 %, t 14, 4.3× | +0.011 %, t 1.7, 1.28× | +0.035 %, t 2.0, 1.39× |
/// | `SmoothedFittedInput` (±20) + `FilterShare` | +0.0004 %, t 0.7, 0.96× | +0.072 %, t 13, 4.0× | +0.010 %, t 1.6, 1.27× | +0.030 %, t 1.8, 1.35× |
/// | `FittedInput` + `Unit` | +0.012 %, t 19 | +0.185 %, t 35 | +0.33 %, t 52 | +2.1 %, t 103 |
///
/// t_r, c_d, d unchanged within their spread. Not a default: the coloured
/// preset (perfect reference) keeps +0.07 %.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputJacobian {
    /// No term.
    #[default]
    None,
    /// u = 1 where the wheel turns (the scalar model's exact-increment weight).
    Unit,
    /// u = the share of the sample's white relative noise removed by the next
    /// measurement update, `σ²n̂_w²·f_wᵀS⁻¹f_w` (f_w = ∂f/∂n_w, pose rows;
    /// filtered, a lower bound of the smoothed share).
    FilterShare,
    /// u = w(1 − 2w) with w the filtered share of [`InputJacobian::FilterShare`]:
    /// the filter's wheel variance `σ²n̂²` is proportional to the *measured*
    /// rotation, so `S⁻¹` is correlated with the noise it weights; to second
    /// order that adds `−2w²` per sample to the expected score (scalar model
    /// with exact increments: w = 1, bias `+σ²` instead of `−σ²`).
    FilterShareSecondOrder,
    /// u = the smoothed share per window and wheel,
    /// `W_w = Σ_k tr(S_k⁻¹ ∂S_k/∂λ_w)` (two more covariance-derivative
    /// recursions), spread evenly over the window's samples where the wheel
    /// turns. The weights are held constant in the derivatives.
    SmoothedShare,
    /// As [`InputJacobian::SmoothedShare`] over all the relative wheel
    /// noise: λ_w scales wheel w's white and per-wheel Gauss-Markov
    /// variance, and half of the common Gauss-Markov share goes to each
    /// wheel (three more recursions). It **replaces** the coloured-noise
    /// correction `−Σ m log(1 − ŝ)` in J (that term is about the filtered
    /// share of the Gauss-Markov noise; M keeps it).
    SmoothedShareAll,
}

/// The null hypothesis of the per-window innovation checks
/// ([`EivOptions::innovation_null`]).
///
/// The measurement floors of `R` ([`EivOptions::position_floor_m`], 1e-5
/// rad on the heading) are regularisation: on a perfect reference the data
/// have no noise at that level, so a filter whose `R` contains the floor
/// does not fully follow the measurements, and its innovations are
/// correlated and smaller than `S` by construction (measured on the
/// `white` preset, 12 km, seed 1: X/Y lag-1 0.63–0.78, NIS/dof 0.50–0.62
/// in every window of a fit within 0.5 % of θ_true). Such windows are not
/// misspecified: their statistics are what the fitted model without the
/// floors predicts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InnovationNull {
    /// The model as fitted, floors included: white innovations (lag-1 0)
    /// and NIS/dof 1. The checks before stop 12.
    FittedModel,
    /// The real noise below the floors is anywhere between none and the
    /// floor: one more filter pass at the estimate propagates the error
    /// covariance of the filter (its gain unchanged) when the data have the
    /// fitted noise without the floors, giving per window the expected
    /// lag-1 autocorrelation ρ₀ and NIS/dof n₀ of the whitened innovations.
    /// A window is flagged when its lag-1 is more than
    /// [`EivOptions::max_lag1`] above `max(0, ρ₀)` or more than
    /// [`EivOptions::max_lag1_below`] below `min(0, ρ₀)`, or its
    /// NIS/dof outside `[lo·min(1, n₀), hi·max(1, n₀)]` (`[lo, hi]` =
    /// [`EivOptions::nis_band`]). Where the reference has noise well above
    /// the floors (real logs, the `paper` preset), ρ₀ ≈ 0 and n₀ ≈ 1 and
    /// the checks are those of [`InnovationNull::FittedModel`].
    FloorsAsRegularisation,
}

/// Default of [`EivOptions::position_floor_m`], m (stop 11; SPEC §10
/// states 1 mm, [`SPEC_POSITION_FLOOR_M`]).
pub const DEFAULT_POSITION_FLOOR_M: f64 = 5e-3;

/// The position σ floor of SPEC §10, m (the default before stop 11).
pub const SPEC_POSITION_FLOOR_M: f64 = 1e-3;

/// Which wheel rotation the relative wheel noise (white and Gauss-Markov)
/// is proportional to in the filter's covariance (issue 9 item 4).
///
/// With the covariance following θ the noise in metres is `C(θ)·ñ·σ`: it
/// grows with the wheel circumference, and the profile cost, which has no
/// `log det S`, lowers its weighted residuals by a larger c_e (about `+2σ²`
/// for white noise in a scalar model). The simulator's (and a real wheel's)
/// relative error is proportional to the *true* rotation; the true rotation
/// fitted at θ is `n̂ = ñ·C(θ_ref)/C(θ)` (the distance `ñ·C(θ_ref)` held at
/// the covariance reference), which makes the wheel noise in metres
/// independent of the circumferences (but not of t_r).
///
/// Measured (12 km, 20 seeds, known noise; [`BiasCorrection`] has the
/// table): the c_e bias flips sign, coloured +0.098 → −0.112 %, paper
/// +0.087 → −0.131 % (t ≈ 20), as a scalar model predicts (`+2σ²` with the
/// measured input, `−σ²`, attenuation, with the fitted one); t_r, c_d, d
/// are unchanged within their spread. Opt-in, not a cure.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WheelNoiseScale {
    /// σ·ñ, the measured rotation (SPEC §10).
    #[default]
    MeasuredInput,
    /// σ·n̂, `n̂ = ñ·C(θ_ref)/C(θ)` (only with [`CovarianceMode::FollowsTheta`];
    /// θ_ref is the start of the fit, batch G-N's θ). Encoder quantisation
    /// (an absolute count error) is not rescaled.
    FittedInput,
    /// As [`WheelNoiseScale::FittedInput`], with ñ replaced by its moving
    /// average over ±`half_width_samples` (within the filter window) in the
    /// noise scale and the s-columns of the covariance transition (the mean
    /// still uses ñ). With ñ itself the filter's variance `σ²ñ_k²` is
    /// correlated with the error ε_k it weights (the +σ² of a scalar model
    /// with exact increments); the average is nearly independent of ε_k.
    SmoothedFittedInput {
        /// Half-width K of the moving average, samples (at least 1).
        half_width_samples: usize,
    },
    /// As [`WheelNoiseScale::FittedInput`], with the rotation scaling the
    /// relative noise (and the s-columns of the covariance transition) taken
    /// from the reference: speed and yaw rate by central differences over
    /// ±`half_width_samples` at θ_ref (`C_l n_l = v − ψ̇ t_r/2`,
    /// `C_r n_r = v + ψ̇ t_r/2`, rev/s), so the scale is independent of both the
    /// white and the Gauss-Markov wheel errors.
    ReferenceInput {
        /// Half-width K of the central difference, samples (at least 1).
        half_width_samples: usize,
    },
}

impl WheelNoiseScale {
    /// Half-width of the moving average (0 without smoothing).
    fn half_width(&self) -> usize {
        match self {
            WheelNoiseScale::SmoothedFittedInput { half_width_samples }
            | WheelNoiseScale::ReferenceInput { half_width_samples } => *half_width_samples,
            _ => 0,
        }
    }
}

/// A correction of the estimator's own bias applied to the estimate
/// (issue 9 item 4).
///
/// Until stop 19 its target was a c_e bias of about +0.1 % under coloured
/// wheel noise, which the bootstrap removed on every preset (the known
/// noise model fixed, 12 km, 20 seeds, B = 10: c_e t 14–35 → 0.5–0.8; the
/// analytic first-order correction, [`FirstOrderBias`], failed).
/// Since the sideslip error is a filter state (stop 19) the default fit has
/// no c_e bias left; what remains under heavy wheel noise is t_r's and d's.
/// Measured (stop 20, `examples/study_eiv.rs --km 12 --seeds 20 --methods
/// est --bootstrap 10 --bootstrap-smooth 20`, η estimated, every parameter
/// corrected, replicates on the smoothed trajectory holding the fitted noise
/// model, [`BootstrapNoise::HeldAtFit`]; mean error (t), coverage of the 95 %
/// interval over the four parameters):
///
/// | preset | t_r uncorrected | t_r corrected | d corrected | largest \|t\| | coverage |
/// |---|---|---|---|---|---|
/// | high | +1.097 % (4.5) | +0.531 % (1.9) | −0.083 (1.3) | 1.9 | 86.3 → 95.0 % |
/// | paper | +0.220 % (3.1) | +0.211 % (2.6) | −0.033 (1.8) | 2.6 | 96.3 → 93.8 % |
/// | white | +0.073 % (1.3) | +0.059 % (1.0) | +0.002 (0.1) | 1.0 | 97.5 → 97.5 % |
/// | coloured | +0.093 % (1.7) | +0.095 % (1.4) | −0.010 (0.6) | 1.4 | 93.8 → 92.5 % |
///
/// That correction (stop 20) added Monte Carlo noise: the corrected t_r
/// was more spread (RMS/CRB on paper 1.69 → 1.82) and fresh-drive Ē_p 1–4
/// cm worse. Since stop 21 the replicates come in antithetic pairs
/// ([`EivOptions::bootstrap_antithetic`], set by
/// [`EivOptions::correct_bias`]), whose means cancel the replicates' odd
/// error: with B = 4 the same bias is removed (high t_r +0.458 %, t 1.9;
/// largest |t| 2.8 on paper) and the RMS error falls (t_r on high 5.38 →
/// 4.01× the bound, paper 1.69 → 1.62×), coverage 93.8 / 96.3 / 97.5 /
/// 95.0 %. It is the EIV method's default in `calibrate`
/// (`calibrate::EivMethodOptions::correct_bias`, the CLI's `--correct-bias
/// B` / `--no-bias-correction`); [`estimate`] applies what this field says
/// (default none). The subtracted bias is a mean over the replicates (or
/// pairs); its Monte Carlo covariance is added to θ's
/// ([`EivReport::sigma_bias_correction`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BiasCorrection {
    /// The root of the profile cost as is.
    #[default]
    None,
    /// The parametric [`bootstrap`] bias (B re-simulations of the fitted
    /// noise at θ̂, each re-fitted without correction) subtracted:
    /// `θ̂ − (mean of the replicates − θ̂)`, for c_e only or for every free
    /// parameter. About B more fits.
    Bootstrap {
        /// Replicates B (at least 2).
        replicates: usize,
        /// Seed of the replicates' random streams.
        seed: u64,
        /// Correct every free parameter (otherwise c_e only).
        all_parameters: bool,
    },
}

/// Half-width of the moving average ([`BootstrapInputs::Smoothed`]) the
/// CLI's `--correct-bias` takes as the replicates' true inputs: ±20
/// samples, ±0.5 s at 40 Hz (stop 14 measured K = 20 only; with the
/// measured inputs as the truth the bootstrap finds no t_r bias).
pub const BIAS_BOOTSTRAP_SMOOTHING_SAMPLES: usize = 20;

/// The noise model the replicates of [`BiasCorrection::Bootstrap`] are
/// fitted with.
///
/// Measured (stop 20, docs/study.md; `study_eiv --km 12 --seeds 20
/// --methods est --bootstrap 10 --bootstrap-smooth 20`, η estimated, every
/// parameter corrected, replicates on the smoothed trajectory): t_r mean
/// error on `high` +1.097 % (t 4.5) uncorrected, +0.531 % (t 1.9) with
/// [`BootstrapNoise::HeldAtFit`], −0.676 % (t −2.4; d t 3.0) with
/// [`BootstrapNoise::Reestimated`], which over-corrects (its replicates, in
/// worlds made from the fitted noise model, shift t_r by 1.8 % where the
/// drive's own fit is off by 1.1 %) at three times the cost. c_e alone is
/// corrected the same either way (high +0.0146 and +0.0159 %, paper
/// +0.0052 % both).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BootstrapNoise {
    /// Every replicate is fitted with the fit's own options: the noise
    /// scales re-estimated when the fit estimated them (the only choice
    /// before stop 20).
    Reestimated,
    /// Every replicate holds the fitted noise model ([`EivReport::noise`],
    /// `fix_noise`): it estimates the bias of θ̂ at the fitted noise, about
    /// a third of the cost of re-estimating. The default.
    #[default]
    HeldAtFit,
}

/// The first-order bias of the profile cost's root at the estimate, a
/// diagnostic (measured as a correction in [`BiasCorrection`]'s table; it
/// is not one of its options because it failed); SI units, θ order
/// `[c_e, c_d, t_r, d]`.
///
/// The profile cost `J = ½Σ νᵀS⁻¹ν − Σ m log(1 − ŝ)` lacks the
/// `½ Σ log det S` of the Gaussian likelihood of the filter's own model
/// (whose θ-gradient is the Jacobian of the noise scale with θ: the wheel
/// noise in metres grows with the circumferences); the `−Σ m log(1 − ŝ)`
/// term stands in for it only for the part of the innovations the filter
/// gives to the coloured states ŝ. Under the filter's model, at the truth,
/// `E[∂J/∂θ] = −(g_logdet − g_corr)`, so the root of J is off by
/// `b = H_θ⁻¹ (g_logdet − g_corr)` to first order (H_θ the scoring metric
/// of J), computed from the last filter pass.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FirstOrderBias {
    /// `g_logdet = ∂(½ Σ log det S)/∂θ`.
    pub score_logdet: [f64; 4],
    /// `g_corr = ∂(−Σ m log(1 − ŝ))/∂θ`.
    pub score_correction: [f64; 4],
    /// `b = H_θ⁻¹ (g_logdet − g_corr)` over the free parameters.
    pub bias: [f64; 4],
    /// `H_θ⁻¹ g_logdet`: the bias if the coloured-noise correction were
    /// kept in the likelihood (J + ½ Σ log det S).
    pub bias_logdet_only: [f64; 4],
    /// Each parameter alone, the others held: `(g_logdet − g_corr)_i / H_ii`.
    pub bias_conditional: [f64; 4],
}

/// Whether the heading white noise of the reference is scaled on its own.
///
/// Measured (docs/study.md, EIV section): tied to the position scale, the
/// estimated heading noise keeps the starting model's ratio (production
/// car 0.02 m : 0.5 mrad against the simulator's 0.02 m : 0.3 mrad), and the
/// estimated-noise t_r on paper noise was +2.7 / +5.3 / +4.2 % (seeds 1–3);
/// with its own scale +0.85 / +1.30 / +0.90 %. Alone it runs away on a
/// 2 %-white-noise drive and on one of 20 `coloured` drives (t_r +250 % /
/// +230 %, flagged). Together with [`QuantisationModel::Measurement`] it is
/// the best combination on every simulated preset with η estimated (paper
/// t_r −1.2 %, high +4.1 %; docs/study.md, EIV section, "Stop 12") and the
/// recommended default, not switched yet. With the SPEC formulation
/// ([`InputJacobian::None`]) the noise-free straight drive stops at a
/// second fixed point of the θ/η iteration (c_e −0.057 %, η well above its
/// lower clamp); with the default [`InputJacobian::FilterShare`] it does
/// not (c_e to 1e-9, "Stop 12"). After stop 13's study the separate scale
/// stopped at the iteration limit on 3 of 20 `white` drives with `Counting`;
/// [`EivOptions::final_step_check`] showed those were converged. The
/// default since stop 14, with [`QuantisationModel::Counting`] and
/// [`QuantisationLevel::FromReadings`] (docs/study.md "Stop 14"; 20 seeds ×
/// 12 km, η estimated: t_r +0.06 % white, +0.02 % coloured, +0.30 % paper,
/// +1.50 % high, against +0.06 %, −0.01 %, +3.65 %, all-fallback tied with
/// process-noise quantisation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum HeadingScale {
    /// η_3 scales position and heading white noise together (η_5 unused, reported equal to η_3).
    TiedToPosition,
    /// η_5 scales the heading white noise alone.
    Separate,
}

/// Whether the encoder quantisation's level is estimated with the white
/// wheel noise (η_0) or given ([`EivOptions::quantisation_level`]).
///
/// The quantisation step q = 1/(ticks per revolution · sample time) is a
/// property of the encoder, usually known, and the wheel-rate readings lie
/// on its lattice. Tied to η_0, the estimated q follows the white relative
/// wheel noise: from the production-car start (q/σ_white = 0.02 rev/s /
/// 0.8 %) on the simulator's `high` preset (512 ticks: q = 0.078 rev/s with
/// 2 % white noise) it comes out at 0.05 rev/s, and the heading channel's
/// misfit moves t_r (docs/study.md, "Stop 13"). Given, with
/// [`QuantisationModel::Counting`] and [`HeadingScale::Separate`], the
/// `high` bias of t_r with η estimated went from +8.5 % to +1.5 % (20 seeds ×
/// 12 km; the known model +0.66 %). Use it with `Counting` only: with the
/// approximate [`QuantisationModel::Measurement`] it made `high` worse
/// (t_r +5.0 % → −11.7 %, 10 seeds). The default since stop 14 is
/// [`QuantisationLevel::FromReadings`]: the step is read off the readings
/// where they lie on a lattice (a simulator's, or rates from counted ticks
/// at the encoder's own sample times), and otherwise scaled as before.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QuantisationLevel {
    /// q scaled by `exp(η_0/2)` with the white wheel noise, a_y and β noise.
    ScaledWithWhite,
    /// q held at [`NoiseModel::quantisation_step_rev_per_s`] of
    /// [`EivOptions::noise`]; η_0 scales the white wheel, a_y and β noise only.
    Given,
    /// q read off the wheel readings when they lie on a lattice of counted
    /// ticks ([`quantisation_step_of_readings`]) and then held there as with
    /// [`QuantisationLevel::Given`]; readings off any lattice (interpolated
    /// ticks, resampled speeds) fall back to
    /// [`QuantisationLevel::ScaledWithWhite`] from the noise model's q.
    /// [`EivReport::quantisation_step_from_readings`] says which.
    FromReadings,
}

impl QuantisationLevel {
    /// The step `FromReadings` finds on `input` (None for the other levels
    /// and where the readings lie on no lattice).
    pub(crate) fn step_found(self, input: &EivInput<'_>) -> Option<f64> {
        match self {
            QuantisationLevel::FromReadings => lattice::input_quantisation_step(input),
            _ => None,
        }
    }
}

impl std::str::FromStr for QuantisationLevel {
    type Err = Error;
    /// `scaled` ([`QuantisationLevel::ScaledWithWhite`]), `given` or
    /// `from-readings`, as the CLI's `--quantisation-level`.
    ///
    /// ```
    /// use odocal::eiv::QuantisationLevel;
    /// assert_eq!("from-readings".parse::<QuantisationLevel>().unwrap(), QuantisationLevel::FromReadings);
    /// assert!("auto".parse::<QuantisationLevel>().is_err());
    /// ```
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "scaled" | "scaled_with_white" => Ok(QuantisationLevel::ScaledWithWhite),
            "given" => Ok(QuantisationLevel::Given),
            "from_readings" => Ok(QuantisationLevel::FromReadings),
            _ => Err(Error::Parse {
                what: "quantisation level",
                input: s.to_string(),
                expected: "scaled, given or from-readings",
            }),
        }
    }
}

/// How the noise of the lateral inputs, a_y and the sideslip β, is scaled
/// ([`EivOptions::lateral_noise`]).
///
/// With six noise scales η, a_y's and β's σ have none of their own: by
/// default η_0 scales them with the white wheel noise (`TiedToWheelWhite`).
/// On the simulator every source scales together (its `high` preset is
/// `paper` × 2.5), so the tie fits there; on real logs the white wheel
/// scale runs to its lower clamp where the encoder's quantisation explains
/// the wheel noise (4 of the 6 test-track runs and the highway van), and
/// the tie then takes a_y and β as exact. `Stated` holds them at the noise
/// model's σ instead: the IMU's and the sideslip source's noise, settable
/// in a noise-model file or a manifest's `[noise]`.
///
/// Measured (docs/study.md, stop 17; 20 × 12 km drives, η estimated,
/// production-car start; bias t = mean/se, tied → stated): `paper` t_r
/// 4.2 → 3.2 (RMS 1.91 → 1.72× the CRB), d 3.1 → 2.2; `high` c_e 4.1 → 0.7,
/// t_r 6.0 → 4.8, d 4.9 → 4.0; `white` c_e 4.1 → 0.5; `coloured` t_r
/// 0.4 → 1.6. Real logs: the test-track cross-run Ē_p 1.587 → 1.644 m (one
/// more run falls back: not converged), the van's halves and the RAV4
/// unchanged. Not the default: a stated noise that the data do not have
/// costs information the tie keeps. On a noise-free straight drive c_e's σ
/// grows from 1.9e-6 m to 4.5e-3 m and the fit stops 4.2 mm off, within
/// that σ (the tie drives every scale to its lower clamp and returns
/// θ_true); the noise-free 6 km drive gives d to 5e-8 relative instead of
/// 1e-8. An own scale for a_y and β would keep both; it is not written.
/// Since the sideslip error is a filter state ([`SideslipNoise`], stop 19)
/// `Stated` no longer changes those simulated results (`high` t_r t 4.4
/// → 4.7): its gains above made up for the white-equivalent sideslip noise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LateralNoise {
    /// η_0 scales a_y and β noise with the white wheel noise.
    #[default]
    TiedToWheelWhite,
    /// a_y and β noise held at [`NoiseModel::lateral_acceleration_sigma_m_per_s2`]
    /// and [`NoiseModel::sideslip_sigma_rad`] of [`EivOptions::noise`].
    Stated,
}

impl std::str::FromStr for LateralNoise {
    type Err = Error;
    /// `tied` ([`LateralNoise::TiedToWheelWhite`]) or `stated`, as the
    /// CLI's `--lateral-noise`.
    ///
    /// ```
    /// use odocal::eiv::LateralNoise;
    /// assert_eq!("stated".parse::<LateralNoise>().unwrap(), LateralNoise::Stated);
    /// assert!("free".parse::<LateralNoise>().is_err());
    /// ```
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().replace('-', "_").as_str() {
            "tied" | "tied_to_wheel_white" => Ok(LateralNoise::TiedToWheelWhite),
            "stated" => Ok(LateralNoise::Stated),
            _ => Err(Error::Parse { what: "lateral noise", input: s.to_string(), expected: "tied or stated" }),
        }
    }
}

/// How the filter models the error of the measured sideslip β, a
/// Gauss-Markov process of σ [`NoiseModel::sideslip_sigma_rad`] and time
/// constant [`NoiseModel::sideslip_time_constant_s`] (as the simulator's,
/// and as a sideslip estimate filtered from the IMU behaves).
///
/// Stop 19 found why the noise scales were off at the truth on `high`
/// (docs/study.md, EIV section): the white equivalent overstates the
/// sideslip error's effect over the few steps the filter's position
/// innovations span by about the factor `(1+a)/(1−a)` (80 at τ = 1 s and
/// 40 Hz), and the fit made up for it by lowering the drift and position
/// scales and raising the heading white one (the scoring step from the
/// truth, 6 drives: drift −0.103, heading white +0.051; with the state
/// −0.002 and +0.015, as with no sideslip error at all). 10 drives × 12
/// km of `high`, η estimated: c_e +0.089 → +0.019 %, t_r +1.33 → +0.91 %,
/// d −0.244 → −0.166 mm/(m/s²).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SideslipNoise {
    /// The error is a filter state `e_β` (the true sideslip is `β̃ − e_β`),
    /// Gauss-Markov like the wheels' coloured errors: one more state.
    #[default]
    GaussMarkovState,
    /// The error taken as white process noise of the long-run variance
    /// `σ²(1+a)/(1−a)`, `a = exp(−t_s/τ)` (the filter before stop 19).
    WhiteEquivalent,
}

/// How the filter models encoder quantisation (q of [`NoiseModel`]).
///
/// Counting ticks carries the remainder over, so the counted rotation is
/// within one tick of the true one at every sample: the error is bounded and
/// white *in the pose*, not a white rate error that accumulates.
/// Measured (docs/study.md, EIV section; 12 km, 20 seeds, known noise, t_r
/// error): `Measurement` paper −0.08 ± 0.30 % (RMS 1.35× the CRB) and high
/// −1.2 ± 1.1 % (5.7×) against `ProcessNoise` +0.39 ± 0.30 % (2.2×) and
/// +3.3 ± 1.2 % (12×); with η estimated from the production-car start,
/// paper −1.2 ± 0.6 % / high +4.5 ± 5.0 % against +4.0 ± 1.0 % / +122 ± 33 %.
/// Alone (heading scale tied) it changes little with η estimated (paper
/// t_r +3.8 %, high +118 %); with [`HeadingScale::Separate`] it gives
/// paper −1.2 %, high +4.5 % (docs/study.md, EIV section, "Stop 11"; "Stop
/// 12", where the pair passes the noise-free straight and turning drives).
/// [`QuantisationModel::Counting`] with the separate scale and the step
/// read off the readings is the default since stop 14.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum QuantisationModel {
    /// White rate noise of variance q²/12 where the wheel turns, in the
    /// process noise (accumulates like a random walk).
    ProcessNoise,
    /// Measurement noise `R_q = q²/12·(f_l f_lᵀ + f_r f_rᵀ)` (f_w = ∂f/∂n_w
    /// of the step, following θ), plus one draw in the window's initial
    /// covariance.
    Measurement,
    /// The exact counting error: the measured rate of a turning wheel is
    /// `ñ_k = n_k + w_{k−1} − w_k`, w the remainder of the tick count in
    /// rev/s (variance q²/12, independent from sample to sample), an MA(1)
    /// input error. The filter carries `w_{k−1}` of each wheel as a state
    /// (two states more): the step takes it off the measured rate, the new
    /// remainder enters as process noise shared by the pose and the state.
    /// Where a wheel counts nothing the remainder is carried over (no error,
    /// no new draw). Scaled by η_0 like the other models. With the
    /// separate heading scale and the noise model known it is the best of the
    /// three (20 seeds × 12 km, t_r paper +0.17 %, high +0.66 %; its
    /// innovation checks flag none of 80 drives), with η estimated paper
    /// +0.28 % but high +8.5 % (docs/study.md "Stop 13"), +1.5 % with the
    /// step held at the encoder's ([`QuantisationLevel::FromReadings`]).
    /// The default since stop 14.
    Counting,
}

impl std::str::FromStr for HeadingScale {
    type Err = Error;
    /// `tied` ([`HeadingScale::TiedToPosition`]) or `separate`, as the CLI's `--heading-noise`.
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "tied" | "tied_to_position" => Ok(HeadingScale::TiedToPosition),
            "separate" => Ok(HeadingScale::Separate),
            _ => Err(Error::Parse { what: "heading noise scale", input: s.to_string(), expected: "tied or separate" }),
        }
    }
}

impl std::str::FromStr for QuantisationModel {
    type Err = Error;
    /// `process` ([`QuantisationModel::ProcessNoise`]), `measurement` or
    /// `counting`, as the CLI's `--quantisation`.
    ///
    /// ```
    /// use odocal::eiv::QuantisationModel;
    /// assert_eq!("counting".parse::<QuantisationModel>().unwrap(), QuantisationModel::Counting);
    /// assert!("ticks".parse::<QuantisationModel>().is_err());
    /// ```
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "process" | "process_noise" => Ok(QuantisationModel::ProcessNoise),
            "measurement" => Ok(QuantisationModel::Measurement),
            "counting" => Ok(QuantisationModel::Counting),
            _ => Err(Error::Parse {
                what: "quantisation model",
                input: s.to_string(),
                expected: "process, measurement or counting",
            }),
        }
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
            eta_secant_damping: true,
            eta_reentry_min_score: None,
            covariance_estimate: CovarianceEstimate::LargerOfModelAndBlock,
            noise_estimate_in_covariance: true,
            theta_convergence: false,
            final_step_check: true,
            passes: 2,
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
            innovation_null: InnovationNull::FloorsAsRegularisation,
            max_lag1_below: 0.2,
            max_half_z: 4.0,
            covariance: CovarianceMode::FollowsTheta,
            quantisation: QuantisationModel::Counting,
            heading_scale: HeadingScale::Separate,
            quantisation_level: QuantisationLevel::FromReadings,
            lateral_noise: LateralNoise::TiedToWheelWhite,
            sideslip_noise: SideslipNoise::GaussMarkovState,
            wheel_noise_scale: WheelNoiseScale::SmoothedFittedInput { half_width_samples: 20 },
            bias_correction: BiasCorrection::None,
            bootstrap_inputs: BootstrapInputs::Measured,
            bootstrap_noise: BootstrapNoise::HeldAtFit,
            bootstrap_antithetic: false,
            input_jacobian: InputJacobian::FilterShare,
            position_floor_m: DEFAULT_POSITION_FLOOR_M,
            hold_unobservable_at: None,
            estimate_time_constants: false,
            time_constant_grid: TimeConstantGrid::default(),
        }
    }
}

impl EivOptions {
    /// Holds the scales of `sources` at the starting model
    /// ([`EivOptions::eta_held`]): their levels in [`EivOptions::noise`] are
    /// known.
    pub fn hold_known(&mut self, sources: &[NoiseSource]) {
        for s in sources {
            self.eta_held[s.index()] = true;
        }
    }

    /// The sources [`EivOptions::eta_held`] holds, in η order.
    pub fn known_sources(&self) -> Vec<NoiseSource> {
        NOISE_SOURCES.into_iter().filter(|s| self.eta_held[s.index()]).collect()
    }

    /// These options with [`QuantisationLevel::FromReadings`] replaced by what
    /// it resolves to where the readings gave the step `found`: `Given` at
    /// that step, or `ScaledWithWhite` for `None`. Other levels are kept.
    pub(crate) fn with_resolved_quantisation(&self, found: Option<f64>) -> EivOptions {
        let mut o = self.clone();
        if o.quantisation_level == QuantisationLevel::FromReadings {
            match found {
                Some(q) => {
                    o.quantisation_level = QuantisationLevel::Given;
                    o.noise.quantisation_step_rev_per_s = q;
                }
                None => o.quantisation_level = QuantisationLevel::ScaledWithWhite,
            }
        }
        o
    }

    /// Subtracts the estimator's own bias from every parameter, estimated by
    /// a parametric bootstrap of `replicates` re-simulations (seed `seed`;
    /// an even number: antithetic pairs, [`EivOptions::bootstrap_antithetic`])
    /// on the smoothed trajectory ([`BIAS_BOOTSTRAP_SMOOTHING_SAMPLES`]),
    /// each holding the fitted noise model ([`BootstrapNoise::HeldAtFit`]):
    /// what the EIV method of `calibrate` applies by default (B = 4), the
    /// CLI's `--correct-bias B` and Python's `correct_bias=B`, measured in
    /// [`BiasCorrection`]'s docs.
    ///
    /// ```
    /// use odocal::eiv::{BiasCorrection, BootstrapNoise, EivOptions};
    /// let mut o = EivOptions::default();
    /// o.correct_bias(10, 0);
    /// assert_eq!(o.bias_correction, BiasCorrection::Bootstrap { replicates: 10, seed: 0, all_parameters: true });
    /// assert_eq!(o.bootstrap_noise, BootstrapNoise::HeldAtFit);
    /// assert!(o.bootstrap_antithetic);
    /// assert!(o.validate().is_ok());
    /// o.correct_bias(5, 0); // an odd B cannot be paired
    /// assert!(o.validate().is_err());
    /// ```
    pub fn correct_bias(&mut self, replicates: usize, seed: u64) {
        self.bias_correction = BiasCorrection::Bootstrap { replicates, seed, all_parameters: true };
        self.bootstrap_inputs = BootstrapInputs::Smoothed { half_width_samples: BIAS_BOOTSTRAP_SMOOTHING_SAMPLES };
        self.bootstrap_noise = BootstrapNoise::HeldAtFit;
        self.bootstrap_antithetic = true;
    }

    /// The defaults with SPEC §10's formulation of the cost and of `R`: the
    /// relative wheel noise scaled by the measured rotation, no input
    /// log-Jacobian term, the 1 mm position floor (the library defaults
    /// before stop 11). The studies' Cramér–Rao bound is computed with it,
    /// so that it depends on the noise model only, not on the estimator's
    /// bias corrections.
    pub fn spec() -> Self {
        EivOptions {
            wheel_noise_scale: WheelNoiseScale::MeasuredInput,
            input_jacobian: InputJacobian::None,
            position_floor_m: SPEC_POSITION_FLOOR_M,
            ..EivOptions::default()
        }
    }

    /// Checks the options, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        let bad = |field: &'static str, reason: &str| Err(Error::InvalidOption { field, reason: reason.into() });
        if self.window_samples < 10 {
            return bad("window_samples", "must be at least 10");
        }
        if self.passes == 0 {
            return bad("passes", "must be at least 1");
        }
        if !self.free.iter().any(|f| *f) {
            return bad("free", "at least one parameter must be free");
        }
        if !(self.step_tolerance.is_finite() && self.step_tolerance > 0.0) {
            return bad("step_tolerance", "must be positive");
        }
        if self.eta_reentry_min_score.is_some_and(|x| !(x.is_finite() && x >= 0.0)) {
            return bad("eta_reentry_min_score", "must be finite and >= 0");
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
        let heading = NoiseSource::HeadingWhite.index();
        if self.eta_held[heading] && self.heading_scale == HeadingScale::TiedToPosition && !self.fix_noise {
            return bad(
                "eta_held",
                "heading_white is known but its scale is tied to pose_white (heading noise `tied`): \
                 use the separate heading scale, or state pose_white as known",
            );
        }
        if let Some(t) = &self.hold_unobservable_at {
            t.validate().map_err(|e| Error::InvalidOption {
                field: "hold_unobservable_at",
                reason: format!("{e}; give a usable θ (or None to hold at the start)"),
            })?;
        }
        if !(self.position_floor_m.is_finite() && self.position_floor_m > 0.0) {
            return bad("position_floor_m", "must be positive (it keeps S regular on a perfect reference)");
        }
        if let BiasCorrection::Bootstrap { replicates, .. } = self.bias_correction {
            if replicates < 2 {
                return bad("bias_correction", "the bootstrap needs at least 2 replicates");
            }
            if self.bootstrap_antithetic && !replicates.is_multiple_of(2) {
                return bad(
                    "bias_correction",
                    "antithetic pairs (bootstrap_antithetic) need an even number of replicates",
                );
            }
        }
        if matches!(
            self.wheel_noise_scale,
            WheelNoiseScale::SmoothedFittedInput { half_width_samples: 0 }
                | WheelNoiseScale::ReferenceInput { half_width_samples: 0 }
        ) {
            return bad("wheel_noise_scale", "the smoothed scales need half_width_samples >= 1");
        }
        if self.wheel_noise_scale != WheelNoiseScale::MeasuredInput && self.covariance != CovarianceMode::FollowsTheta {
            return bad("wheel_noise_scale", "fitted_input needs covariance = follows_theta");
        }
        if self.estimate_time_constants {
            self.time_constant_grid.validate()?;
        }
        self.noise.validate()
    }
}

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
    /// True when the fit converged (step tolerance met).
    pub fn converged(&self) -> bool {
        matches!(self, Termination::StepTolerance { .. })
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Termination::StepTolerance { step_over_sigma, threshold } => {
                write!(f, "step tolerance: max|step|/σ {step_over_sigma:.2e} < {threshold}")
            }
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
    /// (with [`InnovationNull::FloorsAsRegularisation`], the band widened to
    /// cover the NIS expected without the floors, see [`EivOptions::innovation_null`]).
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
    /// between 0 and `expected` (see [`EivOptions::innovation_null`];
    /// `threshold` is the limit on the side where it left the interval).
    CorrelatedInnovations {
        /// Window index.
        window: usize,
        /// The component.
        component: PoseComponent,
        /// Lag-1 autocorrelation.
        lag1: f64,
        /// Expected lag-1 autocorrelation when the data have none of the
        /// measurement floors (0 with [`InnovationNull::FittedModel`]).
        #[serde(default)]
        expected: f64,
        /// The limit.
        threshold: f64,
    },
    /// θ from the two halves of the windows differs by more than its uncertainty allows.
    UnstableAcrossHalves {
        /// The parameter.
        parameter: Parameter,
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
        parameters: Vec<Parameter>,
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
                write!(f, "window {window}: NIS/dof {nis:.2} outside [{}, {}]", band[0], band[1])
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

/// Observability from the information matrix `H_θ`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EivObservability {
    /// Reciprocal condition number of the equilibrated `H_θ` over the free parameters.
    pub rcond: f64,
    /// Standard deviation of each parameter over its resolution (∞ when
    /// singular; 0 for parameters not estimated).
    pub sigma_over_resolution: [f64; 4],
    /// Parameters held fixed because the data cannot determine them.
    pub unobservable: Vec<Parameter>,
    /// Parameters in a near-collinear combination of the free ones.
    pub collinear: Vec<Parameter>,
}

/// Per-window consistency numbers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WindowDiagnostics {
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
    /// ([`InnovationNull::FloorsAsRegularisation`]; 1 with
    /// [`InnovationNull::FittedModel`]).
    #[serde(default = "one")]
    pub nis_without_floors: f64,
    /// Expected lag-1 autocorrelation `[x, y, ψ]` of the whitened
    /// innovations under the same null (0 with [`InnovationNull::FittedModel`]).
    #[serde(default)]
    pub lag1_without_floors: [f64; 3],
}

fn one() -> f64 {
    1.0
}

/// θ re-estimated on each half of the windows (one scoring step from the estimate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HalvesCheck {
    /// θ from the first half.
    pub first: Theta,
    /// θ from the second half.
    pub second: Theta,
    /// Difference over its standard deviation per parameter (0 for fixed ones).
    pub z: [f64; 4],
}

/// One accepted scoring iteration.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct IterationRecord {
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

/// One scoring pass (covariance held at one reference θ).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PassReport {
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
    /// a clamp; `None` when η is fixed or the pass stopped before a step).
    #[serde(default)]
    pub eta_step_over_sigma: Option<f64>,
}

/// The result of an EIV calibration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EivReport {
    /// The starting θ.
    pub initial_theta: Theta,
    /// The estimate.
    pub theta: Theta,
    /// Which parameters were estimated.
    pub free: [bool; 4],
    /// θ's covariance at the estimate (zero rows for fixed parameters):
    /// `H_θ⁻¹`, or per parameter raised to the block sandwich's
    /// ([`EivOptions::covariance_estimate`]), plus what estimating η adds
    /// ([`EivOptions::noise_estimate_in_covariance`]).
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
    /// per-update [`EivReport::sigma_sandwich`] is not (stop 13). NaN with
    /// fewer than two blocks.
    pub sigma_block: [f64; 4],
    /// Standard deviations from the Gaussian Fisher information at the
    /// estimate with both terms (`½ tr(S⁻¹∂S S⁻¹∂S)` included), jointly
    /// with the estimated η (θ block of the inverse): the Cramér–Rao form
    /// of [`cramer_rao_bound`] at θ̂ and the fitted noise. Equal to the
    /// mean-only information with the covariance held. Linearised along the
    /// measured inputs (a fit has no other), whose noise counts as
    /// excitation: under heavy wheel noise it understates t_r's and d's σ
    /// (on the `high` preset t_r's by about half; it covered t_r in 22–25 %
    /// of drives). A diagnostic; [`EivReport::sigma`] is raised to the block
    /// sandwich, which measures the scores' actual spread.
    pub sigma_fisher: [f64; 4],
    /// The part of θ's σ that estimating η from the drive adds
    /// ([`EivOptions::noise_estimate_in_covariance`]): `sqrt(diag A Σ_η Aᵀ)`.
    /// Included in [`EivReport::covariance`] and [`EivReport::sigma`] when
    /// that option is on; 0 with a fixed noise model or the option off.
    #[serde(default)]
    pub sigma_noise_estimate: [f64; 4],
    /// `∂θ̂/∂η_j` at the estimate (`[parameter][source]`, in θ's units per
    /// unit of η; [`EivOptions::noise_estimate_in_covariance`]): how far θ̂
    /// moves when a source's variance is e-fold. Zero for sources not
    /// estimated, with a fixed noise model or with the option off.
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
    pub evaluations: [usize; 2],
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
    /// The root of the profile cost before any [`BiasCorrection`].
    pub theta_uncorrected: Theta,
    /// The bias subtracted by [`EivOptions::bias_correction`] (`theta =
    /// theta_uncorrected − bias_subtracted`; zeros without a correction).
    pub bias_subtracted: [f64; 4],
    /// What the bootstrap of [`EivOptions::bias_correction`] adds to θ's σ
    /// (already in [`EivReport::sigma`] and the covariance): the Monte Carlo
    /// error of the subtracted bias, the replicates' covariance over the
    /// number of replicates fitted, for the corrected parameters (zeros
    /// without a correction).
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
    /// The time-constant search (None unless
    /// [`EivOptions::estimate_time_constants`]); the chosen time constants
    /// are also in [`EivReport::noise`].
    #[serde(default)]
    pub time_constants: Option<TimeConstantFit>,
    /// The quantisation step read off the wheel readings' lattice, rev/s,
    /// with [`QuantisationLevel::FromReadings`] (None when the readings lie
    /// on no lattice or another level was asked for); then also
    /// [`EivReport::noise`]'s q.
    #[serde(default)]
    pub quantisation_step_from_readings: Option<f64>,
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

/// The Cramér–Rao bound of θ for one drive.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrbReport {
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
    /// the bound this function returned before, kept for comparison).
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

// ---------------------------------------------------------------------------

/// Sums of all windows at one (θ, η).
struct Evaluation {
    total: WindowSums,
    windows: Vec<WindowSums>,
    mode: Mode,
}

struct Problem<'a> {
    input: &'a EivInput<'a>,
    windows: Vec<Window>,
    noise: NoiseModel,
    quantisation: QuantisationModel,
    /// [`QuantisationLevel::Given`]: q²/12 not scaled by η_0.
    quantisation_given: bool,
    /// [`SideslipNoise::WhiteEquivalent`].
    sideslip_white: bool,
    /// a_y and β noise held at the model's σ ([`LateralNoise::Stated`]).
    lateral_stated: bool,
    heading_separate: bool,
    fitted_input: bool,
    noise_input_half_width: usize,
    noise_input_from_reference: bool,
    input_jacobian: InputJacobian,
    position_floor_m: f64,
    /// Filter passes over the drive: with derivatives, objective only.
    evaluations: std::cell::Cell<[usize; 2]>,
    /// Lean iteration starts in [`scoring_pass`] (always on; off only in the
    /// test that holds them to the full evaluations' results).
    lean_iterations: bool,
}

impl<'a> Problem<'a> {
    /// The problem of `opts` (its quantisation level already resolved) over `windows`.
    fn new(input: &'a EivInput<'a>, windows: Vec<Window>, opts: &EivOptions) -> Self {
        Problem {
            input,
            windows,
            noise: opts.noise,
            quantisation: opts.quantisation,
            quantisation_given: opts.quantisation_level == QuantisationLevel::Given,
            sideslip_white: opts.sideslip_noise == SideslipNoise::WhiteEquivalent,
            lateral_stated: opts.lateral_noise == LateralNoise::Stated,
            heading_separate: opts.heading_scale == HeadingScale::Separate,
            fitted_input: opts.wheel_noise_scale != WheelNoiseScale::MeasuredInput,
            noise_input_half_width: opts.wheel_noise_scale.half_width(),
            noise_input_from_reference: matches!(opts.wheel_noise_scale, WheelNoiseScale::ReferenceInput { .. }),
            input_jacobian: opts.input_jacobian,
            position_floor_m: opts.position_floor_m,
            evaluations: std::cell::Cell::new([0; 2]),
            lean_iterations: true,
        }
    }
}

impl Problem<'_> {
    fn evaluate(&self, theta: &Theta, theta_ref: &Theta, eta: &[f64; 6], mode: Mode) -> Result<Evaluation> {
        self.evaluate_with(theta, theta_ref, eta, mode, false)
    }

    /// [`Problem::evaluate`], with the null recursion of the innovation
    /// diagnostics when `null` ([`filter::Variances::null_without_floors`]).
    fn evaluate_with(
        &self,
        theta: &Theta,
        theta_ref: &Theta,
        eta: &[f64; 6],
        mode: Mode,
        null: bool,
    ) -> Result<Evaluation> {
        let mut one = self.evaluate_many(&[(*theta, *eta)], theta_ref, mode, null)?;
        one.pop().ok_or_else(|| Error::Numerical("no filter evaluation".into()))
    }

    /// [`Problem::evaluate_with`] at several points `(θ, η)` in one parallel
    /// sweep over every (point, window) pair, so that two threads share the
    /// work of all the points rather than each point's few windows. Each
    /// point's totals are summed window by window in order: the results are
    /// the same to the bit as evaluating the points one by one, whatever the
    /// thread count.
    fn evaluate_many(
        &self,
        points: &[(Theta, [f64; 6])],
        theta_ref: &Theta,
        mode: Mode,
        null: bool,
    ) -> Result<Vec<Evaluation>> {
        let mut count = self.evaluations.get();
        count[usize::from(!mode.derivs)] += points.len();
        self.evaluations.set(count);
        let nw = self.windows.len();
        let vars: Vec<filter::Variances> = points.iter().map(|(_, eta)| self.variances(eta, null)).collect();
        let (input, windows) = (self.input, &self.windows);
        let parts: Vec<Result<WindowSums>> = (0..points.len() * nw)
            .into_par_iter()
            .map(|t| {
                let (pi, wi) = (t / nw, t % nw);
                run_window(input, &windows[wi], &points[pi].0, theta_ref, &vars[pi], mode, None)
            })
            .collect();
        let mut out = Vec::with_capacity(points.len());
        let mut it = parts.into_iter();
        for _ in 0..points.len() {
            let mut total = WindowSums::zero();
            let mut windows = Vec::with_capacity(nw);
            for p in it.by_ref().take(nw) {
                let p = p?;
                total.add(&p);
                windows.push(p);
            }
            out.push(Evaluation { total, windows, mode });
        }
        Ok(out)
    }

    /// Whether the filter's η derivatives give the θ-score's full
    /// η-dependence (see [`noise_estimate_covariance`]): not with the
    /// smoothed-share log-Jacobian weights, whose η-dependence it does not
    /// differentiate.
    fn mixed_partials_by_symmetry(&self) -> bool {
        !matches!(self.input_jacobian, InputJacobian::SmoothedShare | InputJacobian::SmoothedShareAll)
    }

    /// The filter's variances at η under this problem's noise options.
    fn variances(&self, eta: &[f64; 6], null: bool) -> filter::Variances {
        let mut e = *eta;
        if !self.heading_separate {
            // Tied: η_3 scales the heading white noise too; η_5 has no effect.
            e[5] = e[3];
        }
        let mut v = self.noise.variances(&e, self.input.sample_time_s);
        v.quant_in_measurement = self.quantisation == QuantisationModel::Measurement;
        v.quant_counting = self.quantisation == QuantisationModel::Counting;
        if self.quantisation_given {
            v.quant = self.noise.quantisation_step_rev_per_s * self.noise.quantisation_step_rev_per_s / 12.0;
            v.quant_scaled = false;
        }
        if self.lateral_stated {
            let unscaled = self.noise.variances(&[0.0; 6], self.input.sample_time_s);
            (v.a_y, v.beta, v.lateral_scaled) = (unscaled.a_y, unscaled.beta, false);
        }
        if self.sideslip_white {
            // The long-run variance of the Gauss-Markov error as white noise.
            let a = v.a_beta;
            (v.beta_white, v.beta) = (v.beta * (1.0 + a) / (1.0 - a), 0.0);
        }
        v.heading_separate = self.heading_separate;
        v.fitted_input = self.fitted_input;
        v.input_jacobian = self.input_jacobian;
        v.noise_input_half_width = self.noise_input_half_width;
        v.noise_input_from_reference = self.noise_input_from_reference;
        v.position_floor_m = self.position_floor_m;
        v.null_without_floors = null;
        v
    }
}

/// Per parameter: `√max(var(i), 0)` where `mask[i]`, 0 elsewhere.
fn free_sigma(mask: &[bool; 4], var: impl Fn(usize) -> f64) -> [f64; 4] {
    std::array::from_fn(|i| if mask[i] { var(i).max(0.0).sqrt() } else { 0.0 })
}

fn to_array(m: &Matrix4<f64>) -> [[f64; 4]; 4] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// Inverse of the free block of `h`, embedded in 4×4 (None when singular).
fn free_inverse(h: &Matrix4<f64>, free: &[bool; 4]) -> Option<Matrix4<f64>> {
    let idx: Vec<usize> = (0..4).filter(|i| free[*i]).collect();
    let p = idx.len();
    let a = DMatrix::from_fn(p, p, |i, j| h[(idx[i], idx[j])]);
    let inv = a.cholesky()?.inverse();
    let mut out = Matrix4::zeros();
    for (i, &fi) in idx.iter().enumerate() {
        for (j, &fj) in idx.iter().enumerate() {
            out[(fi, fj)] = inv[(i, j)];
        }
    }
    Some(out)
}

fn theta_add(theta: &Theta, step: &[f64; 4], lambda: f64) -> Theta {
    let a = theta.to_array();
    Theta {
        c_e: a[0] + lambda * step[0],
        c_d: a[1] + lambda * step[1],
        t_r: a[2] + lambda * step[2],
        d: a[3] + lambda * step[3],
    }
}

/// The scoring step of θ over the free parameters and the standard deviations.
fn theta_step(sums: &WindowSums, free: &[bool; 4], follows: bool) -> Result<([f64; 4], [f64; 4])> {
    let Some(inv) = free_inverse(&sums.h_theta, free) else {
        let params: crate::error::ParamNames =
            (0..4).filter(|i| free[*i]).map(|i| crate::model::param::Param::THETA[i]).collect();
        return Err(Error::NotObservable {
            params,
            reason: "the EIV information matrix H_θ is singular; hold them fixed (EivOptions::free)".into(),
        });
    };
    let g = theta_score(sums, follows);
    let step = -(inv * g);
    Ok((std::array::from_fn(|i| step[i]), std::array::from_fn(|i| inv[(i, i)].max(0.0).sqrt())))
}

/// The θ-score whose root is the estimate: the profile-cost gradient when
/// the covariance follows θ; with the covariance held, the gradient minus
/// its expectation under the input noise (corrected score).
fn theta_score(sums: &WindowSums, follows: bool) -> nalgebra::Vector4<f64> {
    if follows {
        nalgebra::Vector4::new(sums.grad_profile[0], sums.grad_profile[1], sums.grad_profile[2], sums.grad_profile[3])
    } else {
        nalgebra::Vector4::new(sums.grad[0], sums.grad[1], sums.grad[2], sums.grad[3]) - sums.bias
    }
}

/// `gᵀ H_θ⁻¹ g` of the θ-score over the free parameters (∞ when singular).
fn score_norm(sums: &WindowSums, free: &[bool; 4], follows: bool) -> f64 {
    match theta_step(sums, free, follows) {
        Ok((step, _)) => {
            let g = theta_score(sums, follows);
            -(0..4).filter(|i| free[*i]).map(|i| step[i] * g[i]).sum::<f64>()
        }
        Err(_) => f64::INFINITY,
    }
}

/// The scoring step of η (log-transformed, clamped; see the module docs),
/// its standard deviations and which η are held at a clamp.
fn eta_step(sums: &WindowSums, eta: &[f64; 6], bounds: [f64; 2], reentry_min_score: f64, held: &[bool; 6]) -> EtaStep {
    let tol = 1e-9;
    let g: [f64; 6] = std::array::from_fn(|j| sums.grad[4 + j]);
    // A noise source with no effect on the data has zero information: leave it.
    let scale = (0..NETA).map(|j| sums.i_eta[(j, j)]).fold(0.0f64, f64::max);
    // Sources at the lower clamp that re-enter (EivOptions::eta_reentry_min_score):
    // the score test g²/I of the scale against the data. Both g and I of
    // such a source carry the factor exp(η) (exp(2η)), so the statistic does
    // not depend on how deep in the clamp it sits.
    let reenters: [bool; 6] = std::array::from_fn(|j| {
        let i = sums.i_eta[(j, j)];
        eta[j] <= bounds[0] + tol && g[j] < 0.0 && i > 0.0 && g[j] * g[j] > reentry_min_score * i
    });
    // Information of the variance factor exp(η) relative to the starting
    // model: at the clamp `i_eta` is ~e⁻⁴⁰ of it and would read as none.
    let rel_info = |j: usize| sums.i_eta[(j, j)] * (-2.0 * eta[j]).exp();
    let rel_scale = (0..NETA).map(rel_info).fold(0.0f64, f64::max);
    let mut idx = Vec::new();
    for j in 0..NETA {
        let at_lo = eta[j] <= bounds[0] + tol && g[j] > 0.0;
        let at_hi = eta[j] >= bounds[1] - tol && g[j] < 0.0;
        let no_info = if reenters[j] {
            rel_info(j) <= 1e-12 * rel_scale.max(f64::MIN_POSITIVE)
        } else {
            sums.i_eta[(j, j)] <= 1e-12 * scale.max(f64::MIN_POSITIVE)
        };
        if !(at_lo || at_hi || no_info || held[j]) {
            idx.push(j);
        }
    }
    let mut step = [0.0; 6];
    let mut sigma = [0.0; 6];
    let leaving = idx.iter().any(|j| reenters[*j]);
    if idx.is_empty() {
        return EtaStep { step, sigma, leaving };
    }
    let p = idx.len();
    // With a source re-entering from the clamp its row is ~e⁻²⁰ of the
    // others': solve the equilibrated system (unit diagonal) so that the
    // ridge stays relative to each row.
    let eq: Vec<f64> = (0..p)
        .map(|i| if leaving { 1.0 / sums.i_eta[(idx[i], idx[i])].max(f64::MIN_POSITIVE).sqrt() } else { 1.0 })
        .collect();
    let a = DMatrix::from_fn(p, p, |i, k| sums.i_eta[(idx[i], idx[k])] * eq[i] * eq[k]);
    let ridge = 1e-12 * (0..p).map(|i| a[(i, i)]).fold(0.0f64, f64::max);
    let a = a + DMatrix::identity(p, p) * ridge;
    let b = DVector::from_fn(p, |i, _| -g[idx[i]] * eq[i]);
    let Some(chol) = a.cholesky() else {
        return EtaStep { step, sigma, leaving: false };
    };
    let d = chol.solve(&b).component_mul(&DVector::from_vec(eq.clone()));
    let inv_eq = chol.inverse();
    let inv = DMatrix::from_fn(p, p, |i, k| inv_eq[(i, k)] * eq[i] * eq[k]);
    for (i, &j) in idx.iter().enumerate() {
        let dj = d[i];
        let de = if dj > -0.999 { (1.0 + dj).ln() } else { bounds[0] - eta[j] };
        step[j] = (eta[j] + de).clamp(bounds[0], bounds[1]) - eta[j];
        sigma[j] = inv[(i, i)].max(0.0).sqrt();
    }
    // The scoring step d is a step of the variances (relative change), mapped
    // to η by ln(1 + d) and clamped: each component keeps its sign but not its
    // size, so with correlated sources (off-diagonal information) the mapped
    // step can point uphill on M, and then no halving is accepted (measured on
    // the noise-free straight drive with the heading scale separate: gᵀΔη =
    // +249, the fit stopped after one iteration with c_e 0.06 % off). Then take
    // the scoring step in η itself, which is a descent direction.
    let slope: f64 = (0..NETA).map(|j| g[j] * step[j]).sum();
    if slope >= 0.0 {
        step = eta_descent_step(sums, &g, eta, bounds, idx);
    }
    let leaving = leaving && (0..NETA).any(|j| reenters[j] && step[j] > 0.0);
    EtaStep { step, sigma, leaving }
}

impl EtaStep {
    fn none() -> Self {
        EtaStep { step: [0.0; 6], sigma: [0.0; 6], leaving: false }
    }
}

/// The η step of [`eta_step`].
struct EtaStep {
    /// The step (zero for held sources).
    step: [f64; 6],
    /// Standard deviations of η (0 for held sources).
    sigma: [f64; 6],
    /// Whether a source leaves its lower clamp with this step (re-entry):
    /// then the iteration has not converged, whatever the step's size in σ.
    leaving: bool,
}

/// Largest |Δη| of the fallback step of [`eta_step`] (a variance factor of e²).
const MAX_LOG_ETA_STEP: f64 = 2.0;

/// The Fisher-scoring step in η (not in the variances) over the sources in
/// `idx`, scaled as a whole so that no component exceeds
/// [`MAX_LOG_ETA_STEP`]; a source at a clamp whose step points out of the
/// range is held and the step recomputed without it (otherwise clamping
/// would change the step's direction). Its slope `gᵀΔη = −s·gᵀI⁻¹g` is
/// negative, so a short enough step lowers M.
fn eta_descent_step(
    sums: &WindowSums,
    g: &[f64; 6],
    eta: &[f64; 6],
    bounds: [f64; 2],
    mut idx: Vec<usize>,
) -> [f64; 6] {
    let tol = 1e-9;
    loop {
        let mut step = [0.0; 6];
        let p = idx.len();
        if p == 0 {
            return step;
        }
        let a = DMatrix::from_fn(p, p, |i, k| sums.i_eta[(idx[i], idx[k])]);
        let ridge = 1e-12 * (0..p).map(|i| a[(i, i)]).fold(0.0f64, f64::max);
        let a = a + DMatrix::identity(p, p) * ridge;
        let b = DVector::from_fn(p, |i, _| -g[idx[i]]);
        let Some(chol) = a.cholesky() else {
            return step;
        };
        let d = chol.solve(&b);
        let outward = (0..p).find(|&i| {
            let j = idx[i];
            (eta[j] <= bounds[0] + tol && d[i] < 0.0) || (eta[j] >= bounds[1] - tol && d[i] > 0.0)
        });
        if let Some(i) = outward {
            idx.remove(i);
            continue;
        }
        let s = (MAX_LOG_ETA_STEP / d.amax().max(f64::MIN_POSITIVE)).min(1.0);
        for (i, &j) in idx.iter().enumerate() {
            step[j] = (eta[j] + s * d[i]).clamp(bounds[0], bounds[1]) - eta[j];
        }
        return step;
    }
}

/// The factor of the η scoring step from the last two steps (a secant
/// along the step direction). Near the fixed point of the θ/η iteration the
/// raw scoring step of η is `d_k = −c(η_k − η*)`; when c ≠ 1 the iterates
/// overshoot (c > 1, the steps alternate in sign) or creep (c < 1).
/// Measured on the `white` and `coloured` presets (perfect reference, η
/// estimated, 12 km, seeds 1–2): c ≈ 1.4–1.45, so `max|step|/σ` shrank
/// only 2.2–2.6× per iteration and the fit stopped at the 10-iteration
/// limit (`max|step|/σ` 0.09–0.28) with θ unchanged for six iterations.
/// With the previous raw step `d_{k−1}` taken with factor `s_{k−1}`,
/// `d_k = (1 − c s_{k−1}) d_{k−1}`, so `r = d_k·d_{k−1}/|d_{k−1}|²` gives
/// `c = (1 − r)/s_{k−1}` and the factor `1/c = s_{k−1}/(1 − r)` lands on
/// the fixed point of a linear iteration. Used only when the two steps are
/// nearly parallel or antiparallel (|cos| ≥ 0.9, the one-dimensional
/// regime; otherwise the last factor is kept); the factor is kept in [0.1, 1], so the step is never longer
/// than the scoring step and stays a descent direction of M.
fn secant_eta_factor(step: &[f64; 6], last: Option<([f64; 6], f64)>) -> f64 {
    let Some((prev, s_prev)) = last else {
        return 1.0;
    };
    let dot: f64 = (0..NETA).map(|j| step[j] * prev[j]).sum();
    let nn: f64 = prev.iter().map(|x| x * x).sum();
    let mm: f64 = step.iter().map(|x| x * x).sum();
    if !(nn > 0.0 && mm > 0.0) {
        return 1.0;
    }
    if dot.abs() < 0.9 * (nn * mm).sqrt() {
        // Not the one-dimensional regime: keep the last factor (after a
        // well-damped step the next raw step is small and points anywhere).
        return s_prev.clamp(0.1, 1.0);
    }
    let r = (dot / nn).min(0.9);
    (s_prev / (1.0 - r)).clamp(0.1, 1.0)
}

/// The η step times `factor`, except for components that land on a clamp
/// (an absent source goes to its lower clamp in one step).
fn damp_eta_step(step: &[f64; 6], eta: &[f64; 6], factor: f64, bounds: [f64; 2]) -> [f64; 6] {
    std::array::from_fn(|j| {
        let to = eta[j] + step[j];
        if (to - bounds[0]).abs() < 1e-12 || (to - bounds[1]).abs() < 1e-12 {
            step[j]
        } else {
            factor * step[j]
        }
    })
}

fn eta_add(eta: &[f64; 6], step: &[f64; 6], lambda: f64, bounds: [f64; 2]) -> [f64; 6] {
    std::array::from_fn(|j| (eta[j] + lambda * step[j]).clamp(bounds[0], bounds[1]))
}

/// Observability from `H_θ` over `free`: σ/resolution, rcond, collinear names.
fn observability_of(
    h: &Matrix4<f64>,
    free: &[bool; 4],
    unobservable: Vec<Parameter>,
    opts: &EivOptions,
) -> EivObservability {
    let idx: Vec<usize> = (0..4).filter(|i| free[*i]).collect();
    let mut ratio = [0.0; 4];
    let inv = free_inverse(h, free);
    for &i in &idx {
        ratio[i] = inv.map_or(f64::INFINITY, |m| m[(i, i)].max(0.0).sqrt() / opts.resolution[i]);
    }
    let p = idx.len();
    let he = DMatrix::from_fn(p, p, |a, b| {
        let (i, j) = (idx[a], idx[b]);
        let dd = (h[(i, i)] * h[(j, j)]).sqrt();
        if dd > 0.0 {
            h[(i, j)] / dd
        } else {
            0.0
        }
    });
    let eig = SymmetricEigen::new(he);
    let (mn, mx) = eig.eigenvalues.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &l| (a.min(l), b.max(l)));
    let rcond = if mx > 0.0 { (mn / mx).max(0.0) } else { 0.0 };
    let mut weak = [false; 4];
    if p > 1 {
        for (e, lambda) in eig.eigenvalues.iter().enumerate() {
            if mx <= 0.0 || lambda.max(0.0) / mx < opts.min_rcond {
                let v = eig.eigenvectors.column(e);
                for (a, &i) in idx.iter().enumerate() {
                    if v[a].abs() > 0.3 {
                        weak[i] = true;
                    }
                }
            }
        }
    }
    let collinear = (0..4).filter(|i| weak[*i]).map(|i| PARAMETERS[i]).collect();
    EivObservability { rcond, sigma_over_resolution: ratio, unobservable, collinear }
}

/// Holds fixed, one at a time (worst first), the free parameters whose σ
/// exceeds their resolution. Returns the reduced mask and the names.
fn fix_unobservable(h: &Matrix4<f64>, free: &[bool; 4], opts: &EivOptions) -> ([bool; 4], Vec<Parameter>) {
    let mut free = *free;
    let mut fixed = Vec::new();
    loop {
        let inv = free_inverse(h, &free);
        let mut worst: Option<(usize, f64)> = None;
        for i in (0..4).filter(|i| free[*i]) {
            let r = inv.map_or(f64::INFINITY, |m| m[(i, i)].max(0.0).sqrt() / opts.resolution[i]);
            // With a singular matrix rank the diagonal of H itself.
            let r = if r.is_finite() { r } else { 1.0 / (h[(i, i)].max(0.0).sqrt() * opts.resolution[i]).max(1e-300) };
            if r > 1.0 && worst.is_none_or(|(_, w)| r > w) {
                worst = Some((i, r));
            }
        }
        match worst {
            Some((i, _)) if free.iter().filter(|f| **f).count() > 1 => {
                free[i] = false;
                fixed.push(PARAMETERS[i]);
            }
            _ => break,
        }
    }
    fixed.sort_by_key(|p| PARAMETERS.iter().position(|q| q == p));
    (free, fixed)
}

struct PassOutcome {
    theta: Theta,
    eta: [f64; 6],
    eval: Evaluation,
    report: PassReport,
    free: [bool; 4],
    unobservable: Vec<Parameter>,
    eta_sigma: [f64; 6],
}

/// Result of a line search: the accepted point, or the last cost tried.
enum Search {
    Accepted { theta: Theta, eta: [f64; 6], ev: Box<Evaluation>, lambda: f64 },
    Rejected { cost: f64 },
}

/// Whether a trial point is accepted, and its objective.
type Acceptance<'a> = dyn Fn(&Evaluation, &Theta, &[f64; 6]) -> (bool, f64) + 'a;

/// Step halving along `(dθ, dη)` from `(θ, η)`. The full step is evaluated
/// with derivatives (it is usually accepted); shorter steps with the
/// objective only, unless `accept` needs the derivatives (`needs_derivs`).
/// The accepted point is returned with derivatives.
#[allow(clippy::too_many_arguments)]
fn line_search(
    prob: &Problem<'_>,
    theta: &Theta,
    eta: &[f64; 6],
    dth: &[f64; 4],
    deta: &[f64; 6],
    theta_ref: &Theta,
    full: Mode,
    needs_derivs: bool,
    opts: &EivOptions,
    accept: &Acceptance<'_>,
) -> Result<Search> {
    let mut lambda = 1.0;
    let mut last_cost = f64::NAN;
    for h in 0..=opts.max_halvings {
        let th = theta_add(theta, dth, lambda);
        if th.validate().is_ok() {
            let et = eta_add(eta, deta, lambda, opts.eta_bounds);
            let mode = if h == 0 || needs_derivs { full } else { Mode::cost(full.follows_theta) };
            if let Ok(t) = prob.evaluate(&th, theta_ref, &et, mode) {
                let (ok, cost) = accept(&t, &th, &et);
                if cost.is_finite() {
                    last_cost = cost;
                    if ok {
                        let ev = if t.mode == full { t } else { prob.evaluate(&th, theta_ref, &et, full)? };
                        return Ok(Search::Accepted { theta: th, eta: et, ev: Box::new(ev), lambda });
                    }
                }
            }
        }
        lambda *= 0.5;
    }
    Ok(Search::Rejected { cost: last_cost })
}

/// `max |Δη_j|/σ_j` of an η step alone ([`step_ratio`] without θ).
fn eta_ratio(eta: &[f64; 6], deta: &[f64; 6], seta: &[f64; 6], bounds: [f64; 2]) -> f64 {
    step_ratio(&[0.0; 4], &[0.0; 4], &[false; 4], eta, deta, seta, bounds)
}

/// `max |step_i|/σ_i` over the free θ and the η that move.
fn step_ratio(
    dth: &[f64; 4],
    sth: &[f64; 4],
    free: &[bool; 4],
    eta: &[f64; 6],
    deta: &[f64; 6],
    seta: &[f64; 6],
    bounds: [f64; 2],
) -> f64 {
    let mut ratio = 0.0f64;
    for i in 0..4 {
        if free[i] && sth[i] > 0.0 {
            ratio = ratio.max(dth[i].abs() / sth[i]);
        }
    }
    for j in 0..NETA {
        if seta[j] > 0.0 {
            // A step that lands on a clamp counts by its size, not its σ.
            let at_clamp = (eta[j] + deta[j] - bounds[0]).abs() < 1e-12 || (eta[j] + deta[j] - bounds[1]).abs() < 1e-12;
            if !at_clamp || deta[j].abs() > 1e-12 {
                ratio = ratio.max(deta[j].abs() / seta[j]);
            }
        }
    }
    ratio
}

/// With [`EivOptions::theta_convergence`]: `max_i |·|/σ_i` over the free θ of
/// the remaining θ step and of the θ change the remaining η step would cause
/// through the joint information, `dθ = −I_θθ⁻¹ I_θη dη` (blocks over the
/// free θ and the η that move). Infinite when the θ block is singular.
fn theta_ratio(sums: &WindowSums, dth: &[f64; 4], sth: &[f64; 4], free: &[bool; 4], deta: &[f64; 6]) -> f64 {
    let fi: Vec<usize> = (0..4).filter(|i| free[*i] && sth[*i] > 0.0).collect();
    let p = fi.len();
    if p == 0 {
        return 0.0;
    }
    let a = DMatrix::from_fn(p, p, |i, k| sums.info[(fi[i], fi[k])]);
    let b = DVector::from_fn(p, |i, _| -(0..NETA).map(|j| sums.info[(fi[i], 4 + j)] * deta[j]).sum::<f64>());
    let Some(chol) = a.cholesky() else {
        return f64::INFINITY;
    };
    let induced = chol.solve(&b);
    fi.iter().enumerate().map(|(k, &i)| (dth[i].abs().max(induced[k].abs())) / sth[i]).fold(0.0f64, f64::max)
}

/// One scoring pass (with [`CovarianceMode::HeldAtReference`], at a fixed
/// covariance reference).
///
/// With the covariance following θ, θ and η have different objectives (the
/// profile cost J for θ, the marginal likelihood M for η), so each
/// iteration takes a θ step halved on J at fixed η, then an η step halved
/// on M at fixed θ (block coordinate). With the covariance held, one joint
/// step on M (corrected score for θ) as before.
fn scoring_pass(
    prob: &Problem<'_>,
    theta0: Theta,
    eta0: [f64; 6],
    theta_ref: Theta,
    free0: [bool; 4],
    check_observability: bool,
    opts: &EivOptions,
) -> Result<PassOutcome> {
    let follows = opts.covariance == CovarianceMode::FollowsTheta;
    let eta_derivs = !opts.fix_noise;
    let full = Mode::full(follows, eta_derivs);
    // Lean iterations (stop 24): with the covariance following θ and η
    // estimated, the evaluation an iteration starts from needs its η
    // derivatives only for the convergence test, whose θ part alone decides
    // while the θ step is ≥ the tolerance (the test takes the maximum over
    // θ and η). So it is evaluated with the θ derivatives only (4 of the 10
    // covariance derivatives) and evaluated again in full only when its θ
    // step is below the tolerance, or at the end; once that happened, later
    // starts are evaluated in full directly. Steps and decisions are those
    // of full evaluations (the θ entries are identical to the bit; test
    // `lean_iteration_starts_give_the_full_evaluations_results_to_the_bit`);
    // only `IterationRecord::step_over_sigma` of an unconverged iteration can
    // be smaller (it lacks the η step at the iteration's start).
    let lean = prob.lean_iterations && follows && eta_derivs && !opts.theta_convergence;
    let start_mode = if lean { Mode::full(follows, false) } else { full };
    let bounds = opts.eta_bounds;
    let reentry = opts.eta_reentry_min_score.unwrap_or(f64::INFINITY);
    let objective = |ev: &Evaluation, th: &Theta| -> f64 {
        if follows {
            ev.total.profile()
        } else {
            ev.total.corrected_merit(th, &theta_ref)
        }
    };
    let (mut theta, mut eta) = (theta0, eta0);
    let mut ev = prob.evaluate(&theta, &theta_ref, &eta, start_mode)?;
    let (free, unobservable) = if check_observability && opts.fix_unobservable {
        fix_unobservable(&ev.total.h_theta, &free0, opts)
    } else {
        (free0, Vec::new())
    };
    if let Some(held) = opts.hold_unobservable_at.filter(|_| free != free0) {
        let (mut a, h) = (theta.to_array(), held.to_array());
        for i in (0..4).filter(|i| free0[*i] && !free[*i]) {
            a[i] = h[i];
        }
        theta = Theta::from_array(a);
        theta.validate()?;
        ev = prob.evaluate(&theta, &theta_ref, &eta, start_mode)?;
    }
    let initial_cost = objective(&ev, &theta);
    let mut history = Vec::new();
    let mut termination = Termination::MaxIterations { iterations: opts.max_iterations, step_over_sigma: f64::NAN };
    let mut eta_sigma = [0.0; 6];
    let tol = |c: f64| 1e-12 * c.abs().max(1.0);
    // With the covariance following θ and η estimated, the evaluation at the
    // end of a θ step only serves the η step that follows (its η gradient and
    // information), so it skips `∂P/∂θ` (4 of the 9 covariance derivatives);
    // when that η step is not taken, the point is evaluated again in full.
    // After an iteration whose η did not move, the θ step is evaluated in
    // full directly (η at a clamp: the η step is likely not taken again).
    let mut eta_moved = true;
    // The previous iteration's η scoring step and the factor it was taken
    // with (secant damping, see `secant_eta_factor`).
    let mut last_eta_step: Option<([f64; 6], f64)> = None;
    let mut eta_last: Option<f64> = None;
    // A θ-only evaluation whose θ step is below the tolerance is evaluated
    // again in full; `true` when that happened.
    let upgrade = |ev: Evaluation, th: &Theta, et: &[f64; 6]| -> Result<(Evaluation, bool)> {
        if ev.mode == full {
            return Ok((ev, false));
        }
        let (dth, sth) = theta_step(&ev.total, &free, follows)?;
        if step_ratio(&dth, &sth, &free, et, &[0.0; 6], &[0.0; 6], bounds) < opts.step_tolerance {
            Ok((prob.evaluate(th, &theta_ref, et, full)?, true))
        } else {
            Ok((ev, false))
        }
    };
    // The loop stopped after an iteration start that was evaluated lean (its
    // η step and σ are then taken from the final full evaluation).
    let mut stopped_at_lean_start = false;
    // Once an iteration start had to be evaluated again in full (θ's step
    // below the tolerance, η's not yet), the later ones are evaluated in
    // full directly: θ stays settled while η finishes.
    let mut theta_settled = false;
    for it in 0..opts.max_iterations {
        let upgraded;
        (ev, upgraded) = upgrade(ev, &theta, &eta)?;
        theta_settled |= upgraded;
        let at_full = ev.mode == full;
        let (dth, sth) = theta_step(&ev.total, &free, follows)?;
        let es = if eta_derivs && at_full {
            eta_step(&ev.total, &eta, bounds, reentry, &opts.eta_held)
        } else {
            EtaStep::none()
        };
        let (deta, seta) = (es.step, es.sigma);
        if at_full {
            eta_sigma = seta;
        }
        let mut ratio = step_ratio(&dth, &sth, &free, &eta, &deta, &seta, bounds);
        if es.leaving {
            // A scale leaving its clamp: not converged, whatever its σ says.
            ratio = ratio.max(1.0);
        }
        if eta_derivs && at_full {
            eta_last = Some(eta_ratio(&eta, &deta, &seta, bounds));
        }
        if opts.theta_convergence && eta_derivs && !es.leaving {
            let r = theta_ratio(&ev.total, &dth, &sth, &free, &deta);
            if r < opts.step_tolerance {
                termination = Termination::StepTolerance { step_over_sigma: r, threshold: opts.step_tolerance };
                break;
            }
        }
        if ratio < opts.step_tolerance {
            // Converged: the remaining step is negligible against σ, so it is not
            // taken (the estimate is the point the derivatives were evaluated at).
            termination = Termination::StepTolerance { step_over_sigma: ratio, threshold: opts.step_tolerance };
            break;
        }
        let previous = objective(&ev, &theta);
        let lambda;
        if follows {
            // θ step on the profile cost J at fixed η (cost-only halvings).
            let accept_j = |t: &Evaluation, th: &Theta, _: &[f64; 6]| {
                let c = objective(t, th);
                (c <= previous + tol(previous), c)
            };
            let theta_mode = if eta_derivs && eta_moved { Mode::eta_only(follows) } else { full };
            match line_search(prob, &theta, &eta, &dth, &[0.0; 6], &theta_ref, theta_mode, false, opts, &accept_j)? {
                Search::Accepted { theta: th, ev: e, lambda: l, .. } => {
                    theta = th;
                    ev = *e;
                    lambda = l;
                }
                Search::Rejected { cost } => {
                    // The θ-score holds the input log-Jacobian's weights, which
                    // depend on θ through S, so it is not J's exact gradient and
                    // near its root the scoring step need not lower J (a `high`
                    // drive stopped so, J up by 2.5e-11 relative, and fell back).
                    // The estimate is the score's root: take the full step when
                    // it shrinks the score in the scoring metric, as the joint
                    // step with the covariance held does.
                    let th = theta_add(&theta, &dth, 1.0);
                    let before = score_norm(&ev.total, &free, follows);
                    let rescue = if th.validate().is_ok() {
                        prob.evaluate(&th, &theta_ref, &eta, full).ok().filter(|t| {
                            let after = score_norm(&t.total, &free, follows);
                            after.is_finite() && after < before
                        })
                    } else {
                        None
                    };
                    match rescue {
                        Some(t) => {
                            theta = th;
                            ev = t;
                            lambda = 1.0;
                        }
                        None => {
                            termination = Termination::CostIncreased { cost, previous, halvings: opts.max_halvings };
                            stopped_at_lean_start = !at_full;
                            break;
                        }
                    }
                }
            }
            if eta_derivs {
                // η step on the marginal likelihood M at fixed θ (cost-only halvings).
                let es = eta_step(&ev.total, &eta, bounds, reentry, &opts.eta_held);
                let (deta, seta) = (es.step, es.sigma);
                eta_sigma = seta;
                ratio = ratio.max(eta_ratio(&eta, &deta, &seta, bounds));
                if es.leaving {
                    ratio = ratio.max(1.0);
                }
                eta_moved = false;
                // Lean: the next evaluation in full where this iteration is the
                // last (its step below the tolerance) or θ has settled.
                let next_mode = if theta_settled || ratio < opts.step_tolerance { full } else { start_mode };
                if deta.iter().any(|x| *x != 0.0) {
                    let factor = if opts.eta_secant_damping { secant_eta_factor(&deta, last_eta_step) } else { 1.0 };
                    let deta_raw = deta;
                    let deta = damp_eta_step(&deta, &eta, factor, bounds);
                    let previous_m = ev.total.merit();
                    let accept_m = |t: &Evaluation, _: &Theta, _: &[f64; 6]| {
                        let c = t.total.merit();
                        (c <= previous_m + tol(previous_m), c)
                    };
                    match line_search(
                        prob, &theta, &eta, &[0.0; 4], &deta, &theta_ref, next_mode, false, opts, &accept_m,
                    )? {
                        Search::Accepted { eta: et, ev: e, lambda: l, .. } => {
                            eta = et;
                            ev = *e;
                            eta_moved = true;
                            last_eta_step = Some((deta_raw, factor * l));
                        }
                        Search::Rejected { cost } => {
                            termination =
                                Termination::CostIncreased { cost, previous: previous_m, halvings: opts.max_halvings };
                            ev = prob.evaluate(&theta, &theta_ref, &eta, full)?;
                            break;
                        }
                    }
                }
                // An η step not taken leaves the θ step's evaluation, without ∂P/∂θ.
                if ev.mode != full && ev.mode != start_mode {
                    ev = prob.evaluate(&theta, &theta_ref, &eta, next_mode)?;
                }
            }
        } else {
            // Joint step. Accept when the objective falls, or when the corrected
            // score (whose root is the estimate; the bias term is not an exact
            // gradient) shrinks in the Fisher metric.
            let previous_q = score_norm(&ev.total, &free, follows);
            let accept = |t: &Evaluation, th: &Theta, _: &[f64; 6]| {
                let c = objective(t, th);
                (c <= previous + tol(previous) || score_norm(&t.total, &free, follows) < previous_q, c)
            };
            match line_search(prob, &theta, &eta, &dth, &deta, &theta_ref, full, true, opts, &accept)? {
                Search::Accepted { theta: th, eta: et, ev: e, lambda: l } => {
                    theta = th;
                    eta = et;
                    ev = *e;
                    lambda = l;
                }
                Search::Rejected { cost } => {
                    termination = Termination::CostIncreased { cost, previous, halvings: opts.max_halvings };
                    break;
                }
            }
        }
        history.push(IterationRecord {
            theta,
            eta,
            cost: objective(&ev, &theta),
            step_over_sigma: ratio,
            step_factor: lambda,
        });
        if ratio < opts.step_tolerance {
            termination = Termination::StepTolerance { step_over_sigma: ratio, threshold: opts.step_tolerance };
            break;
        }
        if eta_derivs && follows && opts.final_step_check {
            // Lean: in full only where the θ step alone is below the tolerance.
            let upgraded;
            (ev, upgraded) = upgrade(ev, &theta, &eta)?;
            theta_settled |= upgraded;
        }
        if eta_derivs && follows && ev.mode == full {
            // The remaining steps at the new point (no filter evaluation: `ev`
            // is in full mode here).
            let (dth, sth) = theta_step(&ev.total, &free, follows)?;
            let es = eta_step(&ev.total, &eta, bounds, reentry, &opts.eta_held);
            let (deta, seta) = (es.step, es.sigma);
            eta_last = Some(eta_ratio(&eta, &deta, &seta, bounds));
            // A scale leaving its clamp is not converged, whatever its σ says.
            if opts.final_step_check && !es.leaving {
                let r = step_ratio(&dth, &sth, &free, &eta, &deta, &seta, bounds);
                if r < opts.step_tolerance {
                    termination = Termination::StepTolerance { step_over_sigma: r, threshold: opts.step_tolerance };
                    break;
                }
            }
            if opts.theta_convergence && !es.leaving {
                let r = theta_ratio(&ev.total, &dth, &sth, &free, &deta);
                if r < opts.step_tolerance {
                    termination = Termination::StepTolerance { step_over_sigma: r, threshold: opts.step_tolerance };
                    break;
                }
            }
        }
        if it + 1 == opts.max_iterations {
            termination = Termination::MaxIterations { iterations: opts.max_iterations, step_over_sigma: ratio };
        }
    }
    if ev.mode != full {
        // Lean: the report needs the η derivatives at the estimate (the loop
        // ran out of iterations, or a θ step from a lean start failed).
        ev = prob.evaluate(&theta, &theta_ref, &eta, full)?;
        let es = eta_step(&ev.total, &eta, bounds, reentry, &opts.eta_held);
        eta_last = Some(eta_ratio(&eta, &es.step, &es.sigma, bounds));
        if stopped_at_lean_start {
            eta_sigma = es.sigma;
        }
    }
    let report = PassReport {
        theta_reference: theta_ref,
        theta,
        initial_cost,
        final_cost: objective(&ev, &theta),
        termination,
        history,
        eta_step_over_sigma: eta_last,
    };
    Ok(PassOutcome { theta, eta, eval: ev, report, free, unobservable, eta_sigma })
}

/// The instruction set the filter's kernels run with in this process:
/// `"avx2"` where the CPU has AVX2 and FMA (x86-64, detected at run time),
/// else `"baseline"` (the build's target features, SSE2 on a default x86-64
/// build). The environment variable `ODOCAL_SIMD=baseline` forces the
/// baseline; it is read once per process. Both give results
/// identical to the bit; AVX2 is faster (docs/performance.md, stop 22).
///
/// ```
/// let set = odocal::eiv::kernel_instruction_set();
/// assert!(set == "avx2" || set == "baseline");
/// ```
pub fn kernel_instruction_set() -> &'static str {
    match filter::kernels() {
        filter::Kernels::Avx2 => "avx2",
        filter::Kernels::Baseline => "baseline",
    }
}

/// Estimates θ (and the noise scales η) by the EIV method of SPEC §10,
/// starting from `theta_start` (batch Gauss-Newton on all segments).
///
/// Two passes of Fisher scoring on the objective M of the module docs;
/// the covariance recursion of pass i is linearised at the θ that pass
/// starts from. Returns the estimate with `H_θ⁻¹`, the estimated noise in
/// physical units, observability and consistency diagnostics, and typed
/// warnings. Errors only for invalid input, a singular information matrix
/// (with `fix_unobservable` off) or a numerically failing filter (naming
/// the window).
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{eiv, sim, Theta};
/// let out = sim::simulate(&sim::SimOptions { length_km: 1.0, substeps: 1, ..sim::SimOptions::noise_free(3) })?;
/// let d = &out.drive;
/// let input = eiv::EivInput {
///     sample_time_s: d.sample_time_s(), parts: d.parts(), px: d.px(), py: d.py(), psi: d.psi(),
///     n_rl: d.n_rl(), n_rr: d.n_rr(), beta: d.beta(), a_y: d.a_y(), reference_measured: None,
/// };
/// let start = Theta { c_e: 1.951, ..out.sidecar.theta_true };
/// let report = eiv::estimate(&input, &start, &eiv::EivOptions::default())?;
/// assert!((report.theta.c_e - 1.95).abs() < 1e-6);
/// # Ok(()) }
/// ```
pub fn estimate(input: &EivInput<'_>, theta_start: &Theta, opts: &EivOptions) -> Result<EivReport> {
    if opts.estimate_time_constants {
        return tau::estimate_with_time_constants(input, theta_start, opts);
    }
    estimate_from(input, theta_start, &[0.0; 6], opts).map(|(report, _)| report)
}

/// [`estimate`] at the time constants of `opts.noise`, starting from η =
/// `eta_start`; also returns the Gaussian negative log-likelihood
/// `½ Σ (νᵀS⁻¹ν + log det S)` (without 2π terms) at the estimate, before
/// any bias correction.
pub(crate) fn estimate_from(
    input: &EivInput<'_>,
    theta_start: &Theta,
    eta_start: &[f64; 6],
    opts: &EivOptions,
) -> Result<(EivReport, f64)> {
    let t0 = Instant::now();
    opts.validate()?;
    input.validate()?;
    theta_start.validate()?;
    let windows = make_windows(input.parts, opts.window_samples);
    if windows.is_empty() {
        return Err(Error::NoSegments("EIV needs a drive part of at least two samples".into()));
    }
    // `FromReadings` is resolved once here, on the drive's readings: the
    // rest of the fit sees `Given` with the step found, or `ScaledWithWhite`
    // (and so does a bootstrap of the fit: `bootstrap` resolves it from the
    // report, not from its replicates' readings).
    let q_found = opts.quantisation_level.step_found(input);
    let resolved;
    let opts = if opts.quantisation_level == QuantisationLevel::FromReadings {
        resolved = opts.with_resolved_quantisation(q_found);
        &resolved
    } else {
        opts
    };
    let prob = Problem::new(input, windows, opts);
    let mut theta = *theta_start;
    let mut eta = if opts.fix_noise { [0.0; 6] } else { *eta_start };
    let mut free = opts.free;
    let mut unobservable = Vec::new();
    let mut passes = Vec::new();
    let mut last: Option<(Evaluation, [f64; 6])> = None;
    // With the covariance following θ there is no reference to update: one pass.
    let passes_to_run = if opts.covariance == CovarianceMode::FollowsTheta { 1 } else { opts.passes };
    for pass in 0..passes_to_run {
        let out = scoring_pass(&prob, theta, eta, theta, free, pass == 0, opts)?;
        if pass == 0 {
            unobservable = out.unobservable.clone();
            free = out.free;
        }
        theta = out.theta;
        eta = out.eta;
        passes.push(out.report);
        last = Some((out.eval, out.eta_sigma));
    }
    let Some((ev, mut eta_sigma)) = last else {
        return Err(Error::Numerical("no EIV pass ran".into()));
    };
    let termination = passes
        .last()
        .map(|p| p.termination)
        .unwrap_or(Termination::MaxIterations { iterations: 0, step_over_sigma: f64::NAN });
    let cov = free_inverse(&ev.total.h_theta, &free).unwrap_or_else(|| Matrix4::from_element(f64::NAN));
    let sandwich = cov * ev.total.opg * cov;
    let sigma_sandwich: [f64; 4] = free_sigma(&free, |i| sandwich[(i, i)]);
    let sigma_block: [f64; 4] = match ev.total.blocks.meat() {
        Some(b) => {
            let c = cov * b * cov;
            free_sigma(&free, |i| c[(i, i)])
        }
        None => [f64::NAN; 4],
    };
    // The reported covariance ([`CovarianceEstimate`]).
    let cov_reported = match opts.covariance_estimate {
        CovarianceEstimate::Model => cov,
        CovarianceEstimate::LargerOfModelAndBlock => inflate_to_block(&cov, &ev.total.blocks),
    };
    let eta_free: [bool; 6] = std::array::from_fn(|j| !opts.fix_noise && eta_sigma[j] > 0.0);
    let (noise_cov, theta_eta_sensitivity) = if opts.noise_estimate_in_covariance && eta_free.iter().any(|f| *f) {
        let theta_ref = passes.last().map(|p| p.theta_reference).unwrap_or(theta);
        let follows = opts.covariance == CovarianceMode::FollowsTheta;
        let by_symmetry = prob.mixed_partials_by_symmetry();
        noise_estimate_covariance(&prob, &theta, &theta_ref, &eta, &eta_free, &ev.total, &cov, follows, by_symmetry)?
    } else {
        (Matrix4::zeros(), [[0.0; 6]; 4])
    };
    let sigma_noise_estimate: [f64; 4] = free_sigma(&free, |i| noise_cov[(i, i)]);
    let cov_reported = cov_reported + noise_cov;
    let sigma: [f64; 4] = free_sigma(&free, |i| cov_reported[(i, i)]);
    let sigma_fisher: [f64; 4] = match fisher_covariance(&ev.total.info, &free, &eta_free) {
        Some(c) => free_sigma(&free, |i| c[(i, i)]),
        None => [f64::NAN; 4],
    };
    let observability = observability_of(&ev.total.h_theta, &free, unobservable.clone(), opts);
    let first_order_bias =
        if opts.covariance == CovarianceMode::FollowsTheta { first_order_bias(&ev.total, &free) } else { None };

    let mut warnings = Vec::new();
    if !unobservable.is_empty() {
        warnings.push(EivWarning::Unobservable { parameters: unobservable });
    }
    if !termination.converged() {
        warnings.push(EivWarning::NotConverged { termination });
    }
    if !opts.fix_noise {
        for j in 0..NETA {
            if eta[j] >= opts.eta_bounds[1] - 1e-9 {
                warnings.push(EivWarning::NoiseAtUpperClamp { source: NOISE_SOURCES[j], eta: eta[j] });
            }
        }
    }
    // The null of the innovation checks: one more (objective-only) filter
    // pass at the estimate, with the recursion of the floor-free null.
    let null_sums = match opts.innovation_null {
        InnovationNull::FittedModel => None,
        InnovationNull::FloorsAsRegularisation => {
            let theta_ref = passes.last().map(|p| p.theta_reference).unwrap_or(theta);
            let mode = Mode::cost(opts.covariance == CovarianceMode::FollowsTheta);
            Some(prob.evaluate_with(&theta, &theta_ref, &eta, mode, true)?.windows)
        }
    };
    let mut diags = Vec::with_capacity(prob.windows.len());
    for (i, (w, s)) in prob.windows.iter().zip(&ev.windows).enumerate() {
        let nis = if s.updates > 0 { s.quad / (3 * s.updates) as f64 } else { f64::NAN };
        let lag1: [f64; 3] = std::array::from_fn(|c| if s.e2[c] > 0.0 { s.lag1[c] / s.e2[c] } else { 0.0 });
        let (nis0, lag1_0) = match null_sums.as_ref().and_then(|n| n.get(i)) {
            Some(n) if n.updates > 0 => (
                n.quad_null / (3 * n.updates) as f64,
                std::array::from_fn(|c| if n.e2_null[c] > 0.0 { n.lag1_null[c] / n.e2_null[c] } else { 0.0 }),
            ),
            _ => (1.0, [0.0; 3]),
        };
        if s.updates > 0 {
            let band = [opts.nis_band[0] * nis0.min(1.0), opts.nis_band[1] * nis0.max(1.0)];
            if nis > opts.divergence_nis {
                warnings.push(EivWarning::FilterDiverged { window: w.index, nis, threshold: opts.divergence_nis });
            } else if !(band[0]..=band[1]).contains(&nis) {
                warnings.push(EivWarning::InconsistentInnovations { window: w.index, nis, band });
            }
            let comps = [PoseComponent::X, PoseComponent::Y, PoseComponent::Heading];
            for c in 0..3 {
                let (above, below) = (lag1[c] - lag1_0[c].max(0.0), lag1_0[c].min(0.0) - lag1[c]);
                let below_limit = match opts.innovation_null {
                    InnovationNull::FittedModel => opts.max_lag1,
                    InnovationNull::FloorsAsRegularisation => opts.max_lag1_below,
                };
                if above > opts.max_lag1 || below > below_limit {
                    warnings.push(EivWarning::CorrelatedInnovations {
                        window: w.index,
                        component: comps[c],
                        lag1: lag1[c],
                        expected: lag1_0[c],
                        threshold: if above > opts.max_lag1 { opts.max_lag1 } else { below_limit },
                    });
                }
            }
        }
        diags.push(WindowDiagnostics {
            window: *w,
            updates: s.updates,
            nis,
            lag1,
            nis_without_floors: nis0,
            lag1_without_floors: lag1_0,
        });
    }
    let halves =
        halves_check(&ev, &theta, &free, opts.covariance == CovarianceMode::FollowsTheta, opts.covariance_estimate);
    if let Some(h) = &halves {
        for i in 0..4 {
            if h.z[i].abs() > opts.max_half_z {
                warnings.push(EivWarning::UnstableAcrossHalves {
                    parameter: PARAMETERS[i],
                    z: h.z[i],
                    threshold: opts.max_half_z,
                });
            }
        }
    }
    if opts.heading_scale == HeadingScale::TiedToPosition {
        // The heading white noise was scaled by η_3: report it so.
        eta[5] = eta[3];
        eta_sigma[5] = 0.0;
    }
    let iterations = passes.iter().map(|p| p.history.len()).sum();
    let theta_uncorrected = theta;
    let neg_log_likelihood = 0.5 * (ev.total.quad + ev.total.logdet);
    let mut report = EivReport {
        initial_theta: *theta_start,
        theta,
        first_order_bias,
        theta_uncorrected,
        bias_subtracted: [0.0; 4],
        sigma_bias_correction: [0.0; 4],
        bias_replicates_failed: Vec::new(),
        free,
        covariance: to_array(&cov_reported),
        sigma,
        sigma_sandwich,
        sigma_block,
        sigma_fisher,
        sigma_noise_estimate,
        theta_eta_sensitivity,
        eta_theta_sensitivity: eta_on_theta(&ev.total.info, &free, &eta_free),
        eta,
        eta_sigma,
        evaluations: prob.evaluations.get(),
        noise: {
            let mut n = opts.noise.scaled(&eta);
            if opts.quantisation_level == QuantisationLevel::Given {
                n.quantisation_step_rev_per_s = opts.noise.quantisation_step_rev_per_s;
            }
            if opts.lateral_noise == LateralNoise::Stated {
                n.lateral_acceleration_sigma_m_per_s2 = opts.noise.lateral_acceleration_sigma_m_per_s2;
                n.sideslip_sigma_rad = opts.noise.sideslip_sigma_rad;
            }
            n
        },
        final_cost: ev.total.merit(),
        iterations,
        termination,
        passes,
        observability,
        windows: diags,
        halves,
        warnings,
        updates: ev.total.updates,
        timing_s: t0.elapsed().as_secs_f64(),
        time_constants: None,
        quantisation_step_from_readings: q_found,
    };
    apply_bias_correction(input, &mut report, opts)?;
    Ok((report, neg_log_likelihood))
}

/// Applies `opts.bias_correction` to a fit made without it (nothing for
/// [`BiasCorrection::None`]): runs the [`bootstrap`] it names at the fit
/// (replicates on `opts.bootstrap_inputs`, holding the fitted noise or
/// re-estimating it, `opts.bootstrap_noise`; in antithetic pairs with
/// `opts.bootstrap_antithetic`), subtracts its bias from `report.theta`
/// (every free parameter or c_e only) and adds the bias's Monte Carlo
/// covariance to `report.covariance` and `report.sigma`.
///
/// [`estimate`] calls it at its end; `calibrate` calls it itself after
/// deciding whether to fall back, so that a fit it replaces by batch
/// Gauss-Newton costs no bootstrap. `report` must be that of [`estimate`]
/// on `input` with `opts` except for the correction (and with its
/// `bias_subtracted` zero). With time constants chosen by the fit
/// ([`EivReport::time_constants`]) the replicates hold them.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{eiv, sim};
/// let out = sim::simulate(&sim::SimOptions { length_km: 1.0, ..sim::SimOptions::paper(2) })?;
/// let input = eiv::EivInput::from_drive(&out.drive);
/// let mut opts = eiv::EivOptions { fix_noise: true, ..Default::default() };
/// let mut report = eiv::estimate(&input, &out.sidecar.theta_true, &opts)?;
/// opts.correct_bias(2, 0); // one antithetic pair
/// eiv::apply_bias_correction(&input, &mut report, &opts)?;
/// assert_ne!(report.theta, report.theta_uncorrected);
/// // Each corrected (free) parameter's σ includes the correction's Monte Carlo error.
/// for (s, free) in report.sigma_bias_correction.iter().zip(report.free) {
///     assert_eq!(*s > 0.0, free);
/// }
/// // The same as asking `estimate` for the correction.
/// assert_eq!(eiv::estimate(&input, &out.sidecar.theta_true, &opts)?.theta, report.theta);
/// # Ok(()) }
/// ```
pub fn apply_bias_correction(input: &EivInput<'_>, report: &mut EivReport, opts: &EivOptions) -> Result<()> {
    let BiasCorrection::Bootstrap { replicates, seed, all_parameters } = opts.bias_correction else {
        return Ok(());
    };
    opts.validate()?;
    if report.bias_subtracted.iter().any(|b| *b != 0.0) {
        return Err(Error::InvalidOption {
            field: "bias_correction",
            reason: "the report was already corrected".into(),
        });
    }
    let t0 = Instant::now();
    // The fit's own quantisation level (as `estimate` resolved it on the
    // drive's readings) and time constants.
    let mut opts = EivOptions {
        estimate_time_constants: false,
        ..opts.with_resolved_quantisation(report.quantisation_step_from_readings)
    };
    if let Some(tc) = &report.time_constants {
        opts.noise.wheel_common_time_constant_s = tc.wheel_common_s;
        opts.noise.wheel_differential_time_constant_s = tc.wheel_differential_s;
        opts.noise.drift_time_constant_s = tc.drift_s;
    }
    let opts = &opts;
    // The replicates are fitted without correction (their mean estimates
    // the uncorrected estimator's mean at θ̂).
    let inner = match opts.bootstrap_noise {
        BootstrapNoise::Reestimated => EivOptions { bias_correction: BiasCorrection::None, ..opts.clone() },
        BootstrapNoise::HeldAtFit => {
            EivOptions { bias_correction: BiasCorrection::None, noise: report.noise, fix_noise: true, ..opts.clone() }
        }
    };
    let boot = bootstrap(
        input,
        &*report,
        &inner,
        &BootstrapOptions {
            replicates,
            seed,
            true_inputs: opts.bootstrap_inputs,
            antithetic: opts.bootstrap_antithetic,
            ..Default::default()
        },
    )?;
    let b = boot.bias;
    report.bias_subtracted = if all_parameters { b } else { [b[0], 0.0, 0.0, 0.0] };
    report.theta = theta_add(&report.theta, &report.bias_subtracted, -1.0);
    // The subtracted bias is a mean of B replicates: its Monte Carlo
    // covariance (replicates' covariance / B) joins θ's.
    let corrected: [bool; 4] = std::array::from_fn(|i| report.free[i] && (all_parameters || i == 0));
    let mc = boot.mean_covariance();
    let mut cov = report.covariance;
    for i in 0..4 {
        for j in 0..4 {
            if corrected[i] && corrected[j] {
                cov[i][j] += mc[i][j];
            }
        }
    }
    report.covariance = cov;
    report.sigma_bias_correction = free_sigma(&corrected, |i| mc[i][i]);
    report.bias_replicates_failed = boot.failed;
    report.sigma = free_sigma(&report.free, |i| cov[i][i]);
    report.timing_s += t0.elapsed().as_secs_f64();
    Ok(())
}

/// The first-order bias of the profile cost's root ([`FirstOrderBias`]):
/// `H_θ⁻¹ (g_logdet − g_corr)` over the free parameters, from the sums of
/// one filter pass with the covariance following θ. None when `H_θ` is
/// singular over `free`.
pub(crate) fn first_order_bias(sums: &WindowSums, free: &[bool; 4]) -> Option<FirstOrderBias> {
    let inv = free_inverse(&sums.h_theta, free)?;
    let mask = nalgebra::Vector4::from_fn(|i, _| if free[i] { 1.0 } else { 0.0 });
    let gl = sums.grad_logdet.component_mul(&mask);
    let gc = sums.grad_correction.component_mul(&mask);
    let gap = gl - gc;
    let b = inv * gap;
    let b_l = inv * gl;
    let arr = |v: nalgebra::Vector4<f64>| -> [f64; 4] { std::array::from_fn(|i| v[i]) };
    let conditional = std::array::from_fn(|i| {
        let h = sums.h_theta[(i, i)];
        if free[i] && h > 0.0 {
            gap[i] / h
        } else {
            0.0
        }
    });
    Some(FirstOrderBias {
        score_logdet: arr(gl),
        score_correction: arr(gc),
        bias: arr(b),
        bias_logdet_only: arr(b_l),
        bias_conditional: conditional,
    })
}

/// θ from each half of the windows (split by measurement updates), one
/// scoring step from the joint estimate.
fn halves_check(
    ev: &Evaluation,
    theta: &Theta,
    free: &[bool; 4],
    follows: bool,
    estimate: CovarianceEstimate,
) -> Option<HalvesCheck> {
    if ev.windows.len() < 2 {
        return None;
    }
    let total = ev.total.updates;
    let mut first = WindowSums::zero();
    let mut second = WindowSums::zero();
    let mut acc = 0usize;
    for w in &ev.windows {
        if acc * 2 < total {
            first.add(w);
        } else {
            second.add(w);
        }
        acc += w.updates;
    }
    let (s1, sd1) = theta_step(&first, free, follows).ok()?;
    let (s2, sd2) = theta_step(&second, free, follows).ok()?;
    let robust = |sums: &WindowSums, sd: [f64; 4]| -> [f64; 4] {
        match (estimate, free_inverse(&sums.h_theta, free)) {
            (CovarianceEstimate::LargerOfModelAndBlock, Some(c)) => {
                let r = inflate_to_block(&c, &sums.blocks);
                std::array::from_fn(|i| r[(i, i)].max(0.0).sqrt())
            }
            _ => sd,
        }
    };
    let (sd1, sd2) = (robust(&first, sd1), robust(&second, sd2));
    let t1 = theta_add(theta, &s1, 1.0);
    let t2 = theta_add(theta, &s2, 1.0);
    let (a1, a2) = (t1.to_array(), t2.to_array());
    let z = std::array::from_fn(|i| {
        let v = sd1[i] * sd1[i] + sd2[i] * sd2[i];
        if free[i] && v > 0.0 {
            (a1[i] - a2[i]) / v.sqrt()
        } else {
            0.0
        }
    });
    Some(HalvesCheck { first: t1, second: t2, z })
}

/// Step in η of the forward difference of the θ-score
/// ([`EivOptions::noise_estimate_in_covariance`]): 1e-4, i.e. a 0.01 %
/// change of the source's variance. The score is smooth in η (one-sided
/// error ≈ h/2 relative); its sums have ≥ 10 significant digits to spare.
pub const ETA_SENSITIVITY_STEP: f64 = 1e-4;

/// The covariance that estimating η adds to θ̂: `A Σ_η Aᵀ` with
/// `A = −J⁻¹ ∂g_θ/∂η` over the free η ([`EivOptions::noise_estimate_in_covariance`];
/// J = ∂g_θ/∂θ, observed), and `A` itself (`[parameter][source]`, zero
/// columns for the fixed η). `sums` is the evaluation at (θ̂, η̂) (with η
/// derivatives), `cov` = `H_θ⁻¹` over the free θ (zero rows for the fixed
/// ones; also J⁻¹'s stand-in should J be singular). With
/// `mixed_partials_by_symmetry` (and the covariance following θ) `∂g_θ/∂η`
/// comes from the θ-displaced passes J needs (one per free θ); otherwise
/// from one more pass per free η, displaced by [`ETA_SENSITIVITY_STEP`].
#[allow(clippy::too_many_arguments)]
fn noise_estimate_covariance(
    prob: &Problem<'_>,
    theta: &Theta,
    theta_ref: &Theta,
    eta: &[f64; 6],
    eta_free: &[bool; 6],
    sums: &WindowSums,
    cov: &Matrix4<f64>,
    follows: bool,
    mixed_partials_by_symmetry: bool,
) -> Result<(Matrix4<f64>, [[f64; 6]; 4])> {
    let mut sens = [[0.0; 6]; 4];
    let idx: Vec<usize> = (0..NETA).filter(|j| eta_free[*j]).collect();
    let p = idx.len();
    let info = DMatrix::from_fn(p, p, |i, k| sums.i_eta[(idx[i], idx[k])]);
    let ridge = 1e-12 * (0..p).map(|i| info[(i, i)]).fold(0.0f64, f64::max);
    let Some(chol) = (info + DMatrix::identity(p, p) * ridge).cholesky() else {
        return Ok((Matrix4::zeros(), sens));
    };
    let cov_eta = chol.inverse();
    let g0 = theta_score(sums, follows);
    let h = ETA_SENSITIVITY_STEP;
    // The observed Jacobian of the θ-score, ∂g_θ/∂θ, by forward differences
    // of 1 % of each free parameter's σ: the t_r–d block of H_θ is nearly
    // singular, and the few-% difference between the scoring metric H_θ and
    // the observed Jacobian moved ∂t_r/∂η by 1.5× on a 4 km `high` drive
    // (the refits of the test agree with the observed one).
    let fidx: Vec<usize> = (0..4).filter(|i| cov[(*i, *i)] > 0.0).collect();
    let q = fidx.len();
    // ∂g_θ/∂η by symmetry of the mixed partials (stop 24): with the covariance
    // following θ, g_θ = ∂F/∂θ + G_T, F = ½Σνᵀ S⁻¹ν − Σ m log(1 − ŝ) and G_T
    // the input log-Jacobian's θ-score with its weights u held, so
    // ∂g_θ/∂η_j = ∂/∂θ (∂F/∂η_j) + ∂G_T/∂η_j. The first is the forward
    // difference in θ of `grad_profile`'s η entries at the θ-displaced points
    // the observed Jacobian needs anyway (evaluated with η derivatives), the
    // second is summed exactly by the filter (`grad_jacobian_eta`). That needs
    // 4 filter passes instead of 4 + one per free η. Where u depends on η in a
    // way the filter does not differentiate (the smoothed shares) or with the
    // covariance held (the corrected score's bias term), η is displaced instead.
    let by_symmetry = mixed_partials_by_symmetry && follows;
    // Every displaced point (θ first, then η), evaluated in one sweep.
    let steps: Vec<f64> = fidx.iter().map(|&k| 0.01 * cov[(k, k)].sqrt()).collect();
    let mut points: Vec<(Theta, [f64; 6])> = fidx
        .iter()
        .zip(&steps)
        .map(|(&k, &hk)| {
            let mut t = theta.to_array();
            t[k] += hk;
            (Theta::from_array(t), *eta)
        })
        .collect();
    if !by_symmetry {
        points.extend(idx.iter().map(|&j| {
            let mut e = *eta;
            e[j] += h;
            (*theta, e)
        }));
    }
    // By symmetry only the free η's columns are needed (a scale at its clamp is not estimated).
    let skip = if by_symmetry { (0..NETA).filter(|j| !eta_free[*j]).fold(0u8, |m, j| m | (1 << j)) } else { 0 };
    let evs = prob.evaluate_many(&points, theta_ref, Mode::full(follows, by_symmetry).skipping_eta(skip), false)?;
    let (ev_theta, ev_eta) = evs.split_at(q);
    let mut jac = DMatrix::zeros(q, q);
    for (c, (ev, hk)) in ev_theta.iter().zip(&steps).enumerate() {
        let dg = (theta_score(&ev.total, follows) - g0) / *hk;
        for (r, &i) in fidx.iter().enumerate() {
            jac[(r, c)] = dg[i];
        }
    }
    let jinv = match jac.try_inverse() {
        Some(ji) if (0..q).all(|i| ji[(i, i)] > 0.0) => {
            let mut m = Matrix4::zeros();
            for (r, &i) in fidx.iter().enumerate() {
                for (c, &k) in fidx.iter().enumerate() {
                    m[(i, k)] = ji[(r, c)];
                }
            }
            m
        }
        _ => *cov,
    };
    // ∂g_θ/∂η_j (4-vector) per free η.
    let dg_deta: Vec<nalgebra::Vector4<f64>> = if by_symmetry {
        idx.iter()
            .map(|&j| {
                let mut dg = sums.grad_jacobian_eta[j];
                for ((ev, hk), &i) in ev_theta.iter().zip(&steps).zip(&fidx) {
                    dg[i] += (ev.total.grad_profile[4 + j] - sums.grad_profile[4 + j]) / *hk;
                }
                dg
            })
            .collect()
    } else {
        ev_eta.iter().map(|ev| (theta_score(&ev.total, follows) - g0) / h).collect()
    };
    // A = −J⁻¹ ∂g_θ/∂η, 4 × p.
    let mut a = DMatrix::zeros(4, p);
    for (c, (&j, dg)) in idx.iter().zip(dg_deta).enumerate() {
        let col = -(jinv * dg);
        for i in 0..4 {
            a[(i, c)] = col[i];
            sens[i][j] = col[i];
        }
    }
    let out = &a * cov_eta * a.transpose();
    Ok((Matrix4::from_fn(|i, k| out[(i, k)]), sens))
}

/// [`CovarianceEstimate::LargerOfModelAndBlock`]: `cov` (an `H_θ⁻¹`)
/// with each parameter's σ raised to the block sandwich's where that is
/// larger, `D cov D` with `D = diag(max(1, σ_block,i/σ_i))`. `cov` itself
/// with fewer than two blocks.
fn inflate_to_block(cov: &Matrix4<f64>, blocks: &filter::BlockScores) -> Matrix4<f64> {
    let Some(meat) = blocks.meat() else {
        return *cov;
    };
    let sandwich = cov * meat * cov;
    let f: [f64; 4] = std::array::from_fn(|i| {
        let (m, b) = (cov[(i, i)], sandwich[(i, i)]);
        if m > 0.0 && b.is_finite() && b > m {
            (b / m).sqrt()
        } else {
            1.0
        }
    });
    Matrix4::from_fn(|i, j| cov[(i, j)] * f[i] * f[j])
}

/// The Cramér–Rao bound of θ for this drive: the inverse of the Gaussian
/// Fisher information at `theta` (θ_true) with the given (true) noise
/// model unscaled, over the free parameters of `opts`.
///
/// The innovations form of the state-space likelihood gives, with the
/// covariance recursion following θ (S depends on θ through `F_n Σ_n F_nᵀ`),
///
/// ```text
/// I_ij = Σ_k (∂ν_k/∂θ_i)ᵀ S_k⁻¹ (∂ν_k/∂θ_j) + ½ tr(S_k⁻¹ ∂S_k/∂θ_i S_k⁻¹ ∂S_k/∂θ_j)
/// ```
///
/// with the exact sensitivities of the filter. The second term is
/// information that the size of the innovations carries about θ when the
/// noise model is known (the wheel noise in metres scales with the wheel
/// circumferences); the mean-only part is reported too
/// ([`CrbReport::sigma_mean_only`]). η is not estimated (known noise), so
/// this is the bound of an estimator that knows the noise model;
/// [`CrbReport::sigma_noise_estimated`] is the bound with the noise scales
/// as nuisance parameters, the one an estimator that estimates the noise
/// model from the drive (the EIV default) can reach.
///
/// The sensitivities are linearised along `input`. For the bound at the
/// truth pass the *true* inputs, [`EivInput::from_drive_truth`] of a
/// simulated drive: along the measured ones the wheel noise counts as
/// excitation and the bound on t_r and d comes out too small (on the `high`
/// preset about half of t_r's).
///
/// ## References
/// R. H. Shumway, D. S. Stoffer, *Time Series Analysis and Its
/// Applications*, §6.3 (innovations form of the likelihood); the Gaussian
/// Fisher information `I = ∂μᵀΣ⁻¹∂μ + ½ tr(Σ⁻¹∂Σ Σ⁻¹∂Σ)` (e.g. S. M. Kay,
/// *Fundamentals of Statistical Signal Processing: Estimation Theory*, §3.9).
pub fn cramer_rao_bound(
    input: &EivInput<'_>,
    theta: &Theta,
    noise: &NoiseModel,
    opts: &EivOptions,
) -> Result<CrbReport> {
    opts.validate()?;
    noise.validate()?;
    input.validate()?;
    theta.validate()?;
    let windows = make_windows(input.parts, opts.window_samples);
    if windows.is_empty() {
        return Err(Error::NoSegments("the Cramér–Rao bound needs a drive part of at least two samples".into()));
    }
    // With `FromReadings` the bound takes `noise`'s q as the encoder's
    // (held, not scaled by η_0) where the readings lie on a lattice.
    let prob = Problem {
        noise: *noise,
        quantisation_given: opts.quantisation_level == QuantisationLevel::Given
            || opts.quantisation_level.step_found(input).is_some(),
        // The CRB uses the information matrix only.
        input_jacobian: InputJacobian::None,
        ..Problem::new(input, windows, opts)
    };
    let ev = prob.evaluate(theta, theta, &[0.0; 6], Mode::full(true, true))?;
    let h: Matrix4<f64> = ev.total.info.fixed_view::<4, 4>(0, 0).into_owned();
    let h_mean = ev.total.info_mean_theta;
    let singular = || Error::NotObservable {
        params: (0..4).filter(|i| opts.free[*i]).map(|i| crate::model::param::Param::THETA[i]).collect(),
        reason: "the information matrix is singular; fix some parameters (EivOptions::free)".into(),
    };
    let cov = free_inverse(&h, &opts.free).ok_or_else(singular)?;
    let cov_mean = free_inverse(&h_mean, &opts.free).ok_or_else(singular)?;
    let sd = |c: &Matrix4<f64>| std::array::from_fn(|i| if opts.free[i] { c[(i, i)].max(0.0).sqrt() } else { 0.0 });
    // η of the sources present (a zero σ gives a zero information row).
    let present = noise_sources_present(noise, opts.heading_scale == HeadingScale::Separate);
    let eta_free: [bool; 6] = std::array::from_fn(|j| present[j] && ev.total.info[(4 + j, 4 + j)] > 0.0);
    let sigma_noise_estimated = fisher_covariance(&ev.total.info, &opts.free, &eta_free).map(|c| sd(&c));
    Ok(CrbReport {
        theta: *theta,
        free: opts.free,
        information: to_array(&h),
        covariance: to_array(&cov),
        sigma: sd(&cov),
        information_mean_only: to_array(&h_mean),
        sigma_mean_only: sd(&cov_mean),
        sigma_noise_estimated,
    })
}

/// Which of the six noise log-scales η have a source in `noise` (a group
/// whose standard deviations are all zero carries no information about its
/// scale). η_5 (the heading white noise) is a separate scale only with
/// `heading_separate`; otherwise η_3 scales it with the position white noise.
fn noise_sources_present(noise: &NoiseModel, heading_separate: bool) -> [bool; 6] {
    let n = noise;
    let any = |v: &[f64]| v.iter().any(|x| *x > 0.0);
    [
        any(&[
            n.wheel_white_rel_sigma,
            n.quantisation_step_rev_per_s,
            n.lateral_acceleration_sigma_m_per_s2,
            n.sideslip_sigma_rad,
        ]),
        any(&[n.wheel_common_rel_sigma]),
        any(&[n.wheel_differential_rel_sigma]),
        if heading_separate {
            any(&[n.position_white_sigma_m])
        } else {
            any(&[n.position_white_sigma_m, n.heading_white_sigma_rad])
        },
        any(&[n.position_drift_sigma_m, n.heading_drift_sigma_rad]),
        heading_separate && any(&[n.heading_white_sigma_rad]),
    ]
}

/// The θ block of the inverse of the joint Fisher information of the free
/// θ and the estimated η that are not at a clamp (`eta_sigma > 0`).
/// `∂η̂/∂θ = −I_ηη⁻¹ I_ηθ` over the free η and θ ([`EivReport::eta_theta_sensitivity`]);
/// zeros when no η is free or `I_ηη` is singular.
fn eta_on_theta(info: &filter::MP, free: &[bool; 4], eta_free: &[bool; 6]) -> [[f64; 4]; 6] {
    let mut out = [[0.0; 4]; 6];
    let idx: Vec<usize> = (0..NETA).filter(|j| eta_free[*j]).collect();
    let p = idx.len();
    if p == 0 {
        return out;
    }
    let i_ee = DMatrix::from_fn(p, p, |a, b| info[(4 + idx[a], 4 + idx[b])]);
    let Some(chol) = i_ee.cholesky() else {
        return out;
    };
    for t in (0..4).filter(|t| free[*t]) {
        let col = DVector::from_fn(p, |a, _| info[(4 + idx[a], t)]);
        let x = chol.solve(&col);
        for (a, &j) in idx.iter().enumerate() {
            out[j][t] = -x[a];
        }
    }
    out
}

fn fisher_covariance(info: &filter::MP, free: &[bool; 4], eta_free: &[bool; 6]) -> Option<Matrix4<f64>> {
    let idx: Vec<usize> =
        (0..4).filter(|i| free[*i]).chain((0..NETA).filter(|j| eta_free[*j]).map(|j| 4 + j)).collect();
    let p = idx.len();
    let a = DMatrix::from_fn(p, p, |i, j| info[(idx[i], idx[j])]);
    let inv = a.cholesky()?.inverse();
    let mut out = Matrix4::zeros();
    for (i, &fi) in idx.iter().enumerate().filter(|(_, f)| **f < 4) {
        for (j, &fj) in idx.iter().enumerate().filter(|(_, f)| **f < 4) {
            out[(fi, fj)] = inv[(i, j)];
        }
    }
    Some(out)
}
