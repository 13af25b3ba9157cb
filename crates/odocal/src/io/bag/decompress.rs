//! Decompression of MCAP chunks for the MCAP reader, each chunk once.
//!
//! [`ChunkDecoder`] stands in for the reader's own decompressors: it asks
//! for a chunk's whole compressed records, decompresses them into a buffer
//! of at most the size the chunk declares, checks the records' lengths
//! (`records::check_chunk_records`) and only then hands them to the reader.
//! zstd, the compression ROS 2 writes, is decoded by `ruzstd`, in Rust: the
//! reference C library's build was the longest of the library's
//! dependencies (about 40 s of CPU on the 2-core machine); it decodes about
//! 4 × faster, which is why each chunk is decompressed only once. lz4 is
//! decoded by `lz4_flex`, in Rust too (the C library's build: about 10 s
//! of CPU).
//! Chunks are small (rosbag2 writes 768 KiB), so holding one whole costs no
//! more memory than the length checks allow.

use std::collections::VecDeque;
use std::io::Read;

use mcap::sans_io::decompressor::{DecompressResult, Decompressor};
use mcap::McapError;
use ruzstd::decoding::errors::{FrameDecoderError, ReadFrameHeaderError};
use ruzstd::decoding::{BlockDecodingStrategy, FrameDecoder};

use super::records::{check_chunk_records, CompressedChunk, MAX_COMPRESSED_CHUNK_BYTES};

/// A chunk compression odocal reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Codec {
    Zstd,
    Lz4,
}

impl Codec {
    /// Every codec, each with its own decoder on the MCAP reader.
    pub(super) const ALL: [Codec; 2] = [Codec::Zstd, Codec::Lz4];

    /// The codec of a chunk's `compression` field, if odocal reads it.
    pub(super) fn of_name(name: &[u8]) -> Option<Codec> {
        Codec::ALL.into_iter().find(|c| c.name().as_bytes() == name)
    }

    /// The chunk `compression` string.
    pub(super) fn name(self) -> &'static str {
        match self {
            Codec::Zstd => "zstd",
            Codec::Lz4 => "lz4",
        }
    }

    /// Decompresses `input` into at most `limit` bytes.
    fn decode(self, input: &[u8], limit: usize) -> Result<Vec<u8>, DecodeError> {
        match self {
            Codec::Zstd => decode_zstd(input, limit),
            Codec::Lz4 => decode_lz4(input, limit),
        }
    }
}

/// Why a chunk could not be decompressed ([`decode_zstd`], [`decode_lz4`]).
#[derive(Debug)]
pub(super) enum DecodeError {
    /// The frames hold more than the limit.
    TooLarge,
    /// A corrupt or cut frame, or a content checksum that does not match.
    Corrupt(String),
}

impl std::fmt::Display for DecodeError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            DecodeError::TooLarge => write!(f, "decompresses to more bytes than the chunk may hold"),
            DecodeError::Corrupt(reason) => write!(f, "{reason}"),
        }
    }
}

/// Decompresses the zstd frames of `input` (skippable frames skipped) into
/// at most `limit` bytes; more is an error, as is a corrupt or cut frame
/// or a content checksum that does not match.
pub(super) fn decode_zstd(mut input: &[u8], limit: usize) -> Result<Vec<u8>, DecodeError> {
    let corrupt = |e: FrameDecoderError| DecodeError::Corrupt(e.to_string());
    let mut frame = FrameDecoder::new();
    // The caller's limit is the chunk's declared size; reserve no more than
    // the walk lets a compressed chunk declare.
    let mut out = Vec::with_capacity(limit.min(MAX_COMPRESSED_CHUNK_BYTES as usize));
    while !input.is_empty() {
        match frame.init(&mut input) {
            Ok(()) => {}
            Err(FrameDecoderError::ReadFrameHeaderError(ReadFrameHeaderError::SkipFrame { length, .. })) => {
                input = input.get(length as usize..).ok_or_else(|| {
                    DecodeError::Corrupt(format!("a skippable frame declares {length} bytes, more than remain"))
                })?;
                continue;
            }
            Err(e) => return Err(corrupt(e)),
        }
        loop {
            frame.decode_blocks(&mut input, BlockDecodingStrategy::UptoBytes(1 << 20)).map_err(corrupt)?;
            let ready = frame.can_collect();
            if out.len() + ready > limit {
                return Err(DecodeError::TooLarge);
            }
            frame.collect_to_writer(&mut out).map_err(|e| DecodeError::Corrupt(e.to_string()))?;
            if frame.is_finished() {
                break;
            }
        }
        if let (Some(stored), Some(computed)) = (frame.get_checksum_from_data(), frame.get_calculated_checksum()) {
            if stored != computed {
                return Err(DecodeError::Corrupt(format!(
                    "content checksum {stored:#010x} does not match the data's {computed:#010x}"
                )));
            }
        }
    }
    Ok(out)
}

/// Decompresses the lz4 frames of `input` (one or more, concatenated) into
/// at most `limit` bytes.
pub(super) fn decode_lz4(input: &[u8], limit: usize) -> Result<Vec<u8>, DecodeError> {
    let mut out = Vec::new();
    let mut frames = lz4_flex::frame::FrameDecoder::new(input);
    // Each round decodes one frame: the decoder reports the end of the
    // input at each frame's end. A round consumes input or fails (a frame
    // starts with a 4-byte magic number), so the loop ends.
    while !frames.get_ref().is_empty() {
        let room = (limit - out.len()) as u64 + 1;
        (&mut frames).take(room).read_to_end(&mut out).map_err(|e| DecodeError::Corrupt(e.to_string()))?;
        if out.len() > limit {
            return Err(DecodeError::TooLarge);
        }
    }
    Ok(out)
}

/// The MCAP reader's decompressor for the chunks of one compression. It
/// asks the reader for a chunk's whole compressed records (a read hint of
/// `usize::MAX`, which the reader caps at the bytes left in the chunk and
/// at its record length limit, itself at least the largest chunk),
/// decompresses and checks them, and hands them out as the reader asks.
pub(super) struct ChunkDecoder {
    codec: Codec,
    /// The chunks of this compression the length check found, in file
    /// order: the reader decompresses them in that order.
    chunks: VecDeque<CompressedChunk>,
    /// The chunk being handed out, once its compressed bytes were passed in.
    decoded: Option<Vec<u8>>,
    /// How many bytes of `decoded` were handed out.
    given: usize,
}

impl ChunkDecoder {
    /// The decoder of the chunks compressed with `codec` among `chunks`.
    pub(super) fn new(codec: Codec, chunks: &[CompressedChunk]) -> ChunkDecoder {
        let chunks = chunks.iter().filter(|c| c.codec == codec).cloned().collect();
        ChunkDecoder { codec, chunks, decoded: None, given: 0 }
    }

    /// Decompresses the next chunk's compressed records `src` and checks
    /// them; the message names the chunk.
    fn decode_next(&mut self, src: &[u8]) -> Result<Vec<u8>, String> {
        let Some(chunk) = self.chunks.pop_front() else {
            return Err(format!("corrupt MCAP file: a {} chunk that the length check did not find", self.codec.name()));
        };
        let (offset, declared) = (chunk.offset, chunk.uncompressed);
        let limit = usize::try_from(declared).unwrap_or(usize::MAX);
        let out = self.codec.decode(src, limit).map_err(|e| match e {
            DecodeError::TooLarge => format!(
                "corrupt MCAP file: the chunk at byte offset {offset} decompresses to more than the {declared} bytes \
                 it declares"
            ),
            DecodeError::Corrupt(reason) => {
                format!("corrupt MCAP file: the chunk at byte offset {offset} could not be decompressed: {reason}")
            }
        })?;
        if (out.len() as u64) < declared {
            return Err(format!(
                "corrupt MCAP file: the chunk at byte offset {offset} decompresses to {} bytes, fewer than the \
                 {declared} it declares",
                out.len()
            ));
        }
        check_chunk_records(&out, offset)?;
        Ok(out)
    }
}

impl Decompressor for ChunkDecoder {
    fn next_read_size(&self) -> usize {
        if self.decoded.is_some() {
            0
        } else {
            usize::MAX
        }
    }

    fn decompress(&mut self, src: &[u8], dst: &mut [u8]) -> mcap::McapResult<DecompressResult> {
        let consumed = match self.decoded {
            Some(_) => 0,
            None => {
                self.decoded = Some(self.decode_next(src).map_err(McapError::DecompressionError)?);
                src.len()
            }
        };
        let decoded = self.decoded.as_deref().unwrap_or_default();
        let left = &decoded[self.given.min(decoded.len())..];
        let wrote = left.len().min(dst.len());
        dst[..wrote].copy_from_slice(&left[..wrote]);
        self.given += wrote;
        Ok(DecompressResult { consumed, wrote })
    }

    fn reset(&mut self) -> mcap::McapResult<()> {
        self.decoded = None;
        self.given = 0;
        Ok(())
    }

    fn name(&self) -> &'static str {
        self.codec.name()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn compressed(data: &[u8]) -> Vec<u8> {
        ruzstd::encoding::compress_to_vec(data, ruzstd::encoding::CompressionLevel::Fastest)
    }

    fn sample(n: usize) -> Vec<u8> {
        (0..n).map(|i| (i * 7 % 251) as u8).collect()
    }

    #[test]
    fn frames_and_skippable_frames_decode_in_order() {
        let (a, b) = (sample(300_000), b"second frame".to_vec());
        let mut input = compressed(&a);
        // A skippable frame: magic 0x184D2A50, 4-byte length, payload.
        input.extend_from_slice(&0x184D_2A50u32.to_le_bytes());
        input.extend_from_slice(&3u32.to_le_bytes());
        input.extend_from_slice(b"xyz");
        input.extend_from_slice(&compressed(&b));
        let out = decode_zstd(&input, 1 << 20).expect("decodes");
        assert_eq!(out, [a, b].concat());
    }

    #[test]
    fn output_past_the_limit_cut_frames_and_garbage_are_errors() {
        let data = sample(200_000);
        let input = compressed(&data);
        assert_eq!(decode_zstd(&input, data.len()).expect("exactly the limit"), data);
        assert!(matches!(decode_zstd(&input, data.len() - 1), Err(DecodeError::TooLarge)));
        assert!(decode_zstd(&input[..input.len() / 2], 1 << 20).is_err(), "a cut frame");
        assert!(decode_zstd(b"not zstd at all", 1 << 20).is_err(), "garbage");
        let e = decode_zstd(&[0x50, 0x2A, 0x4D, 0x18, 0xff, 0, 0, 0], 1 << 20).expect_err("skippable frame too long");
        assert!(e.to_string().contains("255 bytes"), "{e}");
    }

    /// `n` message records (opcode 0x05) of 100 bytes each: what a chunk holds.
    fn message_records(n: usize) -> Vec<u8> {
        let mut r = Vec::new();
        for i in 0..n {
            r.push(0x05);
            r.extend_from_slice(&100u64.to_le_bytes());
            r.extend((0..100).map(|j| ((i + j) % 251) as u8));
        }
        r
    }

    fn chunk(offset: u64, codec: Codec, uncompressed: usize) -> CompressedChunk {
        CompressedChunk { offset, codec, uncompressed: uncompressed as u64 }
    }

    /// Hands out what `d` holds after the first call, in pieces of `buf`.
    fn drain(d: &mut ChunkDecoder, mut out: Vec<u8>) -> Vec<u8> {
        let mut buf = [0u8; 4096];
        loop {
            let r = d.decompress(&[], &mut buf).expect("hands out");
            if r.wrote == 0 {
                return out;
            }
            out.extend_from_slice(&buf[..r.wrote]);
        }
    }

    #[test]
    fn the_chunk_decoder_hands_out_each_chunk_in_pieces_in_file_order() {
        let (a, b) = (message_records(100), message_records(7));
        let chunks = [chunk(8, Codec::Zstd, a.len()), chunk(900, Codec::Lz4, 0), chunk(2000, Codec::Zstd, b.len())];
        let mut d = ChunkDecoder::new(Codec::Zstd, &chunks);
        assert_eq!(d.name(), "zstd");
        for data in [&a, &b] {
            assert_eq!(d.next_read_size(), usize::MAX, "asks for the whole chunk");
            let input = compressed(data);
            let mut buf = [0u8; 4096];
            let first = d.decompress(&input, &mut buf).expect("decodes");
            assert_eq!((first.consumed, first.wrote), (input.len(), 4096.min(data.len())));
            assert_eq!(d.next_read_size(), 0);
            assert_eq!(&drain(&mut d, buf[..first.wrote].to_vec()), data);
            d.reset().expect("resets");
        }
        let e = d.decompress(&compressed(&a), &mut [0u8; 16]).expect_err("a third zstd chunk");
        assert!(e.to_string().contains("did not find"), "{e}");
    }

    #[test]
    fn the_chunk_decoder_checks_sizes_and_records_naming_the_chunk() {
        let data = message_records(10);
        let input = compressed(&data);
        let mut buf = [0u8; 4096];
        let cases = [
            (data.len() - 1, "the chunk at byte offset 77 decompresses to more than the 1089 bytes it declares"),
            (data.len() + 1, "the chunk at byte offset 77 decompresses to 1090 bytes, fewer than the 1091 it declares"),
        ];
        for (declared, message) in cases {
            let mut d = ChunkDecoder::new(Codec::Zstd, &[chunk(77, Codec::Zstd, declared)]);
            let e = d.decompress(&input, &mut buf).expect_err("wrong size");
            assert!(e.to_string().contains(message), "{e}");
        }
        // A record inside declaring more bytes than the chunk holds.
        let mut bad = data.clone();
        bad[1..9].copy_from_slice(&5000u64.to_le_bytes());
        let mut d = ChunkDecoder::new(Codec::Zstd, &[chunk(77, Codec::Zstd, bad.len())]);
        let e = d.decompress(&compressed(&bad), &mut buf).expect_err("a record past the chunk");
        assert!(e.to_string().contains("decompressed records of the chunk at byte offset 77"), "{e}");
        let mut d = ChunkDecoder::new(Codec::Zstd, &[chunk(77, Codec::Zstd, data.len())]);
        let e = d.decompress(b"garbage", &mut buf).expect_err("not zstd");
        assert!(e.to_string().contains("the chunk at byte offset 77 could not be decompressed"), "{e}");
    }

    /// lz4 frames of `data`: linked blocks with block and content checksums
    /// as the C library writes them by default, and independent blocks
    /// without checksums, `lz4_flex`'s default.
    fn lz4_frames(data: &[u8]) -> Vec<Vec<u8>> {
        use lz4_flex::frame::{BlockMode, FrameEncoder, FrameInfo};
        let linked = FrameInfo::new().block_mode(BlockMode::Linked).block_checksums(true).content_checksum(true);
        [linked, FrameInfo::new()]
            .into_iter()
            .map(|info| {
                let mut enc = FrameEncoder::with_frame_info(info, Vec::new());
                std::io::Write::write_all(&mut enc, data).expect("compresses");
                enc.finish().expect("finishes")
            })
            .collect()
    }

    /// `message_records(50)` as one frame of the C lz4 library (liblz4
    /// 1.10.0, the encoder that compresses ROS 2 bags' lz4 chunks), committed
    /// (tests/data/compressed-bags/README.md).
    fn c_lz4_frame() -> Vec<u8> {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/compressed-bags/records.lz4");
        std::fs::read(p).expect("the committed lz4 frame")
    }

    #[test]
    fn lz4_chunks_decode_with_the_same_checks() {
        let data = message_records(50);
        let mut frames = lz4_frames(&data);
        frames.insert(0, c_lz4_frame());
        for (which, input) in frames.iter().enumerate() {
            let ctx = format!("frame {which}");
            assert_eq!(decode_lz4(input, data.len()).expect(&ctx), data, "{ctx}");
            assert!(matches!(decode_lz4(input, data.len() - 1), Err(DecodeError::TooLarge)), "{ctx}");
            // Concatenated frames decode to the concatenated data, within the same limit.
            let twice = [input.as_slice(), input.as_slice()].concat();
            assert_eq!(decode_lz4(&twice, 2 * data.len()).expect(&ctx), [data.as_slice(), data.as_slice()].concat());
            assert!(matches!(decode_lz4(&twice, 2 * data.len() - 1), Err(DecodeError::TooLarge)), "{ctx}");
            // A cut frame and bytes that are no frame are errors, not panics.
            for bad in [&input[..input.len() / 2], &input[..3], b"garbage!".as_slice()] {
                assert!(
                    matches!(decode_lz4(bad, data.len()), Err(DecodeError::Corrupt(_))),
                    "{ctx}: {} bytes",
                    bad.len()
                );
            }
            let mut d = ChunkDecoder::new(Codec::Lz4, &[chunk(5, Codec::Zstd, 1), chunk(9, Codec::Lz4, data.len())]);
            let mut buf = [0u8; 4096];
            let first = d.decompress(input, &mut buf).expect(&ctx);
            assert_eq!(drain(&mut d, buf[..first.wrote].to_vec()), data, "{ctx}");
        }
        // The checksums of the C library's frame are checked: a changed byte
        // of the compressed block (after the 7-byte frame header and the
        // 4-byte block size) is an error.
        let mut changed = frames[0].clone();
        changed[20] ^= 0x40;
        assert!(matches!(decode_lz4(&changed, data.len()), Err(DecodeError::Corrupt(_))));
    }
}
