//! The heading derived from the track (a pose without `[pose.heading]`) as
//! the accepted pose samples arrive, with the arithmetic of the whole
//! import's `derive_heading`: the direction of the chord from half
//! `derive_heading_baseline_m` of travelled distance behind each sample to
//! as far ahead ([`Chord`]), held below `derive_heading_min_speed_m_per_s`
//! (the first one back-filled), unwrapped.
//!
//! A sample's heading is known once the track has gone half the baseline
//! further, or the chord's `span` of pose time has passed (the baseline over
//! the minimum speed, 2 s at the defaults; the baseline over
//! [`CHORD_SPEED_FLOOR_M_PER_S`](crate::io::import::pose::CHORD_SPEED_FLOOR_M_PER_S)
//! at most), whichever comes first: the look-ahead is bounded in time, and
//! so in samples by the pose's rate. The samples at the start also wait
//! until the vehicle first moves. The track behind is kept back to half
//! the baseline or the span before the oldest sample still waiting.
//!
//! The wait at the start is bounded: samples more than `max_hold_s` (pose
//! time) older than the newest one are released without a heading while
//! the vehicle has not moved yet; the caller makes their output samples
//! invalid. The samples still held when the vehicle first moves get the
//! whole import's back-filled heading.

use std::collections::VecDeque;

use crate::io::import::pose::{Chord, TrackPoint};

/// An accepted pose sample waiting for its heading: time (pose clock),
/// east, north.
type Sample = (f64, f64, f64);

/// The derived heading's state.
#[derive(Debug)]
pub(crate) struct TrackHeading {
    chord: Chord,
    /// Longest span of samples held before the vehicle first moves, s.
    max_hold_s: f64,
    /// The track the chords still to be figured read, oldest first.
    track: VecDeque<TrackPoint>,
    /// Index in `track` of the oldest sample whose chord is not figured yet
    /// (`track.len()` when all are).
    next: usize,
    /// Samples without a heading yet, oldest first: the first `leading`
    /// have a chord too slow for a heading, before the first motion; the
    /// others are still waiting for their chord.
    waiting: VecDeque<Sample>,
    leading: usize,
    /// The last direction (held through slow stretches), once it moved.
    held: Option<f64>,
    unwrap: crate::drive::Unwrap,
}

impl TrackHeading {
    pub(crate) fn new(min_speed: f64, baseline_m: f64, max_hold_s: f64) -> TrackHeading {
        TrackHeading {
            chord: Chord::new(baseline_m, min_speed),
            max_hold_s,
            track: VecDeque::new(),
            next: 0,
            waiting: VecDeque::new(),
            leading: 0,
            held: None,
            unwrap: Default::default(),
        }
    }

    /// Takes the next accepted sample; hands the samples whose heading is
    /// now known to `out` as `(t, x, y, ψ)`, and those released without a
    /// heading (before the first motion, beyond `max_hold_s`) to `released`.
    pub(crate) fn push(&mut self, s: Sample, out: &mut Vec<[f64; 4]>, released: &mut Vec<Sample>) {
        let d = self.track.back().map_or(0.0, |p| p.next_distance(s.1, s.2));
        let newest = TrackPoint { t: s.0, x: s.1, y: s.2, s: d };
        self.track.push_back(newest);
        self.waiting.push_back(s);
        while self.next < self.track.len() && self.chord.ends_ahead(&self.track[self.next], &newest) {
            self.figure_next(out);
        }
        while self.held.is_none()
            && self.leading > 0
            && self.waiting.front().is_some_and(|f| newest.t - f.0 > self.max_hold_s)
        {
            released.extend(self.waiting.pop_front());
            self.leading -= 1;
        }
        // The samples behind the second one that the oldest chord still to
        // be figured (and every later one) ends at are not read again.
        let c = self.track.get(self.next).copied().unwrap_or(newest);
        while self.next > 1 && self.track.len() > 2 && self.chord.ends_behind(&c, &self.track[1]) {
            self.track.pop_front();
            self.next -= 1;
        }
    }

    /// No more samples: the last ones get their heading.
    pub(crate) fn end(&mut self, out: &mut Vec<[f64; 4]>) {
        while self.next < self.track.len() {
            self.figure_next(out);
        }
        if self.held.is_none() {
            for _ in 0..self.leading {
                self.emit(0.0, out);
            }
            self.leading = 0;
        }
    }

    /// Figures the chord of the oldest sample still waiting for it, and
    /// hands on the samples whose heading it decides.
    fn figure_next(&mut self, out: &mut Vec<[f64; 4]>) {
        let track = &self.track;
        let dir = self.chord.direction(|k| track[k], track.len(), self.next);
        self.next += 1;
        match (dir, self.held) {
            (None, None) => self.leading += 1,
            (Some(h), None) => {
                self.held = Some(h);
                for _ in 0..=self.leading {
                    self.emit(h, out);
                }
                self.leading = 0;
            }
            (Some(h), Some(_)) => {
                self.held = Some(h);
                self.emit(h, out);
            }
            (None, Some(h)) => self.emit(h, out),
        }
    }

    /// The oldest waiting sample's heading is the direction `raw`, unwrapped.
    fn emit(&mut self, raw: f64, out: &mut Vec<[f64; 4]>) {
        let psi = self.unwrap.next(raw);
        if let Some((t, x, y)) = self.waiting.pop_front() {
            out.push([t, x, y, psi]);
        }
    }

    /// Samples held: those waiting for their heading, or the track kept for
    /// the chords, whichever are more.
    pub(crate) fn held(&self) -> usize {
        self.waiting.len().max(self.track.len())
    }

    /// The time of the oldest sample waiting for its heading.
    pub(crate) fn first_waiting(&self) -> Option<f64> {
        self.waiting.front().map(|s| s.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::import::pose::derive_heading;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The heading of `(t, x, y)` streamed sample by sample (nothing
    /// released).
    fn streamed(t: &[f64], x: &[f64], y: &[f64], min_speed: f64, baseline: f64) -> Vec<[f64; 4]> {
        let mut h = TrackHeading::new(min_speed, baseline, f64::INFINITY);
        let (mut out, mut released) = (Vec::new(), Vec::new());
        for k in 0..t.len() {
            h.push((t[k], x[k], y[k]), &mut out, &mut released);
        }
        assert!(released.is_empty());
        h.end(&mut out);
        out
    }

    fn assert_same(t: &[f64], x: &[f64], y: &[f64], min_speed: f64, baseline: f64) {
        let whole = derive_heading(t, x, y, min_speed, baseline);
        let out = streamed(t, x, y, min_speed, baseline);
        assert_eq!(out.len(), t.len());
        for (k, o) in out.iter().enumerate() {
            assert_eq!(o[0].to_bits(), t[k].to_bits());
            assert_eq!(o[3].to_bits(), whole[k].to_bits(), "sample {k}, baseline {baseline}, min speed {min_speed}");
        }
    }

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
        for baseline in [0.3, 1.0, 2.0, 7.0] {
            assert_same(&t, &x, &y, 1.0, baseline);
        }
    }

    /// Noisy positions (2 cm) at an uneven 20 Hz, slow, standing and
    /// turning: the streamed heading is the whole import's sample for
    /// sample, at several baselines and minimum speeds (0 included).
    #[test]
    fn the_streamed_heading_of_noisy_positions_is_the_whole_imports() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let noise = Normal::new(0.0, 0.02).expect("normal");
        let (mut t, mut x, mut y) = (Vec::new(), Vec::new(), Vec::new());
        let (mut tk, mut px, mut py, mut dir) = (0.0f64, 0.0f64, 0.0f64, 0.3f64);
        for k in 0..3000 {
            let dt = 0.05 * rng.random_range(0.8..1.2);
            let v = match k {
                0..200 | 1400..1700 => 0.0,
                200..800 => 2.0,
                800..1400 => 0.6,
                _ => 4.0,
            };
            dir += 0.4 * v * dt * (k as f64 / 300.0).sin();
            px += v * dir.cos() * dt;
            py += v * dir.sin() * dt;
            tk += dt;
            t.push(tk);
            x.push(px + noise.sample(&mut rng));
            y.push(py + noise.sample(&mut rng));
        }
        for (min_speed, baseline) in [(1.0, 2.0), (0.3, 2.0), (0.0, 2.0), (0.5, 0.05), (1.0, 10.0)] {
            assert_same(&t, &x, &y, min_speed, baseline);
        }
    }

    /// A standstill at the start longer than the hold: the oldest samples
    /// are released (the hold stays within `max_hold_s` and the wait for
    /// the track ahead), the others get the whole import's heading.
    #[test]
    fn a_long_standstill_at_the_start_is_held_for_at_most_the_hold() {
        let (n, still, dt, hold, baseline) = (5000, 4000, 0.1, 20.0, 2.0);
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
        let whole = derive_heading(&t, &x, &y, 1.0, baseline);
        let mut h = TrackHeading::new(1.0, baseline, hold);
        let (mut out, mut released) = (Vec::new(), Vec::new());
        let mut most = 0;
        for k in 0..n {
            h.push((t[k], x[k], y[k]), &mut out, &mut released);
            most = most.max(h.held());
        }
        h.end(&mut out);
        // The hold, and the wait for the track ahead: the chord's span,
        // the baseline over the minimum speed.
        let (span, ahead) = ((hold / dt).round() as usize, (baseline / 1.0 / dt).round() as usize);
        assert!((span..=span + ahead + 2).contains(&most), "held {most} samples: at most the hold and the span");
        assert_eq!(released.len() + out.len(), n);
        for (k, r) in released.iter().enumerate() {
            assert_eq!(r.0.to_bits(), t[k].to_bits());
        }
        let first = released.len();
        assert!(t[still] - t[first] <= hold + baseline + dt && t[still] - t[first - 1] > hold, "{}", t[first]);
        for (j, o) in out.iter().enumerate() {
            assert_eq!(o[0].to_bits(), t[first + j].to_bits());
            assert_eq!(o[3].to_bits(), whole[first + j].to_bits(), "sample {}", first + j);
        }
    }
}
