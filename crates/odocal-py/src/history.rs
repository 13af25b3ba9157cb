//! `odocal.History`: a vehicle's calibration history in an SQLite file
//! ([`odocal_history::History`]), rows as dicts.

use std::path::PathBuf;
use std::sync::Mutex;

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use odocal_history::{CalibrationRecord, History, Recorded};

use crate::convert::{json, to_json, to_py};
use crate::drive::PyDrive;
use crate::lib_err;
use crate::report::report_from_json;

/// A vehicle's calibration history (the file `odocal calibrate --vehicle
/// --db` and `odocal follow` write).
#[pyclass(module = "odocal", name = "History", frozen, subclass)]
pub(crate) struct PyHistory {
    db: Mutex<History>,
}

impl PyHistory {
    fn with<T>(&self, f: impl FnOnce(&mut History) -> odocal::Result<T>) -> PyResult<T> {
        let mut db = crate::lock(&self.db, "history")?;
        f(&mut db).map_err(lib_err)
    }
}

/// The fields of a record (`History.record`'s dict), as the table's
/// columns name them.
fn record_fields() -> PyResult<Vec<String>> {
    let example = CalibrationRecord::new("", "", "", odocal::Theta::PAPER_INITIAL);
    Ok(json(&example)?.as_object().map(|m| m.keys().cloned().collect()).unwrap_or_default())
}

/// A record's `sigma` as the table's `ParamSigma` reads it: a dict of
/// `c_e`, `c_d`, `t_r`, `d` (`None`, or a key left out, for a parameter
/// without σ) or four values; a key other than the four is refused (it
/// would be dropped unnoticed). The values are the library's to check.
fn record_sigma(v: serde_json::Value) -> Result<serde_json::Value, String> {
    use odocal::model::THETA_NAMES;
    use serde_json::Value;
    match v {
        Value::Object(m) => match m.keys().find(|k| !THETA_NAMES.contains(&k.as_str())) {
            Some(k) => Err(format!("sigma: unknown key '{k}': σ has c_e, c_d, t_r and d")),
            None => Ok(Value::Object(m)),
        },
        Value::Array(a) if a.len() == 4 => Ok(THETA_NAMES.iter().map(|n| n.to_string()).zip(a).collect()),
        other => Ok(other),
    }
}

/// A record's outcome as `{"id": …, "new": bool}`.
fn recorded<'py>(py: Python<'py>, r: Recorded) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let (id, new) = match r {
        Recorded::New(id) => (id, true),
        Recorded::AlreadyRecorded(id) => (id, false),
    };
    d.set_item("id", id)?;
    d.set_item("new", new)?;
    Ok(d)
}

#[pymethods]
impl PyHistory {
    /// Opens (creating if need be) the history at `path`, bringing its
    /// schema to this odocal's version. Raises `OdocalError` for a file
    /// that is not an odocal history or was written by a newer odocal.
    #[new]
    fn new(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let db = py.detach(|| History::open(&path)).map_err(lib_err)?;
        Ok(PyHistory { db: Mutex::new(db) })
    }

    /// The database file.
    #[getter]
    fn path(&self) -> PyResult<PathBuf> {
        self.with(|db| Ok(db.path.to_path_buf()))
    }

    /// The schema version of the file.
    #[getter]
    fn schema_version(&self) -> PyResult<i64> {
        self.with(|db| Ok(db.schema_version))
    }

    /// The vehicle's calibrations in recording order, one dict per row
    /// (the columns of the table `calibrations`; `theta` and `sigma` as dicts).
    fn rows<'py>(&self, py: Python<'py>, vehicle: &str) -> PyResult<Bound<'py, PyAny>> {
        let rows = self.with(|db| db.vehicle(vehicle, None))?.rows;
        to_py(py, &json(&rows)?)
    }

    /// The row to start from: the vehicle's most recent row whose verdict
    /// is not `rejected` and names no bias beyond its σ (`input_noise_bias`,
    /// `heading_offset_held`), the row `odocal follow` starts from; or None.
    /// With `usable_only=False`, the most recent row whatever its verdict.
    #[pyo3(signature = (vehicle, *, usable_only=true))]
    fn latest<'py>(&self, py: Python<'py>, vehicle: &str, usable_only: bool) -> PyResult<Bound<'py, PyAny>> {
        let mut rows = self.with(|db| db.vehicle(vehicle, None))?.rows;
        let row = if usable_only { odocal_history::start_row(&rows).cloned() } else { rows.pop() };
        to_py(py, &json(&row)?)
    }

    /// Every parameter change between consecutive rows beyond three
    /// combined σ, each drive counted once by its most recent row (as
    /// `odocal history`): dicts with `parameter`, `from_id`, `from_recorded_at`,
    /// `to_id`, `to_recorded_at`, `change`, `combined_sigma`, `model_sigma_only`
    /// (either row's σ is the model's alone: no evidence of drift by itself).
    fn drift<'py>(&self, py: Python<'py>, vehicle: &str) -> PyResult<Bound<'py, PyAny>> {
        let flags = self.with(|db| db.vehicle(vehicle, None))?.drift;
        to_py(py, &json(&flags)?)
    }

    /// The pooled estimate over the vehicle's rows (those with an id in
    /// `ids`, or all), each drive counted once by its most recent row:
    /// `{"rows", "drives", "set_aside", "rejected", "online", "biased",
    /// "not_measured", "mean", "sigma_of_mean", "between_drive_sd"}`
    /// (`set_aside`: `{"id", "by_id"}` of each row left out for a later row
    /// of its drive; `rejected`: the ids of rows left out for their verdict
    /// `rejected`; `online`: the ids of the online running estimates, not
    /// pooled; `biased`: `{"id", "reasons"}` of each row left out because
    /// its verdict names a bias beyond its σ, `input_noise_bias` or
    /// `heading_offset_held`;
    /// `not_measured`: `{"id", "parameter", "why"}` of each parameter a row
    /// held or found not observable, left out of that parameter's pool; a
    /// parameter no row measured has `None`), or None without a row to pool.
    #[pyo3(signature = (vehicle, ids=None))]
    fn pooled<'py>(&self, py: Python<'py>, vehicle: &str, ids: Option<Vec<i64>>) -> PyResult<Bound<'py, PyAny>> {
        let p = self.with(|db| db.vehicle(vehicle, ids.as_deref()))?.pooled;
        to_py(py, &json(&p)?)
    }

    /// The vehicle's logged write-back decisions (table `decisions`), in order.
    fn decisions<'py>(&self, py: Python<'py>, vehicle: &str) -> PyResult<Bound<'py, PyAny>> {
        let d = self.with(|db| db.vehicle(vehicle, None))?.decisions;
        to_py(py, &json(&d)?)
    }

    /// Records a calibration report's JSON text for `vehicle` (the
    /// drives' fingerprints and files from its `"drives"`, the time span
    /// from `drive`). Use `History.record`.
    #[pyo3(signature = (report_json, vehicle, drive=None))]
    fn _record_report<'py>(
        &self,
        py: Python<'py>,
        report_json: &str,
        vehicle: &str,
        drive: Option<&Bound<'_, PyDrive>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let report = report_from_json(report_json)?;
        let v: serde_json::Value =
            serde_json::from_str(report_json).map_err(|e| PyRuntimeError::new_err(format!("report: {e}")))?;
        let entries: Vec<&serde_json::Value> = v["drives"]
            .as_array()
            .map(|a| a.iter().filter(|e| e["role"] == "calibration").collect())
            .unwrap_or_default();
        let prints: Vec<&str> = entries.iter().filter_map(|e| e["fingerprint"].as_str()).collect();
        let fingerprint = match (prints.is_empty(), drive) {
            (false, _) => prints.join(", "),
            (true, Some(d)) => d.get().drive.fingerprint(),
            (true, None) => {
                return Err(lib_err(odocal::Error::InvalidOption {
                    field: "report",
                    reason: "names no calibration drive's fingerprint; give the drive".into(),
                }))
            }
        };
        let sources = entries.iter().filter_map(|e| e["path"].as_str().map(String::from)).collect();
        let span = drive.map_or((0.0, 0.0), |d| {
            let t = d.get().drive.t();
            (t.first().copied().unwrap_or(0.0), t.last().copied().unwrap_or(0.0))
        });
        let mut rec = CalibrationRecord::of_report(vehicle, &fingerprint, sources, span, &report);
        // The files' digests (`History.record`'s docs), when every drive was read from a file that is there.
        rec.source_digest = odocal_history::source_digests(&rec.sources);
        let r = self.with(|db| db.record(&rec))?;
        recorded(py, r)
    }

    /// Records a row given as a dict of the table's fields (`vehicle`,
    /// `fingerprint`, `method`, `theta`; optional `sigma`, `held`,
    /// `unobservable`, `sources`, `source_digest`, `t_start_s`, `t_end_s`,
    /// `heading_offset_rad`, `verdict`, `sigma_model_only`, `reasons`;
    /// another key is refused). Use `History.record`.
    fn _record_dict<'py>(&self, py: Python<'py>, record: &Bound<'_, PyDict>) -> PyResult<Bound<'py, PyDict>> {
        let mut v = to_json(record.as_any(), "record")?;
        let invalid = |reason: String| lib_err(odocal::Error::InvalidOption { field: "record", reason });
        if let Some(m) = v.as_object_mut() {
            // The table's fields only: a misspelt optional one (`sigmaa`) would be dropped unnoticed.
            let known = record_fields()?;
            if let Some(k) = m.keys().find(|k| !known.contains(k)) {
                return Err(invalid(format!("unknown key '{k}'; a record has {}", known.join(", "))));
            }
            // θ read as every θ argument (a dict of the four, or four numbers; no other key).
            if let Some(t) = m.get_mut("theta") {
                *t = json(&odocal::Theta::try_from(t.take()).map_err(lib_err)?)?;
            }
            if let Some(s) = m.get_mut("sigma") {
                *s = record_sigma(s.take()).map_err(invalid)?;
            }
            let defaults = [("sources", serde_json::json!([])), ("t_start_s", 0.0.into()), ("t_end_s", 0.0.into())];
            for (k, d) in defaults {
                m.entry(k).or_insert(d);
            }
            for k in ["sigma", "heading_offset_rad", "verdict"] {
                m.entry(k).or_insert(serde_json::Value::Null);
            }
        }
        let rec: CalibrationRecord = serde_json::from_value(v)
            .map_err(|e| lib_err(odocal::Error::InvalidOption { field: "record", reason: e.to_string() }))?;
        let r = self.with(|db| db.record(&rec))?;
        recorded(py, r)
    }

    fn __repr__(&self) -> PyResult<String> {
        self.with(|db| Ok(format!("<odocal.History {}>", db.path.display())))
    }
}
