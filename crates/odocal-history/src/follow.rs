//! Drives replayed in order, as if live, through the online calibrator,
//! with gated write-back to the vehicle's history (what `odocal follow`
//! runs): [`follow`].

use std::path::PathBuf;

use odocal::io::Replay;
use odocal::{Error, Progress, Theta};
use odocal_online::gate::{Action, GateDecision, Gates};
use odocal_online::{Calibrator, DriveSummary, OnlineOptions};

use crate::source::{held_by_decision, held_by_record, same_data};
use crate::{CalibrationRecord, DecisionRow, History, HistoryRow, ONLINE as METHOD};

/// Settings of [`follow`].
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FollowOptions {
    /// θ_0 when the history holds no calibration of the vehicle; `None`:
    /// the paper's initial θ.
    pub theta0: Option<Theta>,
    /// The online calibrator's options.
    pub online: OnlineOptions,
    /// The write-back gates' thresholds.
    pub gates: Gates,
}

/// What [`follow`] reports as it goes, in order.
#[derive(Debug, Clone, PartialEq)]
pub enum FollowEvent {
    /// Once, when the first drive to follow was read and checked (and is
    /// not one followed before), before it is replayed: the parameters the
    /// replay starts from, and where they come from (`history row N`, or
    /// `θ_0`). Not sent when no drive is replayed: a first drive that
    /// cannot be read stops [`follow`] with its error before any claim of a
    /// start.
    Start {
        /// The stored θ.
        theta: Theta,
        /// Its origin.
        origin: String,
    },
    /// One line about how a drive is read (its reader's warnings, a
    /// manifest imported as a stream or whole), for a log.
    Log(String),
    /// Progress of the current drive's replay.
    Progress(Progress),
    /// A drive the vehicle's history holds already: followed before (its
    /// fingerprint is among the logged decisions) or calibrated (a row of
    /// `calibrations` holds it, by any method), or the same recorded data
    /// imported another way (the same files over overlapping times,
    /// [`source_digest`](crate::source_digest): a manifest that
    /// `calibrate` imported whole and `follow` streams, whose estimated
    /// clock offsets differ). Not replayed: its samples
    /// are in the history already, and the parameters the replay starts
    /// from may have been fitted on them, so replaying it would count them
    /// twice and judge the write-back against parameters fitted on the
    /// very segments it validates on. Also a drive another run (a
    /// concurrent `follow` of the vehicle) logged while this one replayed
    /// it: then nothing is logged or written for it, and the calibrator is
    /// as it was before the drive.
    Skipped {
        /// The drive's file, as given.
        source: String,
        /// Its fingerprint.
        fingerprint: String,
        /// The most recent row of `calibrations` holding the drive, with
        /// its method; `None` for a drive followed before without a write.
        row: Option<(i64, String)>,
    },
    /// A drive replayed: what the calibrator saw, and the gates' decision
    /// (logged in the history's `decisions`; a write is recorded in
    /// `calibrations` and becomes the stored θ).
    Followed {
        /// The drive's file, as given.
        source: String,
        /// Its fingerprint.
        fingerprint: String,
        /// What the calibrator saw of the drive.
        summary: DriveSummary,
        /// The drive's heading offset δ at its end, rad.
        heading_offset_rad: f64,
        /// Time from the drive's first sample to its last, s.
        drive_time_s: f64,
        /// The gates' decision.
        decision: GateDecision,
        /// What one model revolution is ([`Replay::wheel_scale`]): what the
        /// estimate's c_e, c_d and d are per.
        wheel_scale: Option<String>,
    },
}

/// Clock readings from this value on (2001-09-09 in Unix time) are taken
/// for Unix time. Only two such clocks say which drive came first: a
/// logger's clock since boot does not.
const UNIX_TIME_FROM_S: f64 = 1e9;

/// The warning when `source` (first stamp `start_s` on its clock) was
/// recorded before `previous` (first stamp `previous_start_s`), which was
/// followed before it: `None` when it was not, or when either clock does
/// not read as Unix time ([`UNIX_TIME_FROM_S`]).
fn order_warning(source: &str, start_s: f64, previous: &str, previous_start_s: f64) -> Option<String> {
    (unix_time(start_s) && unix_time(previous_start_s) && start_s < previous_start_s).then(|| {
        format!(
            "warning: {source} was recorded {:.0} s before {previous}, which was followed before it (first stamps \
             {start_s:.3} and {previous_start_s:.3} s): follow replays drives in the order given, and the parameters \
             it writes lean on the drives given last; give the drives in the order they were driven",
            previous_start_s - start_s
        )
    })
}

/// A clock reading that reads as Unix time ([`UNIX_TIME_FROM_S`]).
fn unix_time(t: f64) -> bool {
    t.is_finite() && t >= UNIX_TIME_FROM_S
}

/// The parameters in use: θ, its σ, and whether they are a recorded calibration.
struct Stored {
    theta: Theta,
    sigma: Option<Theta>,
    /// A recorded calibration (else θ_0, an initial guess).
    calibrated: bool,
}

/// Refuses `drive` (at `source`) when it counts wheel revolutions
/// otherwise than the first drive that stated a scale (`first`, which the
/// first such drive sets): θ is one vehicle's, in one unit.
fn same_wheel_scale(first: &mut Option<(String, String)>, source: &str, drive: &Replay) -> Result<(), Error> {
    match odocal::wheel_scale_mismatch(first, source, drive.wheel_scale()) {
        Some(why) => {
            let reason = format!("one θ cannot follow drives that count wheel revolutions differently: {why}");
            Err(Error::InvalidDrive { context: source.to_string(), reason })
        }
        None => Ok(()),
    }
}

/// Replays `drives` (drive CSVs or manifests) in order through one online
/// calibrator for `vehicle`, starting from the vehicle's most recent row in
/// `db` whose verdict is not `rejected` and names no bias beyond its σ
/// ([`start_row`]; else `opts.theta0`), and writes back what the
/// gates pass. The
/// row's σ is the recursion's start unless it is the model's alone
/// ([`CalibrationRecord::sigma_model_only`]), a parameter has none (held)
/// or the row names a parameter not observable
/// ([`CalibrationRecord::unobservable`], whose σ is no measure of it); then,
/// as without a σ (a fresh start from θ_0), the options' prior sd is.
///
/// Each drive is read as a stream when it can be (memory flat in its
/// length): a drive CSV, or a manifest of CSV streams (its samples kept in
/// temporary files); another manifest is imported whole. A drive the
/// vehicle's history holds already (among its logged decisions, or in a
/// recorded calibration by any method; by its fingerprint, or by its
/// [`source_digest`](crate::source_digest) and time span) is skipped
/// ([`FollowEvent::Skipped`]): replaying it would count its samples twice.
/// Every other drive is judged first as a calibration judges its drive
/// ([`Replay::check`] at the θ in use): a drive with a lost signal or a
/// wrong convention stops the replay with an error naming it, before it
/// reaches the calibrator; the drives before it stay recorded. After
/// each drive the gates judge the estimate against the stored θ; the
/// decision is logged, and a write is recorded as a calibration (method
/// `online`) that the next drives are judged against. `on` sees every
/// step ([`FollowEvent`]); an error it returns stops the replay.
///
/// ```
/// # fn main() -> Result<(), odocal::Error> {
/// use odocal_history::{follow, FollowEvent, FollowOptions, History};
/// use odocal::sim;
/// let dir = tempfile::tempdir().map_err(|e| odocal::Error::Numerical(e.to_string()))?;
/// let csv = dir.path().join("a.csv");
/// sim::simulate(&sim::SimOptions { length_km: 2.0, noise: "off".parse()?, ..sim::SimOptions::paper(1) })?.drive.write_csv(&csv)?;
/// let mut db = History::open(dir.path().join("van.sqlite"))?;
/// let mut decisions = Vec::new();
/// follow(&mut db, "van-1", &[csv], &FollowOptions::default(), |e| {
///     if let FollowEvent::Followed { decision, .. } = e {
///         decisions.push(decision.action);
///     }
///     Ok::<(), odocal::Error>(())
/// })?;
/// assert_eq!(decisions.len(), 1);
/// assert_eq!(db.vehicle("van-1", None)?.decisions.len(), 1);
/// # Ok(()) }
/// ```
///
/// # Errors
/// A drive's read errors and [`Replay::check`]'s; a drive whose sample time is not the first
/// drive's, or that counts wheel revolutions otherwise ([`Replay::wheel_scale`]); the options'
/// ([`Calibrator::new`]); the history's; `on`'s.
pub fn follow<E: From<Error>>(
    db: &mut History,
    vehicle: &str,
    drives: &[PathBuf],
    opts: &FollowOptions,
    mut on: impl FnMut(FollowEvent) -> std::result::Result<(), E>,
) -> std::result::Result<(), E> {
    let (mut stored, origin) = start(db, vehicle, opts)?;
    let (mut cal, mut started): (Option<Calibrator>, bool) = (None, false);
    // The last drive followed, and its first stamp on its clock: at first
    // the last one an earlier run logged with a Unix-time stamp.
    let mut previous: Option<(String, f64)> = db.last_clock_start(vehicle)?;
    let mut scale: Option<(String, String)> = None; // the first stated wheel scale
    for path in drives {
        let drive = Replay::open(path, |line| on(FollowEvent::Log(line)))?;
        let source = path.display().to_string();
        same_wheel_scale(&mut scale, &source, &drive)?;
        let fingerprint = drive.fingerprint()?;
        let digest = crate::source_digest(path)?;
        let span = drive.time_span_s();
        if let Some(row) = held_already(db, vehicle, &fingerprint, &digest, span)? {
            on(FollowEvent::Skipped { source, fingerprint, row })?;
            continue;
        }
        // Judged as a calibration judges its drive: a lost signal or a
        // wrong convention would enter the recursion, and every later
        // drive's estimate with it.
        drive.check(&stored.theta)?;
        let clock_start_s = drive.clock_span_s().map(|(a, _)| a).filter(|&t| unix_time(t));
        if let (Some((p, p_start)), Some(start)) = (&previous, clock_start_s) {
            if let Some(w) = order_warning(&source, start, p, *p_start) {
                on(FollowEvent::Log(w))?;
            }
        }
        // The calibrator as it was before the drive: restored when another
        // run logs the drive first, so the drive counts once.
        let before = cal.clone();
        let c = match cal.as_mut() {
            Some(c) => c,
            None => {
                // The first drive to replay was read and checked: the replay starts.
                let c = Calibrator::new(stored.theta, stored.sigma, drive.sample_time_s(), opts.online.clone())?;
                if !started {
                    on(FollowEvent::Start { theta: stored.theta, origin: origin.clone() })?;
                    started = true;
                }
                cal.insert(c)
            }
        };
        c.stored = Some(stored.theta);
        on(FollowEvent::Progress(Progress::Stage { name: "following", total: drive.samples() as u64 }))?;
        let mut done = 0;
        let mut progress = Ok(());
        c.push_replay(&drive, |n| {
            if progress.is_ok() {
                progress = on(FollowEvent::Progress(Progress::Advance((n - done) as u64)));
            }
            done = n;
        })?;
        progress?;
        let decision = opts.gates.decide(c, &stored.theta, stored.calibrated);
        let status = c.status();
        let written = (decision.action == Action::Write).then(|| CalibrationRecord {
            sources: vec![source.clone()],
            source_digest: Some(digest.clone()),
            t_start_s: span.0,
            t_end_s: span.1,
            sigma: decision.sigma.into(),
            heading_offset_rad: Some(status.heading_offset_rad),
            // Written only when every gate passed: what its parameter file says.
            verdict: Some(odocal::VerdictLevel::Accepted.to_string()),
            reasons: Some(Vec::new()),
            ..CalibrationRecord::new(vehicle, &fingerprint, METHOD, decision.theta)
        });
        // The decision and its calibration row in one transaction: a
        // decision `written` without its row would skip the drive for ever.
        let logged = db.record_followed(
            &DecisionRow {
                // Set by the database.
                id: 0,
                decided_at: String::new(),
                odocal_version: String::new(),
                vehicle: vehicle.to_string(),
                fingerprint: fingerprint.clone(),
                source: source.clone(),
                source_digest: Some(digest.clone()),
                t_start_s: Some(span.0),
                clock_start_s,
                drive_time_s: span.1 - span.0,
                decision: decision.action.to_string(),
                reasons: decision.reasons.clone(),
                theta: decision.theta,
                sigma: Some(decision.sigma),
            },
            written.as_ref(),
        )?;
        if logged.is_none() {
            // A concurrent run followed the drive while this one replayed it.
            cal = before;
            on(FollowEvent::Skipped { source, fingerprint, row: None })?;
            continue;
        }
        if written.is_some() {
            stored = Stored { theta: decision.theta, sigma: Some(decision.sigma), calibrated: true };
        }
        if let Some(start) = clock_start_s {
            previous = Some((source.clone(), start));
        }
        on(FollowEvent::Followed {
            source,
            fingerprint,
            summary: status.drive,
            heading_offset_rad: status.heading_offset_rad,
            drive_time_s: span.1 - span.0,
            decision,
            wheel_scale: drive.wheel_scale().map(str::to_string),
        })?;
    }
    Ok(())
}

/// Whether the vehicle's history holds the drive already: the same
/// samples (`fingerprint`), or the same files over the same time imported
/// another way (`digest` and `span`: a manifest imported whole by
/// `calibrate`). `Some` with the most recent calibration row holding it
/// (and its method), or `Some(None)` when only a logged decision does.
fn held_already(
    db: &History,
    vehicle: &str,
    fingerprint: &str,
    digest: &str,
    span: (f64, f64),
) -> Result<Option<Option<(i64, String)>>, Error> {
    let here = vec![(digest, Some(span))];
    let row = db
        .rows(vehicle)?
        .into_iter()
        .rev()
        .find(|r| {
            crate::pooled::drives_of(&r.record.fingerprint).any(|f| f == fingerprint)
                || same_data(&held_by_record(&r.record), &here)
        })
        .map(|r| (r.id, r.record.method));
    let decided = |d: &DecisionRow| d.fingerprint == fingerprint || same_data(&held_by_decision(d), &here);
    Ok((row.is_some() || db.decisions(vehicle)?.iter().any(decided)).then_some(row))
}

/// The row [`follow`] starts from among a vehicle's `rows` (in recording
/// order): the most recent whose verdict is not `rejected` and names no
/// bias beyond its σ ([`crate::BIAS_REASONS`]); `None` when no row is
/// such (then `follow` starts from θ_0). A rejected result is not to be
/// deployed, nor started from; a biased one would carry its bias, with a
/// σ that does not hold it, into every later estimate.
pub fn start_row(rows: &[HistoryRow]) -> Option<&HistoryRow> {
    rows.iter().rev().find(|r| !crate::pooled::is_rejected(r) && !crate::pooled::is_biased(r))
}

/// The parameters the replay starts from, and where they come from: the
/// vehicle's most recent row whose verdict is not `rejected` and names no
/// bias beyond its σ ([`crate::BIAS_REASONS`]), else θ_0. The origin
/// names the more recent biased rows passed over.
fn start(db: &History, vehicle: &str, opts: &FollowOptions) -> Result<(Stored, String), Error> {
    let rows = db.rows(vehicle)?;
    let start = start_row(&rows);
    // The biased rows more recent than the start, in recording order.
    let mut passed: Vec<String> = rows
        .iter()
        .rev()
        .take_while(|r| start.is_none_or(|s| s.id != r.id))
        .filter(|r| !crate::pooled::is_rejected(r) && crate::pooled::is_biased(r))
        .map(|r| format!("row {} ({})", r.id, r.record.bias_reasons().join(", ")))
        .collect();
    passed.reverse();
    let passed = if passed.is_empty() {
        String::new()
    } else {
        format!("; not started from, the verdict names a bias beyond its σ: {}", passed.join(", "))
    };
    let (stored, origin) = match start {
        Some(r) => {
            // A σ of the model alone (a batch G-N fit on a short drive) can
            // be several times smaller than the spread between drives: as
            // the recursion's start it would hold θ near the row's, so the
            // calibrator starts from the options' prior sd instead.
            // The recursion needs a σ for every parameter: a row with a
            // parameter held (or without σ) starts from the prior's sd.
            // A parameter the row found not observable has a σ that is
            // no measure of it: the recursion starts as without a σ.
            let unobservable = &r.record.unobservable;
            let sigma = r.record.checked_sigma().all().filter(|_| unobservable.is_empty());
            let origin = match (sigma, r.record.sigma.all()) {
                (None, Some(_)) if !unobservable.is_empty() => {
                    format!("history row {}; {} not observable in it, so the prior's sd", r.id, unobservable.join(", "))
                }
                (None, Some(_)) => format!("history row {}; its σ is the model's alone, so the prior's sd", r.id),
                (None, None) if r.record.sigma != crate::ParamSigma::default() => {
                    format!("history row {}; not every parameter has a σ, so the prior's sd", r.id)
                }
                _ => format!("history row {}", r.id),
            };
            (Stored { theta: r.record.theta, sigma, calibrated: true }, origin)
        }
        None => {
            let theta = opts.theta0.unwrap_or(Theta::PAPER_INITIAL);
            (Stored { theta, sigma: None, calibrated: false }, "θ_0".to_string())
        }
    };
    Ok((stored, origin + &passed))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A drive recorded before the one followed before it is named, with
    /// both first stamps; one recorded after, at the same time, or on a
    /// clock that is not Unix time (since boot, or not a number) is not.
    #[test]
    fn a_drive_recorded_before_the_previous_one_is_named() {
        let (a, b) = (1_722_883_530.268, 1_722_886_117.343);
        let w = order_warning("run-14.toml", a, "run-15.toml", b).expect("out of order");
        for part in ["run-14.toml was recorded 2587 s before run-15.toml", "1722883530.268", "1722886117.343"] {
            assert!(w.contains(part), "{part}: {w}");
        }
        assert_eq!(order_warning("run-15.toml", b, "run-14.toml", a), None);
        assert_eq!(order_warning("run-15.toml", b, "run-15b.toml", b), None);
        assert_eq!(order_warning("boot.toml", 120.0, "boot-2.toml", 3600.0), None);
        assert!(order_warning("unix.toml", a, "later.toml", b * 2.0).is_some());
        assert_eq!(order_warning("unix.toml", a, "boot.toml", 3600.0), None);
        assert_eq!(order_warning("nan.toml", f64::NAN, "run-15.toml", b), None);
    }
}
