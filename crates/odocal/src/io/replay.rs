//! A drive file read in chunks as if it streamed in live ([`Replay`]):
//! what `odocal follow` pushes through the online calibrator (the crate
//! odocal-online), one drive at a time.

use std::path::{Path, PathBuf};

use crate::drive::plausibility::{check_conventions, check_conventions_from, stall_overlap_samples};
use crate::drive::{Drive, DriveBuilder, DriveStream, Signals, StreamChunk};
use crate::error::{Error, Result};
use crate::io::import::stream::{self, reader::ManifestStream, StreamOptions};
use crate::io::import::{is_manifest_path, load_drive, manifest::Manifest, wheel_scale};
use crate::model::Theta;

/// Samples per chunk (10 s at 40 Hz).
const CHUNK: usize = 400;

/// A drive file (a canonical drive CSV or a manifest) opened to be read in
/// chunks of canonical samples, as if it streamed in live: what an online
/// calibrator (the crate odocal-online) is fed, one drive at a time.
///
/// It is read as a stream when it can be (memory flat in the drive's
/// length): a drive CSV, or a manifest of CSV streams (its samples kept in
/// temporary files); another manifest is imported whole. Either way
/// [`Replay::chunks`] hands out the same chunks with the same values.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal::io::Replay;
/// use odocal::sim;
/// let dir = tempfile::tempdir().map_err(|e| odocal::Error::Numerical(e.to_string()))?;
/// let csv = dir.path().join("a.csv");
/// sim::simulate(&sim::SimOptions { length_km: 2.0, noise: "off".parse()?, ..sim::SimOptions::paper(1) })?.drive.write_csv(&csv)?;
/// let drive = Replay::open(&csv, |line| { eprintln!("{line}"); Ok::<(), odocal::Error>(()) })?;
/// let mut samples = 0;
/// for chunk in drive.chunks() {
///     samples += chunk?.t.len();
/// }
/// assert_eq!(samples, drive.samples());
/// # Ok(()) }
/// ```
pub struct Replay {
    /// The file, as given (the context of errors).
    path: PathBuf,
    source: Source,
    /// The wheel-clock time of the drive's t = 0 when it was imported from
    /// a manifest (`ImportReport::time_origin_s`).
    origin_s: Option<f64>,
    /// What one model revolution is, for a manifest
    /// (`ImportReport::wheel_scale`).
    wheel_scale: Option<String>,
}

/// How a [`Replay`] holds its drive.
enum Source {
    Stream(DriveStream),
    Whole(Box<Drive>),
}

impl Replay {
    /// Opens the drive at `path`; `log` hears one line about each thing
    /// its reader reports (its warnings; a manifest imported as a stream or
    /// whole, and why), and an error `log` returns stops the opening.
    ///
    /// # Errors
    /// The drive's read errors; `log`'s.
    pub fn open<E: From<Error>>(
        path: &Path,
        mut log: impl FnMut(String) -> std::result::Result<(), E>,
    ) -> std::result::Result<Replay, E> {
        let (source, origin_s, wheel_scale) = Source::open(path, &mut log)?;
        Ok(Replay { path: path.to_path_buf(), source, origin_s, wheel_scale })
    }

    /// What one model revolution is when the drive was imported from a
    /// manifest (as [`crate::ImportReport::wheel_scale`]), so what c_e, c_d
    /// and d are per; `None` for a drive CSV. Drives followed as one
    /// vehicle must agree ([`crate::wheel_scale_mismatch`]).
    pub fn wheel_scale(&self) -> Option<&str> {
        self.wheel_scale.as_deref()
    }

    /// The drive's [fingerprint](Drive::fingerprint).
    ///
    /// # Errors
    /// A streamed drive's read errors.
    pub fn fingerprint(&self) -> Result<String> {
        Ok(match &self.source {
            Source::Stream(s) => s.fingerprint()?,
            Source::Whole(d) => d.fingerprint(),
        })
    }

    /// The drive's sample time, s.
    pub fn sample_time_s(&self) -> f64 {
        match &self.source {
            Source::Stream(s) => s.sample_time_s,
            Source::Whole(d) => d.sample_time_s(),
        }
    }

    /// The number of samples: at least two (a drive with fewer is refused
    /// when opened).
    pub fn samples(&self) -> usize {
        match &self.source {
            Source::Stream(s) => s.len(),
            Source::Whole(d) => d.len(),
        }
    }

    /// The first and the last time stamp, s.
    pub fn time_span_s(&self) -> (f64, f64) {
        match &self.source {
            Source::Stream(s) => s.time_span_s,
            Source::Whole(d) => (d.t().first().copied().unwrap_or(0.0), d.t().last().copied().unwrap_or(0.0)),
        }
    }

    /// The first and the last time stamp on the recording's own clock (the
    /// wheel stream's, Unix time for most loggers), s, when the drive was
    /// imported from a manifest; `None` for a drive CSV, whose times are as
    /// written (an imported or simulated drive's start at 0). Drives of one
    /// vehicle compare by it: which was driven first.
    pub fn clock_span_s(&self) -> Option<(f64, f64)> {
        let (a, b) = self.time_span_s();
        self.origin_s.map(|o| (o + a, o + b))
    }

    /// The file, as given.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Judges the drive as a calibration judges its drive before fitting
    /// it, at θ_0 = `theta0`: a wheel that reads (almost) no rotation while
    /// the reference moves, or a reference that stands still while the
    /// wheels turn, for 2 s or more; the wheel speeds' sign and scale, the
    /// heading's and the yaw rate's convention, a_y's sign and unit. A
    /// drive read as a stream is judged in blocks of 65 536 samples (27
    /// minutes at 40 Hz) that share more than the shortest stall's samples,
    /// so its memory stays flat and a stall anywhere is found; the
    /// conventions are judged on each block.
    ///
    /// # Errors
    /// [`Error::InvalidDrive`] naming the file and what to check: the
    /// signal that stalls and its samples (counted from the drive's first),
    /// or the convention; a streamed drive's read errors.
    pub fn check(&self, theta0: &Theta) -> Result<()> {
        self.check_in_blocks(theta0, CHECK_BLOCK)
    }

    /// [`Replay::check`] with blocks of at most `size` samples (at least
    /// twice the blocks' overlap).
    fn check_in_blocks(&self, theta0: &Theta, size: usize) -> Result<()> {
        let context = self.path.display().to_string();
        match &self.source {
            Source::Whole(d) => check_conventions(d, theta0, &context),
            Source::Stream(s) => {
                let overlap = stall_overlap_samples(s.sample_time_s);
                let mut block = Block::default();
                for chunk in s.chunks(CHUNK) {
                    let chunk = chunk?;
                    if !block.t.is_empty() && block.t.len() + chunk.t.len() > size.max(2 * overlap) {
                        let next = block.tail(overlap);
                        std::mem::replace(&mut block, next).judge(s.sample_time_s, theta0, &context)?;
                    }
                    block.push(chunk);
                }
                block.judge(s.sample_time_s, theta0, &context)
            }
        }
    }

    /// The samples in chunks of 400 (10 s at 40 Hz), part by part in time
    /// order; a chunk never spans two parts. A drive imported whole is cut
    /// the same way, so the chunks do not depend on how the file was read.
    ///
    /// # Errors
    /// Each chunk: a streamed drive's read errors.
    pub fn chunks(&self) -> Box<dyn Iterator<Item = Result<StreamChunk>> + '_> {
        match &self.source {
            Source::Stream(s) => Box::new(s.chunks(CHUNK)),
            Source::Whole(d) => Box::new(whole_chunks(d, CHUNK).map(Ok)),
        }
    }
}

/// Samples of a streamed drive [`Replay::check`] judges at once.
const CHECK_BLOCK: usize = 1 << 16;

/// Consecutive samples of a streamed drive, with their parts.
#[derive(Default)]
struct Block {
    /// The drive's index of the first sample.
    first: usize,
    t: Vec<f64>,
    signals: Signals,
    /// The drive's part of each sample.
    part: Vec<i64>,
}

impl Block {
    fn push(&mut self, chunk: StreamChunk) {
        if self.t.is_empty() {
            self.first = chunk.start;
        }
        self.part.extend(std::iter::repeat_n(chunk.part as i64, chunk.t.len()));
        self.t.extend(chunk.t);
        let c = chunk.signals;
        self.signals
            .extend((0..c.px.len()).map(|i| [c.px[i], c.py[i], c.psi[i], c.n_rl[i], c.n_rr[i], c.beta[i], c.a_y[i]]));
    }

    /// The last `n` samples, to start the next block with.
    fn tail(&self, n: usize) -> Block {
        let k = self.t.len().saturating_sub(n);
        Block {
            first: self.first + k,
            t: self.t[k..].to_vec(),
            signals: self.signals.slice(k..self.t.len()),
            part: self.part[k..].to_vec(),
        }
    }

    /// [`check_conventions`] of the block as a drive of its own.
    fn judge(self, sample_time_s: f64, theta0: &Theta, context: &str) -> Result<()> {
        if self.t.len() < 2 {
            return Ok(());
        }
        let first = self.first;
        let drive = DriveBuilder {
            context: context.to_string(),
            t: self.t,
            measured: self.signals,
            part_ids: Some(self.part),
            sample_time_s: Some(sample_time_s),
            ..Default::default()
        }
        .build()?;
        check_conventions_from(&drive, theta0, context, first)
    }
}

/// The samples of `drive` in chunks of at most `size`, part by part.
fn whole_chunks(drive: &Drive, size: usize) -> impl Iterator<Item = StreamChunk> + '_ {
    drive.parts().iter().enumerate().flat_map(move |(part, r)| {
        (r.start..r.end).step_by(size).map(move |a| {
            let b = (a + size).min(r.end);
            StreamChunk {
                part,
                start: a,
                starts_part: a == r.start,
                t: drive.t()[a..b].to_vec(),
                signals: drive.measured().slice(a..b),
                reference_measured: drive.reference_measured().map(|m| m[a..b].to_vec()),
            }
        })
    })
}

impl Source {
    /// Opens the drive at `path`; `log` hears what its reader warns about.
    /// The drive at `path` and, for a manifest, the wheel-clock time of
    /// its t = 0 and its wheel scale.
    fn open<E: From<Error>>(
        path: &Path,
        log: &mut impl FnMut(String) -> std::result::Result<(), E>,
    ) -> std::result::Result<(Source, Option<f64>, Option<String>), E> {
        if is_manifest_path(path) {
            let m = Manifest::from_path(path)?;
            let scale = Some(wheel_scale(&m));
            if let Some(why) = stream::not_streamable(&m) {
                log(format!("note: {}: imported whole ({why})", path.display()))?;
                return whole(path, log).map(|(s, o)| (s, o, scale));
            }
            let mut lines = Vec::new();
            let (source, origin_s) = match streamed_manifest(path, &m, &mut lines) {
                Ok((s, origin_s)) => {
                    lines.into_iter().try_for_each(&mut *log)?;
                    (Source::Stream(s), origin_s)
                }
                // The whole import's error (or result) is the reference:
                // the stream judges some whole-drive checks on its warm-up.
                Err(e) => {
                    log(format!("note: {}: imported whole (the streamed import stopped: {e})", path.display()))?;
                    whole(path, log)?
                }
            };
            return Ok((source, origin_s, scale));
        }
        let stream = DriveStream::open(path)?;
        for w in &stream.warnings {
            log(format!("warning: {w}"))?;
        }
        Ok((Source::Stream(stream), None, None))
    }
}

/// The manifest at `path` imported whole, its import's account logged,
/// with the wheel-clock time of its t = 0.
fn whole<E>(
    path: &Path,
    log: &mut impl FnMut(String) -> std::result::Result<(), E>,
) -> std::result::Result<(Source, Option<f64>), E>
where
    E: From<Error>,
{
    let (drive, report) = load_drive(path)?;
    log(format!(
        "imported {}: {} samples in {} part(s), {:.2} km (run `odocal import` for the full import report)",
        path.display(),
        drive.len(),
        drive.parts().len(),
        drive.distance_m() / 1e3
    ))?;
    for w in report.iter().flat_map(|r| &r.warnings) {
        log(format!("warning: {}: {w}", path.display()))?;
    }
    Ok((Source::Whole(Box::new(drive)), report.map(|r| r.time_origin_s)))
}

/// A manifest imported as a stream ([`ManifestStream`]) into a
/// [`DriveStream`] (its samples on disk), with the wheel-clock time of its
/// t = 0; the import's account and warnings go to `lines`.
fn streamed_manifest(path: &Path, m: &Manifest, lines: &mut Vec<String>) -> Result<(DriveStream, Option<f64>)> {
    let opts = StreamOptions::default();
    let warm_up_s = opts.warm_up_s;
    let mut s = ManifestStream::open(m, opts)?;
    let stream = DriveStream::spool(path, m.sample_time_s(), || {
        Ok(s.next_chunk(CHUNK)?.map(|c| (c.t, c.signals, c.starts_part)))
    })?;
    let report = s.raw().report();
    if let Some(r) = report {
        lines.push(format!(
            "imported {} as a stream: {} samples in {} part(s), {:.2} km, clock offset {:+.4} s from the first {} s",
            path.display(),
            r.samples,
            r.parts.iter().filter(|p| p.kept).count(),
            r.distance_m / 1e3,
            r.clock_offset.applied_s,
            warm_up_s
        ));
        for w in &r.warnings {
            lines.push(format!("warning: {}: {w}", path.display()));
        }
    }
    Ok((stream, report.map(|r| r.time_origin_s)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::drive::DriveBuilder;
    use crate::sim::{simulate, SimOptions};

    /// A streamed drive is judged as the whole drive is: a stall anywhere,
    /// across the blocks' boundaries too, is found and named with the
    /// whole drive's samples, and a consistent drive passes.
    #[test]
    fn a_streamed_drive_is_judged_as_the_whole_drive() {
        let d = simulate(&SimOptions { length_km: 3.0, ..SimOptions::paper(1) }).expect("simulate").drive;
        let th = Theta::PAPER_INITIAL;
        let dir = tempfile::tempdir().expect("tmp");
        let judge = |name: &str, drive: &Drive, size: usize| {
            let p = dir.path().join(name);
            drive.write_csv(&p).expect("write");
            let whole = Drive::read_csv(&p).expect("whole").0;
            let replay = Replay::open(&p, |_| Ok::<(), Error>(())).expect("open");
            assert!(matches!(replay.source, Source::Stream(_)));
            let streamed = replay.check_in_blocks(&th, size).err().map(|e| e.to_string());
            let whole = check_conventions(&whole, &th, &p.display().to_string()).err().map(|e| e.to_string());
            (streamed, whole)
        };
        for size in [1000, 1 << 16] {
            let (streamed, whole) = judge("ok.csv", &d, size);
            assert_eq!((streamed, whole), (None, None));
        }
        // One wheel at zero for 3 s (120 samples), within blocks and across
        // their boundaries: the blocks of at most 1 000 samples, filled by
        // chunks of 400 and sharing 160, are 0..800, 640..1600, 1440..2400,
        // 2240..3200, …; without the shared samples a stall across 800,
        // 1600 or 2400 would leave less than 2 s in either block.
        for start in [300, 750, 1000, 1550, 1700, 2350] {
            let mut s = d.measured().clone();
            s.n_rr[start..start + 120].iter_mut().for_each(|v| *v = 0.0);
            let stalled = DriveBuilder { t: d.t().to_vec(), measured: s, ..Default::default() }.build().expect("drive");
            for size in [1000, 1 << 16] {
                let (streamed, whole) = judge("stall.csv", &stalled, size);
                let m = streamed.expect("the stall is found");
                assert!(m.contains(&format!("samples {start}–{}", start + 119)), "{m}");
                assert_eq!(Some(m), whole);
            }
        }
    }

    /// A drive imported whole is cut into the chunks a streamed drive
    /// hands out: the same parts, starts and values, bit for bit, so a
    /// calibrator fed either sees the same samples.
    #[test]
    fn a_drive_read_whole_gives_the_streamed_chunks() {
        let d = simulate(&SimOptions { length_km: 1.0, ..SimOptions::paper(5) }).expect("simulate").drive;
        let k = d.len() / 3;
        let t: Vec<f64> = d.t().iter().enumerate().map(|(i, &t)| if i < k { t } else { t + 2.0 }).collect();
        let gapped = DriveBuilder {
            t,
            measured: d.measured().clone(),
            parts: Some(vec![0..k, k..d.len()]),
            ..Default::default()
        }
        .build()
        .expect("drive");
        let dir = tempfile::tempdir().expect("tmp");
        let p = dir.path().join("d.csv");
        gapped.write_csv(&p).expect("write");
        let whole = Drive::read_csv(&p).expect("whole").0;
        let stream = DriveStream::open(&p).expect("stream");
        let a: Vec<StreamChunk> = whole_chunks(&whole, CHUNK).collect();
        let b: Vec<StreamChunk> = stream.chunks(CHUNK).collect::<Result<_>>().expect("chunks");
        assert!(a.len() > 2 && a.iter().filter(|c| c.starts_part).count() == 2, "{}", a.len());
        let bits = |c: &StreamChunk| {
            let cols = c.signals.columns().map(|(_, v)| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>());
            (c.part, c.start, c.starts_part, c.t.iter().map(|x| x.to_bits()).collect::<Vec<_>>(), cols)
        };
        assert_eq!(a.iter().map(bits).collect::<Vec<_>>(), b.iter().map(bits).collect::<Vec<_>>());
    }
}
