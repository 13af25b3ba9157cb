//! The signals of the streamed import on their own stamps, as rows arrive:
//! each wheel's cumulative rotation, the pose (quality, local frame,
//! unwrapped heading, rejected and missing stretches), an IMU's
//! integrated lateral acceleration and a sideslip column; and their
//! interpolation at the output times with the whole import's arithmetic,
//! over a window that is pruned behind the output.

use std::collections::VecDeque;

use super::super::geodesy::Enu;
use super::super::grid::BadInterval;
use super::super::limits::{echo_num, within};
use super::super::manifest::{HeadingConvention, Manifest, PositionSpec, WheelColumn, WheelSignal};
use super::condition::Row;
use crate::error::{Error, Result};

/// Samples of one signal (or several on the same stamps) on their stamps.
#[derive(Debug, Default)]
pub(crate) struct Track<const N: usize> {
    /// Stamps, s (strictly increasing).
    pub t: VecDeque<f64>,
    /// Values at the stamps.
    pub y: VecDeque<[f64; N]>,
    /// True while `t[0]` is the first stamp the track ever held.
    at_start: bool,
    /// Stamps between which the track has a gap longer than `max_gap_s`,
    /// or a stretch of rejected samples.
    pub bad: VecDeque<BadInterval>,
    /// True once no more samples come.
    pub ended: bool,
    /// The first stamp, s.
    pub first: Option<f64>,
    /// The last stamp before the shift.
    raw_last: Option<f64>,
}

impl<const N: usize> Track<N> {
    pub(crate) fn new() -> Track<N> {
        Track { at_start: true, ..Track::default() }
    }

    /// Appends a sample at `t + shift` (the clock offset moves the pose),
    /// recording a gap to the previous one longer than `max_gap_s`
    /// (judged on `t`, as the whole import does before the shift) as `what`.
    pub(crate) fn push(&mut self, t: f64, shift: f64, y: [f64; N], max_gap_s: f64, what: &str) {
        if let Some(last) = self.raw_last {
            if t - last > max_gap_s {
                self.bad.push_back(BadInterval {
                    from: last + shift,
                    to: t + shift,
                    reason: format!("{what} gap of {:.2} s", t - last),
                });
            }
        }
        self.raw_last = Some(t);
        let t = t + shift;
        self.first.get_or_insert(t);
        self.t.push_back(t);
        self.y.push_back(y);
    }

    /// The last stamp, s.
    pub(crate) fn last(&self) -> Option<f64> {
        self.t.back().copied()
    }

    /// True when the value at `q` no longer depends on samples to come.
    pub(crate) fn covers(&self, q: f64) -> bool {
        self.ended || self.last().is_some_and(|l| l > q)
    }

    /// Linear interpolation at `q`, clamped at the track's ends, with the
    /// arithmetic of the whole import's interpolation (the segment whose
    /// start is the last stamp before `q`).
    pub(crate) fn at(&self, q: f64, i: usize) -> f64 {
        let n = self.t.len();
        if n == 0 {
            return f64::NAN;
        }
        if q <= self.t[0] && self.at_start {
            return self.y[0][i];
        }
        if q >= self.t[n - 1] {
            return self.y[n - 1][i];
        }
        let j1 = self.t.partition_point(|&t| t < q).max(1);
        let j = j1 - 1;
        let (t0, t1) = (self.t[j], self.t[j1]);
        let w = (q - t0) / (t1 - t0);
        self.y[j][i] + w * (self.y[j1][i] - self.y[j][i])
    }

    /// Drops the samples that no query at or after `q` can use (keeps the
    /// last stamp before `q`), and the bad intervals that end before `q − h`.
    pub(crate) fn prune(&mut self, q: f64, h: f64) {
        while self.t.len() > 2 && self.t[1] < q {
            self.t.pop_front();
            self.y.pop_front();
            self.at_start = false;
        }
        while self.bad.front().is_some_and(|b| b.to < q - h) {
            self.bad.pop_front();
        }
    }
}

/// One wheel's cumulative rotation, row by row, with the arithmetic of
/// [`wheel_revolutions`](super::super::wheels::wheel_revolutions).
#[derive(Debug)]
pub(crate) struct Rotation {
    signal: WheelSignal,
    sign: f64,
    per_rev: f64,
    counter_bits: u32,
    column: usize,
    key: &'static str,
    col_name: String,
    first: Option<f64>,
    prev: Option<(f64, f64)>,
    acc: f64,
    ticks: i128,
}

impl Rotation {
    /// The rotation of `wheel`, its column at `column` of the rows.
    pub(crate) fn new(m: &Manifest, wheel: &WheelColumn, column: usize, key: &'static str) -> Rotation {
        let w = &m.wheels;
        let per_rev = match w.signal {
            WheelSignal::MPerS => w.circumference_m.unwrap_or(1.0),
            WheelSignal::TicksCumulative | WheelSignal::TicksRaw => w.ticks_per_rev.unwrap_or(1.0),
            _ => 1.0,
        };
        Rotation {
            signal: w.signal,
            sign: wheel.sign,
            per_rev,
            counter_bits: w.counter_bits.unwrap_or(32),
            column,
            key,
            col_name: wheel.column.clone(),
            first: None,
            prev: None,
            acc: 0.0,
            ticks: 0,
        }
    }

    /// The cumulative rotation at `row`, rev.
    pub(crate) fn next(&mut self, path: &std::path::Path, row: &Row) -> Result<f64> {
        let v = row.values[self.column];
        if !v.is_finite() {
            return Err(Error::Csv {
                path: path.to_path_buf(),
                line: row.line.unwrap_or(0),
                column: Some(self.col_name.clone()),
                reason: format!("value is not finite ({})", self.key),
            });
        }
        let sign = self.sign;
        let out = match self.signal {
            WheelSignal::RevPerS | WheelSignal::RadPerS | WheelSignal::MPerS => {
                let y = match self.signal {
                    WheelSignal::RevPerS => sign * v,
                    WheelSignal::RadPerS => sign * v / std::f64::consts::TAU,
                    _ => sign * v / self.per_rev,
                };
                if let Some((tp, yp)) = self.prev {
                    self.acc += 0.5 * (y + yp) * (row.t - tp);
                }
                self.prev = Some((row.t, y));
                self.acc
            }
            WheelSignal::TicksCumulative => sign * (v - *self.first.get_or_insert(v)) / self.per_rev,
            WheelSignal::RadCumulative => sign * (v - *self.first.get_or_insert(v)) / std::f64::consts::TAU,
            WheelSignal::TicksRaw => {
                if let Some((_, vp)) = self.prev {
                    let modulus: i128 = 1i128 << self.counter_bits;
                    let half = modulus / 2;
                    let d = ((v as i128) - (vp as i128)).rem_euclid(modulus);
                    self.ticks += if d >= half { d - modulus } else { d };
                }
                self.prev = Some((row.t, v));
                if self.first.replace(v).is_none() {
                    0.0
                } else {
                    sign * self.ticks as f64 / self.per_rev
                }
            }
        };
        Ok(out)
    }
}

/// The pose, row by row, with the arithmetic of
/// [`build_pose`](super::super::pose::build_pose): accepted samples in the
/// local frame with the heading unwrapped, rejected stretches and gaps as
/// bad intervals.
#[derive(Debug)]
pub(crate) struct PoseBuilder {
    /// Columns of the rows: x or lat, y or lon, alt, heading, quality.
    cols: [Option<usize>; 5],
    enu: Option<Enu>,
    unwrap: crate::drive::Unwrap,
    rejected: usize,
    rejected_values: Vec<f64>,
    last_good: Option<f64>,
    /// The heading derived from the track, without a heading column.
    derived: Option<super::heading::TrackHeading>,
    /// The longest hold of samples before the first motion, s.
    max_hold_s: f64,
}

/// Column slots of [`PoseBuilder`].
const X: usize = 0;
const Y: usize = 1;
const ALT: usize = 2;
const HEADING: usize = 3;
const QUALITY: usize = 4;

impl PoseBuilder {
    /// The pose of `m`, the columns found by `index`; a heading derived
    /// from the track holds the samples before the first motion for at
    /// most `max_hold_s` of pose time.
    pub(crate) fn new(m: &Manifest, max_hold_s: f64, index: impl Fn(&str) -> usize) -> PoseBuilder {
        let p = &m.pose;
        let mut cols = [None; 5];
        match &p.position {
            PositionSpec::Local { x, y } => (cols[X], cols[Y]) = (Some(index(x)), Some(index(y))),
            PositionSpec::LatLon { lat, lon, alt, .. } => {
                (cols[X], cols[Y]) = (Some(index(lat)), Some(index(lon)));
                cols[ALT] = alt.as_deref().map(&index);
            }
        }
        cols[HEADING] = p.heading.as_ref().map(|h| index(&h.column));
        cols[QUALITY] = p.quality.as_ref().map(|q| index(&q.column));
        PoseBuilder {
            cols,
            enu: None,
            unwrap: Default::default(),
            rejected: 0,
            rejected_values: Vec::new(),
            last_good: None,
            derived: p.heading.is_none().then(|| {
                super::heading::TrackHeading::new(
                    p.derive_heading_min_speed_m_per_s,
                    p.derive_heading_baseline_m,
                    max_hold_s,
                )
            }),
            max_hold_s,
        }
    }

    /// Adds `row` to `track` (`[x, y, ψ]`) when its quality is accepted.
    pub(crate) fn push(
        &mut self,
        m: &Manifest,
        path: &std::path::Path,
        row: &Row,
        offset_s: f64,
        track: &mut Track<3>,
    ) -> Result<()> {
        let p = &m.pose;
        let v = |slot: usize| self.cols[slot].map(|c| row.values[c]);
        if let (Some(q), Some(val)) = (&p.quality, v(QUALITY)) {
            if !q.accepts(val) {
                self.rejected += 1;
                if !self.rejected_values.iter().any(|r| (r - val).abs() < 1e-9) {
                    self.rejected_values.push(val);
                }
                return Ok(());
            }
        }
        let (a, b) = (v(X).unwrap_or(f64::NAN), v(Y).unwrap_or(f64::NAN));
        let (x, y) = match &p.position {
            PositionSpec::Local { .. } => (a, b),
            PositionSpec::LatLon { lat, lon, origin, .. } => {
                for (col, val, max, key) in [(lat, a, 90.0, "pose.position.lat"), (lon, b, 180.0, "pose.position.lon")]
                {
                    if !within(val, max) {
                        return Err(Error::Csv {
                            path: path.to_path_buf(),
                            line: row.line.unwrap_or(0),
                            column: Some(col.clone()),
                            reason: format!(
                                "{key}: {} is outside ±{max}°; the column must hold WGS84 degrees (ECEF or local \
                                 metres? use kind = \"local\" with x and y)",
                                echo_num(val)
                            ),
                        });
                    }
                }
                let h = v(ALT).unwrap_or(0.0);
                let enu = self.enu.get_or_insert_with(|| {
                    let o = origin.unwrap_or([a, b, h]);
                    Enu::new(o[0], o[1], o[2])
                });
                let e = enu.enu_of(a, b, h);
                (e.x, e.y)
            }
        };
        if !(x.is_finite() && y.is_finite()) {
            return Err(Error::Csv {
                path: path.to_path_buf(),
                line: row.line.unwrap_or(0),
                column: None,
                reason: "pose position is not finite".into(),
            });
        }
        if self.rejected > 0 {
            if let (Some(t0), Some(q)) = (self.last_good, &p.quality) {
                track.bad.push_back(BadInterval {
                    from: t0 + offset_s,
                    to: row.t + offset_s,
                    reason: format!(
                        "pose quality rejected ({} = {:?}, {} samples)",
                        q.column, self.rejected_values, self.rejected
                    ),
                });
            }
            self.rejected = 0;
            self.rejected_values.clear();
        }
        let psi = match (&p.heading, v(HEADING)) {
            (Some(hd), Some(val)) => {
                let r = val * hd.unit.radians();
                self.unwrap.next(match hd.convention {
                    HeadingConvention::Enu => r,
                    HeadingConvention::Ned => std::f64::consts::FRAC_PI_2 - r,
                })
            }
            _ => f64::NAN,
        };
        self.last_good = Some(row.t);
        match self.derived.as_mut() {
            None => track.push(row.t, offset_s, [x, y, psi], m.output.max_gap_s, "pose"),
            Some(d) => {
                let (mut out, mut released) = (Vec::new(), Vec::new());
                d.push((row.t, x, y), &mut out, &mut released);
                if !released.is_empty() {
                    self.release(m, released, offset_s, track);
                }
                for [t, x, y, psi] in out {
                    track.push(t, offset_s, [x, y, psi], m.output.max_gap_s, "pose");
                }
            }
        }
        Ok(())
    }

    /// Samples before the first motion released without a heading: into
    /// the track (heading 0), and every output sample before the oldest
    /// sample still held made invalid.
    fn release(&mut self, m: &Manifest, released: Vec<(f64, f64, f64)>, offset_s: f64, track: &mut Track<3>) {
        for (t, x, y) in released {
            track.push(t, offset_s, [x, y, 0.0], m.output.max_gap_s, "pose");
        }
        let Some(to) = self.derived.as_ref().and_then(|d| d.first_waiting()) else { return };
        let to = to + offset_s;
        match track.bad.iter_mut().find(|b| b.from == f64::NEG_INFINITY) {
            Some(b) => b.to = to,
            None => track.bad.push_back(BadInterval {
                from: f64::NEG_INFINITY,
                to,
                reason: format!(
                    "pose heading unknown: the vehicle stood still for more than {} s before it first moved \
                     faster than pose.derive_heading_min_speed_m_per_s (the heading is derived from the track)",
                    self.max_hold_s
                ),
            }),
        }
    }

    /// The pose stream has ended: the samples still waiting for their
    /// derived heading go into `track`.
    pub(crate) fn end(&mut self, m: &Manifest, offset_s: f64, track: &mut Track<3>) {
        if let Some(d) = self.derived.as_mut() {
            let mut out = Vec::new();
            d.end(&mut out);
            for [t, x, y, psi] in out {
                track.push(t, offset_s, [x, y, psi], m.output.max_gap_s, "pose");
            }
        }
    }

    /// Pose samples waiting for their derived heading.
    pub(crate) fn held(&self) -> usize {
        self.derived.as_ref().map_or(0, |d| d.held())
    }
}
