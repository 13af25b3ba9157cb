//! The Fisher-scoring problem: the windows of a drive and their summed filter passes.

use nalgebra::{DMatrix, Matrix4};
use rayon::prelude::*;

use super::filter::{self, run_window, Mode, WindowSums};
use super::{
    EivInput, EivOptions, HeadingScale, InputJacobian, LateralNoise, NoiseModel, QuantisationLevel, QuantisationModel,
    SideslipNoise, WheelNoiseScale, Window,
};
use crate::error::{Error, Result};
use crate::model::Theta;

/// Sums of all windows at one (θ, η).
pub(super) struct Evaluation {
    pub(super) total: WindowSums,
    pub(super) windows: Vec<WindowSums>,
    pub(super) mode: Mode,
}

/// [`filter::Mode::theta_skip`]'s bit of c_d ([`Problem::c_d_covariance_derivative`]).
const C_D_COLUMN: u8 = 1 << 1;

pub(super) struct Problem<'a> {
    pub(super) input: &'a EivInput<'a>,
    pub(super) windows: Vec<Window>,
    pub(super) noise: NoiseModel,
    pub(super) quantisation: QuantisationModel,
    /// [`QuantisationLevel::Given`]: q²/12 not scaled by η_0.
    pub(super) quantisation_given: bool,
    /// [`SideslipNoise::WhiteEquivalent`].
    pub(super) sideslip_white: bool,
    /// a_y and β noise held at the model's σ ([`LateralNoise::Stated`]).
    pub(super) lateral_stated: bool,
    /// a_y's σ held (`ResearchOptions::a_y_sigma_held`), β's as `lateral_stated` says.
    pub(super) a_y_sigma_held: Option<f64>,
    /// a_y's σ never below this while tied (`ResearchOptions::a_y_sigma_floor`), m/s².
    pub(super) a_y_sigma_floor: f64,
    /// The reference heading readings' white noise, rad, part of the
    /// heading's white-noise variance where it is estimated
    /// (`ResearchOptions::heading_white_sigma_floor`).
    pub(super) heading_white_floor: f64,
    pub(super) heading_separate: bool,
    pub(super) fitted_input: bool,
    pub(super) noise_input_half_width: usize,
    pub(super) input_jacobian: InputJacobian,
    pub(super) position_floor_m: f64,
    pub(super) coloured_jacobian_in_marginal: bool,
    pub(super) common_mode_jacobian: bool,
    /// [`ResearchOptions::position_drift_own_scale`](super::ResearchOptions::position_drift_own_scale).
    pub(super) position_drift_own_scale: bool,
    /// [`ResearchOptions::position_drift_time_constant_s`](super::ResearchOptions::position_drift_time_constant_s).
    pub(super) position_drift_time_constant_s: Option<f64>,
    /// [`ResearchOptions::heading_drift_min_eta`](super::ResearchOptions::heading_drift_min_eta).
    pub(super) heading_drift_min_eta: f64,
    /// Filter passes over the drive: with derivatives, objective only.
    pub(super) evaluations: std::cell::Cell<[usize; 2]>,
    /// Lean iteration starts in [`scoring_pass`](super::scoring::scoring_pass) (always on; off only in the
    /// test that holds them to the full evaluations' results).
    pub(super) lean_iterations: bool,
    /// [`ResearchOptions::c_d_covariance_derivative`](super::ResearchOptions::c_d_covariance_derivative):
    /// off, every pass leaves `∂P/∂c_d` out.
    pub(super) c_d_covariance_derivative: bool,
}

impl<'a> Problem<'a> {
    /// The problem of `opts` (its quantisation level already resolved) over `windows`.
    pub(super) fn new(input: &'a EivInput<'a>, windows: Vec<Window>, opts: &EivOptions) -> Self {
        Problem {
            input,
            windows,
            noise: opts.noise,
            quantisation: opts.quantisation,
            quantisation_given: opts.quantisation_level == QuantisationLevel::Given,
            sideslip_white: opts.research.sideslip_noise == SideslipNoise::WhiteEquivalent,
            lateral_stated: opts.lateral_noise == LateralNoise::Stated,
            a_y_sigma_held: opts.research.a_y_sigma_held,
            a_y_sigma_floor: opts.research.a_y_sigma_floor.unwrap_or(0.0),
            heading_white_floor: opts
                .research
                .heading_white_sigma_floor
                .filter(|_| opts.heading_floor_applies())
                .unwrap_or(0.0),
            heading_separate: opts.heading_scale == HeadingScale::Separate,
            fitted_input: opts.research.wheel_noise_scale != WheelNoiseScale::MeasuredInput,
            noise_input_half_width: opts.research.wheel_noise_scale.half_width(),
            input_jacobian: opts.research.input_jacobian,
            position_floor_m: opts.research.position_floor_m,
            coloured_jacobian_in_marginal: opts.research.coloured_jacobian_in_marginal,
            common_mode_jacobian: opts.research.common_mode_jacobian,
            position_drift_own_scale: opts.research.position_drift_own_scale,
            position_drift_time_constant_s: opts.research.position_drift_time_constant_s,
            heading_drift_min_eta: opts.research.heading_drift_min_eta,
            evaluations: std::cell::Cell::new([0; 2]),
            lean_iterations: true,
            c_d_covariance_derivative: opts.research.c_d_covariance_derivative,
        }
    }

    /// The same problem over other windows of the drive, its evaluations
    /// counted from zero.
    pub(super) fn with_windows(&self, windows: Vec<Window>) -> Problem<'a> {
        Problem { windows, evaluations: std::cell::Cell::new([0; 2]), ..*self }
    }

    /// Adds the evaluations of `part`, a problem over every `stride`-th
    /// window, as the passes over the whole drive they cost (rounded up).
    pub(super) fn count_evaluations_of(&self, part: &Problem<'_>, stride: usize) {
        let (mine, theirs) = (self.evaluations.get(), part.evaluations.get());
        self.evaluations.set(std::array::from_fn(|i| mine[i] + theirs[i].div_ceil(stride.max(1))));
    }
}

impl Problem<'_> {
    pub(super) fn evaluate(&self, theta: &Theta, theta_ref: &Theta, eta: &[f64; 6], mode: Mode) -> Result<Evaluation> {
        self.evaluate_with(theta, theta_ref, eta, mode, false)
    }

    /// [`Problem::evaluate`], with the null recursion of the innovation
    /// diagnostics when `null` ([`filter::Variances::null_without_floors`]).
    pub(super) fn evaluate_with(
        &self,
        theta: &Theta,
        theta_ref: &Theta,
        eta: &[f64; 6],
        mode: Mode,
        null: bool,
    ) -> Result<Evaluation> {
        let mut one = self.evaluate_many(&[(*theta, *eta, mode)], theta_ref, null)?;
        one.pop().ok_or_else(|| Error::Numerical("no filter evaluation".into()))
    }

    /// [`Problem::evaluate_with`] at several points `(θ, η)`, each in its
    /// own mode, in one parallel sweep over every (point, window) pair, so
    /// that two threads share the work of all the points rather than each
    /// point's few windows. Each point's totals are summed window by window
    /// in order: the results are the same to the bit as evaluating the
    /// points one by one, whatever the thread count.
    pub(super) fn evaluate_many(
        &self,
        points: &[(Theta, [f64; 6], Mode)],
        theta_ref: &Theta,
        null: bool,
    ) -> Result<Vec<Evaluation>> {
        let mut count = self.evaluations.get();
        for (_, _, mode) in points {
            count[usize::from(!mode.derivs)] += 1;
        }
        self.evaluations.set(count);
        let nw = self.windows.len();
        let vars: Vec<filter::Variances> = points.iter().map(|(_, eta, _)| self.variances(eta, null)).collect();
        let (input, windows) = (self.input, &self.windows);
        let skip = if self.c_d_covariance_derivative { 0 } else { C_D_COLUMN };
        let parts: Vec<Result<WindowSums>> = (0..points.len() * nw)
            .into_par_iter()
            .map(|t| {
                let (pi, wi) = (t / nw, t % nw);
                run_window(
                    input,
                    &windows[wi],
                    &points[pi].0,
                    theta_ref,
                    &vars[pi],
                    points[pi].2.skipping_theta(points[pi].2.theta_skip | skip),
                    None,
                )
            })
            .collect();
        let mut out = Vec::with_capacity(points.len());
        let mut it = parts.into_iter();
        for (_, _, mode) in points {
            let mut total = WindowSums::zero();
            let mut windows = Vec::with_capacity(nw);
            for p in it.by_ref().take(nw) {
                let p = p?;
                total.add(&p);
                windows.push(p);
            }
            out.push(Evaluation { total, windows, mode: *mode });
        }
        Ok(out)
    }

    /// Whether the filter's η derivatives give the θ-score's full
    /// η-dependence (see [`noise_estimate_covariance`](super::covariance::noise_estimate_covariance)): not with the
    /// smoothed-share log-Jacobian weights, whose η-dependence it does not
    /// differentiate.
    pub(super) fn mixed_partials_by_symmetry(&self) -> bool {
        !matches!(self.input_jacobian, InputJacobian::SmoothedShare | InputJacobian::SmoothedShareAll)
    }

    /// The filter's variances at η under this problem's noise options.
    pub(super) fn variances(&self, eta: &[f64; 6], null: bool) -> filter::Variances {
        let mut e = *eta;
        if !self.heading_separate {
            // Tied: η_3 scales the heading white noise too; η_5 has no effect.
            e[5] = e[3];
        }
        let mut v = self.noise.variances(&e, self.input.sample_time_s);
        v.quant_in_measurement = self.quantisation == QuantisationModel::Measurement;
        // A given step of zero is no quantisation: no remainder states.
        let no_quantisation = self.quantisation_given && self.noise.quantisation_step_rev_per_s == 0.0;
        v.quant_counting = self.quantisation == QuantisationModel::Counting && !no_quantisation;
        if self.quantisation_given {
            v.quant = self.noise.quantisation_step_rev_per_s * self.noise.quantisation_step_rev_per_s / 12.0;
            v.quant_scaled = false;
        }
        if self.lateral_stated {
            let unscaled = self.noise.variances(&[0.0; 6], self.input.sample_time_s);
            (v.a_y, v.beta, v.lateral_scaled) = (unscaled.a_y, unscaled.beta, false);
        }
        if let Some(sigma) = self.a_y_sigma_held {
            (v.a_y, v.a_y_scaled) = (sigma * sigma, false);
        }
        // Tied to the white wheel noise, a_y's variance is held at its floor
        // where η_0 would take it lower (it then does not follow η_0).
        let floor = self.a_y_sigma_floor * self.a_y_sigma_floor;
        if v.lateral_scaled && v.a_y_scaled && v.a_y < floor {
            (v.a_y, v.a_y_scaled) = (floor, false);
        }
        v.heading_white_floor = self.heading_white_floor * self.heading_white_floor;
        if self.sideslip_white {
            // The long-run variance of the Gauss-Markov error as white noise.
            let a = v.a_beta;
            (v.beta_white, v.beta) = (v.beta * (1.0 + a) / (1.0 - a), 0.0);
        }
        if self.position_drift_own_scale {
            // The heading drift on the heading white noise's scale (e[5] is
            // η_3 when the heading white noise is tied to the position's).
            let sigma = self.noise.heading_drift_sigma_rad;
            v.drift[2] = sigma * sigma * e[5].exp();
            v.heading_drift_on_white_scale = true;
        } else if e[4] < self.heading_drift_min_eta {
            // Below the floor the position drift alone follows η_4.
            let sigma = self.noise.heading_drift_sigma_rad;
            v.drift[2] = sigma * sigma * self.heading_drift_min_eta.exp();
            v.heading_drift_held = true;
        }
        if let Some(tau) = self.position_drift_time_constant_s {
            v.a_drift = (-self.input.sample_time_s / tau).exp();
        }
        v.heading_separate = self.heading_separate;
        v.fitted_input = self.fitted_input;
        v.input_jacobian = self.input_jacobian;
        v.noise_input_half_width = self.noise_input_half_width;
        v.position_floor_m = self.position_floor_m;
        v.coloured_jacobian_in_marginal = self.coloured_jacobian_in_marginal;
        v.common_mode_jacobian = self.common_mode_jacobian;
        v.null_without_floors = null;
        v
    }
}

/// Per parameter: `√max(var(i), 0)` where `mask[i]`, 0 elsewhere.
pub(super) fn free_sigma(mask: &[bool; 4], var: impl Fn(usize) -> f64) -> [f64; 4] {
    std::array::from_fn(|i| if mask[i] { var(i).max(0.0).sqrt() } else { 0.0 })
}

pub(super) fn to_array(m: &Matrix4<f64>) -> [[f64; 4]; 4] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// Inverse of the free block of `h`, embedded in 4×4 (None when singular).
pub(super) fn free_inverse(h: &Matrix4<f64>, free: &[bool; 4]) -> Option<Matrix4<f64>> {
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

pub(super) fn theta_add(theta: &Theta, step: &[f64; 4], lambda: f64) -> Theta {
    let a = theta.to_array();
    Theta {
        c_e: a[0] + lambda * step[0],
        c_d: a[1] + lambda * step[1],
        t_r: a[2] + lambda * step[2],
        d: a[3] + lambda * step[3],
    }
}
