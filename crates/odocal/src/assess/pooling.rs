//! The σ that predicts the next drive of the same vehicle.
//!
//! A calibration's own σ (batch-gn's cluster-robust σ, the 3-step's batch
//! spread, EIV's filter covariance) is a *within-drive* σ: it says how well
//! this drive determines θ. The next drive of the same vehicle differs by
//! more: tyre temperature and pressure, load, the reference's own biases
//! and the roads change from drive to drive. On the six test-track runs of
//! one afternoon (docs/validation.md, "Coverage of the reported σ") the
//! between-run spread of c_e was about 15× the within-drive σ, of t_r 30×.
//!
//! The σ that stands for a result ([`crate::CalibrationReport::result_sigma`],
//! JSON `sigma`) is therefore the σ for the next drive, per parameter
//!
//! ```text
//! σ_next = √(σ_within² + h² + gap²/3 + f²/3 + a² + b²),   b² = max(τ², s² − σ_within²)
//! ```
//!
//! so that `√(σ_within² + b²) = max(s, √(σ_within² + τ²))`: the
//! within-drive noise counts once.
//!
//! - `σ_within`: the method's within-drive σ (the report's
//!   `sigma_within_drive`); for a parameter the
//!   EIV filter held at its batch Gauss-Newton start's estimate, the
//!   start's σ. When the result is EIV's own estimate or its refit, per
//!   parameter at least the start's cluster-robust σ
//!   (`NextDriveSigma::within_from_start`). EIV's σ holds as far as its
//!   noise model does: a process the model lacks or makes too fast (wheel
//!   noise slower than its time constants, a drifting bias) moves EIV's θ
//!   and its start's alike, and the filter's σ does not see it. The
//!   start's jackknife over 32.5 s clusters of segments measures how θ
//!   varies along the drive with no noise model. Not where the start has
//!   too few clusters for it (its model σ assumes independent residuals
//!   and bounds nothing).
//! - `h`: with the EIV method (its own estimate, its refit or its batch
//!   Gauss-Newton fallback), the common-mode wheel noise the within-drive
//!   σ leaves out, `h = σ_within · σ_c / σ_ref`: σ_c the common-mode
//!   wheel-scale σ of EIV's fitted noise model, σ_ref
//!   `COMMON_MODE_REFERENCE_SIGMA` (2.5 %). The filter's common-mode state
//!   has a fixed correlation time τ_c (2 s); a slower common-mode
//!   variation carries more power at the long periods that set c_e and t_r
//!   than that model grants, and its σ does not cover it (without `h`,
//!   on heavy common-mode worlds c_e's 95 % interval covers 75–85 %). After a
//!   fallback, σ_c is the wheel noise EIV's fit met, and batch G-N's
//!   errors-in-variables bias grows with it. The term grows with the
//!   fitted σ_c and vanishes with it: h ≤ 0.6 σ_within at ordinary levels
//!   (σ_c up to 1.5 %), h = σ_within at 2.5 %, 1.6 σ_within at the upper
//!   clamp (4 %). When σ_c sits at that clamp, the drive's common-mode
//!   noise is heavier than the model allows and `h` is a lower bound; the
//!   verdict says so (`heavy_common_mode_noise`).
//! - `gap`: when EIV's checks failed and the result is its batch
//!   Gauss-Newton start (the fallback), the distance between EIV's own
//!   estimate and the fallback's: batch G-N carries an errors-in-variables
//!   bias under input noise that its own σ does not cover, and the two
//!   estimates bracket it. With the truth anywhere between them (uniform),
//!   the fallback's error has RMS gap/√3. 0 otherwise, and 0 when EIV's
//!   own θ fails a plausibility guard (a diverged filter says nothing about
//!   the fallback's bias). When the calibration held noise levels and
//!   EIV's fit with them held failed, the fit with them estimated stands
//!   in for EIV's own when it passes the checks and the guards (the data
//!   contradict the held levels; the verdict's reason says so). A gap
//!   above 3 σ of the rest makes the verdict doubtful
//!   ([`crate::TrustOptions::max_fallback_gap_sigmas`]).
//! - `a`: when the result is EIV's own estimate and its t_r lies above
//!   its batch Gauss-Newton start's, that excess (for t_r; for the other
//!   parameters the shift that comes with it, along their regression on
//!   t_r in EIV's covariance, `a_i = |a_t · C_it / C_tt|`). Batch G-N's
//!   errors-in-variables bias on t_r points up: noise on the wheel
//!   rotations shrinks the fitted heading change per wheel difference,
//!   1/t_r, as in any regression on a noisy regressor. EIV's correction
//!   of that bias moves t_r down from the start. A t_r above the start is
//!   not that correction; the truth lies, as far as the errors-in-variables
//!   argument goes, at or below the start, so the excess is an error the
//!   filter's own σ does not describe (on random noise worlds, every EIV
//!   result accepted beyond 3 σ of the σ without `a` had its t_r above its
//!   start, by 0.4–3.6 %; docs/validation.md). 0 otherwise. An excess above
//!   3 σ of the rest makes the verdict doubtful
//!   ([`crate::TrustOptions::max_fallback_gap_sigmas`]).
//! - `f`: when the result is EIV's own estimate and its fit holds the
//!   reference's heading drift at its floor (a centimetre-grade position
//!   reference), the distance between its θ and that of the same fit
//!   without the floor (both before the bias correction;
//!   `crate::eiv::HeadingDriftTest::theta_without_floor`). The floor is a
//!   modelling choice the data do not settle, and on such references t_r
//!   moves with it by up to a few % (docs/validation.md, "The heading
//!   drift's floor"); the two fits bracket that choice, and like the
//!   fallback's gap it enters as f²/3. 0 otherwise. A gap above 3 σ of
//!   the rest makes the verdict doubtful
//!   ([`crate::TrustOptions::max_fallback_gap_sigmas`]).
//! - `τ`: the between-drive σ, the spread of the drives' true θ. With one
//!   drive the documented prior `BETWEEN_DRIVE_PRIOR`
//!   (`BetweenDrivePrior::between`); with several drives
//!   ([`crate::Calibration::drives`]), the DerSimonian–Laird
//!   random-effects estimate on the drives' separate fits
//!   (`dersimonian_laird`), never below the prior's.
//! - `s`: the floor, the prior's spread of estimates over the runs it was
//!   measured on (`BetweenDrivePrior::spread`). A spread of estimates
//!   holds the runs' within-drive noise (`s² ≈ τ² + σ_w²`), so adding it
//!   to a drive's σ_within in quadrature would count that noise twice.
//!   The prior's τ is the method-of-moments `√max(0, s² − σ̄_w²)`, σ̄_w
//!   the runs' own within-drive σ. Where those runs' σ_within exceeds their
//!   spread (c_e and d of the test-track runs' EIV estimates) that τ is 0:
//!   three runs cannot tell between-drive spread from within-drive noise.
//!   A drive more precise than they were (a batch Gauss-Newton fit, whose
//!   σ_within is 15–80× below the spread) would then get a σ below the
//!   spread the runs showed; the floor keeps it at `s`.

use serde::{Deserialize, Serialize};

use crate::eiv::NoiseSource;
use crate::model::Theta;

research_pub! {
    /// A random-effects pooling of one parameter over several drives
    /// (`dersimonian_laird`).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    struct RandomEffects {
        /// The pooled estimate: the mean weighted by `1/(σ_i² + τ²)`.
        pub mean: f64,
        /// 1σ of the pooled mean, `1/√Σ(1/(σ_i² + τ²))`.
        pub mean_sigma: f64,
        /// The between-drive σ τ.
        pub tau: f64,
        /// Cochran's Q of the fixed-effect fit.
        pub q: f64,
        /// Number of drives.
        pub drives: usize,
    }
}

/// DerSimonian–Laird random effects: `estimates[i]` with within-drive 1σ
/// `sigmas[i]` are modelled as `μ + b_i + e_i`, `b_i ~ N(0, τ²)`,
/// `e_i ~ N(0, σ_i²)`. τ² is the method-of-moments estimate
/// `max(0, (Q − (k−1)) / (Σw − Σw²/Σw))`, `w = 1/σ²`, `Q = Σw(y − ȳ_w)²`.
/// `None` with fewer than two drives, different lengths, or a σ that is not
/// finite and positive (worked by hand in the unit tests).
pub(crate) fn dersimonian_laird(estimates: &[f64], sigmas: &[f64]) -> Option<RandomEffects> {
    let k = estimates.len();
    if k < 2 || sigmas.len() != k || sigmas.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
        return None;
    }
    if estimates.iter().any(|y| !y.is_finite()) {
        return None;
    }
    let w: Vec<f64> = sigmas.iter().map(|s| 1.0 / (s * s)).collect();
    let sw: f64 = w.iter().sum();
    let sw2: f64 = w.iter().map(|w| w * w).sum();
    let fixed = w.iter().zip(estimates).map(|(w, y)| w * y).sum::<f64>() / sw;
    let q: f64 = w.iter().zip(estimates).map(|(w, y)| w * (y - fixed).powi(2)).sum();
    let c = sw - sw2 / sw;
    let tau2 = if c > 0.0 { ((q - (k - 1) as f64) / c).max(0.0) } else { 0.0 };
    let ws: Vec<f64> = sigmas.iter().map(|s| 1.0 / (s * s + tau2)).collect();
    let sws: f64 = ws.iter().sum();
    let mean = ws.iter().zip(estimates).map(|(w, y)| w * y).sum::<f64>() / sws;
    Some(RandomEffects { mean, mean_sigma: sws.sqrt().recip(), tau: tau2.sqrt(), q, drives: k })
}

research_pub! {
    /// The prior for the between-drive σ of one drive, relative: per
    /// parameter a fraction of a scale of θ (c_e and c_d of c_e, t_r and d
    /// of t_r; d's per m/s²). Measured on the default calibration of the
    /// three earliest test-track runs of 2024-08-05 (14-45-26, 15-28-33,
    /// 16-06-28), confirmed on the other three (docs/validation.md, "The
    /// next drive: six test-track runs"; lab `sigma_coverage`);
    /// docs/method.md, "The σ for the next drive".
    ///
    /// The spread of the runs' *estimates* holds their within-drive noise:
    /// `spread² ≈ τ² + within²`. The between-drive σ proper is the
    /// method-of-moments `τ̂ = √max(0, spread² − within²)`
    /// (`between`), and the spread is a floor on a drive's
    /// within-drive ⊕ between-drive σ ([`NextDriveSigma`]).
    #[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
    struct BetweenDrivePrior {
        /// The spread (sample sd) of c_e's estimates, over c_e.
        pub c_e: f64,
        /// The spread of c_d's estimates, over c_e.
        pub c_d: f64,
        /// The spread of t_r's estimates, over t_r.
        pub t_r: f64,
        /// The spread of d's estimates, over t_r (per m/s²).
        pub d: f64,
        /// The runs' within-drive σ (root mean square; the within-drive
        /// part of their σ for the next drive), relative as the spread,
        /// `[c_e, c_d, t_r, d]`.
        pub within: [f64; 4],
    }
}

research_pub! {
    /// σ_ref of the common-mode term `h = σ_within · σ_c / σ_ref` of the σ
    /// for the next drive (module docs): the fitted common-mode wheel-scale
    /// σ at which `h` equals the within-drive σ. Chosen on heavy
    /// common-mode random worlds (lab `random_worlds --heavy`, world seeds
    /// 1–40, 12 km; offline, on the stored results) as the largest of 1.5,
    /// 2, 2.5, 3, 3.5, 4, 5 % whose σ covers every parameter in ≥ 95 % of
    /// the worlds with none beyond 3 σ; docs/validation.md, "Heavy wheel
    /// noise: the σ".
    const COMMON_MODE_REFERENCE_SIGMA: f64 = 0.025;
}

research_pub! {
    /// The prior for the between-drive σ ([`BetweenDrivePrior`]): the
    /// spread rounded up, the within-drive σ rounded down (both err towards
    /// a larger `τ̂`).
    const BETWEEN_DRIVE_PRIOR: BetweenDrivePrior = BetweenDrivePrior {
        c_e: 3.8e-4,
        c_d: 7.5e-5,
        t_r: 2.9e-3,
        d: 2.8e-5,
        within: [5.6e-4, 3.5e-5, 1.0e-4, 6.2e-5],
    };
}

impl BetweenDrivePrior {
    /// What the relative values are fractions of at θ, `[c_e, c_d, t_r, d]`:
    /// |c_e| for c_e and c_d, |t_r| for t_r and d.
    fn scale(theta: &Theta) -> [f64; 4] {
        let (ce, tr) = (theta.c_e.abs(), theta.t_r.abs());
        [ce, ce, tr, tr]
    }

    /// The spread of the estimates at θ, `[c_e, c_d, t_r, d]` in SI units.
    pub(crate) fn spread(&self, theta: &Theta) -> [f64; 4] {
        let s = Self::scale(theta);
        [self.c_e * s[0], self.c_d * s[1], self.t_r * s[2], self.d * s[3]]
    }

    /// The between-drive σ at θ, `τ̂ = √max(0, spread² − within²)` per
    /// parameter (SI units): 0 where the runs' own within-drive σ exceeds
    /// their spread.
    pub(crate) fn between(&self, theta: &Theta) -> [f64; 4] {
        let (scale, spread) = (Self::scale(theta), self.spread(theta));
        std::array::from_fn(|i| {
            let w = self.within[i] * scale[i];
            (spread[i] * spread[i] - w * w).max(0.0).sqrt()
        })
    }
}

/// Where the between-drive σ τ comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub(crate) enum BetweenDriveSource {
    /// One drive: the documented prior ([`BETWEEN_DRIVE_PRIOR`]).
    Prior,
    /// Several drives: DerSimonian–Laird on their separate fits, at least
    /// the prior ([`PooledDrives`]).
    RandomEffects,
}

/// The label of the σ that stands for a result, the same in the text
/// report, the parameter file, the HTML report and Python.
pub(crate) const NEXT_DRIVE_SIGMA_LABEL: &str = "σ for the next drive: within-drive ⊕ between-drive";

research_pub! {
    /// The parts of the σ for the next drive, per parameter `[c_e, c_d, t_r, d]`
    /// (SI units; `None` for a parameter held). In JSON `next_drive_sigma`.
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct NextDriveSigma {
        /// `√(within² + common_mode² + fallback_gap²/3 + heading_drift_floor_gap²/3
        /// + t_r_above_start² + between²)`: the σ that stands for the result.
        pub sigma: [Option<f64>; 4],
        /// The method's within-drive σ (for a parameter the EIV filter held at
        /// its start's estimate: the start's σ; for EIV's own estimate or
        /// refit, at least its start's cluster-robust σ,
        /// [`Self::within_from_start`]).
        pub within_drive: [Option<f64>; 4],
        /// When the result is EIV's own estimate or refit: per parameter its
        /// batch Gauss-Newton start's cluster-robust σ where that exceeds
        /// EIV's within-drive σ and so stands as [`Self::within_drive`]
        /// (module docs, `σ_within`); zeros otherwise. In JSON only when not
        /// all zero.
        #[serde(default, skip_serializing_if = "all_zero")]
        pub within_from_start: [f64; 4],
        /// With the EIV method, the common-mode wheel noise the within-drive σ
        /// leaves out, `within · wheel_common_rel_sigma / 0.025` (module docs,
        /// `h`; `COMMON_MODE_REFERENCE_SIGMA`); zeros otherwise.
        /// In JSON only when not all zero.
        #[serde(default, skip_serializing_if = "all_zero")]
        pub common_mode: [f64; 4],
        /// The common-mode wheel-scale σ σ_c of EIV's fitted noise model that
        /// [`Self::common_mode`] comes from (relative). In JSON only when present.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub wheel_common_rel_sigma: Option<f64>,
        /// σ_c sits at its upper clamp: the drive's common-mode wheel noise is
        /// heavier than EIV's model allows, and [`Self::common_mode`] is a lower
        /// bound. In JSON only when true.
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        pub wheel_common_clamped: bool,
        /// The gap between the EIV method's two estimates: after an EIV
        /// fallback |EIV's own θ − the fallback's θ|; when the result is EIV's
        /// refit ([`Self::gap_is_refit`]) |the refit's θ − its batch
        /// Gauss-Newton start's θ|; zeros otherwise.
        pub fallback_gap: [f64; 4],
        /// `fallback_gap` is the refit's gap to its batch Gauss-Newton start
        /// (the result is EIV's refit with the noise sources released), not a
        /// fallback's gap to EIV's own estimate. In JSON only when true.
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        pub gap_is_refit: bool,
        /// After a fallback from a fit with these noise levels held:
        /// `fallback_gap` is the gap to EIV's fit with them estimated, which
        /// passed the checks the held fit failed (the data contradict the held
        /// levels). In JSON only when not empty.
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        pub gap_released_noise: Vec<NoiseSource>,
        /// After a fallback: why EIV's fit bounds no errors-in-variables bias
        /// of the fallback, when it does not ([`FallbackUnchecked`]). In JSON
        /// only when present.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub fallback_unchecked: Option<FallbackUnchecked>,
        /// When the result is EIV's own estimate (not a refit, not a fallback)
        /// and its t_r lies above its batch Gauss-Newton start's: the excess
        /// (t_r's entry) and the shift of every other parameter along its
        /// regression on t_r in EIV's covariance (`excess · C_it / C_tt`);
        /// zeros otherwise. Enters as shift² (module docs). In JSON only when
        /// not all zero.
        #[serde(default, skip_serializing_if = "all_zero")]
        pub t_r_above_start: [f64; 4],
        /// When the result is EIV's own estimate holding the reference's
        /// heading drift at its floor: |θ − θ without the floor| (before the
        /// bias correction; `crate::eiv::HeadingDriftTest::theta_without_floor`),
        /// zeros otherwise. The floor is a modelling choice, not an estimate;
        /// with the truth anywhere between the two fits it enters as gap²/3,
        /// as [`Self::fallback_gap`] does (module docs, `f`). In JSON only when
        /// not all zero.
        #[serde(default, skip_serializing_if = "all_zero")]
        pub heading_drift_floor_gap: [f64; 4],
        /// The between-drive part that enters `sigma`,
        /// `√max(τ², floor² − within²)`: τ ([`Self::between_drive_tau`]), or
        /// more where the within-drive σ falls short of the floor
        /// ([`Self::between_drive_floor`]). With it,
        /// `√(within² + between²) = max(floor, √(within² + τ²))`.
        pub between_drive: [f64; 4],
        /// The between-drive σ τ: with one drive the prior's
        /// (`BetweenDrivePrior::between`), with several the larger of that
        /// and their random-effects τ.
        #[serde(default)]
        pub between_drive_tau: [f64; 4],
        /// The floor of the within-drive ⊕ between-drive σ: the prior's spread
        /// of estimates (`BetweenDrivePrior::spread`), which holds the
        /// within-drive noise of the runs it was measured on.
        #[serde(default)]
        pub between_drive_floor: [f64; 4],
        /// Where τ comes from.
        pub(crate) between_source: BetweenDriveSource,
        /// With several drives: their separate fits and the pooling.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        pub pooled: Option<PooledDrives>,
    }
}

impl NextDriveSigma {
    /// The σ for the next drive of one drive's calibration: the prior τ at θ.
    pub(crate) fn one_drive(theta: &Theta, within_drive: [Option<f64>; 4], fallback_gap: [f64; 4]) -> Self {
        let mut s = NextDriveSigma {
            sigma: [None; 4],
            within_drive,
            within_from_start: [0.0; 4],
            common_mode: [0.0; 4],
            wheel_common_rel_sigma: None,
            wheel_common_clamped: false,
            fallback_gap,
            gap_is_refit: false,
            gap_released_noise: Vec::new(),
            fallback_unchecked: None,
            t_r_above_start: [0.0; 4],
            heading_drift_floor_gap: [0.0; 4],
            between_drive: [0.0; 4],
            between_drive_tau: BETWEEN_DRIVE_PRIOR.between(theta),
            between_drive_floor: BETWEEN_DRIVE_PRIOR.spread(theta),
            between_source: BetweenDriveSource::Prior,
            pooled: None,
        };
        s.combine();
        s
    }

    /// With EIV's t_r above its batch Gauss-Newton start's by `excess`:
    /// [`Self::t_r_above_start`] from EIV's covariance `cov`, and `sigma` again.
    pub(crate) fn with_t_r_above_start(&mut self, excess: f64, cov: &[[f64; 4]; 4]) {
        let c_tt = cov[2][2];
        if !(excess > 0.0 && excess.is_finite() && c_tt > 0.0) {
            return;
        }
        self.t_r_above_start = std::array::from_fn(|i| {
            let shift = if i == 2 { excess } else { (excess * cov[i][2] / c_tt).abs() };
            if self.within_drive[i].is_some() && shift.is_finite() {
                shift
            } else {
                0.0
            }
        });
        self.combine();
    }

    /// With EIV's θ before its bias correction, `theta`, and its fit without
    /// the heading drift's floor, `without_floor`, over the parameters with a
    /// within-drive σ: [`Self::heading_drift_floor_gap`], and `sigma` again.
    pub(crate) fn with_heading_drift_floor(&mut self, theta: &Theta, without_floor: &Theta) {
        let (a, b) = (theta.to_array(), without_floor.to_array());
        self.heading_drift_floor_gap = std::array::from_fn(|i| {
            let g = (a[i] - b[i]).abs();
            if self.within_drive[i].is_some() && g.is_finite() {
                g
            } else {
                0.0
            }
        });
        self.combine();
    }

    /// With EIV's fitted common-mode wheel-scale σ `wheel_common_rel_sigma`
    /// (at its upper clamp when `clamped`): [`Self::common_mode`], and
    /// `sigma` again. A σ_c that is not finite and positive adds nothing.
    pub(crate) fn with_common_mode(&mut self, wheel_common_rel_sigma: f64, clamped: bool) {
        if !(wheel_common_rel_sigma.is_finite() && wheel_common_rel_sigma > 0.0) {
            return;
        }
        let ratio = wheel_common_rel_sigma / COMMON_MODE_REFERENCE_SIGMA;
        self.common_mode = std::array::from_fn(|i| self.within_drive[i].map_or(0.0, |w| w * ratio));
        self.wheel_common_rel_sigma = Some(wheel_common_rel_sigma);
        self.wheel_common_clamped = clamped;
        self.combine();
    }

    /// Sets `between_drive` and `sigma` from their parts.
    fn combine(&mut self) {
        self.between_drive = std::array::from_fn(|i| {
            let (tau, floor, w) = (self.between_drive_tau[i], self.between_drive_floor[i], self.within_drive[i]);
            let w = w.unwrap_or(0.0);
            (tau * tau).max(floor * floor - w * w).max(0.0).sqrt()
        });
        self.sigma = std::array::from_fn(|i| {
            self.within_drive[i].map(|w| {
                (w * w
                    + self.common_mode[i].powi(2)
                    + self.fallback_gap[i].powi(2) / 3.0
                    + self.heading_drift_floor_gap[i].powi(2) / 3.0
                    + self.t_r_above_start[i].powi(2)
                    + self.between_drive[i].powi(2))
                .sqrt()
            })
        });
    }

    /// `sigma` without the fallback gap, the heading drift's floor gap, EIV's
    /// t_r above its start and the common-mode term, `√(within² + between²)`, that is
    /// `max(floor, √(within² + τ²))`: the σ the result would have if its
    /// estimator had no errors-in-variables bias and the noise were as its
    /// model says. The gap checks measure against it.
    pub(crate) fn without_gap(&self) -> [Option<f64>; 4] {
        std::array::from_fn(|i| self.within_drive[i].map(|w| (w * w + self.between_drive[i].powi(2)).sqrt()))
    }

    /// With several drives: τ from their random-effects pooling, at least
    /// the prior's; the floor stays.
    pub(crate) fn with_pooled(&mut self, pooled: PooledDrives) {
        for (i, p) in pooled.params.iter().enumerate() {
            if let Some(p) = p {
                self.between_drive_tau[i] = self.between_drive_tau[i].max(p.tau);
            }
        }
        self.between_source = BetweenDriveSource::RandomEffects;
        self.pooled = Some(pooled);
        self.combine();
    }
}

research_pub! {
    /// After an EIV fallback, why batch Gauss-Newton's errors-in-variables
    /// bias is left unchecked: EIV's own θ (and its fit with held noise
    /// levels released, if any) fails a plausibility guard, so no EIV
    /// estimate gives a gap to measure the bias by. On heavy common-mode
    /// wheel noise EIV's fit puts the common-mode scale at its upper clamp
    /// and c_e 9–20 % low (docs/validation.md, "Heavy wheel noise"), while
    /// batch G-N's t_r is off by up to 2.8 %. The verdict is doubtful
    /// ([`crate::assess::trust::VerdictReason::FallbackUnchecked`]); the σ for
    /// the next drive cannot include a bias nothing estimates.
    #[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
    struct FallbackUnchecked {
        /// The wheel noise sources whose scale EIV's fit left at its upper
        /// clamp (the drive's wheel noise is heavier than the model allows).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        pub clamped: Vec<NoiseSource>,
        /// The noise levels the calibration held (`known`; the drive may
        /// contradict them).
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        pub held: Vec<NoiseSource>,
    }
}

/// True when every entry is zero (serde's `skip_serializing_if`).
fn all_zero(a: &[f64; 4]) -> bool {
    a.iter().all(|x| *x == 0.0)
}

research_pub! {
    /// Several drives' separate fits and their random-effects pooling
    /// (DerSimonian–Laird, per parameter).
    #[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
    struct PooledDrives {
        /// The method of the separate fits.
        pub method: String,
        /// Each drive's θ.
        pub theta: Vec<Theta>,
        /// Each drive's within-drive σ, `[c_e, c_d, t_r, d]`.
        pub sigma: Vec<[Option<f64>; 4]>,
        /// Per parameter the pooling (`None` for a parameter held or a drive
        /// without its σ).
        pub params: [Option<RandomEffects>; 4],
    }
}

impl PooledDrives {
    research_pub! {
        /// Pools the separate fits `theta[i]` with σ `sigma[i]`.
        fn new(method: String, theta: Vec<Theta>, sigma: Vec<[Option<f64>; 4]>) -> Self {
            let params = std::array::from_fn(|i| {
                let y: Vec<f64> = theta.iter().map(|t| t.to_array()[i]).collect();
                let s: Option<Vec<f64>> = sigma.iter().map(|s| s[i]).collect();
                dersimonian_laird(&y, &s?)
            });
            PooledDrives { method, theta, sigma, params }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: f64, b: f64, tol: f64) -> bool {
        (a - b).abs() <= tol * b.abs().max(1e-300)
    }

    /// Three equal-σ drives 1, 2, 4 (σ 1): ȳ = 7/3, Q = 42/9, C = 2,
    /// τ² = (42/9 − 2)/2 = 4/3, SE = √((1 + 4/3)/3).
    #[test]
    fn equal_sigmas_by_hand() {
        let r = dersimonian_laird(&[1.0, 2.0, 4.0], &[1.0; 3]).expect("pooled");
        assert!(close(r.q, 42.0 / 9.0, 1e-12), "{r:?}");
        assert!(close(r.tau * r.tau, 4.0 / 3.0, 1e-12), "{r:?}");
        assert!(close(r.mean, 7.0 / 3.0, 1e-12), "{r:?}");
        assert!(close(r.mean_sigma, ((1.0 + 4.0 / 3.0) / 3.0f64).sqrt(), 1e-12), "{r:?}");
        assert_eq!(r.drives, 3);
    }

    /// Two drives 0 ± 1 and 3 ± 2: w = 1, ¼; ȳ_w = 0.6; Q = 0.36 + 1.44 =
    /// 1.8; C = 1.25 − 1.0625/1.25 = 0.4; τ² = 0.8/0.4 = 2; w* = ⅓, ⅙;
    /// μ = (3/6)/(1/2) = 1; SE = √2.
    #[test]
    fn unequal_sigmas_by_hand() {
        let r = dersimonian_laird(&[0.0, 3.0], &[1.0, 2.0]).expect("pooled");
        assert!(close(r.q, 1.8, 1e-12), "{r:?}");
        assert!(close(r.tau * r.tau, 2.0, 1e-12), "{r:?}");
        assert!(close(r.mean, 1.0, 1e-12), "{r:?}");
        assert!(close(r.mean_sigma, 2f64.sqrt(), 1e-12), "{r:?}");
    }

    /// Drives that agree better than their σ say: τ = 0 and the pooled mean
    /// is the fixed-effect one.
    #[test]
    fn agreement_within_sigma_gives_no_between_spread() {
        let r = dersimonian_laird(&[1.0, 1.1, 0.95], &[1.0, 0.5, 1.0]).expect("pooled");
        assert_eq!(r.tau.to_bits(), 0f64.to_bits());
        let w = [1.0, 4.0, 1.0];
        let mean = (1.0 + 4.0 * 1.1 + 0.95) / 6.0;
        assert!(close(r.mean, mean, 1e-12));
        assert!(close(r.mean_sigma, (1.0 / w.iter().sum::<f64>()).sqrt(), 1e-12));
    }

    #[test]
    fn degenerate_inputs_are_refused() {
        assert!(dersimonian_laird(&[1.0], &[1.0]).is_none());
        assert!(dersimonian_laird(&[1.0, 2.0], &[1.0]).is_none());
        assert!(dersimonian_laird(&[1.0, 2.0], &[1.0, 0.0]).is_none());
        assert!(dersimonian_laird(&[1.0, f64::NAN], &[1.0, 1.0]).is_none());
    }

    /// Per-drive θ drawn with a known between-drive sd τ and measured with
    /// known within-drive σ: over many seeds the estimated τ recovers it
    /// within its sampling error.
    #[test]
    fn simulated_drives_recover_the_between_drive_sigma() {
        use rand::{Rng, SeedableRng};
        use rand_distr::StandardNormal;
        let (tau, drives, seeds) = (0.002, 8usize, 400u64);
        let mut taus = Vec::new();
        let mut covered = 0;
        for seed in 0..seeds {
            let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
            let mut z = || -> f64 { rng.sample(StandardNormal) };
            let sig: Vec<f64> = (0..drives).map(|i| 0.0005 + 0.0002 * i as f64).collect();
            let y: Vec<f64> = sig.iter().map(|s| 2.0 + tau * z() + s * z()).collect();
            let r = dersimonian_laird(&y, &sig).expect("pooled");
            taus.push(r.tau);
            // the pooled mean's 95 % interval covers the true mean
            covered += usize::from((r.mean - 2.0).abs() <= 1.96 * r.mean_sigma);
        }
        let mean_tau = taus.iter().sum::<f64>() / taus.len() as f64;
        let sd = (taus.iter().map(|t| (t - mean_tau).powi(2)).sum::<f64>() / (taus.len() - 1) as f64).sqrt();
        // DL's τ is biased low with few drives (√ of a truncated moment
        // estimate): within 15 % of τ, and each seed within 3 sd.
        assert!((mean_tau - tau).abs() < 0.15 * tau, "mean τ̂ {mean_tau} vs τ {tau} (sd {sd})");
        assert!(sd < 0.5 * tau, "τ̂ sd {sd}");
        let cover = covered as f64 / seeds as f64;
        assert!(cover > 0.88, "pooled mean coverage {cover}");
        // and without between-drive spread, τ̂ is mostly 0
        let zero = (0..100u64)
            .filter(|seed| {
                let mut rng = rand::rngs::StdRng::seed_from_u64(1000 + seed);
                let y: Vec<f64> = (0..drives).map(|_| 2.0 + 0.001 * rng.sample::<f64, _>(StandardNormal)).collect();
                dersimonian_laird(&y, &[0.001; 8]).expect("pooled").tau <= 0.0
            })
            .count();
        assert!(zero > 40, "{zero} of 100 seeds gave τ̂ = 0");
    }

    /// EIV's t_r above its start enters in full for t_r and along the
    /// regression on t_r for the others; below its start, or held, nothing.
    #[test]
    fn t_r_above_the_start_enters_the_sigma_with_its_regression() {
        let theta = Theta { c_e: 2.0, c_d: 0.001, t_r: 1.5, d: 0.001 };
        let within = [Some(1e-4), Some(1e-5), Some(3e-3), Some(5e-5)];
        // ρ(t_r, d) = −0.8: C_dt = −0.8 · 3e-3 · 5e-5; c_e uncorrelated.
        let c_dt = -0.8 * 3e-3 * 5e-5;
        let cov = [[1e-8, 0.0, 0.0, 0.0], [0.0, 1e-10, 1e-9, 0.0], [0.0, 1e-9, 9e-6, c_dt], [0.0, 0.0, c_dt, 2.5e-9]];
        let base = NextDriveSigma::one_drive(&theta, within, [0.0; 4]);
        let mut n = base.clone();
        n.with_t_r_above_start(0.01, &cov);
        assert!(close(n.t_r_above_start[2], 0.01, 1e-15), "{n:?}");
        assert!(close(n.t_r_above_start[3], 0.01 * 0.8 * 5e-5 / 3e-3, 1e-12), "{n:?}");
        assert!(close(n.t_r_above_start[1], 0.01 * 1e-9 / 9e-6, 1e-12), "{n:?}");
        assert_eq!(n.t_r_above_start[0].to_bits(), 0f64.to_bits());
        for i in 0..4 {
            let (s, s0) = (n.sigma[i].expect("σ"), base.sigma[i].expect("σ"));
            assert!(close(s, (s0 * s0 + n.t_r_above_start[i].powi(2)).sqrt(), 1e-12), "{i}: {s} {s0}");
        }
        assert_eq!(n.without_gap(), base.without_gap(), "the σ without it is the base's");
        let json = serde_json::to_value(&n).expect("json");
        assert!(json.get("t_r_above_start").is_some());
        // Below the start, or not finite: nothing changes, nothing in JSON.
        for excess in [-0.01, 0.0, f64::NAN] {
            let mut m = base.clone();
            m.with_t_r_above_start(excess, &cov);
            assert_eq!(m, base, "{excess}");
        }
        assert!(serde_json::to_value(&base).expect("json").get("t_r_above_start").is_none());
        // A parameter without a σ gets no shift.
        let mut held = NextDriveSigma::one_drive(&theta, [Some(1e-4), None, Some(3e-3), Some(5e-5)], [0.0; 4]);
        held.with_t_r_above_start(0.01, &cov);
        assert_eq!(held.t_r_above_start[1].to_bits(), 0f64.to_bits());
        assert_eq!(held.sigma[1], None);
    }

    /// The gap to the fit without the heading drift's floor enters as gap²/3
    /// for every parameter with a σ, stays out of the σ the gap checks use,
    /// and is absent from JSON where it is zero.
    #[test]
    fn the_heading_drift_floor_gap_enters_as_a_third_of_its_square() {
        let theta = Theta { c_e: 2.0, c_d: 0.001, t_r: 1.5, d: 0.001 };
        let within = [Some(1e-4), None, Some(3e-3), Some(5e-5)];
        let base = NextDriveSigma::one_drive(&theta, within, [0.0; 4]);
        let without = Theta { c_e: 2.0003, c_d: 0.0012, t_r: 1.53, d: 0.0008 };
        let mut n = base.clone();
        n.with_heading_drift_floor(&theta, &without);
        assert_eq!(n.heading_drift_floor_gap[1].to_bits(), 0f64.to_bits(), "c_d has no σ: {n:?}");
        assert_eq!(n.sigma[1], None);
        for (i, gap) in [(0, 3e-4), (2, 0.03), (3, 2e-4)] {
            assert!(close(n.heading_drift_floor_gap[i], gap, 1e-9), "{i}: {n:?}");
            let (s, s0) = (n.sigma[i].expect("σ"), base.sigma[i].expect("σ"));
            assert!(close(s, (s0 * s0 + gap * gap / 3.0).sqrt(), 1e-9), "{i}: {s} {s0}");
        }
        assert_eq!(n.without_gap(), base.without_gap(), "the σ without it is the base's");
        assert!(serde_json::to_value(&n).expect("json").get("heading_drift_floor_gap").is_some());
        assert!(serde_json::to_value(&base).expect("json").get("heading_drift_floor_gap").is_none());
        // The same θ: no gap, nothing changes.
        let mut same = base.clone();
        same.with_heading_drift_floor(&theta, &theta);
        assert_eq!(same, base);
    }

    /// The common-mode term is σ_within · σ_c / 2.5 % per parameter with a
    /// σ, adds in quadrature, stays out of the σ the gap checks use, and
    /// is absent for a σ_c that is not finite and positive.
    #[test]
    fn the_common_mode_term_scales_the_within_drive_sigma_by_sigma_c() {
        let theta = Theta { c_e: 2.0, c_d: 0.001, t_r: 1.5, d: 0.001 };
        let within = [Some(2e-3), Some(1e-5), None, Some(5e-5)];
        let base = NextDriveSigma::one_drive(&theta, within, [0.0; 4]);
        let mut n = base.clone();
        n.with_common_mode(0.05, false);
        assert_eq!(COMMON_MODE_REFERENCE_SIGMA.to_bits(), 0.025f64.to_bits());
        assert!(close(n.common_mode[0], 4e-3, 1e-15), "{n:?}");
        assert!(close(n.common_mode[3], 1e-4, 1e-15), "{n:?}");
        assert_eq!(n.common_mode[2].to_bits(), 0f64.to_bits(), "a held parameter gets none");
        assert_eq!(n.sigma[2], None);
        for i in [0, 1, 3] {
            let (s, s0) = (n.sigma[i].expect("σ"), base.sigma[i].expect("σ"));
            assert!(close(s, (s0 * s0 + n.common_mode[i].powi(2)).sqrt(), 1e-12), "{i}: {s} {s0}");
        }
        // c_e: σ_within 2e-3 (above the floor 7.6e-4, τ̂ 0) and h 4e-3.
        assert!(n.sigma[0].expect("σ") > 2.0 * base.sigma[0].expect("σ"));
        assert_eq!(n.without_gap(), base.without_gap(), "the gap checks' σ is the base's");
        let json = serde_json::to_value(&n).expect("json");
        assert!(json.get("common_mode").is_some() && json.get("wheel_common_rel_sigma").is_some());
        assert!(json.get("wheel_common_clamped").is_none(), "only when clamped");
        let mut clamped = base.clone();
        clamped.with_common_mode(0.04, true);
        assert!(serde_json::to_value(&clamped).expect("json").get("wheel_common_clamped").is_some());
        for sigma_c in [0.0, -0.01, f64::NAN, f64::INFINITY] {
            let mut m = base.clone();
            m.with_common_mode(sigma_c, true);
            assert_eq!(m, base, "{sigma_c}");
        }
        let json = serde_json::to_value(&base).expect("json");
        assert!(json.get("common_mode").is_none() && json.get("wheel_common_rel_sigma").is_none());
    }

    /// The prior's τ̂ = √max(0, spread² − within²), worked by hand at θ.
    #[test]
    fn the_prior_between_drive_sigma_takes_the_within_drive_noise_out_of_the_spread() {
        let theta = Theta { c_e: 2.0, c_d: 0.001, t_r: 1.5, d: 0.001 };
        let p = BetweenDrivePrior { c_e: 4e-4, c_d: 5e-5, t_r: 3e-3, d: 2e-5, within: [5e-4, 3e-5, 1e-3, 2e-5] };
        let s = p.spread(&theta);
        let expected_spread = [8e-4, 1e-4, 4.5e-3, 3e-5];
        for i in 0..4 {
            assert!(close(s[i], expected_spread[i], 1e-12), "{i}: {s:?}");
        }
        let b = p.between(&theta);
        // c_e: within 1e-3 above the spread 8e-4; d: within = spread.
        assert_eq!(b[0].to_bits(), 0f64.to_bits(), "{b:?}");
        assert_eq!(b[3].to_bits(), 0f64.to_bits(), "{b:?}");
        assert!(close(b[1], (1e-8f64 - 36e-10).sqrt(), 1e-12), "{b:?}");
        assert!(close(b[2], (4.5e-3f64.powi(2) - 1.5e-3f64.powi(2)).sqrt(), 1e-12), "{b:?}");
        // The library's prior: τ̂ of c_e and d is 0 (the runs' EIV σ exceeds
        // their spread), of c_d and t_r most of the spread.
        let lib = BETWEEN_DRIVE_PRIOR.between(&theta);
        assert_eq!((lib[0].to_bits(), lib[3].to_bits()), (0, 0), "{lib:?}");
        let spread = BETWEEN_DRIVE_PRIOR.spread(&theta);
        assert!(lib[1] > 0.8 * spread[1] && lib[1] < spread[1], "{lib:?}");
        assert!(lib[2] > 0.99 * spread[2] && lib[2] < spread[2], "{lib:?}");
    }

    /// σ_next = √(within² + gap²/3 + b²), b² = max(τ², s² − within²): the
    /// floor s for a precise drive, the drive's own σ ⊕ τ for a noisy one,
    /// never within² + s².
    #[test]
    fn the_next_drive_sigma_counts_the_within_drive_noise_once() {
        let theta = Theta { c_e: 2.0, c_d: 0.001, t_r: 1.5, d: 0.001 };
        let within = [Some(3e-4), Some(1.4e-4), None, Some(1e-4)];
        let s = NextDriveSigma::one_drive(&theta, within, [4e-4, 0.0, 0.0, 0.0]);
        let (floor, tau) = (BETWEEN_DRIVE_PRIOR.spread(&theta), BETWEEN_DRIVE_PRIOR.between(&theta));
        assert_eq!(s.between_drive_floor.map(f64::to_bits), floor.map(f64::to_bits));
        assert_eq!(s.between_drive_tau.map(f64::to_bits), tau.map(f64::to_bits));
        // c_e: within 3e-4 below the floor 7.6e-4 (τ̂ 0): within ⊕ between
        // is the floor, and the gap adds to it.
        assert!(close(floor[0], 7.6e-4, 1e-12));
        assert!(close(s.between_drive[0], (floor[0] * floor[0] - 9e-8).sqrt(), 1e-12), "{s:?}");
        assert!(close(s.sigma[0].expect("c_e"), (floor[0] * floor[0] + 16e-8 / 3.0).sqrt(), 1e-12), "{s:?}");
        assert!(close(s.without_gap()[0].expect("c_e"), floor[0], 1e-12));
        // c_d: within 1.4e-4 and τ̂ 1.33e-4 give more than the floor 1.5e-4.
        assert!(close(s.between_drive[1], tau[1], 1e-15), "{s:?}");
        assert!(close(s.sigma[1].expect("c_d"), (1.96e-8f64 + tau[1] * tau[1]).sqrt(), 1e-12), "{s:?}");
        assert!(s.sigma[1].expect("c_d") > floor[1]);
        // d: within 1e-4 above the floor 4.2e-5, τ̂ 0: the drive's own σ.
        assert_eq!(s.between_drive[3].to_bits(), 0f64.to_bits(), "{s:?}");
        assert_eq!(s.sigma[3].map(f64::to_bits), Some(1e-4f64.to_bits()));
        assert_eq!(s.sigma[2], None, "a held parameter has none");
        // Never the double count √(within² + floor²).
        for i in [0, 1, 3] {
            let w = within[i].expect("free");
            let g = s.fallback_gap[i];
            assert!(s.sigma[i].expect("σ") < (w * w + g * g / 3.0 + floor[i] * floor[i]).sqrt(), "{i}");
        }
        let mut m = s.clone();
        let p = PooledDrives::new(
            "batch-gn".into(),
            vec![theta, Theta { c_e: 2.01, ..theta }],
            vec![[Some(1e-4), Some(1e-5), Some(1e-4), Some(1e-5)]; 2],
        );
        m.with_pooled(p);
        assert_eq!(m.between_source, BetweenDriveSource::RandomEffects);
        assert!(m.between_drive[0] > 0.005, "{:?}", m.between_drive);
        assert!(close(m.between_drive[0], m.between_drive_tau[0], 1e-15), "τ of the pooling enters whole");
        assert_eq!(m.between_drive[1].to_bits(), s.between_drive[1].to_bits(), "the prior's τ̂ is a floor");
        assert_eq!(m.between_drive_floor.map(f64::to_bits), floor.map(f64::to_bits));
    }
}
