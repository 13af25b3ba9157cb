//! A drive's fingerprint: a hash of its canonical samples, so the same
//! drive is known whether it was read from a CSV, imported through a
//! manifest or made from arrays.

use std::ops::Range;

use sha2::{Digest, Sha256};

use super::{Drive, SIGNAL_NAMES};
use crate::error::{Error, Result};

/// What the hash starts with: the fingerprint's name and version.
const DOMAIN: &[u8] = b"odocal drive fingerprint v1\0";

impl Drive {
    /// The drive's fingerprint: the SHA-256 (lowercase hex, 64 characters)
    /// of its canonical samples, in this order, every number 8 bytes
    /// little-endian:
    ///
    /// 1. the bytes `odocal drive fingerprint v1` and a NUL;
    /// 2. the number of samples and the number of parts (`u64`), then each
    ///    part's first and one-past-last sample index (`u64`);
    /// 3. the sample time in whole nanoseconds (`i64`, rounded; a CSV's is
    ///    the mean step, a manifest's `1/rate_hz`: equal to the nanosecond);
    /// 4. the columns `t, px, py, psi, n_rl, n_rr, beta, a_y`, each value's
    ///    IEEE-754 bits (`u64`), a negative zero as zero.
    ///
    /// Extra columns, the simulator's truth columns and `ref_measured` are
    /// not part of it: a drive with a column added (as `odocal compensate`
    /// writes it) is the same drive. The samples are those after the
    /// reader's checks (the heading unwrapped), so a drive written with
    /// [`Drive::write_csv`] and read back has the fingerprint it had.
    ///
    /// ```
    /// # fn main() -> Result<(), Box<dyn std::error::Error>> {
    /// use odocal::{Drive, DriveBuilder, Signals};
    /// let t: Vec<f64> = (0..4).map(|k| k as f64 * 0.1).collect();
    /// let s: Signals = (0..4).map(|k| [k as f64, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]).collect();
    /// let d = DriveBuilder { t, measured: s, ..Default::default() }.build()?;
    /// assert_eq!(d.fingerprint().len(), 64);
    /// let mut csv = Vec::new();
    /// d.write_csv_to(&mut csv)?;
    /// let back = Drive::parse_csv(&csv, std::path::Path::new("d.csv"))?;
    /// assert_eq!(back.fingerprint(), d.fingerprint());
    /// # Ok(()) }
    /// ```
    pub fn fingerprint(&self) -> String {
        let mut f = Fingerprinter::new(self.len(), &self.parts, self.sample_time_s);
        let mut columns: Vec<&[f64]> = vec![&self.t];
        columns.extend(self.measured.columns().iter().map(|(_, c)| *c));
        debug_assert_eq!(columns.len(), SIGNAL_NAMES.len() + 1);
        for c in columns {
            for chunk in c.chunks(4096) {
                f.values(chunk);
            }
        }
        f.finish()
    }
}

/// The hash of [`Drive::fingerprint`] fed piece by piece: the counts, parts
/// and sample time first, then the columns' values in order, in pieces of
/// any size (a streamed drive's columns are read back from disk).
pub(crate) struct Fingerprinter {
    hash: Sha256,
    buf: Vec<u8>,
}

impl Fingerprinter {
    /// Starts the hash of a drive of `len` samples in `parts`, sampled every
    /// `sample_time_s`.
    pub(crate) fn new(len: usize, parts: &[Range<usize>], sample_time_s: f64) -> Fingerprinter {
        let mut h = Sha256::new();
        h.update(DOMAIN);
        let count = |n: usize| (n as u64).to_le_bytes();
        h.update(count(len));
        h.update(count(parts.len()));
        for p in parts {
            h.update(count(p.start));
            h.update(count(p.end));
        }
        h.update(((sample_time_s * 1e9).round() as i64).to_le_bytes());
        Fingerprinter { hash: h, buf: Vec::with_capacity(8 * 4096) }
    }

    /// The next values of the columns `t, px, py, psi, n_rl, n_rr, beta,
    /// a_y`, one column after the other.
    pub(crate) fn values(&mut self, values: &[f64]) {
        self.buf.clear();
        for &v in values {
            let bits = if v == 0.0 { 0 } else { v.to_bits() };
            self.buf.extend_from_slice(&bits.to_le_bytes());
        }
        self.hash.update(&self.buf);
    }

    /// The fingerprint: lowercase hex, 64 characters.
    pub(crate) fn finish(self) -> String {
        self.hash.finalize().iter().map(|b| format!("{b:02x}")).collect()
    }
}

/// Refuses a drive given twice: `drives` are `(name, drive)` pairs (the
/// name as errors show it, e.g. "the --validate-on drive b.csv"); two with
/// the same [`Drive::fingerprint`] are an error naming both.
///
/// # Errors
/// [`Error::DuplicateDrive`] naming the first drive and the one that repeats it.
pub fn refuse_duplicates(drives: &[(&str, &Drive)]) -> Result<Vec<String>> {
    let prints: Vec<String> = drives.iter().map(|(_, d)| d.fingerprint()).collect();
    for (k, fp) in prints.iter().enumerate() {
        if let Some(first) = prints[..k].iter().position(|x| x == fp) {
            return Err(Error::DuplicateDrive {
                first: drives[first].0.to_string(),
                second: drives[k].0.to_string(),
                fingerprint: fp.clone(),
            });
        }
    }
    Ok(prints)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::{ExtraColumn, ExtraValues, Signals};

    fn drive(n: usize, shift: f64) -> Drive {
        let t: Vec<f64> = (0..n).map(|k| k as f64 * 0.025).collect();
        let mut s = Signals::with_capacity(n);
        for k in 0..n {
            s.push([k as f64 * 0.25 + shift, 0.0, 0.0, 5.0, 5.0, 0.0, 0.0]);
        }
        crate::drive::DriveBuilder { t, measured: s, ..Default::default() }.build().expect("valid")
    }

    /// The fingerprint of a fixed drive, as documented: pins the byte order.
    #[test]
    fn fingerprint_is_pinned() {
        let d = drive(5, 0.0);
        let mut h = Sha256::new();
        h.update(b"odocal drive fingerprint v1\0");
        for n in [5u64, 1, 0, 5] {
            h.update(n.to_le_bytes());
        }
        h.update(25_000_000i64.to_le_bytes());
        let cols: [[f64; 5]; 8] = [
            std::array::from_fn(|k| k as f64 * 0.025),
            std::array::from_fn(|k| k as f64 * 0.25),
            [0.0; 5],
            [0.0; 5],
            [5.0; 5],
            [5.0; 5],
            [0.0; 5],
            [0.0; 5],
        ];
        for c in cols {
            for v in c {
                h.update(v.to_bits().to_le_bytes());
            }
        }
        let want: String = h.finalize().iter().map(|b| format!("{b:02x}")).collect();
        assert_eq!(d.fingerprint(), want);
        assert_eq!(d.fingerprint(), "0af19d694ec80b164b5996b450f5f47b4e5d337bdd26918fa2d9dac83bc26f89");
    }

    #[test]
    fn same_samples_same_fingerprint_any_change_another() {
        let d = drive(50, 0.0);
        assert_eq!(d.fingerprint(), drive(50, 0.0).fingerprint());
        assert_ne!(d.fingerprint(), drive(50, 1e-12).fingerprint());
        assert_ne!(d.fingerprint(), drive(49, 0.0).fingerprint());
        // An extra column does not make another drive.
        let with = d
            .clone()
            .with_extra(ExtraColumn { name: "flag".into(), values: ExtraValues::Numbers(vec![1.0; 50]) })
            .expect("extra");
        assert_eq!(with.fingerprint(), d.fingerprint());
        // Parts do.
        let parts = crate::drive::DriveBuilder {
            t: d.t().to_vec(),
            measured: d.measured().clone(),
            parts: Some(vec![0..20, 20..50]),
            ..Default::default()
        }
        .build();
        assert_ne!(parts.expect("parts").fingerprint(), d.fingerprint());
    }

    #[test]
    fn duplicates_are_named() {
        let (a, b) = (drive(30, 0.0), drive(30, 1.0));
        let prints = refuse_duplicates(&[("a.csv", &a), ("b.csv", &b)]).expect("distinct");
        assert_eq!(prints, vec![a.fingerprint(), b.fingerprint()]);
        let e = refuse_duplicates(&[("a.csv", &a), ("b.csv", &b), ("the --validate-on drive c.csv", &a)])
            .expect_err("dup")
            .to_string();
        assert!(e.starts_with("the --validate-on drive c.csv is the same drive as a.csv"), "{e}");
    }
}
