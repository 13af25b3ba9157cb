//! The import report: what was read, estimated, split and dropped.

use std::path::PathBuf;

use serde::Serialize;

/// What the import did. `Display` gives a human summary.
#[derive(Debug, Clone, Serialize)]
pub struct ImportReport {
    /// The manifest.
    pub manifest: PathBuf,
    /// Streams read.
    pub(crate) streams: Vec<StreamReport>,
    /// Output rate, Hz.
    pub output_rate_hz: f64,
    /// Wheel-clock time of the drive's t = 0, s (stream time units after
    /// `time_offset_s`). All other times in the report are relative to it.
    pub time_origin_s: f64,
    /// Common time span of the streams, relative to the origin, s.
    pub common_span_s: [f64; 2],
    /// Clock offset between the wheel and pose streams.
    pub clock_offset: ClockOffsetReport,
    /// Intervals without valid output samples, with reasons.
    pub(crate) gaps: Vec<GapRecord>,
    /// Continuous parts, kept and dropped.
    pub(crate) parts: Vec<PartRecord>,
    /// Samples in the imported drive (kept parts).
    pub samples: usize,
    /// Duration of the kept parts, s.
    pub duration_s: f64,
    /// Reference path length of the kept parts, m.
    pub distance_m: f64,
    /// What one model "revolution" is, i.e. how to read c_e.
    pub wheel_scale: String,
    /// Source of the lateral acceleration.
    pub lateral_acceleration: String,
    /// Effect of de-jittering the wheel stream, when it was de-jittered.
    pub(crate) jitter: Option<JitterReport>,
    /// What looked wrong but did not stop the import.
    pub warnings: Vec<String>,
    /// The manifest's `[noise]` (the sensor's noise model) as written, when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) noise: Option<super::NoiseTable>,
    /// The manifest's `[reference]` (reference extrinsics), when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference: Option<super::ReferenceSpec>,
    /// The manifest's `[calibration]` (calibration settings) as written, when stated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) calibration: Option<super::CalibrationTable>,
    /// Wall time of the import, s.
    pub elapsed_s: f64,
}

/// One stream that was read.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct StreamReport {
    /// Name in the manifest.
    pub(crate) name: String,
    /// The file.
    pub(crate) file: PathBuf,
    /// Data rows read.
    pub(crate) rows: usize,
    /// Rows dropped because their time stamp repeated the previous one.
    pub(crate) repeated_stamps_dropped: usize,
    /// Wheel rows dropped as corrupt: a counter jump beyond
    /// `limits.max_speed_m_per_s` that returns within a few rows.
    pub(crate) corrupt_rows_dropped: usize,
    /// First and last time, s (after `time_offset_s`, before the clock offset).
    pub(crate) time_span_s: [f64; 2],
    /// Mean sample rate, Hz.
    pub(crate) mean_rate_hz: f64,
    /// De-jittering, when the stream has a nominal rate.
    pub(crate) dejitter: Option<DejitterReport>,
}

/// Time-stamp corrections of a de-jittered stream.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct DejitterReport {
    /// Nominal rate, Hz.
    pub nominal_rate_hz: f64,
    /// RMS stamp correction, ms.
    pub rms_correction_ms: f64,
    /// Largest stamp correction, ms.
    pub max_correction_ms: f64,
    /// Samples missing from the nominal sequence.
    pub missing_samples: u64,
}

/// Noise of the output wheel speeds with raw and de-jittered stamps.
///
/// Noise is estimated from second differences of n at the output rate,
/// `sqrt(mean(Δ²n)²/6)`, relative to the RMS wheel speed, over moving samples
/// (|n| > 1 rev/s) of the kept parts, both wheels; it holds real speed changes
/// too, so it is an upper bound on the noise.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct JitterReport {
    /// With the raw stamps, per cent.
    pub wheel_speed_noise_raw_pct: f64,
    /// With the de-jittered stamps, per cent.
    pub wheel_speed_noise_dejittered_pct: f64,
}

/// Clock offset between the wheel and pose streams.
#[derive(Debug, Clone, Serialize)]
pub struct ClockOffsetReport {
    /// Estimate from the speed cross-correlation, s (pose time + τ = wheel time).
    pub estimated_s: Option<f64>,
    /// Pearson correlation at the peak.
    pub correlation: Option<f64>,
    /// Sample pairs (at the output rate) in the correlation at the peak.
    pub correlation_pairs: Option<usize>,
    /// Sharpness of the speed-correlation peak, −d²r/dτ², 1/s²: a
    /// confidence (a peak of width w has about 2·(1 − r_edge)/w²).
    pub peak_curvature_per_s2: Option<f64>,
    /// Half-width of the offsets the peak cannot tell apart from its top,
    /// `sqrt(2·(1 − r)/curvature)`, s: how far the correlation's own misfit
    /// (1 − r) reaches down the peak. Informational.
    pub uncertainty_s: Option<f64>,
    /// The best other local maximum of the speed correlation, s.
    pub second_peak_s: Option<f64>,
    /// Its correlation.
    pub second_peak_correlation: Option<f64>,
    /// Cross-check, not applied: the same estimate from the wheel yaw rate
    /// at θ_0 against the reference yaw rate, s (sharper where the drive turns).
    pub yaw_rate_estimate_s: Option<f64>,
    /// Pearson correlation of the yaw-rate cross-check.
    pub yaw_rate_correlation: Option<f64>,
    /// The offset applied, s.
    pub applied_s: f64,
    /// Why `"auto"` did not apply its estimate (see the import docs), if so.
    pub doubt: Option<String>,
    /// Why a fixed offset's estimate was skipped (its search would exceed
    /// the correlation budget), if it was.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub(crate) not_estimated: Option<String>,
    /// `"auto"` or `"fixed"`.
    pub mode: String,
}

/// An interval without valid samples, measured as a part is
/// ([`PartRecord`]): each invalid sample stands for one output step.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct GapRecord {
    /// Start: the first invalid sample's time, s (relative to the origin).
    pub(crate) t_start_s: f64,
    /// End: the last invalid sample's time plus one output step, where the
    /// next part starts, s.
    pub(crate) t_end_s: f64,
    /// Why (the distinct reasons of the invalid samples).
    pub(crate) reasons: Vec<String>,
}

/// A continuous run of valid samples. Its duration is its samples times
/// the output step (each sample stands for one step): `t_end_s −
/// t_start_s`, the duration `output.min_part_s` is compared with and the
/// kept parts' durations add up to [`ImportReport::duration_s`]. A part
/// ends where the next gap starts. The text gives times and durations to
/// the millisecond, which at 40 Hz (a 25 ms step) is exact.
#[derive(Debug, Clone, Serialize)]
pub(crate) struct PartRecord {
    /// Start: the first sample's time, s (relative to the origin).
    pub(crate) t_start_s: f64,
    /// End: the last sample's time plus one output step, s.
    pub(crate) t_end_s: f64,
    /// Samples.
    pub(crate) samples: usize,
    /// Kept in the drive?
    pub(crate) kept: bool,
    /// Why it was dropped.
    pub(crate) dropped_because: Option<String>,
}

impl PartRecord {
    /// The part of output samples `samples` (indices from the origin, step
    /// `h`), kept or dropped as shorter than `min_part_s`.
    pub(crate) fn new(samples: std::ops::Range<usize>, h: f64, kept: bool, min_part_s: f64) -> PartRecord {
        let duration = samples.len() as f64 * h;
        PartRecord {
            t_start_s: samples.start as f64 * h,
            t_end_s: samples.end as f64 * h,
            samples: samples.len(),
            kept,
            dropped_because: (!kept)
                .then(|| format!("{duration:.3} s is shorter than output.min_part_s = {min_part_s} s")),
        }
    }
}

impl std::fmt::Display for ImportReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        writeln!(f, "import of {}", self.manifest.display())?;
        for s in &self.streams {
            write!(
                f,
                "  stream {:<10} {} rows at {:.2} Hz, t = {:.3} … {:.3} s",
                s.name, s.rows, s.mean_rate_hz, s.time_span_s[0], s.time_span_s[1]
            )?;
            if s.repeated_stamps_dropped > 0 {
                write!(f, ", {} repeated stamps dropped", s.repeated_stamps_dropped)?;
            }
            if s.corrupt_rows_dropped > 0 {
                write!(f, ", {} corrupt rows dropped", s.corrupt_rows_dropped)?;
            }
            if let Some(d) = &s.dejitter {
                write!(
                    f,
                    ", de-jittered at {} Hz (correction rms {:.3} ms, max {:.3} ms, {} samples missing)",
                    d.nominal_rate_hz, d.rms_correction_ms, d.max_correction_ms, d.missing_samples
                )?;
            }
            writeln!(f)?;
        }
        let c = &self.clock_offset;
        match (c.estimated_s, c.correlation) {
            (Some(e), Some(r)) => writeln!(
                f,
                "  clock offset: estimated {:+.4} s (speed correlation {r:.4}), applied {:+.4} s ({})",
                e, c.applied_s, c.mode
            )?,
            _ => writeln!(f, "  clock offset: not estimated, applied {:+.4} s ({})", c.applied_s, c.mode)?,
        }
        if let Some(why) = &c.not_estimated {
            writeln!(f, "  clock offset estimate skipped: {why}")?;
        }
        if let Some(k) = c.peak_curvature_per_s2 {
            write!(f, "  clock offset peak sharpness {k:.3} /s²")?;
            if let Some(u) = c.uncertainty_s {
                write!(f, " (± {u:.3} s)")?;
            }
            match (c.second_peak_s, c.second_peak_correlation) {
                (Some(t), Some(r)) => writeln!(f, ", second peak {t:+.3} s (correlation {r:.4})")?,
                _ => writeln!(f, ", no second peak")?,
            }
        }
        if let (Some(e), Some(r)) = (c.yaw_rate_estimate_s, c.yaw_rate_correlation) {
            writeln!(f, "  clock offset cross-check from yaw rates: {e:+.4} s (correlation {r:.4}), not applied")?;
        }
        if let Some(j) = &self.jitter {
            writeln!(
                f,
                "  wheel speed noise at {} Hz: {:.3} % with raw stamps, {:.3} % de-jittered",
                self.output_rate_hz, j.wheel_speed_noise_raw_pct, j.wheel_speed_noise_dejittered_pct
            )?;
        }
        writeln!(
            f,
            "  time origin {:.6} s; common span {:.2} … {:.2} s",
            self.time_origin_s, self.common_span_s[0], self.common_span_s[1]
        )?;
        for g in &self.gaps {
            writeln!(f, "  gap   {:10.3} … {:10.3} s: {}", g.t_start_s, g.t_end_s, g.reasons.join("; "))?;
        }
        for p in &self.parts {
            write!(f, "  part  {:10.3} … {:10.3} s, {:6} samples", p.t_start_s, p.t_end_s, p.samples)?;
            match &p.dropped_because {
                Some(why) => writeln!(f, ", dropped: {why}")?,
                None => writeln!(f, ", kept")?,
            }
        }
        let kept = self.parts.iter().filter(|p| p.kept).count();
        writeln!(
            f,
            "  {} of {} parts kept: {} samples, {:.1} s, {:.1} m at {} Hz",
            kept,
            self.parts.len(),
            self.samples,
            self.duration_s,
            self.distance_m,
            self.output_rate_hz
        )?;
        writeln!(f, "  wheels: {}", self.wheel_scale)?;
        if let Some(n) = &self.noise {
            let entries: Vec<String> = n.table.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            writeln!(f, "  [noise] (start of --method eiv): {}", entries.join(", "))?;
        }
        if let Some(r) = &self.reference {
            let l = r.lever_arm.unwrap_or_default();
            write!(
                f,
                "  [reference]: lever arm ({:+.3}, {:+.3}) m, heading offset {:+.2} mrad",
                l[0],
                l[1],
                r.heading_offset.unwrap_or_default() * 1e3
            )?;
            match r.estimate.is_empty() {
                true => writeln!(f, ", held")?,
                false => writeln!(f, ", estimate {}", r.estimate.join(", "))?,
            }
        }
        if let Some(c) = self.calibration.as_ref().filter(|c| !c.table.is_empty()) {
            let entries: Vec<String> = c.table.iter().map(|(k, v)| format!("{k} = {v}")).collect();
            writeln!(f, "  [calibration]: {}", entries.join(", "))?;
        }
        for w in &self.warnings {
            writeln!(f, "  warning: {w}")?;
        }
        write!(f, "  lateral acceleration: {}", self.lateral_acceleration)
    }
}
