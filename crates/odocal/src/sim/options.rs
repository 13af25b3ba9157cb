//! The simulator's options: route, speed, vehicle, noise and the drive as a whole.

use serde::{Deserialize, Serialize};

use super::MAX_LENGTH_KM;
use crate::error::{Error, Result};
use crate::model::extrinsics::Extrinsics;
use crate::model::Theta;

/// Options of the route generator. Ranges `[min, max]` are sampled uniformly
/// unless said otherwise.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RouteOptions {
    /// Fraction of zones that are suburban (faster, longer straights, fewer
    /// crossroads), 0..=1. Default 0.35.
    pub suburb_fraction: f64,
    /// Mean length of one city or suburb zone, m (each zone is 0.5–1.5× this).
    /// Default 1500.
    pub zone_length_m: f64,
    /// Length range of the straight before each city manoeuvre, m. Default [50, 250].
    pub city_straight_m: [f64; 2],
    /// Length range of the straight before each suburban manoeuvre, m. Default [150, 600].
    pub suburb_straight_m: [f64; 2],
    /// Radius range of 90° crossroad turns, m. Default [7, 14].
    pub crossroad_radius_m: [f64; 2],
    /// Radius range of bends, m, sampled log-uniformly. Default [25, 400].
    pub bend_radius_m: [f64; 2],
    /// Heading change range of bends, rad. Default [0.3, 1.6].
    pub bend_angle_rad: [f64; 2],
    /// Radius range of roundabout circles, m. Default [10, 25].
    pub roundabout_radius_m: [f64; 2],
    /// Length range of the clothoid transitions between curvature levels, m.
    /// Default [5, 20].
    pub transition_length_m: [f64; 2],
    /// Probability that a city manoeuvre is a 90° crossroad turn (a quarter
    /// of it in the suburb). Default 0.4.
    pub crossroad_probability: f64,
    /// Probability that a manoeuvre is a roundabout. Default 0.15.
    /// The remaining manoeuvres are bends (30 % of them S-bends).
    pub roundabout_probability: f64,
}

impl Default for RouteOptions {
    fn default() -> Self {
        RouteOptions {
            suburb_fraction: 0.35,
            zone_length_m: 1500.0,
            city_straight_m: [50.0, 250.0],
            suburb_straight_m: [150.0, 600.0],
            crossroad_radius_m: [7.0, 14.0],
            bend_radius_m: [25.0, 400.0],
            bend_angle_rad: [0.3, 1.6],
            roundabout_radius_m: [10.0, 25.0],
            transition_length_m: [5.0, 20.0],
            crossroad_probability: 0.4,
            roundabout_probability: 0.15,
        }
    }
}

/// Options of the speed profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SpeedOptions {
    /// Cruise speed range in city zones, m/s. Default [8.3, 13.9] (30–50 km/h).
    pub city_speed_m_per_s: [f64; 2],
    /// Cruise speed range in suburb zones, m/s. Default [16.7, 25.0] (60–90 km/h).
    pub suburb_speed_m_per_s: [f64; 2],
    /// Longitudinal acceleration limit, m/s². Default 1.5.
    pub max_acceleration_m_per_s2: f64,
    /// Longitudinal deceleration (braking) limit, m/s², positive. Default 2.5.
    pub max_deceleration_m_per_s2: f64,
    /// Lateral acceleration limit, m/s². Default 3.0.
    pub max_lateral_acceleration_m_per_s2: f64,
    /// Probability of a stop (standstill) before a crossroad turn. Default 0.5.
    pub stop_probability: f64,
    /// Standstill duration range of a stop, s. Default [2, 8].
    pub stop_duration_s: [f64; 2],
}

impl Default for SpeedOptions {
    fn default() -> Self {
        SpeedOptions {
            city_speed_m_per_s: [8.3, 13.9],
            suburb_speed_m_per_s: [16.7, 25.0],
            max_acceleration_m_per_s2: 1.5,
            max_deceleration_m_per_s2: 2.5,
            max_lateral_acceleration_m_per_s2: 3.0,
            stop_probability: 0.5,
            stop_duration_s: [2.0, 8.0],
        }
    }
}

/// Vehicle data of the linear single-track model that gives the sideslip at
/// the rear axle centre: `β = −m·l_f·a_y / (L·C_r)` (steady state).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct VehicleOptions {
    /// Vehicle mass m, kg. Default 1500.
    pub mass_kg: f64,
    /// Wheelbase L, m. Default 2.7.
    pub wheelbase_m: f64,
    /// Distance l_f from the front axle to the centre of gravity, m. Default 1.2.
    pub front_axle_to_cg_m: f64,
    /// Cornering stiffness C_r of the rear axle (both tyres), N/rad. Default 120 000.
    pub rear_cornering_stiffness_n_per_rad: f64,
}

impl Default for VehicleOptions {
    fn default() -> Self {
        VehicleOptions {
            mass_kg: 1500.0,
            wheelbase_m: 2.7,
            front_axle_to_cg_m: 1.2,
            rear_cornering_stiffness_n_per_rad: 120_000.0,
        }
    }
}

impl VehicleOptions {
    /// Rear-axle sideslip per unit lateral acceleration, rad per m/s² (negative:
    /// the rear axle drifts to the outside of the turn).
    pub(crate) fn sideslip_gain_rad_per_m_per_s2(&self) -> f64 {
        -self.mass_kg * self.front_axle_to_cg_m / (self.wheelbase_m * self.rear_cornering_stiffness_n_per_rad)
    }
}

/// Measurement errors. Every source has its own field; 0 switches it off.
/// Defaults are the `paper` preset (the presets by name: `NoiseOptions`'s
/// `FromStr`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NoiseOptions {
    /// Longitudinal wheel slip: relative wheel rotation error per m/s² of
    /// longitudinal acceleration (both wheels), 1/(m/s²). Paper preset 0.002.
    pub wheel_slip_per_m_per_s2: f64,
    /// Standard deviation of the coloured (first-order Gauss-Markov) relative
    /// wheel rotation error common to both wheels (tyre radius changing with
    /// speed, load, temperature), dimensionless. Paper 0.002.
    pub wheel_coloured_rel_sigma: f64,
    /// Standard deviation of the coloured relative wheel rotation error
    /// independent per wheel, dimensionless. Paper 0.0002. It biases the yaw
    /// rate directly and is not removed by input compensation: 0.002 here
    /// biases raw batch G-N on t_r by about 20 % on a 24 km drive.
    pub wheel_coloured_differential_rel_sigma: f64,
    /// Correlation time of the coloured wheel error common to both wheels
    /// (and of the per-wheel one unless
    /// [`NoiseOptions::wheel_coloured_differential_time_constant_s`] gives
    /// its own), s. Paper 5.
    pub wheel_coloured_time_constant_s: f64,
    /// Correlation time of the per-wheel coloured error, s; `None`: the
    /// common error's ([`NoiseOptions::wheel_coloured_time_constant_s`]).
    /// Paper `None`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wheel_coloured_differential_time_constant_s: Option<f64>,
    /// Standard deviation of the white relative wheel rotation error, per
    /// wheel and sample, dimensionless. Paper 0.008.
    pub wheel_white_rel_sigma: f64,
    /// Encoder resolution, ticks per wheel revolution; ticks are counted over
    /// each sample interval. 0 = no quantization. Paper 2048.
    pub encoder_ticks_per_revolution: u32,
    /// Standard deviation of the slow position drift of the reference (per
    /// axis, Gauss-Markov), m. Paper 0.25.
    pub position_drift_sigma_m: f64,
    /// Correlation time of the position drift, s. Paper 30.
    pub position_drift_time_constant_s: f64,
    /// Standard deviation of the white position noise of the reference, per axis, m. Paper 0.02.
    pub position_white_sigma_m: f64,
    /// Standard deviation of the slow heading drift of the reference
    /// (Gauss-Markov), rad. Paper 0.003.
    pub heading_drift_sigma_rad: f64,
    /// Correlation time of the heading drift, s. Paper 30.
    pub heading_drift_time_constant_s: f64,
    /// Standard deviation of the white heading noise of the reference, rad. Paper 0.0003.
    pub heading_white_sigma_rad: f64,
    /// Constant error of the reference heading, rad: the reference's own
    /// heading bias, which a calibration estimates as the heading offset
    /// δ. It adds to [`SimOptions::reference_mount`]'s heading offset and,
    /// with a zero lever arm, acts exactly like it. Paper 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub heading_bias_rad: f64,
    /// Standard deviation of the white noise on the lateral acceleration, m/s². Paper 0.05.
    pub lateral_acceleration_white_sigma_m_per_s2: f64,
    /// Constant error of the lateral acceleration (an accelerometer bias or
    /// a tilted mount), m/s². Paper 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub lateral_acceleration_bias_m_per_s2: f64,
    /// Standard deviation of the sideslip estimate error (Gauss-Markov), rad. Paper 0.002.
    pub sideslip_sigma_rad: f64,
    /// Correlation time of the sideslip error, s. Paper 1.
    pub sideslip_time_constant_s: f64,
    /// Constant error of the sideslip estimate, rad. Paper 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub sideslip_bias_rad: f64,
}

/// True for a setting at 0 (it is then left out of the sidecar, which
/// stays as it is without the setting).
fn is_zero(v: &f64) -> bool {
    *v == 0.0
}

/// A preset by name: `off`, `paper`, `white` (white wheel noise only),
/// `high`, or `random:N`, the random noise world of seed N (the
/// distribution and the regime rule: the [module
/// doc](crate::sim#random-noise-worlds)); the CLI's `--noise`. The same seed
/// gives the same world. N is written right after `random:`, without
/// spaces, 0 … 2^64 − 1.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::sim::{simulate, NoiseOptions, SimOptions};
/// let noise: NoiseOptions = "random:7".parse()?;
/// assert_eq!("random:7".parse::<NoiseOptions>()?, noise);
/// println!("world 7: {}", noise.world_summary());
/// let out = simulate(&SimOptions { length_km: 1.0, noise, ..SimOptions::paper(1) })?;
/// assert!(out.drive.len() > 100);
/// # Ok(()) }
/// ```
impl std::str::FromStr for NoiseOptions {
    type Err = Error;
    fn from_str(name: &str) -> Result<Self> {
        NoiseOptions::by_name(name)
    }
}

impl Default for NoiseOptions {
    fn default() -> Self {
        NoiseOptions::paper()
    }
}

impl NoiseOptions {
    research_pub! {
        /// No noise at all: every measured column equals its truth column.
        /// (Time constants keep their paper values; they do not matter.)
        fn off() -> Self {
            NoiseOptions {
                wheel_slip_per_m_per_s2: 0.0,
                wheel_coloured_rel_sigma: 0.0,
                wheel_coloured_differential_rel_sigma: 0.0,
                wheel_white_rel_sigma: 0.0,
                encoder_ticks_per_revolution: 0,
                position_drift_sigma_m: 0.0,
                position_white_sigma_m: 0.0,
                heading_drift_sigma_rad: 0.0,
                heading_white_sigma_rad: 0.0,
                lateral_acceleration_white_sigma_m_per_s2: 0.0,
                sideslip_sigma_rad: 0.0,
                ..NoiseOptions::paper()
            }
        }
    }

    research_pub! {
        /// Noise of the size the paper's data show: about 1 % relative wheel
        /// rotation error (as on a production car's CAN bus) and a reference
        /// pose good to a few decimetres.
        fn paper() -> Self {
            NoiseOptions {
                wheel_slip_per_m_per_s2: 0.002,
                wheel_coloured_rel_sigma: 0.002,
                wheel_coloured_differential_rel_sigma: 0.0002,
                wheel_coloured_time_constant_s: 5.0,
                wheel_coloured_differential_time_constant_s: None,
                wheel_white_rel_sigma: 0.008,
                encoder_ticks_per_revolution: 2048,
                position_drift_sigma_m: 0.25,
                position_drift_time_constant_s: 30.0,
                position_white_sigma_m: 0.02,
                heading_drift_sigma_rad: 0.003,
                heading_drift_time_constant_s: 30.0,
                heading_white_sigma_rad: 0.0003,
                heading_bias_rad: 0.0,
                lateral_acceleration_white_sigma_m_per_s2: 0.05,
                lateral_acceleration_bias_m_per_s2: 0.0,
                sideslip_sigma_rad: 0.002,
                sideslip_time_constant_s: 1.0,
                sideslip_bias_rad: 0.0,
            }
        }
    }

    /// Only white noise on the wheel rotations, of the paper preset's size;
    /// everything else exact (the `white` preset).
    pub(crate) fn white_wheel_only() -> Self {
        NoiseOptions { wheel_white_rel_sigma: NoiseOptions::paper().wheel_white_rel_sigma, ..NoiseOptions::off() }
    }

    research_pub! {
        /// The paper preset's wheel noise only — coloured common and
        /// differential relative errors, white noise and encoder quantisation —
        /// on a perfect reference, with no slip, a_y or sideslip noise (the
        /// "coloured" preset of the EIV studies).
        fn coloured_wheels_only() -> Self {
            let p = NoiseOptions::paper();
            NoiseOptions {
                wheel_coloured_rel_sigma: p.wheel_coloured_rel_sigma,
                wheel_coloured_differential_rel_sigma: p.wheel_coloured_differential_rel_sigma,
                wheel_coloured_time_constant_s: p.wheel_coloured_time_constant_s,
                wheel_white_rel_sigma: p.wheel_white_rel_sigma,
                encoder_ticks_per_revolution: p.encoder_ticks_per_revolution,
                ..NoiseOptions::off()
            }
        }
    }

    research_pub! {
        /// Every source 2.5× the paper preset (encoder resolution a quarter).
        fn high() -> Self {
            let p = NoiseOptions::paper();
            NoiseOptions {
                encoder_ticks_per_revolution: p.encoder_ticks_per_revolution / 4,
                ..NoiseOptions::paper_scaled(2.5)
            }
        }
    }

    research_pub! {
        /// Every source of the paper preset scaled by `f`: its standard
        /// deviations and the slip coefficient × f, the encoder ticks per
        /// revolution ÷ f (rounded), so the quantisation step × f; time constants
        /// kept. `paper_scaled(2.5)` is [`NoiseOptions::high`] but for the ticks
        /// (819 there, 512 in `high`).
        fn paper_scaled(f: f64) -> Self {
            let p = NoiseOptions::paper();
            NoiseOptions {
                wheel_slip_per_m_per_s2: f * p.wheel_slip_per_m_per_s2,
                wheel_coloured_rel_sigma: f * p.wheel_coloured_rel_sigma,
                wheel_coloured_differential_rel_sigma: f * p.wheel_coloured_differential_rel_sigma,
                wheel_white_rel_sigma: f * p.wheel_white_rel_sigma,
                encoder_ticks_per_revolution: (f64::from(p.encoder_ticks_per_revolution) / f).round() as u32,
                position_drift_sigma_m: f * p.position_drift_sigma_m,
                position_white_sigma_m: f * p.position_white_sigma_m,
                heading_drift_sigma_rad: f * p.heading_drift_sigma_rad,
                heading_white_sigma_rad: f * p.heading_white_sigma_rad,
                lateral_acceleration_white_sigma_m_per_s2: f * p.lateral_acceleration_white_sigma_m_per_s2,
                sideslip_sigma_rad: f * p.sideslip_sigma_rad,
                ..p
            }
        }
    }

    /// A preset by name (outside the crate: `"paper".parse::<NoiseOptions>()`,
    /// the `FromStr` impl): `off`, `paper`, `white` (white wheel noise only),
    /// `high`, or `random:N`, the random noise world of seed N
    /// (`NoiseOptions::random_world`).
    pub(crate) fn by_name(name: &str) -> Result<Self> {
        match name {
            "off" => Ok(NoiseOptions::off()),
            "paper" => Ok(NoiseOptions::paper()),
            "white" => Ok(NoiseOptions::white_wheel_only()),
            "high" => Ok(NoiseOptions::high()),
            other => match other.strip_prefix("random:") {
                Some(seed) => random_world_seed(other, seed).map(|seed| NoiseOptions::random_world(seed).0),
                None => Err(Error::InvalidOption {
                    field: "noise",
                    reason: format!(
                        "unknown noise preset '{other}'; expected one of off, paper, white, high, random:N"
                    ),
                }),
            },
        }
    }
}

/// The world seed `seed` of the preset `name` (`random:N`): written right
/// after `random:`, without spaces (the preset is named by its text in the
/// sidecar and the reports), a whole number 0 … 2^64 − 1.
fn random_world_seed(name: &str, seed: &str) -> Result<u64> {
    let reason = if seed.is_empty() || seed != seed.trim() {
        format!("'{name}': write the world seed right after 'random:', without spaces (random:5)")
    } else if let Ok(seed) = seed.parse::<u64>() {
        return Ok(seed);
    } else if seed.bytes().all(|b| b.is_ascii_digit()) {
        format!("'{name}': the world seed is above the largest, {}", u64::MAX)
    } else {
        format!("'{name}': the world seed after 'random:' must be a whole number ≥ 0")
    };
    Err(Error::InvalidOption { field: "noise", reason })
}

/// A step change of `c_d` during a drive (a tyre change, a pressure loss).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CdStep {
    /// The change of `c_d`, m.
    pub change_m: f64,
    /// When it happens, s from the start of the drive.
    pub at_s: f64,
}

/// Parameters that drift during a drive: the true θ at `t` seconds into
/// the drive is `c_e·(1 + r·t/3600)` (r = `c_e_relative_per_hour`) and
/// `c_d + Δ` from the step's time on. Default: no drift (θ constant, and
/// the simulator's output byte-identical to one without this setting).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct DriftOptions {
    /// `c_e`'s linear change per hour of driving, as a fraction of its
    /// value at the start (tyres warming: about −0.003). Default 0.
    pub c_e_relative_per_hour: f64,
    /// A step of `c_d`. Default none.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub c_d_step: Option<CdStep>,
}

impl DriftOptions {
    /// True when nothing drifts (a step of 0 changes nothing).
    pub(crate) fn is_zero(&self) -> bool {
        self.c_e_relative_per_hour == 0.0 && self.c_d_step.is_none_or(|s| s.change_m == 0.0)
    }

    research_pub! {
        /// The true θ at `t_s` seconds into the drive, from `theta0` at its
        /// start: `c_e·(1 + r·t/3600)` and `c_d + Δ` from the step's time on.
        /// `theta0` itself when nothing drifts.
        fn theta_at(&self, theta0: &Theta, t_s: f64) -> Theta {
            if self.is_zero() {
                return *theta0;
            }
            let mut th = *theta0;
            th.c_e = theta0.c_e * (1.0 + self.c_e_relative_per_hour * t_s / 3600.0);
            if let Some(step) = self.c_d_step {
                if t_s >= step.at_s {
                    th.c_d += step.change_m;
                }
            }
            th
        }
    }

    pub(crate) fn validate(&self) -> Result<()> {
        check_finite("drift.c_e_relative_per_hour", self.c_e_relative_per_hour)?;
        if let Some(s) = self.c_d_step {
            check_finite("drift.c_d_step.change_m", s.change_m)?;
            check_non_negative("drift.c_d_step.at_s", s.at_s)?;
        }
        Ok(())
    }
}

/// Everything the simulator needs. [`SimOptions::paper`] holds the defaults docs/method.md names.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct SimOptions {
    /// Seed of every random choice (route, speeds, noise). Default 0.
    pub seed: u64,
    /// Route length, km. Default 24.
    pub length_km: f64,
    /// Output sample rate, Hz (t_s = 1/rate). Default 40.
    pub sample_rate_hz: f64,
    /// Fine integration steps of the truth per output sample. Default 10.
    pub substeps: usize,
    /// The true parameters θ. Default `[1.950, −2.0 mm, 1.530, 0.8 mm/(m/s²)]`.
    pub theta_true: Theta,
    /// Route generator. Default `RouteOptions::default`.
    pub route: RouteOptions,
    /// Speed profile. Default `SpeedOptions::default`.
    pub speed: SpeedOptions,
    /// Vehicle (sideslip model). Default `VehicleOptions::default`.
    pub vehicle: VehicleOptions,
    /// Measurement errors. Default the `paper` preset (`NoiseOptions`'s `FromStr`).
    pub noise: NoiseOptions,
    /// Where the pose reference sits on the vehicle: the measured pose is
    /// the reference point `p + R(ψ)·[lever_x, lever_y]` with heading
    /// `ψ + heading_offset` of the true axle pose, plus the reference noise
    /// ([`Extrinsics`]); the truth columns stay the axle's. Default 0
    /// (the paper's reference; the output, sidecar included, is then
    /// byte-identical to a simulator without this setting).
    #[serde(skip_serializing_if = "Extrinsics::is_zero")]
    pub reference_mount: Extrinsics,
    /// Parameters that drift during the drive ([`DriftOptions`]); the
    /// sidecar's `theta_true` is θ at the start. Default none (and then
    /// not written to the sidecar, so the output is byte-identical to a
    /// simulator without this setting).
    #[serde(skip_serializing_if = "DriftOptions::is_zero")]
    pub drift: DriftOptions,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions::paper(0)
    }
}

pub(super) fn invalid(field: &'static str, reason: impl Into<String>) -> Error {
    Error::InvalidOption { field, reason: reason.into() }
}

fn check_positive(field: &'static str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(field, format!("must be a positive finite number, got {v}")))
    }
}

fn check_non_negative(field: &'static str, v: f64) -> Result<()> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(invalid(field, format!("must be a non-negative finite number, got {v}")))
    }
}

fn check_finite(field: &'static str, v: f64) -> Result<()> {
    if v.is_finite() {
        Ok(())
    } else {
        Err(invalid(field, format!("must be a finite number, got {v}")))
    }
}

fn check_probability(field: &'static str, v: f64) -> Result<()> {
    if (0.0..=1.0).contains(&v) {
        Ok(())
    } else {
        Err(invalid(field, format!("must be a probability in [0, 1], got {v}")))
    }
}

fn check_range(field: &'static str, r: [f64; 2], allow_zero: bool) -> Result<()> {
    let ok_lo = r[0].is_finite() && (r[0] > 0.0 || (allow_zero && r[0] >= 0.0));
    if ok_lo && r[1].is_finite() && r[1] >= r[0] {
        Ok(())
    } else {
        Err(invalid(
            field,
            format!(
                "must be [min, max] with {} min <= max, got [{}, {}]",
                if allow_zero { "0 <=" } else { "0 <" },
                r[0],
                r[1]
            ),
        ))
    }
}

impl SimOptions {
    /// The defaults docs/method.md names, with the paper noise preset.
    pub fn paper(seed: u64) -> Self {
        SimOptions {
            seed,
            length_km: 24.0,
            sample_rate_hz: 40.0,
            substeps: 10,
            theta_true: Theta::SIM_DEFAULT_TRUE,
            route: RouteOptions::default(),
            speed: SpeedOptions::default(),
            vehicle: VehicleOptions::default(),
            noise: NoiseOptions::paper(),
            reference_mount: Extrinsics::ZERO,
            drift: DriftOptions::default(),
        }
    }

    /// The defaults docs/method.md names, without any noise (measured == truth): the tests'
    /// `SimOptions { noise: "off".parse()?, ..SimOptions::paper(seed) }`.
    #[cfg(test)]
    pub(crate) fn noise_free(seed: u64) -> Self {
        SimOptions { noise: NoiseOptions::off(), ..SimOptions::paper(seed) }
    }

    research_pub! {
        /// The true θ and reference extrinsics that the measured signals are
        /// consistent with. A constant a_y error b
        /// ([`NoiseOptions::lateral_acceleration_bias_m_per_s2`]) acts exactly as
        /// c_d − 2·d·b (the model's wheel circumferences are
        /// `c_e ± (c_d/2 + d·a_y)`), and a constant sideslip error
        /// ([`NoiseOptions::sideslip_bias_rad`]) as a heading offset of the
        /// reference (exactly so with a zero lever arm), as the heading bias
        /// ([`NoiseOptions::heading_bias_rad`]) does. No calibration can tell
        /// them apart, so an estimate is judged against this truth. Without
        /// constant errors it is `(theta_true, reference_mount)`.
        fn equivalent_truth(&self) -> (Theta, Extrinsics) {
            let n = &self.noise;
            let mut theta = self.theta_true;
            let mut mount = self.reference_mount;
            if n.lateral_acceleration_bias_m_per_s2 != 0.0 {
                theta.c_d -= 2.0 * theta.d * n.lateral_acceleration_bias_m_per_s2;
            }
            if n.heading_bias_rad != 0.0 || n.sideslip_bias_rad != 0.0 {
                mount.heading_offset += n.heading_bias_rad + n.sideslip_bias_rad;
            }
            (theta, mount)
        }
    }

    /// Checks every option, naming the offending field.
    pub(crate) fn validate(&self) -> Result<()> {
        self.reference_mount.validate()?;
        self.drift.validate()?;
        check_positive("length_km", self.length_km)?;
        if self.length_km > MAX_LENGTH_KM {
            return Err(invalid(
                "length_km",
                format!("{} km is more than the limit of {MAX_LENGTH_KM} km", self.length_km),
            ));
        }
        check_positive("sample_rate_hz", self.sample_rate_hz)?;
        if self.substeps == 0 || self.substeps > 10_000 {
            return Err(invalid("substeps", format!("must be in 1..=10000, got {}", self.substeps)));
        }
        self.theta_true.validate().map_err(|e| invalid("theta_true", e.to_string()))?;
        let r = &self.route;
        check_probability("route.suburb_fraction", r.suburb_fraction)?;
        check_positive("route.zone_length_m", r.zone_length_m)?;
        check_range("route.city_straight_m", r.city_straight_m, true)?;
        check_range("route.suburb_straight_m", r.suburb_straight_m, true)?;
        check_range("route.crossroad_radius_m", r.crossroad_radius_m, false)?;
        check_range("route.bend_radius_m", r.bend_radius_m, false)?;
        check_range("route.bend_angle_rad", r.bend_angle_rad, true)?;
        check_range("route.roundabout_radius_m", r.roundabout_radius_m, false)?;
        check_range("route.transition_length_m", r.transition_length_m, false)?;
        check_probability("route.crossroad_probability", r.crossroad_probability)?;
        check_probability("route.roundabout_probability", r.roundabout_probability)?;
        if r.crossroad_probability + r.roundabout_probability > 1.0 {
            return Err(invalid(
                "route.roundabout_probability",
                "route.crossroad_probability + route.roundabout_probability must not exceed 1",
            ));
        }
        let s = &self.speed;
        check_range("speed.city_speed_m_per_s", s.city_speed_m_per_s, false)?;
        check_range("speed.suburb_speed_m_per_s", s.suburb_speed_m_per_s, false)?;
        check_positive("speed.max_acceleration_m_per_s2", s.max_acceleration_m_per_s2)?;
        check_positive("speed.max_deceleration_m_per_s2", s.max_deceleration_m_per_s2)?;
        check_positive("speed.max_lateral_acceleration_m_per_s2", s.max_lateral_acceleration_m_per_s2)?;
        check_probability("speed.stop_probability", s.stop_probability)?;
        check_range("speed.stop_duration_s", s.stop_duration_s, true)?;
        let v = &self.vehicle;
        check_positive("vehicle.mass_kg", v.mass_kg)?;
        check_positive("vehicle.wheelbase_m", v.wheelbase_m)?;
        check_non_negative("vehicle.front_axle_to_cg_m", v.front_axle_to_cg_m)?;
        check_positive("vehicle.rear_cornering_stiffness_n_per_rad", v.rear_cornering_stiffness_n_per_rad)?;
        let n = &self.noise;
        check_non_negative("noise.wheel_slip_per_m_per_s2", n.wheel_slip_per_m_per_s2)?;
        check_non_negative("noise.wheel_coloured_rel_sigma", n.wheel_coloured_rel_sigma)?;
        check_non_negative("noise.wheel_coloured_differential_rel_sigma", n.wheel_coloured_differential_rel_sigma)?;
        check_positive("noise.wheel_coloured_time_constant_s", n.wheel_coloured_time_constant_s)?;
        if let Some(tau) = n.wheel_coloured_differential_time_constant_s {
            check_positive("noise.wheel_coloured_differential_time_constant_s", tau)?;
        }
        check_non_negative("noise.wheel_white_rel_sigma", n.wheel_white_rel_sigma)?;
        check_non_negative("noise.position_drift_sigma_m", n.position_drift_sigma_m)?;
        check_positive("noise.position_drift_time_constant_s", n.position_drift_time_constant_s)?;
        check_non_negative("noise.position_white_sigma_m", n.position_white_sigma_m)?;
        check_non_negative("noise.heading_drift_sigma_rad", n.heading_drift_sigma_rad)?;
        check_positive("noise.heading_drift_time_constant_s", n.heading_drift_time_constant_s)?;
        check_non_negative("noise.heading_white_sigma_rad", n.heading_white_sigma_rad)?;
        check_finite("noise.heading_bias_rad", n.heading_bias_rad)?;
        check_non_negative(
            "noise.lateral_acceleration_white_sigma_m_per_s2",
            n.lateral_acceleration_white_sigma_m_per_s2,
        )?;
        check_finite("noise.lateral_acceleration_bias_m_per_s2", n.lateral_acceleration_bias_m_per_s2)?;
        check_non_negative("noise.sideslip_sigma_rad", n.sideslip_sigma_rad)?;
        check_positive("noise.sideslip_time_constant_s", n.sideslip_time_constant_s)?;
        check_finite("noise.sideslip_bias_rad", n.sideslip_bias_rad)?;
        Ok(())
    }
}
