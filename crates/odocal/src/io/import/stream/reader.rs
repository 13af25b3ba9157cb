//! A manifest's CSV stream files read row by row into a [`RawStream`], the
//! stream furthest behind first, so that every stream is read about as far
//! as the others and the rows held stay few.

use std::io::BufRead;
use std::path::PathBuf;

use super::{RawStream, StreamOptions};
use crate::drive::csv_lines::LineCounted;
use crate::drive::StreamChunk;
use crate::error::{Error, Result};
use crate::io::import::limits::echo;
use crate::io::import::manifest::{Manifest, SourceSpec};

/// One CSV stream file being read.
struct CsvRows {
    name: String,
    path: PathBuf,
    reader: ::csv::Reader<LineCounted<std::io::BufReader<std::fs::File>>>,
    headers: Vec<String>,
    /// Field index of the time, then of each column.
    idx: Vec<usize>,
    record: ::csv::StringRecord,
    line: u64,
    /// Time of the last row read, in the stream's unit after scale and offset.
    last_t: f64,
    scale: f64,
    offset: f64,
    ended: bool,
}

impl CsvRows {
    /// Opens stream `name`'s file and finds its columns (`cols`, in order).
    fn open(m: &Manifest, name: &str, cols: &[String]) -> Result<CsvRows> {
        let spec = &m.streams[name];
        let SourceSpec::Csv { file } = &spec.source else {
            return Err(m.error(&format!("streams.{name}.format"), "only CSV streams are read as a stream"));
        };
        let path = m.base_dir().join(file);
        let key = format!("streams.{name}.file");
        let cannot_read = |e: &dyn std::fmt::Display| m.error(&key, format!("cannot read {}: {e}", path.display()));
        let file = std::fs::File::open(&path).map_err(|e| cannot_read(&e))?;
        let mut buffered = std::io::BufReader::with_capacity(1 << 16, file);
        let head = buffered.fill_buf().map_err(|e| cannot_read(&e))?;
        if head.starts_with(b"\xEF\xBB\xBF") {
            buffered.consume(3);
        }
        let mut reader = crate::drive::csv_lines::reader(buffered);
        let headers: Vec<String> = match reader.headers() {
            Ok(h) => h.iter().map(str::to_string).collect(),
            Err(e) => return Err(csv_error(&path, e, reader.get_mut())),
        };
        crate::drive::csv::header_characters(&headers, &path)?;
        let time = spec.time_column.as_deref().unwrap_or_default();
        let mut idx = Vec::new();
        let wanted = std::iter::once((time.to_string(), format!("streams.{name}.time_column")))
            .chain(cols.iter().map(|c| (c.clone(), format!("streams.{name}"))));
        for (col, key) in wanted {
            idx.push(crate::io::import::source::header_column(&headers, &col, &path).map_err(|e| m.error(&key, e))?);
        }
        Ok(CsvRows {
            name: name.to_string(),
            path,
            reader,
            headers,
            idx,
            record: ::csv::StringRecord::new(),
            line: 1,
            last_t: f64::NEG_INFINITY,
            scale: spec.time_unit.seconds(),
            offset: spec.time_offset_s,
            ended: false,
        })
    }

    /// The next row: time (in the stream's unit), values and line; `None`
    /// at the end of the file.
    fn next(&mut self) -> Result<Option<(f64, Vec<f64>, u64)>> {
        let read = self.reader.read_record(&mut self.record);
        if !read.map_err(|e| csv_error(&self.path, e, self.reader.get_mut()))? {
            self.ended = true;
            return Ok(None);
        }
        self.line = self.reader.get_mut().line_of(self.record.position());
        let mut v = Vec::with_capacity(self.idx.len());
        for &j in &self.idx {
            let field = self.record.get(j).unwrap_or("");
            v.push(field.parse::<f64>().map_err(|_| Error::Csv {
                path: self.path.clone(),
                line: self.line,
                column: Some(self.headers[j].clone()),
                reason: format!("'{}' is not a number", echo(field)),
            })?);
        }
        let t = v.remove(0);
        let converted = t * self.scale + self.offset;
        if converted.is_finite() {
            self.last_t = converted;
        }
        Ok(Some((t, v, self.line)))
    }
}

/// A CSV reader's error; `lines` gives the line of the record it is about.
fn csv_error<R>(path: &std::path::Path, e: ::csv::Error, lines: &mut LineCounted<R>) -> Error {
    match e.kind() {
        ::csv::ErrorKind::Io(io) => Error::io(path, std::io::Error::new(io.kind(), io.to_string())),
        _ => Error::Csv {
            path: path.to_path_buf(),
            line: lines.line_of(e.position()),
            column: None,
            reason: crate::drive::csv_lines::reason(&e),
        },
    }
}

/// A manifest's CSV streams imported as they are read ([`RawStream`] over
/// the files): canonical samples chunk by chunk, in memory that does not
/// grow with the drive.
pub(crate) struct ManifestStream {
    raw: RawStream,
    files: Vec<CsvRows>,
    finished: bool,
}

impl std::fmt::Debug for ManifestStream {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ManifestStream").field("raw", &self.raw).finish_non_exhaustive()
    }
}

impl ManifestStream {
    /// Opens the stream files of `manifest`.
    ///
    /// # Errors
    /// [`RawStream::new`]'s; a file that cannot be opened or lacks a column.
    pub(crate) fn open(manifest: &Manifest, opts: StreamOptions) -> Result<ManifestStream> {
        let raw = RawStream::with_options(manifest, opts)?;
        let mut files = Vec::new();
        for (name, _, cols) in raw.columns() {
            files.push(CsvRows::open(manifest, name, cols)?);
        }
        Ok(ManifestStream { raw, files, finished: false })
    }

    /// The next chunk of up to `max` samples of one part, reading the files
    /// as far as needed; `None` after the last. Within a part, the chunks
    /// are of `max` samples from the part's start (the last one shorter).
    ///
    /// # Errors
    /// The whole import's errors about the rows and the drive.
    pub(crate) fn next_chunk(&mut self, max: usize) -> Result<Option<StreamChunk>> {
        let max = max.max(1);
        loop {
            let (n, closed) = self.raw.front_part();
            if n >= max || (n > 0 && (closed || self.finished)) {
                return Ok(self.raw.take_chunk(max));
            }
            if self.finished {
                return Ok(None);
            }
            self.read_some()?;
        }
    }

    /// Reads rows of the stream furthest behind (a batch), or finishes
    /// when every file has ended.
    fn read_some(&mut self) -> Result<()> {
        let Some(i) = (0..self.files.len())
            .filter(|&i| !self.files[i].ended)
            .min_by(|&a, &b| self.files[a].last_t.total_cmp(&self.files[b].last_t))
        else {
            self.raw.finish()?;
            self.finished = true;
            return Ok(());
        };
        let f = &mut self.files[i];
        for _ in 0..256 {
            match f.next()? {
                Some((t, v, line)) => self.raw.push_row(&f.name, t, v, Some(line))?,
                None => {
                    self.raw.end_stream(&f.name)?;
                    break;
                }
            }
        }
        Ok(())
    }

    /// The streamed import underneath.
    pub(crate) fn raw(&self) -> &RawStream {
        &self.raw
    }
}
