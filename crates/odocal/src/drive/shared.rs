//! The samples two drives share: a part of a drive cut out of it, or a copy
//! thinned to every n-th sample, holds samples of that drive bit for bit,
//! whatever its time stamps, length or sample rate.
//!
//! A sample is known by the bits of its reference position and both rear
//! wheel readings `(p_x, p_y, n_rl, n_rr)`: two separate drives never
//! repeat all four of each other's samples bit for bit while moving. The
//! time is left out (a copy may count it from another origin), the heading
//! too (an import may unwrap it from another turn), and so are β and a_y
//! (an import derives them). Samples of a standing vehicle (both wheel
//! readings 0) and samples that occur more than once in their own drive
//! are not counted: a parked car repeats them, within a drive and from one
//! drive to the next.

use std::collections::HashSet;
use std::hash::{BuildHasherDefault, Hasher};

use super::Drive;

/// Two drives may share at most this fraction of the samples of the one
/// with fewer: above it, the one is (in part) the other. Two separate
/// drives share none; a validation drive that shares 1 % of its samples
/// with the calibration drive has a validation segment in 100 on data the
/// calibration saw.
pub(crate) const SHARED_FRACTION_LIMIT: f64 = 0.01;
/// Fewer shared samples than this are never refused (a handful of
/// coincidences on a short drive).
pub(crate) const SHARED_SAMPLES_MIN: usize = 10;

/// The samples of a drive that tell it from another: each moving sample's
/// hash, those that occur once in the drive (module docs).
pub(crate) struct SampleSet {
    once: HashSet<u64, BuildHasherDefault<Prehashed>>,
}

impl SampleSet {
    /// The set of `drive`'s moving samples that occur once in it. Time and
    /// memory are linear in the drive's length (a hash of 8 bytes per
    /// sample).
    pub(crate) fn of(drive: &Drive) -> SampleSet {
        let (px, py, rl, rr) = (drive.px(), drive.py(), drive.n_rl(), drive.n_rr());
        let mut once = HashSet::with_capacity_and_hasher(drive.len(), BuildHasherDefault::default());
        let mut repeated = HashSet::<u64, BuildHasherDefault<Prehashed>>::default();
        for i in 0..drive.len() {
            if rl[i] == 0.0 && rr[i] == 0.0 {
                continue;
            }
            let h = sample_hash([px[i], py[i], rl[i], rr[i]]);
            if !once.insert(h) {
                repeated.insert(h);
            }
        }
        for h in &repeated {
            once.remove(h);
        }
        SampleSet { once }
    }

    /// The number of samples in the set.
    pub(crate) fn len(&self) -> usize {
        self.once.len()
    }

    /// The number of samples both sets hold.
    pub(crate) fn shared_with(&self, other: &SampleSet) -> usize {
        let (small, large) = if self.len() <= other.len() { (self, other) } else { (other, self) };
        small.once.iter().filter(|h| large.once.contains(h)).count()
    }
}

/// Whether two drives with sets `a` and `b` share more than they may
/// ([`SHARED_FRACTION_LIMIT`], [`SHARED_SAMPLES_MIN`]): `(a_is_part, shared,
/// samples)`, where the part is the drive with fewer samples in its set
/// (`b` when they have as many), `samples` their number and `shared` how
/// many of them the other holds.
pub(crate) fn overlap(a: &SampleSet, b: &SampleSet) -> Option<(bool, usize, usize)> {
    let samples = a.len().min(b.len());
    let shared = a.shared_with(b);
    (shared >= SHARED_SAMPLES_MIN && shared as f64 > SHARED_FRACTION_LIMIT * samples as f64).then_some((
        a.len() < b.len(),
        shared,
        samples,
    ))
}

/// A 64-bit hash of a sample's values' bits (a negative zero as zero):
/// SplitMix64's finaliser after each value, so the four bit patterns are
/// mixed in order.
fn sample_hash(values: [f64; 4]) -> u64 {
    let mix = |mut z: u64| {
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    };
    values.iter().fold(0x9e37_79b9_7f4a_7c15, |h, &v| {
        let bits = if v == 0.0 { 0 } else { v.to_bits() };
        mix(h ^ bits).wrapping_add(0x9e37_79b9_7f4a_7c15)
    })
}

/// The hasher of a [`SampleSet`]: its keys are hashes already.
#[derive(Default)]
struct Prehashed(u64);

impl Hasher for Prehashed {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0 << 8) | u64::from(b);
        }
    }

    fn write_u64(&mut self, v: u64) {
        self.0 = v;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::{DriveBuilder, Signals};

    /// A drive of `n` samples at `ts` whose sample k is the path's sample
    /// `first + k * step` (a path that turns, wheels that turn), with
    /// `standing` standing samples (the same pose, wheels still) at its start.
    fn cut(first: usize, n: usize, step: usize, standing: usize) -> Drive {
        let at = |k: usize| {
            let s = k as f64 * 0.25;
            [50.0 * (s / 50.0).sin(), 50.0 * (1.0 - (s / 50.0).cos()), s / 50.0, 10.0, 10.2, 0.0, 0.0]
        };
        let mut m = Signals::with_capacity(n + standing);
        for _ in 0..standing {
            let mut p = at(first);
            p[3] = 0.0;
            p[4] = 0.0;
            m.push(p);
        }
        for k in 0..n {
            m.push(at(first + k * step));
        }
        let ts = 0.025 * step as f64;
        let t = (0..n + standing).map(|k| 7.0 + k as f64 * ts).collect();
        DriveBuilder { t, measured: m, ..Default::default() }.build().expect("valid")
    }

    #[test]
    fn a_cut_or_thinned_copy_shares_its_samples() {
        let whole = SampleSet::of(&cut(0, 4000, 1, 0));
        // The first 1000 samples, time counted from elsewhere.
        assert_eq!(overlap(&SampleSet::of(&cut(0, 1000, 1, 0)), &whole), Some((true, 1000, 1000)));
        // Every other sample, at half the rate.
        assert_eq!(overlap(&whole, &SampleSet::of(&cut(1, 1999, 2, 0))), Some((false, 1999, 1999)));
        // A drive that goes on where the other ends: nothing shared.
        assert_eq!(overlap(&whole, &SampleSet::of(&cut(4000, 4000, 1, 0))), None);
        // 1 % overlap is allowed, a sample more is not.
        assert_eq!(overlap(&whole, &SampleSet::of(&cut(3960, 4000, 1, 0))), None);
        assert_eq!(overlap(&whole, &SampleSet::of(&cut(3959, 4000, 1, 0))), Some((false, 41, 4000)));
        // Too few to count on a short drive.
        assert_eq!(overlap(&whole, &SampleSet::of(&cut(3991, 100, 1, 0))), None);
    }

    #[test]
    fn standing_and_repeated_samples_are_not_counted() {
        // Both drives start standing at the same pose: those samples repeat.
        let a = SampleSet::of(&cut(0, 400, 1, 200));
        let b = SampleSet::of(&cut(400, 400, 1, 200));
        assert_eq!((a.len(), b.len()), (400, 400));
        assert_eq!(a.shared_with(&b), 0);
        // A sample repeated within a drive (a car parked with its wheels
        // creeping) is left out; one sample once is kept.
        let mut m = cut(0, 3, 1, 0).measured().clone();
        let row = [m.px[1], m.py[1], m.psi[1], m.n_rl[1], m.n_rr[1], 0.0, 0.0];
        m.push(row);
        let t = (0..4).map(|k| k as f64 * 0.025).collect();
        let d = DriveBuilder { t, measured: m, ..Default::default() }.build().expect("valid");
        assert_eq!(SampleSet::of(&d).len(), 2);
    }

    #[test]
    fn the_hash_tells_each_value_and_its_place() {
        let h = sample_hash([1.0, 2.0, 3.0, 4.0]);
        assert_ne!(h, sample_hash([2.0, 1.0, 3.0, 4.0]));
        assert_ne!(h, sample_hash([1.0, 2.0, 4.0, 3.0]));
        assert_ne!(h, sample_hash([1.0, 2.0, 3.0, f64::from_bits(4.0f64.to_bits() + 1)]));
        assert_eq!(sample_hash([0.0, 2.0, 3.0, 4.0]), sample_hash([-0.0, 2.0, 3.0, 4.0]));
    }
}
