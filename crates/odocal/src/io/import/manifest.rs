//! The drive manifest: which file each signal comes from, in which unit and
//! convention. See the [module documentation](super) for the format.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::limits::{self, echo_num};
use super::settings::{CalibrationTable, NoiseTable, ReferenceSpec};
use crate::error::{Error, Result};
use crate::model::Theta;

/// A drive manifest (TOML): the streams of one recorded drive and where each
/// model signal comes from. See the [module documentation](super) for the
/// format and a full example.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// The manifest file itself; stream files are relative to its folder.
    /// Set by [`Manifest::from_path`] / [`Manifest::parse`], not read from TOML.
    #[serde(skip)]
    pub path: PathBuf,
    /// Output rate, gaps, clock offset. All fields have defaults.
    #[serde(default)]
    pub output: OutputSpec,
    /// The recorded streams (files), by name. Signals refer to these names.
    pub streams: BTreeMap<String, StreamSpec>,
    /// Rear wheel rotation.
    pub wheels: WheelSpec,
    /// Reference pose.
    pub pose: PoseSpec,
    /// Lateral acceleration a_y. Default: derived from the wheels.
    #[serde(default)]
    pub lateral_acceleration: LateralAccelerationSpec,
    /// Sideslip β. Default: zero.
    #[serde(default)]
    pub sideslip: SideslipSpec,
    /// Physical limits the imported signals must respect. All fields have
    /// defaults; raise them for a vehicle that really exceeds them.
    #[serde(default)]
    pub limits: LimitsSpec,
    /// The sensor's noise (`[noise]`): the starting noise model of
    /// `--method eiv` as written, read by the calibration like a
    /// `--noise-model` file ([`NoiseTable`]).
    #[serde(default, deserialize_with = "super::settings::noise_table", skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseTable>,
    /// The reference sensor's extrinsics (`[reference]`): lever arm,
    /// heading offset and which of them to estimate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<ReferenceSpec>,
    /// Calibration settings (`[calibration]`) as written, read by the
    /// calibration ([`CalibrationTable`]).
    #[serde(default, deserialize_with = "super::settings::calibration_table", skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationTable>,
}

/// Physical limits (`[limits]`): an imported signal beyond one is an error
/// naming the time, because it means a wrong unit, sign, column or a
/// corrupt sample rather than a real motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LimitsSpec {
    /// Largest plausible vehicle speed, m/s: each wheel's speed at θ_0 and
    /// the reference pose's speed between samples. Default 100 (360 km/h).
    pub max_speed_m_per_s: f64,
    /// Largest plausible |a_y|, m/s² (a_y from the wheels, the pose or an
    /// IMU). Default 15 (about 1.5 g; racing cars reach 3–5 g).
    pub max_lateral_acceleration_m_per_s2: f64,
}

impl Default for LimitsSpec {
    fn default() -> Self {
        LimitsSpec { max_speed_m_per_s: 100.0, max_lateral_acceleration_m_per_s2: 15.0 }
    }
}

/// Output settings (`[output]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputSpec {
    /// Output sample rate, Hz. Default 40 (t_s = 0.025 s, as in the paper).
    pub rate_hz: f64,
    /// A stream gap longer than this splits the drive into parts, s. Default 0.5.
    pub max_gap_s: f64,
    /// Parts shorter than this are dropped (and reported), s. Default 30.
    pub min_part_s: f64,
    /// Offset added to the pose stream's time to put it on the wheel clock:
    /// `"auto"` (estimate by cross-correlating speeds, and apply) or seconds.
    /// Default `"auto"`.
    pub clock_offset: ClockOffset,
    /// The offset search range for `"auto"`, ± seconds. Default 2.
    pub max_clock_offset_s: f64,
    /// θ_0 = `[c_e, c_d, t_r, d]` (SI) used to turn wheel rotation into speed
    /// and yaw rate where the import needs them (clock offset, a_y
    /// `from_wheels`). Default the paper's `[2.0, 0, 1.6, 0]`.
    pub theta0: [f64; 4],
}

impl Default for OutputSpec {
    fn default() -> Self {
        OutputSpec {
            rate_hz: 40.0,
            max_gap_s: 0.5,
            min_part_s: 30.0,
            clock_offset: ClockOffset::Auto,
            max_clock_offset_s: 2.0,
            theta0: Theta::PAPER_INITIAL.to_array(),
        }
    }
}

impl OutputSpec {
    /// θ_0 as a [`Theta`].
    pub fn theta0(&self) -> Theta {
        Theta { c_e: self.theta0[0], c_d: self.theta0[1], t_r: self.theta0[2], d: self.theta0[3] }
    }
}

/// The clock offset between the wheel and pose streams (`output.clock_offset`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum ClockOffset {
    /// Estimate it from the data and apply the estimate.
    #[default]
    Auto,
    /// A fixed offset, s, added to the pose stream's time.
    Seconds(f64),
}

impl Serialize for ClockOffset {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        match self {
            ClockOffset::Auto => s.serialize_str("auto"),
            ClockOffset::Seconds(v) => s.serialize_f64(*v),
        }
    }
}

impl<'de> Deserialize<'de> for ClockOffset {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> std::result::Result<Self, D::Error> {
        struct V;
        impl serde::de::Visitor<'_> for V {
            type Value = ClockOffset;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("\"auto\" or a number of seconds")
            }
            fn visit_str<E: serde::de::Error>(self, v: &str) -> std::result::Result<ClockOffset, E> {
                if v == "auto" {
                    Ok(ClockOffset::Auto)
                } else {
                    Err(E::custom(format!("expected \"auto\" or a number of seconds, found \"{v}\"")))
                }
            }
            fn visit_f64<E: serde::de::Error>(self, v: f64) -> std::result::Result<ClockOffset, E> {
                Ok(ClockOffset::Seconds(v))
            }
            fn visit_i64<E: serde::de::Error>(self, v: i64) -> std::result::Result<ClockOffset, E> {
                Ok(ClockOffset::Seconds(v as f64))
            }
            fn visit_u64<E: serde::de::Error>(self, v: u64) -> std::result::Result<ClockOffset, E> {
                Ok(ClockOffset::Seconds(v as f64))
            }
        }
        d.deserialize_any(V)
    }
}

/// Unit of a time column.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TimeUnit {
    /// Seconds.
    #[default]
    S,
    /// Milliseconds.
    Ms,
    /// Microseconds.
    Us,
    /// Nanoseconds.
    Ns,
}

impl TimeUnit {
    /// Seconds per unit.
    pub fn seconds(self) -> f64 {
        match self {
            TimeUnit::S => 1.0,
            TimeUnit::Ms => 1e-3,
            TimeUnit::Us => 1e-6,
            TimeUnit::Ns => 1e-9,
        }
    }
}

/// One recorded stream: where its rows come from ([`SourceSpec`], tagged by
/// `format`, CSV by default) and how to read its time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "RawStreamSpec", into = "RawStreamSpec")]
pub struct StreamSpec {
    /// The file and its format.
    pub source: SourceSpec,
    /// The time column. Required for CSV and Parquet; for MCAP, `None` uses
    /// the message time stamps the bag reader returns.
    pub time_column: Option<String>,
    /// Unit of the time column. Default `"s"`.
    pub time_unit: TimeUnit,
    /// Added to the stream's time (after the unit conversion), s. Default 0.
    pub time_offset_s: f64,
    /// The stream's nominal sample rate, Hz. When given, time-stamp jitter is
    /// removed: each sample gets an integer sample index (missing samples
    /// skip indices) and its stamp is replaced by a local least-squares fit
    /// `t = t0 + k·T` over `dejitter_window_s`. Give it only for streams that
    /// are sampled at a fixed rate and stamped on arrival (encoders).
    pub nominal_rate_hz: Option<f64>,
    /// Length of the local fit window for de-jittering, s. Default 2.
    pub dejitter_window_s: f64,
}

/// Where a stream's rows come from (`streams.<name>.format`, default `"csv"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "format", rename_all = "lowercase")]
pub enum SourceSpec {
    /// A CSV file with a header row (`format = "csv"`, the default).
    Csv {
        /// The file, relative to the manifest's folder.
        file: PathBuf,
    },
    /// One topic of a ROS 2 bag in MCAP (`format = "mcap"`, `topic = "/x"`,
    /// optional `time = "header" | "log"`). Columns are named as
    /// [`crate::io::bag`] names them (`position.<joint>`, `x`, `yaw`, `cov_x`, …).
    Mcap {
        /// The bag, relative to the manifest's folder.
        file: PathBuf,
        /// The topic.
        topic: String,
        /// Which message time becomes the stream's time. Default the header stamp.
        time: BagTime,
    },
    /// A Parquet table (`format = "parquet"`).
    Parquet {
        /// The file, relative to the manifest's folder.
        file: PathBuf,
    },
}

impl SourceSpec {
    /// The file, relative to the manifest's folder.
    pub fn file(&self) -> &Path {
        match self {
            SourceSpec::Csv { file } | SourceSpec::Mcap { file, .. } | SourceSpec::Parquet { file } => file,
        }
    }

    /// The `format` value.
    pub fn format(&self) -> &'static str {
        match self {
            SourceSpec::Csv { .. } => "csv",
            SourceSpec::Mcap { .. } => "mcap",
            SourceSpec::Parquet { .. } => "parquet",
        }
    }
}

/// Which time of a bag message a `format = "mcap"` stream uses
/// (`streams.<name>.time`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BagTime {
    /// `header.stamp` (when the data were measured, on the publisher's clock).
    #[default]
    Header,
    /// The MCAP log time (when the recorder received the message).
    Log,
}

/// The format of a stream as written in the manifest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
enum Format {
    #[default]
    Csv,
    Mcap,
    Parquet,
}

/// A stream table as written: flat keys, `format` defaulting to CSV.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawStreamSpec {
    #[serde(default)]
    format: Format,
    file: PathBuf,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    topic: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    time: Option<BagTime>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    time_column: Option<String>,
    #[serde(default)]
    time_unit: TimeUnit,
    #[serde(default)]
    time_offset_s: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    nominal_rate_hz: Option<f64>,
    #[serde(default = "default_dejitter_window")]
    dejitter_window_s: f64,
}

impl TryFrom<RawStreamSpec> for StreamSpec {
    type Error = String;

    fn try_from(r: RawStreamSpec) -> std::result::Result<Self, String> {
        let source = match (r.format, r.topic) {
            (Format::Csv, None) => SourceSpec::Csv { file: r.file },
            (Format::Parquet, None) => SourceSpec::Parquet { file: r.file },
            (Format::Mcap, Some(topic)) => SourceSpec::Mcap { file: r.file, topic, time: r.time.unwrap_or_default() },
            (Format::Mcap, None) => return Err("`topic` is required for format = \"mcap\"".into()),
            (f, Some(_)) => return Err(format!("`topic` is only for format = \"mcap\", not {f:?}").to_lowercase()),
        };
        let mcap = matches!(source, SourceSpec::Mcap { .. });
        if r.time_column.is_none() && !mcap {
            return Err(format!("`time_column` is required for format = \"{}\"", source.format()));
        }
        if r.time_column.is_some() && mcap {
            return Err("`time_column` is not for format = \"mcap\": bag messages carry their time; choose it with \
                        `time = \"header\"` (the default) or `time = \"log\"`"
                .into());
        }
        if r.time.is_some() && !mcap {
            return Err(format!(
                "`time` is only for format = \"mcap\"; format = \"{}\" takes `time_column`",
                source.format()
            ));
        }
        Ok(StreamSpec {
            source,
            time_column: r.time_column,
            time_unit: r.time_unit,
            time_offset_s: r.time_offset_s,
            nominal_rate_hz: r.nominal_rate_hz,
            dejitter_window_s: r.dejitter_window_s,
        })
    }
}

impl From<StreamSpec> for RawStreamSpec {
    fn from(s: StreamSpec) -> Self {
        let (format, file, topic, time) = match s.source {
            SourceSpec::Csv { file } => (Format::Csv, file, None, None),
            SourceSpec::Mcap { file, topic, time } => (Format::Mcap, file, Some(topic), Some(time)),
            SourceSpec::Parquet { file } => (Format::Parquet, file, None, None),
        };
        RawStreamSpec {
            format,
            file,
            topic,
            time,
            time_column: s.time_column,
            time_unit: s.time_unit,
            time_offset_s: s.time_offset_s,
            nominal_rate_hz: s.nominal_rate_hz,
            dejitter_window_s: s.dejitter_window_s,
        }
    }
}

fn default_dejitter_window() -> f64 {
    2.0
}

/// How the wheel rotation is recorded (`wheels.signal`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WheelSignal {
    /// Rotation speed, revolutions per second.
    RevPerS,
    /// Rotation speed, radians per second.
    RadPerS,
    /// Wheel speed, m/s, converted with `circumference_m` (a nominal value:
    /// the calibrated c_e is then metres per nominal revolution).
    MPerS,
    /// A cumulative (already unwrapped) tick count; `ticks_per_rev` ticks make
    /// one "revolution" of the model.
    TicksCumulative,
    /// A raw encoder counter that wraps around at `counter_bits` bits.
    TicksRaw,
    /// A cumulative wheel angle, rad (e.g. a ROS `JointState` position):
    /// revolutions = rad / 2π.
    RadCumulative,
}

/// The rear wheel rotation (`[wheels]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WheelSpec {
    /// The stream (name in `[streams]`) holding both wheel columns.
    pub stream: String,
    /// How the rotation is recorded.
    pub signal: WheelSignal,
    /// Nominal circumference for `m_per_s`, m.
    #[serde(default)]
    pub circumference_m: Option<f64>,
    /// Ticks per model revolution for `ticks_cumulative` / `ticks_raw`. The
    /// calibrated c_e is metres per `ticks_per_rev` ticks.
    #[serde(default)]
    pub ticks_per_rev: Option<f64>,
    /// Counter width for `ticks_raw`, bits (1..=64); differences are taken
    /// modulo 2^bits into the signed range.
    #[serde(default)]
    pub counter_bits: Option<u32>,
    /// Rear-left wheel.
    pub rear_left: WheelColumn,
    /// Rear-right wheel.
    pub rear_right: WheelColumn,
}

/// One wheel's column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WheelColumn {
    /// The column.
    pub column: String,
    /// +1 or −1: the sign that makes forward driving positive. Default +1.
    #[serde(default = "one")]
    pub sign: f64,
}

fn one() -> f64 {
    1.0
}

/// The reference pose (`[pose]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    /// The stream (name in `[streams]`) holding the pose columns.
    pub stream: String,
    /// Position columns.
    pub position: PositionSpec,
    /// Heading column; when absent the heading is derived from the track.
    #[serde(default)]
    pub heading: Option<HeadingSpec>,
    /// Below this speed the derived heading is held, m/s. Default 1.
    #[serde(default = "one")]
    pub derive_heading_min_speed_m_per_s: f64,
    /// Quality column and its accepted values; samples with other values
    /// split the drive.
    #[serde(default)]
    pub quality: Option<QualitySpec>,
}

/// Position columns (`[pose.position]`, tagged by `kind`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum PositionSpec {
    /// Local metric x (east) / y (north) columns, m.
    Local {
        /// x column, m.
        x: String,
        /// y column, m.
        y: String,
    },
    /// WGS84 latitude / longitude, degrees, converted to a local ENU frame
    /// (geodetic → ECEF → ENU).
    LatLon {
        /// Latitude column, deg.
        lat: String,
        /// Longitude column, deg.
        lon: String,
        /// Ellipsoidal height column, m (optional; 0 when absent).
        #[serde(default)]
        alt: Option<String>,
        /// ENU origin `[lat_deg, lon_deg, h_m]`; default the first accepted sample.
        #[serde(default)]
        origin: Option<[f64; 3]>,
    },
}

/// Heading convention.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum HeadingConvention {
    /// ENU: counter-clockwise from east (the model's convention).
    Enu,
    /// NED: clockwise from north (compass).
    Ned,
}

/// Angle unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum AngleUnit {
    /// Radians.
    #[default]
    Rad,
    /// Degrees.
    Deg,
}

impl AngleUnit {
    /// Radians per unit.
    pub fn radians(self) -> f64 {
        match self {
            AngleUnit::Rad => 1.0,
            AngleUnit::Deg => std::f64::consts::PI / 180.0,
        }
    }
}

/// Heading column (`[pose.heading]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadingSpec {
    /// The column.
    pub column: String,
    /// Convention.
    pub convention: HeadingConvention,
    /// Unit. Default `"rad"`.
    #[serde(default)]
    pub unit: AngleUnit,
}

/// Pose quality (`[pose.quality]`): a sample is accepted when its value is
/// one of `accept` (when given) and within `min`..=`max` (when given); at
/// least one of them is required.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QualitySpec {
    /// The column.
    pub column: String,
    /// Accepted values (e.g. `[6]` for RTK fixed). Default: any value.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub accept: Vec<f64>,
    /// Largest accepted value (e.g. `max = 0.01` on a covariance `cov_x`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<f64>,
    /// Smallest accepted value (e.g. `min = 2` on a NavSatFix `status`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<f64>,
}

impl QualitySpec {
    /// True when `v` passes every test given (NaN passes none).
    pub fn accepts(&self, v: f64) -> bool {
        (self.accept.is_empty() || self.accept.iter().any(|a| (a - v).abs() < 1e-9))
            && self.max.is_none_or(|max| v <= max)
            && self.min.is_none_or(|min| v >= min)
            && !v.is_nan()
    }

    /// The manifest key naming the test(s), for messages.
    pub(crate) fn key(&self) -> &'static str {
        match (self.accept.is_empty(), self.max.is_some() || self.min.is_some()) {
            (false, false) => "pose.quality.accept",
            (true, _) => "pose.quality.max",
            (false, true) => "pose.quality",
        }
    }
}

/// Lateral acceleration source (`[lateral_acceleration]`, tagged by `source`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "snake_case", deny_unknown_fields)]
pub enum LateralAccelerationSpec {
    /// An IMU column, m/s² (its interval mean over each output step).
    Imu {
        /// The stream.
        stream: String,
        /// The column (the vehicle's lateral axis).
        column: String,
        /// +1 when the column is positive to the left, −1 when to the right.
        #[serde(default = "one")]
        sign: f64,
    },
    /// a_y = v·ω of the model at θ_0 (`output.theta0`) from the wheels.
    FromWheels {
        /// Centred moving-average window, s. Default 0 (none).
        #[serde(default)]
        smoothing_s: f64,
        /// The road bank (`[lateral_acceleration.bank]`): subtract the
        /// lateral gravity component measured by two antennas. Default none.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        bank: Option<Box<BankSpec>>,
    },
    /// a_y = speed × yaw rate of the reference pose, smoothed. Feeds the
    /// reference yaw rate into the model through d: see the module docs.
    FromPose {
        /// Centred moving-average window, s. Default 0.5.
        #[serde(default = "half")]
        smoothing_s: f64,
        /// The road bank, as for `from_wheels`. Default none.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        bank: Option<Box<BankSpec>>,
    },
}

impl LateralAccelerationSpec {
    /// The road-bank correction of a derived a_y, when asked for.
    pub fn bank(&self) -> Option<&BankSpec> {
        match self {
            LateralAccelerationSpec::FromWheels { bank, .. } | LateralAccelerationSpec::FromPose { bank, .. } => {
                bank.as_deref()
            }
            LateralAccelerationSpec::Imu { .. } => None,
        }
    }
}

/// The road bank (`[lateral_acceleration.bank]`): a derived a_y is the
/// *kinematic* acceleration v·ω, but the load transfer of SPEC (3a,b)
/// follows the lateral *specific force* in the vehicle frame,
/// f_y = a_y·cos φ − g·sin φ on a road rolled by φ (positive when the
/// left side is lower). The roll φ is measured by two GNSS antennas across
/// the vehicle: sin φ = (h_right − h_left + `height_offset_m`) /
/// `baseline_m`, from their altitudes at the times where both have an
/// accepted quality (the right antenna interpolated linearly to the left
/// one's stamps across at most `output.max_gap_s`), on the GNSS clock like
/// the pose (the pose's clock offset is applied to it), interpolated to the
/// output grid and smoothed with a centred moving average over
/// `smoothing_s`. Output samples farther than `output.max_gap_s` from a
/// roll measurement are invalid (they split the drive like a pose gap).
///
/// ```toml
/// [lateral_acceleration.bank]
/// left = "gnss_left"          # streams of the left and right antennas
/// right = "gnss_right"
/// lat = "lat_deg"             # columns in both (WGS84 degrees, metres)
/// lon = "lon_deg"
/// alt = "alt_m"
/// quality = { column = "fix_mode", accept = [6] }  # optional
/// baseline_m = 1.485          # antenna separation, m (> 0)
/// height_offset_m = 0.0       # left minus right antenna height on level ground, m (default 0)
/// smoothing_s = 1.0           # centred moving average of φ, s (default 1)
/// max_roll_deg = 20.0         # larger |φ| is a glitch or a wrong column (default 20)
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BankSpec {
    /// The stream (name in `[streams]`) of the left antenna.
    pub left: String,
    /// The stream of the right antenna.
    pub right: String,
    /// Latitude column (both streams), WGS84 degrees.
    pub lat: String,
    /// Longitude column (both streams), WGS84 degrees.
    pub lon: String,
    /// Altitude column (both streams), m.
    pub alt: String,
    /// Quality column (both streams) and its accepted values. Default: every sample.
    #[serde(default)]
    pub quality: Option<QualitySpec>,
    /// Distance between the antennas, m; their measured separation must
    /// agree within [`BankSpec::BASELINE_TOLERANCE`].
    pub baseline_m: f64,
    /// Height of the left antenna above the right one on level ground, m. Default 0.
    #[serde(default)]
    pub height_offset_m: f64,
    /// Centred moving-average window of the roll on the output grid, s. Default 1.
    #[serde(default = "one")]
    pub smoothing_s: f64,
    /// Largest plausible |roll|, degrees (roads are banked by a few degrees;
    /// ramps and test tracks by up to ~10–15). A few samples beyond it are
    /// dropped as glitches (a warning), more than 1 % is an error. Default 20.
    #[serde(default = "default_max_roll_deg")]
    pub max_roll_deg: f64,
}

impl BankSpec {
    /// Largest relative disagreement between the median measured antenna
    /// separation and `baseline_m` (a wrong stream, column or baseline).
    pub const BASELINE_TOLERANCE: f64 = 0.1;
    /// Upper bound of `max_roll_deg`.
    pub const MAX_ROLL_LIMIT_DEG: f64 = 45.0;
}

fn default_max_roll_deg() -> f64 {
    20.0
}

fn half() -> f64 {
    0.5
}

impl Default for LateralAccelerationSpec {
    fn default() -> Self {
        LateralAccelerationSpec::FromWheels { smoothing_s: 0.0, bank: None }
    }
}

/// Sideslip source (`[sideslip]`, tagged by `source`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "snake_case", deny_unknown_fields)]
pub enum SideslipSpec {
    /// β = 0.
    #[default]
    Zero,
    /// A sideslip column.
    Column {
        /// The stream.
        stream: String,
        /// The column.
        column: String,
        /// Unit. Default `"rad"`.
        #[serde(default)]
        unit: AngleUnit,
        /// +1 when positive means the velocity points left of the heading.
        #[serde(default = "one")]
        sign: f64,
    },
}

impl Manifest {
    /// Reads and checks a manifest file.
    pub fn from_path(path: &Path) -> Result<Manifest> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses and checks manifest text; `path` locates the stream files and
    /// names the manifest in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Manifest> {
        let err = |reason: String| Error::Manifest { path: path.to_path_buf(), reason };
        let de = toml::de::Deserializer::parse(text).map_err(|e| err(toml_message(&e, text, None)))?;
        let mut m: Manifest = serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            err(toml_message(e.inner(), text, Some(key)))
        })?;
        m.path = path.to_path_buf();
        // The deserializer left byte offsets.
        let line_of = |at: usize| text.get(..at).unwrap_or(text).matches('\n').count() + 1;
        if let Some(n) = &mut m.noise {
            n.line = n.line.map(line_of);
        }
        if let Some(c) = &mut m.calibration {
            c.lines.values_mut().for_each(|at| *at = line_of(*at));
        }
        m.check()?;
        Ok(m)
    }

    /// The manifest error for `key`.
    pub(crate) fn error(&self, key: &str, reason: impl std::fmt::Display) -> Error {
        Error::Manifest { path: self.path.clone(), reason: format!("{key}: {reason}") }
    }

    /// The folder stream files are relative to.
    pub fn base_dir(&self) -> PathBuf {
        self.path.parent().map(Path::to_path_buf).unwrap_or_default()
    }

    /// Checks values and cross references, naming the key.
    pub fn check(&self) -> Result<()> {
        let o = &self.output;
        let positive = |key: &str, v: f64| -> Result<()> {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                Err(self.error(key, format!("must be a positive number, found {v}")))
            }
        };
        let at_most = |key: &str, v: f64, max: f64, why: &str| -> Result<()> {
            if v <= max {
                Ok(())
            } else {
                Err(self.error(key, format!("{} is above the limit of {max}; {why}", echo_num(v))))
            }
        };
        positive("output.rate_hz", o.rate_hz)?;
        at_most(
            "output.rate_hz",
            o.rate_hz,
            limits::MAX_OUTPUT_RATE_HZ,
            "the model runs at tens of Hz (40 in the paper)",
        )?;
        if o.rate_hz < limits::MIN_OUTPUT_RATE_HZ {
            return Err(self.error(
                "output.rate_hz",
                format!(
                    "{} Hz is below {} Hz: give the rate in Hz, not the step",
                    o.rate_hz,
                    limits::MIN_OUTPUT_RATE_HZ
                ),
            ));
        }
        positive("output.max_gap_s", o.max_gap_s)?;
        positive("output.max_clock_offset_s", o.max_clock_offset_s)?;
        at_most(
            "output.max_clock_offset_s",
            o.max_clock_offset_s,
            limits::MAX_CLOCK_OFFSET_S,
            "clocks further apart mean a wrong time_column, time_unit or time_offset_s: fix those instead",
        )?;
        positive("limits.max_speed_m_per_s", self.limits.max_speed_m_per_s)?;
        positive("limits.max_lateral_acceleration_m_per_s2", self.limits.max_lateral_acceleration_m_per_s2)?;
        if !non_negative(o.min_part_s) {
            return Err(self.error("output.min_part_s", format!("must be >= 0, found {}", o.min_part_s)));
        }
        if let ClockOffset::Seconds(v) = o.clock_offset {
            if !v.is_finite() {
                return Err(self.error("output.clock_offset", "must be \"auto\" or a finite number of seconds"));
            }
        }
        o.theta0().validate().map_err(|e| self.error("output.theta0", e))?;
        if self.streams.is_empty() {
            return Err(self.error("streams", "no streams given"));
        }
        for (name, s) in &self.streams {
            if let Some(r) = s.nominal_rate_hz {
                let key = format!("streams.{name}.nominal_rate_hz");
                positive(&key, r)?;
                at_most(&key, r, limits::MAX_NOMINAL_RATE_HZ, "give the sensor's sample rate in Hz")?;
            }
            let key = format!("streams.{name}.dejitter_window_s");
            positive(&key, s.dejitter_window_s)?;
            at_most(&key, s.dejitter_window_s, limits::MAX_DEJITTER_WINDOW_S, "a few seconds follow clock drift")?;
            if let Some(r) = s.nominal_rate_hz {
                let half = s.dejitter_window_s * r / 2.0;
                if half > limits::MAX_DEJITTER_HALF_WINDOW as f64 {
                    return Err(self.error(
                        &key,
                        format!(
                            "{} s at nominal_rate_hz = {r} is {} samples each side, above the limit of {}; \
                             shorten the window",
                            s.dejitter_window_s,
                            echo_num(half.round()),
                            limits::MAX_DEJITTER_HALF_WINDOW
                        ),
                    ));
                }
            }
            if !s.time_offset_s.is_finite() {
                return Err(self.error(&format!("streams.{name}.time_offset_s"), "must be finite"));
            }
        }
        let stream_ref = |key: &str, name: &str| -> Result<()> {
            if self.streams.contains_key(name) {
                Ok(())
            } else {
                let known: Vec<&str> = self.streams.keys().map(String::as_str).collect();
                Err(self.error(key, format!("no stream named '{name}' (streams: {})", known.join(", "))))
            }
        };
        let sign = |key: &str, v: f64| -> Result<()> {
            if (v.abs() - 1.0).abs() < f64::EPSILON {
                Ok(())
            } else {
                Err(self.error(key, format!("must be 1 or -1, found {v}")))
            }
        };
        let w = &self.wheels;
        stream_ref("wheels.stream", &w.stream)?;
        sign("wheels.rear_left.sign", w.rear_left.sign)?;
        sign("wheels.rear_right.sign", w.rear_right.sign)?;
        match w.signal {
            WheelSignal::MPerS => match w.circumference_m {
                Some(c) => positive("wheels.circumference_m", c)?,
                None => return Err(self.error("wheels.circumference_m", "required for signal = \"m_per_s\"")),
            },
            WheelSignal::TicksCumulative | WheelSignal::TicksRaw => match w.ticks_per_rev {
                Some(c) => positive("wheels.ticks_per_rev", c)?,
                None => return Err(self.error("wheels.ticks_per_rev", "required for tick signals")),
            },
            WheelSignal::RevPerS | WheelSignal::RadPerS | WheelSignal::RadCumulative => {}
        }
        if w.signal == WheelSignal::TicksRaw {
            match w.counter_bits {
                Some(b) if (1..=64).contains(&b) => {}
                Some(b) => return Err(self.error("wheels.counter_bits", format!("must be 1..=64, found {b}"))),
                None => return Err(self.error("wheels.counter_bits", "required for signal = \"ticks_raw\"")),
            }
        }
        stream_ref("pose.stream", &self.pose.stream)?;
        if !non_negative(self.pose.derive_heading_min_speed_m_per_s) {
            return Err(self.error("pose.derive_heading_min_speed_m_per_s", "must be >= 0"));
        }
        if let PositionSpec::LatLon { origin: Some(o), .. } = &self.pose.position {
            if !(o[0].abs() <= 90.0 && o[1].abs() <= 360.0 && o[2].is_finite()) {
                return Err(self.error("pose.position.origin", "expected [lat_deg, lon_deg, h_m]"));
            }
        }
        if let Some(q) = &self.pose.quality {
            if q.accept.is_empty() && q.max.is_none() && q.min.is_none() {
                return Err(self.error(
                    "pose.quality.accept",
                    "no accepted values given (give `accept = [...]`, a threshold `max = ...` / `min = ...`, or both)",
                ));
            }
            for (key, v) in [("pose.quality.max", q.max), ("pose.quality.min", q.min)] {
                if v.is_some_and(|v| !v.is_finite()) {
                    return Err(self.error(key, "must be a finite number"));
                }
            }
        }
        match &self.lateral_acceleration {
            LateralAccelerationSpec::Imu { stream, sign: s, .. } => {
                stream_ref("lateral_acceleration.stream", stream)?;
                sign("lateral_acceleration.sign", *s)?;
            }
            LateralAccelerationSpec::FromWheels { smoothing_s, bank }
            | LateralAccelerationSpec::FromPose { smoothing_s, bank } => {
                if !non_negative(*smoothing_s) {
                    return Err(self.error("lateral_acceleration.smoothing_s", "must be >= 0"));
                }
                if let Some(b) = bank {
                    self.check_bank(b, &stream_ref, &positive)?;
                }
            }
        }
        if let SideslipSpec::Column { stream, sign: s, .. } = &self.sideslip {
            stream_ref("sideslip.stream", stream)?;
            sign("sideslip.sign", *s)?;
        }
        if let Some(r) = &self.reference {
            r.check().map_err(|(key, reason)| self.error(key, reason))?;
        }
        Ok(())
    }
}

impl Manifest {
    /// Checks `[lateral_acceleration.bank]`.
    fn check_bank(
        &self,
        b: &BankSpec,
        stream_ref: &dyn Fn(&str, &str) -> Result<()>,
        positive: &dyn Fn(&str, f64) -> Result<()>,
    ) -> Result<()> {
        const K: &str = "lateral_acceleration.bank";
        stream_ref(&format!("{K}.left"), &b.left)?;
        stream_ref(&format!("{K}.right"), &b.right)?;
        if b.left == b.right {
            return Err(self.error(
                &format!("{K}.right"),
                format!("the right antenna's stream is the left one's ('{}'): two antennas are needed", b.left),
            ));
        }
        positive(&format!("{K}.baseline_m"), b.baseline_m)?;
        if !(b.height_offset_m.is_finite() && b.height_offset_m.abs() < b.baseline_m) {
            return Err(self.error(
                &format!("{K}.height_offset_m"),
                format!(
                    "must be a finite number of metres smaller in size than baseline_m = {}, found {}",
                    b.baseline_m,
                    echo_num(b.height_offset_m)
                ),
            ));
        }
        if !(non_negative(b.smoothing_s) && b.smoothing_s.is_finite()) {
            return Err(self.error(&format!("{K}.smoothing_s"), format!("must be >= 0, found {}", b.smoothing_s)));
        }
        if !(b.max_roll_deg > 0.0 && b.max_roll_deg <= BankSpec::MAX_ROLL_LIMIT_DEG) {
            return Err(self.error(
                &format!("{K}.max_roll_deg"),
                format!("must be in (0, {}] degrees, found {}", BankSpec::MAX_ROLL_LIMIT_DEG, echo_num(b.max_roll_deg)),
            ));
        }
        if let Some(q) = &b.quality {
            if q.accept.is_empty() && q.max.is_none() && q.min.is_none() {
                return Err(self.error(&format!("{K}.quality.accept"), "no accepted values given"));
            }
        }
        Ok(())
    }
}

/// `v ≥ 0` (false for NaN).
fn non_negative(v: f64) -> bool {
    v >= 0.0
}

/// A one-line message for a TOML error: `key: message (line L)`.
fn toml_message(e: &toml::de::Error, text: &str, key: Option<String>) -> String {
    let mut msg = e.message().trim().to_string();
    let mut key = key.filter(|k| !k.is_empty() && k != ".");
    // "missing field `file`" → name the missing key itself.
    if let Some(rest) = msg.strip_prefix("missing field `") {
        if let Some(field) = rest.split('`').next() {
            key = Some(match key {
                Some(k) => format!("{k}.{field}"),
                None => field.to_string(),
            });
            msg = "missing (required)".to_string();
        }
    }
    let line = e.span().map(|s| text.get(..s.start).unwrap_or(text).matches('\n').count() + 1);
    let at = line.map(|l| format!(" (line {l})")).unwrap_or_default();
    match key {
        Some(k) => format!("{k}: {msg}{at}"),
        None => format!("{msg}{at}"),
    }
}
