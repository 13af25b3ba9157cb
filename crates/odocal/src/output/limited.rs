//! Bounded reading of the user's files: only regular files are read (a
//! FIFO would block forever, a device such as `/dev/zero` never ends, and
//! its metadata says 0 bytes), and the size limit holds on the bytes
//! actually read, not on what the metadata claims.
//!
//! | file | limit |
//! |---|---|
//! | manifest, noise model, parameter file, simulator sidecar | [`MAX_SETTINGS_BYTES`] = 1 MiB |
//! | drive CSV, CSV stream file | [`MAX_DATA_BYTES`] = 4 GiB |

use std::io::{Error, ErrorKind, Read};
use std::path::Path;

/// Largest settings file (manifest, noise model, parameter file, sidecar).
pub(crate) const MAX_SETTINGS_BYTES: u64 = 1 << 20;
/// Largest data file read whole (a drive CSV, a CSV stream file).
pub(crate) const MAX_DATA_BYTES: u64 = 4 << 30;

/// What a non-regular file is, for the message.
fn kind_of(t: std::fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO (named pipe)"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Refuses anything but a regular file at `path` (a symbolic link is judged
/// by its target), before it is opened: opening a FIFO blocks.
///
/// # Errors
/// An [`ErrorKind::InvalidInput`] error naming what the path is and `what`
/// it should be; the metadata's own error.
pub(crate) fn require_regular_file(path: &Path, what: &str) -> std::io::Result<()> {
    let t = std::fs::metadata(path)?.file_type();
    if t.is_file() {
        Ok(())
    } else {
        Err(Error::new(ErrorKind::InvalidInput, format!("{} where {what} (a regular file) is expected", kind_of(t))))
    }
}

/// The bytes of the regular file `path`, at most `cap` of them: `what`
/// names the file in the messages ("a manifest", "a drive CSV").
///
/// # Errors
/// [`require_regular_file`]'s; an [`ErrorKind::InvalidData`] error when the
/// file holds more than `cap` bytes (counted while reading); read errors.
pub(crate) fn read_limited(path: &Path, cap: u64, what: &str) -> std::io::Result<Vec<u8>> {
    require_regular_file(path, what)?;
    let file = std::fs::File::open(path)?;
    let t = file.metadata()?.file_type();
    if !t.is_file() {
        return Err(Error::new(ErrorKind::InvalidInput, format!("{} where {what} is expected", kind_of(t))));
    }
    let mut bytes = Vec::new();
    file.take(cap.saturating_add(1)).read_to_end(&mut bytes)?;
    if bytes.len() as u64 > cap {
        return Err(Error::new(
            ErrorKind::InvalidData,
            format!("more than {cap} bytes, the limit for {what}: not {what}, or split it"),
        ));
    }
    Ok(bytes)
}

/// A regular file read as a stream, at most `cap` bytes of it: reading past
/// the cap is an [`ErrorKind::InvalidData`] error. It remembers the last
/// byte read (a text file should end with a newline).
pub(crate) struct LimitedFile {
    inner: std::io::Take<std::fs::File>,
    cap: u64,
    what: String,
    read: u64,
    last: Option<u8>,
}

impl LimitedFile {
    /// The last byte read so far; `None` before any.
    pub(crate) fn last_byte(&self) -> Option<u8> {
        self.last
    }
}

impl Read for LimitedFile {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.read += n as u64;
        if self.read > self.cap {
            let (cap, what) = (self.cap, &self.what);
            return Err(Error::new(
                ErrorKind::InvalidData,
                format!("more than {cap} bytes, the limit for {what}: not {what}, or split it"),
            ));
        }
        if n > 0 {
            self.last = Some(buf[n - 1]);
        }
        Ok(n)
    }
}

/// Opens the regular file `path` for reading at most `cap` bytes as a
/// stream ([`LimitedFile`]): [`read_limited`] without holding the bytes.
///
/// # Errors
/// [`require_regular_file`]'s; opening errors.
pub(crate) fn open_limited(path: &Path, cap: u64, what: &str) -> std::io::Result<LimitedFile> {
    require_regular_file(path, what)?;
    let file = std::fs::File::open(path)?;
    let t = file.metadata()?.file_type();
    if !t.is_file() {
        return Err(Error::new(ErrorKind::InvalidInput, format!("{} where {what} is expected", kind_of(t))));
    }
    Ok(LimitedFile { inner: file.take(cap.saturating_add(1)), cap, what: what.to_string(), read: 0, last: None })
}

/// [`read_limited`] as UTF-8 text.
///
/// # Errors
/// As [`read_limited`]; [`ErrorKind::InvalidData`] for text that is not UTF-8.
pub(crate) fn read_text_limited(path: &Path, cap: u64, what: &str) -> std::io::Result<String> {
    String::from_utf8(read_limited(path, cap, what)?)
        .map_err(|e| Error::new(ErrorKind::InvalidData, format!("not UTF-8 text ({what}): {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn devices_directories_and_oversize_files_are_refused() {
        let e = read_limited(Path::new("/dev/zero"), 10, "a manifest").expect_err("device");
        assert!(e.to_string().contains("a character device where a manifest"), "{e}");
        let e = read_limited(Path::new("/"), 10, "a manifest").expect_err("dir");
        assert!(e.to_string().contains("a directory"), "{e}");
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("x.toml");
        std::fs::write(&p, b"0123456789").expect("write");
        assert_eq!(read_limited(&p, 10, "x").expect("at the limit").len(), 10);
        let e = read_limited(&p, 9, "a manifest").expect_err("over");
        assert!(e.to_string().contains("more than 9 bytes"), "{e}");
        let mut f = open_limited(&p, 10, "x").expect("open");
        let mut all = Vec::new();
        f.read_to_end(&mut all).expect("at the limit");
        assert_eq!((all.len(), f.last_byte()), (10, Some(b'9')));
        let mut f = open_limited(&p, 9, "a CSV stream file").expect("open");
        let e = f.read_to_end(&mut Vec::new()).expect_err("over");
        assert!(e.to_string().contains("more than 9 bytes, the limit for a CSV stream file"), "{e}");
        assert!(open_limited(Path::new("/dev/zero"), 10, "x").is_err());
    }
}
