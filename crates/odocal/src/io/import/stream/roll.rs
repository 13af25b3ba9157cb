//! The road bank's roll as the two antennas' rows arrive, with the
//! arithmetic of [`bank::roll`]: each accepted
//! left sample is paired with the right antenna at its stamp as soon as the
//! right antenna's rows decide the pairing, pairs beyond `max_roll_deg` are
//! dropped and counted, and the roll goes onto the wheel clock as a track.
//!
//! The whole drive's checks of the pairs (the median separation against
//! `baseline_m`, the glitch fraction) run on the warm-up prefix; the glitch
//! fraction is judged again over all pairs when the drive ends.

use std::collections::VecDeque;
use std::path::{Path, PathBuf};

use super::super::bank::{self, SAME_EPOCH_S};
use super::super::limits::{echo_num, within};
use super::super::manifest::{BankSpec, Manifest};
use super::condition::Row;
use super::tracks::Track;
use crate::error::{Error, Result};

/// The manifest key of the bank table.
const KEY: &str = "lateral_acceleration.bank";

/// One antenna's stream: its name, file and the columns of its rows.
#[derive(Debug)]
struct Antenna {
    name: String,
    side: &'static str,
    path: PathBuf,
    /// Columns of lat, lon, alt in the rows.
    cols: [usize; 3],
    quality: Option<usize>,
    ended: bool,
}

impl Antenna {
    /// `[lat, lon, alt]` of an accepted row; `None` for a rejected one; the
    /// whole import's error for a latitude, longitude or altitude out of range.
    fn accepted(&self, b: &BankSpec, row: &Row) -> Result<Option<[f64; 3]>> {
        if let (Some(q), Some(c)) = (&b.quality, self.quality) {
            if !q.accepts(row.values[c]) {
                return Ok(None);
            }
        }
        let [lat, lon, alt] = self.cols.map(|c| row.values[c]);
        for (col, v, max, key) in [(&b.lat, lat, 90.0, "lat"), (&b.lon, lon, 180.0, "lon")] {
            if !within(v, max) {
                let reason = format!(
                    "{KEY}.{key} ({} antenna): {} is outside ±{max}°; the column must hold WGS84 degrees",
                    self.side,
                    echo_num(v)
                );
                return Err(row_error(&self.path, row, col, reason));
            }
        }
        if !alt.is_finite() {
            let reason = format!("{KEY}.alt ({} antenna): altitude is not finite", self.side);
            return Err(row_error(&self.path, row, &b.alt, reason));
        }
        Ok(Some([lat, lon, alt]))
    }
}

/// The error about `row` of the file at `path`: its line where it has one,
/// else its time.
fn row_error(path: &Path, row: &Row, column: &str, reason: String) -> Error {
    match row.line {
        Some(line) => Error::Csv { path: path.to_path_buf(), line, column: Some(column.to_string()), reason },
        None => Error::InvalidDrive {
            context: path.display().to_string(),
            reason: format!("row at t = {:.3} s, column '{column}': {reason}", row.t),
        },
    }
}

/// The roll of the streamed import.
#[derive(Debug)]
pub(crate) struct RollBuilder {
    b: BankSpec,
    left: Antenna,
    right: Antenna,
    max_sin: f64,
    max_gap_s: f64,
    offset_s: f64,
    /// Accepted left samples waiting for the right antenna: time, altitude.
    pending: VecDeque<(f64, f64)>,
    /// Accepted right samples from the one before the last paired left
    /// stamp on: times, and `[lat, lon, alt]`.
    right_t: Vec<f64>,
    right_v: Vec<[f64; 3]>,
    /// The time of the right antenna's last row, accepted or not.
    right_last_row: Option<f64>,
    /// The time of the left antenna's last row, accepted or not.
    left_last_row: Option<f64>,
    /// Pairs (both antennas at a left stamp), and those beyond the roll
    /// limit (with the first: antenna time, sin φ).
    pub pairs: usize,
    pub beyond: usize,
    pub first_beyond: Option<(f64, f64)>,
    /// The roll, rad, on the wheel clock.
    pub track: Track<1>,
}

impl RollBuilder {
    /// The roll of bank `b` of `m`, moved by the clock offset `offset_s`;
    /// `index(stream, column)` finds a column in its stream's rows.
    pub(crate) fn new(m: &Manifest, b: &BankSpec, offset_s: f64, index: impl Fn(&str, &str) -> usize) -> RollBuilder {
        let antenna = |name: &str, side| Antenna {
            name: name.to_string(),
            side,
            path: m.base_dir().join(m.streams[name].source.file()),
            cols: [index(name, &b.lat), index(name, &b.lon), index(name, &b.alt)],
            quality: b.quality.as_ref().map(|q| index(name, &q.column)),
            ended: false,
        };
        RollBuilder {
            left: antenna(&b.left, "left"),
            right: antenna(&b.right, "right"),
            max_sin: b.max_roll_deg.to_radians().sin(),
            max_gap_s: m.output.max_gap_s,
            offset_s,
            b: b.clone(),
            pending: VecDeque::new(),
            right_t: Vec::new(),
            right_v: Vec::new(),
            right_last_row: None,
            left_last_row: None,
            pairs: 0,
            beyond: 0,
            first_beyond: None,
            track: Track::new(),
        }
    }

    /// Takes a conditioned row of stream `name` (either antenna's, or both
    /// when one stream carries both).
    pub(crate) fn push(&mut self, name: &str, row: &Row) -> Result<()> {
        if name == self.left.name {
            if let Some(v) = self.left.accepted(&self.b, row)? {
                self.pending.push_back((row.t, v[2]));
            }
            self.left_last_row = Some(row.t);
        }
        if name == self.right.name {
            if let Some(v) = self.right.accepted(&self.b, row)? {
                self.right_t.push(row.t);
                self.right_v.push(v);
            }
            self.right_last_row = Some(row.t);
        }
        self.pair_ready();
        // Left samples to come are later than the left antenna's last row
        // (through a stretch of rejected left samples too).
        if let Some(next) = self.pending.front().map(|p| p.0).or(self.left_last_row) {
            let j = self.right_t.partition_point(|x| *x < next);
            if j > 64 {
                self.right_t.drain(..j - 1);
                self.right_v.drain(..j - 1);
            }
        }
        Ok(())
    }

    /// Stream `name` has ended; the roll's track ends with both antennas.
    pub(crate) fn end_stream(&mut self, name: &str) {
        for a in [&mut self.left, &mut self.right] {
            if a.name == name {
                a.ended = true;
            }
        }
        self.pair_ready();
        if self.left.ended && self.right.ended && self.pending.is_empty() {
            self.track.ended = true;
        }
    }

    /// True when the right antenna's samples so far decide the pairing at
    /// left stamp `t` ([`bank::at`]): it has ended, or has an accepted
    /// sample at or after `t`, or a row so far after `t` and its last
    /// accepted sample that no later one can be paired or interpolated at `t`.
    fn decided(&self, t: f64) -> bool {
        let last = self.right_t.last().copied();
        if self.right.ended || last.is_some_and(|l| l >= t) {
            return true;
        }
        self.right_last_row.is_some_and(|r| r >= t + SAME_EPOCH_S && last.is_none_or(|l| r - l > self.max_gap_s))
    }

    /// Pairs the waiting left samples the right antenna decides, in order.
    fn pair_ready(&mut self) {
        while let Some(&(t, alt)) = self.pending.front() {
            if !self.decided(t) {
                return;
            }
            self.pending.pop_front();
            if let Some(r) = bank::at(&self.right_t, &self.right_v, t, self.max_gap_s) {
                self.pairs += 1;
                let s = bank::sin_roll(alt, r[2], self.b.height_offset_m, self.b.baseline_m);
                if within(s, self.max_sin) {
                    self.track.push(t, self.offset_s, [s.asin()], self.max_gap_s, "roll (both antennas accepted)");
                } else {
                    self.beyond += 1;
                    self.first_beyond.get_or_insert((t, s));
                }
            }
            // Later left stamps need the right samples from the last before `t` on.
            let j = self.right_t.partition_point(|x| *x < t);
            if j > 64 {
                self.right_t.drain(..j - 1);
                self.right_v.drain(..j - 1);
            }
        }
    }

    /// The longest span of antenna time held: the left samples waiting for
    /// the right antenna, the right samples waiting for left ones, s.
    pub(crate) fn held_span_s(&self) -> f64 {
        let left = match (self.pending.front(), self.pending.back()) {
            (Some(a), Some(b)) => b.0 - a.0,
            _ => 0.0,
        };
        let right = match (self.right_t.first(), self.right_t.last()) {
            (Some(a), Some(b)) => b - a,
            _ => 0.0,
        };
        left.max(right)
    }

    /// Samples held: waiting left ones, right ones and the track's.
    pub(crate) fn held(&self) -> usize {
        self.pending.len() + self.right_t.len() + self.track.t.len()
    }
}
