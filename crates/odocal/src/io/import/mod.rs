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
//!    error; repeated stamps are dropped (and counted; a warning names rows
//!    repeating a stamp with other values, and more than 10 % of a stream's
//!    rows repeating one). A stream with a
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
//!    parabola through the correlation peak. It is reported, with the
//!    peak's sharpness (curvature) and the second-best peak (for a fixed
//!    offset, skipped with a note when the search would exceed the
//!    correlation budget). With
//!    `clock_offset = "auto"` it is applied unless it is not clearly better
//!    than the manifest's offset (the streams' `time_offset_s` alone): speed
//!    correlation below 0.9, a peak uncertainty above 1 s, a second peak
//!    within 0.02 of the best, or the yaw-rate cross-check (correlation ≥
//!    0.8) more than one output sample away; then 0 s is added and the
//!    report warns. A number fixes it.
//! 5. **Gaps**: a wheel, pose or IMU gap longer than `max_gap_s`, or pose
//!    samples of rejected quality, make the affected output samples invalid;
//!    the valid samples form the continuous parts of the drive
//!    ([`Drive::parts`]), so no segment spans a gap. Parts shorter than
//!    `min_part_s` are dropped; the report says where and why.
//!
//! 6. **Reference measured**: the output sample nearest to each accepted
//!    pose sample (within half an output step) is marked as carrying a real
//!    reference measurement ([`Drive::reference_measured`], docs/method.md §2
//!    `ref_measured`); the others are interpolated between measurements.
//!
//! ## Code layout
//!
//! [`import`] is orchestration over one module per step: `source` reads a
//! stream (one file per format, see its docs for adding one), `wheels`
//! turns ticks and speeds into rotation, `pose` builds the reference,
//! `clock` estimates and applies the clock offset, `grid` finds the common
//! span, the valid samples and the parts, `lateral` derives a_y.
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
//! ## Road bank
//!
//! A derived a_y is kinematic (v·ω, horizontal), but the load transfer the
//! model's `d·a_y` stands for follows the lateral *specific force* in the
//! vehicle frame, what an IMU would measure: on a road rolled by φ
//! (positive when the left side is lower), f_y = a_y·cos φ − g·sin φ. On a
//! banked curve the two differ by about g·sin φ (≈ 0.9 m/s² at 5.4° on the
//! van's test track), with the sign of the turning direction, and the fit
//! then puts a direction-dependent term into c_d. `[lateral_acceleration.bank]`
//! measures φ from two GNSS antennas across the vehicle
//! ([`BankSpec`](manifest::BankSpec): sin φ = (h_right − h_left + height_offset_m) / baseline_m
//! where both are of accepted quality, on the pose's clock, smoothed) and
//! imports f_y instead. Two other effects of the roll are left out,
//! measured small on the test track: the wheels turn about the road normal
//! (their yaw rate is ω·cos φ: fitted t_r is cos φ short, 8 mm there), and
//! a roof antenna moves h·sin φ towards the low side (h = 2.5 m: c_e moves
//! by 1.8 mm, the cross-run ratio by 0.02).
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
//! format = "csv"              # csv (default) | mcap (with topic = "/...") | parquet (feature `parquet`)
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
//! derive_heading_baseline_m = 2.0         # chord of travel the derived heading is the direction of
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
//! # [lateral_acceleration.bank] # optional, from_wheels / from_pose only: see "Road bank"
//! # left = "gnss_left"          # the two antennas' streams (on the pose's GNSS clock)
//! # right = "gnss_right"
//! # lat = "lat_deg"             # columns of both
//! # lon = "lon_deg"
//! # alt = "alt_m"
//! # quality = { column = "fix_mode", accept = [6] }  # optional
//! # baseline_m = 1.485          # antenna separation, m
//! # height_offset_m = 0.0       # left minus right antenna height on level ground (default 0)
//! # smoothing_s = 1.0           # moving average of the roll (default 1)
//! # max_roll_deg = 20.0         # beyond: a glitch (dropped) or, above 1 % of pairs, an error (default 20)
//!
//! [sideslip]
//! source = "zero"             # zero (default) | column
//! # stream = "ins", column = "beta", unit = "rad", sign = 1
//!
//! [limits]                    # physical limits; beyond them is an error naming the time
//! max_speed_m_per_s = 100.0   # each wheel at θ_0 and the pose (default 100)
//! max_lateral_acceleration_m_per_s2 = 15.0  # |a_y| (default 15; derived a_y judged over 0.5 s)
//!
//! [noise]                     # optional: the sensor's noise, start of --method eiv
//! wheel_white_rel_sigma = 0.01  # any field of a --noise-model file (odocal::eiv::NoiseModel);
//! position_white_sigma_m = 0.03 # missing ones keep the production-car defaults
//! known = ["pose_white"]        # optional: levels held as stated, not estimated
//!
//! [reference]                 # optional: the pose reference's extrinsics
//! lever_arm = [-0.9, 0.0]     # x forward, y left, m, from the rear-axle centre (default 0, 0)
//! heading_offset = -0.0099    # reference heading minus vehicle heading, rad (default 0)
//! estimate = ["lever-arm", "heading-offset"]  # estimate them with θ (default: held)
//!
//! [calibration]               # optional: any calibration setting but the noise model and the
//! method = "batch-gn"         # extrinsics (calibrate::settings::Settings: the CLI's flags,
//! keep_one_way = true         # snake case), e.g. keep the turning-only selection on one-way turns
//! ```
//!
//! `[noise]`, `[reference]` and `[calibration]` are calibration settings, not import
//! settings: the import checks `[reference]`, keeps `[noise]` and
//! `[calibration]` as written ([`NoiseTable`], [`CalibrationTable`]) and
//! carries them on the [`ImportReport`]; the calibration reads them
//! ([`crate::calibrate::settings::ManifestSettings`]) and applies them
//! unless the command line (or a Python keyword) gives its own value, and
//! its report says what became of each.
//!
//! Resource budgets (output samples, clock search, de-jitter window) are
//! fixed and documented in [`limits`]; settings beyond them are rejected
//! before anything is allocated. Corrupt wheel rows (a count jump the
//! vehicle cannot drive that returns within a few rows, e.g. a counter read
//! as 0) are dropped and reported.
//!
//! ## Example
//!
//! ```no_run
//! # fn main() -> odocal::Result<()> {
//! use std::path::Path;
//! let manifest = odocal::Manifest::from_path(Path::new("examples/psu-mapping-van/manifest.toml"))?;
//! let (drive, report) = odocal::import(&manifest)?;
//! println!("{report}");
//! drive.write_csv("drive.csv")?;
//! # Ok(()) }
//! ```

mod bank;
mod checks;
mod clock;
mod geodesy;
mod grid;
mod lateral;
pub(crate) mod limits;
pub(crate) mod manifest;
mod pose;
pub(crate) mod report;
pub(crate) mod settings;
mod signal;
pub(crate) mod source;
pub(crate) mod stream;
#[cfg(test)]
pub(crate) mod tests;
mod wheels;

use std::collections::BTreeMap;
use std::ops::Range;
use std::path::Path;
use std::time::Instant;

pub(crate) use manifest::Manifest;
pub(crate) use manifest::{ClockOffset, LateralAccelerationSpec, PositionSpec, SideslipSpec};
pub(crate) use report::ImportReport;
pub(crate) use settings::ReferenceSpec;
pub(crate) use settings::{CalibrationTable, NoiseTable};
pub(crate) use wheels::wheel_scale;

use crate::drive::{Drive, DriveBuilder, Signals};
use crate::error::{Error, Result};
use crate::model::Theta;
use grid::Grid;
use pose::Pose;
use source::{Stream, Wanted};
use wheels::Wheels;

/// A drive imported from a manifest, with the report of what was done.
#[derive(Debug, Clone)]
pub(crate) struct ImportedDrive {
    /// The uniform drive (time starts at 0 at [`ImportReport::time_origin_s`]).
    pub drive: Drive,
    /// What was read, estimated, split and dropped.
    pub report: ImportReport,
}

/// True for a path [`load_drive`] reads as a manifest (`.toml`), false for
/// one it reads as a canonical CSV.
pub fn is_manifest_path(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("toml"))
}

/// Reads a drive from either a canonical CSV (docs/method.md §2) or a `.toml` manifest
/// (imported with [`import`]); the report is `Some` for a manifest.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// // A 60 s slice of a comma2k19 drive that the crate's tests ship.
/// let manifest = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/comma2k19-rav4/manifest.toml");
/// let (drive, report) = odocal::load_drive(manifest)?;
/// assert!(drive.len() > 0);
/// assert!(report.is_some(), "a manifest comes with its import report");
/// # Ok(()) }
/// ```
pub fn load_drive(path: impl AsRef<Path>) -> Result<(Drive, Option<ImportReport>)> {
    let path = path.as_ref();
    if is_manifest_path(path) {
        let m = Manifest::from_path(path)?;
        let ImportedDrive { drive, report } = import_drive(&m)?;
        Ok((drive, Some(report)))
    } else {
        Ok((Drive::read_csv(path)?.0, None))
    }
}

/// Whether drive `name` counts wheel revolutions as the drives before it
/// (or θ's calibration) do: `first` holds the first of them that stated a
/// wheel scale ([`ImportReport::wheel_scale`], what one model revolution
/// is, e.g. "ticks_per_rev = 40460 ticks"), by name, and the first drive
/// that states one sets it. c_e, c_d and d are per model revolution, so
/// across scales they mean other units (ticks_per_rev 40460 against 40360
/// is 0.25 % in c_e). `None` when the scales agree or either is unknown (a
/// canonical CSV states none); otherwise what differs and what to do.
///
/// ```
/// let (a, b) = ("ticks: c_e is metres per 40460 ticks", "ticks: c_e is metres per 40360 ticks");
/// let mut first = None;
/// assert!(odocal::wheel_scale_mismatch(&mut first, "drive.csv", None).is_none());
/// assert!(odocal::wheel_scale_mismatch(&mut first, "a.toml", Some(a)).is_none());
/// assert!(odocal::wheel_scale_mismatch(&mut first, "a2.toml", Some(a)).is_none());
/// assert!(odocal::wheel_scale_mismatch(&mut first, "b.toml", Some(b)).is_some_and(|w| w.starts_with("a.toml")));
/// assert_eq!(first, Some(("a.toml".to_string(), a.to_string())));
/// ```
pub fn wheel_scale_mismatch(first: &mut Option<(String, String)>, name: &str, scale: Option<&str>) -> Option<String> {
    let y = scale?;
    let Some((a, x)) = first.as_ref() else {
        *first = Some((name.to_string(), y.to_string()));
        return None;
    };
    (x != y).then(|| {
        format!(
            "{a} counts wheel revolutions as \"{x}\" and {name} as \"{y}\": c_e, c_d and d are per model revolution, so \
             they mean other units on the two; give both manifests the same [wheels] scale (the same ticks_per_rev \
             for the same encoder)"
        )
    })
}

/// Imports a drive described by a manifest: reads the streams, estimates the
/// clock offset, resamples to the output rate and splits at gaps. Returns
/// the uniform drive (time 0 at [`ImportReport::time_origin_s`]) and the
/// report of what was read, estimated, split and dropped, as
/// [`load_drive`] does.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{import, Manifest};
/// let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/comma2k19-rav4/manifest.toml");
/// let manifest = Manifest::from_path(path)?;
/// let (drive, report) = import(&manifest)?;
/// println!("{report}"); // what was read, estimated, split and dropped
/// assert!(drive.len() > 0);
/// # Ok(()) }
/// ```
pub fn import(m: &Manifest) -> Result<(Drive, ImportReport)> {
    import_drive(m).map(|i| (i.drive, i.report))
}

/// [`import`]'s drive and report as one value.
pub(crate) fn import_drive(m: &Manifest) -> Result<ImportedDrive> {
    let started = Instant::now();
    let o = &m.output;
    let h = 1.0 / o.rate_hz;
    let theta0: Theta = o.theta0();

    let mut warnings = m.unused_wheel_keys();
    let mut streams = read_streams(m, &mut warnings)?;
    let (wheels, cleaned) = Wheels::new(m, &streams[&m.wheels.stream], &mut warnings)?;
    if let (Some(cleaned), Some(ws)) = (cleaned, streams.get_mut(&m.wheels.stream)) {
        *ws = cleaned;
    }
    let (ws, ps) = (&streams[&m.wheels.stream], &streams[&m.pose.stream]);
    let wheel_bad = grid::gaps_of(&ws.t, o.max_gap_s, "wheel");
    let mut pose = pose::build_pose(m, ps, &mut warnings)?;
    check_budgets(m, &ws.t, &pose.t, h)?;

    let track = clock::WheelTrack { t: &ws.t, cum_l: &wheels.cum_l, cum_r: &wheels.cum_r, bad: &wheel_bad };
    let clock_offset = clock::align(m, &track, &pose, h, &theta0, &mut warnings)?;
    pose.shift(clock_offset.applied_s);
    let roll = bank_roll(m, &streams, clock_offset.applied_s, &mut warnings)?;

    let (start, end) = grid::common_span(m, &spans(m, &streams, &pose, roll.as_ref()), h)?;
    limits::check_samples(m, "the common span of the streams", end - start)?;
    let g = marked_grid(m, (start, end, h), &streams, &wheel_bad, &pose, roll.as_ref());

    let s = OnGrid::resample(m, &streams, &wheels, &pose, &g.t, h);
    let measured = g.measured(&pose.t);
    let hint = limits::short_span_hint(m, end - start, streams.values().map(|s| &s.report));
    let grid::Parts { gaps, parts, kept } = g.parts(m, &hint)?;
    let resampled = s.for_checks(h, start, &kept);
    checks::wheel_speeds(m, &resampled, &theta0)?;
    checks::conventions(m, &resampled, &theta0, &mut warnings)?;
    let inputs = lateral::Inputs {
        grid: &g.t,
        h,
        n_rl: &s.n_rl,
        n_rr: &s.n_rr,
        px: &s.px,
        py: &s.py,
        psi: &s.psi,
        kept: &kept,
        roll: roll.as_ref(),
    };
    let (a_y, a_y_desc) = lateral::lateral_acceleration(m, &streams, &inputs, &theta0);
    checks::lateral_acceleration(m, &resampled, &a_y)?;
    let jitter = wheels::jitter_report(m, &streams[&m.wheels.stream], &g.t, h, &kept, &s.n_rl, &s.n_rr)?;
    let d = s.assemble(m, h, &kept, &a_y, &measured)?;
    checks::lateral_convention(m, &d)?;
    // The drive checks calibrate and validate make (among them the heading
    // against the direction of travel), at θ_0: a heading in the wrong unit
    // can pass the yaw-rate checks above on a drive that turns too little
    // for them.
    if let Err(Error::InvalidDrive { reason, .. }) = crate::drive::plausibility::check_conventions(&d, &theta0, "drive")
    {
        warnings.push(format!("calibrate and validate will refuse this drive (at output.theta0): {reason}"));
    }

    let report = ImportReport {
        manifest: m.path.clone(),
        streams: streams.values().map(|s| s.report.clone()).collect(),
        output_rate_hz: o.rate_hz,
        time_origin_s: start,
        common_span_s: [0.0, end - start],
        clock_offset,
        gaps,
        parts,
        samples: d.len(),
        duration_s: d.len() as f64 * h,
        distance_m: d.distance_m(),
        wheel_scale: wheels::wheel_scale(m),
        lateral_acceleration: a_y_desc,
        jitter,
        warnings,
        noise: m.noise.clone(),
        reference: m.reference.clone(),
        calibration: m.calibration.clone(),
        elapsed_s: started.elapsed().as_secs_f64(),
    };
    Ok(ImportedDrive { drive: d, report })
}

/// The budgets, checked before anything is allocated from the spans: the
/// wheel and pose streams overlap, the clock-offset search grid over the
/// wheel span (which holds the output grid) stays within the sample budget
/// and within what the wheel stream holds, and, for `"auto"`, its
/// correlation stays within its limit (a fixed offset's estimate, only
/// reported, is skipped instead: [`clock::align`]).
fn check_budgets(m: &Manifest, wheel_t: &[f64], pose_t: &[f64], h: f64) -> Result<()> {
    let wheel_span = grid::Span::of(&format!("streams.{}", m.wheels.stream), wheel_t);
    let pose_span = grid::Span::of(&format!("streams.{} (pose)", m.pose.stream), pose_t);
    limits::check_overlap(m, &wheel_span, &pose_span)?;
    let wheel_s = wheel_span.end - wheel_span.start;
    let clock_samples = (wheel_s / h).floor();
    limits::check_samples(m, &format!("{} (the clock-offset search grid)", wheel_span.name), wheel_s)?;
    limits::check_samples_per_row(m, wheel_s, (&wheel_span.name, wheel_t.len()), (&pose_span.name, pose_t.len()))?;
    match m.output.clock_offset {
        ClockOffset::Auto => limits::check_correlation(m, clock_samples as usize),
        ClockOffset::Seconds(_) => Ok(()),
    }
}

/// The bank's roll when the manifest derives a_y with one, shifted by the
/// clock offset: it is on the antennas' GNSS clock, like the pose.
fn bank_roll(
    m: &Manifest,
    streams: &BTreeMap<String, Stream>,
    offset_s: f64,
    warnings: &mut Vec<String>,
) -> Result<Option<bank::Roll>> {
    match m.lateral_acceleration.bank() {
        Some(b) => {
            let mut r = bank::roll(m, b, &streams[&b.left], &streams[&b.right], warnings)?;
            r.shift(offset_s);
            Ok(Some(r))
        }
        None => Ok(None),
    }
}

/// The model signals (all but a_y) on the full output grid.
struct OnGrid {
    /// Rear-left rotation speed over each step, rev/s.
    n_rl: Vec<f64>,
    /// Rear-right rotation speed over each step, rev/s.
    n_rr: Vec<f64>,
    /// Reference east, m.
    px: Vec<f64>,
    /// Reference north, m.
    py: Vec<f64>,
    /// Reference heading, rad.
    psi: Vec<f64>,
    /// Sideslip, rad.
    beta: Vec<f64>,
}

impl OnGrid {
    /// The signals the checks read, on the kept parts of a grid of step `h`
    /// that starts at `origin_s` on the wheel clock.
    fn for_checks<'a>(&'a self, h: f64, origin_s: f64, kept: &'a [Range<usize>]) -> checks::Resampled<'a> {
        checks::Resampled {
            h,
            origin_s,
            kept,
            n_rl: &self.n_rl,
            n_rr: &self.n_rr,
            px: &self.px,
            py: &self.py,
            psi: &self.psi,
        }
    }

    /// Resamples: wheel rotations as rates over each step, the pose
    /// interpolated, the sideslip from its source.
    fn resample(
        m: &Manifest,
        streams: &BTreeMap<String, Stream>,
        wheels: &Wheels,
        pose: &Pose,
        grid: &[f64],
        h: f64,
    ) -> OnGrid {
        let ws = &streams[&m.wheels.stream];
        OnGrid {
            n_rl: signal::interval_rates(&ws.t, &wheels.cum_l, grid, h),
            n_rr: signal::interval_rates(&ws.t, &wheels.cum_r, grid, h),
            px: signal::interp_sorted(&pose.t, &pose.x, grid),
            py: signal::interp_sorted(&pose.t, &pose.y, grid),
            psi: signal::interp_sorted(&pose.t, &pose.psi, grid),
            beta: sideslip(m, streams, grid),
        }
    }

    /// The drive from the kept parts, through the checked constructor (time
    /// from 0 at the grid's start); an invalid sample's error gives its time.
    fn assemble(&self, m: &Manifest, h: f64, kept: &[Range<usize>], a_y: &[f64], measured: &[bool]) -> Result<Drive> {
        let mut sig = Signals::with_capacity(kept.iter().map(|r| r.len()).sum());
        let mut t_out = Vec::with_capacity(sig.px.capacity());
        let mut mask = Vec::with_capacity(sig.px.capacity());
        let mut part_ranges = Vec::with_capacity(kept.len());
        for r in kept {
            let s0 = t_out.len();
            for k in r.clone() {
                t_out.push(k as f64 * h);
                sig.push([self.px[k], self.py[k], self.psi[k], self.n_rl[k], self.n_rr[k], self.beta[k], a_y[k]]);
                mask.push(measured[k]);
            }
            part_ranges.push(s0..t_out.len());
        }
        let t_of = t_out.clone();
        DriveBuilder {
            t: t_out,
            measured: sig,
            parts: Some(part_ranges),
            reference_measured: Some(mask),
            sample_time_s: Some(h),
            context: format!("import of {}", m.path.display()),
            ..Default::default()
        }
        .build()
        .map_err(|e| match e {
            Error::InvalidSample { context, column, sample, reason } => {
                let t = t_of.get(sample).copied().unwrap_or(f64::NAN);
                // Without [pose.heading] the heading is the direction of a
                // chord of the track, not a column that could be in degrees.
                let reason = if column == "psi" && m.pose.heading.is_none() {
                    derived_heading_turns_too_fast(m, &reason)
                } else {
                    reason
                };
                Error::InvalidDrive { context, reason: format!("{column} at t = {t:.3} s: {reason}") }
            }
            e => e,
        })
    }
}

/// Why a heading derived from the positions turns too fast, with the
/// settings that help: the heading column, a longer chord (while below its
/// limit), a higher speed below which the heading is held.
fn derived_heading_turns_too_fast(m: &Manifest, reason: &str) -> String {
    let p = &m.pose;
    let longer = if p.derive_heading_baseline_m < limits::MAX_DERIVE_HEADING_BASELINE_M {
        format!(", lengthen pose.derive_heading_baseline_m (here {} m)", p.derive_heading_baseline_m)
    } else {
        String::new()
    };
    format!(
        "the heading derived from the positions (the manifest has no [pose.heading]) turns too fast: {}; it is \
         the direction of a chord of pose.derive_heading_baseline_m of travel, which the positions' noise turns \
         where it is not small against the chord: give the pose's heading ([pose.heading]){longer}, or raise \
         pose.derive_heading_min_speed_m_per_s (here {} m/s) to hold the heading through slower stretches",
        reason.split(':').next().unwrap_or(reason),
        p.derive_heading_min_speed_m_per_s
    )
}

/// The columns each stream must provide, with the manifest keys asking.
fn wanted_columns(m: &Manifest) -> BTreeMap<String, Vec<Wanted>> {
    let mut needs: BTreeMap<String, Vec<Wanted>> = BTreeMap::new();
    let mut need = |stream: &str, col: &str, key: &str| {
        needs.entry(stream.to_string()).or_default().push(Wanted { column: col.to_string(), key: key.to_string() });
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
    if let Some(b) = m.lateral_acceleration.bank() {
        for s in [&b.left, &b.right] {
            need(s, &b.lat, "lateral_acceleration.bank.lat");
            need(s, &b.lon, "lateral_acceleration.bank.lon");
            need(s, &b.alt, "lateral_acceleration.bank.alt");
            if let Some(q) = &b.quality {
                need(s, &q.column, "lateral_acceleration.bank.quality.column");
            }
        }
    }
    needs
}

/// Reads every stream a signal refers to.
fn read_streams(m: &Manifest, warnings: &mut Vec<String>) -> Result<BTreeMap<String, Stream>> {
    let mut streams = BTreeMap::new();
    for (name, wanted) in &wanted_columns(m) {
        streams.insert(name.clone(), source::read_stream(m, name, wanted, warnings)?);
    }
    Ok(streams)
}

/// The streams other than the wheels and the pose whose gaps invalidate
/// samples: `(name, interval)` (IMU gaps invalidate intervals, sideslip
/// gaps points).
/// The output grid over `[start, end]` with every stream's gaps marked:
/// the wheel gaps `wheel_bad` (intervals), the pose's and the roll's bad
/// stretches (samples), then the extra streams' gaps as
/// [`extra_streams`] says. Shared by the whole import and the streamed
/// import's warm-up prefix check.
fn marked_grid(
    m: &Manifest,
    (start, end, h): (f64, f64, f64),
    streams: &BTreeMap<String, Stream>,
    wheel_bad: &[grid::BadInterval],
    pose: &Pose,
    roll: Option<&bank::Roll>,
) -> Grid {
    let mut g = Grid::new(start, end, h);
    g.mark(wheel_bad, true);
    g.mark(&pose.bad, false);
    if let Some(r) = roll {
        g.mark(&r.bad, false);
    }
    for (name, interval) in extra_streams(m) {
        let b = grid::gaps_of(&streams[&name].t, m.output.max_gap_s, &format!("{name} stream"));
        g.mark(&b, interval);
    }
    g
}

fn extra_streams(m: &Manifest) -> Vec<(String, bool)> {
    let mut extra: Vec<(String, bool)> = Vec::new();
    if let LateralAccelerationSpec::Imu { stream, .. } = &m.lateral_acceleration {
        extra.push((stream.clone(), true));
    }
    if let SideslipSpec::Column { stream, .. } = &m.sideslip {
        extra.push((stream.clone(), false));
    }
    extra.retain(|(name, _)| name != &m.wheels.stream && name != &m.pose.stream);
    extra
}

/// The time span of every stream, the pose (and the bank's roll) after the
/// clock offset.
fn spans(m: &Manifest, streams: &BTreeMap<String, Stream>, pose: &Pose, roll: Option<&bank::Roll>) -> Vec<grid::Span> {
    let (w, p) = (&m.wheels.stream, &m.pose.stream);
    let antenna = |name: &str| m.lateral_acceleration.bank().is_some_and(|b| b.left == name || b.right == name);
    let ws = &streams[w];
    let mut spans = vec![
        grid::Span { name: format!("streams.{w}"), start: ws.t[0], end: ws.t[ws.t.len() - 1] },
        grid::Span {
            name: format!("streams.{p} (pose, after the clock offset)"),
            start: pose.t[0],
            end: pose.t[pose.t.len() - 1],
        },
    ];
    for (name, s) in streams {
        if name != w && name != p && !antenna(name) {
            spans.push(grid::Span { name: format!("streams.{name}"), start: s.t[0], end: s.t[s.t.len() - 1] });
        }
    }
    if let Some(r) = roll {
        spans.push(grid::Span {
            name: "lateral_acceleration.bank (roll, both antennas accepted, after the clock offset)".into(),
            start: r.t[0],
            end: r.t[r.t.len() - 1],
        });
    }
    spans
}

/// The sideslip on the grid.
fn sideslip(m: &Manifest, streams: &BTreeMap<String, Stream>, grid: &[f64]) -> Vec<f64> {
    match &m.sideslip {
        SideslipSpec::Zero => vec![0.0; grid.len()],
        SideslipSpec::Column { stream, column, unit, sign } => {
            let s = &streams[stream];
            let v: Vec<f64> = s.col(column).iter().map(|b| sign * b * unit.radians()).collect();
            signal::interp_sorted(&s.t, &v, grid)
        }
    }
}
