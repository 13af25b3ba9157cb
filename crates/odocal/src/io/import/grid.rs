//! The output grid: the common time span of the streams, which output
//! samples are valid (no stream gap, accepted pose quality), the continuous
//! parts and gaps, and where the reference pose was really measured.

use std::ops::Range;

use super::report::{GapRecord, PartRecord};
use crate::error::{Error, Result};
use crate::io::import::manifest::Manifest;

/// A time interval that invalidates output samples, with its reason.
#[derive(Debug, Clone)]
pub(crate) struct BadInterval {
    /// Start, s.
    pub from: f64,
    /// End, s.
    pub to: f64,
    /// Why.
    pub reason: String,
}

/// Intervals between consecutive stamps longer than `max_gap`.
pub(crate) fn gaps_of(t: &[f64], max_gap: f64, what: &str) -> Vec<BadInterval> {
    t.windows(2)
        .filter(|w| w[1] - w[0] > max_gap)
        .map(|w| BadInterval { from: w[0], to: w[1], reason: format!("{what} gap of {:.2} s", w[1] - w[0]) })
        .collect()
}

/// Marks grid samples invalid: interval `[g, g+h]` (when `interval`) or the
/// point `g` overlapping a bad interval; records the first reason.
pub(crate) fn mark(valid: &mut [Option<String>], grid_start: f64, h: f64, bad: &[BadInterval], interval: bool) {
    let n = valid.len();
    for b in bad {
        let (from, to) = (b.from, b.to);
        let lo = (((from - grid_start) / h).floor() as i64 - 1).max(0) as usize;
        let hi = ((((to - grid_start) / h).ceil() as i64) + 1).clamp(0, n as i64) as usize;
        for (k, v) in valid.iter_mut().enumerate().take(hi).skip(lo) {
            let g = grid_start + k as f64 * h;
            let hit = if interval { g < to && g + h > from } else { g > from && g < to };
            if hit && v.is_none() {
                *v = Some(b.reason.clone());
            }
        }
    }
}

/// A stream's time span, named for messages.
#[derive(Debug, Clone)]
pub(crate) struct Span {
    /// E.g. `streams.encoders`.
    pub name: String,
    /// First time, s.
    pub start: f64,
    /// Last time, s.
    pub end: f64,
}

impl Span {
    /// The span of the stamps `t` (not empty).
    pub(crate) fn of(name: &str, t: &[f64]) -> Span {
        Span { name: name.to_string(), start: t[0], end: t[t.len() - 1] }
    }
}

/// The common span `[latest start, earliest end]` of `spans`, or the error
/// naming the two streams that do not overlap, with their spans.
pub(crate) fn common_span(m: &Manifest, spans: &[Span], h: f64) -> Result<(f64, f64)> {
    let latest_start = spans.iter().max_by(|a, b| a.start.total_cmp(&b.start));
    let earliest_end = spans.iter().min_by(|a, b| a.end.total_cmp(&b.end));
    match (latest_start, earliest_end) {
        (Some(a), Some(b)) if a.start + 2.0 * h < b.end => Ok((a.start, b.end)),
        (Some(a), Some(b)) => Err(Error::Manifest {
            path: m.path.clone(),
            reason: format!(
                "the streams do not overlap in time: {}: no time overlap with {}: t = {:.3} … {:.3} s vs \
                 {:.3} … {:.3} s; check time_column, time_unit and time_offset_s",
                a.name, b.name, a.start, a.end, b.start, b.end
            ),
        }),
        _ => Err(m.error("streams", "no streams")),
    }
}

/// The parts and gaps of a grid.
#[derive(Debug, Clone)]
pub(crate) struct Parts {
    /// Runs of invalid samples, with reasons.
    pub gaps: Vec<GapRecord>,
    /// Runs of valid samples, kept and dropped.
    pub parts: Vec<PartRecord>,
    /// The kept sample ranges (never empty).
    pub kept: Vec<Range<usize>>,
}

/// The uniform output grid `start + k·h`, `k < n`, and the validity of each
/// sample (`Some(reason)` when invalid).
#[derive(Debug, Clone)]
pub(crate) struct Grid {
    /// Time of sample 0, s (the drive's time origin).
    pub start: f64,
    /// Output step, s.
    pub h: f64,
    /// The sample times, s.
    pub t: Vec<f64>,
    /// Why each sample is invalid, `None` when it is valid.
    pub invalid: Vec<Option<String>>,
}

impl Grid {
    /// The grid over `[start, end)`, all samples valid.
    pub(super) fn new(start: f64, end: f64, h: f64) -> Grid {
        let n = ((end - start) / h).floor() as usize;
        super::limits::note_grid(n);
        Grid { start, h, t: (0..n).map(|k| start + k as f64 * h).collect(), invalid: vec![None; n] }
    }

    /// Samples.
    pub(super) fn len(&self) -> usize {
        self.t.len()
    }

    /// Invalidates the samples overlapping `bad` (intervals `[g, g+h]` when
    /// `interval`, else points).
    pub(super) fn mark(&mut self, bad: &[BadInterval], interval: bool) {
        mark(&mut self.invalid, self.start, self.h, bad, interval);
    }

    /// The continuous parts (runs of valid samples) and gaps (runs of
    /// invalid ones); parts shorter than `min_part_s` are dropped. `hint`
    /// ends the error when no part is kept.
    pub(super) fn parts(&self, m: &Manifest, hint: &str) -> Result<Parts> {
        let (n, h, o) = (self.len(), self.h, &m.output);
        let mut runs: Vec<(Range<usize>, bool)> = Vec::new();
        let mut k = 0;
        while k < n {
            let ok = self.invalid[k].is_none();
            let s0 = k;
            while k < n && self.invalid[k].is_none() == ok {
                k += 1;
            }
            runs.push((s0..k, ok));
        }
        let min_samples = ((o.min_part_s / h).ceil() as usize).max(2);
        let mut gaps = Vec::new();
        let mut parts = Vec::new();
        let mut kept = Vec::new();
        for (r, ok) in &runs {
            if *ok {
                let keep = r.len() >= min_samples;
                parts.push(PartRecord::new(r.clone(), h, keep, o.min_part_s));
                if keep {
                    kept.push(r.clone());
                }
            } else {
                let mut reasons: Vec<String> = Vec::new();
                for v in self.invalid[r.clone()].iter().flatten() {
                    if !reasons.contains(v) {
                        reasons.push(v.clone());
                    }
                }
                gaps.push(GapRecord { t_start_s: r.start as f64 * h, t_end_s: r.end as f64 * h, reasons });
            }
        }
        if kept.is_empty() {
            return Err(Error::InvalidDrive {
                context: m.path.display().to_string(),
                reason: format!(
                    "no continuous part of at least output.min_part_s = {} s ({} parts, {} gaps); lower \
                     min_part_s or check the gaps{hint}",
                    crate::drive::echo_num(o.min_part_s),
                    parts.len(),
                    gaps.len()
                ),
            });
        }
        Ok(Parts { gaps, parts, kept })
    }

    /// Which samples carry a real reference sample: the output sample
    /// nearest to each pose sample at times `pose_t` (|t_pose − t_k| ≤ h/2;
    /// a pose sample exactly half-way marks the earlier one). Linear
    /// interpolation reproduces a measurement exactly only at its own time,
    /// so the nearest output sample is the one within h/2 of it; every
    /// other sample is interpolated between measurements.
    pub(super) fn measured(&self, pose_t: &[f64]) -> Vec<bool> {
        let mut mask = vec![false; self.len()];
        for &tp in pose_t {
            let f = (tp - self.start) / self.h;
            let k = (f - 0.5).ceil();
            if k >= 0.0 && (k as usize) < mask.len() {
                mask[k as usize] = true;
            }
        }
        mask
    }
}
