//! Cutting a drive into calibration and validation segments (docs/method.md §3).
//!
//! Expert API: for programs that run the steps ([`crate::identify`],
//! [`crate::compensate`]) or score θ on segments themselves; a calibration
//! cuts its segments from [`crate::CalibrationOptions`].
//!
//! A segment of K steps starting at sample `i0` starts from the reference
//! pose `ỹ_{i0}`, uses the inputs `u_{i0} … u_{i0+K−1}` and is compared with
//! the reference at samples `i0+1 … i0+K`. Starts are `offset, offset +
//! stride, …` within each continuous part of the drive while `i0 + K ≤ N − 1`
//! (N samples in the part). Segments never span two parts.

use serde::{Deserialize, Serialize};

use crate::drive::Drive;
use crate::error::{Error, Result};
use crate::model::{Input, State};

/// How calibration segments are cut and selected.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SegmentOptions {
    /// Steps K per segment. Default 650 (16.25 s at 40 Hz).
    pub length_steps: usize,
    /// Steps between the starts of consecutive segments. Default 100.
    pub stride_steps: usize,
    /// First start, in samples from the start of each part. Default 0.
    /// Each of the three counts is at most 10,000,000.
    pub offset_steps: usize,
    /// A segment is selected when its peak absolute yaw rate (from the
    /// reference heading) is at least this, rad/s: 0 selects every
    /// segment, a straight one too. Default 0.15.
    pub min_peak_yaw_rate_rad_per_s: f64,
}

impl Default for SegmentOptions {
    fn default() -> Self {
        SegmentOptions { length_steps: 650, stride_steps: 100, offset_steps: 0, min_peak_yaw_rate_rad_per_s: 0.15 }
    }
}

impl SegmentOptions {
    /// Checks the options, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        check_counts(
            (self.length_steps, self.stride_steps, self.offset_steps),
            ("segment_length", "segment_stride", "segment_offset"),
        )?;
        if self.min_peak_yaw_rate_rad_per_s.is_nan() || self.min_peak_yaw_rate_rad_per_s < 0.0 {
            return Err(Error::InvalidOption {
                field: "min_peak_yaw_rate_rad_per_s",
                reason: "must be a non-negative number".into(),
            });
        }
        Ok(())
    }
}

/// The shortest segment, samples: one step between two samples.
pub(crate) const MIN_LENGTH_STEPS: usize = 2;
/// The smallest stride between segments' starts, samples.
pub(crate) const MIN_STRIDE_STEPS: usize = 1;

/// The most steps a segment's length, stride or offset may count (the
/// ceiling of `segment_length`, `segment_stride` and `validation_length`
/// wherever they are given).
pub(crate) const MAX_STEPS: usize = 10_000_000;

/// Segment length, stride and offset checks shared by both option structs,
/// naming the offending one as the command line, a manifest's
/// `[calibration]` and Python name it (`names`: the length's, the stride's
/// and the offset's).
fn check_counts(
    (length_steps, stride_steps, offset_steps): (usize, usize, usize),
    (length, stride, offset): (&'static str, &'static str, &'static str),
) -> Result<()> {
    if length_steps < MIN_LENGTH_STEPS {
        let reason = format!("must be at least {MIN_LENGTH_STEPS} steps (length_steps)");
        return Err(Error::InvalidOption { field: length, reason });
    }
    if stride_steps < MIN_STRIDE_STEPS {
        let reason = format!("must be at least {MIN_STRIDE_STEPS} step (stride_steps)");
        return Err(Error::InvalidOption { field: stride, reason });
    }
    for (field, name, v) in [
        (length, "length_steps", length_steps),
        (stride, "stride_steps", stride_steps),
        (offset, "offset_steps", offset_steps),
    ] {
        if v > MAX_STEPS {
            let reason = format!("= {v} is above its ceiling of {MAX_STEPS} steps ({name})");
            return Err(Error::InvalidOption { field, reason });
        }
    }
    Ok(())
}

/// How validation segments are cut (all are used, whatever their yaw rate).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ValidationSegmentOptions {
    /// Steps K_v per segment. Default 1300.
    pub length_steps: usize,
    /// Steps between starts. Default 650.
    pub stride_steps: usize,
    /// First start within each part, samples. Default 50. Each of the three
    /// counts is at most 10,000,000.
    pub offset_steps: usize,
}

impl Default for ValidationSegmentOptions {
    fn default() -> Self {
        ValidationSegmentOptions { length_steps: 1300, stride_steps: 650, offset_steps: 50 }
    }
}

impl ValidationSegmentOptions {
    /// Checks the options, naming the offending field.
    pub fn validate(&self) -> Result<()> {
        check_counts(
            (self.length_steps, self.stride_steps, self.offset_steps),
            ("validation_length", "validation stride", "validation_offset"),
        )
    }
}

/// One segment of a drive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Segment {
    /// Index of the first sample (the start pose).
    pub start: usize,
    /// Number of steps K (residual poses).
    pub steps: usize,
    /// Peak |ψ̃_{k+1} − ψ̃_k| / t_s over the segment, rad/s.
    pub peak_yaw_rate_rad_per_s: f64,
}

/// Cuts segments of `length` steps every `stride` samples from `offset` in
/// every part: none where the offset or length reach past a part (whatever
/// their size) or `length` or `stride` is 0.
pub fn cut(drive: &Drive, offset: usize, length: usize, stride: usize) -> Vec<Segment> {
    let mut out = Vec::new();
    if length == 0 || stride == 0 {
        return out;
    }
    for part in drive.parts() {
        let Some(mut i0) = part.start.checked_add(offset) else { continue };
        while i0.checked_add(length).is_some_and(|end| end < part.end) {
            let peak = (i0..i0 + length).map(|k| (drive.psi()[k + 1] - drive.psi()[k]).abs()).fold(0.0, f64::max)
                / drive.sample_time_s();
            out.push(Segment { start: i0, steps: length, peak_yaw_rate_rad_per_s: peak });
            let Some(next) = i0.checked_add(stride) else { break };
            i0 = next;
        }
    }
    out
}

/// All calibration segments of a drive and those selected by yaw rate.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct SegmentSelection {
    /// Every segment cut.
    pub all: Vec<Segment>,
    /// The segments whose peak yaw rate reaches the threshold (is at least it).
    pub selected: Vec<Segment>,
}

/// Cuts calibration segments and selects those that turn enough: the
/// segments whose peak yaw rate reaches
/// [`SegmentOptions::min_peak_yaw_rate_rad_per_s`] (is at least it), of
/// those [`cut`] gives with the options' offset, length and stride.
pub fn calibration_segments(drive: &Drive, opts: &SegmentOptions) -> Result<Vec<Segment>> {
    Ok(select_segments(drive, opts)?.selected)
}

/// [`calibration_segments`] with every segment cut beside those selected.
pub(crate) fn select_segments(drive: &Drive, opts: &SegmentOptions) -> Result<SegmentSelection> {
    opts.validate()?;
    let all = cut(drive, opts.offset_steps, opts.length_steps, opts.stride_steps);
    let selected =
        all.iter().copied().filter(|s| s.peak_yaw_rate_rad_per_s >= opts.min_peak_yaw_rate_rad_per_s).collect();
    Ok(SegmentSelection { all, selected })
}

/// Cuts validation segments.
pub fn validation_segments(drive: &Drive, opts: &ValidationSegmentOptions) -> Result<Vec<Segment>> {
    opts.validate()?;
    Ok(cut(drive, opts.offset_steps, opts.length_steps, opts.stride_steps))
}

/// The error for a drive without one validation segment: `what` ("the
/// drive", "validation drive NAME") with its sample count, how many
/// samples one part needs (`cut` starts a segment `offset_steps` into a
/// part and needs a sample after its last step) and what to do.
pub(crate) fn too_short_for_validation(what: &str, drive: &Drive, opts: &ValidationSegmentOptions) -> Error {
    let longest = drive.parts().iter().map(|p| p.len()).max().unwrap_or(0);
    let part = if drive.parts().len() > 1 { format!(", its longest part {longest}") } else { String::new() };
    Error::NoSegments(format!(
        "{what} ({} samples{part}) is too short for one validation segment: a part needs at least {} samples \
         (the segment's {} steps, starting {} samples into the part); give a longer drive or a shorter \
         validation_length (--validation-length)",
        drive.len(),
        opts.offset_steps.saturating_add(opts.length_steps).saturating_add(1),
        opts.length_steps,
        opts.offset_steps
    ))
}

/// The data of one segment, borrowed column-wise from a drive, with the
/// wheel rotations optionally replaced (by compensated ones).
#[derive(Debug, Clone, Copy)]
pub struct SegmentData<'a> {
    /// Index of the first sample in the drive.
    pub start: usize,
    /// First sample of the drive this segment comes from, when drives were
    /// joined ([`Drive::drive_starts`]; 0 for a drive that was not): the
    /// cluster-robust σ's blocks restart there, so they never span two
    /// drives and do not depend on the drives' order.
    pub drive_start: usize,
    /// Sample time, s.
    pub sample_time_s: f64,
    /// Rear-left wheel rotation, rev/s, K values.
    pub n_rl: &'a [f64],
    /// Rear-right wheel rotation, rev/s, K values.
    pub n_rr: &'a [f64],
    /// Sideslip, rad, K values.
    pub beta: &'a [f64],
    /// Lateral acceleration, m/s², K values.
    pub a_y: &'a [f64],
    /// Reference x, m, K+1 values (index 0 is the start pose).
    pub px: &'a [f64],
    /// Reference y, m, K+1 values.
    pub py: &'a [f64],
    /// Reference heading, rad, K+1 values.
    pub psi: &'a [f64],
}

impl<'a> SegmentData<'a> {
    /// Borrows a segment's data from a drive.
    pub fn new(drive: &'a Drive, seg: &Segment) -> Self {
        let (a, k) = (seg.start, seg.steps);
        SegmentData {
            start: a,
            drive_start: drive.drive_starts()[drive.drive_of_sample(a)],
            sample_time_s: drive.sample_time_s(),
            n_rl: &drive.n_rl()[a..a + k],
            n_rr: &drive.n_rr()[a..a + k],
            beta: &drive.beta()[a..a + k],
            a_y: &drive.a_y()[a..a + k],
            px: &drive.px()[a..=a + k],
            py: &drive.py()[a..=a + k],
            psi: &drive.psi()[a..=a + k],
        }
    }

    /// The same segment with other wheel rotations (K values each).
    pub(crate) fn with_wheels<'b>(&self, n_rl: &'b [f64], n_rr: &'b [f64]) -> SegmentData<'b>
    where
        'a: 'b,
    {
        assert_eq!(n_rl.len(), self.steps(), "with_wheels: n_rl length");
        assert_eq!(n_rr.len(), self.steps(), "with_wheels: n_rr length");
        SegmentData { n_rl, n_rr, ..*self }
    }

    /// Number of steps K.
    #[inline]
    pub(crate) fn steps(&self) -> usize {
        self.n_rl.len()
    }

    /// Input at step k (0 ≤ k < K).
    #[inline]
    pub(crate) fn input(&self, k: usize) -> Input {
        Input { n_rl: self.n_rl[k], n_rr: self.n_rr[k], beta: self.beta[k], a_y: self.a_y[k] }
    }

    /// Reference pose at k (0 ≤ k ≤ K); k = 0 is the start pose x_0.
    #[inline]
    pub(crate) fn reference(&self, k: usize) -> State {
        State::new(self.px[k], self.py[k], self.psi[k])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::Signals;

    fn drive(n: usize, turn_from: usize) -> Drive {
        drive_with_parts(n, turn_from, vec![0..n])
    }

    fn drive_with_parts(n: usize, turn_from: usize, parts: Vec<std::ops::Range<usize>>) -> Drive {
        let t: Vec<f64> = (0..n).map(|i| i as f64 * 0.025).collect();
        let psi: Vec<f64> = (0..n).map(|i| if i > turn_from { (i - turn_from) as f64 * 0.01 } else { 0.0 }).collect();
        let z = vec![0.0; n];
        crate::drive::DriveBuilder {
            t,
            measured: Signals {
                px: z.clone(),
                py: z.clone(),
                psi,
                n_rl: z.clone(),
                n_rr: z.clone(),
                beta: z.clone(),
                a_y: z,
            },
            context: "test".into(),
            parts: Some(parts),
            ..Default::default()
        }
        .build()
        .expect("valid")
    }

    #[test]
    fn indexing_matches_spec() {
        let d = drive(1000, 2000);
        let s = cut(&d, 0, 650, 100);
        // starts 0,100,200,300: 300+650 = 950 ≤ 999; 400+650 = 1050 > 999
        assert_eq!(s.iter().map(|s| s.start).collect::<Vec<_>>(), vec![0, 100, 200, 300]);
        let s = cut(&d, 0, 999, 1);
        assert_eq!(s.len(), 1, "i0 + K ≤ N − 1 admits exactly K = N − 1");
    }

    #[test]
    fn selection_by_peak_yaw_rate() {
        // yaw rate 0.01 rad / 0.025 s = 0.4 rad/s after sample 700
        let d = drive(1500, 700);
        let sel = select_segments(&d, &SegmentOptions::default()).expect("valid");
        for s in &sel.all {
            let turns = s.start + s.steps > 701;
            assert_eq!(sel.selected.contains(s), turns, "{s:?}");
        }
        assert!(!sel.selected.is_empty());
    }

    /// A threshold is reached by a peak equal to it: 0 selects every
    /// segment of a perfectly straight drive (peak yaw rate 0), and a
    /// turning segment is selected at its own peak, not above it.
    #[test]
    fn a_peak_at_the_threshold_is_selected() {
        let straight = drive(1500, 1500);
        let every = SegmentOptions { min_peak_yaw_rate_rad_per_s: 0.0, ..Default::default() };
        let sel = select_segments(&straight, &every).expect("valid");
        assert!(!sel.all.is_empty() && sel.all.iter().all(|s| s.peak_yaw_rate_rad_per_s == 0.0), "{:?}", sel.all);
        assert_eq!(sel.selected, sel.all);
        let turning = drive(1500, 700);
        let all = select_segments(&turning, &every).expect("valid").all;
        let peak = all.iter().map(|s| s.peak_yaw_rate_rad_per_s).fold(0.0, f64::max);
        let at = |threshold: f64| {
            let opts = SegmentOptions { min_peak_yaw_rate_rad_per_s: threshold, ..Default::default() };
            select_segments(&turning, &opts).expect("valid").selected
        };
        let at_peak: Vec<Segment> =
            all.iter().copied().filter(|s| s.peak_yaw_rate_rad_per_s.to_bits() == peak.to_bits()).collect();
        assert!(!at_peak.is_empty());
        assert_eq!(at(peak), at_peak);
        assert!(at(peak.next_up()).is_empty());
    }

    #[test]
    fn segments_stay_within_parts() {
        let d = drive_with_parts(2000, 5000, vec![0..900, 900..2000]);
        for s in cut(&d, 0, 650, 100) {
            let p = d.parts().iter().find(|p| p.contains(&s.start)).expect("in a part");
            assert!(s.start + s.steps < p.end);
        }
    }

    #[test]
    fn invalid_options_name_the_field() {
        let e = SegmentOptions { stride_steps: 0, ..Default::default() }.validate().expect_err("bad");
        assert!(e.to_string().contains("`segment_stride`") && e.to_string().contains("stride_steps"), "{e}");
        let e = ValidationSegmentOptions { length_steps: 1, ..Default::default() }.validate().expect_err("bad");
        assert!(e.to_string().contains("`validation_length`"), "{e}");
        assert!(e.to_string().contains("2 steps"), "{e}");
    }

    #[test]
    fn counts_above_their_ceiling_are_refused_naming_the_field() {
        for (o, field) in [
            (SegmentOptions { offset_steps: usize::MAX, ..Default::default() }, "segment_offset"),
            (SegmentOptions { length_steps: usize::MAX, ..Default::default() }, "segment_length"),
            (SegmentOptions { stride_steps: MAX_STEPS + 1, ..Default::default() }, "segment_stride"),
        ] {
            let e = o.validate().expect_err("above the ceiling");
            assert!(matches!(e, Error::InvalidOption { field: f, .. } if f == field), "{e}");
            assert!(e.to_string().contains("ceiling of 10000000"), "{e}");
        }
        let v = ValidationSegmentOptions { offset_steps: usize::MAX, ..Default::default() };
        let e = v.validate().expect_err("above the ceiling");
        assert!(matches!(e, Error::InvalidOption { field: "validation_offset", .. }), "{e}");
        let v = ValidationSegmentOptions { length_steps: usize::MAX, ..Default::default() };
        assert!(matches!(v.validate(), Err(Error::InvalidOption { field: "validation_length", .. })));
        assert!(SegmentOptions { offset_steps: MAX_STEPS, ..Default::default() }.validate().is_ok());
    }

    #[test]
    fn cut_never_wraps_around() {
        let d = drive_with_parts(2000, 5000, vec![0..900, 900..2000]);
        assert!(cut(&d, usize::MAX, 650, 100).is_empty());
        assert!(cut(&d, usize::MAX - 1000, 650, 100).is_empty());
        assert!(cut(&d, 0, usize::MAX, 100).is_empty());
        // the last start's stride overflows: the cut stops there
        let s = cut(&d, 0, 650, usize::MAX);
        assert_eq!(s.iter().map(|s| s.start).collect::<Vec<_>>(), vec![0, 900]);
    }
}
