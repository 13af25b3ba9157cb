//! The file line of each CSV record, for any line ending.
//!
//! The `csv` crate's positions count `\n` bytes read before a record. A
//! CRLF file's record begins before the `\n` of the line ending in front of
//! it, so that count names the line before the record's, and a file of
//! lone CRs is all "line 1". [`LineCounted`] sits under the CSV reader,
//! notes where each line that is not empty starts as the bytes go by, and
//! gives the line of a record from the record's byte offset: the first
//! such line at or after it (the parser skips empty lines).

use std::collections::VecDeque;
use std::io::Read;

/// The longest line a CSV table may hold, in bytes: far beyond any drive
/// row (a few hundred bytes), short enough that a file that is no CSV (one
/// long line, binary data) is refused before the reader's record buffer
/// grows with it (memory in proportion to the longest line).
pub(crate) const MAX_LINE_BYTES: u64 = 1 << 20;

/// Why a table's bytes are no CSV text, and on which line: a line longer
/// than [`MAX_LINE_BYTES`], or a NUL byte after the header line (one in
/// the header is named by the header's check, with its column). Carried through the CSV reader
/// as an I/O error ([`not_text`] finds it).
#[derive(Debug)]
pub(crate) struct NotText {
    /// The file line.
    pub(crate) line: u64,
    /// What is wrong, in words.
    pub(crate) reason: String,
}

impl std::fmt::Display for NotText {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "line {}: {}", self.line, self.reason)
    }
}

impl std::error::Error for NotText {}

/// The [`NotText`] a CSV reader's error carries, if any.
pub(crate) fn not_text(e: &::csv::Error) -> Option<&NotText> {
    match e.kind() {
        ::csv::ErrorKind::Io(io) => io.get_ref()?.downcast_ref::<NotText>(),
        _ => None,
    }
}

/// A reader that notes the byte offset and the number of every line that
/// is not empty. Lines end at `\n`, `\r\n` or a lone `\r`, as for the CSV
/// parser.
#[derive(Debug)]
pub(crate) struct LineCounted<R> {
    inner: R,
    /// Bytes read so far.
    offset: u64,
    /// The number of the line the next byte is on.
    line: u64,
    /// The next byte starts a line.
    at_start: bool,
    /// The last byte read was a `\r`.
    after_cr: bool,
    /// (offset, line) of the starts of lines that are not empty, from the
    /// last record asked about on.
    starts: VecDeque<(u64, u64)>,
    /// Bytes of the current line read so far.
    line_len: u64,
}

impl<R> LineCounted<R> {
    /// Wraps `inner`, whose first byte is at offset 0 on line 1.
    pub(crate) fn new(inner: R) -> LineCounted<R> {
        LineCounted::starting_at(inner, 1)
    }

    /// Wraps `inner`, whose first byte is at offset 0 and starts line
    /// `line` of the file (a part of a file cut after a line ending).
    pub(crate) fn starting_at(inner: R, line: u64) -> LineCounted<R> {
        LineCounted { inner, offset: 0, line, at_start: true, after_cr: false, starts: VecDeque::new(), line_len: 0 }
    }

    /// The line of the record that starts at byte `offset` (a `csv`
    /// position's [`byte`](::csv::Position::byte)). Records are asked
    /// about in file order: the lines before `offset` are forgotten.
    pub(crate) fn line_at(&mut self, offset: u64) -> u64 {
        while self.starts.front().is_some_and(|&(at, _)| at < offset) {
            self.starts.pop_front();
        }
        self.starts.front().map_or(self.line, |&(_, line)| line)
    }

    /// The line of a `csv` position (the last line read when there is none).
    pub(crate) fn line_of(&mut self, pos: Option<&::csv::Position>) -> u64 {
        match pos {
            Some(p) => self.line_at(p.byte()),
            None => self.line,
        }
    }

    /// The reader underneath.
    pub(crate) fn get_ref(&self) -> &R {
        &self.inner
    }

    /// The reader underneath, taken back.
    pub(crate) fn into_inner(self) -> R {
        self.inner
    }

    /// Notes the line starts in `bytes`; a line longer than
    /// [`MAX_LINE_BYTES`] or a NUL byte after the header line is an error
    /// ([`NotText`]).
    fn note(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        let mut i = 0;
        while let Some(&b) = bytes.get(i) {
            match b {
                b'\n' if self.after_cr => {}
                b'\n' | b'\r' => {
                    self.line += 1;
                    self.at_start = true;
                    self.line_len = 0;
                }
                // The header's own check names a NUL in a column's name.
                0 if self.line > 1 => {
                    return Err(self.not_text("a NUL byte: binary data, not CSV text; is this a CSV file?".into()))
                }
                _ => {
                    if self.at_start {
                        self.starts.push_back((self.offset + i as u64, self.line));
                        self.at_start = false;
                    }
                    // The rest of the line holds no line ending: skip to the
                    // next one (a file's bytes are almost all such).
                    let rest = &bytes[i + 1..];
                    let run = memchr::memchr3(b'\n', b'\r', 0, rest).unwrap_or(rest.len());
                    self.line_len += 1 + run as u64;
                    if self.line_len > MAX_LINE_BYTES {
                        return Err(self.not_text(format!(
                            "the line is longer than {} MiB ({MAX_LINE_BYTES} bytes), the limit of a CSV line; \
                             is this a CSV file?",
                            MAX_LINE_BYTES >> 20
                        )));
                    }
                    i += 1 + run;
                    self.after_cr = false;
                    continue;
                }
            }
            self.after_cr = b == b'\r';
            i += 1;
        }
        self.offset += bytes.len() as u64;
        Ok(())
    }

    fn not_text(&self, reason: String) -> std::io::Error {
        std::io::Error::new(std::io::ErrorKind::InvalidData, NotText { line: self.line, reason })
    }
}

impl<R: Read> Read for LineCounted<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.note(&buf[..n])?;
        Ok(n)
    }
}

/// The CSV reader every table of the crate is read with: a header row,
/// fields trimmed, over [`LineCounted`] so that errors name the file line.
pub(crate) fn reader<R: Read>(inner: R) -> ::csv::Reader<LineCounted<R>> {
    ::csv::ReaderBuilder::new().has_headers(true).trim(::csv::Trim::All).from_reader(LineCounted::new(inner))
}

/// The line ends in `bytes` as [`LineCounted`] counts them: `\n`, `\r\n`
/// and a lone `\r` each end one line (the line `bytes` ends on, when it
/// follows them, is this count + 1).
pub(crate) fn count_line_ends(bytes: &[u8]) -> u64 {
    let lf = memchr::memchr_iter(b'\n', bytes).count();
    let cr = memchr::memchr_iter(b'\r', bytes).count();
    let crlf = memchr::memmem::find_iter(bytes, b"\r\n").count();
    (lf + cr - crlf) as u64
}

/// A CSV reader's error in words, without the reader's own position
/// (the caller names the line, from [`LineCounted`]).
pub(crate) fn reason(e: &::csv::Error) -> String {
    match e.kind() {
        ::csv::ErrorKind::Utf8 { .. } => "invalid UTF-8 (the file must be UTF-8 text)".to_string(),
        ::csv::ErrorKind::UnequalLengths { expected_len, len, .. } => {
            format!("{len} fields, the header has {expected_len}")
        }
        _ => e.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The line of every record of `text` (one field per record, its text
    /// the line number expected), read in chunks of `chunk` bytes.
    fn lines(text: &str, chunk: usize) -> Vec<(u64, String)> {
        struct Chunked<'a>(&'a [u8], usize);
        impl Read for Chunked<'_> {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                let n = self.0.len().min(self.1).min(buf.len());
                buf[..n].copy_from_slice(&self.0[..n]);
                self.0 = &self.0[n..];
                Ok(n)
            }
        }
        let mut rdr = reader(Chunked(text.as_bytes(), chunk));
        let mut out = Vec::new();
        let mut record = ::csv::StringRecord::new();
        while rdr.read_record(&mut record).expect("valid CSV") {
            let line = rdr.get_mut().line_of(record.position());
            out.push((line, record[0].to_string()));
        }
        out
    }

    fn check(text: &str) {
        for chunk in [1, 2, 3, 1000] {
            for (line, want) in lines(text, chunk) {
                assert_eq!(line.to_string(), want, "chunk {chunk}, text {text:?}");
            }
        }
    }

    #[test]
    fn every_line_ending_gives_the_line_of_the_record() {
        let lf = "h\n2\n3\n\n5\n\n\n8\n9";
        check(lf);
        check(&lf.replace('\n', "\r\n"));
        check(&lf.replace('\n', "\r"));
        check("h\r\n2\n3\r4\r\n\r\n6\n");
    }

    #[test]
    fn a_quoted_field_over_lines_counts_its_lines() {
        check("h,x\n2,\"a\nb\"\n4,y\r\n5,\"c\r\n\r\nd\"\r\n8,z\r\n");
    }
}
