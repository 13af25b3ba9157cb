//! Gauss-Newton identification of θ (docs/method.md §4, paper §3).
//!
//! The public items are the options of the Gauss-Newton fits
//! ([`IdentifyOptions`], set as [`crate::CalibrationOptions::identify`]) and
//! the observability of an estimate ([`Observability`], in
//! [`crate::CalibrationReport`]), and one segment's normal equations over θ
//! and the reference extrinsics ([`extrinsics_normal_equations`], what the
//! online calibrator of the crate odocal-online folds in per segment);
//! [`crate::calibrate()`] runs batch
//! Gauss-Newton for every method. `batch_gauss_newton` itself and its
//! report are public with the cargo feature `research` only (the studies of
//! crates/odocal-lab).
//!
//! For each segment the model is run from the reference start pose with the
//! given inputs; the residual `r_k = ỹ_k − ŷ_k(θ)` (heading wrapped) and the
//! sensitivity `S_k = ∂ŷ_k/∂θ` are propagated together,
//! `S_0 = 0, S_{k+1} = F_x,k S_k + F_θ,k`. One step is
//!
//! ```text
//! θ_i = θ_{i−1} + (JᵀWJ)⁻¹ JᵀW R
//! ```
//!
//! with `W = diag([1, 1, 40²])` per sample. *Batch* Gauss-Newton accumulates
//! `JᵀWJ` and `JᵀWR` over many segments (in parallel, summed in a fixed
//! order so the result does not depend on the thread count). Steps that
//! increase the weighted cost are rejected.
//!
//! ## References
//! G. Fazekas, P. Gáspár, B. Németh, "Wheel Odometry Model Calibration with
//! Input Compensation by Optimal Control", IFAC-PapersOnLine, 2022.

use nalgebra::allocator::Allocator;
use nalgebra::{
    DefaultAllocator, Dim, Matrix3, Matrix3x4, OMatrix, SMatrix, SVector, SymmetricEigen, Vector3, Vector4,
};
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::drive::segment::SegmentData;
use crate::error::{Error, Result};
use crate::model::extrinsics::{Extrinsics, ExtrinsicsEstimate};
use crate::model::param::{Param, ParamSet};
use crate::model::{step_jacobians, wrap_angle, Theta};

mod extrinsics;
mod gauss_newton;
mod per_drive;

/// Normal equations of one segment at (θ, e) over `[θ, lever_x, lever_y,
/// heading_offset]`: the rollout with the reference extrinsics `e`,
/// residuals weighted by `w` (`[w_px, w_py, w_ψ]`). What a recursive
/// calibrator folds in per segment.
pub fn extrinsics_normal_equations(
    seg: &SegmentData<'_>,
    theta: &Theta,
    e: &Extrinsics,
    w: &[f64; 3],
) -> NormalEquations<7> {
    extrinsics::segment_normal_equations(seg, theta, e, w)
}

/// Options of the Gauss-Newton identification.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IdentifyOptions {
    /// Maximum number of Gauss-Newton iterations i_max, 1 … 100,000.
    /// Default 5 (paper).
    pub max_iterations: usize,
    /// Residual weights `[w_px, w_py, w_ψ]` per sample. Default `[1, 1, 40²]`.
    pub weights: [f64; 3],
    /// Which parameters are estimated; the others stay at their initial
    /// value. Default: all four of θ (`["c_e", "c_d", "t_r", "d"]` in JSON).
    pub free: ParamSet,
    /// Stop when the relative step `‖Δθ/θ_scale‖∞` falls below this (a
    /// finite number, 0 or more). Default 1e-12.
    pub step_tolerance: f64,
    /// A step whose relative cost change `|ΔC|/C` is at most this counts as
    /// converged (the cost is flat to round-off) rather than as a cost
    /// increase (a finite number, 0 or more). Default 1e-12.
    pub cost_tolerance: f64,
    /// Parameter resolutions used by the observability check, `[c_e, c_d,
    /// t_r, d]` in SI units. Default `[0.01 m, 0.001 m, 0.015 m, 0.0005
    /// m/(m/s²)]` (0.5 % of c_e, 1 mm, 1 % of t_r, 0.5 mm per m/s²).
    pub resolution: [f64; 4],
    /// A parameter (or combination) is *not observable* when moving it by
    /// its resolution changes the predicted poses by less than this RMS,
    /// in weighted metres (a finite number, 0 or more). Default 0.01 m.
    pub min_sensitivity_m: f64,
    /// Parameters that make up (|component| > 0.3) an eigenvector of the
    /// equilibrated `JᵀWJ` whose eigenvalue is below this fraction of the
    /// largest are also named *not observable*: each of them moves the poses
    /// enough on its own, but the data cannot tell them apart. Default 1e-2.
    ///
    /// Evidence for the default (batch G-N, reciprocal condition numbers):
    /// simulated 8 km paper drives 8.5e-2 and 1.4e-1; PSU van, all segments
    /// of either half, 4.2e-2 and 6.0e-2 (held-out Ē_p 24–26 m against 66–73 m
    /// of θ_0); PSU van, yaw-rate selected segments, 7.3e-3 and 8.7e-4 (c_d
    /// 12 mm and 6.5 mm, held-out Ē_p 349 m and 46 m); comma2k19 RAV4
    /// (straight), 5.1e-4, and 2.6e-3 with t_r fixed (c_d against d: the IMU
    /// a_y carries a roll/bank bias that makes d·a_y act like c_d).
    pub min_rcond: f64,
    /// The reference sensor's extrinsics (lever arm, heading offset): the
    /// initial value of those in [`IdentifyOptions::free`] and the held
    /// value of the others. Default 0 (the reference is the rear-axle
    /// centre, aligned with the vehicle: docs/method.md §1). See [`Extrinsics`].
    #[serde(default)]
    pub extrinsics: Extrinsics,
    /// Resolutions of the extrinsics for the observability check, `[lever_x
    /// (m), lever_y (m), heading_offset (rad)]`. Default `[0.1, 0.1, 0.001]`
    /// (10 cm, 1 mrad: 1 mrad moves a 300 m dead-reckoned path by 0.3 m).
    #[serde(default = "default_extrinsics_resolution")]
    pub extrinsics_resolution: [f64; 3],
    /// Cluster length of the cluster-robust covariance
    /// (`IdentifyReport::robust`), samples: segments starting within this
    /// many samples of a cluster's first segment join it. It must cover at
    /// least one segment length so that segments which share samples mostly
    /// fall in one cluster. Default 1300 (two default segment lengths).
    #[serde(default = "default_robust_block_steps")]
    pub robust_block_steps: usize,
    /// Fewest clusters for which the cluster-robust covariance is computed
    /// (else `IdentifyReport::robust` is `None`). Its meat is a sum of
    /// `G` cluster scores, of rank at most `G − 1`, and the relative error
    /// of a σ from it is about `1/√(2(G − 1))`; with fewer clusters than
    /// parameters it even claims some combinations are known exactly.
    /// Default 10 (σ within about ±25 %; on the PSU test-track runs, whose
    /// turning segments fall in at most 6 clusters, the robust σ came out
    /// below the model σ for some parameters).
    #[serde(default = "default_robust_min_clusters")]
    pub robust_min_clusters: usize,
}

/// The most Gauss-Newton iterations [`IdentifyOptions::max_iterations`]
/// may ask for (the ceiling of `max_iterations` wherever it is given).
pub(crate) const MAX_ITERATIONS: usize = 100_000;

fn default_robust_block_steps() -> usize {
    1300
}

fn default_robust_min_clusters() -> usize {
    10
}

fn default_extrinsics_resolution() -> [f64; 3] {
    [0.1, 0.1, 0.001]
}

impl Default for IdentifyOptions {
    fn default() -> Self {
        IdentifyOptions {
            max_iterations: 5,
            weights: [1.0, 1.0, 1600.0],
            free: ParamSet::THETA,
            step_tolerance: 1e-12,
            cost_tolerance: 1e-12,
            resolution: [0.01, 0.001, 0.015, 0.0005],
            min_sensitivity_m: 0.01,
            min_rcond: 1e-2,
            extrinsics: Extrinsics::ZERO,
            extrinsics_resolution: default_extrinsics_resolution(),
            robust_block_steps: default_robust_block_steps(),
            robust_min_clusters: default_robust_min_clusters(),
        }
    }
}

impl IdentifyOptions {
    /// Checks the options, naming the offending field.
    pub(crate) fn validate(&self) -> Result<()> {
        if !(1..=MAX_ITERATIONS).contains(&self.max_iterations) {
            let reason = format!("= {} is outside 1 … {MAX_ITERATIONS}", self.max_iterations);
            return Err(Error::InvalidOption { field: "max_iterations", reason });
        }
        for (field, v) in [
            ("step_tolerance", self.step_tolerance),
            ("cost_tolerance", self.cost_tolerance),
            ("min_sensitivity_m", self.min_sensitivity_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::InvalidOption {
                    field,
                    reason: format!("= {v}: must be a finite number, 0 or more"),
                });
            }
        }
        if self.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::InvalidOption { field: "weights", reason: "must be finite and non-negative".into() });
        }
        if self.free.is_empty() {
            return Err(Error::InvalidOption { field: "free", reason: "at least one parameter must be free".into() });
        }
        if self.resolution.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(Error::InvalidOption { field: "resolution", reason: "must be positive".into() });
        }
        if !(self.min_rcond.is_finite() && (0.0..1.0).contains(&self.min_rcond)) {
            return Err(Error::InvalidOption { field: "min_rcond", reason: "must be in [0, 1)".into() });
        }
        self.extrinsics.validate()?;
        if self.extrinsics_resolution.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return Err(Error::InvalidOption { field: "extrinsics_resolution", reason: "must be positive".into() });
        }
        if self.robust_block_steps == 0 {
            return Err(Error::InvalidOption { field: "robust_block_steps", reason: "must be at least 1".into() });
        }
        if self.robust_min_clusters < 2 {
            return Err(Error::InvalidOption { field: "robust_min_clusters", reason: "must be at least 2".into() });
        }
        Ok(())
    }

    /// True when the identification involves the reference extrinsics:
    /// some of them are free, or held at a value other than 0. Otherwise
    /// the paper's θ-only path runs, unchanged.
    pub(crate) fn uses_extrinsics(&self) -> bool {
        !self.free.intersection(ParamSet::EXTRINSICS).is_empty() || !self.extrinsics.is_zero()
    }
}

research_pub! {
    /// Why the iteration stopped. Reaching the iteration limit is an outcome, not an error.
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    #[serde(tag = "reason", rename_all = "snake_case")]
    enum Termination {
        /// `max_iterations` accepted steps were taken.
        MaxIterations {
            /// The limit.
            iterations: usize,
        },
        /// The next step gave a θ with a non-finite component; it was rejected.
        NonFiniteCandidate {
            /// Cost before it (kept).
            previous: f64,
        },
        /// The next step gave a θ with `c_e ≤ 0` or `t_r ≤ 0`; it was rejected.
        NonPhysicalCandidate {
            /// Cost before it (kept).
            previous: f64,
        },
        /// The next step would have increased the weighted cost; it was rejected.
        CostIncreased {
            /// Cost after the rejected step.
            cost: f64,
            /// Cost before it (kept).
            previous: f64,
        },
        /// The next step changed the cost by no more than round-off (relative
        /// change at most [`IdentifyOptions::cost_tolerance`]): converged.
        Converged {
            /// Relative cost change of the last step tried.
            rel_change: f64,
            /// The tolerance.
            threshold: f64,
        },
        /// The relative step fell below the tolerance.
        StepTolerance {
            /// The relative step size.
            rel_step: f64,
            /// The tolerance.
            threshold: f64,
        },
    }
}

impl std::fmt::Display for Termination {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Termination::MaxIterations { iterations } => write!(f, "iteration limit: {iterations}"),
            Termination::NonFiniteCandidate { previous } => {
                write!(f, "non-finite candidate θ at cost {previous:.6e} (step rejected)")
            }
            Termination::NonPhysicalCandidate { previous } => {
                write!(f, "candidate θ with c_e or t_r not positive at cost {previous:.6e} (step rejected)")
            }
            Termination::CostIncreased { cost, previous } => {
                write!(f, "cost increased: {cost:.6e} > {previous:.6e} (step rejected)")
            }
            Termination::Converged { rel_change, threshold } => {
                write!(f, "converged: relative cost change {rel_change:.1e} <= {threshold:.0e}")
            }
            Termination::StepTolerance { rel_step, threshold } => {
                write!(f, "step tolerance: {rel_step:.1e} <= {threshold:.0e}")
            }
        }
    }
}

research_pub! {
    /// One accepted iteration.
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    struct IterationRecord {
        /// θ after the step.
        pub theta: Theta,
        /// Weighted cost at that θ.
        pub cost: f64,
    }
}

/// Observability diagnostics: which parameters the data cannot determine,
/// with the numbers of the check that decided it. Batch Gauss-Newton (and
/// the 3-step method's final identification) checks `JᵀWJ` at its estimate
/// and fills [`Observability::sensitivity_m`]; the EIV filter checks its
/// information matrix `H_θ` and fills [`Observability::sigma_over_resolution`]
/// instead (`crate::eiv::EivObservability`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Observability {
    /// Reciprocal condition number of the equilibrated information
    /// (`D^{-½} JᵀWJ D^{-½}`, or the EIV filter's `H_θ`) over the
    /// parameters estimated (1 is perfect, near 0 means collinear columns);
    /// below [`IdentifyOptions::min_rcond`] (the EIV filter's own
    /// `min_rcond`) the parameters of the weak combination are named.
    pub rcond: f64,
    /// Batch Gauss-Newton: RMS change of the predicted poses (weighted
    /// metres per residual pose) when each parameter moves by its
    /// resolution (`[c_e, c_d, t_r, d]`; 0 for fixed parameters). `None`
    /// for an EIV result.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensitivity_m: Option<[f64; 4]>,
    /// EIV: each parameter's σ over its resolution from the filter's
    /// information at its start, the ratio that decided it: above 1 the
    /// filter held the parameter at its start's value and names it (0 for
    /// parameters not estimated; `EivObservability::start_sigma_over_resolution`).
    /// `None` for batch Gauss-Newton, and for an EIV filter told not to
    /// hold parameters (`EivOptions::fix_unobservable` off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_over_resolution: Option<[f64; 4]>,
    /// Parameters that are not observable from these data (alone or in a
    /// combination): their estimate is not to be trusted.
    pub unobservable: ParamSet,
}

impl Observability {
    /// Batch Gauss-Newton's diagnostics (no EIV ratios).
    pub(crate) fn of_batch(rcond: f64, sensitivity_m: [f64; 4], unobservable: ParamSet) -> Observability {
        Observability { rcond, sensitivity_m: Some(sensitivity_m), sigma_over_resolution: None, unobservable }
    }
}

research_pub! {
    /// The cluster-robust covariance of a batch Gauss-Newton estimate: the
    /// delete-one-cluster jackknife,
    ///
    /// ```text
    /// V = (G−1)/G Σ_c (Δ_c − Δ̄)(Δ_c − Δ̄)ᵀ,   Δ_c = (H − H_c)⁻¹ g_c,
    /// H = JᵀWJ,  H_c, g_c = Σ_{s∈c} J_sᵀW J_s, J_sᵀW r_s
    /// ```
    ///
    /// over `G` clusters of consecutive segments
    /// ([`IdentifyOptions::robust_block_steps`] samples each), Δ_c the
    /// one-step refit without cluster c. The model covariance `σ̂²H⁻¹`
    /// assumes independent residuals of one variance; input noise makes a
    /// segment's residuals strongly correlated (the roll-out integrates it)
    /// and overlapping segments share samples, so under the simulator's
    /// paper noise that σ is many times too small. The jackknife needs only
    /// that sums over clusters be roughly independent, and unlike the
    /// sandwich `H⁻¹ · G/(G−1) Σ_c g_c g_cᵀ · H⁻¹` (its first-order form,
    /// which stands in when some `H − H_c` is singular) it does not run
    /// short for a parameter that a few clusters determine. It is itself
    /// estimated from `G` clusters, so with few of them it is noisy: θ̂'s
    /// error over its σ follows Student's t with `G − 1` degrees of freedom,
    /// and `V` is scaled by `(t_{G−1}(Φ(3))/3)²` so that θ̂ ± 3σ keeps the
    /// 99.73 % of a known σ (1.36 × the σ at 10 clusters, 1.09 × at 30).
    /// Each variance is also raised where neighbouring clusters correlate.
    ///
    /// It does not know about bias: input noise biases batch Gauss-Newton
    /// (docs/method.md §9), and an interval around a biased estimate can miss the truth
    /// however honest its width.
    ///
    /// ## References
    /// A. C. Cameron, D. L. Miller, "A Practitioner's Guide to Cluster-Robust
    /// Inference", J. Human Resources 50(2), 2015; J. G. MacKinnon, M. Ø.
    /// Nielsen, M. D. Webb, "Cluster-robust inference: A guide to empirical
    /// practice", J. Econometrics 232(2), 2023; C. A. Bester, T. G. Conley,
    /// C. B. Hansen, "Inference with dependent data using cluster covariance
    /// estimators", J. Econometrics 165(2), 2011.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct RobustCovariance {
        /// Covariance of θ `[c_e, c_d, t_r, d]`, 4×4, row-major, zero rows for
        /// fixed parameters, SI units squared.
        pub covariance: [[f64; 4]; 4],
        /// Number of clusters `G`.
        pub clusters: usize,
        /// The cluster length used, samples.
        pub block_steps: usize,
    }
}

impl RobustCovariance {
    research_pub! {
        /// One-σ of θ (square roots of the diagonal).
        fn std_dev(&self) -> Theta {
            let c = &self.covariance;
            Theta { c_e: c[0][0].sqrt(), c_d: c[1][1].sqrt(), t_r: c[2][2].sqrt(), d: c[3][3].sqrt() }
        }
    }
}

research_pub! {
    /// The result of a Gauss-Newton identification.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct IdentifyReport {
        /// Initial θ.
        pub initial_theta: Theta,
        /// Estimated θ.
        pub theta: Theta,
        /// Weighted cost at the initial θ.
        pub initial_cost: f64,
        /// Weighted cost at the estimate.
        pub final_cost: f64,
        /// Accepted iterations.
        pub iterations: usize,
        /// Why it stopped.
        pub termination: Termination,
        /// Accepted iterations in order.
        pub history: Vec<IterationRecord>,
        /// Covariance estimate `σ² (JᵀWJ)⁻¹` of θ (4×4, row-major, zero rows for
        /// fixed parameters), with `σ² = cost / (m − p)`.
        pub covariance: [[f64; 4]; 4],
        /// The cluster-robust covariance of θ beside the model one (see
        /// [`RobustCovariance`]); `None` when the segments fall in fewer than
        /// [`IdentifyOptions::robust_min_clusters`] clusters or `JᵀWJ` is singular.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub robust: Option<RobustCovariance>,
        /// Observability diagnostics.
        pub observability: Observability,
        /// Segments used.
        pub segments: usize,
        /// Residual poses used (Σ K).
        pub residual_poses: usize,
        /// The reference extrinsics (initial, estimate, σ, covariance), when
        /// the identification involved them (`IdentifyOptions::uses_extrinsics`).
        /// `history` and `covariance` hold θ only.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub extrinsics: Option<ExtrinsicsEstimate>,
    }
}

impl IdentifyReport {
    /// The covariance its within-drive σ stands on: the cluster-robust one
    /// when there is one ([`Self::robust`]), else the model one.
    pub(crate) fn robust_or_model_covariance(&self) -> [[f64; 4]; 4] {
        self.robust.as_ref().map_or(self.covariance, |r| r.covariance)
    }
}

impl std::fmt::Display for IdentifyReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} | cost {:.4e} -> {:.4e} in {} it ({}), rcond {:.2e}",
            self.theta, self.initial_cost, self.final_cost, self.iterations, self.termination, self.observability.rcond
        )?;
        if let Some(e) = &self.extrinsics {
            write!(f, " | {}", e.value)?;
        }
        Ok(())
    }
}

/// Normal equations of one or more segments at one parameter vector:
/// over θ (`N = 4`, the default) or over θ and the reference extrinsics
/// (`N = 7`, [`Extrinsics`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NormalEquations<const N: usize = 4> {
    /// `JᵀWJ`.
    pub jtwj: SMatrix<f64, N, N>,
    /// `JᵀWR`.
    pub jtwr: SVector<f64, N>,
    /// Weighted cost `RᵀWR`.
    pub cost: f64,
    /// Residual poses.
    pub poses: usize,
}

impl<const N: usize> NormalEquations<N> {
    pub(crate) fn zero() -> Self {
        NormalEquations { jtwj: SMatrix::zeros(), jtwr: SVector::zeros(), cost: 0.0, poses: 0 }
    }
    pub(crate) fn add(&mut self, o: &NormalEquations<N>) {
        self.jtwj += o.jtwj;
        self.jtwr += o.jtwr;
        self.cost += o.cost;
        self.poses += o.poses;
    }
}

/// Residual of a predicted pose against the reference, heading wrapped.
#[inline]
pub(crate) fn pose_residual(reference: &Vector3<f64>, predicted: &Vector3<f64>) -> Vector3<f64> {
    let r = reference - predicted;
    Vector3::new(r[0], r[1], wrap_angle(r[2]))
}

/// Weighted cost of one segment at θ (no Jacobian).
pub(crate) fn segment_cost(seg: &SegmentData<'_>, theta: &Theta, weights: &[f64; 3]) -> f64 {
    let mut x = seg.reference(0);
    let mut cost = 0.0;
    for k in 0..seg.steps() {
        x = crate::model::step(&x, &seg.input(k), theta, seg.sample_time_s);
        let r = pose_residual(&seg.reference(k + 1), &x);
        cost += weights[0] * r[0] * r[0] + weights[1] * r[1] * r[1] + weights[2] * r[2] * r[2];
    }
    cost
}

/// Normal equations of one segment at θ, propagating the sensitivity.
pub(crate) fn segment_normal_equations(seg: &SegmentData<'_>, theta: &Theta, weights: &[f64; 3]) -> NormalEquations {
    let w = Matrix3::from_diagonal(&Vector3::from(*weights));
    let mut x = seg.reference(0);
    let mut s = Matrix3x4::<f64>::zeros();
    let mut ne = NormalEquations::zero();
    for k in 0..seg.steps() {
        let j = step_jacobians(&x, &seg.input(k), theta, seg.sample_time_s);
        s = j.f_x * s + j.f_theta;
        x = j.next;
        let r = pose_residual(&seg.reference(k + 1), &x);
        let ws = w * s;
        ne.jtwj += s.transpose() * ws;
        ne.jtwr += ws.transpose() * r;
        ne.cost += r.dot(&(w * r));
    }
    ne.poses = seg.steps();
    ne
}

/// Normal equations summed over segments, computed in parallel and summed in
/// segment order (deterministic whatever the thread count).
pub(crate) fn batch_normal_equations(
    segments: &[SegmentData<'_>],
    theta: &Theta,
    weights: &[f64; 3],
) -> NormalEquations {
    let parts: Vec<NormalEquations> =
        segments.par_iter().map(|s| segment_normal_equations(s, theta, weights)).collect();
    let mut total = NormalEquations::zero();
    for p in &parts {
        total.add(p);
    }
    total
}

/// The cluster-robust covariance of θ ([`RobustCovariance`]) of the batch
/// Gauss-Newton problem on `segments`, evaluated at `theta` without
/// iterating (the scores are centred, so `theta` need not be that
/// problem's minimum): e.g. the 3-step result's on the measured inputs
/// ([`crate::calibrate::three_step::ThreeStepUncertainty`]). θ's free entries only;
/// `None` as for [`IdentifyReport::robust`].
pub(crate) fn robust_covariance_at(
    segments: &[SegmentData<'_>],
    theta: &Theta,
    opts: &IdentifyOptions,
) -> Option<RobustCovariance> {
    let per: Vec<NormalEquations> =
        segments.par_iter().map(|s| segment_normal_equations(s, theta, &opts.weights)).collect();
    let mut total = NormalEquations::zero();
    for p in &per {
        total.add(p);
    }
    let free = opts.free.intersection(ParamSet::THETA).indices();
    gauss_newton::cluster_robust_covariance(&total, &per, segments, &free, opts).map(|(c, clusters)| RobustCovariance {
        covariance: to_array4(&c),
        clusters,
        block_steps: opts.robust_block_steps,
    })
}

/// Observability diagnostics of the free block of `JᵀWJ` (θ only: free
/// extrinsics are left out here; the identification with extrinsics runs
/// [`observability_of`] over all seven).
pub(crate) fn observability(ne: &NormalEquations, free: ParamSet, opts: &IdentifyOptions) -> Observability {
    let jtwj = nalgebra::DMatrix::from_fn(4, 4, |i, j| ne.jtwj[(i, j)]);
    let (rcond, s, unobservable) =
        observability_of(&jtwj, ne.poses, free.intersection(ParamSet::THETA), &opts.resolution, opts);
    Observability::of_batch(rcond, [s[0], s[1], s[2], s[3]], unobservable)
}

/// The observability check on a `JᵀWJ` over the first `jtwj.nrows()`
/// parameters in vector order ([`Param::index`]), with one resolution per
/// parameter: the reciprocal condition number of the equilibrated free
/// block, the sensitivity of each parameter (0 when not free) and the
/// parameters named not observable.
pub(crate) fn observability_of(
    jtwj: &nalgebra::DMatrix<f64>,
    poses: usize,
    free: ParamSet,
    resolution: &[f64],
    opts: &IdentifyOptions,
) -> (f64, Vec<f64>, ParamSet) {
    let n = jtwj.nrows();
    let idx: Vec<usize> = free.indices().into_iter().filter(|i| *i < n).collect();
    observability_of_entries(jtwj, poses, &idx, resolution, opts)
}

/// [`observability_of`] over the entries `idx` of the parameter vector;
/// entries past the heading offset's (a joint calibration's per-drive
/// offsets) are named as the heading offset.
pub(crate) fn observability_of_entries(
    jtwj: &nalgebra::DMatrix<f64>,
    poses: usize,
    idx: &[usize],
    resolution: &[f64],
    opts: &IdentifyOptions,
) -> (f64, Vec<f64>, ParamSet) {
    let n = jtwj.nrows();
    let poses = poses.max(1) as f64;
    let mut sensitivity = vec![0.0; n];
    for &i in idx {
        sensitivity[i] = (jtwj[(i, i)].max(0.0) / poses).sqrt() * resolution[i];
    }
    // Physically scaled matrix: Hs = S H S / poses (S = resolutions).
    let p = idx.len();
    let mut hs = nalgebra::DMatrix::zeros(p, p);
    let mut he = nalgebra::DMatrix::zeros(p, p);
    for (a, &i) in idx.iter().enumerate() {
        for (b, &j) in idx.iter().enumerate() {
            hs[(a, b)] = jtwj[(i, j)] * resolution[i] * resolution[j] / poses;
            let dd = (jtwj[(i, i)] * jtwj[(j, j)]).sqrt();
            he[(a, b)] = if dd > 0.0 { jtwj[(i, j)] / dd } else { 0.0 };
        }
    }
    let eig_e = SymmetricEigen::new(he);
    let (mn, mx) = eig_e.eigenvalues.iter().fold((f64::INFINITY, 0.0f64), |(a, b), &l| (a.min(l), b.max(l)));
    let rcond = if mx > 0.0 { (mn / mx).max(0.0) } else { 0.0 };
    let mut weak = vec![false; n];
    // A near-collinear combination (equilibrated eigenvalue below min_rcond
    // of the largest): the parameters in it cannot be told apart.
    if p > 1 {
        for (e, lambda) in eig_e.eigenvalues.iter().enumerate() {
            if mx <= 0.0 || lambda.max(0.0) / mx < opts.min_rcond {
                let v = eig_e.eigenvectors.column(e);
                for (a, &i) in idx.iter().enumerate() {
                    if v[a].abs() > 0.3 {
                        weak[i] = true;
                    }
                }
            }
        }
    }
    // A direction of the scaled matrix with RMS effect below the threshold is
    // unobservable; name the parameters that make it up.
    let eig = SymmetricEigen::new(hs);
    for (e, lambda) in eig.eigenvalues.iter().enumerate() {
        if lambda.max(0.0).sqrt() < opts.min_sensitivity_m {
            let v = eig.eigenvectors.column(e);
            for (a, &i) in idx.iter().enumerate() {
                if v[a].abs() > 0.3 {
                    weak[i] = true;
                }
            }
        }
    }
    let heading_offset = Param::HeadingOffset.index();
    let unobservable = (0..n).filter(|i| weak[*i]).filter_map(|i| Param::from_index(i.min(heading_offset))).collect();
    (rcond, sensitivity, unobservable)
}

research_pub! {
    /// Batch Gauss-Newton over segments from `theta0` (docs/method.md §4). With one
    /// segment this is the paper's *pure* Gauss-Newton.
    ///
    /// Parameters that the data cannot determine are listed in
    /// [`Observability::unobservable`] of the report; callers decide whether
    /// that is a warning or an error (the CLI warns, naming them).
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// # #[cfg(feature = "research")] {
    /// use odocal::{identify, segment, sim, Theta};
    /// let drive = sim::simulate(&sim::SimOptions { length_km: 2.0, noise: "off".parse()?, ..sim::SimOptions::paper(7) })?.drive;
    /// let selected = segment::calibration_segments(&drive, &Default::default())?;
    /// let data: Vec<_> = selected.iter().map(|s| segment::SegmentData::new(&drive, s)).collect();
    /// let report = identify::batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &Default::default())?;
    /// assert!((report.theta.c_e - 1.95).abs() < 1e-3);
    /// # }
    /// # Ok(()) }
    /// ```
    fn batch_gauss_newton(
        segments: &[SegmentData<'_>],
        theta0: &Theta,
        opts: &IdentifyOptions,
    ) -> Result<IdentifyReport> {
        opts.validate()?;
        theta0.validate()?;
        if segments.is_empty() {
            return Err(Error::NoSegments("Gauss-Newton needs at least one segment".into()));
        }
        if opts.uses_extrinsics() {
            return extrinsics::batch_gauss_newton_with_extrinsics(segments, theta0, opts);
        }
        let free = opts.free.indices();
        let problem = ThetaProblem { weights: opts.weights, opts };
        let scale = Vector4::new(theta0.c_e.abs().max(1.0), 1e-3, theta0.t_r.abs().max(1.0), 1e-3);
        let out = gauss_newton::run(&problem, segments, &theta0.to_vector(), &free, &scale, opts)?;
        let ne = out.total;
        let obs = observability(&ne, opts.free, opts);
        let cov = gauss_newton::model_covariance(&ne, &free);
        let robust = gauss_newton::cluster_robust_covariance(&ne, &out.per_segment, segments, &free, opts);
        Ok(IdentifyReport {
            initial_theta: *theta0,
            theta: Theta::from_vector(&out.x),
            initial_cost: out.initial_cost,
            final_cost: ne.cost,
            iterations: out.history.len(),
            termination: out.termination,
            history: out
                .history
                .iter()
                .map(|(x, cost)| IterationRecord { theta: Theta::from_vector(x), cost: *cost })
                .collect(),
            covariance: to_array4(&cov),
            robust: robust.map(|(c, clusters)| RobustCovariance {
                covariance: to_array4(&c),
                clusters,
                block_steps: opts.robust_block_steps,
            }),
            observability: obs,
            segments: segments.len(),
            residual_poses: ne.poses,
            extrinsics: None,
        })
    }
}

/// [`batch_gauss_newton`] on segments of a drive joined from several
/// (`drive_starts`: [`crate::Drive::drive_starts`]): with the heading
/// offset free and segments from two drives or more, each drive gets its
/// own offset (one θ, one lever arm); otherwise [`batch_gauss_newton`]
/// itself.
pub(crate) fn batch_gauss_newton_drives(
    segments: &[SegmentData<'_>],
    drive_starts: &[usize],
    theta0: &Theta,
    opts: &IdentifyOptions,
) -> Result<IdentifyReport> {
    let drives = per_drive::Drives { starts: drive_starts };
    if !drives.per_drive(segments, opts) {
        return batch_gauss_newton(segments, theta0, opts);
    }
    opts.validate()?;
    theta0.validate()?;
    per_drive::batch_gauss_newton_per_drive(segments, &drives, theta0, opts)
}

/// θ after the first step [`batch_gauss_newton_drives`] takes from
/// `theta0` (and `opts.extrinsics`), without step acceptance: one pass
/// over the segments. None when the step cannot be taken.
pub(crate) fn gauss_newton_step_drives(
    segments: &[SegmentData<'_>],
    drive_starts: &[usize],
    theta0: &Theta,
    opts: &IdentifyOptions,
) -> Option<Theta> {
    let drives = per_drive::Drives { starts: drive_starts };
    if drives.per_drive(segments, opts) {
        return per_drive::one_step(segments, &drives, theta0, opts);
    }
    if opts.uses_extrinsics() {
        return extrinsics::one_step(segments, theta0, opts);
    }
    let problem = ThetaProblem { weights: opts.weights, opts };
    let x = gauss_newton::one_step(&problem, segments, &theta0.to_vector(), &opts.free.indices())?;
    Some(Theta::from_vector(&x))
}

/// `D m D` with `D = diag(max(1, √(wider(i) / m_ii)))`: each variance of
/// the covariance `m` raised to `wider(i)` where that is larger (and finite,
/// and `m_ii` positive), its correlations kept. How a covariance takes a
/// second, wider estimate of its variances: EIV's block sandwich, batch
/// G-N's correlated neighbouring clusters.
pub(crate) fn raise_variances<D: Dim>(m: &OMatrix<f64, D, D>, wider: impl Fn(usize) -> f64) -> OMatrix<f64, D, D>
where
    DefaultAllocator: Allocator<D, D>,
{
    let f: Vec<f64> = (0..m.nrows())
        .map(|i| {
            let (v, w) = (m[(i, i)], wider(i));
            if v > 0.0 && w.is_finite() && w > v {
                (w / v).sqrt()
            } else {
                1.0
            }
        })
        .collect();
    m.map_with_location(|i, j, x| x * f[i] * f[j])
}

/// The top-left 4×4 (θ) block of an N×N matrix as arrays.
pub(crate) fn to_array4<const N: usize>(m: &SMatrix<f64, N, N>) -> [[f64; 4]; 4] {
    std::array::from_fn(|i| std::array::from_fn(|j| m[(i, j)]))
}

/// The θ-only problem of the Gauss-Newton loop (docs/method.md §4).
struct ThetaProblem<'a> {
    weights: [f64; 3],
    opts: &'a IdentifyOptions,
}

impl gauss_newton::Problem<4> for ThetaProblem<'_> {
    fn normal_equations(&self, seg: &SegmentData<'_>, x: &Vector4<f64>) -> NormalEquations {
        segment_normal_equations(seg, &Theta::from_vector(x), &self.weights)
    }
    fn cost(&self, seg: &SegmentData<'_>, x: &Vector4<f64>) -> f64 {
        segment_cost(seg, &Theta::from_vector(x), &self.weights)
    }
    fn physical(&self, x: &Vector4<f64>) -> bool {
        Theta::from_vector(x).validate().is_ok()
    }
    fn non_finite_start(&self, x: &Vector4<f64>) -> Error {
        Error::Numerical(format!("the cost at the initial θ ({}) is not finite", Theta::from_vector(x)))
    }
    fn singular(&self, ne: &NormalEquations) -> Error {
        let weak = observability(ne, self.opts.free, self.opts).unobservable;
        Error::NotObservable {
            params: if weak.is_empty() { self.opts.free } else { weak }.names(),
            reason: "JᵀWJ is singular at the current θ (the data do not excite these parameters); \
                     hold them fixed at θ_0"
                .into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::segment::{cut, SegmentData};
    use crate::drive::{Drive, Signals};
    use crate::model::{step, Input};

    /// A straight drive at varying speed, reference = exact model trajectory,
    /// plus optional small deterministic heading wiggle on the reference.
    fn straight(n: usize, wiggle: f64) -> Drive {
        let th = Theta::SIM_DEFAULT_TRUE;
        let ts = 0.025;
        let mut x = crate::model::State::zeros();
        let (mut t, mut px, mut py, mut psi, mut nl, mut nr) = (vec![], vec![], vec![], vec![], vec![], vec![]);
        for i in 0..n {
            // Straight motion (ω = 0, a_y = 0) at a varying speed.
            let v = 10.0 + 3.0 * (i as f64 * 0.01).sin();
            let (n_rl, n_rr) = crate::model::wheel_rotations(v, 0.0, 0.0, &th);
            let u = Input { n_rl, n_rr, beta: 0.0, a_y: 0.0 };
            t.push(i as f64 * ts);
            px.push(x[0]);
            py.push(x[1]);
            psi.push(x[2] + wiggle * (i as f64 * 0.37).sin());
            nl.push(u.n_rl);
            nr.push(u.n_rr);
            x = step(&x, &u, &th, ts);
        }
        let z = vec![0.0; n];
        crate::drive::DriveBuilder {
            t,
            measured: Signals { px, py, psi, n_rl: nl, n_rr: nr, beta: z.clone(), a_y: z },
            context: "straight".into(),
            ..Default::default()
        }
        .build()
        .expect("valid")
    }

    #[test]
    fn straight_drive_names_track_width_and_load_transfer() {
        // Exactly straight: t_r and d have zero sensitivity; the error names them.
        let d = straight(3000, 0.0);
        let segs = cut(&d, 0, 650, 100);
        let data: Vec<SegmentData> = segs.iter().map(|s| SegmentData::new(&d, s)).collect();
        // Either outcome (singular error, or a report) must name t_r and d, not c_e.
        // (At θ_0 the model still turns, c_d being wrong, so early steps can be regular.)
        let check = |res: Result<IdentifyReport>| match res {
            Err(e) => {
                let m = e.to_string();
                assert!(m.contains("t_r") && m.contains("d not observable"), "{m}");
                assert!(!m.contains("c_e"), "c_e is observable on a straight drive: {m}");
            }
            Ok(r) => {
                let u = r.observability.unobservable;
                assert!(u.contains(Param::TR) && u.contains(Param::D), "{:?}", r.observability);
                assert!(!u.contains(Param::CE), "{:?}", r.observability);
            }
        };
        check(batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &IdentifyOptions::default()));
        // With heading noise on the reference.
        let d = straight(3000, 1e-3);
        let data: Vec<SegmentData> = cut(&d, 0, 650, 100).iter().map(|s| SegmentData::new(&d, s)).collect();
        check(batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &IdentifyOptions::default()));
        // Holding them fixed leaves c_e and c_d, which are identified.
        let opts = IdentifyOptions { free: "c_e,c_d".parse().expect("params"), ..Default::default() };
        let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("fixed");
        assert!(r.observability.unobservable.is_empty(), "{:?}", r.observability);
        assert!((r.theta.c_e - 1.95).abs() < 1e-3, "{}", r.theta);
        approx::assert_relative_eq!(r.theta.t_r, 1.6);
    }

    #[test]
    fn accepted_steps_never_increase_cost() {
        let d = straight(2000, 2e-3);
        let data: Vec<SegmentData> = cut(&d, 0, 650, 100).iter().map(|s| SegmentData::new(&d, s)).collect();
        let opts =
            IdentifyOptions { free: "c_e,c_d".parse().expect("params"), max_iterations: 10, ..Default::default() };
        let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("ok");
        let mut prev = r.initial_cost;
        for h in &r.history {
            assert!(h.cost <= prev, "{} > {prev}", h.cost);
            prev = h.cost;
        }
        assert!(r.final_cost < r.initial_cost);
    }

    /// Normal equations of four parameter columns over `poses` poses, with
    /// columns 1 and 3 (c_d, d) nearly collinear when `collinear`.
    fn normal_equations(collinear: bool) -> NormalEquations {
        // Per-pose sensitivity rows in units of each parameter's resolution,
        // so that every parameter alone moves the poses by ~1 m per step.
        let res = IdentifyOptions::default().resolution;
        let poses = 100;
        let mut jtwj = nalgebra::Matrix4::zeros();
        for k in 0..poses {
            let s = (k as f64 * 0.37).sin();
            let c = (k as f64 * 0.21).cos();
            let d_col = if collinear { s + 1e-3 * c } else { c };
            let row = Vector4::new(1.0 / res[0], s / res[1], (s * c + 0.5) / res[2], d_col / res[3]);
            jtwj += row * row.transpose();
        }
        NormalEquations { jtwj, jtwr: Vector4::zeros(), cost: 1.0, poses }
    }

    #[test]
    fn collinear_parameters_are_named_even_when_each_is_sensitive() {
        let opts = IdentifyOptions::default();
        let o = observability(&normal_equations(true), ParamSet::THETA, &opts);
        assert!(o.sensitivity_m.is_some_and(|s| s.iter().all(|s| *s > opts.min_sensitivity_m)), "{o:?}");
        assert!(o.rcond < opts.min_rcond, "{o:?}");
        assert_eq!(o.unobservable, ParamSet::from_iter([Param::CD, Param::D]));
    }

    #[test]
    fn well_conditioned_parameters_are_not_named() {
        let o = observability(&normal_equations(false), ParamSet::THETA, &IdentifyOptions::default());
        assert!(o.unobservable.is_empty(), "{o:?}");
    }

    #[test]
    fn fixing_one_of_a_collinear_pair_clears_it() {
        let o = observability(&normal_equations(true), ParamSet::THETA.without(Param::D), &IdentifyOptions::default());
        assert!(o.unobservable.is_empty(), "{o:?}");
    }

    /// The cluster-robust covariance on a 12 km paper-noise drive: there,
    /// present, over the clusters the options give, and much wider than the
    /// model σ (5–120× over 20 seeds, `gn_coverage` in crates/odocal-lab); absent
    /// with fewer clusters than asked for. (0.2 s with the test profile's
    /// optimisation.)
    #[test]
    fn robust_covariance_is_wider_than_the_model_one_under_paper_noise() {
        use crate::sim::{simulate, SimOptions};
        let d = simulate(&SimOptions { length_km: 12.0, ..SimOptions::paper(3) }).expect("simulate").drive;
        let sel = crate::drive::segment::select_segments(&d, &Default::default()).expect("segments");
        let data: Vec<SegmentData> = sel.selected.iter().map(|s| SegmentData::new(&d, s)).collect();
        let opts = IdentifyOptions::default();
        let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("identify");
        let rb = r.robust.as_ref().expect("12 km give enough clusters");
        let starts: Vec<(usize, usize)> = data.iter().map(|s| (s.drive_start, s.start)).collect();
        assert_eq!(rb.clusters, gauss_newton::clusters(&starts, opts.robust_block_steps).1);
        assert!(rb.clusters >= opts.robust_min_clusters, "{}", rb.clusters);
        for i in 0..4 {
            let (model, robust) = (r.covariance[i][i].sqrt(), rb.covariance[i][i].sqrt());
            assert!(robust > 3.0 * model, "θ[{i}]: robust σ {robust:.3e} vs model σ {model:.3e}");
        }
        let fewer = IdentifyOptions { robust_min_clusters: rb.clusters + 1, ..opts };
        let r2 = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &fewer).expect("identify");
        assert!(r2.robust.is_none());
        assert_eq!(r2.covariance, r.covariance, "the model covariance does not depend on the robust options");
    }

    /// The cluster-robust covariance is the jackknife of the estimate over
    /// its clusters: refitting to convergence without each cluster in turn
    /// and taking `(G−1)/G Σ (θ_(−c) − θ̄)(θ_(−c) − θ̄)ᵀ`, with the factor
    /// for few clusters, gives the σ it reports to within 8 % (its refits
    /// are one Gauss-Newton step each).
    #[test]
    fn robust_covariance_is_the_jackknife_over_clusters() {
        use crate::sim::{simulate, SimOptions};
        let d = simulate(&SimOptions { length_km: 6.0, ..SimOptions::paper(5) }).expect("simulate").drive;
        let sel = crate::drive::segment::select_segments(&d, &Default::default()).expect("segments");
        let data: Vec<SegmentData> = sel.selected.iter().map(|s| SegmentData::new(&d, s)).collect();
        let opts = IdentifyOptions::default();
        let r = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("identify");
        let rb = r.robust.as_ref().expect("6 km give enough clusters");
        let starts: Vec<(usize, usize)> = data.iter().map(|s| (s.drive_start, s.start)).collect();
        let (id, g) = gauss_newton::clusters(&starts, opts.robust_block_steps);
        let refits: Vec<[f64; 4]> = (0..g)
            .map(|c| {
                let kept: Vec<SegmentData> = data.iter().zip(&id).filter(|(_, &k)| k != c).map(|(s, _)| *s).collect();
                <[f64; 4]>::from(batch_gauss_newton(&kept, &r.theta, &opts).expect("refit").theta)
            })
            .collect();
        for i in 0..4 {
            // The jackknife of the refits, widened where neighbouring
            // clusters (one drive: each cluster and the next) correlate.
            let mean = refits.iter().map(|t| t[i]).sum::<f64>() / g as f64;
            let dev: Vec<f64> = refits.iter().map(|t| t[i] - mean).collect();
            let spread = dev.iter().map(|x| x * x).sum::<f64>();
            let cross = 2.0 * dev.windows(2).map(|w| w[0] * w[1]).sum::<f64>();
            let jackknife =
                (spread.max(spread + cross) * (g - 1) as f64 / g as f64 * gauss_newton::few_clusters_factor(g)).sqrt();
            let reported = rb.covariance[i][i].sqrt();
            // One-step deltas against refits: the plain jackknife agrees within
            // 5 %; the neighbours widen c_e, c_d and d here by 4–28 %, and
            // their one-step cross products of 11 clusters differ from the
            // refits' by up to 6 % (c_e).
            assert!((reported / jackknife - 1.0).abs() < 0.08, "θ[{i}]: {reported:.4e} against refits {jackknife:.4e}");
        }
    }

    #[test]
    fn min_rcond_is_validated() {
        let e = IdentifyOptions { min_rcond: 1.5, ..Default::default() }.validate().expect_err("bad");
        assert!(e.to_string().contains("min_rcond"), "{e}");
    }
}
