//! The output samples of the streamed import, in time order: runs of
//! valid samples become parts once they are `min_part_s` long (shorter ones
//! are dropped), a_y (and the road bank's roll) is smoothed within each
//! part, corrected for the bank and judged, and the kept samples are handed
//! out; gaps and parts are recorded for the report.

use std::collections::VecDeque;

use super::super::bank::specific_force;
use super::super::checks::{grid_time, lateral_acceleration_error, wheel_speed, A_Y_CHECK_SMOOTHING_S};
use super::super::limits::within;
use super::super::manifest::{LateralAccelerationSpec, Manifest};
use super::super::report::{GapRecord, PartRecord};
use crate::error::Result;

/// One output sample before the parts: its grid index, the signals
/// `[px, py, ψ, n_rl, n_rr, β, a_y]` (a_y before smoothing), the road
/// bank's roll (before smoothing; 0 without a bank), whether the reference
/// was measured at it, and why it is invalid (`None`: valid).
#[derive(Debug, Clone)]
pub(crate) struct GridSample {
    pub k: usize,
    pub sig: [f64; 7],
    pub phi: f64,
    pub measured: bool,
    pub invalid: Option<String>,
    /// The wheels' speeds on the raw stamps (the jitter report's), when
    /// the wheel stream is de-jittered.
    pub raw: Option<[f64; 2]>,
}

/// A kept output sample.
#[derive(Debug, Clone)]
pub(crate) struct OutSample {
    /// Index of its part among the kept parts.
    pub part: usize,
    /// Drive time, s (grid index × step).
    pub t: f64,
    /// `[px, py, ψ, n_rl, n_rr, β, a_y]`, ψ unwrapped over the drive.
    pub sig: [f64; 7],
    /// True when the reference was measured at this sample.
    pub measured: bool,
}

/// The speed noise of the jitter report ([`speed_noise_pct`](super::super::wheels::speed_noise_pct))
/// as the kept samples come: the sums over the samples of each part with a
/// sample either side, for the wheels with raw and de-jittered stamps.
#[derive(Debug, Default)]
pub(crate) struct SpeedNoise {
    /// The part and speeds `[raw l, raw r, l, r]` of the last two samples.
    last: VecDeque<(usize, [f64; 4])>,
    s2: [f64; 4],
    sn: [f64; 4],
    c: [usize; 4],
}

impl SpeedNoise {
    fn push(&mut self, part: usize, n: [f64; 4]) {
        if self.last.front().is_some_and(|(p, _)| *p != part) || self.last.back().is_some_and(|(p, _)| *p != part) {
            self.last.clear();
        }
        self.last.push_back((part, n));
        if self.last.len() < 3 {
            return;
        }
        let (a, b, c) = (self.last[0].1, self.last[1].1, self.last[2].1);
        for i in 0..4 {
            if b[i].abs() > 1.0 {
                let d2 = c[i] - 2.0 * b[i] + a[i];
                self.s2[i] += d2 * d2 / 6.0;
                self.sn[i] += b[i] * b[i];
                self.c[i] += 1;
            }
        }
        self.last.pop_front();
    }

    /// The noise, per cent: `[raw l, raw r]` and `[l, r]`.
    pub(crate) fn pct(&self) -> ([f64; 2], [f64; 2]) {
        let p = |i: usize| if self.c[i] == 0 { f64::NAN } else { 100.0 * (self.s2[i] / self.sn[i]).sqrt() };
        ([p(0), p(1)], [p(2), p(3)])
    }
}

/// A centred moving average over a part that grows as samples arrive,
/// with the arithmetic of [`moving_average`](super::super::signal::moving_average):
/// prefix sums from the part's start, each output once its window is complete.
#[derive(Debug)]
struct Smoother {
    half: usize,
    /// Prefix sums `pre[base..]`.
    pre: VecDeque<f64>,
    base: usize,
    /// Inputs fed.
    n: usize,
    /// Index of the next output.
    next: usize,
}

impl Smoother {
    fn new(half: usize) -> Smoother {
        Smoother { half, pre: VecDeque::from([0.0]), base: 0, n: 0, next: 0 }
    }

    fn pre(&self, i: usize) -> f64 {
        self.pre[i - self.base]
    }

    /// Feeds `x`; returns the outputs that became complete.
    fn feed(&mut self, x: f64, out: &mut Vec<f64>) {
        let last = *self.pre.back().unwrap_or(&0.0);
        self.pre.push_back(last + x);
        self.n += 1;
        while self.next + self.half < self.n {
            self.output(self.next + self.half + 1, out);
        }
    }

    /// The part has ended: the remaining outputs.
    fn finish(&mut self, out: &mut Vec<f64>) {
        while self.next < self.n {
            self.output((self.next + self.half + 1).min(self.n), out);
        }
    }

    fn output(&mut self, hi: usize, out: &mut Vec<f64>) {
        let lo = self.next.saturating_sub(self.half);
        out.push((self.pre(hi) - self.pre(lo)) / (hi - lo) as f64);
        self.next += 1;
        while self.base + self.half < self.next && self.pre.len() > 1 {
            self.pre.pop_front();
            self.base += 1;
        }
    }
}

/// The smoothing of a_y within a part: the lateral acceleration's own
/// smoothing and, with a road bank, the roll's, combined into the specific
/// force, then the judging window of the limit check (skipped for an IMU's
/// a_y, judged as it is); `half == 0` leaves a stage out.
#[derive(Debug)]
struct PartPipe {
    first: Option<Smoother>,
    /// The roll's smoothing, when there is a bank (`Some(None)`: a bank,
    /// not smoothed).
    roll: Option<Option<Smoother>>,
    judge: Option<Smoother>,
    /// Samples waiting for their smoothed a_y (first stage) and judged a_y.
    waiting: VecDeque<GridSample>,
    /// Smoothed a_y and roll of the oldest waiting samples, not yet combined.
    a_q: VecDeque<f64>,
    phi_q: VecDeque<f64>,
    /// The final a_y (and roll) of the oldest waiting samples without a
    /// judged value yet.
    smoothed: VecDeque<f64>,
    phis: VecDeque<f64>,
    judged: VecDeque<f64>,
    /// a_y from the pose: the sample waiting for its successor, and the
    /// pose `[px, py, ψ]` of the one before it in the part.
    pose_wait: Option<GridSample>,
    pose_before: Option<[f64; 3]>,
}

impl PartPipe {
    /// The sample waiting for its successor `next` (`None`: the part has
    /// ended) with a_y from the pose, as the whole import derives it: the
    /// reference's speed × yaw rate over the samples either side of it
    /// within the part.
    fn a_y_from_pose(&mut self, next: Option<GridSample>, h: f64) -> Option<GridSample> {
        let Some(mut c) = self.pose_wait.take() else {
            self.pose_wait = next;
            return None;
        };
        let pose = |s: &GridSample| [s.sig[0], s.sig[1], s.sig[2]];
        let p0 = self.pose_before.unwrap_or(pose(&c));
        let p1 = next.as_ref().map_or(pose(&c), pose);
        let steps = usize::from(self.pose_before.is_some()) + usize::from(next.is_some());
        let dt = steps as f64 * h;
        let v = (p1[0] - p0[0]).hypot(p1[1] - p0[1]) / dt;
        let om = (p1[2] - p0[2]) / dt;
        c.sig[6] = v * om;
        self.pose_before = Some(pose(&c));
        self.pose_wait = next;
        Some(c)
    }
}

/// The runs, parts, checks and output of the streamed import.
#[derive(Debug)]
pub(crate) struct Assembler {
    h: f64,
    origin_s: f64,
    min_samples: usize,
    c_e: f64,
    half_first: usize,
    half_judge: usize,
    /// Half the roll's smoothing window, when there is a bank.
    half_roll: Option<usize>,
    /// a_y is derived from the pose (`from_pose`).
    from_pose: bool,
    /// Valid samples of a run not yet `min_part_s` long.
    run: Vec<GridSample>,
    /// The current run: first grid index, valid?
    run_start: Option<(usize, bool)>,
    run_len: usize,
    gap_reasons: Vec<String>,
    pipe: Option<PartPipe>,
    unwrap: crate::drive::Unwrap,
    prev_xy: Option<(f64, f64)>,
    /// Kept samples ready to be taken.
    pub out: VecDeque<OutSample>,
    /// The runs so far.
    pub gaps: Vec<GapRecord>,
    pub parts: Vec<PartRecord>,
    /// Kept parts and samples so far.
    pub kept_parts: usize,
    pub samples: usize,
    /// Reference path length of the kept samples, m.
    pub distance_m: f64,
    /// The smoothed roll over the kept samples: sum and largest |φ|, rad.
    pub phi_sum: f64,
    pub phi_max: f64,
    /// The jitter report's speed noise, when the wheels are de-jittered.
    pub noise: SpeedNoise,
}

impl Assembler {
    /// The assembly of `m`'s output at step `h`; grid index 0 is at
    /// wheel-clock time `origin_s`.
    pub(crate) fn new(m: &Manifest, h: f64, origin_s: f64) -> Assembler {
        let half = |span_s: f64| super::super::signal::odd_width(span_s, h) / 2;
        let (half_first, half_judge) = match &m.lateral_acceleration {
            LateralAccelerationSpec::Imu { .. } => (0, 0),
            LateralAccelerationSpec::FromWheels { smoothing_s, .. }
            | LateralAccelerationSpec::FromPose { smoothing_s, .. } => {
                (half(*smoothing_s), half(A_Y_CHECK_SMOOTHING_S))
            }
        };
        Assembler {
            h,
            origin_s,
            min_samples: ((m.output.min_part_s / h).ceil() as usize).max(2),
            c_e: m.output.theta0[0],
            half_first,
            half_judge,
            half_roll: m.lateral_acceleration.bank().map(|b| half(b.smoothing_s)),
            from_pose: matches!(m.lateral_acceleration, LateralAccelerationSpec::FromPose { .. }),
            run: Vec::new(),
            run_start: None,
            run_len: 0,
            gap_reasons: Vec::new(),
            pipe: None,
            unwrap: Default::default(),
            prev_xy: None,
            out: VecDeque::new(),
            gaps: Vec::new(),
            parts: Vec::new(),
            kept_parts: 0,
            samples: 0,
            distance_m: 0.0,
            // the start of a sum over no term, as the whole import's mean
            phi_sum: std::iter::empty::<f64>().sum(),
            phi_max: 0.0,
            noise: SpeedNoise::default(),
        }
    }

    /// Where sample `k` is, for messages.
    fn at(&self, k: usize) -> String {
        grid_time(k, self.h, self.origin_s)
    }

    /// Takes the next grid sample (grid indices consecutive from 0).
    pub(crate) fn push(&mut self, m: &Manifest, s: GridSample) -> Result<()> {
        let ok = s.invalid.is_none();
        match self.run_start {
            Some((_, was_ok)) if was_ok == ok => {}
            Some(_) => {
                self.close_run(m)?;
                self.run_start = Some((s.k, ok));
            }
            None => self.run_start = Some((s.k, ok)),
        }
        self.run_len += 1;
        if !ok {
            if let Some(r) = &s.invalid {
                if !self.gap_reasons.contains(r) {
                    self.gap_reasons.push(r.clone());
                }
            }
            return Ok(());
        }
        if self.pipe.is_some() {
            return self.feed(m, s);
        }
        self.run.push(s);
        if self.run.len() >= self.min_samples {
            let smoother = |half: usize| (half > 0).then(|| Smoother::new(half));
            self.pipe = Some(PartPipe {
                first: smoother(self.half_first),
                roll: self.half_roll.map(smoother),
                judge: smoother(self.half_judge),
                waiting: VecDeque::new(),
                a_q: VecDeque::new(),
                phi_q: VecDeque::new(),
                smoothed: VecDeque::new(),
                phis: VecDeque::new(),
                judged: VecDeque::new(),
                pose_wait: None,
                pose_before: None,
            });
            for s in std::mem::take(&mut self.run) {
                self.feed(m, s)?;
            }
        }
        Ok(())
    }

    /// Ends the current run (at the end of the drive too).
    pub(crate) fn close_run(&mut self, m: &Manifest) -> Result<()> {
        let Some((k0, ok)) = self.run_start.take() else { return Ok(()) };
        let h = self.h;
        let len = std::mem::take(&mut self.run_len);
        if !ok {
            self.gaps.push(GapRecord {
                t_start_s: k0 as f64 * h,
                t_end_s: (k0 + len) as f64 * h,
                reasons: std::mem::take(&mut self.gap_reasons),
            });
            return Ok(());
        }
        let keep = self.pipe.is_some();
        self.parts.push(PartRecord::new(k0..k0 + len, h, keep, m.output.min_part_s));
        self.run.clear();
        if let Some(mut p) = self.pipe.take() {
            if let Some(s) = p.a_y_from_pose(None, h) {
                self.smooth(m, &mut p, s)?;
            }
            if let Some(f) = p.first.as_mut() {
                let mut out = Vec::new();
                f.finish(&mut out);
                p.a_q.extend(out);
            }
            if let Some(Some(r)) = p.roll.as_mut() {
                let mut out = Vec::new();
                r.finish(&mut out);
                p.phi_q.extend(out);
            }
            self.smoothed_ready(m, &mut p)?;
            let mut out = Vec::new();
            if let Some(j) = p.judge.as_mut() {
                j.finish(&mut out);
            }
            p.judged.extend(out);
            self.emit_ready(m, &mut p)?;
            self.kept_parts += 1;
            self.prev_xy = None;
        }
        Ok(())
    }

    /// A valid sample of a kept part: the wheel speed check, a_y from the
    /// pose (one sample later), then the smoothing stages.
    fn feed(&mut self, m: &Manifest, s: GridSample) -> Result<()> {
        self.check_wheels(m, &s)?;
        let Some(mut p) = self.pipe.take() else { return Ok(()) };
        let ready = if self.from_pose { p.a_y_from_pose(Some(s), self.h) } else { Some(s) };
        let r = match ready {
            Some(s) => self.smooth(m, &mut p, s),
            None => Ok(()),
        };
        self.pipe = Some(p);
        r
    }

    /// A sample with its a_y into the smoothing stages.
    fn smooth(&mut self, m: &Manifest, p: &mut PartPipe, s: GridSample) -> Result<()> {
        let (a, phi) = (s.sig[6], s.phi);
        p.waiting.push_back(s);
        let mut out = Vec::new();
        match p.first.as_mut() {
            Some(f) => f.feed(a, &mut out),
            None => out.push(a),
        }
        p.a_q.extend(out);
        if let Some(roll) = p.roll.as_mut() {
            let mut out = Vec::new();
            match roll {
                Some(r) => r.feed(phi, &mut out),
                None => out.push(phi),
            }
            p.phi_q.extend(out);
        }
        self.smoothed_ready(m, p)
    }

    /// Smoothed a_y (with a bank, combined with the smoothed roll into the
    /// specific force): into the judging stage, then out when judged.
    fn smoothed_ready(&mut self, m: &Manifest, p: &mut PartPipe) -> Result<()> {
        let mut judged = Vec::new();
        while !p.a_q.is_empty() && (p.roll.is_none() || !p.phi_q.is_empty()) {
            let Some(mut a) = p.a_q.pop_front() else { break };
            if p.roll.is_some() {
                let Some(phi) = p.phi_q.pop_front() else { break };
                a = specific_force(a, phi);
                p.phis.push_back(phi);
            }
            p.smoothed.push_back(a);
            match p.judge.as_mut() {
                Some(j) => j.feed(a, &mut judged),
                None => judged.push(a),
            }
        }
        p.judged.extend(judged);
        self.emit_ready(m, p)
    }

    /// Hands out the samples whose a_y is smoothed and judged.
    fn emit_ready(&mut self, m: &Manifest, p: &mut PartPipe) -> Result<()> {
        while let Some(judged) = p.judged.pop_front() {
            let (Some(mut s), Some(a)) = (p.waiting.pop_front(), p.smoothed.pop_front()) else { break };
            if !within(judged, m.limits.max_lateral_acceleration_m_per_s2) {
                return Err(lateral_acceleration_error(m, judged, &self.at(s.k)));
            }
            s.sig[6] = a;
            if let Some(phi) = p.phis.pop_front() {
                self.phi_sum += phi;
                self.phi_max = self.phi_max.max(phi.abs());
            }
            s.sig[2] = self.unwrap.next(s.sig[2]);
            if let Some((x0, y0)) = self.prev_xy {
                self.distance_m += (s.sig[0] - x0).hypot(s.sig[1] - y0);
            }
            self.prev_xy = Some((s.sig[0], s.sig[1]));
            self.samples += 1;
            if let Some([l, r]) = s.raw {
                self.noise.push(self.kept_parts, [l, r, s.sig[3], s.sig[4]]);
            }
            self.out.push_back(OutSample {
                part: self.kept_parts,
                t: s.k as f64 * self.h,
                sig: s.sig,
                measured: s.measured,
            });
        }
        Ok(())
    }

    /// Each wheel's speed at θ_0 within `limits.max_speed_m_per_s`.
    fn check_wheels(&self, m: &Manifest, s: &GridSample) -> Result<()> {
        for (n, key) in [(s.sig[3], "wheels.rear_left"), (s.sig[4], "wheels.rear_right")] {
            wheel_speed(m, key, n, self.c_e, || self.at(s.k))?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_smoother_is_the_moving_average() {
        let x: Vec<f64> = (0..50).map(|i| (i as f64 * 0.37).sin() * 3.0 + i as f64 * 0.01).collect();
        for half in [1usize, 2, 5, 30] {
            let mut whole = x.clone();
            crate::drive::plausibility::moving_average(&mut whole, 0..x.len(), 2 * half + 1);
            let mut s = Smoother::new(half);
            let mut out = Vec::new();
            for &v in &x {
                s.feed(v, &mut out);
            }
            s.finish(&mut out);
            assert_eq!(out.len(), x.len());
            for (a, b) in out.iter().zip(&whole) {
                assert_eq!(a.to_bits(), b.to_bits(), "half {half}");
            }
        }
    }
}
