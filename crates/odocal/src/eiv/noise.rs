//! The filter's noise model, its six scaled sources and their per-sample variances.

use serde::{Deserialize, Serialize};

use super::filter::Variances;
use super::{InputJacobian, DEFAULT_POSITION_FLOOR_M};
use crate::error::{Error, Result};
use crate::model::limits::echo_num;

/// The noise model of the filter, in physical units. The estimated noise
/// (`NoiseModel::scaled` by the estimated η) is reported in the same form.
///
/// Scale factor groups η: 0 = white + quantisation, 1 = common wheel
/// Gauss-Markov, 2 = per-wheel Gauss-Markov, 3 = position white, 4 = pose
/// drift (position and heading), 5 = heading white. σ_a and σ_β scale with
/// η_0 (white input noise); the time constants are given, not estimated.
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

/// The noise model as one line in physical units (σ in %, time constants
/// in s), as the calibration report prints it.
impl std::fmt::Display for NoiseModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let n = self;
        write!(
            f,
            "σ_white {:.3} %, q {:.4} rev/s, σ_c {:.3} % (τ_c {} s), σ_w {:.3} % (τ_w {} s); pose σ {:.3} m / {:.2} mrad, \
             drift {:.3} m / {:.2} mrad (τ {} s); σ_a {:.3} m/s², σ_β {:.2} mrad",
            n.wheel_white_rel_sigma * 100.0,
            n.quantisation_step_rev_per_s,
            n.wheel_common_rel_sigma * 100.0,
            n.wheel_common_time_constant_s,
            n.wheel_differential_rel_sigma * 100.0,
            n.wheel_differential_time_constant_s,
            n.position_white_sigma_m,
            n.heading_white_sigma_rad * 1e3,
            n.position_drift_sigma_m,
            n.heading_drift_sigma_rad * 1e3,
            n.drift_time_constant_s,
            n.lateral_acceleration_sigma_m_per_s2,
            n.sideslip_sigma_rad * 1e3
        )
    }
}

/// Defaults for a production car: about 1 % relative wheel-rotation error
/// on the CAN bus and a GNSS/INS reference good to decimetres.
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
    /// ([`HeadingScale`](crate::eiv::HeadingScale) has the measurements).
    HeadingWhite,
}

impl NoiseSource {
    /// The source's name: `wheel_white`, `wheel_common`,
    /// `wheel_differential`, `pose_white`, `pose_drift`, `heading_white`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            NoiseSource::WheelWhite => "wheel_white",
            NoiseSource::WheelCommon => "wheel_common",
            NoiseSource::WheelDifferential => "wheel_differential",
            NoiseSource::PoseWhite => "pose_white",
            NoiseSource::PoseDrift => "pose_drift",
            NoiseSource::HeadingWhite => "heading_white",
        }
    }

    research_pub! {
        /// The source's index in η (`NOISE_SOURCES` order, as
        /// [`EivOptions::eta_held`](crate::eiv::EivOptions::eta_held)): the declaration order.
        fn index(self) -> usize {
            self as usize
        }
    }
}

impl std::fmt::Display for NoiseSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for NoiseSource {
    type Err = Error;
    /// A source by its `NoiseSource::name` (`-` for `_` accepted, as on
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
pub(crate) const NOISE_SOURCES: [NoiseSource; 6] = [
    NoiseSource::WheelWhite,
    NoiseSource::WheelCommon,
    NoiseSource::WheelDifferential,
    NoiseSource::PoseWhite,
    NoiseSource::PoseDrift,
    NoiseSource::HeadingWhite,
];

impl NoiseModel {
    research_pub! {
        /// Defaults for a production car: about 1 % relative wheel-rotation
        /// error on the CAN bus and a GNSS/INS reference good to decimetres
        /// (the `Default`; outside the crate and the studies:
        /// `NoiseModel::default()`).
        const PRODUCTION_CAR: NoiseModel = NoiseModel {
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
    }

    research_pub! {
        /// The noise model that matches a simulator setting (the "true noise
        /// model" for `cramer_rao_bound`; outside the crate, the experiment's
        /// `ExperimentOptions::noise` takes the simulator's settings). Slip is
        /// not represented (it is absorbed by the common-mode error); the drift
        /// time constant is the position drift's.
        fn from_sim(n: &crate::sim::NoiseOptions, sample_time_s: f64) -> Self {
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
    }

    research_pub! {
        /// The model with each group's standard deviations multiplied by
        /// `exp(η_j/2)` (variances by `exp(η_j)`).
        fn scaled(&self, eta: &[f64; 6]) -> Self {
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
    }

    /// Checks a stated model (a user's, or a simulator's true one), naming
    /// the offending field: every level finite, at least 0 and within its
    /// ceiling, every time constant positive and at most a day.
    pub(crate) fn validate(&self) -> Result<()> {
        self.check(true)
    }

    /// Checks a fitted model (a stated one scaled by `exp(η/2)`, which may
    /// pass a ceiling the stated one kept): finite and at least 0.
    pub(crate) fn validate_fitted(&self) -> Result<()> {
        self.check(false)
    }

    fn check(&self, ceilings: bool) -> Result<()> {
        // Each level with its ceiling: beyond it the noise exceeds any signal
        // the model describes (a wheel error of 100 %, a pose error of a
        // kilometre or a half-turn, 10 g, a sideslip of a radian), so a value
        // there is a typo or a unit error, not a noise level.
        let sig = [
            ("noise.wheel_white_rel_sigma", self.wheel_white_rel_sigma, 1.0, "1"),
            ("noise.quantisation_step_rev_per_s", self.quantisation_step_rev_per_s, 1000.0, "1000"),
            ("noise.wheel_common_rel_sigma", self.wheel_common_rel_sigma, 1.0, "1"),
            ("noise.wheel_differential_rel_sigma", self.wheel_differential_rel_sigma, 1.0, "1"),
            ("noise.position_white_sigma_m", self.position_white_sigma_m, 1000.0, "1000"),
            ("noise.heading_white_sigma_rad", self.heading_white_sigma_rad, std::f64::consts::PI, "π"),
            ("noise.position_drift_sigma_m", self.position_drift_sigma_m, 1000.0, "1000"),
            ("noise.heading_drift_sigma_rad", self.heading_drift_sigma_rad, std::f64::consts::PI, "π"),
            ("noise.lateral_acceleration_sigma_m_per_s2", self.lateral_acceleration_sigma_m_per_s2, 100.0, "100"),
            ("noise.sideslip_sigma_rad", self.sideslip_sigma_rad, 1.0, "1"),
        ];
        for (field, v, max, max_text) in sig {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::InvalidOption { field, reason: format!("must be finite and >= 0, got {v}") });
            }
            if ceilings && v > max {
                return Err(Error::InvalidOption {
                    field,
                    reason: format!("must be at most {max_text}, got {} (a unit or a typo?)", echo_num(v)),
                });
            }
        }
        // A time constant of up to a day (the drives are hours at most).
        for (field, v) in [
            ("noise.wheel_common_time_constant_s", self.wheel_common_time_constant_s),
            ("noise.wheel_differential_time_constant_s", self.wheel_differential_time_constant_s),
            ("noise.drift_time_constant_s", self.drift_time_constant_s),
            ("noise.sideslip_time_constant_s", self.sideslip_time_constant_s),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::InvalidOption { field, reason: format!("must be positive, got {v}") });
            }
            if ceilings && v > 86_400.0 {
                return Err(Error::InvalidOption {
                    field,
                    reason: format!("must be at most a day (86400 s), got {} s", echo_num(v)),
                });
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
            heading_white_floor: 0.0,
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
            a_drift_heading: gm(self.drift_time_constant_s),
            heading_drift_on_white_scale: false,
            heading_drift_held: false,
            a_beta,
            quant_scaled: true,
            lateral_scaled: true,
            a_y_scaled: true,
            quant_in_measurement: false,
            quant_counting: false,
            heading_separate: true,
            fitted_input: false,
            input_jacobian: InputJacobian::None,
            noise_input_half_width: 0,
            position_floor_m: DEFAULT_POSITION_FLOOR_M,
            null_without_floors: false,
            coloured_jacobian_in_marginal: true,
            common_mode_jacobian: true,
        }
    }
}
