//! Resource budgets of the import, checked before anything is allocated
//! from a user's number.
//!
//! | what | limit | why |
//! |---|---|---|
//! | output samples (common span × `rate_hz`, and the wheel span × `rate_hz` of the clock estimate) | [`MAX_OUTPUT_SAMPLES`] = 10⁷ | about 20 f64 columns per sample: ≤ 2 GB; 69 h at 40 Hz |
//! | output samples against the wheel stream's rows | at most [`FREE_OUTPUT_SAMPLES`] = 10⁶ or [`MAX_OUTPUT_PER_WHEEL_ROW`] = 10 × the rows, whichever is more | more is interpolation across gaps, not data; the memory follows the streams |
//! | `output.rate_hz` | [`MIN_OUTPUT_RATE_HZ`] … [`MAX_OUTPUT_RATE_HZ`] = 1 … 1,000 Hz | the model runs at tens of Hz; a drive's sample time is 1 ms … 1 s |
//! | `output.max_gap_s` | [`MAX_GAP_S`] = 10 s | a gap is bridged by interpolation; across more there is no data |
//! | `output.max_clock_offset_s` | [`MAX_CLOCK_OFFSET_S`] = 60 s | larger means a wrong time column, unit or offset |
//! | clock search work (grid samples × lags) | [`MAX_CORRELATION_WORK`] = 4·10⁹ | seconds, not hours |
//! | `streams.*.nominal_rate_hz` | [`MAX_NOMINAL_RATE_HZ`] = 100 kHz, and at most [`MAX_NOMINAL_OVER_MEAN_RATE`] × the stream's mean rate | de-jittering assigns one index per nominal period |
//! | values read from one Parquet stream (declared rows × columns read) | `MAX_STREAM_VALUES` = 10⁸ (feature `parquet`) | 800 MB of f64; a CSV stream is bounded by its file's size |
//! | `streams.*.nominal_rate_hz`, from below | at least [`MIN_NOMINAL_OVER_MEAN_RATE`] = 0.5 × the stream's mean rate | a sensor does not sample slower than its samples arrive |
//! | `streams.*.time_offset_s` | ±[`MAX_TIME_OFFSET_S`] = 10¹⁰ s | covers any two epochs (GNSS, Unix, boot); beyond it the stamps lose their sub-second digits |
//! | `lateral_acceleration.smoothing_s`, `lateral_acceleration.bank.smoothing_s` | [`MAX_SMOOTHING_S`] = 60 s | the moving average is over seconds; a minute flattens every curve |
//! | `streams.*.dejitter_window_s` | [`MAX_DEJITTER_WINDOW_S`] = 60 s and [`MAX_DEJITTER_HALF_WINDOW`] = 5,000 samples each side | the local fit costs the window per sample |
//!
//! The physical limits (speed, lateral acceleration) are in the manifest's
//! `[limits]` table ([`super::manifest::LimitsSpec`]), because a real vehicle may
//! exceed them.

use super::grid::Span;
use super::manifest::Manifest;
use crate::error::{Error, Result};

/// Most output samples an import may allocate.
pub(crate) const MAX_OUTPUT_SAMPLES: usize = 10_000_000;
/// Lowest output rate, Hz.
pub(crate) const MIN_OUTPUT_RATE_HZ: f64 = 1.0;
/// Highest output rate, Hz: the inverse of the shortest sample time a
/// drive may have ([`crate::model::limits::PhysicalLimits`]'s default
/// `min_sample_time_s`, which the imported drive is checked against).
pub(crate) const MAX_OUTPUT_RATE_HZ: f64 = 1_000.0;
/// Longest stream gap `output.max_gap_s` may bridge by interpolation, s.
pub(crate) const MAX_GAP_S: f64 = 10.0;
/// Output samples an import may have whatever the wheel stream holds
/// (about 200 MB of import memory at most).
pub(crate) const FREE_OUTPUT_SAMPLES: usize = 1_000_000;
/// Most output samples per wheel-stream row beyond [`FREE_OUTPUT_SAMPLES`]:
/// a wheel stream at a tenth of the output rate or slower, averaged over
/// the drive, is mostly gaps.
pub(crate) const MAX_OUTPUT_PER_WHEEL_ROW: usize = 10;
/// Largest clock-offset search range, ± s.
pub(crate) const MAX_CLOCK_OFFSET_S: f64 = 60.0;
/// Most multiply-adds of the clock-offset search (grid samples × lags × 2).
pub(crate) const MAX_CORRELATION_WORK: f64 = 4e9;
/// Highest nominal stream rate, Hz.
pub(crate) const MAX_NOMINAL_RATE_HZ: f64 = 100_000.0;
/// Highest nominal rate relative to a stream's mean rate.
pub(crate) const MAX_NOMINAL_OVER_MEAN_RATE: f64 = 20.0;
/// Lowest nominal stream rate relative to a stream's mean rate: stamps
/// that jitter or drop samples arrive at about the nominal rate or below.
pub(crate) const MIN_NOMINAL_OVER_MEAN_RATE: f64 = 0.5;
/// Largest time offset of a stream, ± s: 317 years, more than any two clock
/// epochs apart; at 1e10 s an f64 stamp still holds microseconds.
pub(crate) const MAX_TIME_OFFSET_S: f64 = 1e10;
/// Longest smoothing window of a derived a_y or of the road's roll, s.
pub(crate) const MAX_SMOOTHING_S: f64 = 60.0;
/// Longest `pose.derive_heading_baseline_m`, m.
pub(crate) const MAX_DERIVE_HEADING_BASELINE_M: f64 = 50.0;
/// Longest de-jitter window, s.
pub(crate) const MAX_DEJITTER_WINDOW_S: f64 = 60.0;
/// Most samples each side of the de-jitter window.
pub(crate) const MAX_DEJITTER_HALF_WINDOW: usize = 5_000;
/// Most values (rows × columns read) one Parquet stream may declare; checked
/// before any is read.
#[cfg(feature = "parquet")]
pub(crate) const MAX_STREAM_VALUES: usize = 100_000_000;
/// Characters of a value echoed in a message; a number (`1e300` stays short).
pub(crate) use crate::drive::{echo, echo_num};

/// `|v| ≤ max` and finite (false for NaN).
pub(crate) fn within(v: f64, max: f64) -> bool {
    v.is_finite() && v.abs() <= max
}

/// Output samples of `span_s` at `rate_hz` must stay within the budget.
pub(crate) fn check_samples(m: &Manifest, what: &str, span_s: f64) -> Result<()> {
    let n = span_s * m.output.rate_hz;
    if n.is_finite() && n <= MAX_OUTPUT_SAMPLES as f64 {
        return Ok(());
    }
    let hint = if span_s > 1e6 {
        format!(
            " {} s is {:.0} days: are the times in ms, µs or ns? Set time_unit.",
            echo_num(span_s),
            span_s / 86_400.0
        )
    } else {
        String::new()
    };
    Err(m.error(
        "output.rate_hz",
        format!(
            "{what} spans {} s: at {} Hz that is {} output samples, above the budget of {MAX_OUTPUT_SAMPLES}; lower \
             rate_hz or split the log.{hint}",
            echo_num(span_s),
            echo_num(m.output.rate_hz),
            echo_num(n.round())
        ),
    ))
}

/// Output samples of `span_s` at `rate_hz` must stay within what the
/// wheel stream `wheels` holds (`wheel_rows` rows; `pose` with `pose_rows`
/// is named beside it): at most [`FREE_OUTPUT_SAMPLES`] or
/// [`MAX_OUTPUT_PER_WHEEL_ROW`] × `wheel_rows`, whichever is more. Checked
/// before the grid is allocated.
pub(crate) fn check_samples_per_row(
    m: &Manifest,
    span_s: f64,
    (wheels, wheel_rows): (&str, usize),
    (pose, pose_rows): (&str, usize),
) -> Result<()> {
    let n = span_s * m.output.rate_hz;
    let allowed = FREE_OUTPUT_SAMPLES.max(MAX_OUTPUT_PER_WHEEL_ROW.saturating_mul(wheel_rows));
    if n.is_finite() && n <= allowed as f64 {
        return Ok(());
    }
    Err(Error::Manifest {
        path: m.path.clone(),
        reason: format!(
            "{wheels} spans {} s: at output.rate_hz = {} Hz that is {} output samples, but {wheels} holds \
             {wheel_rows} rows ({pose}: {pose_rows}); an import makes at most {FREE_OUTPUT_SAMPLES} output \
             samples or {MAX_OUTPUT_PER_WHEEL_ROW} per wheel row, whichever is more: the rest would be \
             interpolated across gaps, not data. Check the streams' time_column and time_unit, or split the log \
             where it pauses",
            echo_num(span_s),
            echo_num(m.output.rate_hz),
            echo_num(n.round())
        ),
    })
}

/// The clock-offset search over `grid_samples` samples must stay within
/// [`MAX_CORRELATION_WORK`].
pub(crate) fn check_correlation(m: &Manifest, grid_samples: usize) -> Result<()> {
    let work = correlation_work(m.output.max_clock_offset_s, m.output.rate_hz, grid_samples);
    if work <= MAX_CORRELATION_WORK {
        return Ok(());
    }
    Err(m.error(
        "output.max_clock_offset_s",
        format!(
            "searching ±{} s at {} Hz over {grid_samples} samples is {} multiply-adds, above the budget of \
             {MAX_CORRELATION_WORK:e}; narrow the search or give the offset in seconds",
            m.output.max_clock_offset_s,
            m.output.rate_hz,
            echo_num(work)
        ),
    ))
}

/// Multiply-adds of a clock-offset search over ±`range_s` at `rate_hz` on
/// `grid_samples` samples.
pub(crate) fn correlation_work(range_s: f64, rate_hz: f64, grid_samples: usize) -> f64 {
    let lags = 2.0 * (range_s * rate_hz).ceil() + 1.0;
    2.0 * lags * grid_samples as f64
}

/// Checks, before any resampling, that the wheel and pose streams can
/// overlap: the pose span is widened by the clock-offset search range
/// (`"auto"`) or shifted by the fixed offset. The error names both spans
/// and, when their times differ by a power of 1000, the likely unit mistake.
pub(crate) fn check_overlap(m: &Manifest, wheels: &Span, pose: &Span) -> Result<()> {
    let (lo, hi) = match m.output.clock_offset {
        super::ClockOffset::Auto => (-m.output.max_clock_offset_s, m.output.max_clock_offset_s),
        super::ClockOffset::Seconds(v) => (v, v),
    };
    let (p0, p1) = (pose.start + lo, pose.end + hi);
    if p0.max(wheels.start) < p1.min(wheels.end) {
        return Ok(());
    }
    let search = match m.output.clock_offset {
        super::ClockOffset::Auto => format!(" (with the ±{} s clock offset search)", m.output.max_clock_offset_s),
        super::ClockOffset::Seconds(v) => format!(" (with the clock offset {v} s)"),
    };
    Err(Error::Manifest {
        path: m.path.clone(),
        reason: format!(
            "the streams do not overlap in time (no time overlap): {} t = {} … {} s, {} t = {} … {} s{search}; \
             {}check time_column, time_unit and time_offset_s",
            wheels.name,
            echo_num(wheels.start),
            echo_num(wheels.end),
            pose.name,
            echo_num(pose.start),
            echo_num(pose.end),
            unit_hint(wheels, pose)
        ),
    })
}

/// The hint for an import whose streams overlap for `span_s`, less than
/// `output.min_part_s` (no part can be kept): the streams whose times
/// `time_unit` scales, with the span and mean rate that gives them (times
/// in seconds read as ms span a thousandth of the drive at a thousand times
/// its rate); otherwise where to look. Empty when the span is long enough.
pub(crate) fn short_span_hint<'a>(
    m: &Manifest,
    span_s: f64,
    streams: impl IntoIterator<Item = &'a super::report::StreamReport>,
) -> String {
    if span_s >= m.output.min_part_s {
        return String::new();
    }
    let scaled: Vec<String> = streams
        .into_iter()
        .filter_map(|r| {
            let unit = m.streams.get(&r.name)?.time_unit;
            (unit != super::manifest::TimeUnit::S).then(|| {
                format!(
                    "streams.{} reads its times in {} (time_unit = \"{}\"): {} s at {} Hz",
                    r.name,
                    unit.name(),
                    unit.name(),
                    echo_num(r.time_span_s[1] - r.time_span_s[0]),
                    echo_num(r.mean_rate_hz.round())
                )
            })
        })
        .collect();
    let span = echo_num((span_s * 1000.0).round() / 1000.0);
    if scaled.is_empty() {
        format!("; the streams overlap for only {span} s: check time_column, time_unit and time_offset_s")
    } else {
        format!(
            "; the streams overlap for only {span} s and {}: are the times in seconds already? Then drop time_unit \
             (seconds are the default)",
            scaled.join(", ")
        )
    }
}

/// "streams.a's times are about 10⁶ × those of streams.b: µs?" when the
/// middles of two spans differ by a factor near 10³, 10⁶ or 10⁹.
fn unit_hint(a: &Span, b: &Span) -> String {
    let (ma, mb) = ((0.5 * (a.start + a.end)).abs(), (0.5 * (b.start + b.end)).abs());
    let (big, small, r) = if ma >= mb { (a, b, ma / mb) } else { (b, a, mb / ma) };
    if !(r.is_finite() && r > 100.0) {
        return String::new();
    }
    let decades = r.log10();
    let unit = [(3.0, "ms", "ms"), (6.0, "µs", "us"), (9.0, "ns", "ns")]
        .into_iter()
        .find(|(d, _, _)| (decades - d).abs() < 0.7);
    match unit {
        Some((d, name, key)) => format!(
            "{}'s times are about 1e{d} × those of {}: are they in {name} (time_unit = \"{key}\")? ",
            big.name, small.name
        ),
        None => format!("{}'s times are {} × those of {}; ", big.name, echo_num(r.round()), small.name),
    }
}

#[cfg(test)]
thread_local! {
    /// The largest grid (samples) the import allocated on this thread.
    pub(crate) static LARGEST_GRID: std::cell::Cell<usize> = const { std::cell::Cell::new(0) };
}

/// Records a grid allocation of `n` samples (test builds only).
pub(crate) fn note_grid(n: usize) {
    #[cfg(test)]
    LARGEST_GRID.with(|c| c.set(c.get().max(n)));
    let _ = n;
}
