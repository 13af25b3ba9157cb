//! The import of a manifest's streams as their messages arrive
//! ([`RawStream`], and `ManifestStream` reading the CSV files of a
//! manifest incrementally): canonical samples come out as soon as every
//! stream has passed their time, in memory that does not grow with the
//! drive.
//!
//! Each step is the whole import's ([`import`](super::import)) with the
//! same arithmetic, on a window of the streams instead of all of them:
//!
//! - **de-jittering** fits each stamp over the ±`dejitter_window_s`/2
//!   samples around it, held in a window (a stamp whose fit would not
//!   follow the previous one keeps its raw stamp, where the whole import
//!   keeps the raw stamps of the whole run);
//! - **wheels, pose, IMU and sideslip** are cumulated, converted and
//!   unwrapped row by row, and interpolated at the output times from the
//!   rows around them;
//! - the **clock offset** is estimated once, on a *warm-up prefix*: the
//!   first `warm_up_s` ([`RawStream::new`]) of the wheel stream (and the rows of
//!   the other streams up to the same time). The streams are held until
//!   then; the offset is fixed from then on. A drive no longer than the
//!   warm-up is estimated on all of it, as the whole import does; a longer
//!   one on its start (the estimate's uncertainty is reported);
//! - the **road bank**'s roll (`[lateral_acceleration.bank]`) pairs each
//!   accepted left-antenna sample with the right antenna as soon as the
//!   right antenna's rows decide the pairing, and its centred moving
//!   average over `smoothing_s` waits for half its width of samples after
//!   each output, in parallel with a_y's own smoothing; the limit's judging
//!   window (0.25 s each side) comes after both, so the output lags the
//!   input by the larger half-width of the two plus 0.25 s (0.75 s on the
//!   shipped van manifests);
//! - a **heading derived from the track** (no `[pose.heading]`) is the
//!   whole import's direction of a chord of `derive_heading_baseline_m` of
//!   travel centred on each accepted pose sample, unwrapped: each sample's
//!   heading waits until the track has gone half the baseline further (or
//!   at most the baseline over the minimum speed of pose time, module
//!   `heading`), and the samples at the start wait until the vehicle
//!   first moves faster than `derive_heading_min_speed_m_per_s` (their
//!   heading is back-filled from that direction) — for at most
//!   `warm_up_s` of pose time: a longer standstill before
//!   the first motion releases its oldest samples without a heading, and
//!   the output samples before the samples still held are invalid (a gap,
//!   "pose heading unknown"; the whole import keeps them in a part with
//!   the back-filled heading; the samples after are the whole import's);
//! - a lateral acceleration **from the pose** (speed × yaw rate of the
//!   reference over the samples either side, within the part) is derived
//!   one output sample late, when the next sample of the part is in;
//! - the checks that judge the **whole drive** run on the warm-up prefix
//!   (the pose's speed, the wheel counter's width, the antennas' median
//!   separation against `baseline_m` and their glitch fraction, and, on
//!   the prefix imported as the whole import imports a drive, the wheel
//!   signs, the heading's unit and convention or swapped wheel columns,
//!   and an IMU's a_y sign and scale, with the whole import's messages and
//!   warnings: the same as the whole import's for a drive within the
//!   warm-up, the prefix's figures for a longer one); the
//!   glitch fraction is judged again over every antenna pair when the drive
//!   ends; the per-sample limits on every sample; parts shorter than
//!   `min_part_s` are held until they are long enough or end.
//!
//! With the clock offset of the whole import, the samples are the whole
//! import's bit for bit, road bank included.
//!
//! The rows held are bounded: the warm-up holds `warm_up_s` of the wheel
//! stream (and the other streams to the same time); after it, each track
//! holds the rows around the next output time, and rows before the grid's
//! origin are dropped. A stream that stops sending while the others go on
//! makes them wait: once the rows held span more than 2 × `warm_up_s` and
//! that stream's last message is more than `warm_up_s` behind the newest,
//! [`RawStream::push_message`] fails with an error naming it (end the
//! stream with [`RawStream::end_stream`] if it has stopped). A stretch of
//! pose samples of rejected quality holds the other streams' rows for its
//! length (the pose's messages keep coming, so no stream is behind).
//!
//! Not streamed (refused by [`RawStream::new`] with the reason; the whole
//! import reads them): `mcap` and `parquet` sources. Corrupt wheel rows
//! are dropped by the whole import's rule,
//! each decided once the rows after it that the rule looks at are in.

mod condition;
mod corrupt;
mod engine;
mod heading;
mod parts;
mod prefix;
pub(crate) mod reader;
mod roll;
mod tracks;

use std::collections::BTreeMap;
use std::time::Instant;

use super::manifest::{LateralAccelerationSpec, Manifest, SourceSpec};
use super::report::{ClockOffsetReport, ImportReport};
use super::source::Stream;
use super::{bank, clock, grid, pose, wheels};
use crate::drive::{Signals, StreamChunk};
use crate::error::{Error, Result};
use condition::Conditioner;
use engine::Engine;

/// Settings of the streamed import.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct StreamOptions {
    /// Wheel-stream time over which the clock offset is estimated before
    /// any sample comes out, s. Default 300: long enough for the clock
    /// estimate to see several turns and speed changes, short enough that
    /// the held streams stay small (5 min of a 1 kHz wheel log is 300,000
    /// rows).
    pub warm_up_s: f64,
}

impl Default for StreamOptions {
    fn default() -> StreamOptions {
        StreamOptions { warm_up_s: 300.0 }
    }
}

/// Why a manifest cannot be imported as a stream (`None` when it can).
pub(crate) fn not_streamable(m: &Manifest) -> Option<String> {
    if let Some((name, s)) = m.streams.iter().find(|(_, s)| !matches!(s.source, SourceSpec::Csv { .. })) {
        return Some(format!("streams.{name} is {} source, read whole", s.source.kind()));
    }
    None
}

/// The import of a manifest's streams message by message, for a live
/// system or a replay in time order (see the module's docs).
///
/// Each stream's messages are pushed in time order
/// ([`RawStream::push_message`]); canonical samples come out
/// ([`RawStream::take_chunk`]) once every stream has passed their time and
/// the warm-up is over. [`RawStream::finish`] ends the drive.
///
/// ```
/// # fn main() -> Result<(), Box<dyn std::error::Error>> {
/// use odocal::io::RawStream;
/// let path = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/comma2k19-rav4/manifest.toml");
/// let manifest = odocal::Manifest::from_path(path)?;
/// let mut raw = RawStream::new(&manifest, None)?;
/// // Each stream's file row by row, as a live system would send its messages.
/// let streams: Vec<(String, Option<String>, Vec<String>)> =
///     raw.columns().map(|(n, t, c)| (n.to_string(), t.map(str::to_string), c.to_vec())).collect();
/// for (name, file) in manifest.stream_files() {
///     let (_, time_column, cols) = streams.iter().find(|(n, _, _)| *n == name).ok_or("stream")?;
///     let text = std::fs::read_to_string(file)?;
///     let mut lines = text.lines();
///     let head: Vec<&str> = lines.next().ok_or("header")?.split(',').collect();
///     let at = |c: &str| head.iter().position(|h| *h == c).ok_or("column");
///     let (time, idx) = (at(time_column.as_deref().ok_or("time")?)?, cols.iter().map(|c| at(c)).collect::<Result<Vec<_>, _>>()?);
///     for line in lines {
///         let f: Vec<f64> = line.split(',').map(str::parse).collect::<Result<_, _>>()?;
///         raw.push_message(&name, f[time], &idx.iter().map(|&i| f[i]).collect::<Vec<_>>())?;
///     }
/// }
/// raw.finish()?;
/// let mut samples = 0;
/// while let Some(chunk) = raw.take_chunk(400) {
///     samples += chunk.t.len();
/// }
/// assert_eq!(samples, odocal::import(&manifest)?.0.len());
/// # Ok(()) }
/// ```
#[derive(Debug)]
pub struct RawStream {
    m: Manifest,
    opts: StreamOptions,
    h: f64,
    /// Each stream's conditioning and its column names.
    streams: BTreeMap<String, (Conditioner, Vec<String>)>,
    engine: Option<Engine>,
    clock: Option<ClockOffsetReport>,
    warnings: Vec<String>,
    taken: usize,
    last_part: Option<usize>,
    report: Option<ImportReport>,
    started: Instant,
}

impl RawStream {
    /// The streamed import of `manifest`, the clock offset estimated over
    /// the first `warm_up_s` seconds of wheel-stream time before any sample
    /// comes out (`None`: 300 s, long enough for the clock estimate to see
    /// several turns and speed changes, short enough that the held streams
    /// stay small: 5 min of a 1 kHz wheel log is 300,000 rows).
    ///
    /// # Errors
    /// [`Error::Manifest`] when the manifest asks for what is not streamed
    /// (a source other than CSV) or the warm-up is not a positive number of seconds.
    pub fn new(manifest: &Manifest, warm_up_s: Option<f64>) -> Result<RawStream> {
        let defaults = StreamOptions::default();
        RawStream::with_options(manifest, StreamOptions { warm_up_s: warm_up_s.unwrap_or(defaults.warm_up_s) })
    }

    /// [`RawStream::new`] with the settings `opts`.
    pub(crate) fn with_options(manifest: &Manifest, opts: StreamOptions) -> Result<RawStream> {
        if let Some(why) = not_streamable(manifest) {
            return Err(manifest.error(
                "streams",
                format!("the manifest cannot be imported as a stream: {why}; odocal::import reads it whole"),
            ));
        }
        if !(opts.warm_up_s.is_finite() && opts.warm_up_s > 0.0) {
            return Err(manifest.error("warm_up_s", format!("{} is not a positive number of seconds", opts.warm_up_s)));
        }
        let mut streams = BTreeMap::new();
        for (name, wanted) in super::wanted_columns(manifest) {
            let mut cols: Vec<String> = Vec::new();
            for w in wanted {
                if !cols.contains(&w.column) {
                    cols.push(w.column);
                }
            }
            streams.insert(name.clone(), (Conditioner::new(manifest, &name, &cols), cols));
        }
        Ok(RawStream {
            m: manifest.clone(),
            h: 1.0 / manifest.output.rate_hz,
            opts,
            streams,
            engine: None,
            clock: None,
            warnings: manifest.unused_wheel_keys(),
            taken: 0,
            last_part: None,
            report: None,
            started: Instant::now(),
        })
    }

    /// The streams the manifest reads: each one's name, its time column
    /// (`streams.<name>.time_column`) and the columns each message carries,
    /// in the order [`RawStream::push_message`] takes them.
    pub fn columns(&self) -> impl Iterator<Item = (&str, Option<&str>, &[String])> {
        self.streams.iter().map(|(n, (_, c))| (n.as_str(), self.m.time_column(n), c.as_slice()))
    }

    /// Takes one message of stream `stream`: its time `t` in the stream's
    /// `time_unit` (before `time_offset_s`), and the values of its columns
    /// ([`RawStream::columns`]). Messages of one stream come in time order.
    ///
    /// # Errors
    /// An unknown stream or a wrong number of values; the whole import's
    /// errors about the stream's rows (time going backwards, a value that
    /// is not finite, a limit exceeded), naming the row; a stream that
    /// stalled while the others went on, naming it (see the module's docs).
    pub fn push_message(&mut self, stream: &str, t: f64, values: &[f64]) -> Result<()> {
        self.push_row(stream, t, values.to_vec(), None)
    }

    pub(crate) fn push_row(&mut self, stream: &str, t: f64, values: Vec<f64>, line: Option<u64>) -> Result<()> {
        let Some((c, cols)) = self.streams.get_mut(stream) else {
            return Err(self.m.error("streams", format!("no stream '{stream}' is read by the manifest")));
        };
        if values.len() != cols.len() {
            return Err(self.m.error(
                &format!("streams.{stream}"),
                format!("a message has {} values; the stream's columns are {}", values.len(), cols.join(", ")),
            ));
        }
        if c.ended {
            return Err(self.m.error(&format!("streams.{stream}"), "a message after the stream's end"));
        }
        c.push(t, values, line)?;
        self.advance()
    }

    /// No more messages of `stream` come.
    ///
    /// # Errors
    /// As [`RawStream::push_message`].
    pub fn end_stream(&mut self, stream: &str) -> Result<()> {
        match self.streams.get_mut(stream) {
            Some((c, _)) => c.end(),
            None => return Err(self.m.error("streams", format!("no stream '{stream}' is read by the manifest"))),
        }
        self.advance()
    }

    /// Ends every stream and the drive: the last samples come out. Returns
    /// what was read, estimated, split and dropped (the whole import's
    /// report).
    ///
    /// # Errors
    /// The whole import's errors about the drive as a whole: streams that
    /// do not overlap, no part of at least `min_part_s`.
    pub fn finish(&mut self) -> Result<&ImportReport> {
        for (c, _) in self.streams.values_mut() {
            if !c.ended {
                c.end();
            }
        }
        self.advance()?;
        let (m, h) = (&self.m, self.h);
        let Some(e) = self.engine.as_mut() else { return Err(m.error("streams", "the streams hold no rows")) };
        for name in self.streams.keys() {
            e.end_stream(m, name)?;
        }
        let spans = e.spans(m).ok_or_else(|| m.error("streams", "no streams"))?;
        let (start, end) = grid::common_span(m, &spans, h)?;
        e.try_start(m);
        e.n_end = Some(((end - start) / h).floor() as usize);
        e.step(m)?;
        if let (Some(b), Some(r)) = (m.lateral_acceleration.bank(), e.roll.as_ref()) {
            bank::judge_glitches(m, b, r.beyond, r.first_beyond, r.pairs, &mut self.warnings)?;
        }
        let Some(asm) = e.asm.as_mut() else { return Err(m.error("streams", "no streams")) };
        asm.close_run(m)?;
        if asm.kept_parts == 0 {
            return Err(Error::InvalidDrive {
                context: m.path.display().to_string(),
                reason: format!(
                    "no continuous part of at least output.min_part_s = {} s ({} parts, {} gaps); lower \
                     min_part_s or check the gaps",
                    crate::drive::echo_num(m.output.min_part_s),
                    asm.parts.len(),
                    asm.gaps.len()
                ),
            });
        }
        let jitter = match m.streams[&m.wheels.stream].nominal_rate_hz {
            Some(_) => {
                let (raw, dejittered) = asm.noise.pct();
                Some(wheels::jitter_of(m, raw, dejittered)?)
            }
            None => None,
        };
        let clock =
            self.clock.clone().ok_or_else(|| m.error("output.clock_offset", "no clock offset was estimated"))?;
        let mut report = self.make_report(start, end, clock);
        report.jitter = jitter;
        Ok(self.report.insert(report))
    }

    /// Up to `max` (at least 1) canonical samples of one part that are
    /// ready, oldest first; `None` when none is.
    pub fn take_chunk(&mut self, max: usize) -> Option<StreamChunk> {
        let asm = self.engine.as_mut()?.asm.as_mut()?;
        let part = asm.out.front()?.part;
        let n = asm.out.iter().take(max.max(1)).take_while(|s| s.part == part).count();
        let mut signals = Signals::with_capacity(n);
        let (mut t, mut measured) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for s in asm.out.drain(..n) {
            t.push(s.t);
            signals.push(s.sig);
            measured.push(s.measured);
        }
        let starts_part = self.last_part != Some(part);
        self.last_part = Some(part);
        let start = self.taken;
        self.taken += n;
        Some(StreamChunk { part, start, starts_part, t, signals, reference_measured: Some(measured) })
    }

    /// Samples ready of the oldest part with samples ready, and whether
    /// that part has ended.
    pub(crate) fn front_part(&self) -> (usize, bool) {
        let Some(asm) = self.engine.as_ref().and_then(|e| e.asm.as_ref()) else { return (0, false) };
        let Some(part) = asm.out.front().map(|s| s.part) else { return (0, false) };
        let n = asm.out.iter().take_while(|s| s.part == part).count();
        (n, n < asm.out.len() || asm.kept_parts > part)
    }

    /// The clock offset, once the warm-up is over.
    pub fn clock_offset(&self) -> Option<&ClockOffsetReport> {
        self.clock.as_ref()
    }

    /// What was read, estimated, split and dropped, after
    /// [`RawStream::finish`] (the whole import's report).
    pub(crate) fn report(&self) -> Option<&ImportReport> {
        self.report.as_ref()
    }

    /// Rows held by the streamed import (the warm-up, the de-jitter
    /// windows, the rows around the next output time), and samples ready.
    pub fn held(&self) -> usize {
        let conditioned: usize = self.streams.values().map(|(c, _)| c.ready.len()).sum();
        let e = self.engine.as_ref().map_or(0, |e| {
            e.wheel.t.len()
                + e.pose.t.len()
                + [e.imu.as_ref(), e.side.as_ref()].into_iter().flatten().map(|c| c.track.t.len()).sum::<usize>()
                + e.asm.as_ref().map_or(0, |a| a.out.len())
                + e.roll.as_ref().map_or(0, |r| r.held())
                + e.pose_held()
        });
        conditioned + e
    }

    /// Moves conditioned rows on: the warm-up's decision, then the tracks
    /// and the output.
    fn advance(&mut self) -> Result<()> {
        if self.engine.is_none() && !self.decide()? {
            return Ok(());
        }
        let Some(e) = self.engine.as_mut() else { return Ok(()) };
        let m = &self.m;
        for (name, (c, _)) in self.streams.iter_mut() {
            while let Some(row) = c.ready.pop_front() {
                e.push(m, name, &row)?;
            }
            if c.ended {
                e.end_stream(m, name)?;
            }
        }
        e.try_start(m);
        e.step(m)?;
        self.check_stall()
    }

    /// The rows held must not grow without bound while one stream stops
    /// sending and the others go on: once a stream's or track's held rows
    /// span more than twice the warm-up and a stream's last message is
    /// more than the warm-up behind the newest, that stream is named in
    /// an error.
    fn check_stall(&self) -> Result<()> {
        let bound = 2.0 * self.opts.warm_up_s;
        let queued = self.streams.values().map(|(c, _)| match (c.ready.front(), c.ready.back()) {
            (Some(a), Some(b)) => b.t - a.t,
            _ => 0.0,
        });
        let held = queued.chain(self.engine.as_ref().map(|e| e.held_span_s())).fold(0.0, f64::max);
        if held <= bound {
            return Ok(());
        }
        let newest = self.streams.values().filter_map(|(c, _)| c.last_stamp()).fold(f64::NEG_INFINITY, f64::max);
        let behind = self
            .streams
            .values()
            .filter(|(c, _)| !c.ended)
            .map(|(c, _)| (c, c.last_stamp().unwrap_or(f64::NEG_INFINITY)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match behind {
            Some((c, last)) if newest - last > self.opts.warm_up_s => Err(self.m.error(
                &format!("streams.{}", c.name),
                format!(
                    "the stream stalled: its last message is at {} while the others went on to {newest:.3} s; the \
                     streamed import holds their rows until it catches up, at most 2 × warm_up_s = {bound} s of \
                     them; end the stream (end_stream) if it has stopped, or push the streams in time order",
                    if last.is_finite() { format!("{last:.3} s") } else { "— (none yet)".to_string() },
                ),
            )),
            _ => Ok(()),
        }
    }

    /// Once every stream is past the warm-up (or has ended): the clock
    /// offset from the warm-up prefix, and the engine. False while waiting.
    fn decide(&mut self) -> Result<bool> {
        let m = &self.m;
        let Some(w0) = self.streams[&m.wheels.stream].0.ready.front().map(|r| r.t) else {
            if self.streams.values().all(|(c, _)| c.ended) {
                return Err(self.empty_stream());
            }
            return Ok(false);
        };
        let t_w = w0 + self.opts.warm_up_s;
        let past = |c: &Conditioner| c.ended || c.ready.back().is_some_and(|r| r.t > t_w);
        if !self.streams.values().all(|(c, _)| past(c)) {
            return Ok(false);
        }
        if let Some((name, _)) = self.streams.iter().find(|(_, (c, _))| c.ready.is_empty()) {
            return Err(m.error(&format!("streams.{name}.file"), format!("{} has no data rows", name)));
        }
        let prefix = |name: &str| -> Stream {
            let (c, cols) = &self.streams[name];
            prefix_stream(c, cols, t_w)
        };
        let mut streams: BTreeMap<String, Stream> = self.streams.keys().map(|n| (n.clone(), prefix(n))).collect();
        let h = self.h;
        // The prefix without its corrupt rows (the stream reports them as it drops them).
        let (wh, cleaned) = wheels::Wheels::new(m, &streams[&m.wheels.stream], &mut Vec::new())?;
        if let (Some(c), Some(ws)) = (cleaned, streams.get_mut(&m.wheels.stream)) {
            *ws = c;
        }
        let ws = &streams[&m.wheels.stream];
        let wheel_bad = grid::gaps_of(&ws.t, m.output.max_gap_s, "wheel");
        let mut pose = pose::build_pose(m, &streams[&m.pose.stream], &mut self.warnings)?;
        super::check_budgets(m, &ws.t, &pose.t, h)?;
        // The pairs' whole-drive checks on the prefix (the glitches are
        // counted and reported over the whole drive).
        let mut roll = match m.lateral_acceleration.bank() {
            Some(b) => Some(bank::roll(m, b, &streams[&b.left], &streams[&b.right], &mut Vec::new())?),
            None => None,
        };
        let track = clock::WheelTrack { t: &ws.t, cum_l: &wh.cum_l, cum_r: &wh.cum_r, bad: &wheel_bad };
        let theta0 = m.output.theta0();
        let clock = clock::align(m, &track, &pose, h, &theta0, &mut self.warnings)?;
        let offset = clock.applied_s;
        self.clock = Some(clock);
        pose.shift(offset);
        if let Some(r) = roll.as_mut() {
            r.shift(offset);
        }
        let p = prefix::Prefix { streams: &streams, wheels: &wh, pose: &pose, roll: roll.as_ref() };
        prefix::check_conventions(m, &p, h, &mut self.warnings)?;
        let index = |stream: &str, col: &str| self.streams[stream].1.iter().position(|c| c == col).unwrap_or(0);
        self.engine = Some(Engine::new(m, h, offset, self.opts.warm_up_s, index));
        Ok(true)
    }

    fn empty_stream(&self) -> Error {
        let name = &self.m.wheels.stream;
        self.m.error(&format!("streams.{name}.file"), format!("{name} has no data rows"))
    }

    /// The report once the drive has ended.
    fn make_report(&self, start: f64, end: f64, clock_offset: ClockOffsetReport) -> ImportReport {
        let (m, h) = (&self.m, self.h);
        let mut warnings = self.warnings.clone();
        for (c, _) in self.streams.values() {
            warnings.extend(c.repeat_warnings());
            if c.fallbacks() > 0 {
                warnings.push(format!(
                    "streams.{}: {} de-jittered stamp(s) did not follow the previous one and kept their raw stamp \
                     (or were dropped)",
                    c.name,
                    c.fallbacks()
                ));
            }
        }
        let mut streams: Vec<_> = self.streams.values().map(|(c, _)| c.report()).collect();
        if let Some(f) = self.engine.as_ref().map(|e| &e.corrupt).filter(|f| f.dropped > 0) {
            warnings.push(format!(
                "streams.{}: {} corrupt wheel row(s) dropped (a count jump beyond limits.max_speed_m_per_s that \
                 returns), at {}{}",
                m.wheels.stream,
                f.dropped,
                f.first.join(", "),
                if f.dropped > 3 { ", …" } else { "" }
            ));
            for s in streams.iter_mut().filter(|s| s.name == m.wheels.stream) {
                s.corrupt_rows_dropped = f.dropped;
            }
        }
        let asm = self.engine.as_ref().and_then(|e| e.asm.as_ref());
        let samples = asm.map_or(0, |a| a.samples);
        let theta0 = m.output.theta0();
        ImportReport {
            manifest: m.path.clone(),
            streams,
            output_rate_hz: m.output.rate_hz,
            time_origin_s: start,
            common_span_s: [0.0, end - start],
            clock_offset,
            gaps: asm.map(|a| a.gaps.clone()).unwrap_or_default(),
            parts: asm.map(|a| a.parts.clone()).unwrap_or_default(),
            samples,
            duration_s: samples as f64 * h,
            distance_m: asm.map_or(0.0, |a| a.distance_m),
            wheel_scale: wheels::wheel_scale(m),
            lateral_acceleration: match &m.lateral_acceleration {
                LateralAccelerationSpec::Imu { stream, column, sign } => {
                    format!("IMU column '{column}' of stream '{stream}' × {sign:+}, mean over each output interval")
                }
                LateralAccelerationSpec::FromWheels { smoothing_s, .. } => self.with_bank(format!(
                    "from wheels: v·ω of the model at θ_0 ({theta0}), smoothed over {smoothing_s} s"
                )),
                LateralAccelerationSpec::FromPose { smoothing_s, .. } => self.with_bank(format!(
                    "from pose: speed × yaw rate of the reference, smoothed over {smoothing_s} s (feeds the \
                     reference yaw rate into the model through d)"
                )),
            },
            jitter: None,
            warnings,
            noise: m.noise.clone(),
            reference: m.reference.clone(),
            calibration: m.calibration.clone(),
            elapsed_s: self.started.elapsed().as_secs_f64(),
        }
    }
}

impl RawStream {
    /// `desc` of a derived a_y followed by the road bank's account, when
    /// the manifest has one.
    fn with_bank(&self, mut desc: String) -> String {
        let roll = self.engine.as_ref().and_then(|e| e.roll.as_ref());
        let asm = self.engine.as_ref().and_then(|e| e.asm.as_ref());
        if let (Some(b), Some(r), Some(a)) = (self.m.lateral_acceleration.bank(), roll, asm) {
            let mean = a.phi_sum / a.samples.max(1) as f64;
            desc.push_str(&bank::description(b, r.pairs, r.beyond, mean, a.phi_max));
        }
        desc
    }
}

/// The rows of a stream up to `t_w` as the whole import's [`Stream`].
fn prefix_stream(c: &Conditioner, cols: &[String], t_w: f64) -> Stream {
    let n = c.ready.iter().take_while(|r| r.t <= t_w).count().max(2).min(c.ready.len());
    let rows = || c.ready.iter().take(n);
    Stream {
        path: c.path().to_path_buf(),
        t: rows().map(|r| r.t).collect(),
        t_raw: rows().map(|r| r.t_raw).collect(),
        cols: cols.iter().enumerate().map(|(i, name)| (name.clone(), rows().map(|r| r.values[i]).collect())).collect(),
        lines: rows().map(|r| r.line).collect(),
        report: c.report(),
    }
}

#[cfg(test)]
mod tests;
