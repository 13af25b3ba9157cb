//! A drive's fingerprint: a hash of its canonical samples, so the same
//! drive is known whether it was read from a CSV, imported through a
//! manifest or made from arrays.

use std::ops::Range;

use sha2::{Digest, Sha256};

use super::shared::{self, SampleSet};
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
    /// let dir = tempfile::tempdir()?;
    /// d.write_csv(dir.path().join("d.csv"))?;
    /// let (back, _) = Drive::read_csv(dir.path().join("d.csv"))?;
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
/// the same [`Drive::fingerprint`] are an error naming both, and so are two
/// whose samples agree though their fingerprints differ (the same data
/// imported another way): the same sample time, as many samples within 2,
/// the reference path the same sample for sample (positions within 1 mm,
/// headings within 1 mrad, after a shift of at most 2 samples) and each
/// rear wheel's rotation within 0.5 %.
///
///
/// Two drives that share samples are refused too: a part of a drive, or a
/// copy thinned to every n-th sample, is not another drive, whatever its
/// time stamps or sample rate. A sample is known by the bits of its
/// reference position and rear wheel readings `(p_x, p_y, n_rl, n_rr)`;
/// standing samples (both wheel readings 0) and samples that repeat within
/// their own drive are not counted. Two drives may share at most 1 % of
/// the samples of the one with fewer (and always up to 9). The check takes
/// time and memory linear in the drives' lengths.
///
/// # Errors
/// [`Error::DuplicateDrive`] naming the first drive and the one that
/// repeats it; [`Error::SameSamples`] for the same samples under another
/// fingerprint; [`Error::SharedSamples`] naming the drive that shares its
/// samples, the drive that holds them and the fraction shared.
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
        for first in 0..k {
            if let Some(how) = same_samples(drives[first].1, drives[k].1) {
                return Err(Error::SameSamples {
                    first: drives[first].0.to_string(),
                    second: drives[k].0.to_string(),
                    how,
                    fingerprints: (prints[first].clone(), fp.clone()),
                });
            }
        }
    }
    refuse_shared_samples(drives)?;
    Ok(prints)
}

/// Refuses two of `drives` that share samples ([`shared::overlap`]),
/// naming the one with fewer samples as the part.
fn refuse_shared_samples(drives: &[(&str, &Drive)]) -> Result<()> {
    if drives.len() < 2 {
        return Ok(());
    }
    let sets: Vec<SampleSet> = drives.iter().map(|(_, d)| SampleSet::of(d)).collect();
    for k in 1..drives.len() {
        for first in 0..k {
            if let Some((first_is_part, shared, samples)) = shared::overlap(&sets[first], &sets[k]) {
                let (part, whole) = if first_is_part { (first, k) } else { (k, first) };
                return Err(Error::SharedSamples {
                    part: drives[part].0.to_string(),
                    whole: drives[whole].0.to_string(),
                    shared,
                    samples,
                });
            }
        }
    }
    Ok(())
}

/// Reference positions that differ by at most this much are the same, m:
/// above a CSV's rounding to the millimetre, far below what separates two
/// drives' paths.
const SAME_POSITION_M: f64 = 1e-3;
/// Headings that differ by at most this much (modulo 2π) are the same, rad.
const SAME_HEADING_RAD: f64 = 1e-3;
/// The largest shift, in samples, between two imports of the same data (a
/// manifest's import may start or end a sample later than a CSV of it).
const MAX_SHIFT: usize = 2;
/// Two imports of the same drive's wheel rotation differ by less than this
/// fraction of it (a manifest averages wheel speeds over its output
/// interval, which moves rotation by a sample's worth at the ends).
const SAME_ROTATION_RELATIVE: f64 = 5e-3;

/// Whether `a` and `b` hold the same samples, whatever their fingerprints:
/// the same sample time (within 10⁻⁶), as many samples within
/// [`MAX_SHIFT`] at either end, the reference path the same sample for
/// sample after a shift of at most [`MAX_SHIFT`] samples (positions
/// within 1 mm, headings within 1 mrad), and each rear wheel's rotation
/// over the samples both hold the same within 0.5 %. Times are not
/// compared (a CSV may count them from another origin), nor the columns
/// an import derives (β, a_y). Returns how they agree, for the error.
pub(crate) fn same_samples(a: &Drive, b: &Drive) -> Option<String> {
    let (ha, hb) = (a.sample_time_s(), b.sample_time_s());
    // A vehicle standing still has no path to tell one drive from another.
    let moves = |d: &Drive| d.distance_m() > 1.0;
    if (ha - hb).abs() > 1e-6 * ha.abs().max(hb.abs())
        || a.len().abs_diff(b.len()) > 2 * MAX_SHIFT
        || !(moves(a) && moves(b))
    {
        return None;
    }
    (0..=2 * MAX_SHIFT).find_map(|k| {
        // b's sample i + shift is a's sample i (shift in -MAX_SHIFT..=MAX_SHIFT).
        let (a0, b0) = if k < MAX_SHIFT { (MAX_SHIFT - k, 0) } else { (0, k - MAX_SHIFT) };
        let n = a.len().saturating_sub(a0).min(b.len().saturating_sub(b0));
        if n < 2 || n + 2 * MAX_SHIFT < a.len().max(b.len()) {
            return None;
        }
        let (ra, rb) = (a0..a0 + n, b0..b0 + n);
        let within = |x: &[f64], y: &[f64], tol: f64, d: fn(f64, f64) -> f64| {
            x[ra.clone()].iter().zip(&y[rb.clone()]).all(|(&u, &v)| d(u, v) <= tol)
        };
        let diff = |u: f64, v: f64| (u - v).abs();
        // Modulo 2π: two imports may unwrap the heading from another turn.
        let angle = |u: f64, v: f64| {
            use std::f64::consts::{PI, TAU};
            ((u - v + PI).rem_euclid(TAU) - PI).abs()
        };
        let pose = within(a.px(), b.px(), SAME_POSITION_M, diff)
            && within(a.py(), b.py(), SAME_POSITION_M, diff)
            && within(a.psi(), b.psi(), SAME_HEADING_RAD, angle);
        let rotation = |x: &[f64], y: &[f64]| {
            let (p, q) = (x[ra.clone()].iter().sum::<f64>(), y[rb.clone()].iter().sum::<f64>());
            (p - q).abs() <= SAME_ROTATION_RELATIVE * p.abs().max(q.abs())
        };
        let wheels = rotation(a.n_rl(), b.n_rl()) && rotation(a.n_rr(), b.n_rr());
        let shift = match k as i64 - MAX_SHIFT as i64 {
            0 => "sample for sample".to_string(),
            s => format!("shifted by {s} sample{}", if s.abs() == 1 { "" } else { "s" }),
        };
        (pose && wheels).then(|| {
            format!(
                "{n} samples, {shift}: the reference path within {} mm and {} mrad, each wheel's rotation within {} %",
                SAME_POSITION_M * 1e3,
                SAME_HEADING_RAD * 1e3,
                SAME_ROTATION_RELATIVE * 1e2
            )
        })
    })
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
        // Paths 0.1 m apart: no sample of one is a sample of the other.
        let (a, b) = (drive(30, 0.0), drive(30, 0.1));
        let prints = refuse_duplicates(&[("a.csv", &a), ("b.csv", &b)]).expect("distinct");
        assert_eq!(prints, vec![a.fingerprint(), b.fingerprint()]);
        let e = refuse_duplicates(&[("a.csv", &a), ("b.csv", &b), ("the --validate-on drive c.csv", &a)])
            .expect_err("dup")
            .to_string();
        assert!(e.starts_with("the --validate-on drive c.csv is the same drive as a.csv"), "{e}");
    }

    /// `drive` with its time moved, its pose rounded to 0.1 mm and its
    /// first `skip` samples dropped, the wheels scaled by `wheels`.
    fn read_another_way(d: &Drive, skip: usize, wheels: f64) -> Drive {
        let m = d.measured();
        let s: Signals = (skip..d.len())
            .map(|i| {
                let r = |x: f64| (x * 1e4).round() / 1e4;
                [r(m.px[i]), r(m.py[i]), r(m.psi[i]), wheels * m.n_rl[i], wheels * m.n_rr[i], m.beta[i], m.a_y[i]]
            })
            .collect();
        let t = d.t()[skip..].iter().map(|t| t + 1000.0).collect();
        crate::drive::DriveBuilder { t, measured: s, ..Default::default() }.build().expect("valid")
    }

    #[test]
    fn the_same_samples_under_another_fingerprint_are_named() {
        let a = drive(400, 0.0);
        for skip in [0, 1, 2] {
            let b = read_another_way(&a, skip, 1.0);
            assert_ne!(a.fingerprint(), b.fingerprint());
            let how = same_samples(&a, &b).expect("the same samples");
            assert!(how.starts_with(&format!("{} samples, ", 400 - skip)), "{how}");
            let e = refuse_duplicates(&[("a.csv", &a), ("the --validate-on drive b.toml", &b)])
                .expect_err("the same samples")
                .to_string();
            assert!(e.starts_with("the --validate-on drive b.toml holds the same samples as a.csv ("), "{e}");
            assert!(e.contains(&b.fingerprint()[..12]) && e.contains(&a.fingerprint()[..12]), "{e}");
        }
        assert!(same_samples(&a, &read_another_way(&a, 0, 1.0)).expect("same").contains("sample for sample"));
        // More than a few samples apart, other wheel rotation, another path: another drive.
        assert_eq!(same_samples(&a, &read_another_way(&a, 5, 1.0)), None);
        assert_eq!(same_samples(&a, &read_another_way(&a, 0, 1.01)), None);
        assert_eq!(same_samples(&a, &drive(400, 0.01)), None);
        assert!(refuse_duplicates(&[("a.csv", &a), ("b.csv", &drive(400, 0.01))]).is_ok());
    }

    /// A drive with its samples `keep` (its time counted from `t0`, its
    /// sample time `step` times `a`'s).
    fn samples_of(a: &Drive, keep: impl Iterator<Item = usize>, t0: f64, step: usize) -> Drive {
        let m = a.measured();
        let rows: Vec<usize> = keep.collect();
        let s: Signals = rows.iter().map(|&i| [m.px[i], m.py[i], m.psi[i], m.n_rl[i], m.n_rr[i], 0.0, 0.0]).collect();
        let t = (0..rows.len()).map(|k| t0 + k as f64 * a.sample_time_s() * step as f64).collect();
        crate::drive::DriveBuilder { t, measured: s, ..Default::default() }.build().expect("valid")
    }

    #[test]
    fn a_part_or_a_thinned_copy_is_refused_naming_both_and_the_fraction() {
        let a = drive(4000, 0.0);
        let part = samples_of(&a, 0..1880, 50.0, 1);
        let e = refuse_duplicates(&[("a.csv", &a), ("the --validate-on drive part.csv", &part)])
            .expect_err("a part")
            .to_string();
        assert!(
            e.starts_with("the --validate-on drive part.csv shares 100 % of its samples with a.csv (1880 of its"),
            "{e}"
        );
        assert!(e.contains("held-out data must be a different drive"), "{e}");
        // The part given first, at another rate: still the part that is named.
        let thinned = samples_of(&a, (0..4000).step_by(2), 0.0, 2);
        let e = refuse_duplicates(&[("drive 1 (half.csv)", &thinned), ("drive 2 (a.csv)", &a)])
            .expect_err("thinned")
            .to_string();
        assert!(e.starts_with("drive 1 (half.csv) shares 100 % of its samples with drive 2 (a.csv)"), "{e}");
        // Half of each drive shared.
        let longer = drive(8000, 0.0);
        let e = refuse_duplicates(&[("a.csv", &a), ("b.csv", &samples_of(&longer, 2000..6000, 0.0, 1))]);
        let e = e.expect_err("half shared").to_string();
        assert!(e.starts_with("b.csv shares 50 % of its samples with a.csv (2000 of its 4000 moving"), "{e}");
        // A drive that goes on where another ends shares nothing.
        let next = samples_of(&longer, 4000..8000, 0.0, 1);
        assert!(refuse_duplicates(&[("a.csv", &a), ("b.csv", &next)]).is_ok());
    }
}
