//! Reading one recorded stream: the format-specific readers return a
//! [`Table`] (raw time plus the columns asked for); [`read_stream`] then does
//! what is common to every format: the time unit and offset, time that goes
//! backwards, repeated stamps and de-jittering.
//!
//! ## Adding a format
//!
//! A new format is one new file and one enum variant:
//!
//! 1. a variant of [`SourceSpec`] (tagged by `format` in the manifest, e.g.
//!    `format = "parquet"`), with the keys the format needs;
//! 2. a file `source/<format>.rs` with
//!    `pub(super) fn read(m: &Manifest, name: &str, file: &Path, wanted: &[Wanted]) -> Result<Table>`
//!    returning the raw time and the wanted columns, reporting a missing
//!    column with [`Manifest::error`] under the column's manifest key;
//! 3. one arm in [`read_table`]'s `match`, behind the format's cargo feature
//!    where it needs a dependency.
//!
//! `format = "mcap"` (a ROS 2 bag topic, `topic = "/wheels"`, read by
//! `source/mcap.rs` when the `mcap` feature is on, the default) and
//! `format = "parquet"` (columns named as for CSV, read by
//! `source/parquet.rs` when the `parquet` feature is on, off by default) are
//! the examples; without its feature a format is answered with an error that
//! names the feature.

mod csv;
#[cfg(feature = "mcap")]
mod mcap;
#[cfg(feature = "parquet")]
mod parquet;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub(crate) use self::csv::header_column;
use super::manifest::{Manifest, SourceSpec};
use super::report::{DejitterReport, StreamReport};
use super::{limits, signal};
use crate::error::{Error, Result};

/// A column a reader must return: the column name and the manifest key that
/// asked for it (named when the column is missing).
#[derive(Debug, Clone)]
pub(crate) struct Wanted {
    /// The column.
    pub column: String,
    /// The manifest key, e.g. `wheels.rear_left.column`.
    pub key: String,
}

/// One stream as a format reader returns it: one row per sample.
#[derive(Debug, Clone, Default)]
pub(crate) struct Table {
    /// Raw time of each row, in the stream's `time_unit`.
    pub t_s: Vec<f64>,
    /// The wanted columns, by name.
    pub columns: BTreeMap<String, Vec<f64>>,
    /// Where the rows come from (a file, a file and topic), for messages.
    pub source: String,
    /// The file line of each row, when the format has lines (CSV).
    pub lines: Option<Vec<u64>>,
    /// What the reader noticed (a CSV's last line without a newline).
    pub warnings: Vec<String>,
}

/// Where row `i` of a stream is, for messages: `line L`, its file line,
/// where the format has lines (CSV), else `row i`, counting from 0.
pub(crate) fn row_label(lines: Option<&[u64]>, i: usize) -> String {
    row_label_at(lines.and_then(|l| l.get(i)).copied(), i)
}

/// Where row `i` is, for messages, when its file line is `line`: `line L`
/// where it has one, else `row i` ([`row_label`]).
pub(crate) fn row_label_at(line: Option<u64>, i: usize) -> String {
    match line {
        Some(line) => format!("line {line}"),
        None => format!("row {i}"),
    }
}

impl Table {
    /// Where row `i` is, for messages: `line L` or `row i` ([`row_label`]).
    pub(crate) fn row_label(&self, i: usize) -> String {
        row_label(self.lines.as_deref(), i)
    }

    /// An error about row `i` of column `column`: the file line where the
    /// format has lines, else [`Table::row_label`].
    fn row_error(&self, file: &Path, i: usize, column: &str, reason: String) -> Error {
        match &self.lines {
            Some(lines) => Error::Csv { path: file.to_path_buf(), line: lines[i], column: Some(column.into()), reason },
            None => Error::InvalidDrive {
                context: self.source.clone(),
                reason: format!("{}, '{column}': {reason}", self.row_label(i)),
            },
        }
    }
}

/// Reads the raw table of stream `name` with the format its spec names.
pub(crate) fn read_table(m: &Manifest, name: &str, wanted: &[Wanted]) -> Result<Table> {
    let spec = &m.streams[name];
    match &spec.source {
        SourceSpec::Csv { file } => {
            let time = spec.time_column.as_deref().unwrap_or_default();
            csv::read(m, name, &m.base_dir().join(file), time, wanted)
        }
        #[cfg(feature = "mcap")]
        SourceSpec::Mcap { file, topic, time } => mcap::read(m, name, &m.base_dir().join(file), topic, *time, wanted),
        #[cfg(not(feature = "mcap"))]
        SourceSpec::Mcap { .. } => Err(m.error(
            &format!("streams.{name}.format"),
            "\"mcap\" streams need odocal built with the cargo feature `mcap` (on by default), which this \
             build lacks; rebuild with `--features mcap` or export the topic to CSV",
        )),
        #[cfg(feature = "parquet")]
        SourceSpec::Parquet { file } => {
            let time = spec.time_column.as_deref().unwrap_or_default();
            parquet::read(m, name, &m.base_dir().join(file), time, spec.time_unit, wanted)
        }
        #[cfg(not(feature = "parquet"))]
        SourceSpec::Parquet { .. } => Err(m.error(
            &format!("streams.{name}.format"),
            "\"parquet\" streams need odocal built with the cargo feature `parquet` (off by default), which this \
             build lacks; rebuild with `--features parquet` (the CLI: `cargo install --locked --path \
             crates/odocal-cli --features parquet`) or export the table to CSV",
        )),
    }
}

/// One stream as used by the import: time (s, after offset and
/// de-jittering) and the columns asked for.
#[derive(Debug, Clone)]
pub(crate) struct Stream {
    /// The file.
    pub path: PathBuf,
    /// Time, s: unit converted, offset, de-jittered when asked.
    pub t: Vec<f64>,
    /// Time, s, before de-jittering.
    pub t_raw: Vec<f64>,
    /// The columns, by name (rows of repeated stamps removed).
    pub cols: BTreeMap<String, Vec<f64>>,
    /// File lines of the rows kept, when the format has lines.
    pub lines: Option<Vec<u64>>,
    /// What was read.
    pub report: StreamReport,
}

impl Stream {
    /// The stream without the rows whose `keep` is false.
    pub(super) fn without_rows(&self, keep: &[bool]) -> Stream {
        let f = |v: &[f64]| v.iter().zip(keep).filter(|(_, k)| **k).map(|(x, _)| *x).collect::<Vec<f64>>();
        Stream {
            path: self.path.clone(),
            t: f(&self.t),
            t_raw: f(&self.t_raw),
            cols: self.cols.iter().map(|(c, v)| (c.clone(), f(v))).collect(),
            lines: self.lines.as_ref().map(|l| l.iter().zip(keep).filter(|(_, k)| **k).map(|(x, _)| *x).collect()),
            report: self.report.clone(),
        }
    }

    /// Column `name` (empty when it was not read).
    pub(super) fn col(&self, name: &str) -> &[f64] {
        self.cols.get(name).map(Vec::as_slice).unwrap_or(&[])
    }

    /// Where row `i` is, for messages: `line L` or `row i` ([`row_label`]).
    pub(crate) fn row_label(&self, i: usize) -> String {
        row_label(self.lines.as_deref(), i)
    }

    /// An error about row `i` of column `column`: the file line where the
    /// format has lines, else the row and its time.
    pub(super) fn error_at(&self, i: usize, column: Option<&str>, reason: impl Into<String>) -> Error {
        let reason = reason.into();
        match &self.lines {
            Some(lines) => Error::Csv {
                path: self.path.clone(),
                line: lines.get(i).copied().unwrap_or(0),
                column: column.map(str::to_string),
                reason,
            },
            None => Error::InvalidDrive {
                context: self.path.display().to_string(),
                reason: format!(
                    "{} (t = {:.3} s){}: {reason}",
                    self.row_label(i),
                    self.t.get(i).copied().unwrap_or(f64::NAN),
                    column.map(|c| format!(", column '{c}'")).unwrap_or_default()
                ),
            },
        }
    }
}

/// Reads the columns `wanted` of stream `name`: its table, the time in
/// seconds plus `time_offset_s`, time that goes backwards rejected, repeated
/// stamps dropped (and counted), de-jittered when the stream has a
/// `nominal_rate_hz`. What the reader noticed goes to `warnings`.
pub(crate) fn read_stream(m: &Manifest, name: &str, wanted: &[Wanted], warnings: &mut Vec<String>) -> Result<Stream> {
    let spec = &m.streams[name];
    let path = m.base_dir().join(spec.source.file());
    let key = format!("streams.{name}.file");
    let mut table = read_table(m, name, wanted)?;
    warnings.extend(table.warnings.iter().map(|w| format!("streams.{name}: {w}")));
    if table.t_s.is_empty() {
        return Err(m.error(&key, format!("{} has no data rows", table.source)));
    }
    let time_column = spec.time_column.clone().unwrap_or_else(|| "time".into());
    let scale = spec.time_unit.seconds();
    let mut time: Vec<f64> = std::mem::take(&mut table.t_s);
    for (i, t) in time.iter_mut().enumerate() {
        if !t.is_finite() {
            return Err(table.row_error(&path, i, &time_column, "time is not finite".into()));
        }
        *t = *t * scale + spec.time_offset_s;
    }
    let (keep, repeated) = drop_repeats(&table, &time, &path, &time_column, &format!("streams.{name}"), warnings)?;
    let rows = time.len();
    let t_raw = filter(time, &keep);
    let lines = table.lines.map(|l| filter(l, &keep));
    let cols: BTreeMap<String, Vec<f64>> = table.columns.into_iter().map(|(c, v)| (c, filter(v, &keep))).collect();
    let n = t_raw.len();
    if n < 2 && rows > 1 {
        return Err(m.error(
            &format!("streams.{name}"),
            format!(
                "the time column '{}' holds one time ({} s) in all {rows} rows: the stamps are not set (all zero?); \
                 give a column whose time advances",
                crate::drive::echo(&time_column),
                t_raw[0]
            ),
        ));
    }
    let span = [t_raw[0], t_raw[n - 1]];
    let mean_rate_hz = if n > 1 { (n - 1) as f64 / (span[1] - span[0]) } else { 0.0 };
    let (t, dejitter) = match spec.nominal_rate_hz {
        Some(rate) if rate > limits::MAX_NOMINAL_OVER_MEAN_RATE * mean_rate_hz => {
            return Err(m.error(
                &format!("streams.{name}.nominal_rate_hz"),
                format!(
                    "{} Hz is more than {} × the stream's mean rate of {mean_rate_hz:.3} Hz; give the sensor's \
                     sample rate",
                    limits::echo_num(rate),
                    limits::MAX_NOMINAL_OVER_MEAN_RATE
                ),
            ))
        }
        Some(rate) if rate < limits::MIN_NOMINAL_OVER_MEAN_RATE * mean_rate_hz => {
            return Err(m.error(
                &format!("streams.{name}.nominal_rate_hz"),
                format!(
                    "{} Hz is less than {} × the stream's mean rate of {mean_rate_hz:.3} Hz: a sensor does not \
                     sample slower than its samples arrive; give the sensor's sample rate",
                    limits::echo_num(rate),
                    limits::MIN_NOMINAL_OVER_MEAN_RATE
                ),
            ))
        }
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
        rows,
        repeated_stamps_dropped: repeated,
        corrupt_rows_dropped: 0,
        time_span_s: span,
        mean_rate_hz,
        dejitter,
    };
    Ok(Stream { path, t, t_raw, cols, lines, report })
}

/// Above this fraction of a stream's rows dropped as repeated stamps, a
/// warning says so.
const MAX_REPEATED_FRACTION: f64 = 0.1;

/// Whether a row that repeats a stamp holds another value than the row it
/// repeats, for one column's pair of values: they differ by any amount
/// (two NaN, or a NaN and a number, do not count).
pub(crate) fn values_differ((a, b): (f64, f64)) -> bool {
    (a - b).abs() > 0.0
}

/// The first row that repeats the stamp of the row before with other
/// values: where it is and its stamp (s), the first column (by name) that
/// differs, its value there and in the row it repeats, and where that row is.
#[derive(Debug, Clone)]
pub(crate) struct DifferingRepeat {
    pub at: String,
    pub t: f64,
    pub column: String,
    pub value: f64,
    pub other: f64,
    pub other_at: String,
}

/// The warning about the `count` rows of stream `stream` (`streams.NAME`)
/// in `file` that repeat the stamp of the row before with other values,
/// `first` the first of them.
pub(crate) fn differing_repeats_warning(
    stream: &str,
    count: usize,
    file: &Path,
    first: &DifferingRepeat,
    time_column: &str,
) -> String {
    format!(
        "{stream}: {count} row(s) of {} repeat the stamp of the row before with other values, dropped (first: {} \
         at {} s, column '{}' = {} against {} at {}): the first row of each stamp is kept; check the time column \
         '{time_column}' (its unit, its resolution) and that the rows are not duplicated readings",
        file.display(),
        first.at,
        limits::echo_num(first.t),
        first.column,
        limits::echo_num(first.value),
        limits::echo_num(first.other),
        first.other_at
    )
}

/// The warning when more than [`MAX_REPEATED_FRACTION`] of the `rows` of
/// stream `stream` in `file` repeat a stamp (`repeated` of them, the first
/// where and at what stamp, s); `None` below it.
pub(crate) fn many_repeats_warning(
    stream: &str,
    repeated: usize,
    rows: usize,
    file: &Path,
    (at, t): (&str, f64),
    time_column: &str,
) -> Option<String> {
    (repeated as f64 > MAX_REPEATED_FRACTION * rows as f64).then(|| {
        format!(
            "{stream}: {repeated} of the {rows} rows of {} ({:.0} %) repeat the stamp of the row before and were \
             dropped (first: {at} at {} s): the time column '{time_column}' may be too coarse (its unit?) or the \
             stream's rows duplicated",
            file.display(),
            100.0 * repeated as f64 / rows as f64,
            limits::echo_num(t)
        )
    })
}

/// Which rows of `time` to keep (the first of each stamp) and how many
/// repeat a stamp; time that goes backwards is an error. A warning names
/// the first row that repeats a stamp with other values than the row it
/// repeats, and says when more than [`MAX_REPEATED_FRACTION`] of the rows
/// repeat a stamp.
fn drop_repeats(
    table: &Table,
    time: &[f64],
    path: &Path,
    time_column: &str,
    stream: &str,
    warnings: &mut Vec<String>,
) -> Result<(Vec<bool>, usize)> {
    let mut keep = vec![true; time.len()];
    let mut repeated = 0;
    let mut last = time[0];
    // The row of `last`, and the kept stamp before it.
    let (mut last_i, mut before_last) = (0, None);
    // Rows repeating a stamp with other values, and the first of them.
    let (mut differing, mut first_differing) = (0, None);
    for i in 1..time.len() {
        if time[i] < last {
            // One stamp ahead of both neighbours is that row's fault, not the next one's.
            if let Some(jump) = jumped_ahead(before_last, last, time[i]) {
                return Err(table.row_error(path, last_i, time_column, jump));
            }
            return Err(table.row_error(
                path,
                i,
                time_column,
                format!(
                    "time goes backwards ({} after {} s); the stream must be sorted by time",
                    limits::echo_num(time[i]),
                    limits::echo_num(last)
                ),
            ));
        }
        if time[i] <= last {
            keep[i] = false;
            repeated += 1;
            let pair = |v: &Vec<f64>| Some((*v.get(i)?, *v.get(last_i)?));
            let other = table.columns.iter().find_map(|(c, v)| pair(v).filter(|p| values_differ(*p)).map(|p| (c, p)));
            if let Some((c, (v, u))) = other {
                differing += 1;
                first_differing.get_or_insert_with(|| (i, c.clone(), v, u, last_i));
            }
        } else {
            before_last = Some(last);
            (last, last_i) = (time[i], i);
        }
    }
    if let Some((i, column, value, other, j)) = first_differing {
        let first =
            DifferingRepeat { at: table.row_label(i), t: time[i], column, value, other, other_at: table.row_label(j) };
        warnings.push(differing_repeats_warning(stream, differing, path, &first, time_column));
    }
    if let Some(first) = keep.iter().position(|k| !k) {
        let at = table.row_label(first);
        warnings.extend(many_repeats_warning(stream, repeated, time.len(), path, (&at, time[first]), time_column));
    }
    Ok((keep, repeated))
}

/// The message for a stamp `last` ahead of both its kept neighbours, the
/// one before (`before`) and the next (`next`, below `last`), where `next`
/// is not behind `before`: that row's stamp jumped (a corrupt or out-of-order
/// row), which the next row's "time goes backwards" would blame on the next.
pub(crate) fn jumped_ahead(before: Option<f64>, last: f64, next: f64) -> Option<String> {
    let before = before.filter(|b| next >= *b)?;
    Some(format!(
        "time jumps ahead to {} s, {} s after the row before it ({} s), and the next row is back at {} s: a corrupt \
         or out-of-order stamp; fix or drop this row (the stream must be sorted by time)",
        limits::echo_num(last),
        limits::echo_num(last - before),
        limits::echo_num(before),
        limits::echo_num(next)
    ))
}

/// `v` without the rows whose `keep` is false, in place (a stream's
/// columns can be most of an import's memory).
fn filter<T>(mut v: Vec<T>, keep: &[bool]) -> Vec<T> {
    let mut rows = keep.iter();
    v.retain(|_| rows.next().copied().unwrap_or(true));
    v
}
