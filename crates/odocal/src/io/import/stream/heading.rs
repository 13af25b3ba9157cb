//! The heading derived from the track (a pose without `[pose.heading]`) as
//! the accepted pose samples arrive, with the arithmetic of the whole
//! import's `derive_heading`: the direction of motion between consecutive
//! samples (held below `derive_heading_min_speed_m_per_s`, the first one
//! back-filled), unwrapped, averaged back onto the samples. A sample's
//! heading is known once the next sample is in (the samples at the start
//! wait until the vehicle first moves).
//!
//! The wait at the start is bounded: samples more than `max_hold_s` (pose
//! time) older than the newest one are released without a heading while
//! the vehicle has not moved yet; the caller makes their output samples
//! invalid. The samples still held when the vehicle first moves get the
//! whole import's back-filled heading.

use std::collections::VecDeque;

/// An accepted pose sample waiting for its heading: time (pose clock),
/// east, north.
type Sample = (f64, f64, f64);

/// The derived heading's state.
#[derive(Debug)]
pub(crate) struct TrackHeading {
    min_speed: f64,
    /// Longest span of samples held before the vehicle first moves, s.
    max_hold_s: f64,
    /// Samples without a heading yet, oldest first.
    waiting: VecDeque<Sample>,
    /// The last sample received.
    last: Option<Sample>,
    /// Directions between consecutive samples received while the vehicle
    /// has not moved yet (all back-filled with the first moving one).
    leading: usize,
    /// The last direction (held through slow stretches), once it moved.
    held: Option<f64>,
    unwrap: crate::drive::Unwrap,
    /// The previous unwrapped direction.
    prev_mid: Option<f64>,
}

impl TrackHeading {
    pub(crate) fn new(min_speed: f64, max_hold_s: f64) -> TrackHeading {
        TrackHeading {
            min_speed,
            max_hold_s,
            waiting: VecDeque::new(),
            last: None,
            leading: 0,
            held: None,
            unwrap: Default::default(),
            prev_mid: None,
        }
    }

    /// Takes the next accepted sample; hands the samples whose heading is
    /// now known to `out` as `(t, x, y, ψ)`, and those released without a
    /// heading (before the first motion, beyond `max_hold_s`) to `released`.
    pub(crate) fn push(&mut self, s: Sample, out: &mut Vec<[f64; 4]>, released: &mut Vec<Sample>) {
        self.waiting.push_back(s);
        let Some(p) = self.last.replace(s) else { return };
        let (dx, dy) = (s.1 - p.1, s.2 - p.2);
        let moving = (dx.hypot(dy) / (s.0 - p.0) > self.min_speed).then(|| dy.atan2(dx));
        match (moving, self.held) {
            (None, None) => {
                self.leading += 1;
                // Each released sample takes the direction after it along.
                while self.leading > 0 && self.waiting.front().is_some_and(|f| s.0 - f.0 > self.max_hold_s) {
                    released.extend(self.waiting.pop_front());
                    self.leading -= 1;
                }
            }
            (Some(h), None) => {
                self.held = Some(h);
                for _ in 0..self.leading {
                    self.mid(h, out);
                }
                self.leading = 0;
                self.mid(h, out);
            }
            (Some(h), Some(_)) => {
                self.held = Some(h);
                self.mid(h, out);
            }
            (None, Some(h)) => self.mid(h, out),
        }
    }

    /// No more samples: the last ones get their heading.
    pub(crate) fn end(&mut self, out: &mut Vec<[f64; 4]>) {
        if self.held.is_none() {
            for _ in 0..self.leading {
                self.mid(0.0, out);
            }
            self.leading = 0;
        }
        if let Some((t, x, y)) = self.waiting.pop_front() {
            out.push([t, x, y, self.prev_mid.unwrap_or(0.0)]);
        }
    }

    /// The next direction between samples (filled, before unwrapping): the
    /// oldest waiting sample's heading is the mean of it and the one before.
    fn mid(&mut self, raw: f64, out: &mut Vec<[f64; 4]>) {
        let u = self.unwrap.next(raw);
        let psi = match self.prev_mid.replace(u) {
            None => u,
            Some(before) => 0.5 * (before + u),
        };
        if let Some((t, x, y)) = self.waiting.pop_front() {
            out.push([t, x, y, psi]);
        }
    }

    /// Samples waiting for their heading.
    pub(crate) fn held(&self) -> usize {
        self.waiting.len()
    }

    /// The time of the oldest sample waiting for its heading.
    pub(crate) fn first_waiting(&self) -> Option<f64> {
        self.waiting.front().map(|s| s.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The streamed heading is the whole import's, a standstill at the
    /// start and in the middle and a wrap included.
    #[test]
    fn the_streamed_heading_is_the_whole_imports() {
        let n = 400;
        let (mut t, mut x, mut y) = (Vec::new(), Vec::new(), Vec::new());
        let (mut px, mut py) = (0.0f64, 0.0f64);
        for k in 0..n {
            let moving = !(k < 30 || (200..240).contains(&k));
            let dir = 0.05 * k as f64;
            if moving {
                px += 0.5 * dir.cos();
                py += 0.5 * dir.sin();
            }
            t.push(k as f64 * 0.1);
            x.push(px);
            y.push(py);
        }
        let whole = crate::io::import::pose::derive_heading(&t, &x, &y, 1.0);
        let mut h = TrackHeading::new(1.0, 10.0);
        let (mut out, mut released) = (Vec::new(), Vec::new());
        for k in 0..n {
            h.push((t[k], x[k], y[k]), &mut out, &mut released);
        }
        assert!(released.is_empty());
        h.end(&mut out);
        assert_eq!(out.len(), n);
        for (k, o) in out.iter().enumerate() {
            assert_eq!(o[0].to_bits(), t[k].to_bits());
            assert_eq!(o[3].to_bits(), whole[k].to_bits(), "sample {k}");
        }
    }

    /// A standstill at the start longer than the hold: the oldest samples
    /// are released (the hold stays within `max_hold_s`), the others get
    /// the whole import's heading.
    #[test]
    fn a_long_standstill_at_the_start_is_held_for_at_most_the_hold() {
        let (n, still, dt, hold) = (5000, 4000, 0.1, 20.0);
        let (mut t, mut x, mut y) = (Vec::new(), Vec::new(), Vec::new());
        let (mut px, mut py) = (3.0f64, -2.0f64);
        for k in 0..n {
            if k >= still {
                let dir = 0.01 * k as f64;
                px += 0.5 * dir.cos();
                py += 0.5 * dir.sin();
            }
            t.push(k as f64 * dt);
            x.push(px);
            y.push(py);
        }
        let whole = crate::io::import::pose::derive_heading(&t, &x, &y, 1.0);
        let mut h = TrackHeading::new(1.0, hold);
        let (mut out, mut released) = (Vec::new(), Vec::new());
        let mut most = 0;
        for k in 0..n {
            h.push((t[k], x[k], y[k]), &mut out, &mut released);
            most = most.max(h.held());
        }
        h.end(&mut out);
        let span = (hold / dt).round() as usize;
        assert!((span..=span + 2).contains(&most), "held {most} samples: at most the hold");
        assert_eq!(released.len() + out.len(), n);
        for (k, r) in released.iter().enumerate() {
            assert_eq!(r.0.to_bits(), t[k].to_bits());
        }
        let first = released.len();
        assert!(t[still - 1] - t[first] <= hold && t[still - 1] - t[first - 1] > hold);
        for (j, o) in out.iter().enumerate() {
            assert_eq!(o[0].to_bits(), t[first + j].to_bits());
            assert_eq!(o[3].to_bits(), whole[first + j].to_bits(), "sample {}", first + j);
        }
    }
}
