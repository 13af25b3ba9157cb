//! CSV streams (`format = "csv"`, the default): a header row, one row per
//! sample, numbers in the columns read (other columns are not looked at).

use std::collections::BTreeMap;
use std::io::BufRead;
use std::path::Path;

use super::{Table, Wanted};
use crate::drive::csv_lines::{reason, LineCounted};
use crate::error::{Error, Result};
use crate::io::import::limits::echo;
use crate::io::import::manifest::Manifest;

/// Reads the time column `time` and the `wanted` columns of `path`.
pub(super) fn read(m: &Manifest, name: &str, path: &Path, time: &str, wanted: &[Wanted]) -> Result<Table> {
    let key = format!("streams.{name}.file");
    let cannot_read = |e: &dyn std::fmt::Display| m.error(&key, format!("cannot read {}: {e}", path.display()));
    // Read as a stream, row by row into the columns asked for: the file's
    // text is never held whole.
    let file = crate::output::limited::open_limited(path, crate::output::limited::MAX_DATA_BYTES, "a CSV stream file")
        .map_err(|e| cannot_read(&e))?;
    let mut buffered = std::io::BufReader::with_capacity(1 << 16, file);
    let head = buffered.fill_buf().map_err(|e| cannot_read(&e))?;
    if head.starts_with(b"\xEF\xBB\xBF") {
        buffered.consume(3);
    }
    let mut rdr = crate::drive::csv_lines::reader(buffered);
    let csv_err = |e: ::csv::Error, lines: &mut LineCounted<_>| match e.kind() {
        ::csv::ErrorKind::Io(io) => cannot_read(io),
        _ => {
            Error::Csv { path: path.to_path_buf(), line: lines.line_of(e.position()), column: None, reason: reason(&e) }
        }
    };
    let headers: Vec<String> = match rdr.headers() {
        Ok(h) => h.iter().map(str::to_string).collect(),
        Err(e) => return Err(csv_err(e, rdr.get_mut())),
    };
    crate::drive::csv::header_characters(&headers, path)?;
    let mut all: Vec<Wanted> = vec![Wanted { column: time.to_string(), key: format!("streams.{name}.time_column") }];
    all.extend(wanted.iter().cloned());
    let mut idx = Vec::new();
    for w in &all {
        idx.push(header_column(&headers, &w.column, path).map_err(|e| m.error(&w.key, e))?);
    }
    let mut data: Vec<Vec<f64>> = vec![Vec::new(); all.len()];
    let mut lines: Vec<u64> = Vec::new();
    let mut record = ::csv::StringRecord::new();
    let mut line = 1u64;
    while rdr.read_record(&mut record).map_err(|e| csv_err(e, rdr.get_mut()))? {
        line = rdr.get_mut().line_of(record.position());
        for (c, &j) in idx.iter().enumerate() {
            let field = record.get(j).unwrap_or("");
            let v: f64 = field.parse().map_err(|_| Error::Csv {
                path: path.to_path_buf(),
                line,
                column: Some(headers[j].clone()),
                reason: format!("'{}' is not a number", echo(field)),
            })?;
            data[c].push(v);
        }
        lines.push(line);
    }
    let t_s = std::mem::take(&mut data[0]);
    let mut columns = BTreeMap::new();
    for (c, w) in all.iter().enumerate().skip(1) {
        columns.insert(w.column.clone(), std::mem::take(&mut data[c]));
    }
    let last_byte = rdr.get_ref().get_ref().get_ref().last_byte();
    let warnings = crate::drive::csv::tail_warning_at(last_byte, line, path).into_iter().collect();
    Ok(Table { t_s, columns, source: path.display().to_string(), lines: Some(lines), warnings })
}

/// The index of `column` in the `headers` of the stream file `path`; else
/// why not: the file is empty, the column is missing (with the header, and
/// a hint when it looks separated by `;` or tabs) or named more than once
/// (which of them to read would be a guess).
pub(crate) fn header_column(headers: &[String], column: &str, path: &Path) -> std::result::Result<usize, String> {
    if headers.iter().all(String::is_empty) {
        return Err(format!("{} is empty: a stream file starts with a header row naming its columns", path.display()));
    }
    let at: Vec<usize> = headers.iter().enumerate().filter(|(_, h)| *h == column).map(|(j, _)| j).collect();
    match at[..] {
        [j] => Ok(j),
        [] => {
            let separator = crate::drive::csv::separated_by_semicolons_or_tabs(headers);
            Err(format!(
                "column '{}' not found in {}; columns found: {}{}",
                echo(column),
                path.display(),
                list_headers(headers),
                if separator {
                    " (the header looks separated by ';' or tabs: a CSV stream is comma-separated)"
                } else {
                    ""
                }
            ))
        }
        _ => Err(format!(
            "column '{}' is named {} times in the header of {} (columns {}): which to read would be a guess; name \
             each column once",
            echo(column),
            at.len(),
            path.display(),
            at.iter().map(|j| (j + 1).to_string()).collect::<Vec<_>>().join(", ")
        )),
    }
}

/// The header for a message: at most 30 names, each echoed short.
fn list_headers(headers: &[String]) -> String {
    let mut out: Vec<String> = headers.iter().take(30).map(|h| echo(h)).collect();
    if headers.len() > 30 {
        out.push(format!("… ({} columns)", headers.len()));
    }
    out.join(", ")
}
