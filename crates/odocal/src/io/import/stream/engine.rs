//! The output grid of the streamed import once the clock offset is known:
//! the conditioned rows go into their tracks (the pose moved onto the wheel
//! clock), and each output sample is computed as soon as every track holds
//! the samples it depends on, with the whole import's arithmetic.

use std::collections::VecDeque;
use std::path::PathBuf;

use super::super::grid::{self, BadInterval};
use super::super::manifest::{LateralAccelerationSpec, Manifest, SideslipSpec};
use super::condition::Row;
use super::corrupt::CorruptFilter;
use super::parts::{Assembler, GridSample};
use super::roll::RollBuilder;
use super::tracks::{PoseBuilder, Rotation, Track};
use crate::error::Result;
use crate::model::{kinematics, Input, Theta};

/// A one-column track fed from a stream's rows: an IMU's integrated a_y or
/// a sideslip.
#[derive(Debug)]
pub(crate) struct Column {
    pub stream: String,
    pub track: Track<1>,
    col: usize,
    factor: f64,
    /// Integrated (an IMU's a_y) or as it is (a sideslip).
    integrate: bool,
    prev: Option<(f64, f64)>,
    acc: f64,
    /// Its gaps invalidate output samples (it is neither the wheel nor the
    /// pose stream); over intervals (IMU) or at points (sideslip).
    pub extra: bool,
    what: String,
}

impl Column {
    fn push(&mut self, row: &Row, max_gap_s: f64) {
        let v = self.factor * row.values[self.col];
        let y = if self.integrate {
            if let Some((tp, vp)) = self.prev {
                self.acc += 0.5 * (v + vp) * (row.t - tp);
            }
            self.prev = Some((row.t, v));
            self.acc
        } else {
            v
        };
        self.track.push(row.t, 0.0, [y], max_gap_s, &self.what);
    }
}

/// The streamed import after the warm-up.
#[derive(Debug)]
pub(crate) struct Engine {
    h: f64,
    theta0: Theta,
    pub offset_s: f64,
    wheel_path: PathBuf,
    pose_path: PathBuf,
    pub wheel: Track<2>,
    rot: [Rotation; 2],
    /// The wheels on their raw stamps, for the jitter report, when the
    /// wheel stream is de-jittered.
    raw: Option<(Track<2>, [Rotation; 2])>,
    pub corrupt: CorruptFilter,
    pub pose: Track<3>,
    pose_b: PoseBuilder,
    pub imu: Option<Column>,
    pub side: Option<Column>,
    /// The road bank's roll, when the manifest corrects a_y for it.
    pub roll: Option<RollBuilder>,
    /// Wheel-clock time of grid index 0, once every track has started.
    pub start: Option<f64>,
    /// Grid indices the pose was measured at, not yet passed.
    marks: VecDeque<usize>,
    /// The next grid index.
    k: usize,
    /// Grid samples in all, once every stream has ended.
    pub n_end: Option<usize>,
    pub asm: Option<Assembler>,
}

impl Engine {
    /// The engine of `m`, the pose moved by `offset_s`, a heading derived
    /// from the track held for at most `max_hold_s` before the first
    /// motion; `index(stream, column)` finds a column in its stream's rows.
    pub(crate) fn new(
        m: &Manifest,
        h: f64,
        offset_s: f64,
        max_hold_s: f64,
        index: impl Fn(&str, &str) -> usize,
    ) -> Engine {
        let w = &m.wheels;
        let column = |stream: &str, col: &str, factor: f64, integrate: bool, what: String| Column {
            stream: stream.to_string(),
            track: Track::new(),
            col: index(stream, col),
            factor,
            integrate,
            prev: None,
            acc: 0.0,
            extra: stream != m.wheels.stream && stream != m.pose.stream,
            what,
        };
        let imu = match &m.lateral_acceleration {
            LateralAccelerationSpec::Imu { stream, column: c, sign } => {
                Some(column(stream, c, *sign, true, format!("{stream} stream")))
            }
            _ => None,
        };
        let side = match &m.sideslip {
            SideslipSpec::Column { stream, column: c, unit, sign } => {
                Some(column(stream, c, sign * unit.radians(), false, format!("{stream} stream")))
            }
            SideslipSpec::Zero => None,
        };
        let roll = m.lateral_acceleration.bank().map(|b| RollBuilder::new(m, b, offset_s, &index));
        let base = m.base_dir();
        let rotations = || {
            [
                Rotation::new(m, &w.rear_left, index(&w.stream, &w.rear_left.column), "wheels.rear_left"),
                Rotation::new(m, &w.rear_right, index(&w.stream, &w.rear_right.column), "wheels.rear_right"),
            ]
        };
        Engine {
            h,
            theta0: m.output.theta0(),
            offset_s,
            wheel_path: base.join(m.streams[&w.stream].source.file()),
            pose_path: base.join(m.streams[&m.pose.stream].source.file()),
            wheel: Track::new(),
            rot: rotations(),
            raw: m.streams[&w.stream].nominal_rate_hz.map(|_| (Track::new(), rotations())),
            corrupt: CorruptFilter::new(m, rotations()),
            pose: Track::new(),
            pose_b: PoseBuilder::new(m, max_hold_s, |c| index(&m.pose.stream, c)),
            imu,
            side,
            roll,
            start: None,
            marks: VecDeque::new(),
            k: 0,
            n_end: None,
            asm: None,
        }
    }

    /// Takes a conditioned row of stream `name`.
    pub(crate) fn push(&mut self, m: &Manifest, name: &str, row: &Row) -> Result<()> {
        let max_gap = m.output.max_gap_s;
        if name == m.wheels.stream {
            let mut kept = Vec::new();
            self.corrupt.push(&self.wheel_path, row.clone(), &mut kept)?;
            self.push_wheels(m, kept)?;
        }
        if name == m.pose.stream {
            let before = self.pose.t.len();
            self.pose_b.push(m, &self.pose_path, row, self.offset_s, &mut self.pose)?;
            self.mark_from(before);
        }
        for c in [self.imu.as_mut(), self.side.as_mut()].into_iter().flatten() {
            if c.stream == name {
                c.push(row, max_gap);
            }
        }
        if let Some(r) = self.roll.as_mut() {
            r.push(name, row)?;
        }
        Ok(())
    }

    /// The wheel rows kept by the corrupt-row filter into the wheel track.
    fn push_wheels(&mut self, m: &Manifest, kept: Vec<Row>) -> Result<()> {
        for mut row in kept {
            let l = self.rot[0].next(&self.wheel_path, &row)?;
            let r = self.rot[1].next(&self.wheel_path, &row)?;
            self.wheel.push(row.t, 0.0, [l, r], m.output.max_gap_s, "wheel");
            if let Some((track, rot)) = self.raw.as_mut() {
                row.t = row.t_raw;
                let l = rot[0].next(&self.wheel_path, &row)?;
                let r = rot[1].next(&self.wheel_path, &row)?;
                track.push(row.t, 0.0, [l, r], f64::INFINITY, "wheel");
            }
        }
        Ok(())
    }

    /// Stream `name` has ended: its tracks end (the wheel rows still
    /// waiting for the corrupt-row decision are decided first).
    pub(crate) fn end_stream(&mut self, m: &Manifest, name: &str) -> Result<()> {
        if name == m.wheels.stream && !self.wheel.ended {
            let mut kept = Vec::new();
            self.corrupt.end(&mut kept);
            self.push_wheels(m, kept)?;
            self.wheel.ended = true;
            if let Some((track, _)) = self.raw.as_mut() {
                track.ended = true;
            }
        }
        if name == m.pose.stream && !self.pose.ended {
            let before = self.pose.t.len();
            self.pose_b.end(m, self.offset_s, &mut self.pose);
            self.mark_from(before);
            self.pose.ended = true;
        }
        for c in [self.imu.as_mut(), self.side.as_mut()].into_iter().flatten() {
            if c.stream == name {
                c.track.ended = true;
            }
        }
        if let Some(r) = self.roll.as_mut() {
            r.end_stream(name);
        }
        Ok(())
    }

    /// Pose samples waiting for their derived heading.
    pub(crate) fn pose_held(&self) -> usize {
        self.pose_b.held()
    }

    /// The longest span of stream time any track holds, s (the wheel
    /// track's while the pose waits for a stream behind, and so on).
    pub(crate) fn held_span_s(&self) -> f64 {
        fn span<const N: usize>(t: &Track<N>) -> f64 {
            match (t.t.front(), t.t.back()) {
                (Some(a), Some(b)) => b - a,
                _ => 0.0,
            }
        }
        let mut most = span(&self.wheel).max(span(&self.pose));
        for c in [self.imu.as_ref(), self.side.as_ref()].into_iter().flatten() {
            most = most.max(span(&c.track));
        }
        if let Some(r) = &self.roll {
            most = most.max(span(&r.track)).max(r.held_span_s());
        }
        most
    }

    /// Marks the pose samples of the track from index `before` on.
    fn mark_from(&mut self, before: usize) {
        let new: Vec<f64> = self.pose.t.iter().skip(before).copied().collect();
        for tp in new {
            self.mark(tp);
        }
    }

    /// Marks the grid sample nearest to a pose sample at `tp` (wheel clock).
    fn mark(&mut self, tp: f64) {
        let Some(start) = self.start else { return };
        let f = (tp - start) / self.h;
        let k = (f - 0.5).ceil();
        if k >= 0.0 && self.marks.back() != Some(&(k as usize)) {
            self.marks.push_back(k as usize);
        }
    }

    fn tracks(&self) -> impl Iterator<Item = (&str, &Track<1>)> {
        [self.imu.as_ref(), self.side.as_ref()].into_iter().flatten().map(|c| (c.stream.as_str(), &c.track))
    }

    /// The spans of the tracks (the pose's after the clock offset), named
    /// as the whole import names them, once every track has a sample.
    pub(crate) fn spans(&self, m: &Manifest) -> Option<Vec<grid::Span>> {
        let (w, p) = (&m.wheels.stream, &m.pose.stream);
        let span = |name: String, t: &Track<2>| Some(grid::Span { name, start: t.first?, end: t.last()? });
        let mut spans = vec![
            span(format!("streams.{w}"), &self.wheel)?,
            grid::Span {
                name: format!("streams.{p} (pose, after the clock offset)"),
                start: self.pose.first?,
                end: self.pose.last()?,
            },
        ];
        for (name, t) in self.tracks() {
            if name != w && name != p && !spans.iter().any(|s| s.name == format!("streams.{name}")) {
                spans.push(grid::Span { name: format!("streams.{name}"), start: t.first?, end: t.last()? });
            }
        }
        if let Some(r) = &self.roll {
            spans.push(grid::Span {
                name: "lateral_acceleration.bank (roll, both antennas accepted, after the clock offset)".into(),
                start: r.track.first?,
                end: r.track.last()?,
            });
        }
        Some(spans)
    }

    /// Starts the grid once every track has a sample: its origin is the
    /// latest start, and the pose samples so far are marked.
    pub(crate) fn try_start(&mut self, m: &Manifest) {
        if self.start.is_some() {
            return;
        }
        let Some(spans) = self.spans(m) else { return };
        let Some(latest) = spans.iter().max_by(|a, b| a.start.total_cmp(&b.start)) else { return };
        self.start = Some(latest.start);
        self.asm = Some(Assembler::new(m, self.h, latest.start));
        let pose_t: Vec<f64> = self.pose.t.iter().copied().collect();
        for tp in pose_t {
            self.mark(tp);
        }
    }

    /// True when every track holds what output time `q` depends on (false
    /// once every track has ended: the end of the grid decides then).
    fn ready(&self, q: f64) -> bool {
        let roll = self.roll.as_ref().map(|r| &r.track);
        let all_ended =
            self.wheel.ended && self.pose.ended && self.tracks().all(|(_, t)| t.ended) && roll.is_none_or(|t| t.ended);
        !all_ended
            && self.wheel.covers(q)
            && self.raw.as_ref().is_none_or(|(t, _)| t.covers(q))
            && self.pose.covers(q)
            && self.tracks().all(|(_, t)| t.covers(q))
            && roll.is_none_or(|t| t.covers(q))
    }

    /// Computes and assembles every output sample whose inputs are in.
    pub(crate) fn step(&mut self, m: &Manifest) -> Result<()> {
        let (Some(start), h) = (self.start, self.h) else { return Ok(()) };
        // Rows before the next output time that no output uses (those
        // before the grid's origin, on a stream that starts early).
        self.prune(start + self.k as f64 * h);
        loop {
            let k = self.k;
            if self.n_end.is_some_and(|n| k >= n) {
                return Ok(());
            }
            let g = start + k as f64 * h;
            if self.n_end.is_none() && !self.ready(g + 2.0 * h) {
                return Ok(());
            }
            let s = self.sample(m, k, g);
            if let Some(a) = self.asm.as_mut() {
                a.push(m, s)?;
            }
            self.k += 1;
            self.prune(start + self.k as f64 * h);
        }
    }

    /// Drops what no output at or after `next` uses.
    fn prune(&mut self, next: f64) {
        let h = self.h;
        self.wheel.prune(next, h);
        if let Some((t, _)) = self.raw.as_mut() {
            t.prune(next, h);
        }
        self.pose.prune(next, h);
        for c in [self.imu.as_mut(), self.side.as_mut()].into_iter().flatten() {
            c.track.prune(next, h);
        }
        if let Some(r) = self.roll.as_mut() {
            r.track.prune(next, h);
        }
    }

    /// Output sample `k` at wheel-clock time `g`.
    fn sample(&mut self, m: &Manifest, k: usize, g: f64) -> GridSample {
        let h = self.h;
        let e = g + h;
        let mut invalid = first_hit(&self.wheel.bad, g, h, true);
        if invalid.is_none() {
            invalid = first_hit(&self.pose.bad, g, h, false);
        }
        if let (None, Some(r)) = (&invalid, &self.roll) {
            invalid = first_hit(&r.track.bad, g, h, false);
        }
        for c in [self.imu.as_ref(), self.side.as_ref()].into_iter().flatten() {
            if invalid.is_none() && c.extra {
                invalid = first_hit(&c.track.bad, g, h, c.integrate);
            }
        }
        let n_rl = (self.wheel.at(e, 0) - self.wheel.at(g, 0)) / h;
        let n_rr = (self.wheel.at(e, 1) - self.wheel.at(g, 1)) / h;
        let raw = self.raw.as_ref().map(|(t, _)| [0, 1].map(|i| (t.at(e, i) - t.at(g, i)) / h));
        let a_y = match (&m.lateral_acceleration, &self.imu) {
            (LateralAccelerationSpec::Imu { .. }, Some(c)) => (c.track.at(e, 0) - c.track.at(g, 0)) / h,
            // derived from the pose of the samples either side, in the parts
            (LateralAccelerationSpec::FromPose { .. }, _) => 0.0,
            _ => {
                let mut a = 0.0;
                for _ in 0..3 {
                    let kin = kinematics(&Input { n_rl, n_rr, beta: 0.0, a_y: a }, &self.theta0);
                    a = kin.speed_m_per_s * kin.yaw_rate_rad_per_s;
                }
                a
            }
        };
        let beta = self.side.as_ref().map_or(0.0, |c| c.track.at(g, 0));
        while self.marks.front().is_some_and(|&f| f < k) {
            self.marks.pop_front();
        }
        let measured = self.marks.front() == Some(&k);
        let sig = [self.pose.at(g, 0), self.pose.at(g, 1), self.pose.at(g, 2), n_rl, n_rr, beta, a_y];
        let phi = self.roll.as_ref().map_or(0.0, |r| r.track.at(g, 0));
        GridSample { k, sig, phi, measured, invalid, raw }
    }
}

/// The reason of the first bad interval that invalidates the sample at `g`:
/// its interval `[g, g + h]` overlaps (when `interval`) or the point `g`
/// lies inside, as [`grid::mark`] decides.
fn first_hit(bad: &VecDeque<BadInterval>, g: f64, h: f64, interval: bool) -> Option<String> {
    bad.iter()
        .find(|b| if interval { g < b.to && g + h > b.from } else { g > b.from && g < b.to })
        .map(|b| b.reason.clone())
}
