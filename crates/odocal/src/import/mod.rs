//! Import of real multi-stream logs into a uniform [`Drive`].
//!
//! Real logs never arrive as one neat table: wheel encoders, GNSS/INS pose and
//! IMU come as separate files at their own rates, on clocks that differ by an
//! offset, with jittery time stamps, counters that wrap, gaps and fix-quality
//! changes. A *drive manifest* (TOML) says where each model signal comes from,
//! in which unit and convention; [`import`] reads the streams and resamples
//! them onto one uniform time base:
//!
//! 1. **Streams** are read (only the columns needed), their time converted to
//!    seconds and shifted by `time_offset_s`. Time that goes backwards is an
//!    error; repeated stamps are dropped (and counted). A stream with a
//!    `nominal_rate_hz` is *de-jittered*: each sample gets an integer index
//!    and its stamp is replaced by a local least-squares line `t = t0 + k·T`
//!    (±`dejitter_window_s`/2), because encoder counts are sampled on the
//!    sensor's clock but stamped on arrival.
//! 2. **Wheels** become a cumulative rotation (revolutions) per wheel: ticks
//!    divided by `ticks_per_rev` (raw counters unwrapped modulo 2^bits first),
//!    rates integrated. The output rotation speed `n_k` is the difference of
//!    the interpolated cumulative rotation over the output interval
//!    `[t_k, t_k + t_s]` divided by `t_s` — the mean speed over the step the
//!    model integrates.
//! 3. **Pose** positions (local, or WGS84 latitude/longitude → ECEF → local
//!    ENU) and the heading (converted to ENU, counter-clockwise from east,
//!    unwrapped *before* interpolation; or derived from the track) are
//!    interpolated linearly at `t_k`. Samples of rejected quality are removed.
//! 4. **Clock offset** τ (pose time + τ = wheel time) is estimated by
//!    cross-correlating the wheel speed at θ_0 with the speed differenced from
//!    the pose, over ±`max_clock_offset_s`, with sub-sample resolution from a
//!    parabola through the correlation peak. It is always reported; it is
//!    applied when `clock_offset = "auto"`.
//! 5. **Gaps**: a wheel, pose or IMU gap longer than `max_gap_s`, or pose
//!    samples of rejected quality, make the affected output samples invalid;
//!    the valid samples form the continuous parts of the drive
//!    ([`Drive::parts`]), so no segment spans a gap. Parts shorter than
//!    `min_part_s` are dropped; the report says where and why.
//!
//! ## Lateral acceleration without an IMU
//!
//! `source = "from_wheels"` (the default) sets a_y = v·ω of the model at θ_0
//! from the wheel rotations. `source = "from_pose"` uses speed × yaw rate of
//! the *reference* pose. The latter is smoother, but it feeds the reference
//! yaw rate into the model through `d·a_y`: the wheel circumferences then
//! carry a term proportional to the reference yaw rate, and a fit can use d
//! to pull the model's yaw towards the reference — d absorbs heading errors
//! instead of measuring load transfer, and dead-reckoning errors on the
//! same reference look better than the wheels alone could do. `from_wheels`
//! keeps the model's inputs independent of the reference.
//!
//! ## Wheel units and θ
//!
//! The model's rotation is "revolutions" of whatever the import divided by:
//! for ticks, c_e is metres per `ticks_per_rev` ticks (choose it so that c_e
//! lands near the physical circumference, e.g. ticks per metre × 2.0); for
//! `m_per_s`, c_e is metres per revolution of the stated nominal
//! `circumference_m` (c_e / circumference_m is the scale error of the
//! recorded speed).
//!
//! ## Manifest format
//!
//! Paths are relative to the manifest's folder. Keys with a default may be
//! omitted. Unknown keys are errors.
//!
//! ```toml
//! [output]
//! rate_hz = 40.0             # output rate, Hz (default 40)
//! max_gap_s = 0.5            # longer stream gaps split the drive (default 0.5)
//! min_part_s = 30.0          # shorter parts are dropped (default 30)
//! clock_offset = "auto"      # or seconds added to pose time (default "auto")
//! max_clock_offset_s = 2.0   # search range of "auto", ± s (default 2)
//! theta0 = [2.0, 0.0, 1.6, 0.0]  # θ_0 for speeds / a_y from wheels (default)
//!
//! [streams.encoders]          # one table per file; the name is yours
//! file = "data/encoders.csv"
//! time_column = "stamp"
//! time_unit = "ns"            # s | ms | us | ns (default s)
//! time_offset_s = 0.0         # added after unit conversion (default 0)
//! nominal_rate_hz = 100.0     # optional: de-jitter the stamps
//! dejitter_window_s = 2.0     # local fit window (default 2)
//!
//! [streams.gnss]
//! file = "data/gnss.csv"
//! time_column = "gps_time_s"
//! time_offset_s = 0.105
//!
//! [streams.imu]
//! file = "data/imu.csv"
//! time_column = "stamp"
//! time_unit = "ns"
//!
//! [wheels]
//! stream = "encoders"
//! signal = "ticks_raw"        # rev_per_s | rad_per_s | m_per_s | ticks_cumulative | ticks_raw
//! ticks_per_rev = 4096.0      # ticks signals: c_e is metres per this many ticks
//! counter_bits = 32           # ticks_raw: counter width for wrap-around
//! # circumference_m = 2.0     # m_per_s: nominal circumference
//! rear_left = { column = "left", sign = -1 }   # sign makes forward positive
//! rear_right = { column = "right" }            # sign defaults to +1
//!
//! [pose]
//! stream = "gnss"
//! derive_heading_min_speed_m_per_s = 1.0  # only used without [pose.heading]
//!
//! [pose.position]
//! kind = "lat_lon"            # or kind = "local" with x = "...", y = "..."
//! lat = "lat_deg"
//! lon = "lon_deg"
//! alt = "alt_m"               # optional
//! origin = [40.44, -79.76, 300.0]  # optional, default the first sample
//!
//! [pose.heading]              # optional: derived from the track if absent
//! column = "heading_deg"
//! convention = "ned"          # enu (ccw from east) | ned (cw from north)
//! unit = "deg"                # rad | deg (default rad)
//!
//! [pose.quality]              # optional
//! column = "fix_mode"
//! accept = [6]                # e.g. RTK fixed only
//!
//! [lateral_acceleration]
//! source = "imu"              # imu | from_wheels (default) | from_pose
//! stream = "imu"
//! column = "acc_y"
//! sign = 1                    # +1: column positive to the left
//! # smoothing_s = 0.5         # from_wheels (default 0) / from_pose (default 0.5)
//!
//! [sideslip]
//! source = "zero"             # zero (default) | column
//! # stream = "ins", column = "beta", unit = "rad", sign = 1
//! ```
//!
//! ## Example
//!
//! ```no_run
//! # fn main() -> odocal::Result<()> {
//! use std::path::Path;
//! let manifest = odocal::import::Manifest::from_path(Path::new("examples/psu-mapping-van/manifest.toml"))?;
//! let imported = odocal::import::import(&manifest)?;
//! println!("{}", imported.report);
//! imported.drive.write_csv("drive.csv")?;
//! # Ok(()) }
//! ```

mod geodesy;
mod manifest;
mod signal;
#[cfg(test)]
mod tests;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::Serialize;

pub use manifest::{
    AngleUnit, ClockOffset, HeadingConvention, HeadingSpec, LateralAccelerationSpec, Manifest, OutputSpec,
    PositionSpec, QualitySpec, SideslipSpec, StreamSpec, TimeUnit, WheelColumn, WheelSignal, WheelSpec,
};

use crate::drive::{unwrap_in_place, Drive, Signals};
use crate::error::{Error, Result};
use crate::model::{kinematics, Input, Theta};

/// A drive imported from a manifest, with the report of what was done.
#[derive(Debug, Clone)]
pub struct ImportedDrive {
    /// The uniform drive (time starts at 0 at [`ImportReport::time_origin_s`]).
    pub drive: Drive,
    /// What was read, estimated, split and dropped.
    pub report: ImportReport,
}

/// What the import did. `Display` gives a human summary.
#[derive(Debug, Clone, Serialize)]
pub struct ImportReport {
    /// The manifest.
    pub manifest: PathBuf,
    /// Streams read.
    pub streams: Vec<StreamReport>,
    /// Output rate, Hz.
    pub output_rate_hz: f64,
    /// Wheel-clock time of the drive's t = 0, s (stream time units after
    /// `time_offset_s`). All other times in the report are relative to it.
    pub time_origin_s: f64,
    /// Common time span of the streams, relative to the origin, s.
    pub common_span_s: [f64; 2],
    /// Clock offset between the wheel and pose streams.
    pub clock_offset: ClockOffsetReport,
    /// Intervals without valid output samples, with reasons.
    pub gaps: Vec<GapRecord>,
    /// Continuous parts, kept and dropped.
    pub parts: Vec<PartRecord>,
    /// Samples in the imported drive (kept parts).
    pub samples: usize,
    /// Duration of the kept parts, s.
    pub duration_s: f64,
    /// Reference path length of the kept parts, m.
    pub distance_m: f64,
    /// What one model "revolution" is, i.e. how to read c_e.
    pub wheel_scale: String,
    /// Source of the lateral acceleration.
    pub lateral_acceleration: String,
    /// Effect of de-jittering the wheel stream, when it was de-jittered.
    pub jitter: Option<JitterReport>,
    /// Wall time of the import, s.
    pub elapsed_s: f64,
}

/// One stream that was read.
#[derive(Debug, Clone, Serialize)]
pub struct StreamReport {
    /// Name in the manifest.
    pub name: String,
    /// The file.
    pub file: PathBuf,
    /// Data rows read.
    pub rows: usize,
    /// Rows dropped because their time stamp repeated the previous one.
    pub repeated_stamps_dropped: usize,
    /// First and last time, s (after `time_offset_s`, before the clock offset).
    pub time_span_s: [f64; 2],
    /// Mean sample rate, Hz.
    pub mean_rate_hz: f64,
    /// De-jittering, when the stream has a nominal rate.
    pub dejitter: Option<DejitterReport>,
}

/// Time-stamp corrections of a de-jittered stream.
#[derive(Debug, Clone, Serialize)]
pub struct DejitterReport {
    /// Nominal rate, Hz.
    pub nominal_rate_hz: f64,
    /// RMS stamp correction, ms.
    pub rms_correction_ms: f64,
    /// Largest stamp correction, ms.
    pub max_correction_ms: f64,
    /// Samples missing from the nominal sequence.
    pub missing_samples: u64,
}

/// Noise of the output wheel speeds with raw and de-jittered stamps.
///
/// Noise is estimated from second differences of n at the output rate,
/// `sqrt(mean(Δ²n)²/6)`, relative to the RMS wheel speed, over moving samples
/// (|n| > 1 rev/s) of the kept parts, both wheels; it holds real speed changes
/// too, so it is an upper bound on the noise.
#[derive(Debug, Clone, Serialize)]
pub struct JitterReport {
    /// With the raw stamps, per cent.
    pub wheel_speed_noise_raw_pct: f64,
    /// With the de-jittered stamps, per cent.
    pub wheel_speed_noise_dejittered_pct: f64,
}

/// Clock offset between the wheel and pose streams.
#[derive(Debug, Clone, Serialize)]
pub struct ClockOffsetReport {
    /// Estimate from the speed cross-correlation, s (pose time + τ = wheel time).
    pub estimated_s: Option<f64>,
    /// Pearson correlation at the peak.
    pub correlation: Option<f64>,
    /// Sample pairs (at the output rate) in the correlation at the peak.
    pub correlation_pairs: Option<usize>,
    /// Cross-check, not applied: the same estimate from the wheel yaw rate
    /// at θ_0 against the reference yaw rate, s (sharper where the drive turns).
    pub yaw_rate_estimate_s: Option<f64>,
    /// Pearson correlation of the yaw-rate cross-check.
    pub yaw_rate_correlation: Option<f64>,
    /// The offset applied, s.
    pub applied_s: f64,
    /// `"auto"` or `"fixed"`.
    pub mode: String,
}

/// An interval without valid samples.
#[derive(Debug, Clone, Serialize)]
pub struct GapRecord {
    /// Start, s (relative to the origin).
    pub t_start_s: f64,
    /// End, s.
    pub t_end_s: f64,
    /// Why (the distinct reasons of the invalid samples).
    pub reasons: Vec<String>,
}

/// A continuous run of valid samples.
#[derive(Debug, Clone, Serialize)]
pub struct PartRecord {
    /// Start, s (relative to the origin).
    pub t_start_s: f64,
    /// End, s.
    pub t_end_s: f64,
    /// Samples.
    pub samples: usize,
    /// Kept in the drive?
    pub kept: bool,
    /// Why it was dropped.
    pub dropped_because: Option<String>,
}

impl std::fmt::Display for ImportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "import of {}", self.manifest.display())?;
        for s in &self.streams {
            write!(
                f,
                "  stream {:<10} {} rows at {:.2} Hz, t = {:.3} … {:.3} s",
                s.name, s.rows, s.mean_rate_hz, s.time_span_s[0], s.time_span_s[1]
            )?;
            if s.repeated_stamps_dropped > 0 {
                write!(f, ", {} repeated stamps dropped", s.repeated_stamps_dropped)?;
            }
            if let Some(d) = &s.dejitter {
                write!(
                    f,
                    ", de-jittered at {} Hz (correction rms {:.3} ms, max {:.3} ms, {} samples missing)",
                    d.nominal_rate_hz, d.rms_correction_ms, d.max_correction_ms, d.missing_samples
                )?;
            }
            writeln!(f)?;
        }
        let c = &self.clock_offset;
        match (c.estimated_s, c.correlation) {
            (Some(e), Some(r)) => writeln!(
                f,
                "  clock offset: estimated {:+.4} s (speed correlation {r:.4}), applied {:+.4} s ({})",
                e, c.applied_s, c.mode
            )?,
            _ => writeln!(f, "  clock offset: not estimated, applied {:+.4} s ({})", c.applied_s, c.mode)?,
        }
        if let (Some(e), Some(r)) = (c.yaw_rate_estimate_s, c.yaw_rate_correlation) {
            writeln!(f, "  clock offset cross-check from yaw rates: {e:+.4} s (correlation {r:.4}), not applied")?;
        }
        if let Some(j) = &self.jitter {
            writeln!(
                f,
                "  wheel speed noise at {} Hz: {:.3} % with raw stamps, {:.3} % de-jittered",
                self.output_rate_hz, j.wheel_speed_noise_raw_pct, j.wheel_speed_noise_dejittered_pct
            )?;
        }
        writeln!(
            f,
            "  time origin {:.6} s; common span {:.2} … {:.2} s",
            self.time_origin_s, self.common_span_s[0], self.common_span_s[1]
        )?;
        for g in &self.gaps {
            writeln!(f, "  gap   {:9.2} … {:9.2} s: {}", g.t_start_s, g.t_end_s, g.reasons.join("; "))?;
        }
        for p in &self.parts {
            write!(f, "  part  {:9.2} … {:9.2} s, {:6} samples", p.t_start_s, p.t_end_s, p.samples)?;
            match &p.dropped_because {
                Some(why) => writeln!(f, ", dropped: {why}")?,
                None => writeln!(f, ", kept")?,
            }
        }
        let kept = self.parts.iter().filter(|p| p.kept).count();
        writeln!(
            f,
            "  {} of {} parts kept: {} samples, {:.1} s, {:.1} m at {} Hz",
            kept,
            self.parts.len(),
            self.samples,
            self.duration_s,
            self.distance_m,
            self.output_rate_hz
        )?;
        writeln!(f, "  wheels: {}", self.wheel_scale)?;
        write!(f, "  lateral acceleration: {}", self.lateral_acceleration)
    }
}

/// Reads a drive from either a canonical CSV (SPEC §2) or a `.toml` manifest
/// (imported with [`import`]); the report is `Some` for a manifest.
pub fn load_drive(path: &Path) -> Result<(Drive, Option<ImportReport>)> {
    let is_toml = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("toml"));
    if is_toml {
        let m = Manifest::from_path(path)?;
        let ImportedDrive { drive, report } = import(&m)?;
        Ok((drive, Some(report)))
    } else {
        Ok((Drive::read_csv(path)?, None))
    }
}

/// One stream as read: time (s, after offset and de-jittering) and the
/// columns asked for.
struct Stream {
    path: PathBuf,
    t: Vec<f64>,
    t_raw: Vec<f64>,
    cols: BTreeMap<String, Vec<f64>>,
    report: StreamReport,
}

impl Stream {
    fn col(&self, name: &str) -> &[f64] {
        self.cols.get(name).map(Vec::as_slice).unwrap_or(&[])
    }
}

/// Reads the columns `needs` (column, manifest key) of stream `name`.
fn read_stream(m: &Manifest, name: &str, needs: &[(String, String)]) -> Result<Stream> {
    let spec = &m.streams[name];
    let path = m.base_dir().join(&spec.file);
    let key = format!("streams.{name}.file");
    let bytes = std::fs::read(&path).map_err(|e| m.error(&key, format!("cannot read {}: {e}", path.display())))?;
    let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF".as_slice()).unwrap_or(&bytes);
    let mut rdr = csv::ReaderBuilder::new().has_headers(true).trim(csv::Trim::All).from_reader(bytes);
    let csv_err = |e: csv::Error| Error::Csv {
        path: path.clone(),
        line: e.position().map(|p| p.line()).unwrap_or(0),
        column: None,
        reason: e.to_string(),
    };
    let headers: Vec<String> = rdr.headers().map_err(csv_err)?.iter().map(str::to_string).collect();
    let mut wanted: Vec<(String, String)> = vec![(spec.time_column.clone(), format!("streams.{name}.time_column"))];
    wanted.extend(needs.iter().cloned());
    let mut idx = Vec::new();
    for (col, key) in &wanted {
        match headers.iter().position(|h| h == col) {
            Some(j) => idx.push(j),
            None => {
                return Err(m.error(
                    key,
                    format!("column '{col}' not found in {}; columns found: {}", path.display(), headers.join(", ")),
                ))
            }
        }
    }
    let mut data: Vec<Vec<f64>> = vec![Vec::new(); wanted.len()];
    let mut lines: Vec<u64> = Vec::new();
    let mut record = csv::StringRecord::new();
    let mut line = 1u64;
    while rdr.read_record(&mut record).map_err(csv_err)? {
        line = record.position().map(|p| p.line()).unwrap_or(line + 1);
        for (c, &j) in idx.iter().enumerate() {
            let field = record.get(j).unwrap_or("");
            let v: f64 = field.parse().map_err(|_| Error::Csv {
                path: path.clone(),
                line,
                column: Some(headers[j].clone()),
                reason: format!("'{field}' is not a number"),
            })?;
            data[c].push(v);
        }
        lines.push(line);
    }
    if lines.is_empty() {
        return Err(m.error(&key, format!("{} has no data rows", path.display())));
    }
    let scale = spec.time_unit.seconds();
    let mut time: Vec<f64> = std::mem::take(&mut data[0]);
    for (i, t) in time.iter_mut().enumerate() {
        if !t.is_finite() {
            return Err(Error::Csv {
                path: path.clone(),
                line: lines[i],
                column: Some(spec.time_column.clone()),
                reason: "time is not finite".into(),
            });
        }
        *t = *t * scale + spec.time_offset_s;
    }
    // Backwards time is an error; repeated stamps are dropped.
    let mut keep = vec![true; time.len()];
    let mut repeated = 0;
    let mut last = time[0];
    for i in 1..time.len() {
        if time[i] < last {
            return Err(Error::Csv {
                path: path.clone(),
                line: lines[i],
                column: Some(spec.time_column.clone()),
                reason: format!(
                    "time goes backwards ({} after {} s); the stream must be sorted by time",
                    time[i], last
                ),
            });
        }
        if time[i] <= last {
            keep[i] = false;
            repeated += 1;
        } else {
            last = time[i];
        }
    }
    let filt = |v: Vec<f64>| -> Vec<f64> { v.into_iter().zip(&keep).filter(|(_, k)| **k).map(|(x, _)| x).collect() };
    let t_raw = filt(time);
    let mut cols = BTreeMap::new();
    for (c, (col, _)) in wanted.iter().enumerate().skip(1) {
        cols.insert(col.clone(), filt(std::mem::take(&mut data[c])));
    }
    let n = t_raw.len();
    let span = [t_raw[0], t_raw[n - 1]];
    let mean_rate_hz = if n > 1 { (n - 1) as f64 / (span[1] - span[0]) } else { 0.0 };
    let (t, dejitter) = match spec.nominal_rate_hz {
        Some(rate) => {
            let half = ((spec.dejitter_window_s * rate) / 2.0).round().max(1.0) as usize;
            let d = signal::dejitter(&t_raw, 1.0 / rate, half, m.output.max_gap_s);
            let rep = DejitterReport {
                nominal_rate_hz: rate,
                rms_correction_ms: d.rms_correction_s * 1e3,
                max_correction_ms: d.max_correction_s * 1e3,
                missing_samples: d.missing_samples,
            };
            (d.t, Some(rep))
        }
        None => (t_raw.clone(), None),
    };
    let report = StreamReport {
        name: name.to_string(),
        file: path.clone(),
        rows: lines.len(),
        repeated_stamps_dropped: repeated,
        time_span_s: span,
        mean_rate_hz,
        dejitter,
    };
    Ok(Stream { path, t, t_raw, cols, report })
}

/// A time interval that invalidates output samples, with its reason.
#[derive(Debug, Clone)]
struct BadInterval {
    from: f64,
    to: f64,
    reason: String,
}

/// Intervals between consecutive stamps longer than `max_gap`.
fn gaps_of(t: &[f64], max_gap: f64, what: &str) -> Vec<BadInterval> {
    t.windows(2)
        .filter(|w| w[1] - w[0] > max_gap)
        .map(|w| BadInterval { from: w[0], to: w[1], reason: format!("{what} gap of {:.2} s", w[1] - w[0]) })
        .collect()
}

/// The pose on its own (good-quality) samples.
struct Pose {
    t: Vec<f64>,
    x: Vec<f64>,
    y: Vec<f64>,
    psi: Vec<f64>,
    /// Gaps and quality rejections, on the pose stream's time.
    bad: Vec<BadInterval>,
}

fn build_pose(m: &Manifest, s: &Stream) -> Result<Pose> {
    let p = &m.pose;
    let n = s.t.len();
    let good: Vec<bool> = match &p.quality {
        Some(q) => s.col(&q.column).iter().map(|v| q.accept.iter().any(|a| (a - v).abs() < 1e-9)).collect(),
        None => vec![true; n],
    };
    let first_good = good.iter().position(|g| *g).ok_or_else(|| {
        let mut seen: Vec<f64> = p.quality.as_ref().map(|q| s.col(&q.column).to_vec()).unwrap_or_default();
        seen.sort_by(f64::total_cmp);
        seen.dedup();
        seen.truncate(10);
        m.error("pose.quality.accept", format!("no pose sample has an accepted quality value (values found: {seen:?})"))
    })?;
    let (x, y): (Vec<f64>, Vec<f64>) = match &p.position {
        PositionSpec::Local { x, y } => (s.col(x).to_vec(), s.col(y).to_vec()),
        PositionSpec::LatLon { lat, lon, alt, origin } => {
            let (lat, lon) = (s.col(lat), s.col(lon));
            let h: Vec<f64> = alt.as_ref().map(|a| s.col(a).to_vec()).unwrap_or_else(|| vec![0.0; n]);
            let o = origin.unwrap_or([lat[first_good], lon[first_good], h[first_good]]);
            let enu = geodesy::Enu::new(o[0], o[1], o[2]);
            (0..n).map(|i| enu.enu_of(lat[i], lon[i], h[i])).map(|v| (v.x, v.y)).unzip()
        }
    };
    // Keep good samples; remember rejected runs between them.
    let mut out = Pose { t: Vec::new(), x: Vec::new(), y: Vec::new(), psi: Vec::new(), bad: Vec::new() };
    let mut heading_raw = Vec::new();
    let mut rejected_since_last = 0usize;
    let mut rejected_values: Vec<f64> = Vec::new();
    let qcol = p.quality.as_ref().map(|q| s.col(&q.column));
    for i in 0..n {
        if !good[i] {
            rejected_since_last += 1;
            if let Some(v) = qcol.and_then(|c| c.get(i)) {
                if !rejected_values.iter().any(|r| (r - v).abs() < 1e-9) {
                    rejected_values.push(*v);
                }
            }
            continue;
        }
        if !(x[i].is_finite() && y[i].is_finite()) {
            return Err(Error::Csv {
                path: s.path.clone(),
                line: i as u64 + 2,
                column: None,
                reason: "pose position is not finite".into(),
            });
        }
        if rejected_since_last > 0 {
            if let (Some(&t0), Some(q)) = (out.t.last(), &p.quality) {
                out.bad.push(BadInterval {
                    from: t0,
                    to: s.t[i],
                    reason: format!(
                        "pose quality rejected ({} = {:?}, {} samples)",
                        q.column, rejected_values, rejected_since_last
                    ),
                });
            }
            rejected_since_last = 0;
            rejected_values.clear();
        }
        out.t.push(s.t[i]);
        out.x.push(x[i]);
        out.y.push(y[i]);
        if let Some(h) = &p.heading {
            let v = s.col(&h.column)[i] * h.unit.radians();
            heading_raw.push(match h.convention {
                HeadingConvention::Enu => v,
                HeadingConvention::Ned => std::f64::consts::FRAC_PI_2 - v,
            });
        }
    }
    if out.t.len() < 2 {
        return Err(m.error("pose.quality.accept", "fewer than two pose samples of accepted quality"));
    }
    out.bad.extend(gaps_of(&out.t, m.output.max_gap_s, "pose"));
    out.bad.sort_by(|a, b| a.from.total_cmp(&b.from));
    if p.heading.is_some() {
        unwrap_in_place(&mut heading_raw);
        out.psi = heading_raw;
    } else {
        out.psi = derive_heading(&out.t, &out.x, &out.y, p.derive_heading_min_speed_m_per_s);
    }
    Ok(out)
}

/// Heading from the track: direction of motion between consecutive samples,
/// held below `min_speed`, averaged back onto the samples, unwrapped.
fn derive_heading(t: &[f64], x: &[f64], y: &[f64], min_speed: f64) -> Vec<f64> {
    let n = t.len();
    let mut mid: Vec<Option<f64>> = (0..n - 1)
        .map(|j| {
            let (dx, dy) = (x[j + 1] - x[j], y[j + 1] - y[j]);
            (dx.hypot(dy) / (t[j + 1] - t[j]) > min_speed).then(|| dy.atan2(dx))
        })
        .collect();
    // Hold the last heading through slow stretches (and back-fill the start).
    let first = mid.iter().flatten().next().copied().unwrap_or(0.0);
    let mut last = first;
    for v in mid.iter_mut() {
        match v {
            Some(h) => last = *h,
            None => *v = Some(last),
        }
    }
    let mut mid: Vec<f64> = mid.into_iter().map(|v| v.unwrap_or(first)).collect();
    unwrap_in_place(&mut mid);
    (0..n)
        .map(|i| match i {
            0 => mid[0],
            i if i == n - 1 => mid[n - 2],
            i => 0.5 * (mid[i - 1] + mid[i]),
        })
        .collect()
}

/// Cumulative rotation (revolutions, forward positive) of one wheel.
fn wheel_revolutions(m: &Manifest, s: &Stream, wheel: &WheelColumn, key: &str) -> Result<Vec<f64>> {
    let w = &m.wheels;
    let col = s.col(&wheel.column);
    if let Some(i) = col.iter().position(|v| !v.is_finite()) {
        return Err(Error::Csv {
            path: s.path.clone(),
            line: i as u64 + 2,
            column: Some(wheel.column.clone()),
            reason: format!("value is not finite ({key})"),
        });
    }
    let sign = wheel.sign;
    let per_rev = |v: Option<f64>| v.unwrap_or(1.0);
    Ok(match w.signal {
        WheelSignal::RevPerS => signal::cumulative_integral(&s.t, &col.iter().map(|v| sign * v).collect::<Vec<_>>()),
        WheelSignal::RadPerS => {
            signal::cumulative_integral(&s.t, &col.iter().map(|v| sign * v / std::f64::consts::TAU).collect::<Vec<_>>())
        }
        WheelSignal::MPerS => {
            let c = per_rev(w.circumference_m);
            signal::cumulative_integral(&s.t, &col.iter().map(|v| sign * v / c).collect::<Vec<_>>())
        }
        WheelSignal::TicksCumulative => {
            let tpr = per_rev(w.ticks_per_rev);
            col.iter().map(|v| sign * (v - col[0]) / tpr).collect()
        }
        WheelSignal::TicksRaw => {
            let tpr = per_rev(w.ticks_per_rev);
            let bits = w.counter_bits.unwrap_or(32);
            let modulus: i128 = 1i128 << bits;
            let half = modulus / 2;
            let mut acc: i128 = 0;
            let mut out = Vec::with_capacity(col.len());
            out.push(0.0);
            for pair in col.windows(2) {
                let d = ((pair[1] as i128) - (pair[0] as i128)).rem_euclid(modulus);
                acc += if d >= half { d - modulus } else { d };
                out.push(sign * acc as f64 / tpr);
            }
            out
        }
    })
}

/// Marks grid samples invalid: interval `[g, g+h]` (when `interval`) or the
/// point `g` overlapping a bad interval; records the first reason.
fn mark(valid: &mut [Option<String>], grid_start: f64, h: f64, bad: &[BadInterval], interval: bool, shift: f64) {
    let n = valid.len();
    for b in bad {
        let (from, to) = (b.from + shift, b.to + shift);
        let lo = (((from - grid_start) / h).floor() as i64 - 1).max(0) as usize;
        let hi = ((((to - grid_start) / h).ceil() as i64) + 1).clamp(0, n as i64) as usize;
        for (k, v) in valid.iter_mut().enumerate().take(hi).skip(lo) {
            let g = grid_start + k as f64 * h;
            let hit = if interval { g < to && g + h > from } else { g > from && g < to };
            if hit && v.is_none() {
                *v = Some(b.reason.clone());
            }
        }
    }
}

/// Noise of wheel speeds from second differences (see [`JitterReport`]).
fn speed_noise_pct(n: &[f64], parts: &[std::ops::Range<usize>]) -> f64 {
    let (mut s2, mut sn, mut c) = (0.0, 0.0, 0usize);
    for r in parts {
        for k in r.start + 1..r.end.saturating_sub(1) {
            if n[k].abs() > 1.0 {
                let d2 = n[k + 1] - 2.0 * n[k] + n[k - 1];
                s2 += d2 * d2 / 6.0;
                sn += n[k] * n[k];
                c += 1;
            }
        }
    }
    if c == 0 {
        return f64::NAN;
    }
    100.0 * (s2 / sn).sqrt()
}

/// Imports a drive described by a manifest: reads the streams, estimates the
/// clock offset, resamples to the output rate and splits at gaps.
pub fn import(m: &Manifest) -> Result<ImportedDrive> {
    let started = Instant::now();
    let o = &m.output;
    let h = 1.0 / o.rate_hz;
    let theta0: Theta = o.theta0();

    // Which columns of which stream.
    let mut needs: BTreeMap<String, Vec<(String, String)>> = BTreeMap::new();
    let mut need = |stream: &str, col: &str, key: &str| {
        needs.entry(stream.to_string()).or_default().push((col.to_string(), key.to_string()));
    };
    let w = &m.wheels;
    need(&w.stream, &w.rear_left.column, "wheels.rear_left.column");
    need(&w.stream, &w.rear_right.column, "wheels.rear_right.column");
    let p = &m.pose;
    match &p.position {
        PositionSpec::Local { x, y } => {
            need(&p.stream, x, "pose.position.x");
            need(&p.stream, y, "pose.position.y");
        }
        PositionSpec::LatLon { lat, lon, alt, .. } => {
            need(&p.stream, lat, "pose.position.lat");
            need(&p.stream, lon, "pose.position.lon");
            if let Some(a) = alt {
                need(&p.stream, a, "pose.position.alt");
            }
        }
    }
    if let Some(hd) = &p.heading {
        need(&p.stream, &hd.column, "pose.heading.column");
    }
    if let Some(q) = &p.quality {
        need(&p.stream, &q.column, "pose.quality.column");
    }
    if let LateralAccelerationSpec::Imu { stream, column, .. } = &m.lateral_acceleration {
        need(stream, column, "lateral_acceleration.column");
    }
    if let SideslipSpec::Column { stream, column, .. } = &m.sideslip {
        need(stream, column, "sideslip.column");
    }
    let mut streams: BTreeMap<String, Stream> = BTreeMap::new();
    for (name, cols) in &needs {
        streams.insert(name.clone(), read_stream(m, name, cols)?);
    }
    let ws = &streams[&w.stream];
    let ps = &streams[&p.stream];

    // Wheels: cumulative revolutions on the wheel stream's time.
    let cum_l = wheel_revolutions(m, ws, &w.rear_left, "wheels.rear_left")?;
    let cum_r = wheel_revolutions(m, ws, &w.rear_right, "wheels.rear_right")?;
    let wheel_bad = gaps_of(&ws.t, o.max_gap_s, "wheel");

    // Pose on its own time.
    let mut pose = build_pose(m, ps)?;

    // Clock offset: wheel speed at θ_0 vs pose speed, on a grid over the wheel span.
    let est = {
        let n_grid = ((ws.t[ws.t.len() - 1] - ws.t[0]) / h).floor() as usize;
        let grid: Vec<f64> = (0..n_grid).map(|k| ws.t[0] + k as f64 * h).collect();
        let mut valid: Vec<Option<String>> = vec![None; grid.len()];
        mark(&mut valid, ws.t[0], h, &wheel_bad, true, 0.0);
        let nl = signal::interval_rates(&ws.t, &cum_l, &grid, h);
        let nr = signal::interval_rates(&ws.t, &cum_r, &grid, h);
        let kin: Vec<Option<crate::model::Kinematics>> = (0..grid.len())
            .map(|k| {
                valid[k]
                    .is_none()
                    .then(|| kinematics(&Input { n_rl: nl[k], n_rr: nr[k], beta: 0.0, a_y: 0.0 }, &theta0))
            })
            .collect();
        let vw: Vec<f64> = kin.iter().map(|k| k.map_or(f64::NAN, |k| k.speed_m_per_s)).collect();
        let ww: Vec<f64> = kin.iter().map(|k| k.map_or(f64::NAN, |k| k.yaw_rate_rad_per_s)).collect();
        let mut tm = Vec::new();
        let mut vp = Vec::new();
        let mut wp = Vec::new();
        for j in 0..pose.t.len() - 1 {
            let (t0, t1) = (pose.t[j], pose.t[j + 1]);
            let bad = pose.bad.iter().any(|b| b.from < t1 && b.to > t0);
            tm.push(0.5 * (t0 + t1));
            let dt = t1 - t0;
            vp.push(if bad { f64::NAN } else { (pose.x[j + 1] - pose.x[j]).hypot(pose.y[j + 1] - pose.y[j]) / dt });
            wp.push(if bad { f64::NAN } else { (pose.psi[j + 1] - pose.psi[j]) / dt });
        }
        let centres: Vec<f64> = grid.iter().map(|g| g + 0.5 * h).collect();
        let on_grid = |y: &[f64]| {
            let mut v = signal::interp_sorted(&tm, y, &centres);
            for (v, c) in v.iter_mut().zip(&centres) {
                if tm.is_empty() || *c < tm[0] || *c > tm[tm.len() - 1] {
                    *v = f64::NAN;
                }
            }
            v
        };
        let max_lag = (o.max_clock_offset_s / h).ceil() as usize;
        (
            signal::cross_correlate(&vw, &on_grid(&vp), h, max_lag),
            signal::cross_correlate(&ww, &on_grid(&wp), h, max_lag),
        )
    };
    let (est, est_yaw) = est;
    let applied = match o.clock_offset {
        ClockOffset::Seconds(v) => v,
        ClockOffset::Auto => match est {
            Some(c) => c.offset_s,
            None => {
                return Err(m.error(
                    "output.clock_offset",
                    "\"auto\": the clock offset could not be estimated (no overlapping moving wheel and pose \
                     data within ±max_clock_offset_s); give the offset in seconds",
                ))
            }
        },
    };
    for t in pose.t.iter_mut() {
        *t += applied;
    }
    for b in pose.bad.iter_mut() {
        b.from += applied;
        b.to += applied;
    }

    // Common span.
    let mut spans: Vec<(String, f64, f64)> = vec![
        (format!("streams.{}", w.stream), ws.t[0], ws.t[ws.t.len() - 1]),
        (format!("streams.{} (pose, after the clock offset)", p.stream), pose.t[0], pose.t[pose.t.len() - 1]),
    ];
    for (name, s) in &streams {
        if name != &w.stream && name != &p.stream {
            spans.push((format!("streams.{name}"), s.t[0], s.t[s.t.len() - 1]));
        }
    }
    let latest_start = spans.iter().max_by(|a, b| a.1.total_cmp(&b.1)).cloned();
    let earliest_end = spans.iter().min_by(|a, b| a.2.total_cmp(&b.2)).cloned();
    let (start, end) = match (latest_start, earliest_end) {
        (Some(a), Some(b)) if a.1 + 2.0 * h < b.2 => (a.1, b.2),
        (Some(a), Some(b)) => {
            return Err(Error::Manifest {
                path: m.path.clone(),
                reason: format!(
                    "{}: no time overlap with {}: t = {:.3} … {:.3} s vs {:.3} … {:.3} s; check time_column, \
                     time_unit and time_offset_s",
                    a.0, b.0, a.1, a.2, b.1, b.2
                ),
            })
        }
        _ => return Err(m.error("streams", "no streams")),
    };
    let n_grid = ((end - start) / h).floor() as usize;
    let grid: Vec<f64> = (0..n_grid).map(|k| start + k as f64 * h).collect();

    // Validity.
    let mut invalid: Vec<Option<String>> = vec![None; n_grid];
    mark(&mut invalid, start, h, &wheel_bad, true, 0.0);
    mark(&mut invalid, start, h, &pose.bad, false, 0.0);
    let mut extra_bad: Vec<(String, bool)> = Vec::new();
    if let LateralAccelerationSpec::Imu { stream, .. } = &m.lateral_acceleration {
        extra_bad.push((stream.clone(), true));
    }
    if let SideslipSpec::Column { stream, .. } = &m.sideslip {
        extra_bad.push((stream.clone(), false));
    }
    for (name, interval) in &extra_bad {
        if name != &w.stream && name != &p.stream {
            let b = gaps_of(&streams[name].t, o.max_gap_s, &format!("{name} stream"));
            mark(&mut invalid, start, h, &b, *interval, 0.0);
        }
    }

    // Resample everything on the full grid.
    let n_rl = signal::interval_rates(&ws.t, &cum_l, &grid, h);
    let n_rr = signal::interval_rates(&ws.t, &cum_r, &grid, h);
    let px = signal::interp_sorted(&pose.t, &pose.x, &grid);
    let py = signal::interp_sorted(&pose.t, &pose.y, &grid);
    let psi = signal::interp_sorted(&pose.t, &pose.psi, &grid);
    let beta: Vec<f64> = match &m.sideslip {
        SideslipSpec::Zero => vec![0.0; n_grid],
        SideslipSpec::Column { stream, column, unit, sign } => {
            let s = &streams[stream];
            let v: Vec<f64> = s.col(column).iter().map(|b| sign * b * unit.radians()).collect();
            signal::interp_sorted(&s.t, &v, &grid)
        }
    };

    // Parts: runs of valid samples; gaps: runs of invalid ones.
    let mut runs: Vec<(std::ops::Range<usize>, bool)> = Vec::new();
    let mut k = 0;
    while k < n_grid {
        let ok = invalid[k].is_none();
        let s0 = k;
        while k < n_grid && invalid[k].is_none() == ok {
            k += 1;
        }
        runs.push((s0..k, ok));
    }
    let min_samples = ((o.min_part_s / h).ceil() as usize).max(2);
    let mut gaps = Vec::new();
    let mut parts = Vec::new();
    let mut kept_ranges = Vec::new();
    for (r, ok) in &runs {
        let (t0, t1) = (r.start as f64 * h, (r.end - 1) as f64 * h);
        if *ok {
            let keep = r.len() >= min_samples;
            parts.push(PartRecord {
                t_start_s: t0,
                t_end_s: t1,
                samples: r.len(),
                kept: keep,
                dropped_because: (!keep).then(|| {
                    format!("{:.2} s is shorter than output.min_part_s = {} s", r.len() as f64 * h, o.min_part_s)
                }),
            });
            if keep {
                kept_ranges.push(r.clone());
            }
        } else {
            let mut reasons: Vec<String> = Vec::new();
            for v in invalid[r.clone()].iter().flatten() {
                if !reasons.contains(v) {
                    reasons.push(v.clone());
                }
            }
            gaps.push(GapRecord { t_start_s: t0, t_end_s: t1 + h, reasons });
        }
    }
    if kept_ranges.is_empty() {
        return Err(Error::InvalidDrive {
            context: m.path.display().to_string(),
            reason: format!(
                "no continuous part of at least output.min_part_s = {} s ({} parts, {} gaps); lower min_part_s or \
                 check the gaps",
                o.min_part_s,
                parts.len(),
                gaps.len()
            ),
        });
    }

    // Lateral acceleration on the full grid (smoothing within parts).
    let (a_y, a_y_desc): (Vec<f64>, String) = match &m.lateral_acceleration {
        LateralAccelerationSpec::Imu { stream, column, sign } => {
            let s = &streams[stream];
            let v: Vec<f64> = s.col(column).iter().map(|a| sign * a).collect();
            let cum = signal::cumulative_integral(&s.t, &v);
            (
                signal::interval_rates(&s.t, &cum, &grid, h),
                format!("IMU column '{column}' of stream '{stream}' × {sign:+}, mean over each output interval"),
            )
        }
        LateralAccelerationSpec::FromWheels { smoothing_s } => {
            let mut a = vec![0.0; n_grid];
            for k in 0..n_grid {
                // Fixed point through d·a_y (a single pass when d = 0).
                for _ in 0..3 {
                    let kin = kinematics(&Input { n_rl: n_rl[k], n_rr: n_rr[k], beta: 0.0, a_y: a[k] }, &theta0);
                    a[k] = kin.speed_m_per_s * kin.yaw_rate_rad_per_s;
                }
            }
            let width = 2 * ((smoothing_s / h / 2.0).round() as usize) + 1;
            for r in &kept_ranges {
                signal::moving_average(&mut a, r.clone(), width);
            }
            (a, format!("from wheels: v·ω of the model at θ_0 = {theta0}, smoothed over {smoothing_s} s"))
        }
        LateralAccelerationSpec::FromPose { smoothing_s } => {
            let mut a = vec![0.0; n_grid];
            for r in &kept_ranges {
                for k in r.clone() {
                    let (k0, k1) = (k.saturating_sub(1).max(r.start), (k + 1).min(r.end - 1));
                    let dt = (k1 - k0) as f64 * h;
                    let v = (px[k1] - px[k0]).hypot(py[k1] - py[k0]) / dt;
                    let om = (psi[k1] - psi[k0]) / dt;
                    a[k] = v * om;
                }
            }
            let width = 2 * ((smoothing_s / h / 2.0).round() as usize) + 1;
            for r in &kept_ranges {
                signal::moving_average(&mut a, r.clone(), width);
            }
            (
                a,
                format!(
                    "from pose: speed × yaw rate of the reference, smoothed over {smoothing_s} s (feeds the \
                     reference yaw rate into the model through d)"
                ),
            )
        }
    };

    // Jitter effect: wheel speeds from the raw stamps, same grid and parts.
    let jitter = ws.report.dejitter.as_ref().map(|_| {
        let raw_stream = Stream {
            path: ws.path.clone(),
            t: ws.t_raw.clone(),
            t_raw: ws.t_raw.clone(),
            cols: ws.cols.clone(),
            report: ws.report.clone(),
        };
        let raw = |wheel: &WheelColumn, key: &str| -> Result<Vec<f64>> {
            let cum = wheel_revolutions(m, &raw_stream, wheel, key)?;
            Ok(signal::interval_rates(&raw_stream.t, &cum, &grid, h))
        };
        let nl_raw = raw(&w.rear_left, "wheels.rear_left").unwrap_or_default();
        let nr_raw = raw(&w.rear_right, "wheels.rear_right").unwrap_or_default();
        let both = |a: &[f64], b: &[f64]| {
            let x = speed_noise_pct(a, &kept_ranges);
            let y = speed_noise_pct(b, &kept_ranges);
            ((x * x + y * y) / 2.0).sqrt()
        };
        JitterReport {
            wheel_speed_noise_raw_pct: both(&nl_raw, &nr_raw),
            wheel_speed_noise_dejittered_pct: both(&n_rl, &n_rr),
        }
    });

    // Assemble the drive from the kept parts, through the checked constructor.
    let mut sig = Signals::with_capacity(kept_ranges.iter().map(|r| r.len()).sum());
    let mut t_out = Vec::with_capacity(sig.px.capacity());
    let mut part_ranges = Vec::with_capacity(kept_ranges.len());
    for r in &kept_ranges {
        let s0 = t_out.len();
        for k in r.clone() {
            t_out.push(k as f64 * h);
            sig.push([px[k], py[k], psi[k], n_rl[k], n_rr[k], beta[k], a_y[k]]);
        }
        part_ranges.push(s0..t_out.len());
    }
    let t_of = t_out.clone();
    let d = Drive::builder(t_out, sig)
        .parts(part_ranges)
        .sample_time_s(h)
        .context(format!("import of {}", m.path.display()))
        .build()
        .map_err(|e| match e {
            Error::InvalidSample { context, column, sample, reason } => Error::InvalidDrive {
                context,
                reason: format!("{column} at t = {:.3} s: {reason}", t_of.get(sample).copied().unwrap_or(f64::NAN)),
            },
            e => e,
        })?;

    let wheel_scale = match w.signal {
        WheelSignal::TicksCumulative | WheelSignal::TicksRaw => format!(
            "ticks, one model revolution = ticks_per_rev = {} ticks: c_e is metres per {} ticks (t_r, c_d in m)",
            w.ticks_per_rev.unwrap_or(1.0),
            w.ticks_per_rev.unwrap_or(1.0)
        ),
        WheelSignal::MPerS => format!(
            "m/s divided by the nominal circumference {} m: c_e is metres per nominal revolution, c_e / {} is \
             the scale factor of the recorded speed",
            w.circumference_m.unwrap_or(1.0),
            w.circumference_m.unwrap_or(1.0)
        ),
        WheelSignal::RevPerS => "rev/s: c_e is the effective circumference, m".into(),
        WheelSignal::RadPerS => "rad/s / 2π: c_e is the effective circumference, m".into(),
    };
    let report = ImportReport {
        manifest: m.path.clone(),
        streams: streams.values().map(|s| s.report.clone()).collect(),
        output_rate_hz: o.rate_hz,
        time_origin_s: start,
        common_span_s: [0.0, end - start],
        clock_offset: ClockOffsetReport {
            estimated_s: est.map(|c| c.offset_s),
            correlation: est.map(|c| c.peak),
            correlation_pairs: est.map(|c| c.pairs),
            yaw_rate_estimate_s: est_yaw.map(|c| c.offset_s),
            yaw_rate_correlation: est_yaw.map(|c| c.peak),
            applied_s: applied,
            mode: match o.clock_offset {
                ClockOffset::Auto => "auto".into(),
                ClockOffset::Seconds(_) => "fixed".into(),
            },
        },
        gaps,
        parts,
        samples: d.len(),
        duration_s: d.len() as f64 * h,
        distance_m: d.distance_m(),
        wheel_scale,
        lateral_acceleration: a_y_desc,
        jitter,
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    Ok(ImportedDrive { drive: d, report })
}
