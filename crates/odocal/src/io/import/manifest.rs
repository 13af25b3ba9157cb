//! The drive manifest: which file each signal comes from, in which unit and
//! convention. A program reads one with [`Manifest::from_path`] (or
//! [`Manifest::parse`] for text it built or edited) and hands it to
//! [`crate::import`]; the TOML format, documented in docs/reference.md, is
//! the interface, and the types behind it are the crate's own.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::settings::{CalibrationTable, NoiseTable, ReferenceSpec};
use crate::error::{Error, Result};
use crate::model::Theta;

mod check;

/// A drive manifest (TOML): the streams of one recorded drive and where each
/// model signal comes from. The format, with a full example, is in
/// docs/reference.md.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// The manifest file itself; stream files are relative to its folder.
    /// Set by [`Manifest::from_path`] / [`Manifest::parse`], not read from TOML.
    #[serde(skip)]
    pub path: PathBuf,
    /// Output rate, gaps, clock offset. All fields have defaults.
    #[serde(default)]
    pub(crate) output: OutputSpec,
    /// The recorded streams (files), by name. Signals refer to these names.
    pub(crate) streams: BTreeMap<String, StreamSpec>,
    /// Rear wheel rotation.
    pub(crate) wheels: WheelSpec,
    /// Reference pose.
    pub(crate) pose: PoseSpec,
    /// Lateral acceleration a_y. Default: derived from the wheels.
    #[serde(default)]
    pub(crate) lateral_acceleration: LateralAccelerationSpec,
    /// Sideslip β. Default: zero.
    #[serde(default)]
    pub(crate) sideslip: SideslipSpec,
    /// Physical limits the imported signals must respect. All fields have
    /// defaults; raise them for a vehicle that really exceeds them.
    #[serde(default)]
    pub(crate) limits: LimitsSpec,
    /// The sensor's noise (`[noise]`): the starting noise model of
    /// `--method eiv` as written, read by the calibration like a
    /// `--noise-model` file (`settings::ManifestSettings` reads it).
    #[serde(default, deserialize_with = "super::settings::noise_table", skip_serializing_if = "Option::is_none")]
    pub(crate) noise: Option<NoiseTable>,
    /// The reference sensor's extrinsics (`[reference]`): lever arm,
    /// heading offset and which of them to estimate.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference: Option<ReferenceSpec>,
    /// Calibration settings (`[calibration]`) as written, read by the
    /// calibration (`settings::ManifestSettings`).
    #[serde(default, deserialize_with = "super::settings::calibration_table", skip_serializing_if = "Option::is_none")]
    pub(crate) calibration: Option<CalibrationTable>,
}

/// Physical limits (`[limits]`): an imported signal beyond one is an error
/// naming the time, because it means a wrong unit, sign, column or a
/// corrupt sample rather than a real motion.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct LimitsSpec {
    /// Largest plausible vehicle speed, m/s: each wheel's speed at θ_0 and
    /// the reference pose's speed between samples. Default 100 (360 km/h).
    pub(crate) max_speed_m_per_s: f64,
    /// Largest plausible |a_y|, m/s² (a_y from the wheels, the pose or an
    /// IMU). Default 15 (about 1.5 g; racing cars reach 3–5 g).
    pub(crate) max_lateral_acceleration_m_per_s2: f64,
}

impl Default for LimitsSpec {
    fn default() -> Self {
        LimitsSpec { max_speed_m_per_s: 100.0, max_lateral_acceleration_m_per_s2: 15.0 }
    }
}

/// Output settings (`[output]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub(crate) struct OutputSpec {
    /// Output sample rate, Hz. Default 40 (t_s = 0.025 s, as in the paper).
    pub(crate) rate_hz: f64,
    /// A stream gap longer than this splits the drive into parts, s. Default 0.5.
    pub(crate) max_gap_s: f64,
    /// Parts shorter than this are dropped (and reported), s. Default 30.
    pub(crate) min_part_s: f64,
    /// Offset added to the pose stream's time to put it on the wheel clock:
    /// `"auto"` (estimate by cross-correlating speeds, and apply) or seconds.
    /// Default `"auto"`.
    pub(crate) clock_offset: ClockOffset,
    /// The offset search range for `"auto"`, ± seconds. Default 2.
    pub(crate) max_clock_offset_s: f64,
    /// θ_0 = `[c_e, c_d, t_r, d]` (SI) used to turn wheel rotation into speed
    /// and yaw rate where the import needs them (clock offset, a_y
    /// `from_wheels`). Default the paper's `[2.0, 0, 1.6, 0]`.
    #[serde(deserialize_with = "crate::io::exact::theta")]
    pub(crate) theta0: [f64; 4],
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
    pub(crate) fn theta0(&self) -> Theta {
        Theta { c_e: self.theta0[0], c_d: self.theta0[1], t_r: self.theta0[2], d: self.theta0[3] }
    }
}

/// The clock offset between the wheel and pose streams (`output.clock_offset`).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) enum ClockOffset {
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
pub(crate) enum TimeUnit {
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
    /// The unit as a manifest writes it (`"ms"`).
    pub(crate) fn name(self) -> &'static str {
        match self {
            TimeUnit::S => "s",
            TimeUnit::Ms => "ms",
            TimeUnit::Us => "us",
            TimeUnit::Ns => "ns",
        }
    }

    /// Seconds per unit.
    pub(crate) fn seconds(self) -> f64 {
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
pub(crate) struct StreamSpec {
    /// The file and its format.
    pub(crate) source: SourceSpec,
    /// The time column. Required for CSV and Parquet; for MCAP, `None` uses
    /// the message time stamps the bag reader returns.
    pub(crate) time_column: Option<String>,
    /// Unit of the time column. Default `"s"`.
    pub(crate) time_unit: TimeUnit,
    /// Added to the stream's time (after the unit conversion), s. Default 0.
    pub(crate) time_offset_s: f64,
    /// The stream's nominal sample rate, Hz. When given, time-stamp jitter is
    /// removed: each sample gets an integer sample index (missing samples
    /// skip indices) and its stamp is replaced by a local least-squares fit
    /// `t = t0 + k·T` over `dejitter_window_s`. Give it only for streams that
    /// are sampled at a fixed rate and stamped on arrival (encoders).
    pub(crate) nominal_rate_hz: Option<f64>,
    /// Length of the local fit window for de-jittering, s. Default 2.
    pub(crate) dejitter_window_s: f64,
}

/// Where a stream's rows come from (`streams.<name>.format`, default `"csv"`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "format", rename_all = "lowercase")]
pub(crate) enum SourceSpec {
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
    pub(crate) fn file(&self) -> &Path {
        match self {
            SourceSpec::Csv { file } | SourceSpec::Mcap { file, .. } | SourceSpec::Parquet { file } => file,
        }
    }

    /// The `format` value.
    pub(crate) fn format(&self) -> &'static str {
        match self {
            SourceSpec::Csv { .. } => "csv",
            SourceSpec::Mcap { .. } => "mcap",
            SourceSpec::Parquet { .. } => "parquet",
        }
    }

    /// The kind of source in words, with its article ("an MCAP"), for messages.
    pub(crate) fn kind(&self) -> &'static str {
        match self {
            SourceSpec::Csv { .. } => "a CSV",
            SourceSpec::Mcap { .. } => "an MCAP",
            SourceSpec::Parquet { .. } => "a Parquet",
        }
    }
}

/// Which time of a bag message a `format = "mcap"` stream uses
/// (`streams.<name>.time`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum BagTime {
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
pub(crate) enum WheelSignal {
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
pub(crate) struct WheelSpec {
    /// The stream (name in `[streams]`) holding both wheel columns.
    pub(crate) stream: String,
    /// How the rotation is recorded.
    pub(crate) signal: WheelSignal,
    /// Nominal circumference for `m_per_s`, m.
    #[serde(default)]
    pub(crate) circumference_m: Option<f64>,
    /// Ticks per model revolution for `ticks_cumulative` / `ticks_raw`. The
    /// calibrated c_e is metres per `ticks_per_rev` ticks.
    #[serde(default)]
    pub(crate) ticks_per_rev: Option<f64>,
    /// Counter width for `ticks_raw`, bits (1..=64); differences are taken
    /// modulo 2^bits into the signed range.
    #[serde(default)]
    pub(crate) counter_bits: Option<u32>,
    /// Rear-left wheel.
    pub(crate) rear_left: WheelColumn,
    /// Rear-right wheel.
    pub(crate) rear_right: WheelColumn,
}

/// One wheel's column.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct WheelColumn {
    /// The column.
    pub(crate) column: String,
    /// +1 or −1: the sign that makes forward driving positive. Default +1.
    #[serde(default = "one")]
    pub(crate) sign: f64,
}

fn one() -> f64 {
    1.0
}

/// The reference pose (`[pose]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PoseSpec {
    /// The stream (name in `[streams]`) holding the pose columns.
    pub(crate) stream: String,
    /// Position columns.
    pub(crate) position: PositionSpec,
    /// Heading column; when absent the heading is derived from the track.
    #[serde(default)]
    pub(crate) heading: Option<HeadingSpec>,
    /// Below this speed the derived heading is held, m/s. Default 1.
    #[serde(default = "one")]
    pub(crate) derive_heading_min_speed_m_per_s: f64,
    /// The derived heading is the direction of the chord from half this
    /// distance of travel behind each pose sample to as far ahead, m.
    /// Default [`DEFAULT_DERIVE_HEADING_BASELINE_M`].
    #[serde(default = "default_derive_heading_baseline_m")]
    pub(crate) derive_heading_baseline_m: f64,
    /// Quality column and its accepted values; samples with other values
    /// split the drive.
    #[serde(default)]
    pub(crate) quality: Option<QualitySpec>,
}

/// The default `pose.derive_heading_baseline_m`, m: a chord of 2 m keeps
/// the derived heading of the shipped drives (10–20 Hz poses at 5–30 m/s,
/// steps of 0.5–3 m) that of consecutive steps or closer to their heading
/// column, and holds 1–3 cm of position noise to about a degree at
/// walking speeds.
pub(crate) const DEFAULT_DERIVE_HEADING_BASELINE_M: f64 = 2.0;

fn default_derive_heading_baseline_m() -> f64 {
    DEFAULT_DERIVE_HEADING_BASELINE_M
}

/// Position columns (`[pose.position]`, tagged by `kind`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub(crate) enum PositionSpec {
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
        #[serde(default, deserialize_with = "crate::io::exact::origin")]
        origin: Option<[f64; 3]>,
    },
}

/// Heading convention.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum HeadingConvention {
    /// ENU: counter-clockwise from east (the model's convention).
    Enu,
    /// NED: clockwise from north (compass).
    Ned,
}

/// Angle unit.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub(crate) enum AngleUnit {
    /// Radians.
    #[default]
    Rad,
    /// Degrees.
    Deg,
}

impl AngleUnit {
    /// Radians per unit.
    pub(crate) fn radians(self) -> f64 {
        match self {
            AngleUnit::Rad => 1.0,
            AngleUnit::Deg => std::f64::consts::PI / 180.0,
        }
    }
}

/// Heading column (`[pose.heading]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct HeadingSpec {
    /// The column.
    pub(crate) column: String,
    /// Convention.
    pub(crate) convention: HeadingConvention,
    /// Unit. Default `"rad"`.
    #[serde(default)]
    pub(crate) unit: AngleUnit,
}

/// Pose quality (`[pose.quality]`): a sample is accepted when its value is
/// one of `accept` (when given) and within `min`..=`max` (when given); at
/// least one of them is required.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct QualitySpec {
    /// The column.
    pub(crate) column: String,
    /// Accepted values (e.g. `[6]` for RTK fixed). Default: any value.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub(crate) accept: Vec<f64>,
    /// Largest accepted value (e.g. `max = 0.01` on a covariance `cov_x`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) max: Option<f64>,
    /// Smallest accepted value (e.g. `min = 2` on a NavSatFix `status`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(crate) min: Option<f64>,
}

impl QualitySpec {
    /// True when `v` passes every test given (NaN passes none).
    pub(crate) fn accepts(&self, v: f64) -> bool {
        (self.accept.is_empty() || self.accept.iter().any(|a| (a - v).abs() < 1e-9))
            && self.max.is_none_or(|max| v <= max)
            && self.min.is_none_or(|min| v >= min)
            && !v.is_nan()
    }

    /// The manifest key naming the test(s), for messages: the one test
    /// given, or the table when several are.
    pub(crate) fn key(&self) -> &'static str {
        match (!self.accept.is_empty(), self.max.is_some(), self.min.is_some()) {
            (true, false, false) => "pose.quality.accept",
            (false, true, false) => "pose.quality.max",
            (false, false, true) => "pose.quality.min",
            _ => "pose.quality",
        }
    }
}

/// Lateral acceleration source (`[lateral_acceleration]`, tagged by `source`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "snake_case", deny_unknown_fields)]
pub(crate) enum LateralAccelerationSpec {
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
    pub(crate) fn bank(&self) -> Option<&BankSpec> {
        match self {
            LateralAccelerationSpec::FromWheels { bank, .. } | LateralAccelerationSpec::FromPose { bank, .. } => {
                bank.as_deref()
            }
            LateralAccelerationSpec::Imu { .. } => None,
        }
    }
}

/// The road bank (`[lateral_acceleration.bank]`): a derived a_y is the
/// *kinematic* acceleration v·ω, but the load transfer of docs/method.md (3a,b)
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
pub(crate) struct BankSpec {
    /// The stream (name in `[streams]`) of the left antenna.
    pub(crate) left: String,
    /// The stream of the right antenna.
    pub(crate) right: String,
    /// Latitude column (both streams), WGS84 degrees.
    pub(crate) lat: String,
    /// Longitude column (both streams), WGS84 degrees.
    pub(crate) lon: String,
    /// Altitude column (both streams), m.
    pub(crate) alt: String,
    /// Quality column (both streams) and its accepted values. Default: every sample.
    #[serde(default)]
    pub(crate) quality: Option<QualitySpec>,
    /// Distance between the antennas, m; their measured separation must
    /// agree within `BankSpec::BASELINE_TOLERANCE`.
    pub(crate) baseline_m: f64,
    /// Height of the left antenna above the right one on level ground, m. Default 0.
    #[serde(default)]
    pub(crate) height_offset_m: f64,
    /// Centred moving-average window of the roll on the output grid, s. Default 1.
    #[serde(default = "one")]
    pub(crate) smoothing_s: f64,
    /// Largest plausible |roll|, degrees (roads are banked by a few degrees;
    /// ramps and test tracks by up to ~10–15). A few samples beyond it are
    /// dropped as glitches (a warning), more than 1 % is an error. Default 20.
    #[serde(default = "default_max_roll_deg")]
    pub(crate) max_roll_deg: f64,
}

impl BankSpec {
    /// Largest relative disagreement between the median measured antenna
    /// separation and `baseline_m` (a wrong stream, column or baseline).
    pub(crate) const BASELINE_TOLERANCE: f64 = 0.1;
    /// Largest `baseline_m`: two antennas on one vehicle, a few metres apart.
    pub(crate) const MAX_BASELINE_M: f64 = 20.0;
    /// Upper bound of `max_roll_deg`.
    pub(crate) const MAX_ROLL_LIMIT_DEG: f64 = 45.0;
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
pub(crate) enum SideslipSpec {
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

/// What a CSV file given where a manifest belongs is, and what to do.
const CSV_NOT_MANIFEST: &str = "a CSV file, not a drive manifest (TOML): a drive CSV needs no import (calibrate, \
     validate and compensate take it as it is; Python: Drive.from_csv or Drive.load); a stream's CSV file is named \
     by a manifest's [streams.NAME] table (docs/guide.md, \"A multi-stream log: the manifest\")";

/// Whether text that is not TOML starts with a CSV header row: its first
/// line that is not blank holds commas, no `=` and is no table header or
/// comment.
fn looks_like_csv(text: &str) -> bool {
    let first = text.trim_start_matches('\u{feff}').lines().map(str::trim).find(|l| !l.is_empty());
    first.is_some_and(|l| l.contains(',') && !l.contains('=') && !l.starts_with('[') && !l.starts_with('#'))
}

impl Manifest {
    /// Reads and checks a manifest file.
    pub fn from_path(path: impl AsRef<Path>) -> Result<Manifest> {
        let path = path.as_ref();
        let csv_name = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("csv"));
        if csv_name {
            return Err(Error::Manifest { path: path.to_path_buf(), reason: CSV_NOT_MANIFEST.into() });
        }
        let text =
            crate::output::limited::read_text_limited(path, crate::output::limited::MAX_SETTINGS_BYTES, "a manifest")
                .map_err(|source| Error::Io { path: path.to_path_buf(), source })?;
        Self::parse(&text, path)
    }

    /// Parses and checks manifest text; `path` locates the stream files and
    /// names the manifest in errors.
    pub fn parse(text: &str, path: &Path) -> Result<Manifest> {
        let err = |reason: String| Error::Manifest { path: path.to_path_buf(), reason };
        let de = toml::de::Deserializer::parse(text).map_err(|e| {
            if looks_like_csv(text) {
                err(CSV_NOT_MANIFEST.into())
            } else {
                err(toml_message(&e, text, None))
            }
        })?;
        let mut m: Manifest = serde_path_to_error::deserialize(de).map_err(|e| {
            let key = e.path().to_string();
            err(toml_message(e.inner(), text, Some(key)))
        })?;
        m.path = path.to_path_buf();
        // The deserializer left byte offsets.
        let line_of = |at: usize| crate::io::toml_text::line_column(text, at).0;
        if let Some(n) = &mut m.noise {
            n.line = n.line.map(line_of);
        }
        let base = m.base_dir();
        if let Some(c) = &mut m.calibration {
            c.lines.values_mut().for_each(|at| *at = line_of(*at));
            resolve_theta0_file(&mut c.table, &base);
        }
        m.check()?;
        Ok(m)
    }

    /// The parameter file `[calibration] theta0` names, if it names one
    /// (relative to the manifest's folder, as every file a manifest names):
    /// an input of the calibration, which no output may overwrite.
    pub fn theta0_file(&self) -> Option<PathBuf> {
        let theta0 = self.calibration.as_ref()?.table.get("theta0")?.as_str()?;
        crate::io::param_file::ParamFile::is_param_file(Path::new(theta0)).then(|| PathBuf::from(theta0))
    }

    research_pub! {
        /// The sample time of the imported drive, s (`[output] rate_hz`).
        fn sample_time_s(&self) -> f64 {
            1.0 / self.output.rate_hz
        }
    }

    /// The time column of stream `stream` (`streams.<stream>.time_column`;
    /// `None` for an unknown stream or an MCAP source, whose messages carry
    /// their own time; outside the crate: [`crate::io::RawStream::columns`]).
    pub(crate) fn time_column(&self, stream: &str) -> Option<&str> {
        self.streams.get(stream)?.time_column.as_deref()
    }

    /// The manifest error for `key`.
    pub(crate) fn error(&self, key: &str, reason: impl std::fmt::Display) -> Error {
        Error::Manifest { path: self.path.clone(), reason: format!("{key}: {reason}") }
    }

    /// The folder stream files are relative to.
    pub(crate) fn base_dir(&self) -> PathBuf {
        self.path.parent().map(Path::to_path_buf).unwrap_or_default()
    }

    /// The files the import reads, each with its stream's name: every
    /// stream's file (a bag folder's files one by one), by stream name.
    pub fn stream_files(&self) -> Vec<(String, PathBuf)> {
        let mut out = Vec::new();
        for (name, spec) in &self.streams {
            let path = self.base_dir().join(spec.source.file());
            match std::fs::read_dir(&path) {
                Ok(entries) => {
                    let mut files: Vec<PathBuf> =
                        entries.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_file()).collect();
                    files.sort();
                    out.extend(files.into_iter().map(|f| (name.clone(), f)));
                }
                Err(_) => out.push((name.clone(), path)),
            }
        }
        out
    }
}

/// A `[calibration] theta0` that names a parameter file by a relative
/// path is made absolute from the manifest's folder `base` (the folder
/// every file a manifest names is relative to), so that the calibration
/// reads the file beside the manifest from any working directory, and so
/// does a later calibration of the drive the import wrote, whose report
/// carries the table. A path that is not UTF-8 is left as it is.
fn resolve_theta0_file(table: &mut toml::Table, base: &Path) {
    let Some(toml::Value::String(theta0)) = table.get_mut("theta0") else { return };
    let path = Path::new(theta0.as_str());
    if !crate::io::param_file::ParamFile::is_param_file(path) || path.is_absolute() {
        return;
    }
    let joined = base.join(path);
    let resolved = std::path::absolute(&joined).unwrap_or(joined);
    if let Some(text) = resolved.to_str() {
        *theta0 = text.to_string();
    }
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
    // "duplicate key" names none: name it from the span.
    if msg == "duplicate key" {
        if let Some(k) = e.span().and_then(|s| crate::io::toml_text::duplicate_key(text, s)) {
            key = Some(k);
            msg = "duplicate key: given more than once; keep one".to_string();
        }
    }
    let line = e.span().map(|s| crate::io::toml_text::line_column(text, s.start).0);
    let at = line.map(|l| format!(" (line {l})")).unwrap_or_default();
    // The parser quotes the offending text: a key of a megabyte would be a
    // line of a megabyte.
    let msg = crate::drive::clip(&msg, 400);
    let key = key.map(|k| crate::drive::clip(&k, 200));
    match key {
        Some(k) => format!("{k}: {msg}{at}"),
        None => format!("{msg}{at}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The `[pose] quality` of a small manifest with `quality` as written.
    fn quality(quality: &str) -> QualitySpec {
        let text = format!(
            r#"
[streams.wheels]
file = "w.csv"
time_column = "t"

[streams.pose]
file = "p.csv"
time_column = "t"

[wheels]
stream = "wheels"
signal = "rad_cumulative"
rear_left = {{ column = "l" }}
rear_right = {{ column = "r" }}

[pose]
stream = "pose"
position = {{ kind = "local", x = "x", y = "y" }}
{quality}
"#
        );
        Manifest::parse(&text, Path::new("m.toml")).expect("manifest").pose.quality.expect("quality")
    }

    /// A drive or stream CSV given where a manifest belongs says what it
    /// is, by its name or its header row, instead of a TOML syntax error.
    #[test]
    fn a_csv_given_as_a_manifest_says_so() {
        let dir = tempfile::tempdir().expect("tmp");
        let csv = dir.path().join("drive.csv");
        std::fs::write(&csv, "t,px,py,psi,n_rl,n_rr,beta,a_y\n0,0,0,0,1,1,0,0\n").expect("write");
        let by_name = Manifest::from_path(&csv).expect_err("csv").to_string();
        assert!(by_name.contains("drive.csv: a CSV file, not a drive manifest (TOML)"), "{by_name}");
        let by_header = Manifest::parse("t,px,py\n0,0,0\n", Path::new("log.txt")).expect_err("csv").to_string();
        assert!(by_header.starts_with("log.txt: a CSV file, not a drive manifest"), "{by_header}");
        // A broken manifest keeps its syntax error.
        let broken = Manifest::parse("[streams.a]\nfile = \n", Path::new("m.toml")).expect_err("toml").to_string();
        assert!(!broken.contains("a CSV file"), "{broken}");
    }

    #[test]
    fn quality_thresholds_accept_what_every_given_test_passes() {
        let q = quality("quality = { column = \"q\", max = 0.01, min = 0 }");
        assert!(q.accepts(0.0004) && q.accepts(0.01) && q.accepts(0.0));
        assert!(!q.accepts(100.0) && !q.accepts(-1.0) && !q.accepts(f64::NAN));
        let both = quality("quality = { column = \"q\", accept = [2.0], max = 1.5 }");
        assert!(!both.accepts(2.0), "every given test must pass");
    }

    /// A message about the quality tests names the one test given, or the
    /// table when several are.
    #[test]
    fn the_quality_key_names_the_tests_given() {
        let key = |q: &str| quality(&format!("quality = {{ column = \"q\", {q} }}")).key();
        assert_eq!(key("min = 100.0"), "pose.quality.min");
        assert_eq!(key("max = 1.0"), "pose.quality.max");
        assert_eq!(key("accept = [4.0]"), "pose.quality.accept");
        assert_eq!(key("min = 0.0, max = 1.0"), "pose.quality");
        assert_eq!(key("accept = [4.0], min = 1.0"), "pose.quality");
    }

    /// A key given twice is named with its table, on its line.
    #[test]
    fn a_duplicate_key_is_named() {
        let e = Manifest::parse("[output]\nrate_hz = 40.0\nrate_hz = 41.0\n", Path::new("m.toml"))
            .expect_err("duplicate")
            .to_string();
        assert_eq!(e, "m.toml: output.rate_hz: duplicate key: given more than once; keep one (line 3)");
        let e = Manifest::parse("[output]\nrate_hz = 40.0\n[output]\nmax_gap_s = 1\n", Path::new("m.toml"))
            .expect_err("duplicate")
            .to_string();
        assert!(e.starts_with("m.toml: output: duplicate key") && e.ends_with("(line 3)"), "{e}");
    }
}
