//! The drive simulator (SPEC §8): city and suburb routes with a known true θ.
//!
//! Real logs of wheel rotations with a GNSS/INS reference rarely are public,
//! and they never carry the true parameters. [`simulate`] makes drives that
//! do, reproducibly from a seed.
//!
//! ## How a drive is made
//!
//! 1. **Route.** A curvature-versus-distance profile κ(s), piecewise linear:
//!    straights, bends of varied radius (some S-bends), 90° crossroad turns
//!    and roundabouts, joined by clothoid transitions (curvature linear in s)
//!    so that the yaw rate is continuous. The route alternates between city
//!    and suburb zones.
//! 2. **Speed.** A cruise speed per manoeuvre (city 30–50 km/h, suburb
//!    60–90 km/h), limited by `sqrt(a_lat,max/|κ|)` in curves and brought to
//!    standstill for a few seconds at some crossroads; a forward pass
//!    (acceleration limit) and a backward pass (deceleration limit) on a
//!    0.5 m grid give v(s), integrated in time with constant acceleration
//!    per grid cell.
//! 3. **Truth.** At every fine step `t_s/substeps`, evaluated at the step's
//!    midpoint time: `ω = v·κ`, `a_y = v·ω`, steady-state rear-axle sideslip
//!    of the linear single-track model `β = −m·l_f·a_y/(L·C_r)`, and the
//!    wheel rotations obtained by inverting the model (2a, 2b, 3a, 3b) with
//!    the true θ:
//!
//!    ```text
//!    n_rr = (v + ω·t_r/2)/c_rr      n_rl = (v − ω·t_r/2)/c_rl
//!    ```
//!
//!    The true pose is integrated with [`model::step`] at the fine step.
//! 4. **Output sample k** carries the true pose at `t_k = k·t_s` and, as its
//!    true inputs, the *mean* of the fine-step inputs over the interval
//!    `[t_k, t_k+1)` — for the wheel rotations that is the number of
//!    revolutions turned in the interval divided by `t_s`, which is what a
//!    counting encoder reports. With `substeps = 1` the output inputs are
//!    exactly the ones the truth was integrated with, so [`model::step`]
//!    from a truth pose with the truth inputs reproduces the next truth pose
//!    bit for bit and calibration recovers θ_true to rounding. With more
//!    substeps the one-step model is no longer exact (midpoint rule over
//!    t_s, mean of products), a small model error as in real data.
//! 5. **Measurements.** Wheel rotations get slip proportional to the
//!    longitudinal acceleration, coloured (first-order Gauss-Markov) noise
//!    common to both wheels and, smaller, independent per wheel, white
//!    relative noise per wheel, then encoder quantization: ticks are counted
//!    over each sample interval (the remainder carries over). The reference
//!    pose gets a slow Gauss-Markov drift plus white noise on position and
//!    heading; a_y gets white noise (IMU), β a Gauss-Markov error (filtered
//!    estimate). Each source has its own setting; [`NoiseOptions::off`]
//!    makes every measured column equal to its truth column.
//!
//! Each noise source draws from its own ChaCha8 stream of the seed, so
//! switching one source off leaves the route, the truth and the other
//! sources' realisations unchanged; the same options give byte-identical
//! output on every platform.

use std::path::{Path, PathBuf};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::drive::{Drive, Signals};
use crate::error::{Error, Result};
use crate::extrinsics::Extrinsics;
use crate::model::{self, Input, State, Theta};

/// Grid step of the speed profile along the route, m.
const SPEED_GRID_M: f64 = 0.5;
/// A sample counts as moving (for [`SimStats::wheel_rotation_rel_error_rms`])
/// when its true speed exceeds this, m/s.
pub const MOVING_SPEED_M_PER_S: f64 = 1.0;
/// Longest drive accepted, km (memory guard: about 40 MB of samples per 100 km).
const MAX_LENGTH_KM: f64 = 2000.0;

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
    pub fn sideslip_gain_rad_per_m_per_s2(&self) -> f64 {
        -self.mass_kg * self.front_axle_to_cg_m / (self.wheelbase_m * self.rear_cornering_stiffness_n_per_rad)
    }
}

/// Measurement errors. Every source has its own field; 0 switches it off.
/// Defaults are [`NoiseOptions::paper`].
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
    /// Correlation time of both coloured wheel errors, s. Paper 5.
    pub wheel_coloured_time_constant_s: f64,
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
    /// Standard deviation of the white noise on the lateral acceleration, m/s². Paper 0.05.
    pub lateral_acceleration_white_sigma_m_per_s2: f64,
    /// Standard deviation of the sideslip estimate error (Gauss-Markov), rad. Paper 0.002.
    pub sideslip_sigma_rad: f64,
    /// Correlation time of the sideslip error, s. Paper 1.
    pub sideslip_time_constant_s: f64,
}

impl Default for NoiseOptions {
    fn default() -> Self {
        NoiseOptions::paper()
    }
}

impl NoiseOptions {
    /// No noise at all: every measured column equals its truth column.
    /// (Time constants keep their paper values; they do not matter.)
    pub fn off() -> Self {
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

    /// Noise of the size the paper's data show: about 1 % relative wheel
    /// rotation error (as on a production car's CAN bus) and a reference
    /// pose good to a few decimetres.
    pub fn paper() -> Self {
        NoiseOptions {
            wheel_slip_per_m_per_s2: 0.002,
            wheel_coloured_rel_sigma: 0.002,
            wheel_coloured_differential_rel_sigma: 0.0002,
            wheel_coloured_time_constant_s: 5.0,
            wheel_white_rel_sigma: 0.008,
            encoder_ticks_per_revolution: 2048,
            position_drift_sigma_m: 0.25,
            position_drift_time_constant_s: 30.0,
            position_white_sigma_m: 0.02,
            heading_drift_sigma_rad: 0.003,
            heading_drift_time_constant_s: 30.0,
            heading_white_sigma_rad: 0.0003,
            lateral_acceleration_white_sigma_m_per_s2: 0.05,
            sideslip_sigma_rad: 0.002,
            sideslip_time_constant_s: 1.0,
        }
    }

    /// Only white noise on the wheel rotations, of the paper preset's size;
    /// everything else exact.
    pub fn white_wheel_only() -> Self {
        NoiseOptions { wheel_white_rel_sigma: NoiseOptions::paper().wheel_white_rel_sigma, ..NoiseOptions::off() }
    }

    /// The paper preset's wheel noise only — coloured common and
    /// differential relative errors, white noise and encoder quantisation —
    /// on a perfect reference, with no slip, a_y or sideslip noise (the
    /// "coloured" preset of the EIV studies).
    pub fn coloured_wheels_only() -> Self {
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

    /// Every source 2.5× the paper preset (encoder resolution a quarter).
    pub fn high() -> Self {
        let p = NoiseOptions::paper();
        NoiseOptions {
            encoder_ticks_per_revolution: p.encoder_ticks_per_revolution / 4,
            ..NoiseOptions::paper_scaled(2.5)
        }
    }

    /// Every source of the paper preset scaled by `f`: its standard
    /// deviations and the slip coefficient × f, the encoder ticks per
    /// revolution ÷ f (rounded), so the quantisation step × f; time constants
    /// kept. `paper_scaled(2.5)` is [`NoiseOptions::high`] but for the ticks
    /// (819 there, 512 in `high`).
    pub fn paper_scaled(f: f64) -> Self {
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

    /// A preset by name: `off`, `paper`, `white` (white wheel noise only) or `high`.
    pub fn by_name(name: &str) -> Result<Self> {
        match name {
            "off" => Ok(NoiseOptions::off()),
            "paper" => Ok(NoiseOptions::paper()),
            "white" => Ok(NoiseOptions::white_wheel_only()),
            "high" => Ok(NoiseOptions::high()),
            other => Err(Error::InvalidOption {
                field: "noise",
                reason: format!("unknown noise preset '{other}'; expected one of off, paper, white, high"),
            }),
        }
    }
}

/// Everything the simulator needs. [`SimOptions::paper`] holds the SPEC defaults.
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
    /// The true parameters θ. Default [`Theta::SIM_DEFAULT_TRUE`].
    pub theta_true: Theta,
    /// Route generator. Default [`RouteOptions::default`].
    pub route: RouteOptions,
    /// Speed profile. Default [`SpeedOptions::default`].
    pub speed: SpeedOptions,
    /// Vehicle (sideslip model). Default [`VehicleOptions::default`].
    pub vehicle: VehicleOptions,
    /// Measurement errors. Default [`NoiseOptions::paper`].
    pub noise: NoiseOptions,
    /// Where the pose reference sits on the vehicle: the measured pose is
    /// the reference point `p + R(ψ)·[lever_x, lever_y]` with heading
    /// `ψ + heading_offset` of the true axle pose, plus the reference noise
    /// ([`crate::extrinsics`]); the truth columns stay the axle's. Default 0
    /// (the SPEC's reference; the output, sidecar included, is then
    /// byte-identical to a simulator without this setting).
    #[serde(skip_serializing_if = "Extrinsics::is_zero")]
    pub reference_mount: Extrinsics,
}

impl Default for SimOptions {
    fn default() -> Self {
        SimOptions::paper(0)
    }
}

fn invalid(field: &'static str, reason: impl Into<String>) -> Error {
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
    /// The SPEC defaults with the paper noise preset.
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
        }
    }

    /// The SPEC defaults without any noise (measured == truth).
    pub fn noise_free(seed: u64) -> Self {
        SimOptions { noise: NoiseOptions::off(), ..SimOptions::paper(seed) }
    }

    /// Checks every option, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        self.reference_mount.validate()?;
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
        check_non_negative("noise.wheel_white_rel_sigma", n.wheel_white_rel_sigma)?;
        check_non_negative("noise.position_drift_sigma_m", n.position_drift_sigma_m)?;
        check_positive("noise.position_drift_time_constant_s", n.position_drift_time_constant_s)?;
        check_non_negative("noise.position_white_sigma_m", n.position_white_sigma_m)?;
        check_non_negative("noise.heading_drift_sigma_rad", n.heading_drift_sigma_rad)?;
        check_positive("noise.heading_drift_time_constant_s", n.heading_drift_time_constant_s)?;
        check_non_negative("noise.heading_white_sigma_rad", n.heading_white_sigma_rad)?;
        check_non_negative(
            "noise.lateral_acceleration_white_sigma_m_per_s2",
            n.lateral_acceleration_white_sigma_m_per_s2,
        )?;
        check_non_negative("noise.sideslip_sigma_rad", n.sideslip_sigma_rad)?;
        check_positive("noise.sideslip_time_constant_s", n.sideslip_time_constant_s)?;
        Ok(())
    }
}

/// Summary numbers of a simulated drive (all from the truth).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimStats {
    /// Output samples.
    pub samples: usize,
    /// Length of the true path, m.
    pub distance_m: f64,
    /// Duration, s (`(samples − 1)·t_s`).
    pub duration_s: f64,
    /// Peak absolute true yaw rate, rad/s.
    pub max_yaw_rate_rad_per_s: f64,
    /// Peak absolute true lateral acceleration, m/s².
    pub max_abs_lateral_acceleration_m_per_s2: f64,
    /// RMS of `(measured − true)/true` wheel rotation over both rear wheels
    /// and every moving sample (true speed above [`MOVING_SPEED_M_PER_S`]).
    pub wheel_rotation_rel_error_rms: f64,
}

/// The sidecar of a simulated drive: the truth that the CSV cannot hold.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SimSidecar {
    /// The true θ (SI units).
    pub theta_true: Theta,
    /// Every simulator setting.
    pub settings: SimOptions,
    /// Summary numbers.
    pub stats: SimStats,
}

impl SimSidecar {
    /// Writes the sidecar as pretty JSON.
    pub fn write_json(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)
            .map_err(|source| Error::Json { context: format!("writing {}", path.display()), source })?;
        std::fs::write(path, text + "\n").map_err(|source| Error::Io { path: path.to_path_buf(), source })
    }

    /// Reads a sidecar written by [`SimSidecar::write_json`].
    pub fn read_json(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        serde_json::from_str(&text).map_err(|source| Error::Json { context: path.display().to_string(), source })
    }
}

/// The sidecar path of a drive CSV: `drive.csv` → `drive.json`.
pub fn sidecar_path(drive_csv: &Path) -> PathBuf {
    drive_csv.with_extension("json")
}

/// A simulated drive and its sidecar.
#[derive(Debug, Clone, PartialEq)]
pub struct SimOutput {
    /// The drive, with [`Drive::truth`] filled.
    pub drive: Drive,
    /// θ_true, the settings and summary numbers.
    pub sidecar: SimSidecar,
}

// ---------------------------------------------------------------------------
// Route: curvature versus distance, speed limits and stops.

/// A random stream of the seed; stream 0 is the route, the others are noise sources.
fn stream(seed: u64, id: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(id);
    rng
}

fn uniform(rng: &mut ChaCha8Rng, r: [f64; 2]) -> f64 {
    r[0] + (r[1] - r[0]) * rng.random::<f64>()
}

fn log_uniform(rng: &mut ChaCha8Rng, r: [f64; 2]) -> f64 {
    r[0] * (r[1] / r[0]).powf(rng.random::<f64>())
}

fn random_sign(rng: &mut ChaCha8Rng) -> f64 {
    if rng.random::<bool>() {
        1.0
    } else {
        -1.0
    }
}

fn normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample::<f64, _>(StandardNormal)
}

/// Piecewise-linear curvature profile, speed limits and stops along s.
#[derive(Debug, Default)]
struct Route {
    /// Knot distances, m, non-decreasing, starting at 0.
    s: Vec<f64>,
    /// Curvature at the knots, 1/m (positive to the left).
    kappa: Vec<f64>,
    /// Speed limit pieces `(end distance, limit)`, in order.
    limits: Vec<(f64, f64)>,
    /// Stops `(distance, standstill duration)`, in order.
    stops: Vec<(f64, f64)>,
}

impl Route {
    fn end(&self) -> f64 {
        self.s.last().copied().unwrap_or(0.0)
    }

    fn push(&mut self, len: f64, kappa: f64) {
        if len > 0.0 {
            let s = self.end() + len;
            self.s.push(s);
            self.kappa.push(kappa);
        }
    }

    fn current_kappa(&self) -> f64 {
        self.kappa.last().copied().unwrap_or(0.0)
    }

    fn straight(&mut self, len: f64) {
        let k = self.current_kappa();
        self.push(len, k);
    }

    /// A sequence of curvature levels `(κ_i, heading change θ_i)`, each
    /// entered and left through clothoids of length `lt`, back to κ = 0.
    /// Each level is held for `θ_i/κ_i − lt` (at least 0), so that with the
    /// halves of its two adjacent transitions it turns by θ_i.
    fn levels(&mut self, levels: &[(f64, f64)], lt: f64) {
        for &(kappa, angle) in levels {
            self.push(lt, kappa);
            self.straight((angle / kappa - lt).max(0.0));
        }
        self.push(lt, 0.0);
    }

    /// Curvature at s; `cursor` is a knot index hint for monotone queries.
    fn kappa_at(&self, s: f64, cursor: &mut usize) -> f64 {
        let n = self.s.len();
        while *cursor + 1 < n && self.s[*cursor + 1] <= s {
            *cursor += 1;
        }
        let i = *cursor;
        if i + 1 >= n {
            return self.kappa[n - 1];
        }
        let (s0, s1) = (self.s[i], self.s[i + 1]);
        if s1 <= s0 {
            return self.kappa[i + 1];
        }
        let f = ((s - s0) / (s1 - s0)).clamp(0.0, 1.0);
        self.kappa[i] + f * (self.kappa[i + 1] - self.kappa[i])
    }

    fn limit_at(&self, s: f64, cursor: &mut usize) -> f64 {
        while *cursor + 1 < self.limits.len() && self.limits[*cursor].0 < s {
            *cursor += 1;
        }
        self.limits.get(*cursor).map(|l| l.1).unwrap_or(f64::INFINITY)
    }
}

fn build_route(opts: &SimOptions, rng: &mut ChaCha8Rng) -> Route {
    let ro = &opts.route;
    let so = &opts.speed;
    let length = opts.length_km * 1000.0;
    let mut route = Route { s: vec![0.0], kappa: vec![0.0], ..Default::default() };
    let mut suburb = rng.random::<f64>() < ro.suburb_fraction;
    let mut zone_left = ro.zone_length_m * rng.random_range(0.5..1.5);
    while route.end() < length {
        let start = route.end();
        let cruise = uniform(rng, if suburb { so.suburb_speed_m_per_s } else { so.city_speed_m_per_s });
        route.straight(uniform(rng, if suburb { ro.suburb_straight_m } else { ro.city_straight_m }));
        let lt = uniform(rng, ro.transition_length_m);
        let p_cross = if suburb { ro.crossroad_probability / 4.0 } else { ro.crossroad_probability };
        let u = rng.random::<f64>();
        if u < p_cross {
            // 90° crossroad turn, perhaps after a stop.
            if rng.random::<f64>() < so.stop_probability {
                let dwell = uniform(rng, so.stop_duration_s);
                route.stops.push((route.end(), dwell));
            }
            let sign = random_sign(rng);
            let radius = uniform(rng, ro.crossroad_radius_m);
            route.levels(&[(sign / radius, sign * std::f64::consts::FRAC_PI_2)], lt);
        } else if u < p_cross + ro.roundabout_probability {
            // Roundabout, driven anticlockwise: deflect right, go round, exit right.
            let ring = uniform(rng, ro.roundabout_radius_m);
            let entry_radius = 1.5 * ring;
            // Exit to the right, straight on, to the left or back; the exit
            // deflection is larger than the entry one so that even the first
            // exit goes some way round the ring.
            let entry = rng.random_range(0.7..1.1);
            let exit = entry + 0.6;
            let net = [-std::f64::consts::FRAC_PI_2, 0.0, std::f64::consts::FRAC_PI_2, std::f64::consts::PI]
                [rng.random_range(0..4usize)];
            let lt = lt.min(0.5 * entry_radius * entry);
            route.levels(
                &[(-1.0 / entry_radius, -entry), (1.0 / ring, net + entry + exit), (-1.0 / entry_radius, -exit)],
                lt,
            );
        } else {
            // A bend, sometimes an S-bend.
            let sign = random_sign(rng);
            let r1 = log_uniform(rng, ro.bend_radius_m);
            let a1 = uniform(rng, ro.bend_angle_rad);
            if rng.random::<f64>() < 0.3 {
                let r2 = log_uniform(rng, ro.bend_radius_m);
                let a2 = uniform(rng, ro.bend_angle_rad);
                route.levels(&[(sign / r1, sign * a1), (-sign / r2, -sign * a2)], lt);
            } else {
                route.levels(&[(sign / r1, sign * a1)], lt);
            }
        }
        let end = route.end();
        route.limits.push((end, cruise));
        zone_left -= end - start;
        if zone_left <= 0.0 {
            suburb = rng.random::<f64>() < ro.suburb_fraction;
            zone_left = ro.zone_length_m * rng.random_range(0.5..1.5);
        }
    }
    // Cut at the requested length.
    let keep = route.s.iter().position(|&s| s >= length).unwrap_or(route.s.len() - 1);
    let mut cur = keep.saturating_sub(1);
    let k_end = route.kappa_at(length, &mut cur);
    route.s.truncate(keep);
    route.kappa.truncate(keep);
    route.s.push(length);
    route.kappa.push(k_end);
    route.stops.retain(|st| st.0 < length - 1.0);
    route
}

// ---------------------------------------------------------------------------
// Speed profile: v on a grid in s, time by constant acceleration per cell.

#[derive(Debug)]
struct SpeedProfile {
    ds: f64,
    v: Vec<f64>,
    /// Arrival time at each grid point, s.
    arrive: Vec<f64>,
    /// Departure time from each grid point (arrival + standstill), s.
    depart: Vec<f64>,
}

/// Distance, speed and longitudinal acceleration at one time.
#[derive(Debug, Clone, Copy)]
struct Motion {
    s: f64,
    v: f64,
    a: f64,
}

impl SpeedProfile {
    fn new(route: &Route, so: &SpeedOptions) -> Self {
        let length = route.end();
        let cells = ((length / SPEED_GRID_M).ceil() as usize).max(1);
        let ds = length / cells as f64;
        let n = cells + 1;
        // Peak |κ| per grid cell (its ends and any knot inside): v² is linear in s
        // within a cell, so limiting both ends by the cell's peak keeps
        // v²·|κ| ≤ a_lat,max everywhere.
        let mut cell_kappa = vec![0.0f64; cells];
        let mut kc = 0usize;
        let mut at_grid = route.kappa_at(0.0, &mut kc).abs();
        for (i, ck) in cell_kappa.iter_mut().enumerate() {
            let next = route.kappa_at((i + 1) as f64 * ds, &mut kc).abs();
            *ck = at_grid.max(next);
            at_grid = next;
        }
        for (&sk, &kk) in route.s.iter().zip(&route.kappa) {
            let c = ((sk / ds).floor() as usize).min(cells - 1);
            cell_kappa[c] = cell_kappa[c].max(kk.abs());
        }
        let mut vmax = vec![0.0; n];
        let mut lc = 0usize;
        for (i, vm) in vmax.iter_mut().enumerate() {
            let s = i as f64 * ds;
            let kappa = cell_kappa[i.saturating_sub(1)].max(cell_kappa[i.min(cells - 1)]);
            let lateral =
                if kappa > 0.0 { (so.max_lateral_acceleration_m_per_s2 / kappa).sqrt() } else { f64::INFINITY };
            *vm = route.limit_at(s, &mut lc).min(lateral);
        }
        let mut dwell = vec![0.0; n];
        for &(s, d) in &route.stops {
            let i = ((s / ds).round() as usize).min(n - 1);
            vmax[i] = 0.0;
            dwell[i] += d;
        }
        vmax[0] = 0.0;
        vmax[n - 1] = 0.0;
        let mut v = vmax;
        for i in 1..n {
            v[i] = v[i].min((v[i - 1] * v[i - 1] + 2.0 * so.max_acceleration_m_per_s2 * ds).sqrt());
        }
        for i in (0..n - 1).rev() {
            v[i] = v[i].min((v[i + 1] * v[i + 1] + 2.0 * so.max_deceleration_m_per_s2 * ds).sqrt());
        }
        let mut arrive = vec![0.0; n];
        let mut depart = vec![0.0; n];
        depart[0] = dwell[0];
        for i in 1..n {
            let vs = v[i - 1] + v[i];
            arrive[i] = depart[i - 1] + if vs > 0.0 { 2.0 * ds / vs } else { 0.0 };
            depart[i] = arrive[i] + dwell[i];
        }
        SpeedProfile { ds, v, arrive, depart }
    }

    fn duration(&self) -> f64 {
        self.depart.last().copied().unwrap_or(0.0)
    }

    /// Motion at time t; `cursor` is a grid index hint for monotone queries.
    fn at(&self, t: f64, cursor: &mut usize) -> Motion {
        let n = self.v.len();
        while *cursor + 1 < n && self.arrive[*cursor + 1] <= t {
            *cursor += 1;
        }
        let i = *cursor;
        let s0 = i as f64 * self.ds;
        if i + 1 >= n || t < self.depart[i] {
            return Motion { s: s0, v: self.v[i].min(if i + 1 >= n { 0.0 } else { f64::INFINITY }), a: 0.0 };
        }
        let (v0, v1) = (self.v[i], self.v[i + 1]);
        let a = (v1 * v1 - v0 * v0) / (2.0 * self.ds);
        let tau = (t - self.depart[i]).clamp(0.0, self.arrive[i + 1] - self.depart[i]);
        let v = (v0 + a * tau).max(0.0);
        let s = (s0 + v0 * tau + 0.5 * a * tau * tau).min(s0 + self.ds);
        Motion { s, v, a }
    }
}

// ---------------------------------------------------------------------------
// Noise processes.

/// First-order Gauss-Markov process sampled at a fixed step (exact discretisation).
struct GaussMarkov {
    rng: ChaCha8Rng,
    phi: f64,
    q: f64,
    x: f64,
    on: bool,
}

impl GaussMarkov {
    fn new(mut rng: ChaCha8Rng, sigma: f64, tau: f64, dt: f64) -> Self {
        let on = sigma > 0.0;
        let phi = (-dt / tau).exp();
        let x = if on { sigma * normal(&mut rng) } else { 0.0 };
        GaussMarkov { rng, phi, q: sigma * (1.0 - phi * phi).sqrt(), x, on }
    }

    /// The current value; advances to the next sample.
    fn next(&mut self) -> f64 {
        let out = self.x;
        if self.on {
            self.x = self.phi * self.x + self.q * normal(&mut self.rng);
        }
        out
    }
}

/// White Gaussian noise.
struct White {
    rng: ChaCha8Rng,
    sigma: f64,
}

impl White {
    fn next(&mut self) -> f64 {
        if self.sigma > 0.0 {
            self.sigma * normal(&mut self.rng)
        } else {
            0.0
        }
    }
}

/// Counts encoder ticks of a wheel over each sample interval.
struct Encoder {
    ticks: f64,
    revolutions: f64,
}

impl Encoder {
    /// Average rotation speed over an interval as reported by the encoder.
    fn measure(&mut self, n: f64, ts: f64) -> f64 {
        if self.ticks <= 0.0 {
            return n;
        }
        let before = (self.revolutions * self.ticks).floor();
        self.revolutions += n * ts;
        let after = (self.revolutions * self.ticks).floor();
        (after - before) / (self.ticks * ts)
    }
}

// ---------------------------------------------------------------------------

/// Simulates one drive (SPEC §8).
///
/// The same options (seed included) give an identical drive, byte for byte
/// when written as CSV. The measured columns carry the noise of
/// [`SimOptions::noise`]; [`Drive::truth`] holds the true poses and inputs,
/// the sidecar θ_true, the settings and [`SimStats`].
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::sim::{simulate, SimOptions};
/// let out = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(42) })?;
/// let drive = &out.drive;
/// assert_eq!(drive.len(), out.sidecar.stats.samples);
/// assert!((out.sidecar.stats.distance_m - 1000.0).abs() < 20.0);
/// assert!(drive.truth().is_some());
/// # Ok(()) }
/// ```
pub fn simulate(opts: &SimOptions) -> Result<SimOutput> {
    opts.validate()?;
    let theta = opts.theta_true;
    let mut route_rng = stream(opts.seed, 0);
    let route = build_route(opts, &mut route_rng);
    let profile = SpeedProfile::new(&route, &opts.speed);
    let psi0 = route_rng.random_range(-std::f64::consts::PI..std::f64::consts::PI);

    let ts = 1.0 / opts.sample_rate_hz;
    let sub = opts.substeps;
    let dtf = ts / sub as f64;
    let n = (profile.duration() * opts.sample_rate_hz).floor() as usize + 1;
    if n < 2 {
        return Err(invalid("length_km", "the drive is shorter than two samples"));
    }
    let beta_gain = opts.vehicle.sideslip_gain_rad_per_m_per_s2();

    // Truth, integrated at the fine step.
    let mut truth = Signals::with_capacity(n);
    let mut a_x = Vec::with_capacity(n);
    let mut x = State::new(0.0, 0.0, psi0);
    let (mut pcur, mut kcur) = (0usize, 0usize);
    let (mut max_yaw, mut max_ay) = (0.0f64, 0.0f64);
    for k in 0..n {
        truth.px.push(x[0]);
        truth.py.push(x[1]);
        truth.psi.push(x[2]);
        let mut sum = [0.0f64; 5];
        for j in 0..sub {
            let t_mid = ((k * sub + j) as f64 + 0.5) * dtf;
            let m = profile.at(t_mid, &mut pcur);
            let kappa = route.kappa_at(m.s, &mut kcur);
            let omega = m.v * kappa;
            let a_y = m.v * omega;
            let beta = beta_gain * a_y;
            let (n_rl, n_rr) = model::wheel_rotations(m.v, omega, a_y, &theta);
            let u = Input { n_rl, n_rr, beta, a_y };
            x = model::step(&x, &u, &theta, dtf);
            for (acc, v) in sum.iter_mut().zip([u.n_rl, u.n_rr, u.beta, u.a_y, m.a]) {
                *acc += v;
            }
            max_yaw = max_yaw.max(omega.abs());
            max_ay = max_ay.max(a_y.abs());
        }
        let div = sub as f64;
        truth.n_rl.push(sum[0] / div);
        truth.n_rr.push(sum[1] / div);
        truth.beta.push(sum[2] / div);
        truth.a_y.push(sum[3] / div);
        a_x.push(sum[4] / div);
    }

    // Measurements.
    let no = &opts.noise;
    let seed = opts.seed;
    let tau_w = no.wheel_coloured_time_constant_s;
    let mut gm_common = GaussMarkov::new(stream(seed, 1), no.wheel_coloured_rel_sigma, tau_w, ts);
    let wheel_gm = |id| GaussMarkov::new(stream(seed, id), no.wheel_coloured_differential_rel_sigma, tau_w, ts);
    let (mut gm_rl, mut gm_rr) = (wheel_gm(2), wheel_gm(12));
    let mut white_wheel = White { rng: stream(seed, 3), sigma: no.wheel_white_rel_sigma };
    let ticks = f64::from(no.encoder_ticks_per_revolution);
    let mut phase_rng = stream(seed, 4);
    let mut enc_rl = Encoder { ticks, revolutions: phase_rng.random::<f64>() / ticks.max(1.0) };
    let mut enc_rr = Encoder { ticks, revolutions: phase_rng.random::<f64>() / ticks.max(1.0) };
    let pos_gm =
        |id| GaussMarkov::new(stream(seed, id), no.position_drift_sigma_m, no.position_drift_time_constant_s, ts);
    let (mut drift_x, mut drift_y) = (pos_gm(5), pos_gm(6));
    let mut white_pos = White { rng: stream(seed, 7), sigma: no.position_white_sigma_m };
    let mut drift_psi =
        GaussMarkov::new(stream(seed, 8), no.heading_drift_sigma_rad, no.heading_drift_time_constant_s, ts);
    let mut white_psi = White { rng: stream(seed, 9), sigma: no.heading_white_sigma_rad };
    let mut white_ay = White { rng: stream(seed, 10), sigma: no.lateral_acceleration_white_sigma_m_per_s2 };
    let mut beta_err = GaussMarkov::new(stream(seed, 11), no.sideslip_sigma_rad, no.sideslip_time_constant_s, ts);

    let mut measured = Signals::with_capacity(n);
    let (mut sq, mut count) = (0.0f64, 0usize);
    for (k, &ax) in a_x.iter().enumerate() {
        let slip = no.wheel_slip_per_m_per_s2 * ax + gm_common.next();
        let rel_rl = slip + gm_rl.next() + white_wheel.next();
        let rel_rr = slip + gm_rr.next() + white_wheel.next();
        let n_rl = enc_rl.measure(truth.n_rl[k] * (1.0 + rel_rl), ts);
        let n_rr = enc_rr.measure(truth.n_rr[k] * (1.0 + rel_rr), ts);
        measured.n_rl.push(n_rl);
        measured.n_rr.push(n_rr);
        let tu = Input { n_rl: truth.n_rl[k], n_rr: truth.n_rr[k], beta: truth.beta[k], a_y: truth.a_y[k] };
        if model::kinematics(&tu, &theta).speed_m_per_s > MOVING_SPEED_M_PER_S {
            for (m, t) in [(n_rl, tu.n_rl), (n_rr, tu.n_rr)] {
                let e = (m - t) / t;
                sq += e * e;
                count += 1;
            }
        }
        let mut reference = State::new(truth.px[k], truth.py[k], truth.psi[k]);
        if !opts.reference_mount.is_zero() {
            reference = crate::extrinsics::reference_pose(&reference, &opts.reference_mount);
        }
        measured.px.push(reference[0] + drift_x.next() + white_pos.next());
        measured.py.push(reference[1] + drift_y.next() + white_pos.next());
        measured.psi.push(reference[2] + drift_psi.next() + white_psi.next());
        measured.a_y.push(truth.a_y[k] + white_ay.next());
        measured.beta.push(truth.beta[k] + beta_err.next());
    }
    let distance_m = (1..n).map(|k| (truth.px[k] - truth.px[k - 1]).hypot(truth.py[k] - truth.py[k - 1])).sum::<f64>();
    let stats = SimStats {
        samples: n,
        distance_m,
        duration_s: (n - 1) as f64 * ts,
        max_yaw_rate_rad_per_s: max_yaw,
        max_abs_lateral_acceleration_m_per_s2: max_ay,
        wheel_rotation_rel_error_rms: if count > 0 { (sq / count as f64).sqrt() } else { 0.0 },
    };
    let t = (0..n).map(|k| k as f64 / opts.sample_rate_hz).collect();
    let drive = Drive::builder(t, measured).truth(truth).sample_time_s(ts).context("simulator").build()?;
    Ok(SimOutput { drive, sidecar: SimSidecar { theta_true: theta, settings: opts.clone(), stats } })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{batch_gauss_newton, IdentifyOptions};
    use crate::segment::{calibration_segments, SegmentData};

    /// Rounding over one f64 model step of ~0.5 m at coordinates up to ~2 km.
    const STEP_REPRODUCTION_TOL_M: f64 = 1e-9;
    /// Noise-free, substeps = 1: the model is exact, G-N converges to rounding.
    const EXACT_RECOVERY_REL_TOL: f64 = 1e-8;
    /// Noise-free, 10 substeps: the one-step model's midpoint-rule error.
    const SUBSTEP_RECOVERY_REL_TOL: f64 = 1e-4;

    fn short(opts: SimOptions, km: f64) -> SimOutput {
        simulate(&SimOptions { length_km: km, ..opts }).expect("simulate")
    }

    fn csv_bytes(d: &Drive) -> Vec<u8> {
        let mut buf = Vec::new();
        d.write_csv_to(&mut buf).expect("write csv");
        buf
    }

    fn truth(d: &Drive) -> &Signals {
        d.truth().as_ref().expect("simulated drives carry the truth")
    }

    #[test]
    fn same_seed_same_bytes_other_seed_differs() {
        let a = short(SimOptions::paper(5), 1.5);
        let b = short(SimOptions::paper(5), 1.5);
        assert_eq!(a, b);
        assert_eq!(csv_bytes(&a.drive), csv_bytes(&b.drive));
        let c = short(SimOptions::paper(6), 1.5);
        assert_ne!(a.drive, c.drive);
        assert_ne!(csv_bytes(&a.drive), csv_bytes(&c.drive));
    }

    #[test]
    fn noise_sources_do_not_change_the_truth() {
        let a = short(SimOptions::paper(3), 1.0);
        let b = short(SimOptions::noise_free(3), 1.0);
        assert_eq!(a.drive.truth(), b.drive.truth());
        assert_ne!(a.drive.n_rl(), b.drive.n_rl());
    }

    #[test]
    fn noise_off_measured_equals_truth_and_model_reproduces_truth() {
        let out = short(SimOptions { substeps: 1, ..SimOptions::noise_free(11) }, 2.0);
        let d = &out.drive;
        let tr = truth(d);
        assert_eq!(d.px(), tr.px);
        assert_eq!(d.py(), tr.py);
        assert_eq!(d.psi(), tr.psi);
        assert_eq!(d.n_rl(), tr.n_rl);
        assert_eq!(d.n_rr(), tr.n_rr);
        assert_eq!(d.beta(), tr.beta);
        assert_eq!(d.a_y(), tr.a_y);
        assert_eq!(d.parts(), vec![0..d.len()]);
        approx::assert_relative_eq!(d.sample_time_s(), 0.025, max_relative = 1e-15);
        let theta = out.sidecar.theta_true;
        let mut worst = 0.0f64;
        for k in 0..d.len() - 1 {
            let next = model::step(&d.pose(k), &d.input(k), &theta, d.sample_time_s());
            worst = worst.max((next - d.pose(k + 1)).abs().max());
        }
        assert!(worst <= STEP_REPRODUCTION_TOL_M, "one-step model error {worst:e}");
        // With substeps the one-step model is close but no longer exact.
        let out = short(SimOptions::noise_free(11), 2.0);
        let d = &out.drive;
        let mut worst = 0.0f64;
        for k in 0..d.len() - 1 {
            let next = model::step(&d.pose(k), &d.input(k), &theta, d.sample_time_s());
            worst = worst.max((next - d.pose(k + 1)).abs().max());
        }
        assert!(worst > 0.0 && worst < 1e-5, "substep model error {worst:e}");
    }

    fn identify(out: &SimOutput) -> (Theta, usize) {
        let d = &out.drive;
        let sel = calibration_segments(d, &Default::default()).expect("segments");
        assert!(sel.selected.len() >= 5, "too few turning segments: {}", sel.selected.len());
        let data: Vec<_> = sel.selected.iter().map(|s| SegmentData::new(d, s)).collect();
        let opts = IdentifyOptions { max_iterations: 20, ..Default::default() };
        let report = batch_gauss_newton(&data, &Theta::PAPER_INITIAL, &opts).expect("identify");
        (report.theta, data.len())
    }

    fn rel_errors(est: &Theta, truth: &Theta) -> [f64; 4] {
        let (e, t) = (est.to_array(), truth.to_array());
        [0, 1, 2, 3].map(|i| ((e[i] - t[i]) / t[i]).abs())
    }

    #[test]
    fn noise_free_calibration_recovers_theta() {
        let truth_theta = Theta::SIM_DEFAULT_TRUE;
        // The start is off by more than 1 % in every parameter.
        for r in rel_errors(&Theta::PAPER_INITIAL, &truth_theta) {
            assert!(r > 0.01, "start too close: {r}");
        }
        let out = short(SimOptions { substeps: 1, ..SimOptions::noise_free(21) }, 3.0);
        let (est, _) = identify(&out);
        for (name, r) in crate::model::THETA_NAMES.iter().zip(rel_errors(&est, &truth_theta)) {
            assert!(r <= EXACT_RECOVERY_REL_TOL, "substeps 1: {name} off by {r:e} ({est})");
        }
        let out = short(SimOptions::noise_free(21), 3.0);
        let (est, _) = identify(&out);
        for (name, r) in crate::model::THETA_NAMES.iter().zip(rel_errors(&est, &truth_theta)) {
            assert!(r <= SUBSTEP_RECOVERY_REL_TOL, "substeps 10: {name} off by {r:e} ({est})");
        }
    }

    #[test]
    fn paper_noise_has_the_paper_size() {
        let out = short(SimOptions::paper(4), 3.0);
        let d = &out.drive;
        let tr = truth(d);
        let rms = out.sidecar.stats.wheel_rotation_rel_error_rms;
        assert!((0.005..0.02).contains(&rms), "wheel rms relative error {rms}");
        let n = d.len() as f64;
        let pos_rms = (d.px().iter().zip(&tr.px).zip(d.py().iter().zip(&tr.py)))
            .map(|((a, b), (c, e))| (a - b).powi(2) + (c - e).powi(2))
            .sum::<f64>()
            / n;
        let pos_rms = pos_rms.sqrt();
        assert!((0.05..1.0).contains(&pos_rms), "reference position error rms {pos_rms} m");
        let psi_rms = (d.psi().iter().zip(&tr.psi).map(|(a, b)| (a - b).powi(2)).sum::<f64>() / n).sqrt();
        assert!((2e-4..0.02).contains(&psi_rms), "reference heading error rms {psi_rms} rad");
        // Measured wheels differ from the truth, and standstill reads zero.
        assert!(d.n_rl().iter().zip(&tr.n_rl).any(|(a, b)| (a - b).abs() > 1e-3));
        // At standstill the true rotation is exactly 0 (v = ω = 0) and so is the encoder count.
        #[allow(clippy::float_cmp)]
        for (m, t) in d.n_rr().iter().zip(&tr.n_rr) {
            if *t == 0.0 {
                assert_eq!(*m, 0.0);
            }
        }
    }

    #[test]
    fn presets_are_ordered() {
        let white = short(SimOptions { noise: NoiseOptions::white_wheel_only(), ..SimOptions::paper(8) }, 1.0);
        let paper = short(SimOptions::paper(8), 1.0);
        let high = short(SimOptions { noise: NoiseOptions::high(), ..SimOptions::paper(8) }, 1.0);
        let (w, p, h) = (
            white.sidecar.stats.wheel_rotation_rel_error_rms,
            paper.sidecar.stats.wheel_rotation_rel_error_rms,
            high.sidecar.stats.wheel_rotation_rel_error_rms,
        );
        assert!(w > 0.0 && w < p && p * 1.8 < h, "white {w}, paper {p}, high {h}");
        let tr = truth(&white.drive);
        assert_eq!(white.drive.px(), tr.px);
        assert_eq!(white.drive.a_y(), tr.a_y);
        assert_eq!(NoiseOptions::by_name("white").expect("preset"), NoiseOptions::white_wheel_only());
        assert_eq!(NoiseOptions::by_name("off").expect("preset"), NoiseOptions::off());
        let e = NoiseOptions::by_name("loud").expect_err("unknown preset");
        assert!(e.to_string().contains("loud") && e.to_string().contains("paper"), "{e}");
    }

    #[test]
    fn stats_are_sane_and_sidecar_round_trips() {
        let opts = SimOptions { length_km: 2.0, ..SimOptions::paper(9) };
        let out = simulate(&opts).expect("simulate");
        let st = &out.sidecar.stats;
        let d = &out.drive;
        assert_eq!(st.samples, d.len());
        approx::assert_relative_eq!(st.duration_s, d.t()[d.len() - 1], max_relative = 1e-12);
        assert!((st.distance_m - 2000.0).abs() < 10.0, "distance {}", st.distance_m);
        let mean_speed = st.distance_m / st.duration_s;
        assert!((5.0..25.0).contains(&mean_speed), "mean speed {mean_speed} m/s");
        assert!((0.15..2.0).contains(&st.max_yaw_rate_rad_per_s), "yaw rate {}", st.max_yaw_rate_rad_per_s);
        let ay_max = opts.speed.max_lateral_acceleration_m_per_s2;
        assert!(
            (0.5 * ay_max..=ay_max * (1.0 + 1e-9)).contains(&st.max_abs_lateral_acceleration_m_per_s2),
            "lateral acceleration {}",
            st.max_abs_lateral_acceleration_m_per_s2
        );
        let tr = truth(d);
        let truth_ay = tr.a_y.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        assert!(truth_ay <= st.max_abs_lateral_acceleration_m_per_s2 * (1.0 + 1e-12));
        // Heading unwrapped, time uniform.
        assert!(tr.psi.windows(2).all(|w| (w[1] - w[0]).abs() < 0.1));
        assert!(d.t().windows(2).all(|w| ((w[1] - w[0]) - 0.025).abs() < 1e-9));
        assert_eq!(out.sidecar.theta_true, opts.theta_true);
        assert_eq!(out.sidecar.settings, opts);

        let dir = std::env::temp_dir().join(format!("odocal-sim-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("temp dir");
        let csv = dir.join("drive.csv");
        let json = sidecar_path(&csv);
        assert_eq!(json, dir.join("drive.json"));
        out.sidecar.write_json(&json).expect("write sidecar");
        let back = SimSidecar::read_json(&json).expect("read sidecar");
        assert_eq!(back, out.sidecar);
        let text = std::fs::read_to_string(&json).expect("read");
        assert!(text.contains("\"theta_true\"") && text.contains("\"c_e\""), "{text}");
        let e = SimSidecar::read_json(&dir.join("missing.json")).expect_err("missing file");
        assert!(e.to_string().contains("missing.json"), "{e}");
        std::fs::remove_dir_all(&dir).expect("clean up");
    }

    #[test]
    fn route_turns_enough() {
        let out = short(SimOptions::paper(13), 5.0);
        let sel = calibration_segments(&out.drive, &Default::default()).expect("segments");
        let frac = sel.selected.len() as f64 / sel.all.len() as f64;
        assert!((0.25..0.8).contains(&frac), "selected {} of {} segments", sel.selected.len(), sel.all.len());
        // And it also has straight stretches and stops.
        assert!(sel.selected.len() < sel.all.len());
        let tr = truth(&out.drive);
        // A standstill integrates v = 0 exactly: the pose does not change at all.
        #[allow(clippy::float_cmp)]
        let stopped = tr.px.windows(2).zip(tr.py.windows(2)).filter(|(x, y)| x[0] == x[1] && y[0] == y[1]).count();
        assert!(stopped > 40, "no standstill: {stopped} samples");
    }

    #[test]
    fn invalid_options_name_the_field() {
        let cases: Vec<(SimOptions, &str)> = vec![
            (SimOptions { length_km: 0.0, ..Default::default() }, "length_km"),
            (SimOptions { sample_rate_hz: f64::NAN, ..Default::default() }, "sample_rate_hz"),
            (SimOptions { substeps: 0, ..Default::default() }, "substeps"),
            (
                SimOptions { theta_true: Theta { t_r: -1.0, ..Theta::SIM_DEFAULT_TRUE }, ..Default::default() },
                "theta_true",
            ),
            (
                SimOptions {
                    route: RouteOptions { bend_radius_m: [50.0, 10.0], ..Default::default() },
                    ..Default::default()
                },
                "route.bend_radius_m",
            ),
            (
                SimOptions {
                    noise: NoiseOptions { wheel_white_rel_sigma: -0.1, ..NoiseOptions::paper() },
                    ..Default::default()
                },
                "noise.wheel_white_rel_sigma",
            ),
            (
                SimOptions {
                    speed: SpeedOptions { stop_probability: 1.5, ..Default::default() },
                    ..Default::default()
                },
                "speed.stop_probability",
            ),
        ];
        for (opts, field) in cases {
            let e = simulate(&opts).expect_err(field);
            assert!(matches!(&e, Error::InvalidOption { field: f, .. } if *f == field), "{field}: {e}");
        }
        assert!(SimOptions::default().validate().is_ok());
        assert_eq!(SimOptions::default(), SimOptions::paper(0));
    }
}
