//! A walk over an MCAP file's record headers that checks every declared
//! length against the bytes that remain, before the MCAP reader allocates a
//! buffer of that length.
//!
//! The walk reads the opcode and length of each top-level record and seeks
//! past its body. For a chunk it also reads the chunk header (its declared
//! uncompressed size, compression and records length); the records of an
//! uncompressed chunk are walked the same way, and a compressed chunk's
//! once its decoder has decompressed them into a buffer of at most its
//! declared uncompressed size (itself capped), before the reader parses
//! them ([`check_chunk_records`]; the walk lists the compressed chunks for
//! the decoder, so each is decompressed once). Schema and channel records
//! have their string lengths checked,
//! so a topic name declaring 4 GiB in a tiny file is named as such. The
//! walk also returns a record length limit for the reader: no record may be
//! longer than the file or than the largest chunk's declared uncompressed
//! size.

use std::io::{BufReader, Cursor, Read, Seek};

use super::decompress::Codec;
use super::MAX_RECORD_BYTES;

const HEADER: u8 = 0x01;
const FOOTER: u8 = 0x02;
const SCHEMA: u8 = 0x03;
const CHANNEL: u8 = 0x04;
const CHUNK: u8 = 0x06;
const MESSAGE_INDEX: u8 = 0x07;
const CHUNK_INDEX: u8 = 0x08;
const ATTACHMENT: u8 = 0x09;
const ATTACHMENT_INDEX: u8 = 0x0A;
const STATISTICS: u8 = 0x0B;
const METADATA: u8 = 0x0C;
const METADATA_INDEX: u8 = 0x0D;
const DATA_END: u8 = 0x0F;

/// The largest uncompressed size a compressed chunk may declare. A chunk is
/// decompressed whole (by this walk, then by the reader), so this bounds the
/// memory a few kilobytes of compressed zeros can demand; writers cut chunks
/// far smaller (rosbag2's default is 768 KiB, the MCAP libraries' 4 MiB or
/// less). Uncompressed chunks are bytes of the file itself and need no cap
/// beyond the file's length.
pub(super) const MAX_COMPRESSED_CHUNK_BYTES: u64 = 64 << 20;

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

/// A compressed chunk the walk found: where it is and what it declares, for
/// the decoder that decompresses it when the reader reaches it
/// (`decompress::ChunkDecoder`).
#[derive(Debug, Clone, PartialEq)]
pub(super) struct CompressedChunk {
    /// The chunk record's file offset.
    pub(super) offset: u64,
    /// Its compression.
    pub(super) codec: Codec,
    /// The uncompressed size it declares (capped).
    pub(super) uncompressed: u64,
}

/// What the walk found: the record length limit for the MCAP reader and the
/// compressed chunks in file order.
#[derive(Debug)]
pub(super) struct Checked {
    pub(super) record_limit: usize,
    pub(super) compressed: Vec<CompressedChunk>,
}

/// Why [`check_lengths`] refused a file.
#[derive(Debug)]
pub(super) enum LengthError {
    /// A record of the file itself declares more bytes than remain in the
    /// file: where a cut file stops. The record and the bytes left, without
    /// the "corrupt or truncated" lead ([`PAST_END_LEAD`]) that its `Display`
    /// puts before it.
    PastEnd(String),
    /// Any other fault: the message naming the record.
    Damaged(String),
}

impl std::fmt::Display for LengthError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            LengthError::PastEnd(what) => write!(f, "{PAST_END_LEAD}{what}"),
            LengthError::Damaged(reason) => f.write_str(reason),
        }
    }
}

/// The lead of a message about a record that runs past the end of what
/// holds it.
const PAST_END_LEAD: &str = "corrupt or truncated MCAP file: ";

/// Reads records from `r` (positioned at file offset `start`, `len` bytes
/// to its end) and checks their lengths; returns the record length limit
/// for the MCAP reader and the compressed chunks, or why not, naming the
/// record at fault.
pub(super) fn check_lengths(r: impl Read + Seek, start: u64, len: u64) -> Result<Checked, LengthError> {
    let mut w = Walk { r: BufReader::new(r), at: start, compressed: Vec::new() };
    let mut limit = len;
    while w.at + 9 <= len {
        let (offset, op, rec_len) = w.header().map_err(LengthError::Damaged)?;
        if let Some(what) = past_end(offset, op, rec_len, len - w.at, "the file") {
            return Err(LengthError::PastEnd(what));
        }
        let body_start = w.at;
        let body = match op {
            CHUNK => w.chunk(rec_len).map(|uncompressed| limit = limit.max(uncompressed)),
            _ => w.strings(op, rec_len),
        };
        body.and_then(|()| w.skip_to(body_start + rec_len)).map_err(LengthError::Damaged)?;
        if op == FOOTER {
            break;
        }
    }
    Ok(Checked {
        record_limit: usize::try_from(limit).unwrap_or(usize::MAX).min(MAX_RECORD_BYTES),
        compressed: w.compressed,
    })
}

/// Checks the records of a compressed chunk once decompressed (`records`;
/// the chunk at file offset `offset`) as the walk checks the records of an
/// uncompressed one, before the MCAP reader parses them.
pub(super) fn check_chunk_records(records: &[u8], offset: u64) -> Result<(), String> {
    let mut inner = Walk { r: BufReader::new(Cursor::new(records)), at: 0, compressed: Vec::new() };
    // The inner walk's offsets count from the start of the decompressed
    // records: say so.
    inner
        .chunk_records(records.len() as u64, "the decompressed records")
        .map_err(|e| format!("{e} (offsets within the decompressed records of the chunk at byte offset {offset})"))
}

/// For a record at `offset` (opcode `op`) declaring `rec_len` bytes where
/// `left` remain in `within`: what runs past the end, if it does.
fn past_end(offset: u64, op: u8, rec_len: u64, left: u64, within: &str) -> Option<String> {
    (rec_len > left).then(|| {
        format!(
            "the {} record (opcode {op:#04x}) at byte offset {offset} declares {rec_len} bytes, but only {left} \
             remain in {within}",
            kind(op)
        )
    })
}

struct Walk<R> {
    r: BufReader<R>,
    /// The file offset of the next byte `r` reads.
    at: u64,
    /// The compressed chunks met so far.
    compressed: Vec<CompressedChunk>,
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
        let (offset, op, rec_len) = self.header()?;
        match past_end(offset, op, rec_len, end - self.at, within) {
            Some(what) => Err(format!("{PAST_END_LEAD}{what}")),
            None => Ok((op, rec_len)),
        }
    }

    /// The record header at the walk's position: its file offset, opcode
    /// and declared length.
    fn header(&mut self) -> Result<(u64, u8, u64), String> {
        let offset = self.at;
        let [op] = self.bytes::<1>()?;
        Ok((offset, op, self.u64()?))
    }

    /// Checks a chunk's header and, when it is uncompressed, its records (a
    /// compressed chunk is noted for its decoder); returns its declared
    /// uncompressed size.
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
        if !name.is_empty() && uncompressed > MAX_COMPRESSED_CHUNK_BYTES {
            return Err(bad(format!(
                "declares {uncompressed} uncompressed bytes for {records_len} compressed bytes, above odocal's limit \
                 of {MAX_COMPRESSED_CHUNK_BYTES} bytes (64 MiB) for a compressed chunk; rewrite the bag with smaller \
                 chunks (rosbag2 writes chunks of 768 KiB)"
            )));
        }
        if !name.is_empty() && records_len > MAX_RECORD_BYTES as u64 {
            return Err(bad(format!(
                "declares {records_len} compressed bytes, above odocal's limit of {MAX_RECORD_BYTES} for one chunk"
            )));
        }
        let within = format!("its chunk (at byte offset {offset})");
        if name.is_empty() {
            if uncompressed != records_len {
                return Err(bad(format!(
                    "is uncompressed but declares {uncompressed} uncompressed bytes for {records_len} bytes of records"
                )));
            }
            let records_end = self.at + records_len;
            self.chunk_records(records_end, &within)?;
        } else {
            let Some(codec) = Codec::of_name(&name) else {
                return Err(bad(format!(
                    "uses the compression '{}', which odocal cannot read (zstd, lz4 or none)",
                    String::from_utf8_lossy(&name)
                )));
            };
            // Its records are checked once decompressed, when the reader
            // reaches it (check_chunk_records).
            self.compressed.push(CompressedChunk { offset, codec, uncompressed });
        }
        Ok(uncompressed)
    }

    /// Walks the records of a chunk up to `records_end`, checking their
    /// lengths and the strings of schema and channel records.
    fn chunk_records(&mut self, records_end: u64, within: &str) -> Result<(), String> {
        while self.at + 9 <= records_end {
            let (op, inner) = self.record_header(records_end, within)?;
            let body_start = self.at;
            self.strings(op, inner)?;
            self.skip_to(body_start + inner)?;
        }
        // A chunk's records fill it: bytes too few for a record header
        // would be read by the MCAP reader as a record reaching past it.
        if self.at < records_end {
            return Err(format!(
                "corrupt MCAP file: {within} ends with {} byte(s) that are not a whole record",
                records_end - self.at
            ));
        }
        Ok(())
    }

    /// Checks the length-prefixed fields (strings, byte arrays, maps) of a
    /// record of `rec_len` bytes against the bytes left in it: the MCAP
    /// parser reserves a string's declared length before reading it.
    fn strings(&mut self, op: u8, rec_len: u64) -> Result<(), String> {
        let Some(fields) = layout(op) else { return Ok(()) };
        let offset = self.at - 9;
        let end = self.at + rec_len;
        for field in fields {
            let (name, prefix) = match *field {
                Field::Skip(n) => {
                    if end - self.at < n {
                        return Err(format!(
                            "corrupt MCAP file: the {} record at byte offset {offset} is too short for its fixed fields",
                            kind(op)
                        ));
                    }
                    self.skip_to(self.at + n)?;
                    continue;
                }
                Field::Len32(name) | Field::StrMap(name) | Field::Entries(name, _) => (name, 4),
                Field::Len64(name) => (name, 8),
            };
            if end - self.at < prefix {
                return Err(format!(
                    "corrupt MCAP file: the {} record at byte offset {offset} ends before its {name}",
                    kind(op)
                ));
            }
            let n = if prefix == 4 { u64::from(self.u32()?) } else { self.u64()? };
            let left = end - self.at;
            if n > left {
                return Err(format!(
                    "corrupt MCAP file: the {} record at byte offset {offset} declares a {name} of {n} bytes, but \
                     only {left} remain in the record",
                    kind(op)
                ));
            }
            if let Field::Entries(_, size) = *field {
                if n % size != 0 {
                    return Err(format!(
                        "corrupt MCAP file: the {} record at byte offset {offset} declares a {name} of {n} bytes, \
                         not a whole number of its {size}-byte entries",
                        kind(op)
                    ));
                }
            }
            if matches!(field, Field::StrMap(_)) {
                self.string_map(op, offset, name, self.at + n)?;
            } else {
                self.skip_to(self.at + n)?;
            }
        }
        Ok(())
    }

    /// Checks the keys and values of a map of strings that ends at `end`:
    /// each string's declared length within what is left of the map.
    fn string_map(&mut self, op: u8, offset: u64, name: &str, end: u64) -> Result<(), String> {
        while self.at < end {
            let left = end - self.at;
            let n = if left >= 4 { u64::from(self.u32()?) } else { u64::MAX };
            if n > left.saturating_sub(4) {
                return Err(format!(
                    "corrupt MCAP file: the {} record at byte offset {offset} has a string in its {name} declaring \
                     {} bytes, but only {} remain in the {name}",
                    kind(op),
                    if n == u64::MAX { "more".to_string() } else { n.to_string() },
                    left.saturating_sub(4)
                ));
            }
            self.skip_to(self.at + n)?;
        }
        Ok(())
    }
}

/// A field of a record, for the length checks: fixed-size fields to skip,
/// or a field whose length comes first (as 4 or 8 bytes).
enum Field {
    Skip(u64),
    Len32(&'static str),
    Len64(&'static str),
    /// A map of strings to strings (4-byte length, then length-prefixed
    /// keys and values).
    StrMap(&'static str),
    /// A map or array of fixed-size entries (4-byte length, then entries of
    /// this many bytes): a length between entries would shift every field
    /// after it.
    Entries(&'static str, u64),
}

/// The fields of the records that hold length-prefixed fields, up to the
/// last of those (MCAP specification, records section); `None` for the
/// others. A chunk's own header is checked by `Walk::chunk`.
fn layout(op: u8) -> Option<&'static [Field]> {
    use Field::{Entries, Len32, Len64, Skip, StrMap};
    Some(match op {
        HEADER => &[Len32("profile"), Len32("library")],
        SCHEMA => &[Skip(2), Len32("name"), Len32("encoding"), Len32("data")],
        CHANNEL => &[Skip(4), Len32("topic name"), Len32("message encoding"), StrMap("metadata")],
        MESSAGE_INDEX => &[Skip(2), Entries("records", 16)],
        CHUNK_INDEX => &[Skip(32), Entries("message index offsets", 10), Skip(8), Len32("compression")],
        ATTACHMENT => &[Skip(16), Len32("name"), Len32("media type"), Len64("data")],
        ATTACHMENT_INDEX => &[Skip(40), Len32("name"), Len32("media type")],
        STATISTICS => &[Skip(42), Entries("channel message counts", 10)],
        METADATA => &[Len32("name"), StrMap("metadata")],
        METADATA_INDEX => &[Skip(16), Len32("name")],
        _ => return None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(op: u8, body: &[u8]) -> Vec<u8> {
        let mut r = vec![op];
        r.extend_from_slice(&(body.len() as u64).to_le_bytes());
        r.extend_from_slice(body);
        r
    }

    fn string(s: &str) -> Vec<u8> {
        let mut b = (s.len() as u32).to_le_bytes().to_vec();
        b.extend_from_slice(s.as_bytes());
        b
    }

    /// A file of a header and one chunk compressed with `compression`
    /// holding one channel record whose topic name declares `topic_len`
    /// bytes (followed by the 13 bytes of a short topic).
    fn file_with_chunk(compression: &str, topic_len: u32) -> Vec<u8> {
        file_with_chunk_declaring(compression, topic_len, None)
    }

    /// As `file_with_chunk`, the chunk declaring `declared` uncompressed
    /// bytes when given (instead of its records' true length).
    fn file_with_chunk_declaring(compression: &str, topic_len: u32, declared: Option<u64>) -> Vec<u8> {
        let mut channel = Vec::new();
        channel.extend_from_slice(&1u16.to_le_bytes());
        channel.extend_from_slice(&0u16.to_le_bytes());
        channel.extend_from_slice(&topic_len.to_le_bytes());
        channel.extend_from_slice(b"/a");
        channel.extend_from_slice(&string("cdr"));
        channel.extend_from_slice(&0u32.to_le_bytes());
        let records = record(CHANNEL, &channel);
        let packed = match compression {
            "zstd" => ruzstd::encoding::compress_to_vec(&records[..], ruzstd::encoding::CompressionLevel::Fastest),
            _ => records.clone(),
        };
        let mut chunk = Vec::new();
        chunk.extend_from_slice(&0u64.to_le_bytes());
        chunk.extend_from_slice(&0u64.to_le_bytes());
        chunk.extend_from_slice(&declared.unwrap_or(records.len() as u64).to_le_bytes());
        chunk.extend_from_slice(&0u32.to_le_bytes());
        chunk.extend_from_slice(&string(compression));
        chunk.extend_from_slice(&(packed.len() as u64).to_le_bytes());
        chunk.extend_from_slice(&packed);
        let mut f = b"\x89MCAP0\r\n".to_vec();
        f.extend(record(0x01, &[string("ros2"), string("test")].concat()));
        f.extend(record(CHUNK, &chunk));
        f.extend(record(DATA_END, &0u32.to_le_bytes()));
        f.extend(record(FOOTER, &[0u8; 20]));
        f.extend_from_slice(b"\x89MCAP0\r\n");
        f
    }

    fn walk(f: &[u8]) -> Result<Checked, String> {
        let mut c = Cursor::new(f);
        c.set_position(8);
        check_lengths(c, 8, f.len() as u64).map_err(|e| e.to_string())
    }

    #[test]
    fn a_topic_length_inside_a_chunk_is_checked_compressed_or_not() {
        // The honest file walks clean, compressed or not; the compressed
        // chunk is listed for its decoder.
        let checked = walk(&file_with_chunk("zstd", 2)).expect("walks");
        let offset = 8 + 9 + 4 + 4 + 4 + 4;
        assert!(walk(&file_with_chunk("", 2)).expect("walks").compressed.is_empty());
        assert_eq!(checked.compressed.len(), 1);
        assert_eq!((checked.compressed[0].offset, checked.compressed[0].codec), (offset, Codec::Zstd));
        // A topic name declaring 4 GiB is refused before the reader sees it:
        // in an uncompressed chunk by the walk, in a compressed one by the
        // check its decoder runs on the decompressed records.
        let e = walk(&file_with_chunk("", u32::MAX - 15)).expect_err("a 4 GiB topic name");
        assert!(e.contains("topic name"), "{e}");
        let f = file_with_chunk("zstd", u32::MAX - 15);
        let c = &walk(&f).expect("the header is sound").compressed[0];
        let mut d = super::super::decompress::ChunkDecoder::new(Codec::Zstd, std::slice::from_ref(c));
        // The chunk's records follow its opcode and length (9 bytes), times,
        // size and CRC (28), the compression "zstd" (8) and the records' length.
        let records_len_at = c.offset as usize + 9 + 28 + 8;
        let records_len = u64::from_le_bytes(f[records_len_at..records_len_at + 8].try_into().expect("8 bytes"));
        let start = records_len_at + 8;
        let e = mcap::sans_io::decompressor::Decompressor::decompress(
            &mut d,
            &f[start..start + records_len as usize],
            &mut [0u8; 64],
        )
        .expect_err("a 4 GiB topic name");
        assert!(
            e.to_string().contains("decompressed records of the chunk at byte offset")
                && e.to_string().contains("topic name"),
            "{e}"
        );
    }

    #[test]
    fn a_compressed_chunk_may_not_declare_more_than_64_mib() {
        // Right at the cap the declared size is accepted by the header check
        // (the decoder then finds fewer bytes than declared, which is fine).
        assert!(walk(&file_with_chunk_declaring("zstd", 2, Some(MAX_COMPRESSED_CHUNK_BYTES))).is_ok());
        let e = walk(&file_with_chunk_declaring("zstd", 2, Some(MAX_COMPRESSED_CHUNK_BYTES + 1)))
            .expect_err("a chunk above the cap");
        assert!(e.contains("chunk at byte offset") && e.contains("64 MiB") && e.contains("smaller chunks"), "{e}");
        // An uncompressed chunk is bounded by the file itself, not by this cap.
        let e = walk(&file_with_chunk_declaring("", 2, Some(MAX_COMPRESSED_CHUNK_BYTES + 1))).expect_err("mismatch");
        assert!(e.contains("is uncompressed but declares"), "{e}");
    }

    #[test]
    fn an_unknown_compression_is_named() {
        let e = walk(&file_with_chunk("brotli", 2)).expect_err("unknown compression");
        assert!(e.contains("'brotli'"), "{e}");
    }
}
