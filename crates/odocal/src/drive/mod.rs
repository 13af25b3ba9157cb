//! A drive: one uniformly sampled time series of reference poses and model
//! inputs (docs/method.md §2), its checked constructor and its canonical CSV reader and
//! writer ([`csv`](self#canonical-csv)).
//!
//! A drive may consist of several continuous *parts* (after a gap in a real
//! log, say); time is uniform within each part and segments never span two.
//!
//! Every path that makes a [`Drive`] — the CSV reader, the multi-stream
//! importer, the simulator, numpy arrays in the Python package — goes through
//! one checked constructor, [`DriveBuilder::build`]. It rejects a column of
//! the wrong length, a non-finite value, time that does not increase and a
//! non-uniform sample step, naming the column and the sample index
//! ([`Error::InvalidSample`]); the CSV reader turns the sample index into
//! the file's line.
//!
//! # Canonical CSV
//!
//! [`Drive::read_csv`] / [`Drive::write_csv`]: columns `t, px, py, psi, n_rl,
//! n_rr, beta, a_y` in any order, optional `ref_measured` (0/1) and `part`
//! (integer), truth columns `*_true` for simulated drives, and any extra
//! columns (numbers or text), carried along unchanged. [`DriveStream`]
//! reads the same file as a stream, in chunks, in memory that does not
//! grow with the drive.
//!
//! # Example
//!
//! ```
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal::{DriveBuilder, Signals};
//! let n = 100;
//! let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.025).collect();
//! // One sample `[px, py, psi, n_rl, n_rr, beta, a_y]` at a time.
//! let s: Signals = (0..n).map(|k| [k as f64 * 0.25, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]).collect();
//! let drive = DriveBuilder { t, measured: s, context: "my arrays".into(), ..Default::default() }.build()?;
//! assert_eq!(drive.len(), 100);
//! assert!((drive.sample_time_s() - 0.025).abs() < 1e-12);
//! // Bad data is rejected, naming the column and the sample.
//! let mut bad = drive.measured().clone();
//! bad.n_rl[7] = f64::NAN;
//! let b = DriveBuilder { t: drive.t().to_vec(), measured: bad, context: "my arrays".into(), ..Default::default() };
//! let e = b.build().unwrap_err();
//! assert_eq!(e.to_string(), "my arrays: column 'n_rl', sample 7: value NaN is not finite");
//! # Ok(()) }
//! ```

mod concat;
pub(crate) mod correlate;
pub(crate) mod csv;
pub(crate) mod csv_lines;
pub(crate) mod fingerprint;
pub(crate) mod plausibility;
pub mod segment;
pub(crate) mod shared;
pub(crate) mod stream;

use std::ops::Range;

pub(crate) use self::stream::Unwrap;
pub(crate) use self::stream::{DriveStream, StreamChunk};

pub(crate) use self::csv::{clip, echo};
use crate::error::{Error, Result};
use crate::model::extrinsics::{axle_pose, Extrinsics};
pub(crate) use crate::model::limits::echo_num;
use crate::model::limits::PhysicalLimits;
use crate::model::{Input, State};

/// Relative tolerance on the uniformity of the sample step (docs/method.md §2: 1 %).
pub(crate) const STEP_UNIFORMITY_TOL: f64 = 0.01;

/// Names of the seven signal columns of [`Signals`], in [`Signals::columns`] order.
pub(crate) const SIGNAL_NAMES: [&str; 7] = ["px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"];

/// The seven signals of a drive sample by sample: reference pose and model
/// inputs. The same type holds the measured columns and, for simulated
/// drives, the noise-free truth.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Signals {
    /// Reference x position, m (local metric frame).
    pub px: Vec<f64>,
    /// Reference y position, m.
    pub py: Vec<f64>,
    /// Reference heading, rad, counter-clockwise from the x axis (east in
    /// ENU), pointing forward (unwrapped by the constructor).
    pub psi: Vec<f64>,
    /// Rear-left wheel rotation speed, rev/s.
    pub n_rl: Vec<f64>,
    /// Rear-right wheel rotation speed, rev/s.
    pub n_rr: Vec<f64>,
    /// Sideslip angle, rad (0 when unknown): the direction of travel
    /// minus the heading, positive when the velocity points to the left of
    /// the heading (counter-clockwise, as ψ); the model moves along ψ + β.
    pub beta: Vec<f64>,
    /// Lateral acceleration, m/s², positive to the left.
    pub a_y: Vec<f64>,
}

/// Appends samples `[px, py, psi, n_rl, n_rr, beta, a_y]` (the order of
/// [`Signals::columns`]).
impl Extend<[f64; 7]> for Signals {
    fn extend<I: IntoIterator<Item = [f64; 7]>>(&mut self, samples: I) {
        for v in samples {
            self.push(v);
        }
    }
}

/// Signals of samples `[px, py, psi, n_rl, n_rr, beta, a_y]` (the order of
/// [`Signals::columns`]).
impl FromIterator<[f64; 7]> for Signals {
    fn from_iter<I: IntoIterator<Item = [f64; 7]>>(samples: I) -> Self {
        let samples = samples.into_iter();
        let mut s = Signals::with_capacity(samples.size_hint().0);
        s.extend(samples);
        s
    }
}

impl Signals {
    /// Empty signals with room for `n` samples.
    pub(crate) fn with_capacity(n: usize) -> Signals {
        let v = || Vec::with_capacity(n);
        Signals { px: v(), py: v(), psi: v(), n_rl: v(), n_rr: v(), beta: v(), a_y: v() }
    }

    /// Appends one sample `[px, py, psi, n_rl, n_rr, beta, a_y]` (outside
    /// the crate: the `Extend` and `FromIterator` impls).
    pub(crate) fn push(&mut self, v: [f64; 7]) {
        for (col, x) in self.columns_mut().into_iter().zip(v) {
            col.push(x);
        }
    }

    /// The columns with their names, in `SIGNAL_NAMES` order.
    pub fn columns(&self) -> [(&'static str, &[f64]); 7] {
        [
            ("px", &self.px),
            ("py", &self.py),
            ("psi", &self.psi),
            ("n_rl", &self.n_rl),
            ("n_rr", &self.n_rr),
            ("beta", &self.beta),
            ("a_y", &self.a_y),
        ]
    }

    fn columns_mut(&mut self) -> [&mut Vec<f64>; 7] {
        [&mut self.px, &mut self.py, &mut self.psi, &mut self.n_rl, &mut self.n_rr, &mut self.beta, &mut self.a_y]
    }

    /// The samples in `r` as new signals.
    pub(crate) fn slice(&self, r: Range<usize>) -> Signals {
        let c = |v: &Vec<f64>| v[r.clone()].to_vec();
        Signals {
            px: c(&self.px),
            py: c(&self.py),
            psi: c(&self.psi),
            n_rl: c(&self.n_rl),
            n_rr: c(&self.n_rr),
            beta: c(&self.beta),
            a_y: c(&self.a_y),
        }
    }
}

/// The values of an extra column: numbers, or text when any field of the
/// column is not a number (a label, a status string).
#[derive(Debug, Clone, PartialEq)]
pub enum ExtraValues {
    /// A numeric column.
    Numbers(Vec<f64>),
    /// A text column, kept as read.
    Text(Vec<String>),
}

impl ExtraValues {
    /// Number of values.
    pub(crate) fn len(&self) -> usize {
        match self {
            ExtraValues::Numbers(v) => v.len(),
            ExtraValues::Text(v) => v.len(),
        }
    }

    fn slice(&self, r: Range<usize>) -> ExtraValues {
        match self {
            ExtraValues::Numbers(v) => ExtraValues::Numbers(v[r].to_vec()),
            ExtraValues::Text(v) => ExtraValues::Text(v[r].to_vec()),
        }
    }
}

/// A named column odocal does not use, carried along (written after the
/// standard ones).
#[derive(Debug, Clone, PartialEq)]
pub struct ExtraColumn {
    /// Column name.
    pub name: String,
    /// Its values, one per sample.
    pub values: ExtraValues,
}

/// One drive, stored column by column; made only by [`DriveBuilder::build`]
/// (or the readers that call it), so every `Drive` has passed its checks.
#[derive(Debug, Clone, PartialEq)]
pub struct Drive {
    t: Vec<f64>,
    measured: Signals,
    truth: Option<Signals>,
    reference_measured: Option<Vec<bool>>,
    extra: Vec<ExtraColumn>,
    parts: Vec<Range<usize>>,
    sample_time_s: f64,
    /// The first sample of each drive this one was joined from
    /// ([`Drive::concat`]); `[0]` for one drive.
    drive_starts: Vec<usize>,
    /// What [`Drive::concat`] added to each of those drives' time stamps
    /// (one per `drive_starts`); `[0]` for one drive.
    drive_time_shifts_s: Vec<f64>,
}

/// The checked constructor of a [`Drive`]: the time and the measured
/// signals, optionally the truth, parts, a reference mask and extra columns;
/// fill the fields (the rest from [`Default`]) and call
/// [`build`](DriveBuilder::build).
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::{DriveBuilder, Signals};
/// let s: Signals = (0..4).map(|k| [k as f64 * 0.25, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]).collect();
/// let t = vec![0.0, 0.025, 0.05, 0.075];
/// let drive = DriveBuilder { t, measured: s, part_ids: Some(vec![0, 0, 1, 1]), ..Default::default() }.build()?;
/// assert_eq!(drive.parts(), &[0..2, 2..4]);
/// # Ok(()) }
/// ```
#[derive(Debug, Clone)]
#[must_use = "a builder does nothing until .build()"]
pub struct DriveBuilder {
    /// Where the data come from (a path, "simulator", "numpy arrays"), used
    /// in error messages. Default `"drive"`.
    pub context: String,
    /// Time stamps, s, strictly increasing.
    pub t: Vec<f64>,
    /// The measured signals, one value per time stamp.
    pub measured: Signals,
    /// The noise-free truth (simulated drives).
    pub truth: Option<Signals>,
    /// Per-sample flag: true where the reference pose was really measured
    /// (not interpolated or held). `None` means every sample is measured.
    pub reference_measured: Option<Vec<bool>>,
    /// Extra columns carried along with the drive, each named once; a name
    /// may not be empty, hold a control character or white space at either
    /// end, or be one of the drive CSV's own columns (`t`, `px`, …, the
    /// `*_true` columns, `ref_measured`, `part`), so that the drive's CSV
    /// reads back as the same drive.
    pub extra: Vec<ExtraColumn>,
    /// Per-sample part ids, non-negative integers as a CSV's `part`
    /// column holds them: a new part starts wherever the id changes.
    /// Give this or [`parts`](DriveBuilder::parts), not both; neither
    /// makes one part.
    pub part_ids: Option<Vec<i64>>,
    /// Parts as consecutive index ranges that cover every sample in order.
    pub parts: Option<Vec<Range<usize>>>,
    /// The nominal sample time, s, when the source knows it (a simulator, a
    /// resampler): steps are checked against it instead of their mean, and
    /// it is kept exactly as given. `None` infers it from the time stamps.
    pub sample_time_s: Option<f64>,
    /// The physical limits the drive is checked against (default
    /// [`PhysicalLimits::default`], the table of [`crate::model::PhysicalLimits`]).
    pub limits: PhysicalLimits,
}

impl Default for DriveBuilder {
    fn default() -> Self {
        DriveBuilder {
            context: "drive".into(),
            t: Vec::new(),
            measured: Signals::default(),
            truth: None,
            reference_measured: None,
            extra: Vec::new(),
            part_ids: None,
            parts: None,
            sample_time_s: None,
            limits: PhysicalLimits::default(),
        }
    }
}

impl DriveBuilder {
    /// Checks everything and makes the drive: equal column lengths, finite
    /// values, strictly increasing time, a uniform step within each part
    /// (within `STEP_UNIFORMITY_TOL`); infers t_s and unwraps the heading;
    /// then checks the `PhysicalLimits`.
    ///
    /// # Errors
    /// [`Error::InvalidSample`] naming the column and sample index, or
    /// [`Error::InvalidDrive`] for whole-drive problems (no samples, too few
    /// to infer t_s, bad part ranges, an extra column's name that is
    /// reserved, repeated, empty or has control characters).
    pub fn build(self) -> Result<Drive> {
        let DriveBuilder {
            context,
            t,
            mut measured,
            mut truth,
            reference_measured,
            extra,
            part_ids,
            parts,
            sample_time_s,
            limits,
        } = self;
        limits.validate()?;
        let n = t.len();
        let err = BuildErrors { context: &context };
        if n == 0 {
            return Err(err.invalid("no samples".into()));
        }
        if let Some(i) = t.iter().position(|v| !v.is_finite()) {
            return Err(err.sample("t", i, format!("value {} is not finite", t[i])));
        }
        check_signals(&measured, "", n, &err)?;
        if let Some(tr) = &truth {
            check_signals(tr, "_true", n, &err)?;
        }
        if let Some(m) = &reference_measured {
            if m.len() != n {
                return Err(err.invalid(format!("column ref_measured has {} samples, t has {n}", m.len())));
            }
        }
        for (k, c) in extra.iter().enumerate() {
            if let Some(problem) = csv::extra_name_problem(&c.name) {
                return Err(err.invalid(format!("extra column '{}' {problem}", csv::echo(&c.name))));
            }
            if extra[..k].iter().any(|e| e.name == c.name) {
                return Err(err.invalid(format!("extra column '{}' is given twice", csv::echo(&c.name))));
            }
            if c.values.len() != n {
                return Err(err.invalid(format!("column {} has {} samples, t has {n}", c.name, c.values.len())));
            }
        }
        let parts = resolve_parts(part_ids, parts, n, &err)?;
        check_increasing(&t, &err)?;
        let ts = sample_time(&t, &parts, sample_time_s, &err)?;
        check_uniform_steps(&t, &parts, ts, sample_time_s.is_some(), &err)?;
        unwrap_in_place(&mut measured.psi);
        if let Some(tr) = truth.as_mut() {
            unwrap_in_place(&mut tr.psi);
        }
        let drive = Drive {
            t,
            measured,
            truth,
            reference_measured,
            extra,
            parts,
            sample_time_s: ts,
            drive_starts: vec![0],
            drive_time_shifts_s: vec![0.0],
        };
        plausibility::check_limits(&drive, &limits, &context)?;
        Ok(drive)
    }
}

/// The errors of a drive being built, naming where its data come from.
struct BuildErrors<'a> {
    /// The builder's context.
    context: &'a str,
}

impl BuildErrors<'_> {
    /// A problem of the whole drive.
    fn invalid(&self, reason: String) -> Error {
        Error::InvalidDrive { context: self.context.to_string(), reason }
    }

    /// A problem of one sample of one column.
    fn sample(&self, column: &str, sample: usize, reason: String) -> Error {
        Error::InvalidSample { context: self.context.to_string(), column: column.to_string(), sample, reason }
    }
}

/// Every column of `sig` (named with `suffix`) has `n` finite samples.
fn check_signals(sig: &Signals, suffix: &str, n: usize, err: &BuildErrors<'_>) -> Result<()> {
    for (name, col) in sig.columns() {
        let name = format!("{name}{suffix}");
        if col.len() != n {
            return Err(err.invalid(format!("column {name} has {} samples, t has {n}", col.len())));
        }
        if let Some(i) = col.iter().position(|v| !v.is_finite()) {
            return Err(err.sample(&name, i, format!("value {} is not finite", col[i])));
        }
    }
    Ok(())
}

/// The parts as index ranges: one part; a new part wherever the id
/// (non-negative) changes; or the given ranges, which must be non-empty, consecutive and
/// cover the `n` samples.
fn resolve_parts(
    ids: Option<Vec<i64>>,
    ranges: Option<Vec<Range<usize>>>,
    n: usize,
    err: &BuildErrors<'_>,
) -> Result<Vec<Range<usize>>> {
    match (ids, ranges) {
        (None, None) => Ok(vec![0..n]),
        (Some(_), Some(_)) => Err(err.invalid("both part ids and part ranges given; give one of them".into())),
        (Some(ids), None) => {
            if ids.len() != n {
                return Err(err.invalid(format!("column part has {} samples, t has {n}", ids.len())));
            }
            // As the CSV's `part` column: ids are 0, 1, 2, ….
            if let Some(i) = ids.iter().position(|id| *id < 0) {
                return Err(err.sample(
                    "part",
                    i,
                    format!("part id {} is not a non-negative integer (parts are numbered 0, 1, 2, …)", ids[i]),
                ));
            }
            let mut parts = Vec::new();
            let mut start = 0;
            for i in 1..=n {
                if i == n || ids[i] != ids[i - 1] {
                    parts.push(start..i);
                    start = i;
                }
            }
            Ok(parts)
        }
        (None, Some(r)) => {
            let mut next = 0;
            for p in &r {
                if p.start != next || p.end <= p.start {
                    return Err(err.invalid(format!(
                        "parts must be non-empty consecutive ranges covering every sample; got {r:?}"
                    )));
                }
                next = p.end;
            }
            if next != n {
                return Err(err.invalid(format!("parts cover {next} samples, the drive has {n}")));
            }
            Ok(r)
        }
    }
}

/// Time strictly increasing everywhere.
fn check_increasing(t: &[f64], err: &BuildErrors<'_>) -> Result<()> {
    for i in 1..t.len() {
        if t[i].partial_cmp(&t[i - 1]) != Some(std::cmp::Ordering::Greater) {
            let (now, before) = (echo_num(t[i]), echo_num(t[i - 1]));
            return Err(err.sample("t", i, format!("time is not strictly increasing ({now} after {before})")));
        }
    }
    Ok(())
}

/// t_s: the nominal one when given (a positive number), else the mean step
/// over all parts.
fn sample_time(t: &[f64], parts: &[Range<usize>], nominal: Option<f64>, err: &BuildErrors<'_>) -> Result<f64> {
    let (mut span, mut steps) = (0.0, 0usize);
    for r in parts {
        if r.len() >= 2 {
            span += t[r.end - 1] - t[r.start];
            steps += r.len() - 1;
        }
    }
    match nominal {
        Some(ts) if ts.is_finite() && ts > 0.0 => Ok(ts),
        Some(ts) => Err(err.invalid(format!("sample time {ts} s is not a positive number"))),
        None if steps == 0 && parts.len() > 1 => Err(err.invalid(format!(
            "{} parts of one sample each: the part ids change at every sample; a part is a continuous stretch with \
             one id (e.g. 0, 0, 0, 1, 1, 1)",
            parts.len()
        ))),
        None if steps == 0 => Err(err.invalid(format!("{} sample(s): too few to infer the sample time", t.len()))),
        None => Ok(span / steps as f64),
    }
}

/// Every step within a part is within [`STEP_UNIFORMITY_TOL`] of `ts`
/// (the `nominal` step, or the mean). Against the mean, the error names
/// the first step off the median step: one long gap moves the mean off
/// every other step, and the gap is what to fix.
fn check_uniform_steps(t: &[f64], parts: &[Range<usize>], ts: f64, nominal: bool, err: &BuildErrors<'_>) -> Result<()> {
    let off = |dt: f64, ts: f64| (dt - ts).abs() > STEP_UNIFORMITY_TOL * ts;
    let steps = || parts.iter().flat_map(|r| r.start + 1..r.end).map(|i| (i, t[i] - t[i - 1]));
    let Some((i, dt)) = steps().find(|&(_, dt)| off(dt, ts)) else { return Ok(()) };
    let (i, dt, ts, which) = if nominal {
        (i, dt, ts, "nominal")
    } else {
        let mut all: Vec<f64> = steps().map(|(_, dt)| dt).collect();
        let mid = all.len() / 2;
        let median = *all.select_nth_unstable_by(mid, f64::total_cmp).1;
        match steps().find(|&(_, dt)| off(dt, median)) {
            Some((j, dj)) if median > 0.0 => (j, dj, median, "median"),
            _ => (i, dt, ts, "mean"),
        }
    };
    let num = |v: f64| if v.abs() >= 1e9 { format!("{v:e}") } else { format!("{v:.6}") };
    let (dt, ts) = (num(dt), num(ts));
    Err(err.sample(
        "t",
        i,
        format!(
            "sample step {dt} s differs from the {which} step {ts} s by more than 1 %; the time must be uniform \
             (resample the log, or mark gaps with a 'part' column)"
        ),
    ))
}

// A built drive has samples (`DriveBuilder::build` refuses none), so an
// `is_empty` would always be false.
#[allow(clippy::len_without_is_empty)]
impl Drive {
    /// Number of samples (at least one: a drive without samples is not built).
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Time stamps, s.
    pub fn t(&self) -> &[f64] {
        &self.t
    }
    /// Reference x position, m.
    pub(crate) fn px(&self) -> &[f64] {
        &self.measured.px
    }
    /// Reference y position, m.
    pub(crate) fn py(&self) -> &[f64] {
        &self.measured.py
    }
    /// Reference heading, rad, unwrapped.
    pub(crate) fn psi(&self) -> &[f64] {
        &self.measured.psi
    }
    /// Measured rear-left wheel rotation speed, rev/s.
    pub(crate) fn n_rl(&self) -> &[f64] {
        &self.measured.n_rl
    }
    /// Measured rear-right wheel rotation speed, rev/s.
    pub(crate) fn n_rr(&self) -> &[f64] {
        &self.measured.n_rr
    }
    /// Sideslip angle, rad.
    pub(crate) fn beta(&self) -> &[f64] {
        &self.measured.beta
    }
    /// Lateral acceleration, m/s², positive to the left.
    pub(crate) fn a_y(&self) -> &[f64] {
        &self.measured.a_y
    }
    /// All measured signals.
    pub fn measured(&self) -> &Signals {
        &self.measured
    }
    /// The noise-free truth of a simulated drive.
    pub fn truth(&self) -> Option<&Signals> {
        self.truth.as_ref()
    }
    /// Per-sample flag: true where the reference was really measured; `None`
    /// means every sample is.
    pub fn reference_measured(&self) -> Option<&[bool]> {
        self.reference_measured.as_deref()
    }
    /// True when the reference pose was really measured at sample `i`.
    #[cfg(test)]
    pub(crate) fn is_reference_measured(&self, i: usize) -> bool {
        self.reference_measured.as_ref().is_none_or(|m| m[i])
    }
    /// Extra columns carried along.
    pub fn extra(&self) -> &[ExtraColumn] {
        &self.extra
    }
    /// The extra column `name`, if present.
    #[cfg(test)]
    pub(crate) fn extra_column(&self, name: &str) -> Option<&ExtraColumn> {
        self.extra.iter().find(|c| c.name == name)
    }
    /// Continuous parts as index ranges, in order, covering every sample.
    pub fn parts(&self) -> &[Range<usize>] {
        &self.parts
    }
    /// The first sample of each drive this one was joined from
    /// ([`Drive::concat`], in the order given); `[0]` for a drive that was
    /// not joined. A joint calibration fits each drive's own reference
    /// heading offset.
    pub fn drive_starts(&self) -> &[usize] {
        &self.drive_starts
    }
    /// The index (into [`Drive::drive_starts`]) of the drive that sample
    /// `i` came from.
    pub(crate) fn drive_of_sample(&self, i: usize) -> usize {
        self.drive_starts.partition_point(|&b| b <= i).saturating_sub(1)
    }
    /// The time of sample `i` on the clock of the drive it came from: its
    /// time stamp less the shift [`Drive::concat`] gave that drive's stamps
    /// to follow the previous drive (the stamp itself for a drive that was
    /// not joined, or not shifted). What that drive's own file and import
    /// report call the sample's time.
    pub fn own_time_s(&self, i: usize) -> f64 {
        self.t[i] - self.drive_time_shifts_s.get(self.drive_of_sample(i)).copied().unwrap_or(0.0)
    }
    /// Sample time t_s, s.
    pub fn sample_time_s(&self) -> f64 {
        self.sample_time_s
    }

    /// Reference pose at sample `i`.
    #[inline]
    pub(crate) fn pose(&self, i: usize) -> State {
        State::new(self.measured.px[i], self.measured.py[i], self.measured.psi[i])
    }

    /// Measured inputs at sample `i`.
    #[inline]
    pub(crate) fn input(&self, i: usize) -> Input {
        let m = &self.measured;
        Input { n_rl: m.n_rl[i], n_rr: m.n_rr[i], beta: m.beta[i], a_y: m.a_y[i] }
    }

    /// Total path length of the reference, m (sum of position increments within parts).
    pub fn distance_m(&self) -> f64 {
        let (px, py) = (self.px(), self.py());
        self.parts.iter().flat_map(|r| (r.start + 1..r.end).map(|i| (px[i] - px[i - 1]).hypot(py[i] - py[i - 1]))).sum()
    }

    /// The same drive with the extra column `column` added, replacing one of
    /// the same name.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] when its length differs from the drive's, or
    /// its name is empty, has a control character or white space at either
    /// end, or is one of the drive CSV's own columns (`t`, `px`, …, the
    /// `*_true` columns, `ref_measured`, `part`).
    pub fn with_extra(mut self, column: ExtraColumn) -> Result<Drive> {
        if let Some(problem) = csv::extra_name_problem(&column.name) {
            return Err(Error::InvalidDrive {
                context: format!("extra column '{}'", csv::echo(&column.name)),
                reason: format!("the name {problem}"),
            });
        }
        if column.values.len() != self.len() {
            return Err(Error::InvalidDrive {
                context: format!("extra column {}", column.name),
                reason: format!("{} values, the drive has {} samples", column.values.len(), self.len()),
            });
        }
        self.extra.retain(|c| c.name != column.name);
        self.extra.push(column);
        Ok(self)
    }

    /// The samples with `t_start_s ≤ t < t_end_s` as a new drive; parts are
    /// clipped to the window (extra columns, the reference mask and the truth
    /// come along).
    #[cfg(test)]
    pub(crate) fn window(&self, t_start_s: f64, t_end_s: f64) -> Result<Drive> {
        let a = self.t.partition_point(|&t| t < t_start_s);
        let b = self.t.partition_point(|&t| t < t_end_s);
        if a >= b {
            return Err(Error::InvalidDrive {
                context: "time window".into(),
                reason: format!(
                    "no samples in [{t_start_s}, {t_end_s}) s; the drive spans {:.3} … {:.3} s",
                    self.t.first().copied().unwrap_or(f64::NAN),
                    self.t.last().copied().unwrap_or(f64::NAN)
                ),
            });
        }
        self.slice(a..b)
    }

    /// Splits the drive at time `t_split_s`: samples before it and from it on.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] when either side would be empty or too short to
    /// infer the sample time.
    pub(crate) fn split_at_time(&self, t_split_s: f64) -> Result<(Drive, Drive)> {
        let k = self.t.partition_point(|&t| t < t_split_s);
        if k == 0 || k >= self.len() {
            return Err(Error::InvalidDrive {
                context: "split".into(),
                reason: format!(
                    "t = {t_split_s} s is outside the drive ({:.3} … {:.3} s)",
                    self.t[0],
                    self.t[self.len() - 1]
                ),
            });
        }
        Ok((self.slice(0..k)?, self.slice(k..self.len())?))
    }

    /// The samples in `r` as a new drive (parts clipped).
    fn slice(&self, r: Range<usize>) -> Result<Drive> {
        let truth = self.truth.as_ref().map(|t| t.slice(r.clone()));
        self.rebuild(self.t[r.clone()].to_vec(), self.measured.slice(r.clone()), truth, r)
    }

    /// A drive of samples `r` of this one with new columns; parts, mask and
    /// extra columns are taken from `r`.
    fn rebuild(&self, t: Vec<f64>, measured: Signals, truth: Option<Signals>, r: Range<usize>) -> Result<Drive> {
        let parts = self
            .parts
            .iter()
            .filter_map(|p| {
                let (s, e) = (p.start.max(r.start), p.end.min(r.end));
                (s < e).then(|| s - r.start..e - r.start)
            })
            .collect();
        // Keep the parent's t_s: a sub-drive is sampled like the drive it came from.
        let mut d = DriveBuilder {
            t,
            measured,
            truth,
            reference_measured: self.reference_measured.as_ref().map(|m| m[r.clone()].to_vec()),
            extra: self
                .extra
                .iter()
                .map(|c| ExtraColumn { name: c.name.clone(), values: c.values.slice(r.clone()) })
                .collect(),
            parts: Some(parts),
            sample_time_s: Some(self.sample_time_s),
            // Samples of a drive that passed its limits: no need to check again.
            limits: PhysicalLimits::NONE,
            ..Default::default()
        }
        .build()?;
        // The joined drives that reach into `r`, from where they do, with their shifts.
        let reach: Vec<usize> = (0..self.drive_starts.len())
            .filter(|&i| {
                self.drive_starts[i] < r.end && self.drive_starts.get(i + 1).is_none_or(|&next| next > r.start)
            })
            .collect();
        d.drive_starts = reach.iter().map(|&i| self.drive_starts[i].max(r.start) - r.start).collect();
        d.drive_time_shifts_s =
            reach.iter().map(|&i| self.drive_time_shifts_s.get(i).copied().unwrap_or(0.0)).collect();
        Ok(d)
    }
}

/// Unwraps an angle series in place: every step larger than π in magnitude
/// is taken as a 2π wrap.
pub(crate) fn unwrap_in_place(a: &mut [f64]) {
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut offset = 0.0;
    let mut prev_raw = match a.first() {
        Some(v) => *v,
        None => return,
    };
    for v in a.iter_mut().skip(1) {
        let raw = *v;
        let d = raw - prev_raw;
        if d > std::f64::consts::PI {
            offset -= two_pi * ((d + std::f64::consts::PI) / two_pi).floor();
        } else if d < -std::f64::consts::PI {
            offset += two_pi * ((-d + std::f64::consts::PI) / two_pi).floor();
        }
        prev_raw = raw;
        *v = raw + offset;
    }
}

/// A copy of `drive` whose reference poses are the axle poses they imply
/// under `e` ([`axle_pose`] per sample); wheels, parts and the
/// reference-measured mask are kept, truth and extra columns dropped. The
/// 3-step method's input compensation and the EIV filter run on it.
pub(crate) fn axle_reference_drive(drive: &Drive, e: &Extrinsics) -> Result<Drive> {
    axle_reference_drive_by(drive, |_| *e)
}

/// [`axle_reference_drive`] with the extrinsics of each sample `e(i)` (a
/// joint calibration's drives each with their own heading offset).
pub(crate) fn axle_reference_drive_by(drive: &Drive, e: impl Fn(usize) -> Extrinsics) -> Result<Drive> {
    let mut m = drive.measured().clone();
    for i in 0..drive.len() {
        let x = axle_pose(&drive.pose(i), &e(i));
        (m.px[i], m.py[i], m.psi[i]) = (x[0], x[1], x[2]);
    }
    let mut d = DriveBuilder {
        t: drive.t().to_vec(),
        measured: m,
        parts: Some(drive.parts().to_vec()),
        sample_time_s: Some(drive.sample_time_s()),
        context: "axle reference".into(),
        reference_measured: drive.reference_measured().map(<[bool]>::to_vec),
        ..Default::default()
    }
    .build()?;
    d.drive_starts.clone_from(&drive.drive_starts);
    d.drive_time_shifts_s.clone_from(&drive.drive_time_shifts_s);
    Ok(d)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn signals(n: usize) -> Signals {
        let mut s = Signals::with_capacity(n);
        for k in 0..n {
            s.push([k as f64 * 0.25, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]);
        }
        s
    }

    fn times(n: usize) -> Vec<f64> {
        (0..n).map(|k| k as f64 * 0.025).collect()
    }

    #[test]
    fn builder_names_column_and_sample() {
        let mut s = signals(10);
        s.a_y[4] = f64::INFINITY;
        let e = DriveBuilder { t: times(10), measured: s, context: "arrays".into(), ..Default::default() }
            .build()
            .expect_err("inf");
        assert_eq!(e.to_string(), "arrays: column 'a_y', sample 4: value inf is not finite");
        let mut t = times(10);
        t[6] = t[5];
        let e = DriveBuilder { t, measured: signals(10), context: "arrays".into(), ..Default::default() }
            .build()
            .expect_err("time");
        assert!(e.to_string().starts_with("arrays: column 't', sample 6: time is not strictly increasing"), "{e}");
        let mut tr = signals(10);
        tr.px[2] = f64::NAN;
        let e = DriveBuilder {
            t: times(10),
            measured: signals(10),
            truth: Some(tr),
            context: "sim".into(),
            ..Default::default()
        }
        .build()
        .expect_err("truth");
        assert_eq!(e.to_string(), "sim: column 'px_true', sample 2: value NaN is not finite");
        let e = DriveBuilder { t: times(9), measured: signals(10), ..Default::default() }.build().expect_err("length");
        assert!(e.to_string().contains("column px has 10 samples, t has 9"), "{e}");
    }

    #[test]
    fn builder_checks_parts_and_mask() {
        let d =
            DriveBuilder { t: times(10), measured: signals(10), parts: Some(vec![0..4, 4..10]), ..Default::default() }
                .build()
                .expect("ok");
        assert_eq!(d.parts(), &[0..4, 4..10]);
        assert!(DriveBuilder {
            t: times(10),
            measured: signals(10),
            parts: Some(vec![0..4, 5..10]),
            ..Default::default()
        }
        .build()
        .is_err());
        assert!(DriveBuilder { t: times(10), measured: signals(10), parts: Some(vec![0..4]), ..Default::default() }
            .build()
            .is_err());
        assert!(DriveBuilder {
            t: times(10),
            measured: signals(10),
            reference_measured: Some(vec![true; 9]),
            ..Default::default()
        }
        .build()
        .is_err());
        let mask: Vec<bool> = (0..10).map(|k| k % 4 == 0).collect();
        let d =
            DriveBuilder { t: times(10), measured: signals(10), reference_measured: Some(mask), ..Default::default() }
                .build()
                .expect("ok");
        assert!(d.is_reference_measured(4) && !d.is_reference_measured(5));
        let w = d.window(0.1, 1.0).expect("window");
        assert!(w.is_reference_measured(0) && !w.is_reference_measured(1));
    }

    #[test]
    fn negative_part_ids_are_refused_as_the_csv_refuses_them() {
        let ids = vec![0, 0, 0, 0, 0, -1, -1, -1, -1, -1];
        let e = DriveBuilder { t: times(10), measured: signals(10), part_ids: Some(ids), ..Default::default() }
            .build()
            .expect_err("negative")
            .to_string();
        assert_eq!(
            e,
            "drive: column 'part', sample 5: part id -1 is not a non-negative integer (parts are numbered 0, 1, 2, …)"
        );
    }

    #[test]
    fn part_ids_changing_at_every_sample_are_named() {
        let ids = (0..10).map(|k| k % 2).collect();
        let e = DriveBuilder { t: times(10), measured: signals(10), part_ids: Some(ids), ..Default::default() }
            .build()
            .expect_err("alternating")
            .to_string();
        assert!(e.contains("10 parts of one sample each: the part ids change at every sample"), "{e}");
    }

    #[test]
    fn split_at_time_keeps_everything() {
        let d = DriveBuilder {
            t: times(10),
            measured: signals(10),
            extra: vec![ExtraColumn {
                name: "x".into(),
                values: ExtraValues::Numbers((0..10).map(f64::from).collect()),
            }],
            ..Default::default()
        }
        .build()
        .expect("ok");
        let (a, b) = d.split_at_time(0.1).expect("split");
        assert_eq!((a.len(), b.len()), (4, 6));
        assert_eq!(
            b.extra_column("x").map(|c| &c.values),
            Some(&ExtraValues::Numbers(vec![4.0, 5.0, 6.0, 7.0, 8.0, 9.0]))
        );
        assert!(d.split_at_time(-1.0).is_err());
        let (a, _) = d.split_at_time(0.025).expect("one sample keeps the parent's t_s");
        assert_eq!((a.len(), a.sample_time_s()), (1, d.sample_time_s()));
    }

    /// An extra column whose name the CSV round trip would not give back
    /// (a standard column's, `part`, a repeated, empty or control-character
    /// name) is refused naming it, by `build` and by `with_extra`; one that
    /// passes round-trips.
    #[test]
    fn extra_column_names_that_break_the_csv_are_refused() {
        let column = |name: &str| ExtraColumn { name: name.into(), values: ExtraValues::Numbers(vec![1.0; 10]) };
        let build = |extra: Vec<ExtraColumn>| {
            DriveBuilder { t: times(10), measured: signals(10), extra, ..Default::default() }.build()
        };
        for name in ["px", "part", "ref_measured", "n_rl_true", "t", "", "a\nb", " x", "x\t"] {
            let e = build(vec![column(name)]).expect_err(name).to_string();
            assert!(e.contains("extra column '"), "{name:?}: {e}");
            let plain = build(Vec::new()).expect("plain");
            let e = plain.with_extra(column(name)).expect_err(name).to_string();
            assert!(e.contains("extra column '"), "{name:?}: {e}");
        }
        let e = build(vec![column("x"), column("x")]).expect_err("twice").to_string();
        assert!(e.contains("extra column 'x' is given twice"), "{e}");
        let d = build(vec![column("x"), column("pX")]).expect("fine");
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("d.csv");
        d.write_csv(&p).expect("write");
        let (back, _) = Drive::read_csv(&p).expect("read back");
        assert_eq!((back.extra(), back.parts()), (d.extra(), d.parts()));
    }

    #[test]
    fn heading_is_unwrapped() {
        let mut a = vec![3.0, 3.1, -3.1, -3.0, 3.1];
        unwrap_in_place(&mut a);
        for w in a.windows(2) {
            assert!((w[1] - w[0]).abs() < 0.5, "{a:?}");
        }
    }
}
