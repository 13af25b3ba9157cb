//! Several drives of one vehicle as one drive whose parts never span drives.

use super::{Drive, DriveBuilder, Signals, STEP_UNIFORMITY_TOL};
use crate::error::{Error, Result};
use crate::model::limits::PhysicalLimits;

/// Seconds between the last sample of one drive and the first of the next
/// when [`Drive::concat`] has to shift a drive's clock (its time does not
/// follow the previous drive's).
pub(crate) const CONCAT_GAP_S: f64 = 1.0;

impl Drive {
    /// The drives one after the other as one drive, each drive's parts kept
    /// as parts of their own, so that calibration and validation segments
    /// never span two drives (a joint fit of several drives of one vehicle).
    ///
    /// Time: a drive whose first stamp follows the previous drive's last
    /// keeps its stamps; otherwise its stamps are shifted to start
    /// `CONCAT_GAP_S` after the previous drive's last (only differences
    /// within a part enter the model). The truth is kept when every drive
    /// has it, the reference mask when any has it (samples of a drive
    /// without one count as measured); extra columns are dropped. The
    /// sample time is the first drive's. Each sample's time on its own
    /// drive's clock stays known ([`Drive::own_time_s`]).
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] when `drives` is empty or a drive's sample
    /// time differs from the first's by more than 1 % (naming both; resample
    /// the drives to one rate, e.g. the manifest's `[output] rate_hz`).
    ///
    /// ```
    /// # fn main() -> Result<(), odocal::Error> {
    /// use odocal::{sim, Drive};
    /// let a = sim::simulate(&sim::SimOptions { length_km: 1.0, ..sim::SimOptions::paper(1) })?.drive;
    /// let b = sim::simulate(&sim::SimOptions { length_km: 1.0, ..sim::SimOptions::paper(2) })?.drive;
    /// let both = Drive::concat(&[&a, &b])?;
    /// assert_eq!(both.len(), a.len() + b.len());
    /// assert_eq!(both.parts().len(), a.parts().len() + b.parts().len());
    /// # Ok(()) }
    /// ```
    pub fn concat(drives: &[&Drive]) -> Result<Drive> {
        let invalid = |reason: String| Error::InvalidDrive { context: "joining drives".into(), reason };
        let first = drives.first().ok_or_else(|| invalid("no drives given".into()))?;
        let ts = first.sample_time_s;
        for (i, d) in drives.iter().enumerate().skip(1) {
            if !first.shares_rate_with(d) {
                return Err(invalid(format!(
                    "drive {} has a sample time of {:.6} s, drive 1 {ts:.6} s; drives fitted or validated \
                     together must share one sample rate (resample them, e.g. the manifest's [output] rate_hz)",
                    i + 1,
                    d.sample_time_s
                )));
            }
        }
        let n: usize = drives.iter().map(|d| d.len()).sum();
        let mut t = Vec::with_capacity(n);
        let mut measured = Signals::with_capacity(n);
        let all_truth = drives.iter().all(|d| d.truth.is_some());
        let mut truth = all_truth.then(|| Signals::with_capacity(n));
        let any_mask = drives.iter().any(|d| d.reference_measured.is_some());
        let mut mask = any_mask.then(|| Vec::with_capacity(n));
        let mut parts = Vec::new();
        let mut starts = Vec::new();
        let mut shifts = Vec::new();
        for d in drives {
            let offset = match (t.last(), d.t.first()) {
                (Some(&last), Some(&start)) if start <= last => last + CONCAT_GAP_S - start,
                _ => 0.0,
            };
            let base = t.len();
            starts.extend(d.drive_starts.iter().map(|s| base + s));
            shifts.extend(d.drive_time_shifts_s.iter().map(|s| s + offset));
            t.extend(d.t.iter().map(|v| v + offset));
            append(&mut measured, &d.measured);
            if let (Some(all), Some(tr)) = (truth.as_mut(), d.truth.as_ref()) {
                append(all, tr);
            }
            if let Some(m) = mask.as_mut() {
                match &d.reference_measured {
                    Some(dm) => m.extend_from_slice(dm),
                    None => m.extend(std::iter::repeat_n(true, d.len())),
                }
            }
            parts.extend(d.parts.iter().map(|p| base + p.start..base + p.end));
        }
        let mut joined = DriveBuilder {
            context: "joined drives".into(),
            t,
            measured,
            truth,
            reference_measured: mask,
            parts: Some(parts),
            sample_time_s: Some(ts),
            // Every drive passed its own limits when it was built.
            limits: PhysicalLimits::NONE,
            ..Default::default()
        }
        .build()?;
        joined.drive_starts = starts;
        joined.drive_time_shifts_s = shifts;
        Ok(joined)
    }

    /// Whether `other`'s sample time is this drive's to within 1 %
    /// (`STEP_UNIFORMITY_TOL`): the drives can be fitted or validated
    /// together.
    fn shares_rate_with(&self, other: &Drive) -> bool {
        (other.sample_time_s - self.sample_time_s).abs() <= STEP_UNIFORMITY_TOL * self.sample_time_s
    }

    /// Refuses a drive `held` (named `name`) that validates a calibration
    /// of this drive at another sample rate (its sample time differs by
    /// more than 1 %), as [`Drive::concat`] refuses drives fitted together:
    /// validation segments are counted in samples, so at another rate they
    /// span another length of time and their Ē_p is not comparable.
    pub(crate) fn refuse_other_rate(&self, name: &str, held: &Drive) -> Result<()> {
        if self.shares_rate_with(held) {
            return Ok(());
        }
        let (ts, th) = (self.sample_time_s, held.sample_time_s);
        Err(Error::InvalidDrive {
            context: name.to_string(),
            reason: format!(
                "its sample time is {th:.6} s, the calibration drive's {ts:.6} s; drives fitted or validated \
                 together must share one sample rate (validation segments are counted in samples, so at another \
                 rate they span another length of drive and Ē_p is not comparable): resample it to the \
                 calibration drive's rate, e.g. the manifest's [output] rate_hz"
            ),
        })
    }
}

fn append(to: &mut Signals, from: &Signals) {
    to.px.extend_from_slice(&from.px);
    to.py.extend_from_slice(&from.py);
    to.psi.extend_from_slice(&from.psi);
    to.n_rl.extend_from_slice(&from.n_rl);
    to.n_rr.extend_from_slice(&from.n_rr);
    to.beta.extend_from_slice(&from.beta);
    to.a_y.extend_from_slice(&from.a_y);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::segment::{cut, validation_segments, ValidationSegmentOptions};

    fn drive(n: usize, t0: f64, ts: f64, parts: Vec<std::ops::Range<usize>>) -> Drive {
        let mut s = Signals::with_capacity(n);
        for k in 0..n {
            s.push([k as f64, 0.0, 0.01 * k as f64, 5.0, 5.0, 0.0, 0.0]);
        }
        let t = (0..n).map(|k| t0 + k as f64 * ts).collect();
        DriveBuilder { t, measured: s, parts: Some(parts), ..Default::default() }.build().expect("drive")
    }

    #[test]
    fn parts_never_span_drives() {
        let a = drive(100, 0.0, 0.025, vec![0..60, 60..100]);
        // b starts before a ends: its clock is shifted.
        let b = drive(80, 1.0, 0.025, vec![0..80]);
        let j = Drive::concat(&[&a, &b]).expect("join");
        assert_eq!(j.parts(), &[0..60, 60..100, 100..180]);
        assert_eq!(j.len(), 180);
        approx::assert_relative_eq!(j.t()[100], a.t()[99] + CONCAT_GAP_S);
        assert_eq!(j.px()[100].to_bits(), 0.0f64.to_bits());
        // Segments stay inside the drives.
        for s in cut(&j, 0, 30, 10) {
            assert!(s.start + s.steps < 100 || s.start >= 100, "{s:?}");
        }
        // A later drive keeps its stamps.
        let c = drive(80, 100.0, 0.025, vec![0..80]);
        assert_eq!(Drive::concat(&[&a, &c]).expect("join").t()[100].to_bits(), 100.0f64.to_bits());
        let v =
            validation_segments(&j, &ValidationSegmentOptions { length_steps: 40, stride_steps: 20, offset_steps: 0 })
                .expect("segments");
        assert!(v.iter().all(|s| s.start + s.steps < 100 || s.start >= 100));
    }

    /// Each sample keeps the time its own drive gave it, through a shift, a
    /// second join and a split.
    #[test]
    fn each_sample_keeps_its_own_drives_time() {
        let a = drive(100, 0.0, 0.025, vec![0..100]);
        let b = drive(80, 1.0, 0.025, vec![0..80]);
        let c = drive(60, 500.0, 0.025, vec![0..60]);
        let ab = Drive::concat(&[&a, &b]).expect("join");
        let abc = Drive::concat(&[&ab, &c]).expect("join again");
        assert_eq!(abc.drive_starts(), &[0, 100, 180]);
        let own: Vec<f64> = a.t().iter().chain(b.t()).chain(c.t()).copied().collect();
        for (i, want) in own.iter().enumerate() {
            approx::assert_relative_eq!(abc.own_time_s(i), *want, max_relative = 1e-12);
        }
        assert_eq!(abc.drive_of_sample(150), 1);
        // The second half of the joined drive starts inside b.
        let (_, late) = abc.split_at_time(abc.t()[150]).expect("split");
        assert_eq!(late.drive_starts(), &[0, 30]);
        approx::assert_relative_eq!(late.own_time_s(0), b.t()[50], max_relative = 1e-12);
        approx::assert_relative_eq!(late.own_time_s(30), 500.0);
    }

    #[test]
    fn different_sample_times_are_an_error() {
        let a = drive(100, 0.0, 0.025, vec![0..100]);
        let b = drive(100, 10.0, 0.01, vec![0..100]);
        let e = Drive::concat(&[&a, &b]).expect_err("rates differ");
        assert!(e.to_string().contains("drive 2 has a sample time of 0.010000 s, drive 1 0.025000 s"), "{e}");
        assert!(Drive::concat(&[]).is_err());
        assert_eq!(Drive::concat(&[&a]).expect("one"), a);
    }

    #[test]
    fn a_validation_drive_at_another_rate_is_an_error() {
        let a = drive(100, 0.0, 0.025, vec![0..100]);
        a.refuse_other_rate("v.csv", &drive(50, 0.0, 0.0251, vec![0..50])).expect("within 1 %");
        let e = a.refuse_other_rate("v.csv", &drive(50, 0.0, 0.05, vec![0..50])).expect_err("half the rate");
        assert!(e.to_string().starts_with("v.csv: its sample time is 0.050000 s, the calibration drive's 0.025000 s"));
    }
}
