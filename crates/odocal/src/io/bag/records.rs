//! A walk over an MCAP file's record headers that checks every declared
//! length against the bytes that remain, before the MCAP reader allocates a
//! buffer of that length.
//!
//! The walk reads the opcode and length of each top-level record and seeks
//! past its body. For a chunk it also reads the chunk header (its declared
//! uncompressed size, compression and records length); the records of an
//! uncompressed chunk are walked the same way. Schema and channel records
//! outside compressed chunks have their string lengths checked, so a topic
//! name declaring 4 GiB in a tiny file is named as such. What the walk
//! cannot see (the records inside a compressed chunk) is bounded by the
//! record length limit it returns: no record may be longer than the file or
//! than the largest chunk's declared uncompressed size.

use std::io::{BufReader, Read, Seek};

use super::MAX_RECORD_BYTES;

const CHUNK: u8 = 0x06;
const SCHEMA: u8 = 0x03;
const CHANNEL: u8 = 0x04;
const FOOTER: u8 = 0x02;
const DATA_END: u8 = 0x0F;

/// The record kind of an opcode, for messages.
fn kind(op: u8) -> &'static str {
    match op {
        0x01 => "header",
        FOOTER => "footer",
        SCHEMA => "schema",
        CHANNEL => "channel",
        0x05 => "message",
        CHUNK => "chunk",
        0x07 => "message index",
        0x08 => "chunk index",
        0x09 => "attachment",
        0x0A => "attachment index",
        0x0B => "statistics",
        0x0C => "metadata",
        0x0D => "metadata index",
        0x0E => "summary offset",
        DATA_END => "data end",
        _ => "unknown",
    }
}

/// Reads records from `r` (positioned at file offset `start`, `len` bytes
/// to its end) and checks their lengths; returns the record length limit
/// for the MCAP reader, or a message naming the record at fault.
pub(super) fn check_lengths(r: impl Read + Seek, start: u64, len: u64) -> Result<usize, String> {
    let mut w = Walk { r: BufReader::new(r), at: start };
    let mut limit = len;
    while w.at + 9 <= len {
        let (op, rec_len) = w.record_header(len, "the file")?;
        let body_start = w.at;
        match op {
            CHUNK => limit = limit.max(w.chunk(rec_len)?),
            SCHEMA | CHANNEL => w.strings(op, rec_len)?,
            _ => {}
        }
        w.skip_to(body_start + rec_len)?;
        if op == FOOTER {
            break;
        }
    }
    Ok(usize::try_from(limit).unwrap_or(usize::MAX).min(MAX_RECORD_BYTES))
}

struct Walk<R> {
    r: BufReader<R>,
    /// The file offset of the next byte `r` reads.
    at: u64,
}

impl<R: Read + Seek> Walk<R> {
    fn io(&self, e: std::io::Error) -> String {
        format!("reading the MCAP file at byte offset {} failed: {e}", self.at)
    }

    fn bytes<const N: usize>(&mut self) -> Result<[u8; N], String> {
        let mut b = [0u8; N];
        self.r.read_exact(&mut b).map_err(|e| self.io(e))?;
        self.at += N as u64;
        Ok(b)
    }

    fn u64(&mut self) -> Result<u64, String> {
        Ok(u64::from_le_bytes(self.bytes()?))
    }

    fn u32(&mut self) -> Result<u32, String> {
        Ok(u32::from_le_bytes(self.bytes()?))
    }

    fn skip_to(&mut self, to: u64) -> Result<(), String> {
        let by =
            i64::try_from(to - self.at).map_err(|_| format!("a record length at byte offset {} overflows", self.at))?;
        self.r.seek_relative(by).map_err(|e| self.io(e))?;
        self.at = to;
        Ok(())
    }

    /// A record's opcode and length, the length checked against the `end`
    /// of what holds it (`within`: "the file" or "its chunk").
    fn record_header(&mut self, end: u64, within: &str) -> Result<(u8, u64), String> {
        let offset = self.at;
        let [op] = self.bytes::<1>()?;
        let rec_len = self.u64()?;
        let left = end - self.at;
        if rec_len > left {
            return Err(format!(
                "corrupt or truncated MCAP file: the {} record (opcode {op:#04x}) at byte offset {offset} declares \
                 {rec_len} bytes, but only {left} remain in {within}",
                kind(op)
            ));
        }
        Ok((op, rec_len))
    }

    /// Checks a chunk's header and, when it is uncompressed, its records;
    /// returns its declared uncompressed size.
    fn chunk(&mut self, rec_len: u64) -> Result<u64, String> {
        let offset = self.at - 9;
        let end = self.at + rec_len;
        let bad = |what: String| format!("corrupt MCAP file: the chunk at byte offset {offset} {what}");
        if rec_len < 8 + 8 + 8 + 4 + 4 + 8 {
            return Err(bad(format!("is {rec_len} bytes, shorter than a chunk header")));
        }
        let _start_time = self.u64()?;
        let _end_time = self.u64()?;
        let uncompressed = self.u64()?;
        let _crc = self.u32()?;
        let name_len = u64::from(self.u32()?);
        if name_len + 8 > end - self.at {
            return Err(bad(format!("declares a compression name of {name_len} bytes, more than the chunk holds")));
        }
        let mut name = vec![0u8; name_len as usize];
        self.r.read_exact(&mut name).map_err(|e| self.io(e))?;
        self.at += name_len;
        let records_len = self.u64()?;
        let left = end - self.at;
        if records_len > left {
            return Err(bad(format!("declares {records_len} bytes of records, but only {left} remain in it")));
        }
        if uncompressed > MAX_RECORD_BYTES as u64 {
            return Err(bad(format!(
                "declares {uncompressed} uncompressed bytes, above odocal's limit of {MAX_RECORD_BYTES} for one chunk"
            )));
        }
        if name.is_empty() {
            if uncompressed != records_len {
                return Err(bad(format!(
                    "is uncompressed but declares {uncompressed} uncompressed bytes for {records_len} bytes of records"
                )));
            }
            let records_end = self.at + records_len;
            while self.at + 9 <= records_end {
                let (op, inner) = self.record_header(records_end, &format!("its chunk (at byte offset {offset})"))?;
                let body_start = self.at;
                if matches!(op, SCHEMA | CHANNEL) {
                    self.strings(op, inner)?;
                }
                self.skip_to(body_start + inner)?;
            }
        }
        Ok(uncompressed)
    }

    /// Checks the string (and schema data) lengths of a schema or channel
    /// record of `rec_len` bytes against the bytes left in it.
    fn strings(&mut self, op: u8, rec_len: u64) -> Result<(), String> {
        let offset = self.at - 9;
        let end = self.at + rec_len;
        let fields: &[&str] = if op == SCHEMA {
            self.skip_ids(2, end, offset)?;
            &["name", "encoding", "data"]
        } else {
            self.skip_ids(4, end, offset)?;
            &["topic name", "message encoding", "metadata"]
        };
        for field in fields {
            if end - self.at < 4 {
                return Err(format!(
                    "corrupt MCAP file: the {} record at byte offset {offset} ends before its {field}",
                    kind(op)
                ));
            }
            let n = u64::from(self.u32()?);
            let left = end - self.at;
            if n > left {
                return Err(format!(
                    "corrupt MCAP file: the {} record at byte offset {offset} declares a {field} of {n} bytes, but \
                     only {left} remain in the record",
                    kind(op)
                ));
            }
            self.skip_to(self.at + n)?;
        }
        Ok(())
    }

    fn skip_ids(&mut self, n: u64, end: u64, offset: u64) -> Result<(), String> {
        if end - self.at < n {
            return Err(format!("corrupt MCAP file: the record at byte offset {offset} is too short for its ids"));
        }
        self.skip_to(self.at + n)
    }
}
