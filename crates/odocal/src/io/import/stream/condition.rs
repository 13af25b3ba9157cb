//! One stream's time stamps as its messages arrive: unit and offset, time
//! that goes backwards refused, repeated stamps dropped, and the
//! de-jittering of [`signal::dejitter`](super::super::signal::dejitter)
//! over a window that holds only ±`half_window` samples.

use std::collections::VecDeque;
use std::path::PathBuf;

use super::super::manifest::Manifest;
use super::super::report::{DejitterReport, StreamReport};
use super::super::source::{
    differing_repeats_warning, many_repeats_warning, row_label_at, values_differ, DifferingRepeat,
};
use crate::error::{Error, Result};

/// A message after conditioning: the stamp the import uses, the stamp
/// before de-jittering, the values of the columns read and the file line.
#[derive(Debug, Clone)]
pub(crate) struct Row {
    /// Time, s: unit converted, offset, de-jittered when asked.
    pub t: f64,
    /// Time, s, before de-jittering.
    pub t_raw: f64,
    /// The columns, in the order of the stream's column list.
    pub values: Vec<f64>,
    /// The file line, when the source has lines.
    pub line: Option<u64>,
}

/// A row waiting in the de-jitter window, with its index in the nominal
/// sequence of its run.
#[derive(Debug, Clone)]
struct Held {
    row: Row,
    k: i64,
}

/// The de-jitter state of a stream with a nominal rate.
#[derive(Debug)]
struct Dejitter {
    period_s: f64,
    half: usize,
    max_gap_s: f64,
    /// The rows of the current run from `half` before the next one to fit,
    /// and every later row read.
    window: VecDeque<Held>,
    /// Position in the run of `window[0]`.
    first_pos: usize,
    /// Position in the run of the next row to fit.
    next_pos: usize,
    /// The tracker's smoothed stamp.
    s: f64,
    missing: u64,
    sum_sq: f64,
    max_abs: f64,
    /// Rows whose fitted stamp did not follow the previous stamp: given
    /// their raw stamp (or dropped when that does not follow either).
    fallbacks: u64,
}

/// One stream's conditioning.
#[derive(Debug)]
pub(crate) struct Conditioner {
    /// The stream's name in the manifest.
    pub name: String,
    path: PathBuf,
    scale: f64,
    offset: f64,
    time_column: String,
    /// Rows received.
    pub rows: usize,
    repeated: usize,
    /// The column names, in the order of a row's values, and their
    /// positions in name order (the order the whole import compares them in).
    columns: Vec<String>,
    by_name: Vec<usize>,
    /// The values of `last`'s row.
    last_values: Vec<f64>,
    /// Rows repeating a stamp with other values, and the first of them.
    differing: usize,
    first_differing: Option<DifferingRepeat>,
    /// Where the first row repeating a stamp is, and its stamp.
    first_repeat: Option<(String, f64)>,
    last: Option<f64>,
    /// The line and the row (counting from 0) of `last`'s row, and the
    /// kept stamp before it.
    last_line: Option<u64>,
    last_row: usize,
    before_last: Option<f64>,
    first: Option<f64>,
    /// Rows passed on (after repeated stamps).
    pub kept: usize,
    dejitter: Option<Dejitter>,
    /// The last stamp handed out.
    last_out: f64,
    /// Conditioned rows ready to be taken.
    pub ready: VecDeque<Row>,
    /// True once the stream has ended.
    pub ended: bool,
}

impl Conditioner {
    /// The conditioning of stream `name` of `m`, whose rows hold the
    /// values of `columns`.
    pub(crate) fn new(m: &Manifest, name: &str, columns: &[String]) -> Conditioner {
        let spec = &m.streams[name];
        let dejitter = spec.nominal_rate_hz.map(|rate| Dejitter {
            period_s: 1.0 / rate,
            half: ((spec.dejitter_window_s * rate) / 2.0).round().max(1.0) as usize,
            max_gap_s: m.output.max_gap_s,
            window: VecDeque::new(),
            first_pos: 0,
            next_pos: 0,
            s: 0.0,
            missing: 0,
            sum_sq: 0.0,
            max_abs: 0.0,
            fallbacks: 0,
        });
        Conditioner {
            name: name.to_string(),
            path: m.base_dir().join(spec.source.file()),
            scale: spec.time_unit.seconds(),
            offset: spec.time_offset_s,
            time_column: spec.time_column.clone().unwrap_or_else(|| "time".into()),
            rows: 0,
            repeated: 0,
            columns: columns.to_vec(),
            by_name: {
                let mut order: Vec<usize> = (0..columns.len()).collect();
                order.sort_by(|&a, &b| columns[a].cmp(&columns[b]));
                order
            },
            last_values: Vec::new(),
            differing: 0,
            first_differing: None,
            first_repeat: None,
            last: None,
            last_line: None,
            last_row: 0,
            before_last: None,
            first: None,
            kept: 0,
            dejitter,
            last_out: f64::NEG_INFINITY,
            ready: VecDeque::new(),
            ended: false,
        }
    }

    /// The stamp of the last message kept, s (unit and offset applied).
    pub(crate) fn last_stamp(&self) -> Option<f64> {
        self.last
    }

    /// The stream's file.
    pub(crate) fn path(&self) -> &std::path::Path {
        &self.path
    }

    /// The error about the current row's time, at its line when it has one.
    fn time_error(&self, line: Option<u64>, reason: String) -> Error {
        match line {
            Some(line) => Error::Csv { path: self.path.clone(), line, column: Some(self.time_column.clone()), reason },
            None => Error::InvalidDrive {
                context: self.path.display().to_string(),
                reason: format!("row {}, '{}': {reason}", self.rows - 1, self.time_column),
            },
        }
    }

    /// Takes one message: `t` in the stream's time unit.
    pub(crate) fn push(&mut self, t: f64, values: Vec<f64>, line: Option<u64>) -> Result<()> {
        self.rows += 1;
        if !t.is_finite() {
            return Err(self.time_error(line, "time is not finite".into()));
        }
        let t = t * self.scale + self.offset;
        if let Some(last) = self.last {
            if t < last {
                if let Some(jump) = crate::io::import::source::jumped_ahead(self.before_last, last, t) {
                    return Err(self.time_error(self.last_line, jump));
                }
                return Err(self.time_error(
                    line,
                    format!(
                        "time goes backwards ({} after {} s); the stream must be sorted by time",
                        crate::drive::echo_num(t),
                        crate::drive::echo_num(last)
                    ),
                ));
            }
            if t <= last {
                self.repeated_stamp(t, &values, line);
                return Ok(());
            }
        }
        self.before_last = self.last;
        (self.last, self.last_line, self.last_row) = (Some(t), line, self.rows - 1);
        self.last_values.clone_from(&values);
        self.first.get_or_insert(t);
        self.kept += 1;
        let row = Row { t, t_raw: t, values, line };
        match self.dejitter.take() {
            None => self.emit(row),
            Some(mut d) => {
                self.dejitter_push(&mut d, row);
                self.dejitter = Some(d);
            }
        }
        Ok(())
    }

    /// Counts the current row, at stamp `t` (s), which repeats the stamp
    /// of the last row kept, and notes it when it is the first, or the
    /// first to hold other values than that row.
    fn repeated_stamp(&mut self, t: f64, values: &[f64], line: Option<u64>) {
        self.repeated += 1;
        let at = || row_label_at(line, self.rows - 1);
        if self.first_repeat.is_none() {
            self.first_repeat = Some((at(), t));
        }
        let pair = |c: usize| Some((*values.get(c)?, *self.last_values.get(c)?));
        let Some((c, (value, other))) =
            self.by_name.iter().find_map(|&c| pair(c).filter(|p| values_differ(*p)).map(|p| (c, p)))
        else {
            return;
        };
        self.differing += 1;
        if self.first_differing.is_none() {
            self.first_differing = Some(DifferingRepeat {
                at: at(),
                t,
                column: self.columns[c].clone(),
                value,
                other,
                other_at: row_label_at(self.last_line, self.last_row),
            });
        }
    }

    /// The warnings about the stream's repeated stamps, the whole import's:
    /// the rows that repeat a stamp with other values, and more than a
    /// tenth of the rows repeating a stamp. For the stream read so far.
    pub(crate) fn repeat_warnings(&self) -> Vec<String> {
        let stream = format!("streams.{}", self.name);
        let mut out = Vec::new();
        if let Some(first) = &self.first_differing {
            out.push(differing_repeats_warning(&stream, self.differing, &self.path, first, &self.time_column));
        }
        if let Some((at, t)) = &self.first_repeat {
            out.extend(many_repeats_warning(
                &stream,
                self.repeated,
                self.rows,
                &self.path,
                (at, *t),
                &self.time_column,
            ));
        }
        out
    }

    /// The stream has ended: fits the rows still in the window.
    pub(crate) fn end(&mut self) {
        if let Some(mut d) = self.dejitter.take() {
            self.flush_run(&mut d);
            self.dejitter = Some(d);
        }
        self.ended = true;
    }

    fn emit(&mut self, row: Row) {
        self.last_out = row.t;
        self.ready.push_back(row);
    }

    /// Adds a row to the de-jitter window: a new run starts after a gap
    /// longer than `max_gap_s`; rows are fitted as soon as their window
    /// is complete.
    fn dejitter_push(&mut self, d: &mut Dejitter, row: Row) {
        let prev = d.window.back().map(|h| (h.row.t_raw, h.k));
        let k = match prev {
            Some((tp, _)) if row.t_raw - tp > d.max_gap_s => {
                self.flush_run(d);
                d.s = row.t_raw;
                0
            }
            Some((_, kp)) => {
                // Index assignment with a smoothed tracker (gain 0.1).
                let m = ((row.t_raw - d.s) / d.period_s).round().max(1.0);
                d.missing += (m as u64).saturating_sub(1);
                d.s += m * d.period_s;
                d.s += 0.1 * (row.t_raw - d.s);
                kp + m as i64
            }
            None => {
                d.s = row.t_raw;
                0
            }
        };
        d.window.push_back(Held { row, k });
        let last_pos = d.first_pos + d.window.len() - 1;
        while d.next_pos + d.half <= last_pos {
            self.fit_next(d, None);
        }
    }

    /// Fits every row left of the current run (its end is known).
    fn flush_run(&mut self, d: &mut Dejitter) {
        let end = d.first_pos + d.window.len();
        while d.next_pos < end {
            self.fit_next(d, Some(end));
        }
        d.window.clear();
        d.first_pos = 0;
        d.next_pos = 0;
    }

    /// Fits the row at `next_pos` over the window ±`half` (within the run,
    /// which ends at `run_end` when known), with the arithmetic of the
    /// whole import's de-jittering, and hands it out.
    fn fit_next(&mut self, d: &mut Dejitter, run_end: Option<usize>) {
        let i = d.next_pos;
        let lo = i.saturating_sub(d.half);
        let hi = (i + d.half + 1).min(run_end.unwrap_or(usize::MAX));
        let at = |p: usize| &d.window[p - d.first_pos];
        let ti = at(i).row.t_raw;
        let fitted = if hi - lo < 3 {
            ti
        } else {
            let cnt = (hi - lo) as f64;
            let (mut mk, mut mt) = (0.0, 0.0);
            for j in lo..hi {
                mk += at(j).k as f64;
                mt += at(j).row.t_raw - ti;
            }
            mk /= cnt;
            mt /= cnt;
            let (mut skk, mut skt) = (0.0, 0.0);
            for j in lo..hi {
                let dk = at(j).k as f64 - mk;
                skk += dk * dk;
                skt += dk * (at(j).row.t_raw - ti - mt);
            }
            if skk <= 0.0 {
                ti
            } else {
                let b = skt / skk;
                ti + mt + b * (at(i).k as f64 - mk)
            }
        };
        let mut row = at(i).row.clone();
        d.next_pos += 1;
        while d.first_pos + d.half < d.next_pos && !d.window.is_empty() {
            d.window.pop_front();
            d.first_pos += 1;
        }
        let t = if fitted.is_finite() && fitted > self.last_out {
            fitted
        } else {
            d.fallbacks += 1;
            if row.t_raw > self.last_out {
                row.t_raw
            } else {
                return;
            }
        };
        let c = t - row.t_raw;
        d.sum_sq += c * c;
        d.max_abs = d.max_abs.max(c.abs());
        row.t = t;
        self.emit(row);
    }

    /// What was read so far (`rows` received, the span and mean rate of
    /// the rows kept), in the whole import's form.
    pub(crate) fn report(&self) -> StreamReport {
        let span = [self.first.unwrap_or(f64::NAN), self.last.unwrap_or(f64::NAN)];
        let n = self.kept;
        StreamReport {
            name: self.name.clone(),
            file: self.path.clone(),
            rows: self.rows,
            repeated_stamps_dropped: self.repeated,
            corrupt_rows_dropped: 0,
            time_span_s: span,
            mean_rate_hz: if n > 1 { (n - 1) as f64 / (span[1] - span[0]) } else { 0.0 },
            dejitter: self.dejitter.as_ref().map(|d| DejitterReport {
                nominal_rate_hz: 1.0 / d.period_s,
                rms_correction_ms: (d.sum_sq / n.max(1) as f64).sqrt() * 1e3,
                max_correction_ms: d.max_abs * 1e3,
                missing_samples: d.missing,
            }),
        }
    }

    /// Rows whose fitted stamp did not follow the previous one: given
    /// their raw stamp, or dropped when that does not follow either.
    pub(crate) fn fallbacks(&self) -> u64 {
        self.dejitter.as_ref().map_or(0, |d| d.fallbacks)
    }
}

#[cfg(test)]
mod tests {
    use super::Conditioner;
    use crate::io::import::manifest::Manifest;

    /// A stamp ahead of both its neighbours is named on its own line, as the
    /// whole import names it (`io::import::source::jumped_ahead`); a stamp
    /// behind both is named on its line as going backwards.
    #[test]
    fn a_stamp_that_jumps_ahead_is_named_on_its_own_line() {
        let dir = tempfile::tempdir().expect("tempdir");
        let m = Manifest::from_path(crate::io::import::tests::small_case(dir.path())).expect("manifest");
        let run = |stamps: &[f64]| {
            let mut c = Conditioner::new(&m, "pose", &[]);
            for (k, t) in stamps.iter().enumerate() {
                c.push(*t, vec![0.0; 3], Some(k as u64 + 2))?;
            }
            Ok::<_, crate::Error>(())
        };
        let e = run(&[0.0, 0.1, 5.5, 0.3, 0.4]).expect_err("jump").to_string();
        assert!(e.contains("line 4") && e.contains("time jumps ahead to 5.5 s, 5.4 s after the row before it"), "{e}");
        let e = run(&[0.0, 0.1, 0.2, 0.05, 0.4]).expect_err("backwards").to_string();
        assert!(e.contains("line 5") && e.contains("time goes backwards (0.05 after 0.2 s)"), "{e}");
        run(&[0.0, 0.1, 0.1, 0.2]).expect("a repeated stamp is dropped");
    }
}
