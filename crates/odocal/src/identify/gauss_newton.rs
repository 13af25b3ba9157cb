//! The one batch Gauss-Newton loop (docs/method.md §4) behind
//! [`crate::identify::batch_gauss_newton`], over θ alone (N = 4) and over
//! θ with the reference extrinsics (N = 7, [[`Extrinsics`](crate::Extrinsics)]).
//!
//! What varies between the two is a [`Problem`]: the residuals and
//! Jacobian of one segment at a parameter vector (as its normal
//! equations), its cost, and the words of the errors. The loop — the
//! reduced solve over the free parameters, the candidate checks, the step
//! acceptance and the termination — is this module's, as are the model
//! covariance `σ̂²(JᵀWJ)⁻¹` and the cluster-robust covariance of
//! [`cluster_robust_covariance`].

use nalgebra::{DMatrix, DVector, SMatrix, SVector};
use rayon::prelude::*;

use super::{
    to_array4, IdentifyOptions, IdentifyReport, IterationRecord, NormalEquations, Observability, RobustCovariance,
    Termination,
};
use crate::drive::segment::SegmentData;
use crate::error::{Error, Result};
use crate::model::extrinsics::ExtrinsicsEstimate;
use crate::model::param::ParamSet;
use crate::model::Theta;

/// The residual/Jacobian supplier of the loop over an N-parameter vector.
pub(crate) trait Problem<const N: usize>: Sync {
    /// Normal equations of one segment at `x`.
    fn normal_equations(&self, seg: &SegmentData<'_>, x: &SVector<f64, N>) -> NormalEquations<N>;
    /// Weighted cost of one segment at `x` (no Jacobian).
    fn cost(&self, seg: &SegmentData<'_>, x: &SVector<f64, N>) -> f64;
    /// True when `x` is physical (θ's `c_e`, `t_r` positive).
    fn physical(&self, x: &SVector<f64, N>) -> bool;
    /// The error for a non-finite cost at the start `x`.
    fn non_finite_start(&self, x: &SVector<f64, N>) -> Error;
    /// The error for a singular reduced `JᵀWJ` (`total` at the current x).
    fn singular(&self, total: &NormalEquations<N>) -> Error;
}

/// What the loop hands back.
pub(crate) struct Outcome<const N: usize> {
    /// The estimate.
    pub x: SVector<f64, N>,
    /// Weighted cost at the start.
    pub initial_cost: f64,
    /// Accepted iterates and their costs, in order.
    pub history: Vec<(SVector<f64, N>, f64)>,
    /// Why it stopped.
    pub termination: Termination,
    /// Normal equations at the estimate, summed over segments.
    pub total: NormalEquations<N>,
    /// Normal equations at the estimate, per segment (input order).
    pub per_segment: Vec<NormalEquations<N>>,
}

/// Per-segment normal equations in parallel and their sum in segment order
/// (deterministic whatever the thread count).
pub(crate) fn batch<const N: usize, P: Problem<N>>(
    p: &P,
    segments: &[SegmentData<'_>],
    x: &SVector<f64, N>,
) -> (NormalEquations<N>, Vec<NormalEquations<N>>) {
    let parts: Vec<NormalEquations<N>> = segments.par_iter().map(|s| p.normal_equations(s, x)).collect();
    let mut total = NormalEquations::zero();
    for q in &parts {
        total.add(q);
    }
    (total, parts)
}

fn batch_cost<const N: usize, P: Problem<N>>(p: &P, segments: &[SegmentData<'_>], x: &SVector<f64, N>) -> f64 {
    let costs: Vec<f64> = segments.par_iter().map(|s| p.cost(s, x)).collect();
    costs.iter().sum()
}

/// The free block of `m` (rows and columns `free`) and of `v`.
pub(crate) fn reduce<const N: usize>(
    m: &SMatrix<f64, N, N>,
    v: &SVector<f64, N>,
    free: &[usize],
) -> (DMatrix<f64>, DVector<f64>) {
    let a = DMatrix::from_fn(free.len(), free.len(), |i, j| m[(free[i], free[j])]);
    let b = DVector::from_fn(free.len(), |i, _| v[free[i]]);
    (a, b)
}

/// Batch Gauss-Newton from `x0` over the `free` entries; `scale` divides
/// the step for the step-tolerance test. Accepted steps never increase the
/// weighted cost; see [`Termination`] for how it stops.
pub(crate) fn run<const N: usize, P: Problem<N>>(
    p: &P,
    segments: &[SegmentData<'_>],
    x0: &SVector<f64, N>,
    free: &[usize],
    scale: &SVector<f64, N>,
    opts: &IdentifyOptions,
) -> Result<Outcome<N>> {
    let mut x = *x0;
    let (mut ne, mut parts) = batch(p, segments, &x);
    if !ne.cost.is_finite() {
        return Err(p.non_finite_start(&x));
    }
    let initial_cost = ne.cost;
    let mut history = Vec::new();
    let mut termination = Termination::MaxIterations { iterations: opts.max_iterations };
    for _ in 0..opts.max_iterations {
        let (a, b) = reduce(&ne.jtwj, &ne.jtwr, free);
        let Some(chol) = a.cholesky() else {
            return Err(p.singular(&ne));
        };
        let dx = chol.solve(&b);
        let mut step = SVector::<f64, N>::zeros();
        for (i, &fi) in free.iter().enumerate() {
            step[fi] = dx[i];
        }
        let cand = x + step;
        let rel_step = step.component_div(scale).amax();
        if !cand.iter().all(|v| v.is_finite()) {
            termination = Termination::NonFiniteCandidate { previous: ne.cost };
            break;
        }
        if !p.physical(&cand) {
            termination = Termination::NonPhysicalCandidate { previous: ne.cost };
            break;
        }
        let cand_cost = batch_cost(p, segments, &cand);
        let rel_change = (cand_cost - ne.cost).abs() / ne.cost.max(f64::MIN_POSITIVE);
        if cand_cost.is_nan() || cand_cost > ne.cost {
            termination = if rel_change <= opts.cost_tolerance {
                Termination::Converged { rel_change, threshold: opts.cost_tolerance }
            } else {
                Termination::CostIncreased { cost: cand_cost, previous: ne.cost }
            };
            break;
        }
        x = cand;
        (ne, parts) = batch(p, segments, &x);
        history.push((x, ne.cost));
        if rel_step <= opts.step_tolerance {
            termination = Termination::StepTolerance { rel_step, threshold: opts.step_tolerance };
            break;
        }
    }
    Ok(Outcome { x, initial_cost, history, termination, total: ne, per_segment: parts })
}

/// One Gauss-Newton step from `x` over the `free` entries, without step
/// acceptance: `x` plus the solution of the normal equations there (one
/// pass over the segments). None when the cost is not finite or the free
/// block is singular.
pub(crate) fn one_step<const N: usize, P: Problem<N>>(
    p: &P,
    segments: &[SegmentData<'_>],
    x: &SVector<f64, N>,
    free: &[usize],
) -> Option<SVector<f64, N>> {
    let (ne, _) = batch(p, segments, x);
    if !ne.cost.is_finite() {
        return None;
    }
    let (a, b) = reduce(&ne.jtwj, &ne.jtwr, free);
    let dx = a.cholesky()?.solve(&b);
    let mut next = *x;
    for (i, &fi) in free.iter().enumerate() {
        next[fi] += dx[i];
    }
    Some(next)
}

/// The model covariance `σ̂² (JᵀWJ)⁻¹` over the free entries (zero rows and
/// columns elsewhere), `σ̂² = cost / (m − p)` with `m = 3·poses` residuals
/// and `p` free parameters; zero when the free block is singular.
pub(crate) fn model_covariance<const N: usize>(ne: &NormalEquations<N>, free: &[usize]) -> SMatrix<f64, N, N> {
    let (a, _) = reduce(&ne.jtwj, &ne.jtwr, free);
    let m = 3 * ne.poses;
    let sigma2 = if m > free.len() { ne.cost / (m - free.len()) as f64 } else { f64::NAN };
    let mut cov = SMatrix::<f64, N, N>::zeros();
    if let Some(inv) = a.try_inverse() {
        for (i, &fi) in free.iter().enumerate() {
            for (j, &fj) in free.iter().enumerate() {
                cov[(fi, fj)] = sigma2 * inv[(i, j)];
            }
        }
    }
    cov
}

/// Groups segments into clusters for [`cluster_robust_covariance`]:
/// segments sorted by (drive start, start sample); a new cluster begins at
/// the first segment of another drive ([`SegmentData::drive_start`]) and at
/// the first segment starting `block_steps` or more after the current
/// cluster's first segment. Blocks thus restart at each drive's start, so
/// a joint calibration's clusters do not depend on the drives' order.
/// Takes `(drive_start, start)` of each segment; returns the cluster index
/// of each segment (input order) and the number of clusters.
pub(crate) fn clusters(starts: &[(usize, usize)], block_steps: usize) -> (Vec<usize>, usize) {
    let mut order: Vec<usize> = (0..starts.len()).collect();
    order.sort_by_key(|&i| (starts[i], i));
    let mut id = vec![0; starts.len()];
    let (mut g, mut first) = (0usize, None::<(usize, usize)>);
    for &i in &order {
        let (drive, start) = starts[i];
        match first {
            Some((fd, f)) if fd == drive && start < f + block_steps.max(1) => {}
            Some(_) => {
                g += 1;
                first = Some(starts[i]);
            }
            None => first = Some(starts[i]),
        }
        id[i] = g;
    }
    (id, if starts.is_empty() { 0 } else { g + 1 })
}

/// The cluster-robust covariance over the free entries: the
/// delete-one-cluster jackknife of the estimate (the "CV3" estimator of
/// MacKinnon, Nielsen and Webb, J. Econometrics 2023), each refit one
/// Gauss-Newton step from the estimate,
///
/// ```text
/// Δ_c = (H − H_c)⁻¹ g_c,   V = (G−1)/G Σ_c (Δ_c − Δ̄)(Δ_c − Δ̄)ᵀ,
/// H = JᵀWJ,  H_c, g_c = Σ_{s∈c} J_sᵀW J_s, J_sᵀW r_s
/// ```
///
/// with the clusters of [`clusters`] (`G` of them; Δ̄ the mean of the
/// Δ_c), each variance raised where neighbouring clusters of a drive
/// correlate ([`widened_by_neighbours`]: slow wheel-scale variation, with a
/// correlation time that is not short against the 32.5 s clusters, makes
/// them move together, and the jackknife, which takes clusters as
/// independent, then understates the spread). Unlike the model covariance it does not assume independent,
/// equally scaled residuals: a segment's residuals integrate the same
/// input noise, and overlapping segments share samples, so only sums over
/// long stretches of the drive are close to independent. Unlike the
/// sandwich `H⁻¹ · G/(G−1) Σ_c g_c g_cᵀ · H⁻¹`, which it approaches when every
/// cluster holds a small share of the information, it widens a parameter
/// that a few clusters determine (the load transfer d, from the few
/// turns with large lateral acceleration), where the sandwich, summing a
/// few large squared scores, runs short. When some `H − H_c` is singular
/// (one cluster alone determines a direction) the sandwich stands in.
/// Clusters are [`IdentifyOptions::robust_block_steps`] long; `None` with
/// fewer than [`IdentifyOptions::robust_min_clusters`] of them or a
/// singular free block.
pub(crate) fn cluster_robust_covariance<const N: usize>(
    total: &NormalEquations<N>,
    per_segment: &[NormalEquations<N>],
    segments: &[SegmentData<'_>],
    free: &[usize],
    opts: &IdentifyOptions,
) -> Option<(SMatrix<f64, N, N>, usize)> {
    let starts: Vec<(usize, usize)> = segments.iter().map(|s| (s.drive_start, s.start)).collect();
    let (id, g) = clusters(&starts, opts.robust_block_steps);
    if g < opts.robust_min_clusters.max(2) {
        return None;
    }
    let p = free.len();
    let mut scores = vec![DVector::<f64>::zeros(p); g];
    for (s, ne) in per_segment.iter().enumerate() {
        for (i, &fi) in free.iter().enumerate() {
            scores[id[s]][i] += ne.jtwr[fi];
        }
    }
    let mut information = vec![DMatrix::<f64>::zeros(p, p); g];
    for (s, ne) in per_segment.iter().enumerate() {
        information[id[s]] += reduce(&ne.jtwj, &ne.jtwr, free).0;
    }
    let (a, _) = reduce(&total.jtwj, &total.jtwr, free);
    let inv = a.clone().try_inverse()?;
    let deleted: Option<Vec<DVector<f64>>> =
        scores.iter().zip(&information).map(|(score, h)| (&a - h).try_inverse().map(|m| m * score)).collect();
    // Clusters whose successor is the next cluster of the same drive.
    let mut drive_of = vec![usize::MAX; g];
    for (s, seg) in segments.iter().enumerate() {
        drive_of[id[s]] = seg.drive_start;
    }
    let neighbours: Vec<bool> = (0..g).map(|c| c + 1 < g && drive_of[c] == drive_of[c + 1]).collect();
    let v = match deleted {
        Some(deltas) => widened_by_neighbours(&deltas, &neighbours) * ((g - 1) as f64 / g as f64),
        None => &inv * widened_by_neighbours(&scores, &neighbours) * (g as f64 / (g - 1) as f64) * &inv,
    } * few_clusters_factor(g);
    let mut cov = SMatrix::<f64, N, N>::zeros();
    for (i, &fi) in free.iter().enumerate() {
        for (j, &fj) in free.iter().enumerate() {
            // Symmetrise against round-off.
            cov[(fi, fj)] = 0.5 * (v[(i, j)] + v[(j, i)]);
        }
    }
    Some((cov, g))
}

/// The factor on the cluster-robust covariance of `g` clusters, `(t_{g−1}(Φ(3))/3)²`:
/// its σ is estimated from `g` cluster deltas, and θ̂'s error over that
/// estimated σ follows Student's t with `g − 1` degrees of freedom, whose
/// tails are heavier than the normal's. Scaled by it, θ̂ ± 3σ keeps the
/// probability a known σ's 3σ interval has (99.73 %) and θ̂ ± 1.96σ covers
/// at least 95 %. It widens the σ by 1.36 at 10 clusters, 1.09 at 30 and
/// 1.03 at 100 (docs/method.md, "Which within-drive σ"). At the 3σ level rather than
/// the 95 % one because the checks the σ serves (a gap beyond 3σ, a
/// result's distance from the truth) are made there.
pub(crate) fn few_clusters_factor(g: usize) -> f64 {
    use statrs::distribution::{ContinuousCDF, Normal, StudentsT};
    const Z: f64 = 3.0;
    let (Ok(normal), Ok(t)) = (Normal::new(0.0, 1.0), StudentsT::new(0.0, 1.0, g.saturating_sub(1).max(1) as f64))
    else {
        return 1.0;
    };
    (t.inverse_cdf(normal.cdf(Z)) / Z).powi(2)
}

/// [`spread`] of `vs` with each diagonal entry raised, where that is
/// larger, to the spread plus the cross products of neighbouring entries
/// (`neighbours[c]`: `vs[c]` and `vs[c + 1]` are neighbours), the
/// correlation of neighbouring clusters, `S D` → `D S D` with
/// `D = diag(max(1, √(diag(S + C) / diag S)))`. Slow wheel-scale variation
/// correlates the clusters next to each other; neighbours of one drive
/// follow each other in time. Only widening: the cross products of a few
/// dozen clusters are noisy.
fn widened_by_neighbours(vs: &[DVector<f64>], neighbours: &[bool]) -> DMatrix<f64> {
    let s = spread(vs);
    let p = s.nrows();
    let mean = mean_of(vs);
    let mut cross = DMatrix::<f64>::zeros(p, p);
    for c in (0..vs.len().saturating_sub(1)).filter(|c| neighbours[*c]) {
        let (x, y) = (&vs[c] - &mean, &vs[c + 1] - &mean);
        cross += &x * y.transpose() + &y * x.transpose();
    }
    super::raise_variances(&s, |i| s[(i, i)] + cross[(i, i)])
}

/// The mean v̄ of `vs` (all of one length).
fn mean_of(vs: &[DVector<f64>]) -> DVector<f64> {
    let p = vs.first().map_or(0, |v| v.len());
    vs.iter().fold(DVector::zeros(p), |acc, v| acc + v) / vs.len().max(1) as f64
}

/// `Σ (v − v̄)(v − v̄)ᵀ` over `vs` (all of one length).
fn spread(vs: &[DVector<f64>]) -> DMatrix<f64> {
    let mean = mean_of(vs);
    let p = mean.len();
    vs.iter().fold(DMatrix::zeros(p, p), |acc, v| {
        let c = v - &mean;
        acc + &c * c.transpose()
    })
}

/// The report of a fit of θ with the reference extrinsics, whose vector
/// starts with θ: the model and cluster-robust covariances over `free`
/// are computed here and handed, with the sensitivities of
/// `observability` (`rcond`, sensitivity per entry, unobservable set), to
/// `extrinsics`, which builds the extrinsics part from them.
pub(crate) fn joint_report<const N: usize>(
    segments: &[SegmentData<'_>],
    theta0: &Theta,
    out: &Outcome<N>,
    free: &[usize],
    (rcond, sens, unobservable): (f64, Vec<f64>, ParamSet),
    opts: &IdentifyOptions,
    extrinsics: impl FnOnce(&SMatrix<f64, N, N>, Option<&SMatrix<f64, N, N>>, &[f64]) -> ExtrinsicsEstimate,
) -> IdentifyReport {
    let theta_of = |x: &SVector<f64, N>| Theta { c_e: x[0], c_d: x[1], t_r: x[2], d: x[3] };
    let ne = &out.total;
    let cov = model_covariance(ne, free);
    let robust = cluster_robust_covariance(ne, &out.per_segment, segments, free, opts);
    let estimate = extrinsics(&cov, robust.as_ref().map(|(c, _)| c), &sens);
    let history = out.history.iter().map(|(x, cost)| IterationRecord { theta: theta_of(x), cost: *cost }).collect();
    IdentifyReport {
        initial_theta: *theta0,
        theta: theta_of(&out.x),
        initial_cost: out.initial_cost,
        final_cost: ne.cost,
        iterations: out.history.len(),
        termination: out.termination,
        history,
        covariance: to_array4(&cov),
        robust: robust.map(|(c, clusters)| RobustCovariance {
            covariance: to_array4(&c),
            clusters,
            block_steps: opts.robust_block_steps,
        }),
        observability: Observability::of_batch(rcond, [sens[0], sens[1], sens[2], sens[3]], unobservable),
        segments: segments.len(),
        residual_poses: ne.poses,
        extrinsics: Some(estimate),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The few-clusters factor is the square of Student's t quantile at
    /// Φ(3) over 3. Reference quantiles from the Cornish–Fisher expansion
    /// of t in the normal quantile (Abramowitz and Stegun 26.7.5, five
    /// terms; within 2e-4 of t, relative, from 9 degrees of freedom up):
    /// t_9 = 4.0936, t_29 = 3.2804, t_99 = 3.0768. It falls towards 1 as the
    /// clusters grow.
    #[test]
    fn few_clusters_factor_is_students_t_at_three_sigma() {
        for (g, t) in [(10, 4.0936), (30, 3.2804), (100, 3.0768)] {
            let f = few_clusters_factor(g).sqrt();
            assert!((f / (t / 3.0) - 1.0).abs() < 5e-4, "{g} clusters: {f} against {}", t / 3.0);
        }
        let mut last = f64::INFINITY;
        for g in [2, 3, 5, 10, 30, 100, 1000, 1_000_000] {
            let f = few_clusters_factor(g);
            assert!(f > 1.0 && f < last, "{g} clusters: {f}");
            last = f;
        }
        assert!(last < 1.0 + 1e-5, "{last}");
    }

    /// One step of [`one_step`] is the loop's first accepted iterate (θ
    /// alone, with the extrinsics, with a heading offset per drive), and
    /// from the loop's converged estimate it stays there.
    #[test]
    fn one_step_is_the_loops_first_step() {
        use crate::drive::segment::{select_segments, SegmentOptions};
        use crate::identify::{batch_gauss_newton_drives, gauss_newton_step_drives};
        use crate::model::param::Param;
        use crate::model::Theta;
        use crate::sim::{simulate, SimOptions};
        let a = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) }).expect("sim").drive;
        let b = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(2) }).expect("sim").drive;
        let joined = crate::Drive::concat(&[&a, &b]).expect("concat");
        let sel = select_segments(&joined, &SegmentOptions::default()).expect("segments");
        let data: Vec<SegmentData<'_>> = sel.selected.iter().map(|s| SegmentData::new(&joined, s)).collect();
        let theta_only = IdentifyOptions::default();
        let with_offset = IdentifyOptions { free: theta_only.free.with(Param::HeadingOffset), ..theta_only.clone() };
        for (opts, starts) in [(&theta_only, &[0][..]), (&with_offset, &[0][..]), (&with_offset, joined.drive_starts())]
        {
            let first = IdentifyOptions { max_iterations: 1, ..opts.clone() };
            let loop1 = batch_gauss_newton_drives(&data, starts, &Theta::PAPER_INITIAL, &first).expect("loop");
            let step = gauss_newton_step_drives(&data, starts, &Theta::PAPER_INITIAL, opts).expect("step");
            assert_eq!(
                <[f64; 4]>::from(step).map(f64::to_bits),
                <[f64; 4]>::from(loop1.theta).map(f64::to_bits),
                "{starts:?}"
            );
        }
        let fit = batch_gauss_newton_drives(&data, &[0], &Theta::PAPER_INITIAL, &theta_only).expect("fit");
        let again = gauss_newton_step_drives(&data, &[0], &fit.theta, &theta_only).expect("step");
        for (x, y) in <[f64; 4]>::from(again).iter().zip(<[f64; 4]>::from(fit.theta)) {
            assert!((x - y).abs() <= 1e-9 * y.abs().max(1e-3), "{x} against {y}");
        }
    }

    /// Neighbours that move together widen the spread by `√((S + C)/S)`;
    /// neighbours that alternate, and entries that are not neighbours (other
    /// drives), leave it as it is.
    #[test]
    #[allow(clippy::float_cmp)] // unchanged entries are the spread's own bits
    fn neighbouring_clusters_that_correlate_widen_the_spread() {
        let vs = |x: &[f64]| x.iter().map(|v| DVector::from_vec(vec![*v, 1.0 - *v])).collect::<Vec<_>>();
        let smooth = vs(&[1.0, 2.0, 3.0, 4.0]);
        let s = spread(&smooth);
        // Deviations −1.5, −0.5, 0.5, 1.5: S = 5, C = 2 (0.75 − 0.25 + 0.75) = 2.5.
        let w = widened_by_neighbours(&smooth, &[true, true, true, false]);
        assert!((w[(0, 0)] / s[(0, 0)] - 1.5).abs() < 1e-12, "{w}");
        assert!((w[(1, 1)] / s[(1, 1)] - 1.5).abs() < 1e-12, "{w}");
        assert!((w[(0, 1)] / s[(0, 1)] - 1.5).abs() < 1e-12, "correlations kept: {w}");
        assert_eq!(widened_by_neighbours(&smooth, &[false; 4]), s, "no neighbours");
        let alternating = vs(&[1.0, 3.0, 1.0, 3.0]);
        assert_eq!(widened_by_neighbours(&alternating, &[true, true, true, false]), spread(&alternating));
    }

    #[test]
    fn clusters_start_a_new_block_every_block_steps() {
        let one = |v: &[usize]| v.iter().map(|&s| (0, s)).collect::<Vec<_>>();
        let (id, g) = clusters(&one(&[0, 100, 200, 700, 800, 1400, 5000]), 650);
        assert_eq!(id, vec![0, 0, 0, 1, 1, 2, 3]);
        assert_eq!(g, 4);
        // Unsorted input: cluster by start, reported in input order.
        let (id, g) = clusters(&one(&[800, 0, 700, 100]), 650);
        assert_eq!((id, g), (vec![1, 0, 1, 0], 2));
        assert_eq!(clusters(&[], 650), (vec![], 0));
    }

    /// Joined drives: a block restarts at each drive's first segment, so
    /// swapping two drives gives each drive the same clusters.
    #[test]
    fn clusters_restart_at_each_drive() {
        // Drive A (1000 samples): segments at 0 and 600; drive B (800
        // samples): at 0, 100 and 700. A block is 650 samples.
        let (id, g) = clusters(&[(0, 0), (0, 600), (1000, 1000), (1000, 1100), (1000, 1700)], 650);
        assert_eq!((id, g), (vec![0, 0, 1, 1, 2], 3));
        // B first: B's segment at 700 and A's at 800 (A's first) are 100
        // samples apart but in separate blocks, as are A's two segments
        // when A came first.
        let (id, g) = clusters(&[(0, 0), (0, 100), (0, 700), (800, 800), (800, 1400)], 650);
        assert_eq!((id, g), (vec![0, 0, 1, 2, 2], 3));
    }
}
