//! Zstandard decompression of MCAP chunks in pure Rust (`ruzstd`).
//!
//! ROS 2 writes its MCAP bags with zstd-compressed chunks. The reference C
//! library takes longer to compile than the rest of odocal's dependencies
//! together on a small machine, so the chunks are decoded with `ruzstd`,
//! a decoder written in Rust: for the walk that checks a bag's lengths
//! ([`decode`]) and for the MCAP reader ([`ChunkDecoder`], registered in
//! place of the reader's C-backed one). A chunk is decoded whole into a
//! buffer of at most its declared (capped) size; chunks are small (rosbag2
//! writes 768 KiB), so decoding whole costs no more memory than the checks
//! already allow.

use mcap::sans_io::decompressor::{DecompressResult, Decompressor};
use mcap::McapError;
use ruzstd::decoding::errors::{FrameDecoderError, ReadFrameHeaderError};
use ruzstd::decoding::{BlockDecodingStrategy, FrameDecoder};

/// Why [`decode`] failed.
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
pub(super) fn decode(mut input: &[u8], limit: usize) -> Result<Vec<u8>, DecodeError> {
    let corrupt = |e: FrameDecoderError| DecodeError::Corrupt(e.to_string());
    let mut frame = FrameDecoder::new();
    let mut out = Vec::new();
    while !input.is_empty() {
        match frame.init(&mut input) {
            Ok(()) => {}
            Err(FrameDecoderError::ReadFrameHeaderError(ReadFrameHeaderError::SkipFrame { length, .. })) => {
                input = input
                    .get(length as usize..)
                    .ok_or_else(|| {
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
            if let Some(bytes) = frame.collect() {
                out.extend_from_slice(&bytes);
            }
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

/// The MCAP reader's decompressor for `"zstd"` chunks: it asks the reader
/// for the chunk's whole compressed records (a read hint of `usize::MAX`,
/// which the reader caps at the bytes left in the chunk and at its record
/// length limit, itself at least the largest chunk), decodes them with
/// [`decode`] and hands the result out as the reader asks for it.
pub(super) struct ChunkDecoder {
    /// The most bytes one chunk may decompress to.
    limit: usize,
    /// The decoded chunk, once the compressed bytes were passed in.
    decoded: Option<Vec<u8>>,
    /// How many bytes of `decoded` were handed out.
    given: usize,
}

impl ChunkDecoder {
    pub(super) fn new(limit: usize) -> ChunkDecoder {
        ChunkDecoder { limit, decoded: None, given: 0 }
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
                self.decoded = Some(decode(src, self.limit).map_err(|e| McapError::DecompressionError(e.to_string()))?);
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
        "zstd"
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
        let out = decode(&input, 1 << 20).expect("decodes");
        assert_eq!(out, [a, b].concat());
    }

    #[test]
    fn output_past_the_limit_cut_frames_and_garbage_are_errors() {
        let data = sample(200_000);
        let input = compressed(&data);
        assert_eq!(decode(&input, data.len()).expect("exactly the limit"), data);
        assert!(matches!(decode(&input, data.len() - 1), Err(DecodeError::TooLarge)));
        assert!(decode(&input[..input.len() / 2], 1 << 20).is_err(), "a cut frame");
        assert!(decode(b"not zstd at all", 1 << 20).is_err(), "garbage");
        let e = decode(&[0x50, 0x2A, 0x4D, 0x18, 0xff, 0, 0, 0], 1 << 20).expect_err("skippable frame too long");
        assert!(e.to_string().contains("255 bytes"), "{e}");
    }

    #[test]
    fn the_chunk_decoder_hands_out_a_chunk_in_pieces_and_resets() {
        let data = sample(10_000);
        let input = compressed(&data);
        let mut d = ChunkDecoder::new(1 << 20);
        assert_eq!(d.next_read_size(), usize::MAX, "asks for the whole chunk");
        let mut out = Vec::new();
        let mut buf = [0u8; 4096];
        let first = d.decompress(&input, &mut buf).expect("decodes");
        assert_eq!((first.consumed, first.wrote), (input.len(), 4096));
        out.extend_from_slice(&buf[..first.wrote]);
        assert_eq!(d.next_read_size(), 0);
        loop {
            let r = d.decompress(&[], &mut buf).expect("hands out");
            if r.wrote == 0 {
                break;
            }
            out.extend_from_slice(&buf[..r.wrote]);
        }
        assert_eq!(out, data);
        d.reset().expect("resets");
        assert_eq!(d.next_read_size(), usize::MAX);
        let again = d.decompress(&input, &mut buf).expect("decodes again");
        assert_eq!(&buf[..again.wrote], &data[..4096]);
    }
}
