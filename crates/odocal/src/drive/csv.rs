//! The canonical drive CSV (docs/method.md §2): reader and writer.

use std::path::Path;

use rayon::prelude::*;

use super::csv_lines::{count_line_ends, LineCounted};
use super::{Drive, DriveBuilder, ExtraColumn, ExtraValues, Signals, SIGNAL_NAMES};
use crate::error::{Error, Result};

/// The columns a canonical drive CSV must have.
pub(crate) const REQUIRED_COLUMNS: [&str; 8] = ["t", "px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"];
pub(crate) const TRUTH_COLUMNS: [&str; 7] =
    ["px_true", "py_true", "psi_true", "n_rl_true", "n_rr_true", "beta_true", "a_y_true"];
/// Optional column: 1 where the reference was really measured.
pub(crate) const MASK_COLUMN: &str = "ref_measured";
/// Optional column: integer part ids.
pub(crate) const PART_COLUMN: &str = "part";

/// Why `name` cannot name an extra column, or `None`: a CSV written with
/// it must read back as the same drive, so it is not empty, has no control
/// character and no white space at either end (the reader trims fields), and
/// is not the name of a column the reader takes itself (the required
/// columns, the truth columns, `ref_measured`, `part`).
pub(crate) fn extra_name_problem(name: &str) -> Option<&'static str> {
    if name.is_empty() {
        Some("is empty")
    } else if name.chars().any(char::is_control) {
        Some("has a control character")
    } else if name.trim() != name {
        Some("starts or ends with white space")
    } else if REQUIRED_COLUMNS.contains(&name)
        || TRUTH_COLUMNS.contains(&name)
        || [MASK_COLUMN, PART_COLUMN].contains(&name)
    {
        Some("is reserved: the drive CSV's own columns (t, px, py, psi, n_rl, n_rr, beta, a_y, their *_true, ref_measured, part) cannot be extra columns")
    } else {
        None
    }
}

/// Longest echo of a field in an error message, characters.
pub(crate) const ECHO_CHARS: usize = 40;

/// A value as echoed in an error message: at most [`ECHO_CHARS`]
/// characters, then "…" and the full length, with control characters
/// escaped ([`crate::output::visible`]; every reader uses this one).
pub(crate) fn echo(field: &str) -> String {
    clip(field, ECHO_CHARS)
}

/// `text` cut after `max_chars` characters ("…" and the full length
/// follow), with control characters escaped: a message quoting a
/// user's text (a parser's message naming a 1 MB key) stays short.
pub(crate) fn clip(text: &str, max_chars: usize) -> String {
    let mut it = text.chars();
    let head: String = it.by_ref().take(max_chars).collect();
    if it.next().is_some() {
        format!("{}… ({} bytes)", crate::output::visible(&head), text.len())
    } else {
        crate::output::visible(&head).into_owned()
    }
}

/// At most this many names are listed in an error message.
const LIST_NAMES: usize = 12;

/// The first [`LIST_NAMES`] names, then "… (N more)".
fn listed(names: &[String]) -> Vec<String> {
    let mut v: Vec<String> = names.iter().take(LIST_NAMES).map(|n| echo(n)).collect();
    if names.len() > LIST_NAMES {
        v.push(format!("… ({} more)", names.len() - LIST_NAMES));
    }
    v
}

fn list(names: &[String]) -> String {
    listed(names).join(", ")
}

/// Files that are sometimes given where a canonical drive CSV belongs, known
/// by their first bytes: what the file is and what to do instead. (Not CSV
/// text, they would otherwise fail as "invalid UTF-8" or as missing columns.)
const NOT_CSV: [(&[u8], &str); 9] = [
    (
        b"\x89MCAP0\r\n",
        "a ROS 2 bag (MCAP), not a canonical drive CSV: draft a manifest that names its wheel, pose and IMU topics \
         with `odocal inspect FILE --manifest OUT.toml` (docs/guide.md, \"A ROS 2 bag\"), check it and give the manifest \
         (.toml) instead",
    ),
    (
        b"SQLite format 3\0",
        "a ROS 2 sqlite3 (.db3) bag, not a canonical drive CSV: odocal reads bags in MCAP; convert it with \
         `ros2 bag convert`, then describe its topics in a manifest (.toml) and give that instead",
    ),
    (
        b"#ROSBAG V",
        "a ROS 1 bag, not a canonical drive CSV: odocal reads ROS 2 bags in MCAP; convert it (e.g. \
         `mcap convert IN.bag OUT.mcap`), then describe its topics in a manifest (.toml) and give that instead",
    ),
    (
        b"PAR1",
        "a Parquet file, not a canonical drive CSV: name it as a stream (`format = \"parquet\"`) in a manifest \
         (.toml; docs/guide.md, \"Parquet streams\") and give the manifest instead",
    ),
    (b"\x1f\x8b", "gzip-compressed: decompress it first (`gunzip -k FILE`)"),
    (b"\x28\xb5\x2f\xfd", "zstd-compressed: decompress it first (`zstd -d FILE`)"),
    (b"\xfd7zXZ\0", "xz-compressed: decompress it first (`xz -dk FILE`)"),
    (b"PK\x03\x04", "a zip archive: extract the drive CSV from it first"),
    (
        b"{",
        "a JSON file (a simulated drive's sidecar, a report or a parameter file), not a canonical drive CSV: give \
         the drive CSV (a sidecar has the drive's name with .json)",
    ),
];

/// What a file is when its first bytes say it is not CSV text ([`NOT_CSV`]).
pub(crate) fn not_csv(bytes: &[u8]) -> Option<&'static str> {
    NOT_CSV.iter().find(|(magic, _)| bytes.starts_with(magic)).map(|(_, what)| *what)
}

/// What to do about a cell of a drive's column that holds no finite
/// number (a gap in the log, a sensor the log lacks).
const NUMBER_IN_EVERY_CELL: &str = "every cell needs a number: drop the row and mark the gap with a 'part' \
     column (docs/reference.md, the drive CSV), or import the log with a manifest (docs/guide.md)";

/// The error at `line` (and `column`) of the CSV file `path`.
pub(crate) fn csv_error(path: &Path, line: u64, column: Option<&str>, reason: String) -> Error {
    Error::Csv { path: path.to_path_buf(), line, column: column.map(echo), reason }
}

/// A CSV reader's error, in words for the common cases; `lines` gives the
/// line of the record it is about.
pub(crate) fn from_csv<R>(path: &Path, e: ::csv::Error, lines: &mut LineCounted<R>) -> Error {
    if let Some(t) = super::csv_lines::not_text(&e) {
        return csv_error(path, t.line, None, t.reason.clone());
    }
    csv_error(path, lines.line_of(e.position()), None, super::csv_lines::reason(&e))
}

/// The line number of the last line of `bytes` that is not blank (lines
/// end at `\n`, `\r\n` or a lone `\r`, as for the CSV parser).
fn last_line(bytes: &[u8]) -> u64 {
    // The text up to the last byte that is not white space, so no `\r\n` is cut.
    let end = bytes.iter().rposition(|b| !b.is_ascii_whitespace()).map_or(0, |i| i + 1);
    count_line_ends(&bytes[..end]) + 1
}

/// A row with too few fields on the last line: says the file looks cut off.
fn short_last_row(e: Error, bytes: &[u8]) -> Error {
    match e {
        Error::Csv { path, line, column, reason } if line == last_line(bytes) && reason.contains("the header has") => {
            let reason = format!(
                "{reason}: the last row is short, the file looks cut off (an interrupted write?); \
                 restore or re-create it, or delete the partial row"
            );
            Error::Csv { path, line, column, reason }
        }
        e => e,
    }
}

/// The warning for a file whose last line has no newline at its end: fine
/// for a file made by hand, a sign of a cut-off file otherwise.
fn tail_warning(bytes: &[u8], path: &Path) -> Option<String> {
    // The line count scans the whole file: only for a file that warns.
    match bytes.last() {
        None | Some(b'\n') => None,
        last => tail_warning_at(last.copied(), last_line(bytes), path),
    }
}

/// [`tail_warning`] from the file's last byte and the number of its last
/// line, for a file read as a stream.
pub(crate) fn tail_warning_at(last_byte: Option<u8>, last_line: u64, path: &Path) -> Option<String> {
    if last_byte.is_none_or(|b| b == b'\n') {
        return None;
    }
    Some(format!(
        "{}: line {last_line}, the last line, has no newline at its end: check that the file is complete (a file \
         cut off by an interrupted write ends this way; a hand-made one may)",
        path.display()
    ))
}

/// Refuses a header whose column names hold a NUL byte or another control
/// character (a tab aside), naming the column by position: such a name matches nothing,
/// and "missing column" would send the user looking for the wrong cause.
pub(crate) fn header_characters(headers: &[String], path: &Path) -> Result<()> {
    for (i, h) in headers.iter().enumerate() {
        // A tab is left to the separator hint of the missing-column message.
        if let Some(c) = h.chars().find(|c| c.is_control() && *c != '\t') {
            let what =
                if c == '\0' { "a NUL byte".to_string() } else { format!("the control character U+{:04X}", c as u32) };
            return Err(csv_error(
                path,
                1,
                None,
                format!(
                    "column {} of the header of {} ('{}') contains {what}: the file is damaged or not text; \
                     fix the header",
                    i + 1,
                    path.display(),
                    echo(h)
                ),
            ));
        }
    }
    Ok(())
}

/// A header read as one column that holds `;` or tabs: a file separated
/// by those rather than commas.
pub(crate) fn separated_by_semicolons_or_tabs(headers: &[String]) -> bool {
    headers.len() == 1 && (headers[0].contains(';') || headers[0].contains('\t'))
}

/// Checks the header: every column named once, no control characters,
/// every required column present (with a hint when the separator looks
/// wrong).
pub(crate) fn check_header(headers: &[String], path: &Path) -> Result<()> {
    let mut seen = std::collections::BTreeSet::new();
    let dups: Vec<String> = headers.iter().filter(|h| !seen.insert(h.as_str())).map(|h| echo(h)).collect();
    if !dups.is_empty() {
        return Err(csv_error(
            path,
            1,
            None,
            format!("duplicate column name(s) {}: every column must be named once", list(&dups)),
        ));
    }
    header_characters(headers, path)?;
    let missing: Vec<String> =
        REQUIRED_COLUMNS.iter().filter(|c| !headers.iter().any(|h| h == *c)).map(|c| c.to_string()).collect();
    if !missing.is_empty() {
        let first = headers.first().map(|h| h.trim_start()).unwrap_or_default();
        // A manifest under another name is read as a CSV by its ending.
        let hint = if first.starts_with('[') {
            Some("the file looks like a manifest (TOML): give it a name ending in .toml".to_string())
        } else if first.starts_with('#') {
            Some(
                "the first line is a comment: the canonical CSV starts with its header row (a manifest, TOML, needs \
                 a name ending in .toml)"
                    .to_string(),
            )
        } else if separated_by_semicolons_or_tabs(headers) {
            Some("the header looks separated by ';' or tabs: the canonical CSV is comma-separated".to_string())
        } else {
            None
        };
        return Err(Error::MissingColumns {
            path: path.to_path_buf(),
            missing,
            found: listed(&headers.iter().map(|h| echo(h)).collect::<Vec<_>>()),
            hint,
        });
    }
    Ok(())
}

/// The smallest part of a drive CSV read by a thread of its own
/// ([`Columns::read_in_parts`]): about 4 000 rows, a few milliseconds of
/// parsing; a smaller file gains too little from being split.
const PART_MIN_BYTES: usize = 1 << 20;

/// Where to cut `bytes` into `parts` parts of about equal size, each cut
/// right after a `\n` at or after `header_end` (the byte the header's
/// reader stopped at): the offsets, from 0 to `bytes.len()`; fewer parts
/// where the file has too few line ends.
fn part_cuts(bytes: &[u8], header_end: usize, parts: usize) -> Vec<usize> {
    let mut cuts = vec![0];
    for k in 1..parts {
        let last = cuts.last().copied().unwrap_or(0);
        let from = (bytes.len() / parts * k).max(header_end).max(last);
        match bytes.get(from..).and_then(|rest| memchr::memchr(b'\n', rest)) {
            Some(i) if from + i + 1 < bytes.len() => cuts.push(from + i + 1),
            _ => break,
        }
    }
    cuts.push(bytes.len());
    cuts.dedup();
    cuts
}

/// The cells of a canonical CSV by column, and the file line of each row.
struct Columns {
    /// Column names, in file order.
    headers: Vec<String>,
    /// Columns odocal uses (required, truth, mask, part): numbers only.
    /// Others may hold text.
    numeric: Vec<bool>,
    /// Each column's numbers (emptied when the column turns to text).
    nums: Vec<Vec<f64>>,
    /// Each extra column's cells as text, once one of them is not a number.
    text: Vec<Option<Vec<String>>>,
    /// File line of each row.
    lines: Vec<u64>,
}

impl Columns {
    /// Reads every data row; a row with the wrong number of fields, a
    /// non-number or a non-finite number in a column odocal uses, or no row
    /// at all is an error.
    fn read(rdr: &mut ::csv::Reader<LineCounted<&[u8]>>, headers: Vec<String>, path: &Path) -> Result<Columns> {
        let cols = Self::read_rows(rdr, headers, path)?;
        if cols.lines.is_empty() {
            return Err(Error::InvalidDrive {
                context: path.display().to_string(),
                reason: "the file has a header but no data rows".into(),
            });
        }
        Ok(cols)
    }

    /// [`Columns::read`] of a whole file, `bytes`, in parts at once, one per
    /// thread of the rayon pool and none under `min_part` bytes. `rdr` has
    /// read the header, `headers`, and is used as it is where the file is
    /// read in one part.
    ///
    /// The parts are cut after line ends (`\n`), each read with its file
    /// lines: the result is the same as reading the file in one part. So is
    /// the error: each part is read to its first error, and the error of
    /// the earliest part that has one is returned. A file holding a `"` is read in one part (a quoted
    /// field may hold a line end, so a cut after one need not be between
    /// rows), and one whose extra column turns to text in any part is read
    /// again in one part (the cells after the first text cell are kept as
    /// written, which only the part that holds it knows).
    fn read_in_parts(
        mut rdr: ::csv::Reader<LineCounted<&[u8]>>,
        bytes: &[u8],
        headers: Vec<String>,
        path: &Path,
        min_part: usize,
    ) -> Result<Columns> {
        let parts = rayon::current_num_threads().min(bytes.len() / min_part.max(1));
        let header_end = usize::try_from(rdr.position().byte()).unwrap_or(bytes.len());
        let cuts = part_cuts(bytes, header_end, parts);
        if cuts.len() < 3 || memchr::memchr(b'"', bytes).is_some() {
            return Self::read(&mut rdr, headers, path);
        }
        let spans: Vec<(usize, usize)> = cuts.windows(2).map(|w| (w[0], w[1])).collect();
        let ends: Vec<u64> = spans.par_iter().map(|&(a, b)| count_line_ends(&bytes[a..b])).collect();
        let first_lines: Vec<u64> = ends.iter().scan(1, |line, e| Some(std::mem::replace(line, *line + e))).collect();
        let read: Vec<Option<Result<Columns>>> = spans
            .par_iter()
            .zip(&first_lines)
            .map(|(&(a, b), &line)| {
                let part = &bytes[a..b];
                if a == 0 {
                    let mut rdr = super::csv_lines::reader(part);
                    // The whole header in the first part; else (never seen) one part.
                    let same = rdr.headers().is_ok_and(|h| h.iter().eq(headers.iter().map(String::as_str)));
                    same.then(|| Self::read_rows(&mut rdr, headers.clone(), path))
                } else {
                    // Rows of the wrong length are the row check's error, as the
                    // header's reader gives them.
                    let mut rdr = ::csv::ReaderBuilder::new()
                        .has_headers(false)
                        .flexible(true)
                        .trim(::csv::Trim::All)
                        .from_reader(LineCounted::starting_at(part, line));
                    Some(Self::read_rows(&mut rdr, headers.clone(), path))
                }
            })
            .collect();
        let mut parts = Vec::with_capacity(read.len());
        for r in read {
            let Some(cols) = r.transpose()? else {
                return Self::read_whole(bytes, headers, path);
            };
            if cols.text.iter().any(Option::is_some) {
                return Self::read_whole(bytes, headers, path);
            }
            parts.push(cols);
        }
        match Self::join(parts) {
            Some(cols) if !cols.lines.is_empty() => Ok(cols),
            _ => Self::read_whole(bytes, headers, path),
        }
    }

    /// [`Columns::read`] of the whole file `bytes` in one part.
    fn read_whole(bytes: &[u8], headers: Vec<String>, path: &Path) -> Result<Columns> {
        let mut rdr = super::csv_lines::reader(bytes);
        if let Err(e) = rdr.headers().map(|_| ()) {
            return Err(from_csv(path, e, rdr.get_mut()));
        }
        Self::read(&mut rdr, headers, path)
    }

    /// The rows of `parts` (same headers, numbers only) one after another,
    /// each column joined by a thread of its own, the parts' copies of a
    /// column freed once it is joined (memory as for one part, but for the
    /// columns being joined); `None` for no part.
    fn join(parts: Vec<Columns>) -> Option<Columns> {
        let mut parts = parts.into_iter();
        let mut first = parts.next()?;
        let mut rest: Vec<Columns> = parts.collect();
        let rows = first.lines.len() + rest.iter().map(|p| p.lines.len()).sum::<usize>();
        let later: Vec<Vec<Vec<f64>>> =
            (0..first.nums.len()).map(|j| rest.iter_mut().map(|p| std::mem::take(&mut p.nums[j])).collect()).collect();
        first.nums.par_iter_mut().zip(later).for_each(|(column, later)| {
            column.reserve_exact(rows.saturating_sub(column.len()));
            for part in later {
                column.extend_from_slice(&part);
            }
        });
        first.lines.reserve_exact(rows.saturating_sub(first.lines.len()));
        for p in rest {
            first.lines.extend_from_slice(&p.lines);
        }
        Some(first)
    }

    /// The rows `rdr` gives, none an error.
    fn read_rows(rdr: &mut ::csv::Reader<LineCounted<&[u8]>>, headers: Vec<String>, path: &Path) -> Result<Columns> {
        let numeric: Vec<bool> = headers
            .iter()
            .map(|h| {
                REQUIRED_COLUMNS.contains(&h.as_str())
                    || TRUTH_COLUMNS.contains(&h.as_str())
                    || h == MASK_COLUMN
                    || h == PART_COLUMN
            })
            .collect();
        let n = headers.len();
        let mut cols = Columns { headers, numeric, nums: vec![Vec::new(); n], text: vec![None; n], lines: Vec::new() };
        let mut record = ::csv::StringRecord::new();
        while rdr.read_record(&mut record).map_err(|e| from_csv(path, e, rdr.get_mut()))? {
            let line = rdr.get_mut().line_of(record.position());
            if record.len() != n {
                return Err(csv_error(path, line, None, format!("{} fields, the header has {n}", record.len())));
            }
            for (j, field) in record.iter().enumerate() {
                cols.push(j, field, line, path)?;
            }
            cols.lines.push(line);
        }
        Ok(cols)
    }

    /// One cell of column `j`: a number, or text in an extra column from its
    /// first cell that is not a number on (the numbers before it kept as
    /// text).
    fn push(&mut self, j: usize, field: &str, line: u64, path: &Path) -> Result<()> {
        if let Some(tx) = self.text[j].as_mut() {
            tx.push(field.to_string());
            return Ok(());
        }
        let column = Some(self.headers[j].as_str());
        match field.parse::<f64>() {
            Ok(v) if v.is_finite() || !self.numeric[j] => self.nums[j].push(v),
            Ok(_) => {
                let why = format!("value '{}' is not finite; {NUMBER_IN_EVERY_CELL}", echo(field));
                return Err(csv_error(path, line, column, why));
            }
            Err(_) if self.numeric[j] => {
                let why = format!("'{}' is not a number; {NUMBER_IN_EVERY_CELL}", echo(field));
                return Err(csv_error(path, line, column, why));
            }
            Err(_) => {
                let mut tx: Vec<String> = std::mem::take(&mut self.nums[j]).iter().map(|v| v.to_string()).collect();
                tx.push(field.to_string());
                self.text[j] = Some(tx);
            }
        }
        Ok(())
    }

    /// Index of the column `name`.
    fn find(&self, name: &str) -> Option<usize> {
        self.headers.iter().position(|h| h == name)
    }

    /// File line of a sample (0 when unknown).
    fn line_of(&self, sample: usize) -> u64 {
        self.lines.get(sample).copied().unwrap_or(0)
    }

    /// Takes the numbers of the column `name` (empty when there is none).
    fn take(&mut self, name: &str) -> Vec<f64> {
        self.find(name).map(|j| std::mem::take(&mut self.nums[j])).unwrap_or_default()
    }

    /// Takes the model signals of the columns named with `suffix`.
    fn signals(&mut self, suffix: &str) -> Signals {
        let [px, py, psi, n_rl, n_rr, beta, a_y] = SIGNAL_NAMES.map(|c| self.take(&format!("{c}{suffix}")));
        Signals { px, py, psi, n_rl, n_rr, beta, a_y }
    }

    /// The drive: time, measured signals, the truth when every truth column
    /// is there, part ids, the reference mask, extra columns; an invalid
    /// sample's error names its line and column.
    fn into_drive(mut self, path: &Path) -> Result<Drive> {
        let measured = self.signals("");
        let truth = TRUTH_COLUMNS.iter().all(|c| self.find(c).is_some()).then(|| self.signals("_true"));
        let t = self.take("t");
        let b = DriveBuilder {
            context: path.display().to_string(),
            t,
            measured,
            truth,
            part_ids: self.part_ids(path)?,
            reference_measured: self.reference_mask(path)?,
            extra: self.extra_columns(),
            ..Default::default()
        };
        b.build().map_err(|e| match e {
            Error::InvalidSample { column, sample, reason, .. } => {
                csv_error(path, self.line_of(sample), Some(&column), reason)
            }
            e => e,
        })
    }

    /// The `part` column as integer ids, when there is one.
    fn part_ids(&self, path: &Path) -> Result<Option<Vec<i64>>> {
        let Some(j) = self.find(PART_COLUMN) else { return Ok(None) };
        let mut ids = Vec::with_capacity(self.nums[j].len());
        for (i, &v) in self.nums[j].iter().enumerate() {
            if v.fract() != 0.0 || !(0.0..=1e15).contains(&v) {
                return Err(csv_error(
                    path,
                    self.line_of(i),
                    Some(PART_COLUMN),
                    format!("part id {v} is not a non-negative integer (parts are numbered 0, 1, 2, …)"),
                ));
            }
            ids.push(v as i64);
        }
        Ok(Some(ids))
    }

    /// The `ref_measured` column as flags (each exactly 0 or 1), when there
    /// is one.
    fn reference_mask(&self, path: &Path) -> Result<Option<Vec<bool>>> {
        let Some(j) = self.find(MASK_COLUMN) else { return Ok(None) };
        let mut mask = Vec::with_capacity(self.nums[j].len());
        for (i, &v) in self.nums[j].iter().enumerate() {
            let one = v.to_bits() == 1.0f64.to_bits();
            if v != 0.0 && !one {
                return Err(csv_error(path, self.line_of(i), Some(MASK_COLUMN), format!("{v} is not 0 or 1")));
            }
            mask.push(one);
        }
        Ok(Some(mask))
    }

    /// Takes the columns odocal does not use, as numbers or text.
    fn extra_columns(&mut self) -> Vec<ExtraColumn> {
        let mut extra = Vec::new();
        for (j, h) in self.headers.iter().enumerate() {
            let values = match self.text[j].take() {
                Some(tx) => ExtraValues::Text(tx),
                None if !self.numeric[j] => ExtraValues::Numbers(std::mem::take(&mut self.nums[j])),
                None => continue,
            };
            extra.push(ExtraColumn { name: h.clone(), values });
        }
        extra
    }
}

impl Drive {
    /// Reads a canonical drive CSV (docs/method.md §2), with what the reader noticed
    /// that is not an error: a last line without a newline at its end (a
    /// hand-made file, or one cut off by an interrupted write). Accepts a
    /// UTF-8 BOM, CRLF line endings, extra columns (numbers or text, kept in
    /// [`Drive::extra`]; truth columns in [`Drive::truth`]) and any column
    /// order. An optional integer `part` column marks continuous parts of a
    /// drive with gaps; an optional 0/1 `ref_measured` column marks where
    /// the reference was really measured.
    ///
    /// # Errors
    /// [`Error::Io`], [`Error::Csv`] naming the line and column,
    /// [`Error::MissingColumns`] listing what was found,
    /// [`Error::InvalidDrive`] for a directory or a file that is not CSV text
    /// but a ROS bag, a Parquet file or a compressed archive (known by its
    /// first bytes), saying what to do instead. A short last row is an error
    /// naming the file and the line.
    ///
    /// ```
    /// # fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// use odocal::{Drive, sim::{simulate, SimOptions}};
    /// let drive = simulate(&SimOptions { length_km: 0.5, ..SimOptions::paper(1) })?.drive;
    /// let dir = tempfile::tempdir()?;
    /// let path = dir.path().join("drive.csv");
    /// drive.write_csv(&path)?;
    /// let (read, warnings) = Drive::read_csv(&path)?;
    /// assert_eq!(read.fingerprint(), drive.fingerprint());
    /// assert!(warnings.is_empty());
    /// # Ok(()) }
    /// ```
    pub fn read_csv(path: impl AsRef<Path>) -> Result<(Drive, Vec<String>)> {
        let path = path.as_ref();
        if path.is_dir() {
            // A rosbag2 directory (metadata.yaml beside .mcap or .db3 files) or
            // any other folder: say so instead of the OS's "Is a directory".
            let bag = path.join("metadata.yaml").is_file();
            let reason = if bag {
                "a ROS 2 bag directory, not a canonical drive CSV: draft a manifest for it with `odocal inspect \
                 DIR --manifest OUT.toml`, check it and give the manifest (.toml) instead"
            } else {
                "a directory, not a canonical drive CSV: give the drive's .csv file (or a manifest, .toml)"
            };
            return Err(Error::InvalidDrive { context: path.display().to_string(), reason: reason.into() });
        }
        if path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("toml")) {
            return Err(Error::InvalidDrive {
                context: path.display().to_string(),
                reason: "a manifest (.toml), not a canonical drive CSV: import it (calibrate, validate and \
                         compensate take it as it is; `odocal import FILE --out drive.csv`; Python: \
                         Drive.from_manifest or Drive.load)"
                    .into(),
            });
        }
        let bytes = crate::output::limited::read_limited(path, crate::output::limited::MAX_DATA_BYTES, "a drive CSV")
            .map_err(|source| Error::io(path, source))?;
        let drive = Self::parse_csv(&bytes, path)?;
        Ok((drive, tail_warning(&bytes, path).into_iter().collect()))
    }

    /// Parses canonical CSV from bytes; `path` is used in error messages
    /// (outside the crate: [`Drive::read_csv`] of a file).
    pub(crate) fn parse_csv(bytes: &[u8], path: &Path) -> Result<Drive> {
        Self::parse_csv_in_parts(bytes, path, PART_MIN_BYTES)
    }

    /// [`Drive::parse_csv`], its rows read in parts of at least `min_part`
    /// bytes ([`Columns::read_in_parts`]).
    fn parse_csv_in_parts(bytes: &[u8], path: &Path, min_part: usize) -> Result<Drive> {
        if let Some(what) = not_csv(bytes) {
            return Err(Error::InvalidDrive { context: path.display().to_string(), reason: what.into() });
        }
        let bytes = bytes.strip_prefix(b"\xEF\xBB\xBF".as_slice()).unwrap_or(bytes);
        if bytes.iter().all(|b| b.is_ascii_whitespace()) {
            return Err(Error::InvalidDrive {
                context: path.display().to_string(),
                reason: "the file is empty (expected a header row with columns t, px, py, psi, n_rl, n_rr, beta, a_y)"
                    .into(),
            });
        }
        let mut rdr = super::csv_lines::reader(bytes);
        let headers: Vec<String> = match rdr.headers() {
            Ok(h) => h.iter().map(|h| h.to_string()).collect(),
            Err(e) => return Err(from_csv(path, e, rdr.get_mut())),
        };
        check_header(&headers, path)?;
        let cols = Columns::read_in_parts(rdr, bytes, headers, path, min_part).map_err(|e| short_last_row(e, bytes))?;
        cols.into_drive(path)
    }

    /// Writes the canonical CSV (with truth, `ref_measured` when present,
    /// `part` when there are several parts, and extra columns). Numbers are
    /// written in full precision (shortest round-trip form), so a write/read
    /// round trip is exact. The file is written atomically
    /// ([`crate::output`]): an interrupted write leaves
    /// the previous file (or none), never a part of the drive.
    pub fn write_csv(&self, path: impl AsRef<Path>) -> Result<()> {
        crate::output::write_atomically(path.as_ref(), |w| self.write_csv_to(w))
    }

    /// Writes the canonical CSV to any writer.
    pub fn write_csv_to<W: std::io::Write>(&self, w: W) -> std::io::Result<()> {
        let mut wtr = ::csv::WriterBuilder::new().from_writer(w);
        let mut header: Vec<String> = std::iter::once("t".to_string())
            .chain(self.measured.columns().iter().map(|(n, _)| n.to_string()))
            .collect();
        if self.truth.is_some() {
            header.extend(TRUTH_COLUMNS.iter().map(|c| c.to_string()));
        }
        header.extend(self.extra.iter().map(|c| c.name.clone()));
        if self.reference_measured.is_some() {
            header.push(MASK_COLUMN.into());
        }
        let with_parts = self.parts.len() > 1;
        if with_parts {
            header.push(PART_COLUMN.into());
        }
        wtr.write_record(&header)?;
        let mut part_of = vec![0usize; self.len()];
        for (p, r) in self.parts.iter().enumerate() {
            part_of[r.clone()].fill(p);
        }
        let mut row: Vec<String> = Vec::with_capacity(header.len());
        for i in 0..self.len() {
            row.clear();
            row.push(format!("{}", self.t[i]));
            row.extend(self.measured.columns().iter().map(|(_, c)| format!("{}", c[i])));
            if let Some(tr) = &self.truth {
                row.extend(tr.columns().iter().map(|(_, c)| format!("{}", c[i])));
            }
            for c in &self.extra {
                row.push(match &c.values {
                    ExtraValues::Numbers(v) => format!("{}", v[i]),
                    ExtraValues::Text(v) => v[i].clone(),
                });
            }
            if let Some(m) = &self.reference_measured {
                row.push(if m[i] { "1" } else { "0" }.into());
            }
            if with_parts {
                row.push(part_of[i].to_string());
            }
            wtr.write_record(&row)?;
        }
        wtr.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv_text(rows: usize, ts: f64) -> String {
        let mut s = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
        for i in 0..rows {
            s.push_str(&format!("{},{},0,0,5,5,0,0\n", i as f64 * ts, i as f64 * 0.25));
        }
        s
    }

    fn parse(s: &str) -> Result<Drive> {
        Drive::parse_csv(s.as_bytes(), Path::new("d.csv"))
    }

    /// `text` read in one part and in parts of at least 64 bytes by 4
    /// threads: the drives, or the errors' messages.
    fn in_one_part_and_in_parts(
        text: &[u8],
    ) -> (std::result::Result<Drive, String>, std::result::Result<Drive, String>) {
        let read = |min_part: usize| {
            let pool = rayon::ThreadPoolBuilder::new().num_threads(4).build().expect("pool");
            pool.install(|| Drive::parse_csv_in_parts(text, Path::new("d.csv"), min_part).map_err(|e| e.to_string()))
        };
        (read(usize::MAX), read(64))
    }

    #[test]
    fn a_file_read_in_parts_gives_the_drive_of_one_part() {
        let sim = crate::sim::simulate(&crate::sim::SimOptions { length_km: 0.3, ..crate::sim::SimOptions::paper(2) })
            .expect("sim");
        let mut lf = Vec::new();
        sim.drive.write_csv_to(&mut lf).expect("write");
        let crlf = String::from_utf8(lf.clone()).expect("utf-8").replace('\n', "\r\n").into_bytes();
        let extra = String::from_utf8(lf.clone())
            .expect("utf-8")
            .lines()
            .enumerate()
            .map(|(i, l)| format!("{l},{}\n", if i == 0 { "note".to_string() } else { (i % 7).to_string() }))
            .collect::<String>();
        // An extra column that turns to text far into the file, and a quoted one.
        let on_rows = |rows: std::ops::Range<usize>, cell: &str| {
            let mut lines: Vec<String> = extra.lines().map(str::to_string).collect();
            for line in &mut lines[rows] {
                let last = line.rfind(',').expect("a comma");
                line.replace_range(last + 1.., cell);
            }
            lines.join("\n") + "\n"
        };
        let text_late = on_rows(150..151, "late");
        // Quoted numbers that hold line ends (trimmed): a cut after one is
        // inside a row.
        let quoted = on_rows(1..sim.drive.len() + 1, "\"7\n\"");
        for text in [lf, crlf, extra.into_bytes(), text_late.into_bytes(), quoted.into_bytes()] {
            let (one, parts) = in_one_part_and_in_parts(&text);
            let one = one.expect("a valid drive");
            assert_eq!(Ok(&one), parts.as_ref(), "{}", String::from_utf8_lossy(&text[..200]));
            assert!(one.len() > 200);
        }
    }

    #[test]
    fn a_file_read_in_parts_fails_as_in_one_part() {
        let base = csv_text(400, 0.025);
        let lines: Vec<&str> = base.lines().collect();
        let faults: [&dyn Fn(&str) -> String; 8] = [
            &|l| l.replacen(",", ",abc", 2).replacen(",abc", ",", 1),
            &|l| l.replacen(",0,", ",inf,", 1),
            &|l| l.rsplit_once(',').map_or("", |x| x.0).to_string(),
            &|l| format!("{l},9"),
            &|l| l.replacen(",0,", ",0\u{0},", 1),
            &|_| "   ".to_string(),
            &|l| format!("{l}\n\n"),
            &|l| format!("{l}\r"),
        ];
        for row in [1, 2, 37, 150, 200, 399, 400] {
            for (k, fault) in faults.iter().enumerate() {
                for ending in ["\n", "\r\n"] {
                    let mut text: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
                    text[row] = fault(&text[row]);
                    let text = text.join(ending) + ending;
                    let (one, parts) = in_one_part_and_in_parts(text.as_bytes());
                    assert_eq!(one, parts, "fault {k} on row {row}, line ending {ending:?}");
                }
            }
            // Bytes that are not UTF-8 in a number.
            let mut bytes = base.clone().into_bytes();
            let at = base.match_indices('\n').nth(row - 1).map(|(i, _)| i + 3).expect("row");
            bytes[at] = 0xff;
            let (one, parts) = in_one_part_and_in_parts(&bytes);
            assert!(one.is_err());
            assert_eq!(one, parts, "invalid UTF-8 on row {row}");
        }
    }

    #[test]
    fn parses_and_infers_sample_time() {
        let d = parse(&csv_text(10, 0.025)).expect("valid");
        assert_eq!(d.len(), 10);
        approx::assert_relative_eq!(d.sample_time_s(), 0.025, max_relative = 1e-12);
    }

    #[test]
    fn accepts_bom_crlf_extra_columns_any_order() {
        let s = "\u{feff}a_y,extra,beta,n_rr,n_rl,psi,py,px,t\r\n0,7,0,5,5,0,0,0,0\r\n0,8,0,5,5,0,0,0.25,0.025\r\n0,9,0,5,5,0,0,0.5,0.05\r\n";
        let d = parse(s).expect("valid");
        assert_eq!(d.len(), 3);
        assert_eq!(d.extra().len(), 1);
        assert_eq!(d.extra()[0].name, "extra");
        approx::assert_relative_eq!(d.px()[2], 0.5);
    }

    #[test]
    fn text_in_extra_columns_is_kept() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,note\n0,0,0,0,5,5,0,0,1\n0.025,0.25,0,0,5,5,0,0,ramp\n0.05,0.5,0,0,5,5,0,0,\"a, b\"\n";
        let d = parse(s).expect("valid");
        let note = d.extra_column("note").expect("note");
        assert_eq!(note.values, ExtraValues::Text(vec!["1".into(), "ramp".into(), "a, b".into()]));
        let mut buf = Vec::new();
        d.write_csv_to(&mut buf).expect("write");
        assert_eq!(Drive::parse_csv(&buf, Path::new("y.csv")).expect("valid"), d);
    }

    #[test]
    fn missing_columns_are_listed() {
        let m = parse("t,px,py\n0,0,0\n").expect_err("missing").to_string();
        assert!(m.contains("missing column(s) psi, n_rl, n_rr, beta, a_y"), "{m}");
        assert!(m.contains("columns found: t, px, py"), "{m}");
        let m = parse("t;px;py;psi;n_rl;n_rr;beta;a_y\n0;0;0;0;0;0;0;0\n").expect_err("semicolons").to_string();
        assert!(m.contains("separated by ';'"), "{m}");
        // A manifest given a .csv or .txt name, and a CSV opening with a comment.
        let m = parse("[output]\nrate_hz = 40\n").expect_err("a manifest").to_string();
        assert!(m.contains("looks like a manifest (TOML): give it a name ending in .toml"), "{m}");
        let m = parse("# a drive\nt,px,py,psi,n_rl,n_rr,beta,a_y\n0,0,0,0,0,0,0,0\n").expect_err("comment").to_string();
        assert!(m.contains("the first line is a comment: the canonical CSV starts with its header row"), "{m}");
    }

    #[test]
    fn duplicate_columns_are_rejected() {
        let m = parse("t,px,py,psi,n_rl,n_rr,beta,a_y,t\n0,0,0,0,0,0,0,0,1\n").expect_err("dup").to_string();
        assert_eq!(m, "d.csv: line 1: duplicate column name(s) t: every column must be named once");
    }

    #[test]
    fn long_fields_are_truncated_in_errors() {
        let big = "x".repeat(10_000);
        let s = csv_text(5, 0.025).replacen("0.05,0.5", &format!("0.05,{big}"), 1);
        let m = parse(&s).expect_err("text").to_string();
        // Short but for the advice every cell without a number gets.
        assert!(m.len() < 200 + NUMBER_IN_EVERY_CELL.len(), "{} chars", m.len());
        assert!(m.contains("… (10000 bytes)"), "{m}");
    }

    #[test]
    fn nan_and_text_name_line_and_column() {
        let s = csv_text(5, 0.025).replacen("0.05,0.5", "0.05,NaN", 1);
        let m = parse(&s).expect_err("nan").to_string();
        assert!(m.contains("line 4") && m.contains("column 'px'") && m.contains("not finite"), "{m}");
        let s = csv_text(5, 0.025).replacen("0.05,0.5", "0.05,abc", 1);
        let m = parse(&s).expect_err("text").to_string();
        assert!(m.contains("line 4") && m.contains("'abc' is not a number"), "{m}");
    }

    /// The error of `text` with LF, CRLF and lone-CR line endings, then with
    /// CRLF and two empty lines after line 2 (the line named moves down by
    /// two); a `§` in `text` becomes the byte 0xFF (not UTF-8).
    fn errors_at_every_line_ending(text: &str) -> Vec<String> {
        let blank = text.replacen('\n', "\n\n\n", 2).replacen("\n\n\n", "\n", 1);
        [text.to_string(), text.replace('\n', "\r\n"), text.replace('\n', "\r"), blank.replace('\n', "\r\n")]
            .iter()
            .map(|t| {
                let bytes: Vec<u8> = t.split('§').map(str::as_bytes).collect::<Vec<_>>().join(&[0xFF_u8][..]);
                Drive::parse_csv(&bytes, Path::new("d.csv")).expect_err("bad row").to_string()
            })
            .collect()
    }

    #[test]
    fn errors_name_the_line_for_lf_crlf_and_cr_files() {
        let s = csv_text(6, 0.025);
        for (bad, what, line) in [
            (s.replacen("0.05,0.5", "0.05,NaN", 1), "not finite", 4),
            (s.replacen("0.05,0.5", "0.05,abc", 1), "is not a number", 4),
            (s.replacen("0.05,0.5,0,0,5,5,0,0", "0.05,0.5,0", 1), "3 fields, the header has 8", 4),
            (s.replacen("0.05,", "0.01,", 1), "not strictly increasing", 4),
            (s.replacen("0.05,0.5,0,0,5,5", "0.05,0.5,0,0,5,§", 1), "invalid UTF-8", 4),
            (s[..s.len() - 6].to_string(), "the last row is short", 7),
        ] {
            for (i, m) in errors_at_every_line_ending(&bad).iter().enumerate() {
                let want = if i == 3 { line + 2 } else { line };
                assert!(m.starts_with(&format!("d.csv: line {want}")) && m.contains(what), "ending {i}: {m}");
            }
        }
        // A JSON file (the simulator's sidecar given by mistake) says so.
        let m = parse("{\"theta_true\": {\"c_e\": 2.0}}\n").expect_err("json").to_string();
        assert!(m.contains("a JSON file") && m.contains("give the drive CSV"), "{m}");
        // A cell without a number says what to do about it.
        for cell in ["NaN", "inf", ""] {
            let m = parse(&s.replacen("0.05,0.5", &format!("0.05,{cell}"), 1)).expect_err("no number").to_string();
            assert!(m.ends_with("drop the row and mark the gap with a 'part' column (docs/reference.md, the drive CSV), or import the log with a manifest (docs/guide.md)"), "{m}");
        }
    }

    #[test]
    fn time_errors_name_line() {
        let s = csv_text(6, 0.025).replacen("0.05,", "0.01,", 1);
        let m = parse(&s).expect_err("nonmono").to_string();
        assert!(m.contains("line 4") && m.contains("not strictly increasing"), "{m}");
        let s = csv_text(6, 0.025).replacen("0.1,", "0.11,", 1);
        let m = parse(&s).expect_err("nonuni").to_string();
        assert!(m.contains("uniform") && m.contains("line 6"), "{m}");
    }

    /// One long gap is named at its own line: against the mean step, which
    /// the gap moves off every other step, the first step would be named.
    /// Huge times are echoed short.
    #[test]
    fn a_gap_is_named_at_its_line_and_huge_times_stay_short() {
        let with_jump = |jump: f64| {
            let mut s = String::from("t,px,py,psi,n_rl,n_rr,beta,a_y\n");
            for i in 0..100 {
                let t = i as f64 * 0.025 + if i >= 60 { jump } else { 0.0 };
                s.push_str(&format!("{t},{},0,0,5,5,0,0\n", i as f64 * 0.25));
            }
            s
        };
        let m = parse(&with_jump(1e6)).expect_err("gap").to_string();
        assert!(m.contains("line 62") && m.contains("sample step 1000000.025000 s"), "{m}");
        assert!(m.contains("the median step 0.025000 s") && m.contains("'part' column"), "{m}");
        let m = parse(&with_jump(1e300)).expect_err("equal times").to_string();
        assert!(m.contains("line 63") && m.contains("(1e300 after 1e300)") && m.len() < 200, "{m}");
    }

    #[test]
    fn bad_part_ids_name_the_cause() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,0.5\n";
        let m = parse(s).expect_err("float id").to_string();
        assert!(m.contains("line 3") && m.contains("not a non-negative integer"), "{m}");
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n0,0,0,0,1,1,0,0,-1\n0.1,0,0,0,1,1,0,0,-1\n";
        assert!(parse(s).expect_err("negative").to_string().contains("line 2"));
    }

    #[test]
    fn empty_inputs() {
        let m = parse("").expect_err("empty").to_string();
        assert!(m.contains("empty"), "{m}");
        let m = parse("t,px,py,psi,n_rl,n_rr,beta,a_y\n").expect_err("no rows").to_string();
        assert!(m.contains("no data rows"), "{m}");
    }

    #[test]
    fn a_short_last_row_is_an_error_naming_the_line() {
        let s = csv_text(6, 0.025);
        let cut = &s[..s.len() - 6];
        let m = parse(cut).expect_err("short row").to_string();
        assert!(m.starts_with("d.csv: line 7: 6 fields, the header has 8: the last row is short"), "{m}");
        // A short row elsewhere is not called the last.
        let mid = s.replacen("0.05,0.5,0,0,5,5,0,0\n", "0.05,0.5,0\n", 1);
        let m = parse(&mid).expect_err("short row").to_string();
        assert!(m.contains("line 4") && !m.contains("last row"), "{m}");
    }

    #[test]
    fn a_last_line_without_newline_is_read_with_a_warning() {
        let d = tmp_csv(csv_text(6, 0.025).trim_end());
        let (drive, warnings) = Drive::read_csv(d.path()).expect("valid");
        assert_eq!(drive.len(), 6);
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(warnings[0].contains("line 7, the last line, has no newline"), "{}", warnings[0]);
        let d = tmp_csv(&csv_text(6, 0.025));
        assert!(Drive::read_csv(d.path()).expect("valid").1.is_empty());
    }

    #[test]
    fn a_manifest_given_as_a_drive_csv_says_to_import_it() {
        let dir = tempfile::tempdir().expect("tmp");
        let m = dir.path().join("drive.toml");
        std::fs::write(&m, "# a manifest\n[streams.w]\nfile = \"w.csv\"\n").expect("write");
        let e = Drive::read_csv(&m).expect_err("manifest").to_string();
        assert!(e.contains("drive.toml: a manifest (.toml), not a canonical drive CSV: import it"), "{e}");
    }

    fn tmp_csv(text: &str) -> tempfile::NamedTempFile {
        let mut f = tempfile::NamedTempFile::new().expect("tmp");
        std::io::Write::write_all(&mut f, text.as_bytes()).expect("write");
        f
    }

    #[test]
    fn round_trip_is_exact() {
        let d = parse(&csv_text(20, 0.025)).expect("valid");
        let mut buf = Vec::new();
        d.write_csv_to(&mut buf).expect("write");
        let d2 = Drive::parse_csv(&buf, Path::new("y.csv")).expect("valid");
        assert_eq!(d, d2);
    }

    #[test]
    fn mask_round_trips() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,ref_measured\n0,0,0,0,1,1,0,0,1\n0.1,0,0,0,1,1,0,0,0\n0.2,0,0,0,1,1,0,0,1\n";
        let d = parse(s).expect("valid");
        assert_eq!(d.reference_measured(), Some(&[true, false, true][..]));
        let mut buf = Vec::new();
        d.write_csv_to(&mut buf).expect("write");
        assert_eq!(Drive::parse_csv(&buf, Path::new("y.csv")).expect("valid"), d);
        let bad = s.replacen(",0\n0.2", ",2\n0.2", 1);
        assert!(parse(&bad).expect_err("2").to_string().contains("is not 0 or 1"));
    }

    #[test]
    fn window_clips_parts() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,0\n0.2,0,0,0,1,1,0,0,0\n5.0,0,0,0,1,1,0,0,1\n5.1,0,0,0,1,1,0,0,1\n5.2,0,0,0,1,1,0,0,1\n";
        let d = parse(s).expect("valid");
        let w = d.window(0.15, 5.15).expect("window");
        assert_eq!(w.len(), 3);
        assert_eq!(w.parts(), &[0..1, 1..3]);
        assert!(d.window(10.0, 11.0).is_err());
    }

    #[test]
    fn parts_allow_gaps() {
        let s = "t,px,py,psi,n_rl,n_rr,beta,a_y,part\n0,0,0,0,1,1,0,0,0\n0.1,0,0,0,1,1,0,0,0\n0.2,0,0,0,1,1,0,0,0\n5.0,0,0,0,1,1,0,0,1\n5.1,0,0,0,1,1,0,0,1\n";
        let d = parse(s).expect("valid");
        assert_eq!(d.parts(), &[0..3, 3..5]);
        approx::assert_relative_eq!(d.sample_time_s(), 0.1, max_relative = 1e-9);
    }
}
