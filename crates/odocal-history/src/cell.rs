//! Reading the rows of a table with an error for a cell that does not
//! read (a hand-edited row: text in a numeric column) naming the row, its
//! vehicle and drive, the column and what to do.

use std::path::Path;

use rusqlite::types::ValueRef;
use rusqlite::Row;

use odocal::{Error, Result};

/// A row read by `read`, or why one of its cells does not read.
pub(crate) type Checked<T> = std::result::Result<T, String>;

/// `read` for `query_map` over a row of `table` whose columns 0, 3 and 4
/// are `id`, `vehicle` and `fingerprint`: a cell that does not read gives
/// the text [`bad_cell`] says, the other errors stay the database's.
pub(crate) fn checked<T>(
    table: &'static str,
    read: fn(&Row<'_>) -> rusqlite::Result<T>,
) -> impl FnMut(&Row<'_>) -> rusqlite::Result<Checked<T>> {
    move |r| match read(r) {
        Ok(v) => Ok(Ok(v)),
        Err(e) => bad_cell(table, r, &e).map(Err).ok_or(e),
    }
}

/// Collects the rows [`checked`] read: a database error as `sql_err`
/// makes it, a cell that does not read as [`Error::History`] with its text.
pub(crate) fn collect<T>(
    rows: impl Iterator<Item = rusqlite::Result<Checked<T>>>,
    path: &Path,
    sql_err: impl Fn(rusqlite::Error) -> Error,
) -> Result<Vec<T>> {
    let mut out = Vec::new();
    for row in rows {
        match row.map_err(&sql_err)? {
            Ok(v) => out.push(v),
            Err(reason) => return Err(Error::History { path: path.to_path_buf(), reason }),
        }
    }
    Ok(out)
}

/// `row 7 of table calibrations (vehicle 'van', drive 3f2a9c01b2d4…):
/// column c_e holds the text 'abc', where a number is expected; …` for an
/// error reading a cell, `None` for another error.
fn bad_cell(table: &str, r: &Row<'_>, e: &rusqlite::Error) -> Option<String> {
    use rusqlite::Error::{FromSqlConversionFailure, IntegralValueOutOfRange, InvalidColumnType};
    let i = match e {
        InvalidColumnType(i, ..) | FromSqlConversionFailure(i, ..) | IntegralValueOutOfRange(i, _) => *i,
        _ => return None,
    };
    let column = r.as_ref().column_name(i).map_or_else(|_| format!("number {i}"), str::to_string);
    let (held, expected) = match r.get_ref(i) {
        Ok(ValueRef::Text(t)) => (format!("the text '{}'", String::from_utf8_lossy(t).escape_debug()), "a number"),
        Ok(ValueRef::Blob(b)) => (format!("a blob of {} bytes", b.len()), "a number or text"),
        Ok(ValueRef::Null) => ("no value (NULL)".to_string(), "a value"),
        Ok(ValueRef::Integer(v)) => (format!("the number {v}"), "text"),
        Ok(ValueRef::Real(v)) => (format!("the number {v}"), "text"),
        Err(_) => ("a value".to_string(), "another"),
    };
    let id = r.get::<_, i64>(0).map_or_else(|_| "?".to_string(), |id| id.to_string());
    let text = |k: usize| r.get::<_, String>(k).ok();
    let mut of = Vec::new();
    if let Some(v) = text(3) {
        of.push(format!("vehicle '{}'", v.escape_debug()));
    }
    if let Some(f) = text(4) {
        let short: String = f.chars().take(12).collect();
        of.push(format!("drive {short}{}", if short.len() < f.len() { "…" } else { "" }));
    }
    let of = if of.is_empty() { String::new() } else { format!(" ({})", of.join(", ")) };
    Some(format!(
        "row {id} of table {table}{of}: column {column} holds {held}, where {expected} is expected (a row edited \
         by hand?); correct the cell or delete the row, e.g. with sqlite3: DELETE FROM {table} WHERE id = {id}"
    ))
}
