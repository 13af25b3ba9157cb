//! The scoring steps of θ and η, their damping, and observability.

use nalgebra::{DMatrix, DVector, Matrix4, SymmetricEigen};

use super::filter::{WindowSums, NETA};
use super::problem::free_inverse;
use super::{EivObservability, EivOptions, PARAMETERS};
use crate::error::{Error, Result};
use crate::model::param::Param;

/// The scoring step of θ over the free parameters and the standard deviations.
pub(super) fn theta_step(sums: &WindowSums, free: &[bool; 4], follows: bool) -> Result<([f64; 4], [f64; 4])> {
    let Some(inv) = free_inverse(&sums.h_theta, free) else {
        let params = (0..4)
            .filter(|i| free[*i])
            .map(|i| crate::model::param::Param::THETA[i])
            .collect::<crate::model::param::ParamSet>()
            .names();
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
pub(super) fn theta_score(sums: &WindowSums, follows: bool) -> nalgebra::Vector4<f64> {
    if follows {
        nalgebra::Vector4::new(sums.grad_profile[0], sums.grad_profile[1], sums.grad_profile[2], sums.grad_profile[3])
    } else {
        nalgebra::Vector4::new(sums.grad[0], sums.grad[1], sums.grad[2], sums.grad[3]) - sums.bias
    }
}

/// `gᵀ H_θ⁻¹ g` of the θ-score over the free parameters (∞ when singular).
pub(super) fn score_norm(sums: &WindowSums, free: &[bool; 4], follows: bool) -> f64 {
    match theta_step(sums, free, follows) {
        Ok((step, _)) => {
            let g = theta_score(sums, follows);
            -(0..4).filter(|i| free[*i]).map(|i| step[i] * g[i]).sum::<f64>()
        }
        Err(_) => f64::INFINITY,
    }
}

/// How close to a bound η counts as at its clamp.
const CLAMP_TOLERANCE: f64 = 1e-9;

/// True when `eta` sits at its lower clamp (`bounds[0]`).
pub(super) fn at_lower_clamp(eta: f64, bounds: [f64; 2]) -> bool {
    eta <= bounds[0] + CLAMP_TOLERANCE
}

/// True when `eta` sits at its upper clamp (`bounds[1]`).
pub(super) fn at_upper_clamp(eta: f64, bounds: [f64; 2]) -> bool {
    eta >= bounds[1] - CLAMP_TOLERANCE
}

/// The scoring step of η (log-transformed, clamped; see the module docs)
/// and its standard deviations. A source at its lower clamp whose score
/// points down stays there.
pub(super) fn eta_step(sums: &WindowSums, eta: &[f64; 6], bounds: [f64; 2], held: &[bool; 6]) -> EtaStep {
    let g: [f64; 6] = std::array::from_fn(|j| sums.grad[4 + j]);
    // A noise source with no effect on the data has zero information: leave it.
    let scale = (0..NETA).map(|j| sums.i_eta[(j, j)]).fold(0.0f64, f64::max);
    let mut idx = Vec::new();
    for j in 0..NETA {
        let at_lo = at_lower_clamp(eta[j], bounds) && g[j] > 0.0;
        let at_hi = at_upper_clamp(eta[j], bounds) && g[j] < 0.0;
        let no_info = sums.i_eta[(j, j)] <= 1e-12 * scale.max(f64::MIN_POSITIVE);
        if !(at_lo || at_hi || no_info || held[j]) {
            idx.push(j);
        }
    }
    let mut step = [0.0; 6];
    let mut sigma = [0.0; 6];
    if idx.is_empty() {
        return EtaStep { step, sigma };
    }
    let p = idx.len();
    let a = DMatrix::from_fn(p, p, |i, k| sums.i_eta[(idx[i], idx[k])]);
    let ridge = 1e-12 * (0..p).map(|i| a[(i, i)]).fold(0.0f64, f64::max);
    let a = a + DMatrix::identity(p, p) * ridge;
    let b = DVector::from_fn(p, |i, _| -g[idx[i]]);
    let Some(chol) = a.cholesky() else {
        return EtaStep { step, sigma };
    };
    let d = chol.solve(&b);
    let inv = chol.inverse();
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
    EtaStep { step, sigma }
}

/// The score z from which a noise source at its lower clamp is released at
/// the end of a fit ([`reentering_sources`]): its score `−∂M/∂η_j / √I_jj`
/// (the score test of the clamp, the other scales held) points into the
/// range by more than this. An absent source's z is about standard normal,
/// so 3 releases one on about one fit in 700.
pub(super) const REENTRY_SCORE_Z: f64 = 3.0;

/// The lowest one-step estimate of η at which a released source restarts:
/// e^−10 of the starting variance (σ 0.7 % of the start's). Below it the
/// source's effect on θ is negligible (on the shipped test-track runs
/// released sources' one-step estimates were as low as η −18.9).
pub(super) const REENTRY_MIN_ETA: f64 = -10.0;

/// The noise sources at their lower clamp whose score at the fit's end says
/// the data hold them, with the η each restarts from. A source the scoring
/// steps sent to the clamp early, where θ and the other scales were still
/// far from their estimates (a source whose data show it absent, `d ≤ −1`,
/// goes to the clamp in one step), otherwise stays there whatever the data
/// say later: its variance is then e^−20 of the start's and its
/// information e^−40, which the step's ridge swallows. Returned: the sources whose
/// score z exceeds [`REENTRY_SCORE_Z`] and whose one-step estimate (the
/// others held), `η_j + ln(1 + d_j)` with `d_j = −g_j/I_jj`, is at least
/// [`REENTRY_MIN_ETA`], each with that estimate.
pub(super) fn reentering_sources(
    sums: &WindowSums,
    eta: &[f64; 6],
    bounds: [f64; 2],
    held: &[bool; 6],
) -> Vec<(usize, f64)> {
    (0..NETA)
        .filter_map(|j| {
            let (g, i_jj) = (sums.grad[4 + j], sums.i_eta[(j, j)]);
            let holds = i_jj > 0.0 && -g / i_jj.sqrt() > REENTRY_SCORE_Z;
            if held[j] || !at_lower_clamp(eta[j], bounds) || !holds {
                return None;
            }
            let to = (eta[j] + (1.0 - g / i_jj).ln()).min(bounds[1]);
            (to >= REENTRY_MIN_ETA).then_some((j, to))
        })
        .collect()
}

impl EtaStep {
    pub(super) fn none() -> Self {
        EtaStep { step: [0.0; 6], sigma: [0.0; 6] }
    }
}

/// The η step of [`eta_step`].
pub(super) struct EtaStep {
    /// The step (zero for held sources).
    pub(super) step: [f64; 6],
    /// Standard deviations of η (0 for held sources).
    pub(super) sigma: [f64; 6],
}

/// Largest |Δη| of the fallback step of [`eta_step`] (a variance factor of e²).
pub(super) const MAX_LOG_ETA_STEP: f64 = 2.0;

/// The Fisher-scoring step in η (not in the variances) over the sources in
/// `idx`, scaled as a whole so that no component exceeds
/// [`MAX_LOG_ETA_STEP`]; a source at a clamp whose step points out of the
/// range is held and the step recomputed without it (otherwise clamping
/// would change the step's direction). Its slope `gᵀΔη = −s·gᵀI⁻¹g` is
/// negative, so a short enough step lowers M.
pub(super) fn eta_descent_step(
    sums: &WindowSums,
    g: &[f64; 6],
    eta: &[f64; 6],
    bounds: [f64; 2],
    mut idx: Vec<usize>,
) -> [f64; 6] {
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
            (at_lower_clamp(eta[j], bounds) && d[i] < 0.0) || (at_upper_clamp(eta[j], bounds) && d[i] > 0.0)
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
pub(super) fn secant_eta_factor(step: &[f64; 6], last: Option<([f64; 6], f64)>) -> f64 {
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
pub(super) fn damp_eta_step(step: &[f64; 6], eta: &[f64; 6], factor: f64, bounds: [f64; 2]) -> [f64; 6] {
    std::array::from_fn(|j| {
        let to = eta[j] + step[j];
        if (to - bounds[0]).abs() < 1e-12 || (to - bounds[1]).abs() < 1e-12 {
            step[j]
        } else {
            factor * step[j]
        }
    })
}

pub(super) fn eta_add(eta: &[f64; 6], step: &[f64; 6], lambda: f64, bounds: [f64; 2]) -> [f64; 6] {
    std::array::from_fn(|j| (eta[j] + lambda * step[j]).clamp(bounds[0], bounds[1]))
}

/// Observability from `H_θ` over `free`: σ/resolution, rcond, collinear
/// names; with the names held at the start and the ratios that decided them
/// (`start`: [`fix_unobservable`]'s).
pub(super) fn observability_of(
    h: &Matrix4<f64>,
    free: &[bool; 4],
    (unobservable, start): (Vec<Param>, Option<[f64; 4]>),
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
    EivObservability {
        rcond,
        sigma_over_resolution: ratio,
        start_sigma_over_resolution: start,
        unobservable,
        collinear,
    }
}

/// The observability decision at the first pass's start, from `h`
/// (`H_θ` at the start's θ and the starting noise model): the free
/// parameters whose σ exceeds their resolution held fixed, one at a time
/// (worst first, the others' ratios recomputed after each; the last free
/// parameter is never held). Returns the reduced mask, the names held and
/// the ratios that decided: a held parameter's when it was held, a free
/// one's after the holds (0 for parameters not free).
pub(super) fn fix_unobservable(
    h: &Matrix4<f64>,
    free: &[bool; 4],
    opts: &EivOptions,
) -> ([bool; 4], Vec<Param>, [f64; 4]) {
    let mut free = *free;
    let mut fixed = Vec::new();
    let mut ratios = [0.0; 4];
    loop {
        let inv = free_inverse(h, &free);
        let mut worst: Option<(usize, f64)> = None;
        for i in (0..4).filter(|i| free[*i]) {
            let r = inv.map_or(f64::INFINITY, |m| m[(i, i)].max(0.0).sqrt() / opts.resolution[i]);
            // With a singular matrix rank the diagonal of H itself.
            let r = if r.is_finite() { r } else { 1.0 / (h[(i, i)].max(0.0).sqrt() * opts.resolution[i]).max(1e-300) };
            ratios[i] = r;
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
    (free, fixed, ratios)
}
