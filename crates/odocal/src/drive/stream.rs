//! A canonical drive CSV read as a stream ([`DriveStream`]): the drive's
//! samples chunk by chunk, with the checks, sample time, parts and
//! fingerprint of [`Drive::read_csv`], in memory that does not grow with
//! the drive.
//!
//! Opening reads the file once, row by row: every check of the whole reader
//! runs on the way, those that need the whole drive as running statistics
//! (the sample time is the mean step, a running sum over the parts; the
//! uniformity of the steps, the speed and the yaw rate are judged from the
//! smallest and largest step, the longest move and the largest heading
//! change, which decide them exactly once the sample time is known). The
//! columns `t, px, py, psi, n_rl, n_rr, beta, a_y` (the heading unwrapped)
//! go to anonymous temporary files, 64 bytes a sample, deleted with the
//! stream; the chunks and the fingerprint are read back from them. Extra
//! columns, the truth and `ref_measured` are checked and not kept.
//!
//! A file the stream refuses is read whole once more, so that its error is
//! the whole reader's, word for word (the first problem of the file in the
//! reader's order, with its line); memory then grows with the file, as the
//! whole reader's does. A line longer than the CSV line limit (1 MiB) or a
//! NUL byte (a file that is no CSV text) is the error at once, with its
//! line: memory stays within that limit however long the line.

use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::ops::Range;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use super::csv::{
    check_header, csv_error, echo, extra_name_problem, not_csv, tail_warning_at, MASK_COLUMN, PART_COLUMN,
    REQUIRED_COLUMNS, TRUTH_COLUMNS,
};
use super::csv_lines::LineCounted;
use super::fingerprint::Fingerprinter;
use super::{Drive, Signals, STEP_UNIFORMITY_TOL};
use crate::error::{Error, Result};
use crate::model::limits::PhysicalLimits;

/// Columns kept: `t` and the seven signals, in [`REQUIRED_COLUMNS`] order
/// (the fingerprint's).
const KEPT: usize = 8;

/// Values per read of a kept column when hashing.
const BLOCK: usize = 4096;

/// A canonical drive CSV (docs/method.md §2) read as a stream: what
/// [`Drive::read_csv`] reads, checked the same way, handed out in chunks
/// ([`DriveStream::chunks`]) with the same values, sample time and parts,
/// and the same [`fingerprint`](DriveStream::fingerprint), while memory
/// stays flat in the drive's length (the module's docs say how).
#[derive(Debug)]
pub(crate) struct DriveStream {
    /// The file read (or the source a spooled stream names in messages).
    pub path: PathBuf,
    /// Sample time t_s, s, as [`Drive::sample_time_s`] (the mean step).
    pub sample_time_s: f64,
    /// The first and the last time stamp, s.
    pub time_span_s: (f64, f64),
    /// What the reader noticed that is not an error, as
    /// [`Drive::read_csv`] returns it.
    pub warnings: Vec<String>,
    /// Number of samples; with `parts`, what the spilled columns hold, so
    /// both stay private.
    len: usize,
    parts: Vec<Range<usize>>,
    /// The kept columns, 8-byte little-endian values.
    columns: Vec<File>,
}

/// Canonical samples of a stream, all of one part: of a streamed import
/// ([`RawStream::take_chunk`](crate::io::RawStream::take_chunk)), or
/// of a drive CSV read as a stream.
#[derive(Debug, Clone, PartialEq)]
pub struct StreamChunk {
    /// The part they belong to (0, 1, …; an index into the drive's
    /// continuous parts, in time order).
    pub part: usize,
    /// The index of the first of them among the drive's samples.
    pub start: usize,
    /// True when the first of them starts its part.
    pub starts_part: bool,
    /// Time stamps, s (for an import, 0 at the drive's origin as
    /// [`import`](crate::import)'s).
    pub t: Vec<f64>,
    /// The signals, the heading unwrapped as [`Drive`] unwraps it.
    pub signals: Signals,
    /// Whether the reference was measured at each sample
    /// ([`Drive::reference_measured`]); `None` from a drive CSV read as
    /// a stream, which keeps no such column.
    pub reference_measured: Option<Vec<bool>>,
}

impl DriveStream {
    /// Reads the canonical drive CSV `path` through once, checking it as
    /// [`Drive::read_csv`] does and keeping its samples on disk.
    ///
    /// # Errors
    /// [`Drive::read_csv`]'s errors, the same words; [`Error::Io`] when the
    /// temporary files cannot be written.
    pub(crate) fn open(path: impl AsRef<Path>) -> Result<DriveStream> {
        let path = path.as_ref();
        match scan(path, &PhysicalLimits::default()) {
            Ok(s) => Ok(s),
            Err(Stop::Error(e)) => Err(e),
            Err(Stop::Refused(reason)) => Err(whole_readers_error(path, reason)),
        }
    }

    /// Keeps the canonical samples of a streamed import on disk as a
    /// stream: `next` hands out chunks of one part each (time stamps,
    /// signals with the heading unwrapped, and whether the chunk starts a
    /// part) until `None`; the drive's sample time is `sample_time_s`.
    /// `path` names the source in messages.
    ///
    /// # Errors
    /// `next`'s; [`Error::Io`] when the temporary files cannot be written.
    pub(crate) fn spool(
        path: &Path,
        sample_time_s: f64,
        mut next: impl FnMut() -> Result<Option<(Vec<f64>, Signals, bool)>>,
    ) -> Result<DriveStream> {
        let io = |e: std::io::Error| Error::io(Path::new("a temporary file"), e);
        let mut out = (0..KEPT)
            .map(|_| tempfile::tempfile().map(|f| BufWriter::with_capacity(1 << 16, f)))
            .collect::<std::io::Result<Vec<_>>>()
            .map_err(io)?;
        let (mut len, mut parts, mut span) = (0usize, Vec::<Range<usize>>::new(), (f64::NAN, f64::NAN));
        while let Some((t, s, starts_part)) = next()? {
            if starts_part || parts.is_empty() {
                parts.push(len..len);
            }
            for (k, col) in [&t, &s.px, &s.py, &s.psi, &s.n_rl, &s.n_rr, &s.beta, &s.a_y].into_iter().enumerate() {
                for v in col {
                    out[k].write_all(&v.to_le_bytes()).map_err(io)?;
                }
            }
            if len == 0 {
                span.0 = t.first().copied().unwrap_or(f64::NAN);
            }
            span.1 = t.last().copied().unwrap_or(span.1);
            len += t.len();
            if let Some(p) = parts.last_mut() {
                p.end = len;
            }
        }
        let columns = out.into_iter().map(|w| w.into_inner().map_err(|e| io(e.into_error()))).collect::<Result<_>>()?;
        Ok(DriveStream {
            path: path.to_path_buf(),
            len,
            parts,
            sample_time_s,
            time_span_s: span,
            columns,
            warnings: Vec::new(),
        })
    }

    /// Number of samples.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// The drive's fingerprint, equal to [`Drive::fingerprint`] of the drive
    /// read whole (hashed from the kept columns).
    ///
    /// # Errors
    /// [`Error::Io`] when the temporary files cannot be read.
    pub(crate) fn fingerprint(&self) -> Result<String> {
        let mut f = Fingerprinter::new(self.len, &self.parts, self.sample_time_s);
        for k in 0..KEPT {
            let mut a = 0;
            while a < self.len {
                let b = (a + BLOCK).min(self.len);
                f.values(&self.column(k, a..b)?);
                a = b;
            }
        }
        Ok(f.finish())
    }

    /// The samples in chunks of at most `size` (at least 1), part by part
    /// in time order; a chunk never spans two parts.
    pub(crate) fn chunks(&self, size: usize) -> impl Iterator<Item = Result<StreamChunk>> + '_ {
        StreamChunks { stream: self, size: size.max(1), part: 0, next: 0 }
    }

    /// The samples `r` as a chunk of part `part`.
    fn read(&self, part: usize, r: Range<usize>) -> Result<StreamChunk> {
        let starts_part = self.parts.get(part).is_some_and(|p| p.start == r.start);
        let mut c: [Vec<f64>; KEPT] = Default::default();
        for (k, col) in c.iter_mut().enumerate() {
            *col = self.column(k, r.clone())?;
        }
        let [t, px, py, psi, n_rl, n_rr, beta, a_y] = c;
        let signals = Signals { px, py, psi, n_rl, n_rr, beta, a_y };
        Ok(StreamChunk { part, start: r.start, starts_part, t, signals, reference_measured: None })
    }

    /// Values `r` of kept column `k`.
    fn column(&self, k: usize, r: Range<usize>) -> Result<Vec<f64>> {
        let mut bytes = vec![0u8; 8 * r.len()];
        self.columns[k].read_exact_at(&mut bytes, 8 * r.start as u64).map_err(|e| self.spill_error(e))?;
        Ok(bytes.chunks_exact(8).map(|b| f64::from_le_bytes(b.try_into().unwrap_or_default())).collect())
    }

    fn spill_error(&self, e: std::io::Error) -> Error {
        let what = std::io::Error::new(e.kind(), format!("the temporary copy of its samples: {e}"));
        Error::io(&self.path, what)
    }
}

/// The chunks of a [`DriveStream`] ([`DriveStream::chunks`]).
#[derive(Debug)]
struct StreamChunks<'a> {
    stream: &'a DriveStream,
    size: usize,
    part: usize,
    next: usize,
}

impl Iterator for StreamChunks<'_> {
    type Item = Result<StreamChunk>;

    fn next(&mut self) -> Option<Result<StreamChunk>> {
        let parts = &self.stream.parts;
        while parts.get(self.part).is_some_and(|p| self.next >= p.end) {
            self.part += 1;
        }
        let p = parts.get(self.part)?;
        let a = self.next.max(p.start);
        let b = (a + self.size).min(p.end);
        self.next = b;
        Some(self.stream.read(self.part, a..b))
    }
}

/// Why a scan stopped.
enum Stop {
    /// The file is not a valid drive; the reason names the line when it can.
    Refused(String),
    /// Any other failure (the temporary files), returned as it is.
    Error(Error),
}

/// The error of a file the stream refused: the whole reader's (the
/// reason when the file is too large to be read whole, or when the whole
/// reader accepts it).
fn whole_readers_error(path: &Path, reason: String) -> Error {
    let small = std::fs::metadata(path).map_or(true, |m| m.len() <= crate::output::limited::MAX_DATA_BYTES);
    if small {
        if let Err(e) = Drive::read_csv(path) {
            return e;
        }
    }
    Error::InvalidDrive { context: path.display().to_string(), reason }
}

/// A reader that counts lines: the last byte and the line number of the
/// last byte that is not white space, for the tail warning.
struct Counted<R> {
    inner: R,
    newlines: u64,
    last_line: u64,
    last_byte: Option<u8>,
}

impl<R: Read> Read for Counted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        for &b in &buf[..n] {
            if b == b'\n' {
                self.newlines += 1;
            } else if !b.is_ascii_whitespace() {
                self.last_line = self.newlines + 1;
            }
        }
        if n > 0 {
            self.last_byte = Some(buf[n - 1]);
        }
        Ok(n)
    }
}

/// Reads `path` through: checks every row, keeps the columns, returns the
/// stream.
fn scan(path: &Path, limits: &PhysicalLimits) -> std::result::Result<DriveStream, Stop> {
    let refused = |e: &dyn std::fmt::Display| Stop::Refused(e.to_string());
    let file = crate::output::limited::open_limited(path, u64::MAX, "a drive CSV").map_err(|e| refused(&e))?;
    let counted = Counted { inner: file, newlines: 0, last_line: 1, last_byte: None };
    let mut input = BufReader::with_capacity(1 << 16, counted);
    let head = input.fill_buf().map_err(|e| refused(&e))?;
    if let Some(what) = not_csv(head) {
        return Err(Stop::Error(Error::InvalidDrive { context: path.display().to_string(), reason: what.into() }));
    }
    if head.starts_with(b"\xEF\xBB\xBF") {
        input.consume(3);
    }
    let mut rdr = super::csv_lines::reader(input);
    // A line too long or a NUL byte is the error as it is: the whole
    // reader would hold the file (and say the same).
    let not_text = |e: &::csv::Error| {
        super::csv_lines::not_text(e).map(|t| Stop::Error(csv_error(path, t.line, None, t.reason.clone())))
    };
    let headers: Vec<String> =
        rdr.headers().map_err(|e| not_text(&e).unwrap_or_else(|| refused(&e)))?.iter().map(str::to_string).collect();
    check_header(&headers, path).map_err(|e| refused(&e))?;
    let mut scanner = Scanner::new(&headers, *limits)?;
    let mut record = ::csv::StringRecord::new();
    let bad_row = |e: ::csv::Error, lines: &mut LineCounted<_>| {
        not_text(&e).unwrap_or_else(|| {
            Stop::Refused(format!("line {}: {}", lines.line_of(e.position()), super::csv_lines::reason(&e)))
        })
    };
    while rdr.read_record(&mut record).map_err(|e| bad_row(e, rdr.get_mut()))? {
        let line = rdr.get_mut().line_of(record.position());
        scanner.row(&record).map_err(|what| Stop::Refused(format!("line {line}: {what}")))?;
    }
    let counted = rdr.into_inner().into_inner().into_inner();
    let warnings = tail_warning_at(counted.last_byte, counted.last_line, path).into_iter().collect();
    scanner.finish(path, warnings)
}

/// The running state of a scan.
struct Scanner {
    limits: PhysicalLimits,
    /// The file column of each kept column.
    at: [usize; KEPT],
    /// The file columns that must hold finite numbers.
    numeric: Vec<usize>,
    mask: Option<usize>,
    part: Option<usize>,
    /// One row's numbers by file column (0 where not parsed).
    row: Vec<f64>,
    out: Vec<BufWriter<File>>,
    len: usize,
    parts: Vec<Range<usize>>,
    part_id: Option<i64>,
    part_start: usize,
    /// The current part's first time stamp, s.
    part_t0: f64,
    /// Σ over the parts of (last − first time stamp), and the steps.
    span_s: f64,
    steps: usize,
    /// The previous row's kept values, the heading unwrapped.
    prev: [f64; KEPT],
    first_t: f64,
    /// The smallest and largest step within a part, s.
    step_range_s: (f64, f64),
    /// The longest move of the reference in one step, m.
    max_move_m: f64,
    /// The largest heading change in one step, rad.
    max_turn_rad: f64,
    unwrap: Unwrap,
}

impl Scanner {
    fn new(headers: &[String], limits: PhysicalLimits) -> std::result::Result<Scanner, Stop> {
        let find = |name: &str| headers.iter().position(|h| h == name);
        let mut at = [0; KEPT];
        for (k, name) in REQUIRED_COLUMNS.iter().enumerate() {
            at[k] = find(name).ok_or_else(|| Stop::Refused(format!("no column {name}")))?;
        }
        let numeric: Vec<usize> = (0..headers.len())
            .filter(|&j| {
                let h = headers[j].as_str();
                REQUIRED_COLUMNS.contains(&h) || TRUTH_COLUMNS.contains(&h) || h == MASK_COLUMN || h == PART_COLUMN
            })
            .collect();
        // The other columns are extra columns, whose names the whole
        // reader checks as every drive's (an empty one, a tab in one).
        let extra = (0..headers.len()).filter(|j| !numeric.contains(j)).map(|j| headers[j].as_str());
        if let Some((h, problem)) = extra.filter_map(|h| extra_name_problem(h).map(|p| (h, p))).next() {
            return Err(Stop::Refused(format!("extra column '{}' {problem}", echo(h))));
        }
        let out = (0..KEPT)
            .map(|_| tempfile::tempfile().map(|f| BufWriter::with_capacity(1 << 16, f)))
            .collect::<std::io::Result<Vec<_>>>()
            .map_err(|e| Stop::Error(Error::io(Path::new("a temporary file"), e)))?;
        Ok(Scanner {
            limits,
            at,
            numeric,
            mask: find(MASK_COLUMN),
            part: find(PART_COLUMN),
            row: vec![0.0; headers.len()],
            out,
            len: 0,
            parts: Vec::new(),
            part_id: None,
            part_start: 0,
            part_t0: 0.0,
            span_s: 0.0,
            steps: 0,
            prev: [0.0; KEPT],
            first_t: 0.0,
            step_range_s: (f64::INFINITY, f64::NEG_INFINITY),
            max_move_m: 0.0,
            max_turn_rad: 0.0,
            unwrap: Unwrap::default(),
        })
    }

    /// Checks one row and keeps it; the error says what is wrong with it.
    fn row(&mut self, record: &::csv::StringRecord) -> std::result::Result<(), String> {
        if record.len() != self.row.len() {
            return Err(format!("{} fields, the header has {}", record.len(), self.row.len()));
        }
        for &j in &self.numeric {
            match record[j].parse::<f64>() {
                Ok(v) if v.is_finite() => self.row[j] = v,
                _ => return Err(format!("column {}: not a finite number", j + 1)),
            }
        }
        let v: [f64; KEPT] = std::array::from_fn(|k| self.row[self.at[k]]);
        if let Some(j) = self.mask {
            let m = self.row[j];
            if m != 0.0 && m.to_bits() != 1.0f64.to_bits() {
                return Err(format!("{MASK_COLUMN} {m} is not 0 or 1"));
            }
        }
        let id = match self.part {
            Some(j) => {
                let id = self.row[j];
                if id.fract() != 0.0 || !(0.0..=1e15).contains(&id) {
                    return Err(format!("part id {id} is not a non-negative integer"));
                }
                Some(id as i64)
            }
            None => None,
        };
        self.check_limits(&v)?;
        let mut v = v;
        v[3] = self.unwrap.next(v[3]);
        self.step(&v, id)?;
        for (w, x) in self.out.iter_mut().zip(v) {
            w.write_all(&x.to_le_bytes()).map_err(|e| format!("cannot write a temporary file: {e}"))?;
        }
        self.prev = v;
        self.len += 1;
        Ok(())
    }

    /// The limits that do not depend on the sample time.
    fn check_limits(&self, v: &[f64; KEPT]) -> std::result::Result<(), String> {
        let l = &self.limits;
        if v[4].abs() > l.max_wheel_rev_per_s || v[5].abs() > l.max_wheel_rev_per_s {
            return Err("a wheel rotation speed beyond the physical limits".into());
        }
        if v[7].abs() > l.max_lateral_acceleration_m_per_s2 {
            return Err("a lateral acceleration beyond the physical limits".into());
        }
        if v[6].abs() > l.max_sideslip_rad {
            return Err("a sideslip beyond the physical limits".into());
        }
        Ok(())
    }

    /// Time, parts and the step statistics of the row `v` (part id `id`).
    fn step(&mut self, v: &[f64; KEPT], id: Option<i64>) -> std::result::Result<(), String> {
        if self.len == 0 {
            (self.first_t, self.part_t0, self.part_id) = (v[0], v[0], id);
            return Ok(());
        }
        if v[0].partial_cmp(&self.prev[0]) != Some(std::cmp::Ordering::Greater) {
            return Err(format!(
                "time is not strictly increasing ({} after {})",
                super::echo_num(v[0]),
                super::echo_num(self.prev[0])
            ));
        }
        if id != self.part_id {
            self.close_part();
            (self.part_t0, self.part_id) = (v[0], id);
            return Ok(());
        }
        let dt = v[0] - self.prev[0];
        self.step_range_s = (self.step_range_s.0.min(dt), self.step_range_s.1.max(dt));
        let moved = (v[1] - self.prev[1]).hypot(v[2] - self.prev[2]);
        let turned = (v[3] - self.prev[3]).abs();
        if moved.is_nan() || turned.is_nan() {
            return Err("a step of the reference that is not a number".into());
        }
        self.max_move_m = self.max_move_m.max(moved);
        self.max_turn_rad = self.max_turn_rad.max(turned);
        Ok(())
    }

    /// Ends the part that ends before the current sample.
    fn close_part(&mut self) {
        let part = self.part_start..self.len;
        if part.len() >= 2 {
            self.span_s += self.prev[0] - self.part_t0;
            self.steps += part.len() - 1;
        }
        self.parts.push(part);
        self.part_start = self.len;
    }

    /// The stream, once the last row is read: the sample time and the
    /// checks that need it.
    fn finish(mut self, path: &Path, warnings: Vec<String>) -> std::result::Result<DriveStream, Stop> {
        let refuse = |what: String| Err(Stop::Refused(what));
        if self.len == 0 {
            return refuse("the file has a header but no data rows".into());
        }
        self.close_part();
        if self.steps == 0 {
            return refuse("too few samples in a part to infer the sample time".into());
        }
        let ts = self.span_s / self.steps as f64;
        let (lo, hi) = self.step_range_s;
        if (lo - ts).abs() > STEP_UNIFORMITY_TOL * ts || (hi - ts).abs() > STEP_UNIFORMITY_TOL * ts {
            return refuse(format!("sample steps from {lo} s to {hi} s: not within 1 % of the mean step {ts} s"));
        }
        let l = &self.limits;
        if !(l.min_sample_time_s..=l.max_sample_time_s).contains(&ts) {
            return refuse(format!("sample time {ts:.3e} s is outside the plausible range"));
        }
        if self.max_move_m / ts > l.max_speed_m_per_s {
            return refuse(format!("the reference moves {} m in one step", self.max_move_m));
        }
        if self.max_turn_rad / ts > l.max_yaw_rate_rad_per_s {
            return refuse(format!("the heading changes by {} rad in one step", self.max_turn_rad));
        }
        let mut columns = Vec::with_capacity(KEPT);
        for w in self.out {
            let f = w.into_inner().map_err(|e| Stop::Error(Error::io(path, e.into_error())))?;
            columns.push(f);
        }
        Ok(DriveStream {
            path: path.to_path_buf(),
            len: self.len,
            parts: self.parts,
            sample_time_s: ts,
            time_span_s: (self.first_t, self.prev[0]),
            columns,
            warnings,
        })
    }
}

/// Unwraps a heading sample by sample with the arithmetic of
/// [`super::unwrap_in_place`] (the first sample as it is).
#[derive(Debug, Default)]
pub(crate) struct Unwrap {
    offset: f64,
    prev_raw: Option<f64>,
}

impl Unwrap {
    pub(crate) fn next(&mut self, raw: f64) -> f64 {
        let Some(prev) = self.prev_raw.replace(raw) else { return raw };
        let two_pi = 2.0 * std::f64::consts::PI;
        let d = raw - prev;
        if d > std::f64::consts::PI {
            self.offset -= two_pi * ((d + std::f64::consts::PI) / two_pi).floor();
        } else if d < -std::f64::consts::PI {
            self.offset += two_pi * ((-d + std::f64::consts::PI) / two_pi).floor();
        }
        raw + self.offset
    }
}

#[cfg(test)]
#[path = "stream_tests.rs"]
mod tests;
