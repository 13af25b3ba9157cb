//! Options of the online calibration.

use std::ops::RangeInclusive;

use serde::{Deserialize, Serialize};

use odocal::segment::{SegmentOptions, ValidationSegmentOptions};
use odocal::{Error, Result, Theta};

/// How fast the parameters may drift: the standard deviation of a random
/// walk per parameter after one hour of driving (its variance grows
/// linearly with driving time). Each from 0 (the parameter held
/// constant) to its [`MAX_RANDOM_WALK`].
///
/// The defaults are the between-run spread measured on the shipped
/// test-track runs of one van on one afternoon (docs/validation.md):
/// `c_e` 0.07 % (sd), `c_d` 0.25 mm, `t_r` 5 mm, taken as accumulating over
/// one hour; `d`, whose spread those runs do not resolve, moves like `c_d`
/// per m/s² (0.25 mm per m/s²).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RandomWalk {
    /// `c_e`'s sd after one hour, as a fraction of `c_e`. Default 7e-4.
    pub c_e_relative: f64,
    /// `c_d`'s sd after one hour, m. Default 2.5e-4.
    pub c_d_m: f64,
    /// `t_r`'s sd after one hour, m. Default 5e-3.
    pub t_r_m: f64,
    /// `d`'s sd after one hour, m/(m/s²). Default 2.5e-4.
    pub d: f64,
}

impl Default for RandomWalk {
    fn default() -> Self {
        RandomWalk { c_e_relative: 7e-4, c_d_m: 2.5e-4, t_r_m: 5e-3, d: 2.5e-4 }
    }
}

impl RandomWalk {
    /// The per-hour sd of each parameter at θ.
    pub(crate) fn sd_per_hour(&self, theta: &Theta) -> [f64; 4] {
        [self.c_e_relative * theta.c_e.abs(), self.c_d_m, self.t_r_m, self.d]
    }
}

/// Options of [`super::Calibrator`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OnlineOptions {
    /// The calibration segments: each segment of the stream whose peak yaw
    /// rate reaches the threshold (is at least it) is folded in when it completes. Default:
    /// the calibration's length and stride (650 steps every 100) and every
    /// segment folded (threshold 0), as the default method's batch
    /// Gauss-Newton uses every cut segment: turning-only segments leave
    /// c_d and the heading offset confounded on drives that turn one way.
    pub segments: SegmentOptions,
    /// A folded segment counts as informative driving (for the steadiness
    /// gate) when its peak yaw rate is at least this, rad/s. Default 0.15 (the
    /// calibration's selection threshold).
    pub informative_yaw_rate_rad_per_s: f64,
    /// The validation segments of the prequential error. Default: the
    /// calibration's (1300 steps every 650 from sample 50).
    pub validation: ValidationSegmentOptions,
    /// Residual weights `[w_px, w_py, w_ψ]`. Default `[1, 1, 40²]` (the
    /// Gauss-Newton's).
    pub weights: [f64; 3],
    /// θ's sd when the calibration starts without one. Default
    /// `[2 % of c_e, 5 mm, 5 % of t_r, 2 mm/(m/s²)]`: about the spread of
    /// datasheet values around a vehicle's own. Each within its
    /// [`PRIOR_SD_RANGE`].
    pub prior_relative_c_e: f64,
    /// `c_d`'s prior sd, m. Default 5e-3.
    pub prior_c_d_m: f64,
    /// `t_r`'s prior sd as a fraction of `t_r`. Default 0.05.
    pub prior_relative_t_r: f64,
    /// `d`'s prior sd, m/(m/s²). Default 2e-3.
    pub prior_d: f64,
    /// The random walk of the parameters. Default [`RandomWalk::default`].
    pub random_walk: RandomWalk,
    /// Estimate the reference's heading offset, a state of each drive
    /// (reset by [`super::Calibrator::begin_drive`]). Default true.
    pub heading_offset: bool,
    /// The heading offset's sd at the start of a drive, rad. Default 0.05.
    pub heading_offset_prior_sd_rad: f64,
    /// Gauss-Newton iterations per folded segment (an iterated update:
    /// each re-linearises at the previous iterate). Default 2; at most
    /// [`MAX_ITERATIONS_PER_SEGMENT`].
    pub iterations_per_segment: usize,
    /// The weight of one segment's normal equations. Stride / length (0.15
    /// by default) would count each sample once, as if residuals were
    /// independent; they are not (a segment's residuals integrate the same
    /// input noise, and a drive's segments share its slowly varying
    /// errors), and a larger weight makes θ follow each segment's noise.
    /// Within [`INFORMATION_SCALE_RANGE`].
    /// Default 0.005, chosen on the six shipped test-track runs replayed in
    /// order (prequential Ē_p of runs 2–6, m: 1.85 at 0.15, 1.57 at 0.05,
    /// 1.39 at 0.02, 1.28 at 0.01, 1.24 at 0.005, 1.23 at 0.002;
    /// docs/validation.md): an in-sample choice that runs it has not seen
    /// have to confirm.
    pub information_scale: f64,
    /// Factors on the sd of `[c_e, c_d, t_r, d]` that the recursion's
    /// covariance gives, for the σ the calibrator reports
    /// ([`super::Status::sigma`]); the recursion itself (θ's updates)
    /// does not use them. One segment weight cannot make the covariance
    /// cover every parameter: the weight that fits c_e's spread leaves the
    /// recursion's sd of c_d, t_r and d 4–8 times below their errors, and
    /// Gauss-Newton's bias under input noise (t_r's above all) adds to the
    /// error. Default `[1.1, 4.6, 6.3, 4.1]`: the factors that put the truth
    /// inside ±2σ 90 % of the time on simulated 60-minute drives with the
    /// paper's noise (seeds 1–6, with and without a c_e ramp), confirmed
    /// on seeds 7–12 (docs/validation.md).
    pub sigma_factors: [f64; 4],
    /// Completed validation segments kept for the held-out comparison of
    /// the write-back gates. Default 3; at most
    /// [`MAX_RECENT_VALIDATION_SEGMENTS`].
    pub recent_validation_segments: usize,
    /// Informative time over which θ's track is kept for the steadiness
    /// gate, s. Default 120.
    pub steady_window_s: f64,
}

/// The most Gauss-Newton iterations per folded segment
/// ([`OnlineOptions::iterations_per_segment`]): an update from the previous
/// iterate settles in a few, and every iteration costs a segment's
/// Jacobian, so a count beyond this only makes a replay run for days.
pub const MAX_ITERATIONS_PER_SEGMENT: usize = 100;

/// The range of [`OnlineOptions::information_scale`]: 0.15 (the default
/// stride over the default length) counts each sample once; 1 counts it
/// as often as the segments overlap it (6.5 times), beyond which a
/// segment's noise moves θ more than its samples can; below 10⁻⁶ (5000
/// times less than the default) a day of driving moves θ by next to
/// nothing.
pub const INFORMATION_SCALE_RANGE: RangeInclusive<f64> = 1e-6..=1.0;

/// The largest [`RandomWalk`] sd after one hour, per parameter `[c_e
/// (fraction of c_e), c_d (m), t_r (m), d (m/(m/s²))]`: 140 to 200 times
/// the defaults (the spread between runs of one van). A walk beyond them
/// lets the prior of earlier drives count for nothing within a segment.
pub const MAX_RANDOM_WALK: [f64; 4] = [0.1, 0.05, 1.0, 0.05];

/// The range of θ's prior sd, per parameter `[c_e (fraction of c_e), c_d
/// (m), t_r (fraction of t_r), d (m/(m/s²))]`
/// ([`OnlineOptions::prior_relative_c_e`] and the three after it): from
/// 10⁻⁶ (a parameter as good as known) to about the span of the
/// parameter's physical limits (c_e and t_r: half their value; c_d and d:
/// 5 cm, 0.05 m/(m/s²)), 10 to 25 times the defaults.
pub const PRIOR_SD_RANGE: [RangeInclusive<f64>; 4] = [1e-6..=0.5, 1e-6..=0.05, 1e-6..=0.5, 1e-6..=0.05];

/// The most [`OnlineOptions::recent_validation_segments`]: the validation
/// segments of 45 hours of driving at the default stride (650 samples at
/// 40 Hz), more than any one drive holds.
pub const MAX_RECENT_VALIDATION_SEGMENTS: usize = 10_000;

/// The names of θ's parameters in messages, in `[c_e, c_d, t_r, d]` order,
/// with the unit of an sd of each in [`RandomWalk`] and the prior.
const SD_UNITS: [(&str, &str, &str); 4] = [
    ("c_e", "a fraction of c_e", "a fraction of c_e"),
    ("c_d", "m", "m"),
    ("t_r", "m", "a fraction of t_r"),
    ("d", "m/(m/s²)", "m/(m/s²)"),
];

/// `a … b` as a message shows a range.
fn shown(r: &RangeInclusive<f64>) -> String {
    format!("{} … {}", num(*r.start()), num(*r.end()))
}

/// A number as a message shows it: in exponent notation outside
/// 10⁻⁴ … 10⁹ (`1e308` and `1e-6` stay short), else as Rust prints it.
fn num(v: f64) -> String {
    if v.is_finite() && v != 0.0 && !(1e-4..1e9).contains(&v.abs()) {
        format!("{v:e}")
    } else {
        v.to_string()
    }
}

impl Default for OnlineOptions {
    fn default() -> Self {
        OnlineOptions {
            segments: SegmentOptions { min_peak_yaw_rate_rad_per_s: 0.0, ..SegmentOptions::default() },
            informative_yaw_rate_rad_per_s: 0.15,
            validation: ValidationSegmentOptions::default(),
            weights: [1.0, 1.0, 1600.0],
            prior_relative_c_e: 0.02,
            prior_c_d_m: 5e-3,
            prior_relative_t_r: 0.05,
            prior_d: 2e-3,
            random_walk: RandomWalk::default(),
            heading_offset: true,
            heading_offset_prior_sd_rad: 0.05,
            iterations_per_segment: 2,
            information_scale: 0.005,
            sigma_factors: [1.1, 4.6, 6.3, 4.1],
            recent_validation_segments: 3,
            steady_window_s: 120.0,
        }
    }
}

impl OnlineOptions {
    /// Checks the options, naming the offending field.
    pub(crate) fn validate(&self) -> Result<()> {
        self.segments.validate()?;
        self.validation.validate()?;
        let prior = [
            ("prior_relative_c_e", self.prior_relative_c_e),
            ("prior_c_d_m", self.prior_c_d_m),
            ("prior_relative_t_r", self.prior_relative_t_r),
            ("prior_d", self.prior_d),
        ];
        for (((field, v), range), (name, _, unit)) in prior.into_iter().zip(&PRIOR_SD_RANGE).zip(SD_UNITS) {
            if !range.contains(&v) {
                let reason = format!("{name}'s prior sd {} is outside {} ({unit})", num(v), shown(range));
                return Err(Error::InvalidOption { field, reason });
            }
        }
        let positive = [
            ("heading_offset_prior_sd_rad", self.heading_offset_prior_sd_rad),
            ("steady_window_s", self.steady_window_s),
        ];
        if !(self.informative_yaw_rate_rad_per_s.is_finite() && self.informative_yaw_rate_rad_per_s >= 0.0) {
            return Err(Error::InvalidOption {
                field: "informative_yaw_rate_rad_per_s",
                reason: "must be a non-negative number".into(),
            });
        }
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidOption { field, reason: "must be positive".into() });
            }
        }
        let rw = &self.random_walk;
        for ((v, max), (name, unit, _)) in
            [rw.c_e_relative, rw.c_d_m, rw.t_r_m, rw.d].into_iter().zip(MAX_RANDOM_WALK).zip(SD_UNITS)
        {
            if !(0.0..=max).contains(&v) {
                let reason = format!("{name}'s sd after one hour {} is outside 0 … {} ({unit})", num(v), num(max));
                return Err(Error::InvalidOption { field: "random_walk", reason });
            }
        }
        if self.weights.iter().any(|w| !(w.is_finite() && *w >= 0.0)) {
            return Err(Error::InvalidOption { field: "weights", reason: "must be finite and non-negative".into() });
        }
        if !(1..=MAX_ITERATIONS_PER_SEGMENT).contains(&self.iterations_per_segment) {
            return Err(Error::InvalidOption {
                field: "iterations_per_segment",
                reason: format!("must be at least 1 and at most {MAX_ITERATIONS_PER_SEGMENT}"),
            });
        }
        if !INFORMATION_SCALE_RANGE.contains(&self.information_scale) {
            return Err(Error::InvalidOption {
                field: "information_scale",
                reason: format!(
                    "must be within {} (0.15 counts each sample once; the default is 0.005)",
                    shown(&INFORMATION_SCALE_RANGE)
                ),
            });
        }
        if self.sigma_factors.iter().any(|f| !(f.is_finite() && *f > 0.0)) {
            return Err(Error::InvalidOption { field: "sigma_factors", reason: "must be positive".into() });
        }
        if !(1..=MAX_RECENT_VALIDATION_SEGMENTS).contains(&self.recent_validation_segments) {
            return Err(Error::InvalidOption {
                field: "recent_validation_segments",
                reason: format!("must be at least 1 and at most {MAX_RECENT_VALIDATION_SEGMENTS}"),
            });
        }
        Ok(())
    }

    /// θ's prior sd at θ.
    pub(crate) fn prior_sd(&self, theta: &Theta) -> [f64; 4] {
        [
            self.prior_relative_c_e * theta.c_e.abs(),
            self.prior_c_d_m,
            self.prior_relative_t_r * theta.t_r.abs(),
            self.prior_d,
        ]
    }
}
