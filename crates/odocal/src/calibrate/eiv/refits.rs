//! The refits after an EIV fit that failed its checks: with the noise
//! sources released (a scale at its lower clamp, or unconverged), with the
//! held noise levels estimated (after a fallback from a fit with levels
//! held), and with c_e held at the batch Gauss-Newton start's value (a
//! scale at its upper clamp), whose covariance carries the held c_e's σ.

use serde::{Deserialize, Serialize};

use super::{is_misspecification, HeldNoiseReleased};
use crate::eiv::{self, EivInput, EivOptions, EivReport, EivWarning, NoiseSource};
use crate::model::Theta;

/// The refit after a fit that failed its checks with a noise scale at its
/// upper clamp (`ResearchOptions::clamp_refit_hold_scale`,
/// `clamp_refit_common_mode_eta`): what was held, and the first fit. In
/// JSON only when the refit is the result.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct ClampRefit {
    /// c_e was held at the start's value.
    pub scale_held: bool,
    /// The common-mode wheel noise scale η_1 was held at this value.
    pub common_mode_eta: Option<f64>,
    /// The first fit's θ.
    pub first_theta: Theta,
    /// The first fit's noise scales η.
    pub first_eta: [f64; 6],
    /// The first fit's findings that say the model does not fit the data.
    pub first_findings: Vec<EivWarning>,
    /// The first fit's covariance (c_e free): the regression of the other
    /// parameters on c_e that the held c_e's σ is carried along.
    pub first_covariance: [[f64; 4]; 4],
}

/// A fit that failed its checks with a noise scale at its upper clamp,
/// fitted once more from the same start with c_e held at the start's
/// value (`ResearchOptions::clamp_refit_hold_scale`) and/or the common-mode
/// wheel noise scale held at `ResearchOptions::clamp_refit_common_mode_eta`;
/// the refit, the options it ran with and the first fit, when the refit
/// passes the checks and its t_r is not above the start's. `None` when neither option is set, the noise model is
/// fixed, no scale is at its upper clamp, or the refit fails.
pub(super) fn refit_at_clamp(
    input: &EivInput<'_>,
    theta: &Theta,
    filter: &EivOptions,
    first: &EivReport,
) -> Option<(EivReport, EivOptions, ClampRefit)> {
    let research = &filter.research;
    let hold_scale = research.clamp_refit_hold_scale && first.free[0] && first.free[1..].iter().any(|f| *f);
    let common_eta = research.clamp_refit_common_mode_eta;
    if filter.fix_noise || !(hold_scale || common_eta.is_some()) {
        return None;
    }
    let clamped = first.warnings.iter().any(|w| matches!(w, EivWarning::NoiseAtUpperClamp { .. }));
    if !clamped || !first.warnings.iter().any(|w| is_misspecification(w, first)) {
        return None;
    }
    let mut opts = filter.clone();
    if hold_scale {
        opts.free[0] = false;
    }
    if let Some(eta) = common_eta {
        opts.noise.wheel_common_rel_sigma *= (0.5 * eta).exp();
        opts.eta_held[NoiseSource::WheelCommon.index()] = true;
    }
    let again = eiv::estimate(input, theta, &opts).ok()?;
    if again.warnings.iter().any(|w| is_misspecification(w, &again)) {
        return None;
    }
    // Batch G-N's errors-in-variables bias puts its t_r above the truth; a
    // refit whose t_r lies above the start's is no correction of that bias
    // (on heavy wheel noise such refits erred by +4 … +10 %).
    if again.free[2] && again.theta.t_r > theta.t_r {
        return None;
    }
    let first = ClampRefit {
        scale_held: hold_scale,
        common_mode_eta: common_eta,
        first_theta: first.theta,
        first_eta: first.eta,
        first_findings: first.warnings.iter().filter(|w| is_misspecification(w, first)).cloned().collect(),
        first_covariance: first.covariance,
    };
    Some((again, opts, first))
}

/// The covariance of a refit that held c_e at its start's value, with the
/// start's uncertainty about c_e carried ([`carried_covariance`]), and its
/// σ (c_e's included).
pub(super) fn carry_held_scale(r: &mut EivReport, first: &[[f64; 4]; 4], v: f64) {
    r.covariance = carried_covariance(&r.covariance, r.free, first, v);
    r.sigma = std::array::from_fn(|i| if r.free[i] || i == 0 { r.covariance[i][i].max(0.0).sqrt() } else { 0.0 });
}

/// `cov` (a fit with c_e held; `free` its estimated parameters) with c_e's
/// variance `v` (the start's) carried: c_e's own variance, and for each
/// other free parameter its share along its regression on c_e,
/// `b_i = C_i,c_e / C_c_e,c_e` of `first` (the first fit's covariance, c_e
/// free): `C + b bᵀ v` with `b_c_e = 1`. The θ of the refit moves with the
/// held c_e as the first fit's joint distribution says the other
/// parameters move with c_e. Without a usable regression (c_e's variance
/// in `first` not positive) only c_e's own variance is added; with `v` not
/// positive, `cov` is returned as is.
pub(super) fn carried_covariance(cov: &[[f64; 4]; 4], free: [bool; 4], first: &[[f64; 4]; 4], v: f64) -> [[f64; 4]; 4] {
    let mut out = *cov;
    if !(v.is_finite() && v > 0.0) {
        return out;
    }
    let c00 = first[0][0];
    let b: [f64; 4] = std::array::from_fn(|i| match i {
        0 => 1.0,
        _ if free[i] && c00.is_finite() && c00 > 0.0 && first[i][0].is_finite() => first[i][0] / c00,
        _ => 0.0,
    });
    for (i, row) in out.iter_mut().enumerate() {
        for (j, c) in row.iter_mut().enumerate() {
            *c += b[i] * b[j] * v;
        }
    }
    out
}

/// The lower clamp of the noise scales in the refit of
/// [`refit_with_sources_released`]: a variance factor of e⁻⁸ (σ 1.8 % of
/// the starting model's), low enough to stand for an absent source and
/// high enough that the source's score still moves it (at the default
/// clamp, −20, a source's information is ~1e-17 of its starting value and
/// the step leaves it there).
pub(super) const RELEASED_LOWER_CLAMP: f64 = -8.0;

/// The refit of [`refit_with_sources_released`] may take this many times
/// the options' iterations.
const REFIT_ITERATION_FACTOR: usize = 2;

/// A fit that failed the checks with some noise scale at its lower clamp
/// or without converging, fitted again from the same start with the lower
/// clamp at [`RELEASED_LOWER_CLAMP`] and [`REFIT_ITERATION_FACTOR`] times
/// the iterations; the refit when it passes the checks (otherwise the
/// first fit and its findings stand).
///
/// A source the first scoring steps find absent (`d ≤ −1`, which a joint
/// step through correlated sources gives at a start far from the fit)
/// jumps to the lower clamp and cannot come back, and the others absorb
/// its noise: the reference heading's white noise at the clamp leaves
/// heading innovations at lag-1 ≈ −0.5 (the filter follows each heading
/// reading), the white wheel noise at the clamp drives the common-mode
/// scale to its upper clamp. Refitted with the sources able to return,
/// the model holds the noise the data have. A fit stopped by the
/// iteration limit (the block-coordinate θ/η steps can zig-zag along a
/// ridge of correlated noise scales) gets the iterations to finish.
pub(super) fn refit_with_sources_released(
    input: &EivInput<'_>,
    theta: &Theta,
    filter: &EivOptions,
    first: &EivReport,
) -> Option<EivReport> {
    let lower = filter.eta_bounds[0];
    let misspecified = first.warnings.iter().any(|w| is_misspecification(w, first));
    let clamped = lower < RELEASED_LOWER_CLAMP
        && first.eta.iter().zip(&filter.eta_held).any(|(e, held)| !held && *e <= lower + 1e-9);
    let unconverged = !first.termination.converged();
    if filter.fix_noise || !misspecified || !(clamped || unconverged) {
        return None;
    }
    let released = EivOptions {
        eta_bounds: [lower.max(RELEASED_LOWER_CLAMP), filter.eta_bounds[1]],
        max_iterations: REFIT_ITERATION_FACTOR * filter.max_iterations,
        ..filter.clone()
    };
    let again = eiv::estimate(input, theta, &released).ok()?;
    (!again.warnings.iter().any(|w| is_misspecification(w, &again))).then_some(again)
}

/// After a fallback from a fit with noise levels held: the fit from
/// `theta` with every level estimated ([`HeldNoiseReleased`]); `None`
/// when no level was held (or the whole model was fixed) or the fit
/// failed with an error.
pub(super) fn release_held_noise(
    input: &EivInput<'_>,
    theta: &Theta,
    filter: &EivOptions,
) -> Option<HeldNoiseReleased> {
    let held = filter.known_sources();
    if held.is_empty() || filter.fix_noise {
        return None;
    }
    let released = EivOptions { eta_held: [false; 6], ..filter.without_bias_correction() };
    let first = eiv::estimate(input, theta, &released).ok()?;
    let fit = refit_with_sources_released(input, theta, &released, &first).unwrap_or(first);
    let findings = fit.warnings.iter().filter(|w| is_misspecification(w, &fit)).cloned().collect();
    Some(HeldNoiseReleased { held, theta: fit.theta, free: fit.free, noise: fit.noise, findings })
}
