//! Online calibration: θ kept current while a drive streams in.
//!
//! For programs that calibrate as the vehicle drives (a ROS 2 node, a
//! replay of logs in time order): [`Calibrator::push`] takes the drive's
//! canonical samples chunk by chunk and keeps θ with its σ at any time, in
//! memory that does not grow with the drive's length;
//! [`Calibrator::push_drive`] pushes a drive in memory, and
//! [`Calibrator::push_replay`] a drive file read as a stream
//! ([`odocal::io::Replay`]). The gates ([`gate`]) judge whether an
//! estimate should replace the stored θ; `odocal follow` (the crate
//! odocal-history) replays drive files through a calibrator and writes
//! back to a vehicle's history what the gates pass.
//!
//! The crate builds on the library odocal: the segments and their
//! Gauss-Newton normal equations
//! ([`odocal::identify::extrinsics_normal_equations`]) are the
//! calibration's; batch calibration itself does not use this crate.
//!
//! ## The method: recursive Gauss-Newton over the paper's segments
//!
//! The samples are cut into the calibration's segments as they arrive
//! (650 steps every 100, [`odocal::segment`]). When a segment completes
//! (and turns enough, when a yaw-rate threshold is set), its dead-reckoning
//! residual is linearised at the current estimate and folded into an
//! information-form state over `x = [c_e, c_d, t_r, d, δ]`, `δ` the
//! reference's heading offset on the current drive:
//!
//! ```text
//! P ← P + Q·Δt                                   (random walk of θ)
//! Λ₀ = P⁻¹,  H = f·JᵀWJ/s²,  g = f·JᵀW r/s²      (at x_i, i = 0, 1, …)
//! x_{i+1} = x₀ + (Λ₀ + H)⁻¹ (g + H (x_i − x₀)),   P ← (Λ₀ + H)⁻¹
//! ```
//!
//! with `J`, `r` the segment's Jacobian and residual from the library's
//! Gauss-Newton (the rollout with reference extrinsics), `f` a segment's
//! weight ([`OnlineOptions::information_scale`]: consecutive segments share
//! most samples and a segment's residuals are correlated), `s²` a running
//! estimate of the weighted residual
//! variance and `Q` the random walk of [`RandomWalk`]. The σ reported
//! ([`Status::sigma`]) is `P`'s, times per-parameter factors
//! ([`OnlineOptions::sigma_factors`]) that make it cover the truth on
//! simulated drives; `P` itself drives the updates unchanged. Each fold costs
//! a few rollouts of one segment (a few hundred microseconds), and the
//! state is a 5-vector and a 5×5 matrix; the sample buffer holds at most
//! one validation segment and a little more. A new drive resets `δ` (its
//! mean to 0, its variance to the prior, its correlations with θ to 0).
//!
//! The errors-in-variables estimator ([`odocal::eiv`]) corrects the bias
//! that input noise puts into Gauss-Newton, but it runs a filter and a
//! smoother over the whole drive per iteration: its memory grows with the
//! drive and a recursive form of it is not available. The online
//! calibrator trades that bias correction for constant cost per sample;
//! docs/method.md says more.
//!
//! ## The prequential error
//!
//! The validation segments (1300 steps every 650) are dead-reckoned with
//! the θ and δ known when each segment *starts*, and scored when it ends:
//! the mean of those errors is the drive's prequential Ē_p
//! ([`DriveSummary::prequential_mean_position_error_m`]), a held-out error
//! of the online estimate.

#![forbid(unsafe_code)]
#![deny(clippy::float_cmp)]
// Numerical loops index several parallel arrays at once; index loops read like the maths.
#![allow(clippy::needless_range_loop)]

use std::collections::VecDeque;

use nalgebra::{SMatrix, SVector};
use serde::{Deserialize, Serialize};

use odocal::identify::extrinsics_normal_equations;
use odocal::io::Replay;
use odocal::segment::SegmentData;
use odocal::{dead_reckoning, Drive, Error, Extrinsics, Result, Signals, StreamChunk, Theta};

pub mod gate;
mod options;

pub use options::*;

type Vec5 = SVector<f64, 5>;
type Mat5 = SMatrix<f64, 5, 5>;

/// Indices of `[c_e, c_d, t_r, d, heading_offset]` in the library's
/// seven-vector of θ with the reference extrinsics.
const JOINT: [usize; 5] = [0, 1, 2, 3, 6];

/// The smallest residual variance used (noise-free data), weighted m².
const MIN_RESIDUAL_VARIANCE: f64 = 1e-12;

/// Weight of a new segment in the running residual variance.
const RESIDUAL_VARIANCE_GAIN: f64 = 0.1;

/// Steps between pushed samples larger than this many sample times are a
/// gap ([`Calibrator::push`]): a new continuous part starts after them.
const GAP_STEPS: f64 = 1.5;

/// Relative tolerance of a step against the sample time (as a drive's).
const STEP_TOLERANCE: f64 = 0.01;

/// A chunk of canonical samples (the [`Drive`] columns), in time order.
#[derive(Debug, Clone, Copy)]
struct Chunk<'a> {
    /// Reference x, m.
    pub px: &'a [f64],
    /// Reference y, m.
    pub py: &'a [f64],
    /// Reference heading, rad, unwrapped.
    pub psi: &'a [f64],
    /// Rear-left wheel rotation, rev/s.
    pub n_rl: &'a [f64],
    /// Rear-right wheel rotation, rev/s.
    pub n_rr: &'a [f64],
    /// Sideslip, rad.
    pub beta: &'a [f64],
    /// Lateral acceleration, m/s².
    pub a_y: &'a [f64],
}

impl<'a> Chunk<'a> {
    /// Samples `range` of a drive.
    fn of(drive: &'a Drive, range: std::ops::Range<usize>) -> Chunk<'a> {
        let r = range;
        let m = drive.measured();
        Chunk {
            px: &m.px[r.clone()],
            py: &m.py[r.clone()],
            psi: &m.psi[r.clone()],
            n_rl: &m.n_rl[r.clone()],
            n_rr: &m.n_rr[r.clone()],
            beta: &m.beta[r.clone()],
            a_y: &m.a_y[r],
        }
    }

    /// All samples of `signals`.
    fn of_signals(signals: &'a Signals) -> Chunk<'a> {
        let s = signals;
        Chunk { px: &s.px, py: &s.py, psi: &s.psi, n_rl: &s.n_rl, n_rr: &s.n_rr, beta: &s.beta, a_y: &s.a_y }
    }

    /// Samples `r` of the chunk.
    fn range(&self, r: std::ops::Range<usize>) -> Chunk<'a> {
        Chunk {
            px: &self.px[r.clone()],
            py: &self.py[r.clone()],
            psi: &self.psi[r.clone()],
            n_rl: &self.n_rl[r.clone()],
            n_rr: &self.n_rr[r.clone()],
            beta: &self.beta[r.clone()],
            a_y: &self.a_y[r],
        }
    }

    fn columns(&self) -> [&'a [f64]; 7] {
        [self.px, self.py, self.psi, self.n_rl, self.n_rr, self.beta, self.a_y]
    }
}

/// Unwraps a heading that arrives chunk by chunk, as [`Drive`] unwraps a
/// whole column: every step larger than π in magnitude is taken as a 2π
/// wrap, with the same arithmetic, so a stream unwrapped chunk by chunk
/// equals the drive's column bit for bit.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct HeadingUnwrap {
    offset: f64,
    prev_raw: Option<f64>,
}

impl HeadingUnwrap {
    /// Unwraps the next samples in place, continuing from the last chunk.
    fn unwrap(&mut self, psi: &mut [f64]) {
        let two_pi = 2.0 * std::f64::consts::PI;
        for v in psi.iter_mut() {
            let raw = *v;
            if let Some(prev) = self.prev_raw {
                let d = raw - prev;
                if d > std::f64::consts::PI {
                    self.offset -= two_pi * ((d + std::f64::consts::PI) / two_pi).floor();
                } else if d < -std::f64::consts::PI {
                    self.offset += two_pi * ((-d + std::f64::consts::PI) / two_pi).floor();
                }
                *v = raw + self.offset;
            }
            self.prev_raw = Some(raw);
        }
    }
}

/// One validation segment scored when it completed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct ValidationScore {
    /// Time of its first sample from the start of the drive, s.
    pub start_s: f64,
    /// Its E_p,s with the θ and δ known when it started, m.
    pub prequential_m: f64,
    /// Its E_p,s with the stored θ ([`Calibrator::stored`]) and the
    /// same δ, m; `None` without a stored θ.
    pub stored_m: Option<f64>,
}

/// What the calibrator saw of the current drive.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct DriveSummary {
    /// Samples pushed.
    pub samples: usize,
    /// Calibration segments folded in (those that turned enough).
    pub folded_segments: usize,
    /// Validation segments scored.
    pub validation_segments: usize,
    /// Mean of their prequential E_p,s, m; `None` before the first.
    pub prequential_mean_position_error_m: Option<f64>,
    /// Mean of their E_p,s with the stored θ, m; `None` without one.
    pub stored_mean_position_error_m: Option<f64>,
}

/// θ from one drive's data alone ([`Status::drive_estimate`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct OwnEstimate {
    /// The estimate.
    pub theta: Theta,
    /// Its σ, scaled as [`Status::sigma`] is.
    pub sigma: Theta,
}

/// A snapshot of a [`Calibrator`] ([`Calibrator::status`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Status {
    /// The current estimate of θ.
    pub theta: Theta,
    /// θ's standard deviation: the recursion's, times the options'
    /// [`OnlineOptions::sigma_factors`].
    pub sigma: Theta,
    /// The covariance of `[c_e, c_d, t_r, d, δ]`, θ's rows and columns
    /// scaled by the options' [`OnlineOptions::sigma_factors`] (δ's by 1),
    /// so that its diagonal is `sigma` squared.
    pub covariance: [[f64; 5]; 5],
    /// The current drive's heading offset δ (reference heading minus the
    /// vehicle's), rad.
    pub heading_offset_rad: f64,
    /// δ's standard deviation, rad.
    pub heading_offset_sd_rad: f64,
    /// The sample time the calibrator was made for, s.
    pub sample_time_s: f64,
    /// Informative driving so far: the new samples (stride × sample time)
    /// of every folded segment whose peak yaw rate reached the options'
    /// `informative_yaw_rate_rad_per_s`, s.
    pub informative_time_s: f64,
    /// Samples held in the buffer: bounded by the longest segment and its
    /// stride plus one chunk, whatever the drive's length.
    pub buffered_samples: usize,
    /// What the calibrator saw of the current drive.
    pub drive: DriveSummary,
    /// The current drive's most recently scored validation segments, oldest first.
    pub recent_validation: Vec<ValidationScore>,
    /// θ from the current drive's folded segments alone, without the prior
    /// the recursion carries from earlier drives (each segment linearised
    /// where the recursion stood, with its weight): where this drive puts
    /// θ. `None` until the drive determines every parameter.
    pub drive_estimate: Option<OwnEstimate>,
}

/// The sample columns kept for the segments still to complete.
#[derive(Debug, Default, Clone)]
struct Buffer {
    cols: [Vec<f64>; 7],
    /// Index in the part of `cols[_][0]`.
    base: usize,
    /// Samples of the part received.
    len: usize,
}

impl Buffer {
    fn clear(&mut self) {
        self.cols.iter_mut().for_each(Vec::clear);
        self.base = 0;
        self.len = 0;
    }

    fn segment(&self, start: usize, steps: usize, sample_time_s: f64) -> SegmentData<'_> {
        let a = start - self.base;
        let c = &self.cols;
        SegmentData {
            start,
            drive_start: 0,
            sample_time_s,
            px: &c[0][a..=a + steps],
            py: &c[1][a..=a + steps],
            psi: &c[2][a..=a + steps],
            n_rl: &c[3][a..a + steps],
            n_rr: &c[4][a..a + steps],
            beta: &c[5][a..a + steps],
            a_y: &c[6][a..a + steps],
        }
    }

    /// Drops the samples before `keep_from` once enough have piled up.
    fn trim(&mut self, keep_from: usize, slack: usize) {
        let drop = keep_from.saturating_sub(self.base);
        if drop > slack {
            self.cols.iter_mut().for_each(|c| {
                c.drain(..drop);
            });
            self.base += drop;
        }
    }
}

/// A validation segment that has started: its start and the θ, δ then.
#[derive(Debug, Clone, Copy)]
struct Pending {
    start: usize,
    theta: Theta,
    heading_offset: f64,
}

/// The online calibrator: a recursive Gauss-Newton over the calibration
/// segments of a stream of samples (the crate's docs give the method).
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal_online::{Calibrator, OnlineOptions};
/// use odocal::{sim, Theta};
/// let out = sim::simulate(&sim::SimOptions { length_km: 3.0, noise: "off".parse()?, ..sim::SimOptions::paper(2) })?;
/// let d = &out.drive;
/// let mut cal = Calibrator::new(Theta::PAPER_NOMINAL, None, d.sample_time_s(), OnlineOptions::default())?;
/// // The drive in chunks of 400 samples, as they would arrive.
/// cal.push_drive(d, 400, |_| {})?;
/// let truth = out.sidecar.theta_true;
/// assert!((cal.status().theta.c_e - truth.c_e).abs() < 1e-3 * truth.c_e);
/// # Ok(()) }
/// ```
#[derive(Debug, Clone)]
pub struct Calibrator {
    opts: OnlineOptions,
    sample_time_s: f64,
    x: Vec5,
    p: Mat5,
    buf: Buffer,
    next_cal: usize,
    next_val: usize,
    pending: VecDeque<Pending>,
    /// Driving time since the calibrator started, s.
    clock_s: f64,
    /// `clock_s` at the current part's first sample.
    part_clock_s: f64,
    /// The driving time up to which the random walk was applied, s.
    noise_applied_s: f64,
    residual_variance: Option<f64>,
    informative_s: f64,
    track: VecDeque<(f64, Theta)>,
    /// The θ to compare the online estimate with on each validation
    /// segment (the parameters in use); `None` (the default) scores the
    /// online estimate only.
    pub stored: Option<Theta>,
    drive: DriveState,
    /// The heading of [`Calibrator::push`] unwrapped across its pushes.
    unwrap: HeadingUnwrap,
    /// The time of the last sample [`Calibrator::push`] took with times.
    last_t: Option<f64>,
    /// The last step of the previous push when it was a gap, s.
    last_gap_s: Option<f64>,
}

/// Counters of the current drive.
#[derive(Debug, Clone, Default)]
struct DriveState {
    /// The heading offset seen in the direction of travel: Σ wₖδₖ and Σ wₖ
    /// ([`Calibrator::course_heading_offset`]).
    course_sum: f64,
    course_weight: f64,
    /// The last sample of the current part `(px, py, psi)`.
    last_pose: Option<[f64; 3]>,
    /// The sideslip of the last sample.
    last_beta: f64,
    /// The next sample of the part to observe.
    course_next: usize,
    samples: usize,
    folded: usize,
    scored: usize,
    prequential_sum: f64,
    stored_sum: f64,
    recent: VecDeque<ValidationScore>,
    /// The drive's own normal equations over `[θ, δ]`, without the prior:
    /// Σ H_k and Σ (g_k + H_k x_k) of its folded segments, each linearised
    /// where the recursion stood (`x_k`) with the recursion's weight.
    own_h: Mat5,
    own_b: Vec5,
}

impl Calibrator {
    /// A calibrator starting at `theta0` with sd `sigma0` (`None`: the
    /// options' prior), for samples every `sample_time_s` seconds.
    /// `sigma0` is a reported σ (as [`Status::sigma`] gives it): the
    /// recursion starts from it divided by the options' `sigma_factors`,
    /// so a calibrator restarted from another's θ and σ continues its
    /// recursion. A σ of 0 (all four, or some) stands for "not known": the
    /// options' prior is used for all four, as with `None`.
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the field: invalid options, a sample
    /// time that is not a positive number, a `sigma0` with a negative or
    /// non-finite component; [`Error::InvalidTheta`] for a θ_0 outside its
    /// physical limits ([`Theta::check_physical_limits`]).
    pub fn new(theta0: Theta, sigma0: Option<Theta>, sample_time_s: f64, opts: OnlineOptions) -> Result<Calibrator> {
        opts.validate()?;
        if !(sample_time_s.is_finite() && sample_time_s > 0.0) {
            return Err(Error::InvalidOption { field: "sample_time_s", reason: "must be positive".into() });
        }
        theta0.check_physical_limits()?;
        if let Some(s) = sigma0 {
            let named = ["c_e", "c_d", "t_r", "d"].into_iter().zip(<[f64; 4]>::from(s));
            if let Some((name, v)) = named.into_iter().find(|(_, v)| !(v.is_finite() && *v >= 0.0)) {
                let reason = format!("{name} = {v}: a σ must be a finite number, 0 or more");
                return Err(Error::InvalidOption { field: "sigma0", reason });
            }
        }
        let sd = match sigma0 {
            Some(s) if <[_; 4]>::from(s).iter().all(|v| v.is_finite() && *v > 0.0) => {
                let f = opts.sigma_factors;
                std::array::from_fn(|i| <[_; 4]>::from(s)[i] / f[i])
            }
            _ => opts.prior_sd(&theta0),
        };
        let t = <[_; 4]>::from(theta0);
        let x = Vec5::from_column_slice(&[t[0], t[1], t[2], t[3], 0.0]);
        let mut p = Mat5::zeros();
        for i in 0..4 {
            p[(i, i)] = sd[i] * sd[i];
        }
        p[(4, 4)] = opts.heading_offset_prior_sd_rad.powi(2);
        Ok(Calibrator {
            sample_time_s,
            x,
            p,
            buf: Buffer::default(),
            next_cal: opts.segments.offset_steps,
            next_val: opts.validation.offset_steps,
            pending: VecDeque::new(),
            clock_s: 0.0,
            part_clock_s: 0.0,
            noise_applied_s: 0.0,
            residual_variance: None,
            informative_s: 0.0,
            track: VecDeque::new(),
            stored: None,
            drive: DriveState::default(),
            unwrap: HeadingUnwrap::default(),
            last_t: None,
            last_gap_s: None,
            opts,
        })
    }

    /// Starts a new drive: a new continuous part, the heading offset reset
    /// (mean 0, the prior's variance, no correlation with θ) and the drive's
    /// counters cleared. θ and its covariance carry over.
    pub fn begin_drive(&mut self) {
        self.begin_part();
        self.x[4] = 0.0;
        for i in 0..5 {
            self.p[(i, 4)] = 0.0;
            self.p[(4, i)] = 0.0;
        }
        self.p[(4, 4)] = self.opts.heading_offset_prior_sd_rad.powi(2);
        self.drive = DriveState::default();
        self.unwrap = HeadingUnwrap::default();
        self.last_t = None;
        self.last_gap_s = None;
    }

    /// Starts a new continuous part of the current drive (after a gap):
    /// segments never span two parts. Segments of the old part that had
    /// not completed are dropped.
    pub fn begin_part(&mut self) {
        self.buf.clear();
        self.drive.last_pose = None;
        self.drive.course_next = 0;
        self.part_clock_s = self.clock_s;
        self.next_cal = self.opts.segments.offset_steps;
        self.next_val = self.opts.validation.offset_steps;
        self.pending.clear();
    }

    /// Takes the next samples of the current drive, in time order, as a
    /// live system sends them: the [`Drive`] columns, the heading wrapped or
    /// not (it is unwrapped across pushes as [`Drive`] unwraps a column,
    /// until [`Calibrator::begin_drive`]), with their times `t` when known.
    /// With `t`, each step must be the sample time (within 1 %) or a gap of
    /// more than 1.5 sample times, after which a new continuous part starts
    /// ([`Calibrator::begin_part`]); without it, the samples follow the
    /// previous ones. Folds every calibration segment the samples complete
    /// and scores every validation segment they complete.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] for columns (or `t`) of another length than
    /// `px`; [`Error::InvalidOption`] for times that do not fit: a step
    /// neither the sample time nor a gap, or two gaps in a row of one
    /// length (samples at another rate than `sample_time_s`, which would
    /// each start a part and fold nothing);
    /// [`Error::InvalidSample`] naming the column and the sample (of this
    /// push) of a value that is not finite.
    pub fn push(&mut self, t: Option<&[f64]>, samples: &Signals) -> Result<()> {
        let s = samples;
        let cols = s.columns();
        let n = s.px.len();
        let mut lengths = cols.iter().map(|(name, c)| (*name, c.len())).chain(t.map(|t| ("t", t.len())));
        if let Some((name, len)) = lengths.find(|c| c.1 != n) {
            return Err(Error::InvalidDrive {
                context: "the pushed samples".into(),
                reason: format!("column {name} has {len} samples, px has {n}"),
            });
        }
        // A value that is not finite, named by its column and sample (of this push).
        for (name, col) in cols.iter().chain(t.map(|t| ("t", t)).as_ref()) {
            if let Some(i) = col.iter().position(|v| !v.is_finite()) {
                return Err(Error::InvalidSample {
                    context: "the pushed samples".into(),
                    column: (*name).to_string(),
                    sample: i,
                    reason: format!("value {} is not finite", col[i]),
                });
            }
        }
        let (starts, last_gap) = match t {
            Some(t) => self.part_starts(t)?,
            None => (Vec::new(), None),
        };
        let mut psi = s.psi.clone();
        self.unwrap.unwrap(&mut psi);
        // Each part's samples, a new part begun at each gap.
        let mut from = 0;
        for to in starts.iter().copied().chain([n]) {
            if starts.contains(&from) {
                self.begin_part();
            }
            let r = from..to;
            let chunk = Chunk { psi: &psi[r.clone()], ..Chunk::of_signals(s).range(r) };
            self.push_chunk(&chunk)?;
            from = to;
        }
        if let Some(last) = t.and_then(|t| t.last()) {
            self.last_t = Some(*last);
            self.last_gap_s = last_gap;
        }
        Ok(())
    }

    /// Checks times against the sample time; returns the sample indices
    /// where a new part starts (after a gap), the first possibly 0, and
    /// the last step when it was a gap.
    ///
    /// Two gaps in a row of one length (within 1 %) leave a part of one
    /// sample between them: not gaps but samples that come at another
    /// rate than the calibrator was made for, which would each start a
    /// part and fold nothing.
    fn part_starts(&self, t: &[f64]) -> Result<(Vec<usize>, Option<f64>)> {
        let ts = self.sample_time_s;
        let mut starts = Vec::new();
        let mut prev = self.last_t;
        let mut last_gap = self.last_gap_s;
        // Every time is finite: `push` checked them.
        for (i, &ti) in t.iter().enumerate() {
            if let Some(p) = prev {
                let step = ti - p;
                if step > GAP_STEPS * ts {
                    if last_gap.is_some_and(|g| (step - g).abs() <= STEP_TOLERANCE * g) {
                        return Err(Error::InvalidOption {
                            field: "sample_time_s",
                            reason: format!(
                                "sample {i}: the samples come every {step} s, not every {ts} s (the sample \
                                 time the calibrator was made for): each step would be a gap and nothing \
                                 would be folded; make the calibrator with sample_time_s = {step}"
                            ),
                        });
                    }
                    starts.push(i);
                    last_gap = Some(step);
                    prev = Some(ti);
                    continue;
                } else if (step - ts).abs() > STEP_TOLERANCE * ts {
                    return Err(Error::InvalidOption {
                        field: "t",
                        reason: format!(
                            "sample {i}: step {step} s from the previous sample is not the sample time {ts} s \
                             (within 1 %) nor a gap (more than {GAP_STEPS} sample times)"
                        ),
                    });
                }
            }
            prev = Some(ti);
            last_gap = None;
        }
        Ok((starts, last_gap))
    }

    /// Takes the next samples of the current part, in time order; folds
    /// every calibration segment they complete and scores every validation
    /// segment they complete. The columns must have one length.
    fn push_chunk(&mut self, chunk: &Chunk<'_>) -> Result<()> {
        let cols = chunk.columns();
        let n = cols[0].len();
        if cols.iter().any(|c| c.len() != n) {
            return Err(Error::InvalidOption { field: "chunk", reason: "columns of different lengths".into() });
        }
        if let Some(bad) = cols.iter().position(|c| c.iter().any(|v| !v.is_finite())) {
            let names = ["px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"];
            return Err(Error::InvalidOption {
                field: "chunk",
                reason: format!("column {} holds a value that is not finite", names[bad]),
            });
        }
        for (b, c) in self.buf.cols.iter_mut().zip(cols) {
            b.extend_from_slice(c);
        }
        self.buf.len += n;
        self.drive.samples += n;
        self.clock_s += n as f64 * self.sample_time_s;
        self.process();
        self.observe_course(self.buf.len);
        let keep_from = self.pending.front().map_or(self.next_val, |p| p.start).min(self.next_cal);
        self.buf.trim(keep_from, self.opts.validation.length_steps);
        Ok(())
    }

    /// Adds the steps up to sample `i` of the part (inclusive) to the
    /// heading offset seen in the direction of travel: over a step of the
    /// reference point the course is the vehicle's heading plus the
    /// sideslip (the model's `ψ + ω·t_s/2 + β`), so
    /// `δₖ = (ψ̃ₖ + ψ̃ₖ₊₁)/2 − βₖ − atan2(Δy, Δx)`, weighted by the step's
    /// length (steps slower than 1 m/s are left out).
    fn observe_course(&mut self, i: usize) {
        let min_step = self.sample_time_s;
        let (c, base) = (&self.buf.cols, self.buf.base);
        let d = &mut self.drive;
        while d.course_next <= i && d.course_next < self.buf.len {
            let j = d.course_next - base;
            let now = [c[0][j], c[1][j], c[2][j]];
            if let Some(prev) = d.last_pose {
                let (dx, dy) = (now[0] - prev[0], now[1] - prev[1]);
                let len = dx.hypot(dy);
                if len > min_step {
                    let delta = wrap_angle(0.5 * (prev[2] + now[2]) - d.last_beta - dy.atan2(dx));
                    d.course_sum += len * delta;
                    d.course_weight += len;
                }
            }
            d.last_pose = Some(now);
            d.last_beta = c[5][j];
            d.course_next += 1;
        }
    }

    /// The current drive's heading offset from the direction of travel
    /// (the calibrator's first estimate of δ, before a segment is folded), rad;
    /// `None` before the vehicle has moved.
    pub(crate) fn course_heading_offset(&self) -> Option<f64> {
        let d = &self.drive;
        (d.course_weight > 0.0).then(|| d.course_sum / d.course_weight)
    }

    /// δ as known now: the filter's once the drive has a folded segment,
    /// else the one from the direction of travel (0 before any motion).
    fn heading_offset_now(&self) -> f64 {
        if self.drive.folded > 0 || !self.opts.heading_offset {
            self.x[4]
        } else {
            self.course_heading_offset().unwrap_or(0.0)
        }
    }

    /// Handles every event the samples received so far allow, in sample
    /// order: a calibration segment's end (folded), a validation segment's
    /// start (θ noted) and its end (scored). At one sample a fold comes
    /// first: a segment ending at a validation segment's start pose is data
    /// known when it starts.
    fn process(&mut self) {
        let (k, stride) = (self.opts.segments.length_steps, self.opts.segments.stride_steps);
        let kv = self.opts.validation.length_steps;
        loop {
            let have = self.buf.len;
            let cal_end = self.next_cal + k;
            let val_start = self.next_val;
            let val_end = self.pending.front().map(|p| p.start + kv);
            let candidates = [Some(cal_end), Some(val_start), val_end];
            let Some(next) = candidates.iter().flatten().copied().filter(|&i| i < have).min() else { break };
            self.observe_course(next);
            if next == cal_end {
                self.fold(self.next_cal);
                self.next_cal += stride;
            } else if next == val_start {
                let heading_offset = self.heading_offset_now();
                self.pending.push_back(Pending { start: val_start, theta: self.theta(), heading_offset });
                self.next_val += self.opts.validation.stride_steps;
            } else if let Some(p) = self.pending.pop_front() {
                self.score(&p);
            }
        }
    }

    /// Adds the random walk's variance for the driving time up to sample
    /// `i` of the current part since it was last added.
    fn add_process_noise(&mut self, i: usize) {
        let now = self.part_clock_s + i as f64 * self.sample_time_s;
        let hours = (now - self.noise_applied_s).max(0.0) / 3600.0;
        self.noise_applied_s = now;
        let sd = self.opts.random_walk.sd_per_hour(&self.theta());
        for i in 0..4 {
            self.p[(i, i)] += sd[i] * sd[i] * hours;
        }
    }

    /// The segment's normal equations over `[θ, δ]` at `x`, weighted by
    /// `scale` (δ's rows zero when it is not estimated); `None` when not finite.
    fn normal_equations(&self, seg: &SegmentData<'_>, x: &Vec5, scale: f64) -> Option<(Mat5, Vec5, f64)> {
        let theta = Theta { c_e: x[0], c_d: x[1], t_r: x[2], d: x[3] };
        let e = Extrinsics { heading_offset: x[4], ..Extrinsics::default() };
        let ne = extrinsics_normal_equations(seg, &theta, &e, &self.opts.weights);
        let dims = if self.opts.heading_offset { 5 } else { 4 };
        let mut h = Mat5::zeros();
        let mut g = Vec5::zeros();
        for i in 0..dims {
            g[i] = scale * ne.jtwr[JOINT[i]];
            for j in 0..dims {
                h[(i, j)] = scale * ne.jtwj[(JOINT[i], JOINT[j])];
            }
        }
        let finite = ne.cost.is_finite() && g.iter().all(|v| v.is_finite()) && h.iter().all(|v| v.is_finite());
        finite.then_some((h, g, ne.cost))
    }

    /// Folds the calibration segment starting at `start` (if it turns
    /// enough): the iterated information update of the crate's docs.
    fn fold(&mut self, start: usize) {
        let k = self.opts.segments.length_steps;
        let peak = {
            let psi = self.buf.segment(start, k, self.sample_time_s).psi;
            psi.windows(2).map(|w| (w[1] - w[0]).abs()).fold(0.0, f64::max) / self.sample_time_s
        };
        // The calibration's rule (`odocal::segment::calibration_segments`):
        // a peak at the threshold turns enough, so 0 folds every segment.
        if peak < self.opts.segments.min_peak_yaw_rate_rad_per_s {
            return;
        }
        self.add_process_noise(start + k);
        if self.drive.folded == 0 && self.opts.heading_offset {
            self.x[4] = self.heading_offset_now();
        }
        let seg = self.buf.segment(start, k, self.sample_time_s);
        let Some(lambda0) = self.p.try_inverse() else { return };
        let x0 = self.x;
        let share = self.opts.information_scale;
        let Some((_, _, cost0)) = self.normal_equations(&seg, &x0, 1.0) else { return };
        let seg_variance = (cost0 / (3 * k) as f64).max(MIN_RESIDUAL_VARIANCE);
        let s2 = self.residual_variance.unwrap_or(seg_variance);
        let scale = share / s2;
        let (mut xi, mut lambda) = (x0, lambda0);
        // This segment's normal equations at x0, for the drive's own estimate.
        let mut own = None;
        for _ in 0..self.opts.iterations_per_segment {
            let Some((h, g, _)) = self.normal_equations(&seg, &xi, scale) else { break };
            own.get_or_insert((h, g + h * x0));
            let post = lambda0 + h;
            let Some(step) = post.cholesky().map(|c| c.solve(&(g + h * (xi - x0)))) else { break };
            let cand = x0 + step;
            if !(cand.iter().all(|v| v.is_finite()) && cand[0] > 0.0 && cand[2] > 0.0) {
                break;
            }
            (xi, lambda) = (cand, post);
        }
        let Some(p) = lambda.try_inverse() else { return };
        self.x = xi;
        self.p = 0.5 * (p + p.transpose());
        if let Some((h, b)) = own {
            self.drive.own_h += h;
            self.drive.own_b += b;
        }
        self.residual_variance = Some(match self.residual_variance {
            None => seg_variance,
            Some(v) => v + RESIDUAL_VARIANCE_GAIN * (seg_variance - v),
        });
        self.drive.folded += 1;
        if peak < self.opts.informative_yaw_rate_rad_per_s {
            return;
        }
        self.informative_s += self.opts.segments.stride_steps as f64 * self.sample_time_s;
        self.track.push_back((self.informative_s, self.theta()));
        while self.track.front().is_some_and(|(t, _)| *t < self.informative_s - self.opts.steady_window_s) {
            self.track.pop_front();
        }
    }

    /// Scores a validation segment that has completed.
    fn score(&mut self, p: &Pending) {
        let seg = self.buf.segment(p.start, self.opts.validation.length_steps, self.sample_time_s);
        let e = Extrinsics { heading_offset: p.heading_offset, ..Extrinsics::default() };
        let prequential_m = dead_reckoning(&seg, &p.theta, &e).0;
        let stored_m = self.stored.map(|t| dead_reckoning(&seg, &t, &e).0);
        if !prequential_m.is_finite() {
            return;
        }
        let score = ValidationScore { start_s: self.drive_time_at(p.start), prequential_m, stored_m };
        let d = &mut self.drive;
        d.scored += 1;
        d.prequential_sum += prequential_m;
        d.stored_sum += stored_m.unwrap_or(f64::NAN);
        d.recent.push_back(score);
        if d.recent.len() > self.opts.recent_validation_segments {
            d.recent.pop_front();
        }
    }

    /// Time of sample `i` of the current part from the start of the drive, s.
    fn drive_time_at(&self, i: usize) -> f64 {
        let part_start = self.drive.samples - self.buf.len;
        (part_start + i) as f64 * self.sample_time_s
    }

    /// The current estimate of θ.
    pub(crate) fn theta(&self) -> Theta {
        Theta { c_e: self.x[0], c_d: self.x[1], t_r: self.x[2], d: self.x[3] }
    }

    /// θ's standard deviation: the recursion's, times the options'
    /// [`OnlineOptions::sigma_factors`].
    pub(crate) fn sigma(&self) -> Theta {
        let f = self.opts.sigma_factors;
        Theta::from(std::array::from_fn(|i| f[i] * self.p[(i, i)].max(0.0).sqrt()))
    }

    /// The covariance of `[c_e, c_d, t_r, d, δ]`, θ's rows and columns
    /// scaled by the options' [`OnlineOptions::sigma_factors`] (δ's by 1),
    /// so that its diagonal is `sigma` squared.
    pub(crate) fn covariance(&self) -> [[f64; 5]; 5] {
        let f = |i: usize| self.opts.sigma_factors.get(i).copied().unwrap_or(1.0);
        std::array::from_fn(|i| std::array::from_fn(|j| f(i) * f(j) * self.p[(i, j)]))
    }

    /// The current drive's heading offset δ (reference heading minus the
    /// vehicle's), rad, and its sd.
    pub(crate) fn heading_offset(&self) -> (f64, f64) {
        (self.x[4], self.p[(4, 4)].max(0.0).sqrt())
    }

    /// The informative time over which every parameter of θ has stayed
    /// within `tolerance` (`[c_e, c_d, t_r, d]`) of its current value, s
    /// (at most the options' `steady_window_s`).
    pub(crate) fn steady_for_s(&self, tolerance: [f64; 4]) -> f64 {
        let now = <[_; 4]>::from(self.theta());
        let mut since = self.informative_s;
        for (t, theta) in self.track.iter().rev() {
            let th = <[_; 4]>::from(theta);
            if (0..4).any(|i| gate::exceeds((th[i] - now[i]).abs(), tolerance[i])) {
                break;
            }
            since = *t;
        }
        self.informative_s - since
    }

    /// θ from the current drive's folded segments alone (without the
    /// prior the recursion carries from earlier drives), with its σ scaled
    /// as [`Status::sigma`] is: `None` before the drive determines every
    /// parameter (its normal equations are not positive definite).
    ///
    /// The recursion follows a change of the vehicle only as fast as its
    /// random walk allows; this estimate shows where the drive itself
    /// puts θ, for the gates' consistency and change checks.
    pub(crate) fn drive_estimate(&self) -> Option<OwnEstimate> {
        let d = &self.drive;
        let dims = if self.opts.heading_offset { 5 } else { 4 };
        let h = d.own_h.view((0, 0), (dims, dims)).into_owned();
        let b = d.own_b.rows(0, dims).into_owned();
        let chol = h.cholesky()?;
        let x = chol.solve(&b);
        let cov = chol.inverse();
        let f = self.opts.sigma_factors;
        let theta = Theta { c_e: x[0], c_d: x[1], t_r: x[2], d: x[3] };
        let sigma = Theta::from(std::array::from_fn(|i| f[i] * cov[(i, i)].max(0.0).sqrt()));
        let finite = <[_; 4]>::from(theta).iter().chain(&<[_; 4]>::from(sigma)).all(|v| v.is_finite());
        finite.then_some(OwnEstimate { theta, sigma })
    }

    /// The current drive's most recently scored validation segments, oldest first.
    pub(crate) fn recent_validation(&self) -> impl Iterator<Item = &ValidationScore> {
        self.drive.recent.iter()
    }

    /// What the calibrator saw of the current drive.
    pub(crate) fn drive_summary(&self) -> DriveSummary {
        let d = &self.drive;
        let mean = |sum: f64| (d.scored > 0 && sum.is_finite()).then(|| sum / d.scored as f64);
        DriveSummary {
            samples: d.samples,
            folded_segments: d.folded,
            validation_segments: d.scored,
            prequential_mean_position_error_m: mean(d.prequential_sum),
            stored_mean_position_error_m: self.stored.and(mean(d.stored_sum)),
        }
    }

    /// Samples held in the buffer: bounded by the longest segment and its
    /// stride plus one chunk, whatever the drive's length.
    pub(crate) fn buffered_samples(&self) -> usize {
        self.buf.cols[0].len()
    }

    /// A snapshot of the estimate and the counters, as plain data.
    pub fn status(&self) -> Status {
        let (heading_offset_rad, heading_offset_sd_rad) = self.heading_offset();
        Status {
            theta: self.theta(),
            sigma: self.sigma(),
            covariance: self.covariance(),
            heading_offset_rad,
            heading_offset_sd_rad,
            sample_time_s: self.sample_time_s,
            informative_time_s: self.informative_s,
            buffered_samples: self.buffered_samples(),
            drive: self.drive_summary(),
            recent_validation: self.drive.recent.iter().copied().collect(),
            drive_estimate: self.drive_estimate(),
        }
    }

    /// Pushes a whole drive as a new drive, part by part, in chunks of
    /// `chunk` samples; `each` is called after every chunk with the samples
    /// pushed so far.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] when the drive's sample time is not the
    /// calibrator's; [`Error::InvalidOption`] (`chunk`) for a chunk of 0
    /// samples; both before any sample is pushed. [`Calibrator::push`]'s.
    pub fn push_drive(&mut self, drive: &Drive, chunk: usize, mut each: impl FnMut(usize)) -> Result<()> {
        if (drive.sample_time_s() - self.sample_time_s).abs() > 1e-9 {
            let reason = format!(
                "sample time {} s differs from the calibrator's {} s",
                drive.sample_time_s(),
                self.sample_time_s
            );
            return Err(Error::InvalidDrive { context: "push_drive".into(), reason });
        }
        if chunk == 0 {
            return Err(Error::InvalidOption { field: "chunk", reason: "must be at least 1 sample".into() });
        }
        self.begin_drive();
        for (i, part) in drive.parts().iter().enumerate() {
            if i > 0 {
                self.begin_part();
            }
            let mut a = part.start;
            while a < part.end {
                let b = (a + chunk).min(part.end);
                self.push_chunk(&Chunk::of(drive, a..b))?;
                each(b);
                a = b;
            }
        }
        Ok(())
    }

    /// Pushes the drive file `replay` as a new drive, in its chunks of 400
    /// samples ([`Replay::chunks`]); `each` is called after every chunk with
    /// the samples pushed so far. A file read as a stream and one imported
    /// whole give the same chunks, so the same results as
    /// [`Calibrator::push_drive`] with chunks of 400.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] when the drive's sample time is not the
    /// calibrator's; a streamed drive's read errors; [`Calibrator::push`]'s.
    pub fn push_replay(&mut self, replay: &Replay, mut each: impl FnMut(usize)) -> Result<()> {
        if (replay.sample_time_s() - self.sample_time_s).abs() > 1e-9 {
            let reason = "sample time differs from the first drive's".into();
            return Err(Error::InvalidDrive { context: replay.path().display().to_string(), reason });
        }
        self.begin_drive();
        for c in replay.chunks() {
            let c: StreamChunk = c?;
            if c.starts_part && c.part > 0 {
                self.begin_part();
            }
            self.push_chunk(&Chunk::of_signals(&c.signals))?;
            each(c.start + c.t.len());
        }
        Ok(())
    }
}

/// Wraps an angle to (−π, π].
fn wrap_angle(a: f64) -> f64 {
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut r = a.rem_euclid(two_pi);
    if r > std::f64::consts::PI {
        r -= two_pi;
    }
    r
}

#[cfg(test)]
mod tests;
