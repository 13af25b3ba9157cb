//! Parquet tables (`format = "parquet"`, cargo feature `parquet`): columns
//! are named in the manifest exactly as for CSV streams (the time column, the
//! wheel, pose, quality and IMU columns); other columns are not read.
//!
//! ## What is read
//!
//! Flat (top-level, non-repeated) columns of numbers: integers of any width,
//! signed or unsigned (`int8` … `uint64`), `float` and `double`, and
//! `boolean` as 0/1. Integers become the `f64` nearest them, as the same
//! digits parsed from CSV would; a `float` (32-bit) column is widened
//! exactly, so it equals its CSV text only when that text was printed from
//! the `float`. A timestamp column is read as its integer: give the stream's
//! `time_unit` as the column's unit (a column typed `timestamp[ns]` with
//! another `time_unit` is refused with the unit to set).
//!
//! ## What is refused
//!
//! Every error names the manifest key, the file and the column: a column the
//! file lacks (listing the columns it has, with their types), a column that
//! is not a number (strings, decimals, `float16`, `INT96`, lists and
//! structs), a null, a file that is not Parquet or is corrupt. Memory is
//! bounded: the rows the file declares × the columns read must fit
//! [`limits::MAX_STREAM_VALUES`] before anything is read, row groups are read
//! in batches of at most [`BATCH_ROWS`] rows, and a column chunk that holds
//! more or fewer rows than its row group declares is an error.

use std::collections::BTreeMap;
use std::fs::File;
use std::path::Path;

use ::parquet::basic::{LogicalType, TimeUnit as PqTimeUnit, Type as Physical};
use ::parquet::column::reader::{ColumnReader, ColumnReaderImpl};
use ::parquet::data_type::DataType;
use ::parquet::file::reader::{FileReader, SerializedFileReader};
use ::parquet::schema::types::{ColumnDescPtr, ColumnDescriptor};

use super::{Table, Wanted};
use crate::error::Result;
use crate::io::import::limits::{self, echo};
use crate::io::import::manifest::{Manifest, TimeUnit};

/// Rows read per batch from a row group.
pub(crate) const BATCH_ROWS: usize = 65_536;

/// How a column's values become `f64`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Kind {
    Bool,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

/// A column to read: its index in the file's leaf columns, how to convert
/// it, and the manifest key that asked for it.
struct Plan<'a> {
    name: &'a str,
    key: &'a str,
    leaf: usize,
    kind: Kind,
}

/// Reads the time column `time` (in `time_unit`) and the `wanted` columns of
/// the Parquet file `path`.
pub(super) fn read(
    m: &Manifest,
    name: &str,
    path: &Path,
    time: &str,
    time_unit: TimeUnit,
    wanted: &[Wanted],
) -> Result<Table> {
    let file_key = format!("streams.{name}.file");
    let shown = path.display().to_string();
    let file = File::open(path).map_err(|e| m.error(&file_key, format!("cannot read {shown}: {e}")))?;
    let reader = SerializedFileReader::new(file)
        .map_err(|e| m.error(&file_key, format!("{shown} is not a readable Parquet file: {e}")))?;
    let leaves = reader.metadata().file_metadata().schema_descr().columns();

    let time_key = format!("streams.{name}.time_column");
    let plans = plan_columns(m, leaves, (time, &time_key), time_unit, wanted, &shown)?;
    let rows = declared_rows(m, &file_key, &reader, plans.len(), &shown)?;
    let data = read_columns(m, &file_key, &reader, &plans, rows, &shown)?;

    let by_name: BTreeMap<&str, Vec<f64>> = plans.iter().map(|p| p.name).zip(data).collect();
    let t_s = by_name.get(time).cloned().unwrap_or_default();
    let columns: BTreeMap<String, Vec<f64>> = by_name
        .into_iter()
        .filter(|(c, _)| wanted.iter().any(|w| w.column == *c))
        .map(|(c, v)| (c.to_string(), v))
        .collect();
    Ok(Table { t_s, columns, source: shown, lines: None, warnings: Vec::new() })
}

/// A plan per distinct column, the time column (`(column, manifest key)`)
/// first, then the `wanted` ones: the column must be a flat number, and a
/// timestamp-typed time column must be read in its own unit.
fn plan_columns<'a>(
    m: &Manifest,
    leaves: &[ColumnDescPtr],
    time: (&'a str, &'a str),
    time_unit: TimeUnit,
    wanted: &'a [Wanted],
    shown: &str,
) -> Result<Vec<Plan<'a>>> {
    let (time_column, time_key) = time;
    let mut all: Vec<(&str, &str)> = vec![time];
    all.extend(wanted.iter().map(|w| (w.column.as_str(), w.key.as_str())));
    let mut plans: Vec<Plan> = Vec::new();
    for (column, key) in all {
        if plans.iter().any(|p| p.name == column) {
            continue;
        }
        // A list or struct `column` is found (its first leaf) and refused below.
        let Some(leaf) = leaves.iter().position(|d| d.path().parts().first().is_some_and(|p| p == column)) else {
            return Err(m.error(
                key,
                format!("column '{}' not found in {shown}; columns found: {}", echo(column), list_columns(leaves)),
            ));
        };
        let d = &leaves[leaf];
        let kind = kind_of(d).ok_or_else(|| {
            m.error(
                key,
                format!(
                    "column '{}' of {shown} is {}, not a number; odocal reads int, float, double and boolean \
                     columns; columns found: {}",
                    echo(column),
                    describe(d),
                    list_columns(leaves)
                ),
            )
        })?;
        if column == time_column {
            check_time_unit(m, time_key, d, time_unit, shown)?;
        }
        plans.push(Plan { name: column, key, leaf, kind });
    }
    Ok(plans)
}

/// The rows the file declares, within the budget of
/// [`limits::MAX_STREAM_VALUES`] values for `columns` columns: checked
/// before reading any data.
fn declared_rows(
    m: &Manifest,
    file_key: &str,
    reader: &SerializedFileReader<File>,
    columns: usize,
    shown: &str,
) -> Result<u64> {
    let mut rows: u64 = 0;
    for g in reader.metadata().row_groups() {
        let n = u64::try_from(g.num_rows())
            .map_err(|_| m.error(file_key, format!("{shown} declares a row group of {} rows", g.num_rows())))?;
        rows = rows.saturating_add(n);
    }
    let values = rows.saturating_mul(columns as u64);
    if values > limits::MAX_STREAM_VALUES as u64 {
        return Err(m.error(
            file_key,
            format!(
                "{shown} declares {rows} rows × {columns} columns read = {values} values, above the budget of {}; \
                 split the file",
                limits::MAX_STREAM_VALUES
            ),
        ));
    }
    Ok(rows)
}

/// The planned columns' values, row group by row group; a null, a chunk
/// with more or fewer rows than its group declares, or an unreadable chunk
/// is an error naming the column.
fn read_columns(
    m: &Manifest,
    file_key: &str,
    reader: &SerializedFileReader<File>,
    plans: &[Plan<'_>],
    rows: u64,
    shown: &str,
) -> Result<Vec<Vec<f64>>> {
    let leaves = reader.metadata().file_metadata().schema_descr().columns();
    let mut data: Vec<Vec<f64>> = plans.iter().map(|_| Vec::with_capacity(rows as usize)).collect();
    let mut first_row = 0usize;
    for g in 0..reader.num_row_groups() {
        let group = reader
            .get_row_group(g)
            .map_err(|e| m.error(file_key, format!("{shown}: cannot read row group {g}: {e}")))?;
        let n = usize::try_from(group.metadata().num_rows()).unwrap_or(0);
        for (p, out) in plans.iter().zip(data.iter_mut()) {
            let col = group.get_column_reader(p.leaf).map_err(|e| {
                m.error(p.key, format!("{shown}: cannot read column '{}' in row group {g}: {e}", echo(p.name)))
            })?;
            read_chunk(p.kind, col, n, leaves[p.leaf].max_def_level(), out).map_err(|e| {
                let reason = match e {
                    ColumnError::Null(i) => format!(
                        "column '{}' of {shown} has a null in row {} (counting from 0); every row needs a value: \
                         drop or fill the nulls",
                        echo(p.name),
                        first_row + i
                    ),
                    ColumnError::Rows(got) => format!(
                        "column '{}' of {shown}: row group {g} declares {n} rows but the column holds {}",
                        echo(p.name),
                        if got > n { format!("more than {n}") } else { got.to_string() }
                    ),
                    ColumnError::Corrupt(why) => {
                        format!("column '{}' of {shown}, row group {g}: {why}", echo(p.name))
                    }
                };
                m.error(p.key, reason)
            })?;
        }
        first_row += n;
    }
    Ok(data)
}

/// Appends one column chunk of `rows` values to `out`, converted as `kind`
/// says; pages of another type than the column declares are corrupt.
fn read_chunk(
    kind: Kind,
    col: ColumnReader,
    n: usize,
    max_def: i16,
    out: &mut Vec<f64>,
) -> std::result::Result<(), ColumnError> {
    match (kind, col) {
        (Kind::Bool, ColumnReader::BoolColumnReader(r)) => {
            read_column(r, n, max_def, out, |v| if v { 1.0 } else { 0.0 })
        }
        (Kind::I32, ColumnReader::Int32ColumnReader(r)) => read_column(r, n, max_def, out, f64::from),
        (Kind::U32, ColumnReader::Int32ColumnReader(r)) => read_column(r, n, max_def, out, |v| f64::from(v as u32)),
        (Kind::I64, ColumnReader::Int64ColumnReader(r)) => read_column(r, n, max_def, out, |v| v as f64),
        (Kind::U64, ColumnReader::Int64ColumnReader(r)) => read_column(r, n, max_def, out, |v| (v as u64) as f64),
        (Kind::F32, ColumnReader::FloatColumnReader(r)) => read_column(r, n, max_def, out, f64::from),
        (Kind::F64, ColumnReader::DoubleColumnReader(r)) => read_column(r, n, max_def, out, |v| v),
        _ => Err(ColumnError::Corrupt("its pages do not match its declared type".into())),
    }
}

/// Why a column chunk could not be read.
enum ColumnError {
    /// A null in the chunk's row `i`.
    Null(usize),
    /// The chunk holds this many rows, not its row group's count.
    Rows(usize),
    /// The parquet reader failed.
    Corrupt(String),
}

/// Appends the `rows` values of one column chunk to `out`, converted by
/// `conv`, in batches of [`BATCH_ROWS`]; a null is an error.
fn read_column<T: DataType>(
    mut r: ColumnReaderImpl<T>,
    rows: usize,
    max_def: i16,
    out: &mut Vec<f64>,
    conv: impl Fn(T::T) -> f64,
) -> std::result::Result<(), ColumnError>
where
    T::T: Copy,
{
    let mut values: Vec<T::T> = Vec::new();
    let mut defs: Vec<i16> = Vec::new();
    let mut done = 0usize;
    while done < rows {
        let batch = (rows - done).min(BATCH_ROWS);
        values.clear();
        defs.clear();
        let levels = if max_def > 0 { Some(&mut defs) } else { None };
        let (records, _, _) =
            r.read_records(batch, levels, None, &mut values).map_err(|e| ColumnError::Corrupt(e.to_string()))?;
        if records == 0 {
            return Err(ColumnError::Rows(done));
        }
        if values.len() < records {
            let i = defs.iter().position(|&d| d < max_def).unwrap_or(0);
            return Err(ColumnError::Null(done + i));
        }
        out.extend(values.iter().map(|&v| conv(v)));
        done += records;
    }
    // A chunk holding more rows than its group declares is corrupt.
    values.clear();
    defs.clear();
    let levels = if max_def > 0 { Some(&mut defs) } else { None };
    match r.read_records(1, levels, None, &mut values) {
        Ok((0, _, _)) => Ok(()),
        Ok(_) => Err(ColumnError::Rows(rows + 1)),
        Err(e) => Err(ColumnError::Corrupt(e.to_string())),
    }
}

/// How a leaf column becomes `f64`, or `None` when it is not a flat number.
fn kind_of(d: &ColumnDescriptor) -> Option<Kind> {
    if d.max_rep_level() > 0 || d.path().parts().len() != 1 {
        return None;
    }
    let unsigned = matches!(d.logical_type_ref(), Some(LogicalType::Integer(i)) if !i.is_signed);
    match (d.physical_type(), d.logical_type_ref()) {
        (_, Some(LogicalType::Decimal(_) | LogicalType::Date | LogicalType::Time(_))) => None,
        (Physical::BOOLEAN, _) => Some(Kind::Bool),
        (Physical::INT32, _) if unsigned => Some(Kind::U32),
        (Physical::INT32, _) => Some(Kind::I32),
        (Physical::INT64, _) if unsigned => Some(Kind::U64),
        (Physical::INT64, _) => Some(Kind::I64),
        (Physical::FLOAT, _) => Some(Kind::F32),
        (Physical::DOUBLE, _) => Some(Kind::F64),
        _ => None,
    }
}

/// A timestamp-typed time column must be read in its own unit.
fn check_time_unit(m: &Manifest, key: &str, d: &ColumnDescriptor, unit: TimeUnit, shown: &str) -> Result<()> {
    let Some(LogicalType::Timestamp(ts)) = d.logical_type_ref() else { return Ok(()) };
    let (theirs, name) = match ts.unit {
        PqTimeUnit::MILLIS => (TimeUnit::Ms, "ms"),
        PqTimeUnit::MICROS => (TimeUnit::Us, "us"),
        PqTimeUnit::NANOS => (TimeUnit::Ns, "ns"),
    };
    if theirs == unit {
        return Ok(());
    }
    Err(m.error(
        key,
        format!(
            "column '{}' of {shown} is a timestamp in {name}: set time_unit = \"{name}\" for this stream",
            echo(d.name())
        ),
    ))
}

/// A column's type as a message names it: `double`, `int16`, `uint32`,
/// `timestamp[ns]`, `string`, …
fn describe(d: &ColumnDescriptor) -> String {
    if d.max_rep_level() > 0 {
        return "a list".into();
    }
    if d.path().parts().len() != 1 {
        return "a struct".into();
    }
    let unit = |u: &PqTimeUnit| match u {
        PqTimeUnit::MILLIS => "ms",
        PqTimeUnit::MICROS => "us",
        PqTimeUnit::NANOS => "ns",
    };
    match (d.physical_type(), d.logical_type_ref()) {
        (_, Some(LogicalType::Integer(i))) => format!("{}int{}", if i.is_signed { "" } else { "u" }, i.bit_width),
        (_, Some(LogicalType::Timestamp(t))) => format!("timestamp[{}]", unit(&t.unit)),
        (_, Some(LogicalType::Time(t))) => format!("time of day[{}]", unit(&t.unit)),
        (_, Some(LogicalType::Date)) => "a date".into(),
        (_, Some(LogicalType::Decimal(x))) => format!("decimal({}, {})", x.precision, x.scale),
        (_, Some(LogicalType::String | LogicalType::Enum | LogicalType::Json)) => "string".into(),
        (_, Some(LogicalType::Float16)) => "float16".into(),
        (Physical::BOOLEAN, _) => "boolean".into(),
        (Physical::INT32, _) => "int32".into(),
        (Physical::INT64, _) => "int64".into(),
        (Physical::INT96, _) => "INT96 (a legacy timestamp)".into(),
        (Physical::FLOAT, _) => "float".into(),
        (Physical::DOUBLE, _) => "double".into(),
        (Physical::BYTE_ARRAY, _) => "binary".into(),
        (Physical::FIXED_LEN_BYTE_ARRAY, _) => "fixed-size binary".into(),
    }
}

/// The file's top-level columns for a message: at most 30, each with its
/// type (a list or struct once, by its first leaf).
fn list_columns(leaves: &[std::sync::Arc<ColumnDescriptor>]) -> String {
    let mut seen: Vec<&str> = Vec::new();
    let mut out: Vec<String> = Vec::new();
    for d in leaves {
        let top = d.path().parts().first().map(String::as_str).unwrap_or_default();
        if seen.contains(&top) {
            continue;
        }
        seen.push(top);
        if out.len() < 30 {
            out.push(format!("{} ({})", echo(top), describe(d)));
        }
    }
    if seen.len() > 30 {
        out.push(format!("… ({} columns)", seen.len()));
    }
    out.join(", ")
}
