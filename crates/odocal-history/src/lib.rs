//! # odocal-history — a per-vehicle history of calibrations in an SQLite file
//!
//! For programs that keep a vehicle's calibration current: `odocal
//! calibrate --vehicle ID --db FILE` and `odocal follow` record here, and
//! `odocal history` reads it ([`History::vehicle`]: the rows, drift flags,
//! pooled estimate and decisions of one vehicle, [`VehicleHistory`]). One row of the table `calibrations` per
//! recorded drive and method: θ with σ, the verdict, the time span, the
//! source files, the odocal version and the drive's
//! [fingerprint](odocal::Drive::fingerprint). A drive already recorded for a
//! vehicle with the same method is recognised and not recorded twice
//! ([`Recorded::AlreadyRecorded`]); a drive recorded by several methods
//! keeps a row for each, and the drift flags and the pooled estimate count
//! it once, by its most recent row ([`SetAside`]). The table `decisions` logs the gated
//! write-back of `odocal follow` ([`fn@follow`]: drive files replayed through
//! the online calibrator of the crate odocal-online), one row per decision.
//!
//! A crate of its own on top of the `odocal` library: it compiles SQLite in
//! (rusqlite, feature `bundled`), which calibrating does not need.
//!
//! The file is in WAL mode with a busy timeout, so several processes may
//! read and write it at once; each write is one transaction. The schema
//! is versioned (`PRAGMA user_version`) and migrated on [`History::open`];
//! docs/reference.md lists its tables and columns.
//!
//! ```
//! # fn main() -> Result<(), odocal::Error> {
//! use odocal_history::{CalibrationRecord, History, Recorded};
//! use odocal::Theta;
//! let dir = tempfile::tempdir().map_err(|e| odocal::Error::Numerical(e.to_string()))?;
//! let mut db = History::open(dir.path().join("van.sqlite"))?;
//! let rec = CalibrationRecord::new("van-1", "ab12", "eiv", Theta::PAPER_NOMINAL);
//! assert!(matches!(db.record(&rec)?, Recorded::New(_)));
//! assert!(matches!(db.record(&rec)?, Recorded::AlreadyRecorded(_)));
//! assert_eq!(db.vehicle("van-1", None)?.rows.len(), 1);
//! # Ok(()) }
//! ```

use std::path::{Path, PathBuf};
use std::time::Duration;

use rusqlite::{params, Connection, OptionalExtension, Row};
use serde::{Deserialize, Serialize};

use odocal::model::THETA_NAMES;
use odocal::{CalibrationReport, Error, Result, Theta};

mod cell;
mod follow;
mod pooled;
mod schema;
mod source;
mod store;
mod table;

use store::{insert_decision, insert_record, read_only_connection};

pub use follow::{follow, start_row, FollowEvent, FollowOptions};
pub use pooled::{Biased, DriftFlag, NotMeasured, Pooled, SetAside, BIAS_REASONS, DRIFT_SIGMAS};
pub use source::{source_digest, source_digests};

/// The parameters of θ in vector order `[c_e, c_d, t_r, d]`.
const THETA_PARAMS: [odocal::Param; 4] = [odocal::Param::CE, odocal::Param::CD, odocal::Param::TR, odocal::Param::D];

/// How long a writer waits for another process's transaction to finish.
const BUSY_TIMEOUT: Duration = Duration::from_secs(30);

/// One calibration of one drive, as recorded.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRecord {
    /// The vehicle's identifier (any text the user chooses).
    pub vehicle: String,
    /// The drive's [fingerprint](odocal::Drive::fingerprint).
    pub fingerprint: String,
    /// The files the drive was read from.
    pub sources: Vec<String>,
    /// The drive's [source digest](source_digest), a hash of the files it
    /// was read from, one per drive as in `fingerprint` (comma separated):
    /// with the time span it tells the same recorded data imported another
    /// way. `None` when not known (a drive made from arrays, or a row
    /// recorded before the column).
    #[serde(default)]
    pub source_digest: Option<String>,
    /// First and last sample time of the drive, s.
    pub t_start_s: f64,
    /// Last sample time, s.
    pub t_end_s: f64,
    /// The method (`eiv`, `three-step`, `batch-gn`, `online`, …).
    pub method: String,
    /// The estimate.
    pub theta: Theta,
    /// Its standard deviation, per parameter: `None` for a parameter
    /// without one (held at θ_0, or a method without σ).
    #[serde(default, deserialize_with = "sigma_or_null")]
    pub sigma: ParamSigma,
    /// The parameters held at θ_0 (`c_e`, `c_d`, `t_r`, `d`): fixed by the
    /// user (`--fix`) or by auto-fix. Their value is the start's, not a
    /// measurement, so it takes no part in that parameter's drift flags and
    /// pooled estimate. Empty for a row of a file that did not record it.
    #[serde(default)]
    pub held: Vec<String>,
    /// The free parameters the calibration found not observable from its
    /// drive: their value is not to be trusted, so, as a held one, it takes
    /// no part in that parameter's drift flags and pooled estimate.
    #[serde(default)]
    pub unobservable: Vec<String>,
    /// The reference's heading offset on this drive, rad, when estimated.
    pub heading_offset_rad: Option<f64>,
    /// The verdict (`accepted`, `doubtful`, `rejected`), when judged.
    pub verdict: Option<String>,
    /// Whether `sigma` is the model's alone, checked against nothing in the
    /// data (the verdict reason `model_sigma_only`: batch Gauss-Newton
    /// without its cluster-robust σ, on a drive too short for it). Such a σ
    /// can be several times smaller than the spread of estimates between
    /// drives, so a change beyond three of it is no evidence of drift by
    /// itself ([`DriftFlag::model_sigma_only`]). `None` when not known.
    #[serde(default)]
    pub sigma_model_only: Option<bool>,
    /// The verdict's reason kinds (the JSON `kind`s of the calibration
    /// report's verdict reasons, e.g. `input_noise_bias`); empty for a
    /// verdict without reasons, `None` when not known (rows recorded
    /// without them). A row whose reasons name a bias of its estimate
    /// beyond its σ ([`BIAS_REASONS`]) is not pooled ([`Pooled::biased`])
    /// nor started from by [`fn@follow`].
    #[serde(default)]
    pub reasons: Option<Vec<String>>,
}

impl CalibrationRecord {
    /// A record with the required fields; the others empty or zero.
    pub fn new(vehicle: &str, fingerprint: &str, method: &str, theta: Theta) -> Self {
        CalibrationRecord {
            vehicle: vehicle.to_string(),
            fingerprint: fingerprint.to_string(),
            sources: Vec::new(),
            source_digest: None,
            t_start_s: 0.0,
            t_end_s: 0.0,
            method: method.to_string(),
            theta,
            sigma: ParamSigma::default(),
            held: Vec::new(),
            unobservable: Vec::new(),
            heading_offset_rad: None,
            verdict: None,
            sigma_model_only: None,
            reasons: None,
        }
    }

    /// Checks the record before it is written ([`History::record`]): the
    /// vehicle's identifier ([`check_vehicle_id`]), a method of odocal's
    /// ([`METHODS`]), θ within the physical limits
    /// ([`Theta::check_physical_limits`]), each σ finite and not
    /// negative, `held` and `unobservable` naming parameters of θ, each
    /// of `reasons` a kind's name (letters, digits and `_`).
    ///
    /// # Errors
    /// [`Error::InvalidOption`] naming the field, or [`Error::InvalidTheta`].
    pub fn check(&self) -> Result<()> {
        check_vehicle_id(&self.vehicle)?;
        if !METHODS.contains(&self.method.as_str()) {
            return Err(Error::InvalidOption {
                field: "method",
                reason: format!("'{}' is not a method of odocal's: {}", self.method.escape_debug(), METHODS.join(", ")),
            });
        }
        self.theta.check_physical_limits()?;
        let sigma = <[Option<f64>; 4]>::from(self.sigma);
        let bad = THETA_NAMES
            .iter()
            .zip(sigma)
            .find_map(|(name, v)| v.filter(|v| !v.is_finite() || *v < 0.0).map(|v| (name, v)));
        if let Some((name, v)) = bad {
            return Err(Error::InvalidOption {
                field: "sigma",
                reason: format!("{name} = {v}: a standard deviation is a finite number, not negative"),
            });
        }
        for (field, names) in [("held", &self.held), ("unobservable", &self.unobservable)] {
            if let Some(p) = names.iter().find(|p| !THETA_NAMES.contains(&p.as_str())) {
                return Err(Error::InvalidOption {
                    field,
                    reason: format!("'{}' is not a parameter of θ: c_e, c_d, t_r or d", p.escape_debug()),
                });
            }
        }
        let is_kind = |k: &str| !k.is_empty() && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        if let Some(k) = self.reasons.iter().flatten().find(|k| !is_kind(k)) {
            return Err(Error::InvalidOption {
                field: "reasons",
                reason: format!("'{}' is not a verdict reason's kind (letters, digits and _)", k.escape_debug()),
            });
        }
        Ok(())
    }

    /// `sigma` unless it is the model's alone ([`Self::sigma_model_only`]):
    /// the σ a row is weighed by in the pooled estimate and `follow` starts
    /// from.
    pub(crate) fn checked_sigma(&self) -> ParamSigma {
        if self.sigma_model_only == Some(true) {
            ParamSigma::default()
        } else {
            self.sigma
        }
    }

    /// The kinds among [`Self::reasons`] that name a bias of the estimate
    /// beyond its σ ([`BIAS_REASONS`]), in [`BIAS_REASONS`]' order; empty
    /// when none is named or the reasons are not known.
    pub fn bias_reasons(&self) -> Vec<&'static str> {
        let named = |k: &&str| self.reasons.iter().flatten().any(|r| r == k);
        BIAS_REASONS.iter().copied().filter(named).collect()
    }

    /// True when parameter `i` (`[c_e, c_d, t_r, d]`) was measured: neither
    /// held nor named not observable.
    pub fn measured(&self, i: usize) -> bool {
        let name = THETA_NAMES[i];
        !self.held.iter().chain(&self.unobservable).any(|p| p == name)
    }

    /// Why parameter `i` is no measurement (`held`, `not observable`), or
    /// `None` for a measured one.
    pub fn not_measured(&self, i: usize) -> Option<&'static str> {
        let name = THETA_NAMES[i];
        if self.held.iter().any(|p| p == name) {
            Some("held")
        } else if self.unobservable.iter().any(|p| p == name) {
            Some("not observable")
        } else {
            None
        }
    }
}

/// One standard deviation per parameter of θ, SI units; `None` for a
/// parameter without one. In JSON `{"c_e": …, "c_d": …, "t_r": …, "d": null}`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct ParamSigma {
    /// 1σ of c_e, m.
    #[serde(default)]
    pub c_e: Option<f64>,
    /// 1σ of c_d, m.
    #[serde(default)]
    pub c_d: Option<f64>,
    /// 1σ of t_r, m.
    #[serde(default)]
    pub t_r: Option<f64>,
    /// 1σ of d, m per m/s².
    #[serde(default)]
    pub d: Option<f64>,
}

impl ParamSigma {
    /// Every parameter's σ, when each has one.
    pub fn all(self) -> Option<Theta> {
        match <[_; 4]>::from(self) {
            [Some(c_e), Some(c_d), Some(t_r), Some(d)] => Some(Theta { c_e, c_d, t_r, d }),
            _ => None,
        }
    }
}

/// `[c_e, c_d, t_r, d]`.
impl From<ParamSigma> for [Option<f64>; 4] {
    fn from(s: ParamSigma) -> Self {
        [s.c_e, s.c_d, s.t_r, s.d]
    }
}

/// From `[c_e, c_d, t_r, d]`.
impl From<[Option<f64>; 4]> for ParamSigma {
    fn from([c_e, c_d, t_r, d]: [Option<f64>; 4]) -> Self {
        ParamSigma { c_e, c_d, t_r, d }
    }
}

/// A σ for every parameter.
impl From<Theta> for ParamSigma {
    fn from(s: Theta) -> Self {
        <[f64; 4]>::from(s).map(Some).into()
    }
}

/// A σ of `null` (no σ at all) reads as one without any parameter's.
fn sigma_or_null<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<ParamSigma, D::Error> {
    Ok(Option::<ParamSigma>::deserialize(d)?.unwrap_or_default())
}

impl CalibrationRecord {
    /// The record of an offline calibration: θ, the σ that stands for the
    /// result (each parameter's that has one), the parameters held and those
    /// named not observable, the estimated heading offset and the verdict
    /// of `report`; `fingerprint` names the calibration drive(s), `sources`
    /// their files and `span_s` their first and last sample time.
    pub fn of_report(
        vehicle: &str,
        fingerprint: &str,
        sources: Vec<String>,
        span_s: (f64, f64),
        report: &CalibrationReport,
    ) -> Self {
        let sigma = ParamSigma::from(<[_; 4]>::from(report.result_sigma()));
        let free = report.options.identify.free;
        let names = |keep: &dyn Fn(odocal::Param) -> bool| -> Vec<String> {
            THETA_PARAMS.iter().filter(|p| keep(**p)).map(|p| p.to_string()).collect()
        };
        let held = names(&|p| !free.contains(p));
        let unobservable = names(&|p| free.contains(p) && report.observability.unobservable.contains(p));
        CalibrationRecord {
            held,
            unobservable,
            sources,
            t_start_s: span_s.0,
            t_end_s: span_s.1,
            sigma,
            heading_offset_rad: report.extrinsics.as_ref().map(|x| x.value.heading_offset),
            verdict: Some(report.verdict.level.to_string()),
            sigma_model_only: Some(
                report.verdict.reasons.iter().any(|r| matches!(r, odocal::VerdictReason::ModelSigmaOnly { .. })),
            ),
            // The JSON `kind` of each reason (its serde tag).
            reasons: Some(
                report
                    .verdict
                    .reasons
                    .iter()
                    .filter_map(|r| serde_json::to_value(r).ok()?.get("kind")?.as_str().map(String::from))
                    .collect(),
            ),
            ..CalibrationRecord::new(vehicle, fingerprint, &report.method, report.theta)
        }
    }
}

/// The methods a row of `calibrations` records: the offline methods of
/// `odocal calibrate` and `online`, the calibrator `odocal follow` runs.
pub const METHODS: [&str; 4] = ["eiv", "three-step", "batch-gn", ONLINE];

/// Checks a vehicle's identifier, the key of its rows (`--vehicle ID`,
/// Python's `History.record`): not blank, no space at either end (`van-1 `
/// would be a vehicle of its own, apart from `van-1`) and no control
/// characters.
///
/// # Errors
/// [`Error::InvalidOption`] (field `vehicle`) saying what to give.
pub fn check_vehicle_id(id: &str) -> Result<()> {
    let reason = if id.trim().is_empty() {
        "the vehicle's identifier is empty: give the name its history is kept under, e.g. van-1".to_string()
    } else if id.chars().any(char::is_control) {
        format!("'{}' holds a control character: give a plain name, e.g. van-1", id.escape_debug())
    } else if id.trim() != id {
        format!(
            "'{id}' has a space at an end, which would keep its history apart from '{}': give it without",
            id.trim()
        )
    } else {
        return Ok(());
    };
    Err(Error::InvalidOption { field: "vehicle", reason })
}

/// A row of the table `calibrations`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HistoryRow {
    /// The row id (increasing in recording order).
    pub id: i64,
    /// When it was recorded, UTC, ISO 8601 (`2026-11-29T04:05:06.789Z`).
    pub recorded_at: String,
    /// The odocal version that recorded it.
    pub odocal_version: String,
    /// What was recorded.
    #[serde(flatten)]
    pub record: CalibrationRecord,
}

/// The outcome of [`History::record`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Recorded {
    /// A new row, with its id.
    New(i64),
    /// The vehicle's history already holds this drive (same fingerprint)
    /// calibrated by the same method: nothing was added; the existing row's id.
    AlreadyRecorded(i64),
}

/// A row of the table `decisions`: a write-back decision of the online
/// calibration ([`fn@follow`]).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DecisionRow {
    /// The row id (increasing in logging order).
    pub id: i64,
    /// When it was decided, UTC, ISO 8601.
    pub decided_at: String,
    /// The odocal version that decided it.
    pub odocal_version: String,
    /// The vehicle.
    pub vehicle: String,
    /// The drive's fingerprint.
    pub fingerprint: String,
    /// The drive's source (file or manifest).
    pub source: String,
    /// The drive's [source digest](source_digest); `None` when not known
    /// (a decision logged before the column).
    #[serde(default)]
    pub source_digest: Option<String>,
    /// Time of the drive's first sample, s on its own clock; `None` when
    /// not known (a decision logged before the column).
    #[serde(default)]
    pub t_start_s: Option<f64>,
    /// The drive's first stamp on the logger's clock, s, when that clock
    /// reads as Unix time (which tells the order drives were recorded in);
    /// `None` otherwise, or for a decision logged before the column.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub clock_start_s: Option<f64>,
    /// Time into the drive, s (from its first sample).
    pub drive_time_s: f64,
    /// `written`, `held` or `flagged` (a change too large to write without a person).
    pub decision: String,
    /// Why: the gates that held it, or what was written.
    pub reasons: Vec<String>,
    /// The proposed θ.
    pub theta: Theta,
    /// Its σ.
    pub sigma: Option<Theta>,
}

/// A vehicle's history as read ([`History::vehicle`]): its calibrations,
/// the drift flags between consecutive ones, their pooled estimate and the
/// logged write-back decisions. The drift flags and the pooled estimate
/// count each drive once: of several rows holding one drive, the most
/// recent stands and the others are [`SetAside`]. Its
/// [`Display`](std::fmt::Display) is the table `odocal history` prints.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct VehicleHistory {
    /// The vehicle's identifier.
    pub vehicle: String,
    /// Its calibrations in recording order, every row recorded.
    pub rows: Vec<HistoryRow>,
    /// The rows the drift flags leave out: a more recent row holds their
    /// drive. In recording order.
    pub set_aside: Vec<SetAside>,
    /// Every parameter change between consecutive rows (those not set
    /// aside, nor rejected) beyond [`DRIFT_SIGMAS`] combined σ (pairs where
    /// a row has no σ are skipped).
    pub drift: Vec<DriftFlag>,
    /// The pooled estimate over the rows asked for (all by default), each
    /// drive once; `None` without rows.
    pub pooled: Option<Pooled>,
    /// The logged write-back decisions in logging order.
    pub decisions: Vec<DecisionRow>,
}

impl VehicleHistory {
    /// The history of `vehicle` made of `rows` (in recording order): their
    /// drift flags and the pooled estimate over those with an id in `pool`
    /// (all when `None`), each drive counted once; no decisions.
    pub fn of_rows(vehicle: &str, rows: Vec<HistoryRow>, pool: Option<&[i64]>) -> VehicleHistory {
        let judged: Vec<HistoryRow> = rows.iter().filter(|r| !pooled::is_rejected(r)).cloned().collect();
        let (standing, set_aside) = pooled::counted_once(&judged);
        let drift = pooled::drift_between(&standing);
        let pooled_rows: Vec<HistoryRow> =
            rows.iter().filter(|r| pool.is_none_or(|ids| ids.contains(&r.id))).cloned().collect();
        let pooled = pooled::pooled_estimate(&pooled_rows);
        VehicleHistory { vehicle: vehicle.to_string(), rows, set_aside, drift, pooled, decisions: Vec::new() }
    }
}

/// The method of the rows `odocal follow` writes: running estimates of the
/// online calibrator, each holding the drives followed before it.
pub const ONLINE: &str = "online";

/// Appended to a drift flag whose combined σ holds a model-only σ
/// ([`DriftFlag::model_sigma_only`]).
pub const MODEL_SIGMA_NOTE: &str =
    " — a σ of the model alone (verdict reason model_sigma_only): no evidence of drift by itself";

/// Appended to a drift flag between rows one of which names a bias of its
/// estimate beyond its σ ([`DriftFlag::biased`]).
pub const BIASED_NOTE: &str =
    " — a row whose verdict names a bias beyond its σ (not pooled): the change may be that bias, not drift";

/// An open history database.
#[derive(Debug)]
pub struct History {
    /// The database file.
    pub path: PathBuf,
    /// The schema version of the file (after [`History::open`]'s
    /// migration, this odocal's).
    pub schema_version: i64,
    conn: Connection,
}

fn sql_err(path: &Path) -> impl Fn(rusqlite::Error) -> Error {
    let path = path.to_path_buf();
    move |e| Error::History { path: path.clone(), reason: e.to_string() }
}

/// [`sql_err`] for opening: a file that is not an SQLite database (a
/// drive, a report given as `--db`) says what to give instead.
fn open_err(path: &Path) -> impl Fn(rusqlite::Error) -> Error {
    let plain = sql_err(path);
    let path = path.to_path_buf();
    move |e| match e {
        rusqlite::Error::SqliteFailure(f, _) if f.code == rusqlite::ErrorCode::NotADatabase => {
            Error::History { path: path.clone(), reason: format!("not an SQLite file ({NOT_A_HISTORY})") }
        }
        e => plain(e),
    }
}

/// Why `path`, when it exists, is no file a history can be kept in: a
/// folder, or not a regular file (a FIFO, a device, a socket; a symbolic
/// link counts as its target). `None` for a regular file or a path where
/// nothing is.
fn not_a_regular_file(path: &Path) -> Option<String> {
    let m = std::fs::metadata(path).ok()?;
    if m.is_dir() {
        Some(format!("a folder, not a file ({NOT_A_HISTORY})"))
    } else if !m.is_file() {
        Some(format!("not a regular file (a FIFO, device or socket), so no history database ({NOT_A_HISTORY})"))
    } else {
        None
    }
}

/// What to give instead of a file that is no history database.
const NOT_A_HISTORY: &str =
    "give the file that calibrate --vehicle or follow record in, or the name of a new file to start a history";

const ROW_COLUMNS: &str = "id, recorded_at, odocal_version, vehicle, fingerprint, sources, t_start_s, t_end_s, \
     method, c_e, c_d, t_r, d, sigma_c_e, sigma_c_d, sigma_t_r, sigma_d, heading_offset_rad, verdict, sigma_model_only, \
     held, unobservable, reasons, source_digest";

fn theta_at(r: &Row<'_>, i: usize) -> rusqlite::Result<Theta> {
    Ok(Theta { c_e: r.get(i)?, c_d: r.get(i + 1)?, t_r: r.get(i + 2)?, d: r.get(i + 3)? })
}

fn sigma_at(r: &Row<'_>, i: usize) -> rusqlite::Result<ParamSigma> {
    let v: [Option<f64>; 4] = [r.get(i)?, r.get(i + 1)?, r.get(i + 2)?, r.get(i + 3)?];
    Ok(v.into())
}

/// A column of parameter names (`t_r,d`); NULL (not recorded) and empty
/// text name none.
fn names_at(r: &Row<'_>, i: usize) -> rusqlite::Result<Vec<String>> {
    let v: Option<String> = r.get(i)?;
    Ok(v.unwrap_or_default().split(',').map(str::trim).filter(|p| !p.is_empty()).map(String::from).collect())
}

fn history_row(r: &Row<'_>) -> rusqlite::Result<HistoryRow> {
    let sources: String = r.get(5)?;
    Ok(HistoryRow {
        id: r.get(0)?,
        recorded_at: r.get(1)?,
        odocal_version: r.get(2)?,
        record: CalibrationRecord {
            vehicle: r.get(3)?,
            fingerprint: r.get(4)?,
            sources: serde_json::from_str(&sources).unwrap_or_else(|_| vec![sources.clone()]),
            t_start_s: r.get(6)?,
            t_end_s: r.get(7)?,
            method: r.get(8)?,
            theta: theta_at(r, 9)?,
            sigma: sigma_at(r, 13)?,
            heading_offset_rad: r.get(17)?,
            verdict: r.get(18)?,
            sigma_model_only: r.get(19)?,
            held: names_at(r, 20)?,
            unobservable: names_at(r, 21)?,
            reasons: r
                .get::<_, Option<String>>(22)?
                .map(|v| v.split(',').map(str::trim).filter(|k| !k.is_empty()).map(String::from).collect()),
            source_digest: r.get(23)?,
        },
    })
}

fn decision_row(r: &Row<'_>) -> rusqlite::Result<DecisionRow> {
    let reasons: String = r.get(6)?;
    Ok(DecisionRow {
        id: r.get(0)?,
        decided_at: r.get(1)?,
        odocal_version: r.get(2)?,
        vehicle: r.get(3)?,
        fingerprint: r.get(4)?,
        source: r.get(5)?,
        reasons: serde_json::from_str(&reasons).unwrap_or_else(|_| vec![reasons.clone()]),
        drive_time_s: r.get(7)?,
        decision: r.get(8)?,
        theta: theta_at(r, 9)?,
        sigma: sigma_at(r, 13)?.all(),
        source_digest: r.get(17)?,
        t_start_s: r.get(18)?,
        clock_start_s: r.get(19)?,
    })
}

fn sigma_params(s: &Option<Theta>) -> [Option<f64>; 4] {
    s.map_or([None; 4], |s| ParamSigma::from(s).into())
}

/// The current time in the database's format (UTC, milliseconds).
const NOW: &str = "strftime('%Y-%m-%dT%H:%M:%fZ', 'now')";

impl History {
    /// Opens (creating if need be) the history at `path`, switches it to
    /// WAL mode and brings its schema to this odocal's version. A history
    /// is created only in a new or empty file (or an SQLite database
    /// without tables); an SQLite file that is no history (another
    /// application's tables, an `application_id`, a schema version without
    /// the history's tables) is refused before anything in it changes, as
    /// are a file that is not a regular file and one written by a newer
    /// odocal (a higher schema version).
    ///
    /// # Errors
    /// [`Error::History`] naming the file and what to give.
    pub fn open(path: impl AsRef<Path>) -> Result<History> {
        let path = path.as_ref().to_path_buf();
        if let Some(reason) = not_a_regular_file(&path) {
            return Err(Error::History { path, reason });
        }
        let err = open_err(&path);
        let mut conn = Connection::open(&path).map_err(&err)?;
        conn.busy_timeout(BUSY_TIMEOUT).map_err(&err)?;
        if let schema::Found::Foreign(what) = schema::inspect(&conn).map_err(&err)? {
            return Err(Error::History { path, reason: format!("{what}, not an odocal history ({NOT_A_HISTORY})") });
        }
        // WAL: readers do not block the writer and a crash mid-write leaves
        // the last committed state. Setting it needs a moment of exclusive
        // access; the busy timeout covers a concurrent opener.
        let mode = switch_to_wal(&conn).map_err(&err)?;
        if !mode.eq_ignore_ascii_case("wal") {
            return Err(Error::History { path, reason: format!("could not switch to WAL mode (journal mode {mode})") });
        }
        conn.pragma_update(None, "synchronous", "NORMAL").map_err(&err)?;
        schema::migrate(&mut conn).map_err(|reason| Error::History { path: path.clone(), reason })?;
        let schema_version = conn.query_row("PRAGMA user_version", [], |r| r.get(0)).map_err(&err)?;
        Ok(History { conn, path, schema_version })
    }

    /// [`History::open`] for a program that will write (`follow`,
    /// `calibrate --db`): a file SQLite can open only read-only (no
    /// permission, a read-only file system), which [`History::open`] takes
    /// for reading and which would fail at the first write, after the
    /// work, is refused at once.
    ///
    /// # Errors
    /// [`History::open`]'s; [`Error::History`] for a file that cannot be written.
    pub fn open_to_write(path: impl AsRef<Path>) -> Result<History> {
        let db = History::open(path)?;
        if db.conn.is_readonly(rusqlite::MAIN_DB).map_err(sql_err(&db.path))? {
            return Err(Error::History {
                path: db.path,
                reason: "cannot be written (read-only, or no permission): give a file you can write to".into(),
            });
        }
        Ok(db)
    }

    /// Opens the history at `path` to read it, changing nothing: neither
    /// the file nor its schema (a file of an older schema is read from a
    /// copy in memory, migrated there). A file that is not there, that is
    /// empty or that is no history database (an SQLite file without its
    /// tables) is refused, as is one written by a newer odocal.
    ///
    /// # Errors
    /// [`Error::History`] naming the file and what to give.
    pub fn open_read_only(path: impl AsRef<Path>) -> Result<History> {
        let path = path.as_ref().to_path_buf();
        let refuse = |reason: String| Error::History { path: path.clone(), reason };
        if let Some(reason) = not_a_regular_file(&path) {
            return Err(refuse(reason));
        }
        match std::fs::metadata(&path) {
            Ok(m) if m.len() == 0 => {
                return Err(refuse(format!("an empty file, not a history database ({NOT_A_HISTORY})")))
            }
            Ok(_) => {}
            Err(e) => return Err(refuse(format!("cannot be read: {e}"))),
        }
        let err = open_err(&path);
        let (conn, version) = read_only_connection(&path).map_err(&err)?;
        let tables: i64 = conn
            .query_row(
                "SELECT COUNT(*) FROM sqlite_master WHERE type = 'table' AND name IN ('calibrations', 'decisions')",
                [],
                |r| r.get(0),
            )
            .map_err(&err)?;
        if version == 0 || tables < 2 {
            return Err(refuse(format!("an SQLite file without a history's tables ({NOT_A_HISTORY})")));
        }
        schema::check_not_newer(version).map_err(&refuse)?;
        if version == schema::SCHEMA_VERSION {
            return Ok(History { conn, path, schema_version: version });
        }
        // An older schema: migrated in a copy, the file left as it is.
        let mut copy = Connection::open_in_memory().map_err(&err)?;
        rusqlite::backup::Backup::new(&conn, &mut copy)
            .and_then(|b| b.run_to_completion(256, Duration::ZERO, None))
            .map_err(&err)?;
        schema::migrate(&mut copy).map_err(&refuse)?;
        Ok(History { conn: copy, path, schema_version: schema::SCHEMA_VERSION })
    }

    /// Records a calibration, unless the vehicle's history already holds
    /// the same drive (fingerprint) calibrated by the same method
    /// ([`Recorded::AlreadyRecorded`]). One transaction; safe with other
    /// writers.
    ///
    /// # Errors
    /// [`CalibrationRecord::check`]'s, before anything is written;
    /// [`Error::History`] for the database's.
    pub fn record(&mut self, rec: &CalibrationRecord) -> Result<Recorded> {
        insert_record(&self.conn, &self.path, rec)
    }

    /// The history of `vehicle`: its calibrations, their drift flags, the
    /// pooled estimate over those with an id in `pool` (all when `None`)
    /// and its logged write-back decisions.
    pub fn vehicle(&self, vehicle: &str, pool: Option<&[i64]>) -> Result<VehicleHistory> {
        let decisions = self.decisions(vehicle)?;
        Ok(VehicleHistory { decisions, ..VehicleHistory::of_rows(vehicle, self.rows(vehicle)?, pool) })
    }

    /// The vehicles the database holds calibrations or decisions of, sorted.
    pub fn vehicles(&self) -> Result<Vec<String>> {
        let err = sql_err(&self.path);
        let mut st = self
            .conn
            .prepare("SELECT vehicle FROM calibrations UNION SELECT vehicle FROM decisions ORDER BY vehicle")
            .map_err(&err)?;
        let rows = st.query_map([], |r| r.get::<_, String>(0)).map_err(&err)?;
        rows.collect::<rusqlite::Result<Vec<_>>>().map_err(&err)
    }

    /// The vehicle's calibrations in recording order.
    pub(crate) fn rows(&self, vehicle: &str) -> Result<Vec<HistoryRow>> {
        let err = sql_err(&self.path);
        let mut st = self
            .conn
            .prepare(&format!("SELECT {ROW_COLUMNS} FROM calibrations WHERE vehicle = ?1 ORDER BY id"))
            .map_err(&err)?;
        let rows = st.query_map(params![vehicle], cell::checked("calibrations", history_row)).map_err(&err)?;
        cell::collect(rows, &self.path, err)
    }

    /// Logs a write-back decision unless the vehicle's decisions hold one
    /// for the drive (same fingerprint) already and, when the decision is
    /// logged and `written` is given, records that calibration
    /// ([`Self::record`]), in one transaction: an error or an interruption
    /// between the two leaves neither, so no decision says `written`
    /// without its row in `calibrations`. Returns the decision's id, or
    /// `None` when another run (a concurrent `follow`) logged the drive
    /// first; then nothing is written. The check and the insert are one
    /// statement, so of two writers one logs the drive. The database sets
    /// the decision's `id`, `decided_at` and `odocal_version` (`d`'s are
    /// not read).
    pub(crate) fn record_followed(
        &mut self,
        d: &DecisionRow,
        written: Option<&CalibrationRecord>,
    ) -> Result<Option<i64>> {
        let err = sql_err(&self.path);
        // Dropped without a commit on any error: rolled back.
        let tx = self.conn.transaction_with_behavior(rusqlite::TransactionBehavior::Immediate).map_err(&err)?;
        let id = insert_decision(&tx, &self.path, d)?;
        if let (Some(_), Some(rec)) = (id, written) {
            insert_record(&tx, &self.path, rec)?;
        }
        tx.commit().map_err(&err)?;
        Ok(id)
    }

    /// The vehicle's logged write-back decisions in logging order.
    pub(crate) fn decisions(&self, vehicle: &str) -> Result<Vec<DecisionRow>> {
        let err = sql_err(&self.path);
        let mut st = self
            .conn
            .prepare(
                "SELECT id, decided_at, odocal_version, vehicle, fingerprint, source, reasons, drive_time_s, \
                 decision, c_e, c_d, t_r, d, sigma_c_e, sigma_c_d, sigma_t_r, sigma_d, source_digest, t_start_s, \
                 clock_start_s FROM decisions \
                 WHERE vehicle = ?1 ORDER BY id",
            )
            .map_err(&err)?;
        let rows = st.query_map(params![vehicle], cell::checked("decisions", decision_row)).map_err(&err)?;
        cell::collect(rows, &self.path, err)
    }

    /// The source and Unix-time first stamp of the vehicle's last logged
    /// decision that has one ([`DecisionRow::clock_start_s`]).
    pub(crate) fn last_clock_start(&self, vehicle: &str) -> Result<Option<(String, f64)>> {
        self.conn
            .query_row(
                "SELECT source, clock_start_s FROM decisions WHERE vehicle = ?1 AND clock_start_s IS NOT NULL \
                 ORDER BY id DESC LIMIT 1",
                params![vehicle],
                |r| Ok((r.get(0)?, r.get(1)?)),
            )
            .optional()
            .map_err(sql_err(&self.path))
    }

    /// The number of decisions logged for the vehicle.
    #[cfg(test)]
    pub(crate) fn decision_count(&self, vehicle: &str) -> Result<usize> {
        self.conn
            .query_row("SELECT COUNT(*) FROM decisions WHERE vehicle = ?1", params![vehicle], |r| r.get(0))
            .map_err(sql_err(&self.path))
    }
}

/// Switches the connection to WAL mode. Two processes opening a new file at
/// once can both hold a read lock while asking for the exclusive one the
/// switch needs; SQLite then answers "database is locked" at once, without
/// its busy handler (waiting could deadlock). The switch is retried until
/// the busy timeout has passed.
fn switch_to_wal(conn: &Connection) -> rusqlite::Result<String> {
    let start = std::time::Instant::now();
    loop {
        match conn.query_row("PRAGMA journal_mode = WAL", [], |r| r.get::<_, String>(0)) {
            Err(rusqlite::Error::SqliteFailure(e, _))
                if matches!(e.code, rusqlite::ErrorCode::DatabaseBusy | rusqlite::ErrorCode::DatabaseLocked)
                    && start.elapsed() < BUSY_TIMEOUT =>
            {
                std::thread::sleep(Duration::from_millis(10));
            }
            other => return other,
        }
    }
}

#[cfg(test)]
mod tests;
