//! θ's covariance beyond H_θ⁻¹: the noise-estimate term, the block inflation, the joint Fisher inverse.

use nalgebra::{DMatrix, DVector, Matrix4, Vector4};

use super::filter::{self, Mode, WindowSums, NETA};
use super::problem::Problem;
use super::steps::theta_score;
use crate::error::Result;
use crate::model::Theta;

/// Step in η of the forward difference of the θ-score
/// ([`NoiseEstimateTerm::Observed`](super::NoiseEstimateTerm::Observed)): 1e-4, i.e. a 0.01 %
/// change of the source's variance. The score is smooth in η (one-sided
/// error ≈ h/2 relative); its sums have ≥ 10 significant digits to spare.
pub(crate) const ETA_SENSITIVITY_STEP: f64 = 1e-4;

/// The covariance that estimating η adds to θ̂: `A Σ_η Aᵀ` with
/// `A = −J⁻¹ ∂g_θ/∂η` over the free η ([`NoiseEstimateTerm::Observed`](super::NoiseEstimateTerm::Observed);
/// J = ∂g_θ/∂θ, observed), and `A` itself (`[parameter][source]`, zero
/// columns for the fixed η). `sums` is the evaluation at (θ̂, η̂) (with η
/// derivatives), `cov` = `H_θ⁻¹` over the free θ (zero rows for the fixed
/// ones; also J⁻¹'s stand-in should J be singular). With
/// `mixed_partials_by_symmetry` (and the covariance following θ) `∂g_θ/∂η`
/// comes from the θ-displaced passes J needs (one per free θ); otherwise
/// from one more pass per free η, displaced by [`ETA_SENSITIVITY_STEP`].
#[allow(clippy::too_many_arguments)]
pub(super) fn noise_estimate_covariance(
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
    let idx: Vec<usize> = (0..NETA).filter(|j| eta_free[*j]).collect();
    let Some(cov_eta) = eta_covariance(sums, &idx) else {
        return Ok((Matrix4::zeros(), [[0.0; 6]; 4]));
    };
    let g0 = theta_score(sums, follows);
    let h = ETA_SENSITIVITY_STEP;
    // The Jacobian of the θ-score, J = ∂g_θ/∂θ: observed (forward
    // differences of 1 % of the parameter's σ) in the columns of t_r and d,
    // the scoring metric H_θ's in those of c_e and c_d. The t_r–d block of
    // H_θ is nearly singular, and there the few-% difference between H_θ and
    // the observed Jacobian moved ∂t_r/∂η by 1.5× on a 4 km `high` drive
    // (the refits of the test agree with the observed one). In the columns
    // of the well-determined c_e and c_d the metric serves (`A` within 5 %
    // of the refits on the same drive, every entry), and the displaced
    // passes of c_e and c_d then need no `∂P/∂θ` (4 of their 9 covariance
    // columns).
    let observed = |k: usize| k >= 2;
    let fidx: Vec<usize> = (0..4).filter(|i| cov[(*i, *i)] > 0.0).collect();
    let q = fidx.len();
    // ∂g_θ/∂η by symmetry of the mixed partials: with the covariance
    // following θ, g_θ = ∂F/∂θ + G_T, F = ½Σνᵀ S⁻¹ν − Σ m log(1 − ŝ) and G_T
    // the input log-Jacobian's θ-score with its weights u held, so
    // ∂g_θ/∂η_j = ∂/∂θ (∂F/∂η_j) + ∂G_T/∂η_j. The first is the forward
    // difference in θ of `grad_profile`'s η entries at θ-displaced points
    // (one per free θ, evaluated with η derivatives; those of J's observed
    // columns with θ's too), the second is summed exactly by the filter
    // (`grad_jacobian_eta`). That needs 4 filter passes instead of 2 + one
    // per free η. Where u depends on η in a way the filter does not
    // differentiate (the smoothed shares) or with the covariance held (the
    // corrected score's bias term), η is displaced instead.
    let by_symmetry = mixed_partials_by_symmetry && follows;
    let steps: Vec<f64> = fidx.iter().map(|&k| 0.01 * cov[(k, k)].sqrt()).collect();
    // The displaced free θ (indices into `fidx`).
    let displaced: Vec<usize> = (0..q).filter(|&c| by_symmetry || observed(fidx[c])).collect();
    // By symmetry only the free η's columns are needed (a scale at its clamp is not estimated).
    let skip = if by_symmetry { (0..NETA).filter(|j| !eta_free[*j]).fold(0u8, |m, j| m | (1 << j)) } else { 0 };
    // Only the displaced points' θ-scores and η gradients are used: no information matrices.
    let mode = Mode::full(follows, by_symmetry).skipping_eta(skip).gradients_only();
    let eta_mode = Mode::eta_only(follows).skipping_eta(skip).gradients_only();
    // Every displaced point (θ first, then η), evaluated in one sweep.
    let mut points: Vec<(Theta, [f64; 6], Mode)> = displaced
        .iter()
        .map(|&c| {
            let mut t = theta.to_array();
            t[fidx[c]] += steps[c];
            (Theta::from_array(t), *eta, if observed(fidx[c]) { mode } else { eta_mode })
        })
        .collect();
    if !by_symmetry {
        points.extend(idx.iter().map(|&j| {
            let mut e = *eta;
            e[j] += h;
            (*theta, e, mode)
        }));
    }
    let evs = prob.evaluate_many(&points, theta_ref, false)?;
    let (ev_theta, ev_eta) = evs.split_at(displaced.len());
    let mut jac = DMatrix::zeros(q, q);
    for c in 0..q {
        let k = fidx[c];
        let dg = match displaced.iter().position(|&d| d == c) {
            Some(n) if observed(k) => (theta_score(&ev_theta[n].total, follows) - g0) / steps[c],
            _ => sums.h_theta.column(k).into_owned(),
        };
        for (r, &i) in fidx.iter().enumerate() {
            jac[(r, c)] = dg[i];
        }
    }
    let jinv = embedded_inverse(jac, &fidx).unwrap_or(*cov);
    // ∂g_θ/∂η_j (4-vector) per free η.
    let dg_deta: Vec<Vector4<f64>> = if by_symmetry {
        idx.iter()
            .map(|&j| {
                let mut dg = sums.grad_jacobian_eta[j];
                for (ev, &c) in ev_theta.iter().zip(&displaced) {
                    dg[fidx[c]] += (ev.total.grad_profile[4 + j] - sums.grad_profile[4 + j]) / steps[c];
                }
                dg
            })
            .collect()
    } else {
        ev_eta.iter().map(|ev| (theta_score(&ev.total, follows) - g0) / h).collect()
    };
    Ok(term_of(&jinv, &dg_deta, &idx, &cov_eta))
}

/// η's covariance over the estimated scales `idx`: the inverse of their
/// information (with a 1e-12 relative ridge); None when that is singular.
fn eta_covariance(sums: &WindowSums, idx: &[usize]) -> Option<DMatrix<f64>> {
    let p = idx.len();
    let info = DMatrix::from_fn(p, p, |i, k| sums.i_eta[(idx[i], idx[k])]);
    let ridge = 1e-12 * (0..p).map(|i| info[(i, i)]).fold(0.0f64, f64::max);
    Some((info + DMatrix::identity(p, p) * ridge).cholesky()?.inverse())
}

/// `A Σ_η Aᵀ` and `A` (`[parameter][source]`, zero columns for the fixed
/// η) with `A = −J⁻¹ ∂g_θ/∂η`: `jinv` is J⁻¹, `dg_deta` one `∂g_θ/∂η_j` per
/// estimated scale of `idx`, `cov_eta` their covariance.
fn term_of(
    jinv: &Matrix4<f64>,
    dg_deta: &[Vector4<f64>],
    idx: &[usize],
    cov_eta: &DMatrix<f64>,
) -> (Matrix4<f64>, [[f64; 6]; 4]) {
    let mut sens = [[0.0; 6]; 4];
    let mut a = DMatrix::zeros(4, idx.len());
    for (c, (&j, dg)) in idx.iter().zip(dg_deta).enumerate() {
        let col = -(jinv * dg);
        for i in 0..4 {
            a[(i, c)] = col[i];
            sens[i][j] = col[i];
        }
    }
    let out = &a * cov_eta * a.transpose();
    (Matrix4::from_fn(|i, k| out[(i, k)]), sens)
}

/// The inverse of `jac` (over the parameters `fidx`) embedded in 4×4;
/// `None` when it is singular or a diagonal entry is not positive.
fn embedded_inverse(jac: DMatrix<f64>, fidx: &[usize]) -> Option<Matrix4<f64>> {
    let ji = jac.try_inverse()?;
    if !(0..fidx.len()).all(|i| ji[(i, i)] > 0.0) {
        return None;
    }
    let mut m = Matrix4::zeros();
    for (r, &i) in fidx.iter().enumerate() {
        for (c, &k) in fidx.iter().enumerate() {
            m[(i, k)] = ji[(r, c)];
        }
    }
    Some(m)
}

/// The covariance of
/// [`CovarianceEstimate::LargerOfModelAndBlock`](super::CovarianceEstimate::LargerOfModelAndBlock):
/// `cov` (an `H_θ⁻¹`) with each parameter's σ raised to the block
/// sandwich's where that is larger, `D cov D` with
/// `D = diag(max(1, σ_block,i/σ_i))`. `cov` itself with fewer than two
/// blocks.
pub(super) fn inflate_to_block(cov: &Matrix4<f64>, blocks: &filter::BlockScores) -> Matrix4<f64> {
    let Some(meat) = blocks.meat() else {
        return *cov;
    };
    let sandwich = cov * meat * cov;
    crate::identify::raise_variances(cov, |i| sandwich[(i, i)])
}

/// The θ block of the inverse of the joint Fisher information of the free
/// θ and the estimated η that are not at a clamp (`eta_sigma > 0`).
/// `∂η̂/∂θ = −I_ηη⁻¹ I_ηθ` over the free η and θ ([`EivReport::eta_theta_sensitivity`](super::EivReport::eta_theta_sensitivity));
/// zeros when no η is free or `I_ηη` is singular.
pub(super) fn eta_on_theta(info: &filter::MP, free: &[bool; 4], eta_free: &[bool; 6]) -> [[f64; 4]; 6] {
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

pub(super) fn fisher_covariance(info: &filter::MP, free: &[bool; 4], eta_free: &[bool; 6]) -> Option<Matrix4<f64>> {
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
