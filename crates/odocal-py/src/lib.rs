//! Python bindings of odocal: the native module `odocal._odocal`, wrapped
//! by the pure-Python package in `python/odocal` (`import odocal`).
//!
//! The bindings are a thin layer over the library, like the CLI:
//! - every drive made from arrays goes through [`odocal::drive::DriveBuilder::build`],
//!   and every library error becomes `odocal.OdocalError` (a `ValueError`)
//!   with the library's message;
//! - keyword options are turned into [`CalibrationOptions`] in one place,
//!   [`calibration_plan`], named like the CLI's flags;
//! - reports leave as JSON ([`serde_json::Value`] → Python objects, and the
//!   CLI's pretty text), so `report.to_dict()` equals `odocal calibrate
//!   --json` (timing aside) without mirroring the report types here;
//! - numeric work runs with the GIL released ([`Python::detach`]); the
//!   progress callback is called only on the calling thread, with the GIL.

use std::ops::Range;
use std::path::PathBuf;
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use numpy::{AllowTypeChange, IntoPyArray, PyArray1, PyArray2, PyArrayLike1};
use pyo3::exceptions::{PyKeyError, PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict, PyList, PyString};

use odocal::calibrate::settings::{GivenSettings, ManifestSettings, SettingUse};
use odocal::calibrate::CorrectBias;
use odocal::compensate::qp::SolverKind;
use odocal::drive::{Drive, ExtraColumn, ExtraValues, Signals};
use odocal::eiv::{HeadingScale, QuantisationLevel, QuantisationModel};
use odocal::io::import::{NoiseTable, ReferenceSpec};
use odocal::model::param::{Param, ParamSet};
use odocal::model::Theta;
use odocal::sim::{NoiseOptions, SimOptions, SimSidecar};
use odocal::{CalibrationOptions, FinalSegments, Holdout, Method, Progress};

#[allow(unsafe_code)] // pyo3's exception boilerplate implements an unsafe trait
mod exception {
    pyo3::create_exception!(
        odocal,
        OdocalError,
        pyo3::exceptions::PyValueError,
        "An error of the odocal library (bad data, a bad option, a calibration that cannot run); the message is \
         the library's."
    );
}
use exception::OdocalError;

/// A library error as `odocal.OdocalError` with the library's message.
fn lib_err(e: odocal::Error) -> PyErr {
    OdocalError::new_err(e.to_string())
}

/// Names of the drive columns `Drive.to_numpy()` returns, in order.
const COLUMNS: [&str; 8] = ["t", "px", "py", "psi", "n_rl", "n_rr", "beta", "a_y"];

/// Where a drive came from, beyond its samples: the simulator's sidecar
/// (true θ) and a manifest import's report. The CLI uses the same facts.
#[derive(Debug, Clone, Default)]
struct Provenance {
    /// The simulator sidecar (as for `drive.json` beside a CSV).
    sidecar: Option<SimSidecar>,
    /// The import report of a manifest, as JSON text.
    import_report: Option<String>,
    /// What one model revolution is (manifest imports).
    wheel_scale: Option<String>,
}

impl Provenance {
    /// The manifest's calibration settings (`[noise]`, `[reference]`, `[calibration]`), read
    /// back from the import report (so they survive pickling with it).
    fn settings(&self) -> PyResult<Option<ManifestSettings>> {
        let Some(text) = &self.import_report else { return Ok(None) };
        let bad = |e: serde_json::Error| PyRuntimeError::new_err(format!("import report: {e}"));
        let v: serde_json::Value = serde_json::from_str(text).map_err(bad)?;
        let field = |k: &str| v.get(k).filter(|x| !x.is_null()).cloned();
        let noise: Option<NoiseTable> = field("noise").map(serde_json::from_value).transpose().map_err(bad)?;
        let settings = ManifestSettings::new(
            field("manifest").map(serde_json::from_value).transpose().map_err(bad)?.unwrap_or_default(),
            noise.as_ref(),
            field("reference").map(serde_json::from_value).transpose().map_err(bad)?,
            field("calibration").map(serde_json::from_value).transpose().map_err(bad)?,
        )
        .map_err(lib_err)?;
        Ok(Some(settings))
    }
}

/// One drive, or several of one vehicle joined with `Drive::concat`
/// (segments and parts never span two): the argument `drive` of
/// `calibrate` and `validate_on`. Returns the drive and each one's provenance.
fn drives_arg(v: &Bound<'_, PyAny>, what: &str) -> PyResult<(Arc<Drive>, Vec<Provenance>)> {
    if let Ok(d) = v.cast::<PyDrive>() {
        let d = d.get();
        return Ok((Arc::clone(&d.drive), vec![d.prov.clone()]));
    }
    let not_drives = || PyTypeError::new_err(format!("{what}: give an odocal.Drive or a list of them"));
    if v.cast::<PyString>().is_ok() {
        return Err(not_drives());
    }
    let items: Vec<Bound<'_, PyAny>> = v.try_iter().map_err(|_| not_drives())?.collect::<PyResult<_>>()?;
    let mut drives = Vec::with_capacity(items.len());
    for item in &items {
        drives.push(item.cast::<PyDrive>().map_err(|_| not_drives())?.get());
    }
    match drives.as_slice() {
        [] => Err(lib_err(odocal::Error::InvalidOption { field: "drive", reason: format!("{what}: no drives given") })),
        [one] => Ok((Arc::clone(&one.drive), vec![one.prov.clone()])),
        many => {
            let refs: Vec<&Drive> = many.iter().map(|d| d.drive.as_ref()).collect();
            let joined = Drive::concat(&refs).map_err(lib_err)?;
            Ok((Arc::new(joined), many.iter().map(|d| d.prov.clone()).collect()))
        }
    }
}

/// A drive: one uniformly sampled time series of reference poses and model
/// inputs, checked by the library's constructor.
#[pyclass(module = "odocal", name = "Drive", frozen)]
struct PyDrive {
    drive: Arc<Drive>,
    prov: Provenance,
}

impl PyDrive {
    fn new(drive: Drive, prov: Provenance) -> Self {
        PyDrive { drive: Arc::new(drive), prov }
    }
}

fn vec_f64(a: &PyArrayLike1<'_, f64, AllowTypeChange>) -> Vec<f64> {
    a.as_array().to_vec()
}

fn f64_bytes(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn f64_from_bytes(b: &[u8], what: &str) -> PyResult<Vec<f64>> {
    if !b.len().is_multiple_of(8) {
        return Err(PyValueError::new_err(format!("drive state: {what} is not a whole number of f64")));
    }
    Ok(b.chunks_exact(8)
        .map(|c| {
            let mut a = [0u8; 8];
            a.copy_from_slice(c);
            f64::from_le_bytes(a)
        })
        .collect())
}

fn signals_state(s: &Signals) -> Vec<Vec<u8>> {
    s.columns().iter().map(|(_, c)| f64_bytes(c)).collect()
}

fn signals_from_state(cols: Vec<Vec<u8>>) -> PyResult<Signals> {
    if cols.len() != 7 {
        return Err(PyValueError::new_err("drive state: expected 7 signal columns"));
    }
    let mut it = cols.into_iter().map(|b| f64_from_bytes(&b, "a signal column"));
    let mut next = || it.next().unwrap_or_else(|| Ok(Vec::new()));
    Ok(Signals { px: next()?, py: next()?, psi: next()?, n_rl: next()?, n_rr: next()?, beta: next()?, a_y: next()? })
}

/// A drive's loader for a CSV: the drive, and the simulator sidecar beside
/// it when there is one (as the CLI's `calibrate` reads it).
fn read_csv_with_sidecar(path: &std::path::Path) -> odocal::Result<(Drive, Provenance)> {
    let drive = Drive::read_csv(path)?;
    let side = odocal::sim::sidecar_path(path);
    let sidecar = if side.exists() { SimSidecar::read_json(&side).ok() } else { None };
    Ok((drive, Provenance { sidecar, ..Default::default() }))
}

fn read_manifest(path: &std::path::Path) -> odocal::Result<(Drive, Provenance)> {
    let m = odocal::Manifest::from_path(path)?;
    // The calibration settings are checked too, so a bad one is named now.
    ManifestSettings::of_manifest(&m)?;
    let imported = odocal::import(&m)?;
    let import_report = serde_json::to_string_pretty(&odocal::calibrate::settings::import_report_json(
        &imported.report,
    )?)
    .map_err(|source| odocal::Error::Json { context: format!("import report of {}", path.display()), source })?;
    let wheel_scale = Some(imported.report.wheel_scale.clone());
    Ok((imported.drive, Provenance { sidecar: None, import_report: Some(import_report), wheel_scale }))
}

#[pymethods]
impl PyDrive {
    /// Makes a drive from 1-D arrays (anything numpy converts to float64),
    /// checked by the library: equal lengths, finite values, strictly
    /// increasing and uniform time (within 1 % per part). `beta` defaults to
    /// zeros; `part` holds per-sample integer ids (a new part starts where
    /// the id changes); `sample_time_s` is the nominal step when known.
    ///
    /// Raises `OdocalError` naming the column and the sample.
    #[staticmethod]
    #[pyo3(signature = (t, px, py, psi, n_rl, n_rr, a_y, beta=None, part=None, sample_time_s=None))]
    #[allow(clippy::too_many_arguments)]
    fn from_arrays(
        gil: Python<'_>,
        t: PyArrayLike1<'_, f64, AllowTypeChange>,
        px: PyArrayLike1<'_, f64, AllowTypeChange>,
        py: PyArrayLike1<'_, f64, AllowTypeChange>,
        psi: PyArrayLike1<'_, f64, AllowTypeChange>,
        n_rl: PyArrayLike1<'_, f64, AllowTypeChange>,
        n_rr: PyArrayLike1<'_, f64, AllowTypeChange>,
        a_y: PyArrayLike1<'_, f64, AllowTypeChange>,
        beta: Option<PyArrayLike1<'_, f64, AllowTypeChange>>,
        part: Option<PyArrayLike1<'_, i64, AllowTypeChange>>,
        sample_time_s: Option<f64>,
    ) -> PyResult<Self> {
        let t = vec_f64(&t);
        let beta = match beta {
            Some(b) => vec_f64(&b),
            None => vec![0.0; t.len()],
        };
        let signals = Signals {
            px: vec_f64(&px),
            py: vec_f64(&py),
            psi: vec_f64(&psi),
            n_rl: vec_f64(&n_rl),
            n_rr: vec_f64(&n_rr),
            beta,
            a_y: vec_f64(&a_y),
        };
        let part = part.map(|p| p.as_array().to_vec());
        let drive = gil
            .detach(move || {
                let mut b = Drive::builder(t, signals).context("numpy arrays");
                if let Some(ids) = part {
                    b = b.part_ids(ids);
                }
                if let Some(ts) = sample_time_s {
                    b = b.sample_time_s(ts);
                }
                b.build()
            })
            .map_err(lib_err)?;
        Ok(PyDrive::new(drive, Provenance::default()))
    }

    /// Reads a canonical CSV (SPEC §2). A simulator sidecar beside it
    /// (`drive.json` for `drive.csv`) gives the true θ, as in the CLI.
    #[staticmethod]
    fn from_csv(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (drive, prov) = py.detach(|| read_csv_with_sidecar(&path)).map_err(lib_err)?;
        Ok(PyDrive::new(drive, prov))
    }

    /// Imports a multi-stream log described by a drive manifest (`.toml`).
    #[staticmethod]
    fn from_manifest(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let (drive, prov) = py.detach(|| read_manifest(&path)).map_err(lib_err)?;
        Ok(PyDrive::new(drive, prov))
    }

    /// Reads a canonical CSV or, for a `.toml` path, imports a manifest
    /// (what the CLI's `calibrate DRIVE` accepts).
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let is_toml = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("toml"));
        if is_toml {
            Self::from_manifest(py, path)
        } else {
            Self::from_csv(py, path)
        }
    }

    /// Names of the columns of `to_numpy()`, in order.
    #[getter]
    fn columns(&self) -> Vec<&'static str> {
        COLUMNS.to_vec()
    }

    /// The measured columns as a float64 array of shape (samples, 8), in
    /// `columns` order (the heading `psi` is unwrapped).
    fn to_numpy<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let d = &self.drive;
        let cols: [&[f64]; 8] = [d.t(), d.px(), d.py(), d.psi(), d.n_rl(), d.n_rr(), d.beta(), d.a_y()];
        let n = d.len();
        let mut flat = Vec::with_capacity(n * cols.len());
        for i in 0..n {
            flat.extend(cols.iter().map(|c| c[i]));
        }
        // The shape matches the data by construction.
        numpy::ndarray::Array2::from_shape_vec((n, cols.len()), flat)
            .map(|a| a.into_pyarray(py))
            .unwrap_or_else(|_| PyArray2::zeros(py, (0, cols.len()), false))
    }

    /// One column as a float64 array: a name of `columns`, a truth column
    /// (`px_true`, …, simulated drives) or a numeric extra column.
    fn column<'py>(&self, py: Python<'py>, name: &str) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let d = &self.drive;
        if name == "t" {
            return Ok(PyArray1::from_slice(py, d.t()));
        }
        if let Some((_, c)) = d.measured().columns().into_iter().find(|(n, _)| *n == name) {
            return Ok(PyArray1::from_slice(py, c));
        }
        if let (Some(base), Some(truth)) = (name.strip_suffix("_true"), d.truth()) {
            if let Some((_, c)) = truth.columns().into_iter().find(|(n, _)| *n == base) {
                return Ok(PyArray1::from_slice(py, c));
            }
        }
        if let Some(c) = d.extra_column(name).and_then(|c| c.as_numbers()) {
            return Ok(PyArray1::from_slice(py, c));
        }
        Err(PyKeyError::new_err(format!("the drive has no numeric column '{name}'")))
    }

    /// Per-sample part index (0, 1, …) as an int64 array.
    fn part_ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i64>> {
        let mut ids = vec![0i64; self.drive.len()];
        for (p, r) in self.drive.parts().iter().enumerate() {
            ids[r.clone()].fill(p as i64);
        }
        ids.into_pyarray(py)
    }

    /// Continuous parts as `(start, stop)` sample index pairs.
    #[getter]
    fn parts(&self) -> Vec<(usize, usize)> {
        self.drive.parts().iter().map(|r| (r.start, r.end)).collect()
    }

    /// Sample time t_s, s.
    #[getter]
    fn sample_time_s(&self) -> f64 {
        self.drive.sample_time_s()
    }

    /// Reference path length, m.
    #[getter]
    fn distance_m(&self) -> f64 {
        self.drive.distance_m()
    }

    /// The true θ of a simulated drive (`{"c_e": …, "c_d": …, "t_r": …, "d": …}`), else None.
    #[getter]
    fn theta_true<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.prov.sidecar.as_ref().map(|s| to_py(py, &json(&s.theta_true)?)).transpose()
    }

    /// The simulator sidecar (true θ, settings, statistics) of a simulated
    /// drive as a dict, else None.
    #[getter]
    fn simulation<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        self.prov.sidecar.as_ref().map(|s| to_py(py, &json(s)?)).transpose()
    }

    /// The import report of a drive read from a manifest, as a dict, else None.
    #[getter]
    fn import_report<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        match &self.prov.import_report {
            None => Ok(None),
            Some(text) => {
                let v: serde_json::Value =
                    serde_json::from_str(text).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
                Ok(Some(to_py(py, &v)?))
            }
        }
    }

    /// Writes the canonical CSV; for a simulated drive also the sidecar
    /// (`drive.json` beside `drive.csv`), as `odocal simulate` does.
    fn to_csv(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let drive = Arc::clone(&self.drive);
        let sidecar = self.prov.sidecar.clone();
        py.detach(move || {
            drive.write_csv(&path)?;
            if let Some(s) = sidecar {
                s.write_json(&odocal::sim::sidecar_path(&path))?;
            }
            Ok(())
        })
        .map_err(lib_err)
    }

    fn __len__(&self) -> usize {
        self.drive.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "<odocal.Drive: {} samples in {} part(s), t_s {} s, {:.2} km{}>",
            self.drive.len(),
            self.drive.parts().len(),
            self.drive.sample_time_s(),
            self.drive.distance_m() / 1e3,
            if self.prov.sidecar.is_some() { ", simulated" } else { "" }
        )
    }

    /// Pickling (Ray and multiprocessing send drives this way): the exact
    /// columns, parts and sample time, rebuilt through the checked constructor.
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyDict>,))> {
        let d = &self.drive;
        let state = PyDict::new(py);
        state.set_item("t", PyBytes::new(py, &f64_bytes(d.t())))?;
        let bytes_list = |cols: Vec<Vec<u8>>| -> PyResult<Bound<'py, PyList>> {
            PyList::new(py, cols.iter().map(|b| PyBytes::new(py, b)))
        };
        state.set_item("measured", bytes_list(signals_state(d.measured()))?)?;
        state.set_item("truth", d.truth().map(|t| bytes_list(signals_state(t))).transpose()?)?;
        state.set_item("parts", self.parts())?;
        state.set_item("ref_measured", d.reference_measured().map(|m| m.to_vec()))?;
        let extra = PyList::empty(py);
        for c in d.extra() {
            let values: Bound<'py, PyAny> = match &c.values {
                ExtraValues::Numbers(v) => PyBytes::new(py, &f64_bytes(v)).into_any(),
                ExtraValues::Text(v) => PyList::new(py, v)?.into_any(),
            };
            extra.append((c.name.as_str(), values))?;
        }
        state.set_item("extra", extra)?;
        state.set_item("sample_time_s", d.sample_time_s())?;
        let sidecar = self.prov.sidecar.as_ref().map(json).transpose()?.map(|v| v.to_string());
        state.set_item("sidecar", sidecar)?;
        state.set_item("import_report", self.prov.import_report.as_deref())?;
        state.set_item("wheel_scale", self.prov.wheel_scale.as_deref())?;
        let ctor = py.import("odocal._odocal")?.getattr("_drive_from_state")?;
        Ok((ctor, (state,)))
    }
}

/// Rebuilds a pickled drive (see `Drive.__reduce__`).
#[pyfunction]
fn _drive_from_state(py: Python<'_>, state: &Bound<'_, PyDict>) -> PyResult<PyDrive> {
    let get = |k: &str| -> PyResult<Bound<'_, PyAny>> {
        state.get_item(k)?.ok_or_else(|| PyValueError::new_err(format!("drive state: no '{k}'")))
    };
    let t = f64_from_bytes(&get("t")?.extract::<Vec<u8>>()?, "t")?;
    let measured = signals_from_state(get("measured")?.extract()?)?;
    let truth = get("truth")?.extract::<Option<Vec<Vec<u8>>>>()?.map(signals_from_state).transpose()?;
    let parts: Vec<Range<usize>> =
        get("parts")?.extract::<Vec<(usize, usize)>>()?.into_iter().map(|(a, b)| a..b).collect();
    let ref_measured: Option<Vec<bool>> = get("ref_measured")?.extract()?;
    let mut extra = Vec::new();
    for item in get("extra")?.cast::<PyList>()?.iter() {
        let (name, values): (String, Bound<'_, PyAny>) = item.extract()?;
        let values = if let Ok(b) = values.cast::<PyBytes>() {
            ExtraValues::Numbers(f64_from_bytes(b.as_bytes(), "an extra column")?)
        } else {
            ExtraValues::Text(values.extract()?)
        };
        extra.push(ExtraColumn { name, values });
    }
    let ts: f64 = get("sample_time_s")?.extract()?;
    let sidecar = match get("sidecar")?.extract::<Option<String>>()? {
        Some(s) => Some(serde_json::from_str(&s).map_err(|e| PyValueError::new_err(format!("drive state: {e}")))?),
        None => None,
    };
    let prov = Provenance {
        sidecar,
        import_report: get("import_report")?.extract()?,
        wheel_scale: get("wheel_scale")?.extract()?,
    };
    let drive = py
        .detach(move || {
            let mut b = Drive::builder(t, measured).context("pickled drive").parts(parts).sample_time_s(ts);
            if let Some(tr) = truth {
                b = b.truth(tr);
            }
            if let Some(m) = ref_measured {
                b = b.reference_measured(m);
            }
            for c in extra {
                b = b.extra(c);
            }
            b.build()
        })
        .map_err(lib_err)?;
    Ok(PyDrive::new(drive, prov))
}

// ---------------------------------------------------------------------------
// JSON → Python objects.

fn json<T: serde::Serialize>(v: &T) -> PyResult<serde_json::Value> {
    serde_json::to_value(v).map_err(|e| PyRuntimeError::new_err(format!("serialising a report: {e}")))
}

/// A JSON value as plain Python objects (dict, list, str, int, float, bool,
/// None), the same as `json.loads` of its text.
fn to_py<'py>(py: Python<'py>, v: &serde_json::Value) -> PyResult<Bound<'py, PyAny>> {
    use serde_json::Value;
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
        Value::Number(n) => {
            if let Some(i) = n.as_i64() {
                i.into_pyobject(py)?.into_any()
            } else if let Some(u) = n.as_u64() {
                u.into_pyobject(py)?.into_any()
            } else {
                n.as_f64().unwrap_or(f64::NAN).into_pyobject(py)?.into_any()
            }
        }
        Value::String(s) => PyString::new(py, s).into_any(),
        Value::Array(a) => PyList::new(py, a.iter().map(|x| to_py(py, x)).collect::<PyResult<Vec<_>>>()?)?.into_any(),
        Value::Object(m) => {
            let d = PyDict::new(py);
            for (k, x) in m {
                d.set_item(k, to_py(py, x)?)?;
            }
            d.into_any()
        }
    })
}

// ---------------------------------------------------------------------------
// Options: the one place that maps Python keyword arguments to library options.

/// What to run: the library options plus the CLI's run settings.
struct CalibrationPlan {
    opts: CalibrationOptions,
    /// The CLI's `--holdout` or `--validate-on`.
    holdout: Option<Holdout>,
    /// The `validate_on` drives one by one (several: Ē_p per drive too),
    /// each with its manifest's `[reference]`.
    validate_on: Vec<(Arc<Drive>, Option<ReferenceSpec>)>,
    /// The extrinsic parameters the keywords give (`lever_arm`,
    /// `heading_offset`): they apply to every validation drive.
    given_extrinsics: ParamSet,
    /// What became of the manifest's settings.
    setting_uses: Vec<SettingUse>,
    /// Which starting noise model method eiv uses.
    noise_model_origin: Option<String>,
}

/// The keyword options of `odocal.calibrate`, named like the CLI's flags.
const CALIBRATION_KWARGS: [&str; 31] = [
    "seed",
    "estimate",
    "lever_arm",
    "heading_offset",
    "noise_model",
    "known_noise",
    "fix_noise",
    "fallback",
    "eiv_window",
    "quantisation",
    "quantisation_level",
    "lateral_noise",
    "heading_noise",
    "correct_bias",
    "bootstrap_seed",
    "qp_solver",
    "theta0",
    "fix",
    "min_yaw_rate",
    "keep_one_way",
    "segment_length",
    "segment_stride",
    "validation_length",
    "batches",
    "batch_size",
    "picks",
    "final_segments",
    "max_iterations",
    "holdout",
    "validate_on",
    "auto_fix",
];

fn invalid_option(field: &'static str, reason: String) -> PyErr {
    lib_err(odocal::Error::InvalidOption { field, reason })
}

fn parse_holdout(s: &str) -> PyResult<Holdout> {
    match s {
        "first-half" | "first_half" => Ok(Holdout::FirstHalf),
        "second-half" | "second_half" => Ok(Holdout::SecondHalf),
        s => Err(invalid_option("holdout", format!("'{s}': use first-half or second-half (the half held out)"))),
    }
}

/// The parameter file a θ argument names: a text ending in `.yaml`, `.yml`
/// or `.json` (the Python layer turns path objects into text), read by the
/// library; `None` for any other argument.
fn params_file_arg(v: &Bound<'_, PyAny>) -> PyResult<Option<odocal::io::param_file::ParamFile>> {
    let Ok(s) = v.cast::<PyString>() else { return Ok(None) };
    let path = std::path::Path::new(s.to_str()?);
    if odocal::io::param_file::is_param_file(path) {
        return odocal::io::param_file::ParamFile::read(path).map(Some).map_err(lib_err);
    }
    Ok(None)
}

/// θ from a dict `{"c_e", "c_d", "t_r", "d"}`, a sequence of four numbers,
/// the CLI's text `"c_e,c_d,t_r,d"` or the path of a parameter file
/// (`--params-out`'s); checked by the library.
fn extract_theta(v: &Bound<'_, PyAny>) -> PyResult<Theta> {
    if let Some(f) = params_file_arg(v)? {
        return f.theta().map_err(lib_err);
    }
    let theta = if let Ok(s) = v.cast::<PyString>() {
        s.to_str()?.parse::<Theta>().map_err(lib_err)?
    } else if let Ok(d) = v.cast::<PyDict>() {
        let mut a = [0.0; 4];
        for (i, name) in odocal::model::THETA_NAMES.iter().enumerate() {
            a[i] = d
                .get_item(name)?
                .ok_or_else(|| PyKeyError::new_err(format!("θ: missing '{name}' (give c_e, c_d, t_r, d)")))?
                .extract()?;
        }
        Theta { c_e: a[0], c_d: a[1], t_r: a[2], d: a[3] }
    } else {
        let a: Vec<f64> = v.extract().map_err(|_| {
            PyTypeError::new_err("θ: give a dict {c_e, c_d, t_r, d}, four numbers or the text 'c_e,c_d,t_r,d'")
        })?;
        if a.len() != 4 {
            return Err(lib_err(odocal::Error::InvalidTheta(format!(
                "expected 4 values c_e, c_d, t_r, d, got {}",
                a.len()
            ))));
        }
        Theta { c_e: a[0], c_d: a[1], t_r: a[2], d: a[3] }
    };
    theta.validate().map_err(lib_err)?;
    Ok(theta)
}

/// Builds the calibration from `method` and the keyword options, exactly as
/// the CLI's `calibrate` flags do (`--min-yaw-rate` is `min_yaw_rate=`, …):
/// the three-step options (`batches`, `batch_size`, `picks`,
/// `final_segments`, `qp_solver`) go into [`Method::ThreeStep`] and are an
/// error with another method. Unknown keywords raise `TypeError`; invalid
/// values `OdocalError`.
///
/// This is the only function that knows the shape of [`CalibrationOptions`].
fn calibration_plan(
    method: &str,
    kwargs: Option<&Bound<'_, PyDict>>,
    manifest: Option<&ManifestSettings>,
) -> PyResult<CalibrationPlan> {
    let mut o = CalibrationOptions { method: method.parse::<Method>().map_err(lib_err)?, ..Default::default() };
    // The manifest's settings first, where no keyword gives its own value.
    let given_kw = |k: &str| -> PyResult<bool> {
        Ok(match kwargs {
            Some(kw) => kw.get_item(k)?.is_some_and(|v| !v.is_none()),
            None => false,
        })
    };
    let given = GivenSettings {
        noise_model: given_kw("noise_model")?,
        lever_arm: given_kw("lever_arm")?,
        heading_offset: given_kw("heading_offset")?,
        estimate: given_kw("estimate")?,
        keep_one_way: given_kw("keep_one_way")?,
        lateral_noise: given_kw("lateral_noise")?,
    };
    let setting_uses = manifest.map(|m| m.apply(&mut o, given)).unwrap_or_default();
    let mut noise_model_file: Option<PathBuf> = None;
    let mut fix = ParamSet::EMPTY;
    let mut holdout = None;
    let mut validate_on = None;
    let mut validate_on_drives = Vec::new();
    // Three-step settings, applied to the method below.
    let (mut batches, mut batch_size, mut picks, mut final_segments, mut qp_solver) = (None, None, None, None, None);
    // EIV settings (`--noise-model`, `--fix-noise`, `--no-fallback`, `--eiv-window`).
    let (mut noise_model, mut fix_noise, mut fallback, mut eiv_window) = (None, None, None, None);
    let mut known_noise: Option<Vec<odocal::eiv::NoiseSource>> = None;
    let (mut quantisation, mut quantisation_level, mut heading_noise) = (None, None, None);
    let mut lateral_noise = None;
    let (mut correct_bias, mut bootstrap_seed) = (None, None);
    if let Some(kwargs) = kwargs {
        for (key, v) in kwargs.iter() {
            let key: String = key.extract()?;
            if v.is_none() {
                continue; // None means "the default", as an absent flag.
            }
            match key.as_str() {
                "seed" => o.seed = v.extract()?,
                "qp_solver" => qp_solver = Some(v.extract::<String>()?.parse::<SolverKind>().map_err(lib_err)?),
                "theta0" => o.theta0 = extract_theta(&v)?,
                "fix" => fix = param_set_arg(&v)?,
                "estimate" => {
                    let e = param_set_arg(&v)?;
                    let theta = e.intersection(ParamSet::THETA);
                    if !theta.is_empty() {
                        return Err(invalid_option(
                            "estimate",
                            format!(
                                "takes lever-arm, heading-offset (or lever_x, lever_y, heading_offset), not \
                                 {theta}: θ is estimated by default (hold parameters with fix=)"
                            ),
                        ));
                    }
                    o.identify.free = o.identify.free.difference(ParamSet::EXTRINSICS).union(e);
                }
                "lever_arm" => {
                    let l: Vec<f64> =
                        v.extract().map_err(|_| PyTypeError::new_err("lever_arm: give [x, y] in metres"))?;
                    let [x, y] = l[..] else {
                        return Err(invalid_option(
                            "lever_arm",
                            format!("give [x, y] in metres, got {} values", l.len()),
                        ));
                    };
                    (o.identify.extrinsics.lever_x, o.identify.extrinsics.lever_y) = (x, y);
                }
                "heading_offset" => {
                    o.identify.extrinsics.heading_offset = v.extract()?;
                    o.hold_stated_heading_offset();
                }
                "min_yaw_rate" => o.segments.min_peak_yaw_rate_rad_per_s = v.extract()?,
                "keep_one_way" => o.keep_one_way_selection = v.extract()?,
                "segment_length" => o.segments.length_steps = v.extract()?,
                "segment_stride" => o.segments.stride_steps = v.extract()?,
                "validation_length" => {
                    let k: usize = v.extract()?;
                    o.validation.length_steps = k;
                    o.validation.stride_steps = (k / 2).max(1);
                }
                "batches" => batches = Some(v.extract::<usize>()?),
                "batch_size" => batch_size = Some(v.extract::<usize>()?),
                "picks" => picks = Some(v.extract::<usize>()?),
                "final_segments" => {
                    final_segments = Some(match v.extract::<String>() {
                        Ok(s) => s.parse::<FinalSegments>().map_err(lib_err)?,
                        Err(_) => FinalSegments::Random(v.extract()?),
                    })
                }
                "max_iterations" => o.identify.max_iterations = v.extract()?,
                "holdout" => holdout = Some(parse_holdout(&v.extract::<String>()?)?),
                "validate_on" => {
                    let (joined, provs) = drives_arg(&v, "validate_on")?;
                    let drives: Vec<Arc<Drive>> = match v.cast::<PyDrive>() {
                        Ok(_) => vec![Arc::clone(&joined)],
                        Err(_) => v
                            .try_iter()?
                            .map(|d| Ok(Arc::clone(&d?.cast::<PyDrive>()?.get().drive)))
                            .collect::<PyResult<_>>()?,
                    };
                    let references = provs
                        .iter()
                        .map(|p| Ok(p.settings()?.and_then(|s| s.reference)))
                        .collect::<PyResult<Vec<_>>>()?;
                    validate_on_drives = drives.into_iter().zip(references).collect();
                    validate_on = Some(Holdout::Other(Drive::clone(&joined)));
                }
                "auto_fix" => o.auto_fix = v.extract()?,
                "noise_model" => {
                    let path: std::path::PathBuf = v.extract()?;
                    noise_model = Some(odocal::calibrate::eiv::read_noise_model(&path).map_err(lib_err)?);
                    noise_model_file = Some(path);
                }
                "known_noise" => {
                    let names: Vec<String> = match v.cast::<PyString>() {
                        Ok(s) => s.to_str()?.split(',').map(str::to_string).collect(),
                        Err(_) => v.extract::<Vec<String>>()?,
                    };
                    known_noise = Some(
                        names
                            .iter()
                            .map(|n| n.parse::<odocal::eiv::NoiseSource>())
                            .collect::<Result<_, _>>()
                            .map_err(lib_err)?,
                    );
                }
                "fix_noise" => fix_noise = Some(v.extract::<bool>()?),
                "fallback" => fallback = Some(v.extract::<bool>()?),
                "eiv_window" => eiv_window = Some(v.extract::<usize>()?),
                "quantisation" => {
                    quantisation = Some(v.extract::<String>()?.parse::<QuantisationModel>().map_err(lib_err)?)
                }
                "quantisation_level" => {
                    quantisation_level = Some(v.extract::<String>()?.parse::<QuantisationLevel>().map_err(lib_err)?)
                }
                "heading_noise" => {
                    heading_noise = Some(v.extract::<String>()?.parse::<HeadingScale>().map_err(lib_err)?)
                }
                "lateral_noise" => {
                    lateral_noise = Some(v.extract::<String>()?.parse::<odocal::eiv::LateralNoise>().map_err(lib_err)?)
                }
                "correct_bias" => correct_bias = Some(v.extract::<usize>()?),
                "bootstrap_seed" => bootstrap_seed = Some(v.extract::<u64>()?),
                _ => {
                    return Err(PyTypeError::new_err(format!(
                        "calibrate() got an unknown option '{key}'; options: {}",
                        CALIBRATION_KWARGS.join(", ")
                    )))
                }
            }
        }
    }
    let eiv_given: Vec<&str> = [
        ("noise_model", noise_model.is_some()),
        ("known_noise", known_noise.is_some()),
        ("fix_noise", fix_noise.is_some()),
        ("fallback", fallback.is_some()),
        ("eiv_window", eiv_window.is_some()),
        ("quantisation", quantisation.is_some()),
        ("quantisation_level", quantisation_level.is_some()),
        ("lateral_noise", lateral_noise.is_some()),
        ("heading_noise", heading_noise.is_some()),
        ("correct_bias", correct_bias.is_some()),
        ("bootstrap_seed", bootstrap_seed.is_some()),
    ]
    .iter()
    .filter(|g| g.1)
    .map(|g| g.0)
    .collect();
    if let Method::Eiv(e) = &mut o.method {
        if let Some(spec) = &noise_model {
            spec.apply(&mut e.filter);
        }
        e.filter.hold_known(known_noise.as_deref().unwrap_or_default());
        e.filter.fix_noise = fix_noise.unwrap_or(e.filter.fix_noise);
        e.fallback = fallback.unwrap_or(e.fallback);
        e.filter.window_samples = eiv_window.unwrap_or(e.filter.window_samples);
        e.filter.quantisation = quantisation.unwrap_or(e.filter.quantisation);
        e.filter.quantisation_level = quantisation_level.unwrap_or(e.filter.quantisation_level);
        e.filter.heading_scale = heading_noise.unwrap_or(e.filter.heading_scale);
        e.filter.lateral_noise = lateral_noise.unwrap_or(e.filter.lateral_noise);
        // The bias correction is on by default (B = 4); correct_bias=B sets
        // B (even), correct_bias=0 turns it off, bootstrap_seed seeds it.
        match (correct_bias, bootstrap_seed) {
            (Some(0), Some(_)) => {
                return Err(invalid_option(
                    "bootstrap_seed",
                    "is the seed of the bias correction, which correct_bias=0 turns off".into(),
                ))
            }
            (Some(0), None) => e.correct_bias = None,
            (Some(b), _) if !b.is_multiple_of(2) => {
                return Err(invalid_option(
                    "correct_bias",
                    format!(
                        "must be 0 (no correction) or an even number of at least 2 (the replicates come in \
                         antithetic pairs), got {b}"
                    ),
                ))
            }
            (Some(b), seed) => e.correct_bias = Some(CorrectBias { replicates: b, seed: seed.unwrap_or(0) }),
            (None, Some(seed)) => e.correct_bias = e.correct_bias.map(|c| CorrectBias { seed, ..c }),
            (None, None) => {}
        }
    } else if !eiv_given.is_empty() {
        return Err(invalid_option(
            "method",
            format!(
                "{} appl{} to method eiv only, not to {}",
                eiv_given.join(", "),
                if eiv_given.len() == 1 { "ies" } else { "y" },
                o.method
            ),
        ));
    }
    match &mut o.method {
        Method::ThreeStep(t) => {
            t.initial_batches = batches.unwrap_or(t.initial_batches);
            t.initial_batch_size = batch_size.unwrap_or(t.initial_batch_size);
            t.picks = picks.unwrap_or(t.picks);
            t.final_segments = final_segments.unwrap_or(t.final_segments);
            t.qp.solver = qp_solver.unwrap_or(t.qp.solver);
        }
        other => {
            let given: Vec<&str> = [
                ("batches", batches.is_some()),
                ("batch_size", batch_size.is_some()),
                ("picks", picks.is_some()),
                ("final_segments", final_segments.is_some()),
                ("qp_solver", qp_solver.is_some()),
            ]
            .iter()
            .filter(|g| g.1)
            .map(|g| g.0)
            .collect();
            if !given.is_empty() {
                return Err(invalid_option(
                    "method",
                    format!(
                        "{} appl{} to method three-step only, not to {other}",
                        given.join(", "),
                        if given.len() == 1 { "ies" } else { "y" }
                    ),
                ));
            }
        }
    }
    if matches!(o.method, Method::Eiv(_)) && o.keep_one_way_selection {
        return Err(invalid_option(
            "keep_one_way",
            "applies to the segment-selecting methods (three-step, batch-gn), not to method eiv".into(),
        ));
    }
    if holdout.is_some() && validate_on.is_some() {
        return Err(invalid_option("validate_on", "give holdout or validate_on, not both".into()));
    }
    // `fix` last, so that it also holds an extrinsic the manifest or `estimate` frees.
    for p in fix.iter() {
        o.hold(p);
    }
    o.validate().map_err(lib_err)?;
    let noise_model_origin =
        odocal::calibrate::settings::noise_model_origin(&o.method, noise_model_file.as_deref(), &setting_uses);
    Ok(CalibrationPlan {
        opts: o,
        holdout: holdout.or(validate_on),
        validate_on: validate_on_drives,
        given_extrinsics: {
            let mut g = ParamSet::EMPTY;
            if given.lever_arm {
                g = g.union(ParamSet::LEVER_ARM);
            }
            if given.heading_offset {
                g = g.with(Param::HeadingOffset);
            }
            g
        },
        setting_uses,
        noise_model_origin,
    })
}

/// A parameter set from a list of names or the CLI's text `"c_d,t_r,d"`.
fn param_set_arg(v: &Bound<'_, PyAny>) -> PyResult<ParamSet> {
    let text = match v.cast::<PyString>() {
        Ok(s) => s.to_str()?.to_string(),
        Err(_) => v.extract::<Vec<String>>()?.join(","),
    };
    text.parse::<ParamSet>().map_err(lib_err)
}

// ---------------------------------------------------------------------------
// Running: GIL released, progress delivered on the calling thread.

/// Runs `f` with `threads` rayon threads (the global pool when None).
fn with_threads<T: Send>(threads: Option<usize>, f: impl FnOnce() -> T + Send) -> PyResult<T> {
    match threads {
        None => Ok(f()),
        Some(0) => Err(PyValueError::new_err("threads must be at least 1")),
        Some(n) => {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(n)
                .build()
                .map_err(|e| PyRuntimeError::new_err(format!("building a thread pool: {e}")))?;
            Ok(pool.install(f))
        }
    }
}

/// Minimum interval between two progress calls for the same stage.
const PROGRESS_INTERVAL: Duration = Duration::from_millis(100);

/// Runs `work` without the GIL. With a callback, `work` runs on a helper
/// thread and this thread forwards its progress events to
/// `callback(stage, done, total)`, re-attaching to Python for each call
/// (coalesced to one call per [`PROGRESS_INTERVAL`] and stage change). An
/// exception from the callback, or a pending signal (Ctrl-C), stops the
/// calls and is raised once the work has finished (the library cannot be
/// interrupted mid-calibration).
fn run_detached<T: Send>(
    py: Python<'_>,
    callback: Option<Py<PyAny>>,
    work: impl FnOnce(Option<&(dyn Fn(Progress) + Sync)>) -> T + Send,
) -> PyResult<T> {
    let Some(callback) = callback else {
        return Ok(py.detach(|| work(None)));
    };
    let (result, deferred) = py.detach(|| {
        std::thread::scope(|s| {
            let (tx, rx) = mpsc::channel::<Progress>();
            let worker = s.spawn(move || {
                let send = move |e: Progress| {
                    let _ = tx.send(e); // a receiver gone only means nobody listens
                };
                work(Some(&send))
            });
            let mut deferred: Option<PyErr> = None;
            let (mut stage, mut done, mut total) = (String::new(), 0u64, 0u64);
            let (mut dirty, mut last) = (false, Instant::now());
            let call = |stage: &str, done: u64, total: u64, deferred: &mut Option<PyErr>| {
                if deferred.is_some() {
                    return;
                }
                Python::attach(|py| {
                    if let Err(e) = py.check_signals().and_then(|_| callback.call1(py, (stage, done, total)).map(drop))
                    {
                        *deferred = Some(e);
                    }
                });
            };
            loop {
                match rx.recv_timeout(PROGRESS_INTERVAL) {
                    Ok(Progress::Stage { name, total: t }) => {
                        if dirty {
                            call(&stage, done, total, &mut deferred);
                        }
                        (stage, done, total) = (name.to_string(), 0, t);
                        call(&stage, done, total, &mut deferred);
                        (dirty, last) = (false, Instant::now());
                    }
                    Ok(Progress::Advance(k)) => {
                        done += k;
                        dirty = true;
                    }
                    Err(mpsc::RecvTimeoutError::Timeout) => {}
                    Err(mpsc::RecvTimeoutError::Disconnected) => break,
                }
                if dirty && last.elapsed() >= PROGRESS_INTERVAL {
                    call(&stage, done, total, &mut deferred);
                    (dirty, last) = (false, Instant::now());
                }
            }
            if dirty {
                call(&stage, done, total, &mut deferred);
            }
            (worker.join(), deferred)
        })
    });
    let result = result.map_err(|_| PyRuntimeError::new_err("odocal panicked during the calibration (a bug)"))?;
    match deferred {
        Some(e) => Err(e),
        None => Ok(result),
    }
}

/// The CLI's JSON report: the library report plus `truth` (simulated
/// drives) and `wheel_scale` (manifest imports), as `odocal calibrate --json`.
fn calibrate_json(
    drive: &Drive,
    prov: &Provenance,
    plan: &CalibrationPlan,
    progress: Option<&(dyn Fn(Progress) + Sync)>,
) -> odocal::Result<serde_json::Value> {
    let split = plan.holdout.as_ref().map(|h| h.split(drive)).transpose()?;
    let (fit, held): (&Drive, Option<&Drive>) = match &split {
        Some((fit, held)) => (fit.as_ref(), Some(held.as_ref())),
        None => (drive, None),
    };
    let names: Vec<String> = (0..plan.validate_on.len()).map(|i| format!("validate_on[{i}]")).collect();
    let validation: Vec<odocal::ValidationDrive> = names
        .iter()
        .zip(&plan.validate_on)
        .map(|(name, (d, r))| odocal::ValidationDrive { name, drive: d, reference: r.as_ref() })
        .collect();
    // Validation drives: each with the extrinsics that apply to it (odocal::assess::validation_drives).
    let (report, per_drive) = match validation.is_empty() {
        true => (odocal::calibrate_held_out(fit, held, &plan.opts, progress)?, None),
        false => {
            let (r, m) =
                odocal::calibrate_validated_on(drive, &validation, plan.given_extrinsics, &plan.opts, progress)?;
            (r, Some(m))
        }
    };
    let json_err = |source| odocal::Error::Json { context: "calibration report".into(), source };
    let mut v = serde_json::to_value(&report).map_err(json_err)?;
    let scored = held.unwrap_or(drive);
    if let (Some(side), Some(obj)) = (&prov.sidecar, v.as_object_mut()) {
        let t = side.theta_true;
        let segs = odocal::drive::segment::validation_segments(scored, &plan.opts.validation)?;
        let e = odocal::mean_position_error(scored, &segs, &t)?.mean_position_error_m;
        obj.insert("truth".into(), serde_json::json!({"theta": t, "mean_position_error_m": e}));
    }
    if let (Some(w), Some(obj)) = (&prov.wheel_scale, v.as_object_mut()) {
        obj.insert("wheel_scale".into(), serde_json::json!(w));
    }
    if let Some(obj) = v.as_object_mut() {
        // The σ that stands for the result (as the CLI's JSON `sigma`).
        obj.insert("sigma".into(), serde_json::to_value(report.result_sigma()).map_err(json_err)?);
        if let Some(m) = per_drive {
            obj.insert("validate_on".into(), serde_json::to_value(m).map_err(json_err)?);
        }
        if !plan.setting_uses.is_empty() {
            obj.insert("manifest_settings".into(), serde_json::to_value(&plan.setting_uses).map_err(json_err)?);
        }
        if let Some(n) = &plan.noise_model_origin {
            obj.insert("noise_model_origin".into(), serde_json::json!(n));
        }
    }
    with_schema_version(&mut v);
    Ok(v)
}

/// Calibrates `drive` (see the Python docstring of `odocal.calibrate`).
/// Returns `(report dict, report JSON text)`.
#[pyfunction]
#[pyo3(signature = (drive, method="eiv", *, progress=None, threads=None, **options))]
fn calibrate<'py>(
    py: Python<'py>,
    drive: &Bound<'py, PyAny>,
    method: &str,
    progress: Option<Py<PyAny>>,
    threads: Option<usize>,
    options: Option<&Bound<'py, PyDict>>,
) -> PyResult<(Bound<'py, PyAny>, String)> {
    let (inner, provs) = drives_arg(drive, "drive")?;
    let settings: Vec<ManifestSettings> =
        provs.iter().map(Provenance::settings).collect::<PyResult<Vec<_>>>()?.into_iter().flatten().collect();
    let manifest = ManifestSettings::merge(&settings).map_err(lib_err)?;
    let plan = calibration_plan(method, options, manifest.as_ref())?;
    // Several drives: no single truth (as the CLI); how to read c_e from the first that says.
    let prov = match provs.as_slice() {
        [one] => one.clone(),
        many => Provenance { wheel_scale: many.iter().find_map(|p| p.wheel_scale.clone()), ..Default::default() },
    };
    let value = run_detached(py, progress, |cb| with_threads(threads, || calibrate_json(&inner, &prov, &plan, cb)))??
        .map_err(|e| match e {
        e @ odocal::Error::NotObservable { .. } => OdocalError::new_err(format!(
            "{e}; in Python: fix=['c_d', 't_r', 'd'], min_yaw_rate=0 calibrates c_e alone, or pass auto_fix=True"
        )),
        e => lib_err(e),
    })?;
    let text = serde_json::to_string_pretty(&value).map_err(|e| PyRuntimeError::new_err(e.to_string()))?;
    Ok((to_py(py, &value)?, text))
}

/// The error for JSON text that is not a calibration report.
fn not_a_report(e: serde_json::Error) -> PyErr {
    PyValueError::new_err(format!("not a calibration report: {e}"))
}

/// A calibration report from its JSON text (the Python report's `_json`).
fn report_from_json(report_json: &str) -> PyResult<odocal::CalibrationReport> {
    serde_json::from_str(report_json).map_err(not_a_report)
}

/// The method's own account of the fit (`CalibrationReport::method_details`
/// of the library: the EIV lines the CLI prints; empty for the other
/// methods) of a calibration report's JSON text.
#[pyfunction]
fn _method_details(report_json: &str) -> PyResult<String> {
    Ok(report_from_json(report_json)?.method_details())
}

/// Reads a parameter file (ROS 2 YAML or JSON, as `--params-out` writes
/// it; library `ParamFile::read`) into the layout of the JSON file.
#[pyfunction]
fn read_params(py: Python<'_>, path: PathBuf) -> PyResult<Bound<'_, PyAny>> {
    let f = odocal::io::param_file::ParamFile::read(&path).map_err(lib_err)?;
    to_py(py, &f.to_json())
}

/// Writes the parameter file of a calibration report (its JSON text) as
/// `odocal calibrate --params-out` does: YAML for `.yaml`/`.yml`, JSON for
/// `.json` (library `CalibrationReport::param_file`).
#[pyfunction]
#[pyo3(signature = (report_json, path, *, input, node, mapping))]
fn _write_params(report_json: &str, path: PathBuf, input: &str, node: &str, mapping: &str) -> PyResult<()> {
    let mut f = report_from_json(report_json)?.param_file(input);
    f.node = node.to_string();
    f.mapping = mapping.parse().map_err(lib_err)?;
    f.write(&path).map_err(lib_err)
}

/// Writes the HTML report (odocal-report) of a calibration report (its
/// JSON text) on the drive it was validated on: `drive`, its held-out half
/// (`holdout`), or `validate_on`. Maps the JSON report to the renderer's
/// input in this one place.
#[pyfunction]
#[pyo3(signature = (drive, report_json, path, *, holdout=None, validate_on=None, title=None))]
fn _report_html(
    py: Python<'_>,
    drive: &Bound<'_, PyAny>,
    report_json: &str,
    path: PathBuf,
    holdout: Option<&str>,
    validate_on: Option<&Bound<'_, PyAny>>,
    title: Option<String>,
) -> PyResult<()> {
    let value: serde_json::Value = serde_json::from_str(report_json).map_err(not_a_report)?;
    let truth: Option<Theta> = value
        .get("truth")
        .and_then(|t| t.get("theta"))
        .map(|t| serde_json::from_value(t.clone()))
        .transpose()
        .map_err(not_a_report)?;
    let report: odocal::CalibrationReport = serde_json::from_value(value).map_err(not_a_report)?;
    let holdout = match (holdout, validate_on) {
        (Some(h), _) => Some(parse_holdout(h)?),
        (None, Some(d)) => Some(Holdout::Other(Drive::clone(&drives_arg(d, "validate_on")?.0))),
        (None, None) => None,
    };
    let inner = drives_arg(drive, "drive")?.0;
    let title = title.unwrap_or_else(|| "odocal calibration".into());
    py.detach(move || -> Result<(), String> {
        let split = holdout.as_ref().map(|h| h.split(&inner)).transpose().map_err(|e| e.to_string())?;
        let scored: &Drive = split.as_ref().map_or(&inner, |(_, h)| h.as_ref());
        let segs = odocal::drive::segment::validation_segments(scored, &report.options.validation)
            .map_err(|e| e.to_string())?;
        // The σ that stands for the result (the verdict's, the CLI's).
        let sigma = report.result_sigma().to_array();
        let theta0 = report.options.theta0;
        let mut input = odocal_report::ReportInput {
            provenance: vec![
                ("method".into(), report.method.to_string()),
                ("odocal".into(), env!("CARGO_PKG_VERSION").into()),
                ("from".into(), "Python (odocal.CalibrationReport.to_html)".into()),
            ],
            params: odocal_report::ParamRow::theta_rows(&theta0, &report.theta, Some(sigma), truth.as_ref()),
            truth,
            verdict: Some((
                report.verdict.level.to_string(),
                report.verdict.reasons.iter().map(|r| r.to_string()).collect(),
            )),
            warnings: report.warnings.iter().map(|w| w.to_string()).collect(),
            method_details: report.method_details().lines().map(str::to_string).collect(),
            ..odocal_report::ReportInput::new(title, scored, &segs, theta0, report.theta)
        };
        if let Some(step) = report.initial_step() {
            input.batches = step.batches.iter().map(|b| (b.score.theta, b.score.mean_position_error_m)).collect();
        }
        odocal_report::write_html(&path, &input).map_err(|e| e.to_string())
    })
    .map_err(OdocalError::new_err)
}

/// Mean position error Ē_p of θ on the validation segments of `drive`
/// (the CLI's `validate --json`): a dict with `theta`,
/// `mean_position_error_m`, `segments` and `per_segment_m`.
#[pyfunction]
#[pyo3(signature = (drive, theta, *, validation_length=None, threads=None, report_json=None))]
fn validate<'py>(
    py: Python<'py>,
    drive: &Bound<'py, PyDrive>,
    theta: &Bound<'py, PyAny>,
    validation_length: Option<usize>,
    threads: Option<usize>,
    report_json: Option<&str>,
) -> PyResult<Bound<'py, PyAny>> {
    // A parameter file is read once: its θ (checked by `read`) and extrinsics.
    let file = params_file_arg(theta)?;
    let theta = match &file {
        Some(f) => f.theta().map_err(lib_err)?,
        None => extract_theta(theta)?,
    };
    // A CalibrationReport as θ: its extrinsics, as a parameter file of it would carry them.
    let file = match report_json {
        Some(j) => Some(report_from_json(j)?.param_file("")),
        None => file,
    };
    let mut opts = odocal::ValidateOptions::default();
    if let Some(k) = validation_length {
        opts.segments.length_steps = k;
        opts.segments.stride_steps = (k / 2).max(1);
    }
    // A manifest's [reference]: the drive's own mount (as `odocal validate`);
    // a parameter file's estimated extrinsics win (ParamFile::extrinsics_for_drive).
    let stated = drive.get().prov.settings()?.and_then(|s| s.reference).map(|r| r.extrinsics());
    if let Some(x) = stated {
        opts.extrinsics = x;
    }
    if let Some(f) = &file {
        opts.extrinsics = f.extrinsics_for_drive(stated.as_ref()).0;
    }
    let inner = Arc::clone(&drive.get().drive);
    let report = py.detach(|| with_threads(threads, || odocal::validate(&inner, &theta, &opts)))?.map_err(lib_err)?;
    let mut v = json(&report)?;
    with_schema_version(&mut v);
    to_py(py, &v)
}

/// Adds the `schema_version` that the CLI writes into every JSON report.
fn with_schema_version(v: &mut serde_json::Value) {
    if let Some(obj) = v.as_object_mut() {
        obj.insert("schema_version".into(), odocal::REPORT_SCHEMA_VERSION.into());
    }
}

/// Simulates a drive with known true θ (the CLI's `simulate`).
#[pyfunction]
#[pyo3(signature = (seed=0, length_km=24.0, noise="paper", *, theta=None, substeps=None))]
fn simulate(
    py: Python<'_>,
    seed: u64,
    length_km: f64,
    noise: &str,
    theta: Option<&Bound<'_, PyAny>>,
    substeps: Option<usize>,
) -> PyResult<PyDrive> {
    let mut o = SimOptions {
        seed,
        length_km,
        noise: NoiseOptions::by_name(noise).map_err(lib_err)?,
        ..SimOptions::paper(seed)
    };
    if let Some(t) = theta {
        o.theta_true = extract_theta(t)?;
    }
    if let Some(s) = substeps {
        o.substeps = s;
    }
    let out = py.detach(|| odocal::sim::simulate(&o)).map_err(lib_err)?;
    Ok(PyDrive::new(out.drive, Provenance { sidecar: Some(out.sidecar), ..Default::default() }))
}

/// The native module `odocal._odocal`.
#[pymodule]
fn _odocal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("OdocalError", m.py().get_type::<OdocalError>())?;
    m.add_class::<PyDrive>()?;
    m.add_function(wrap_pyfunction!(calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(validate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(_drive_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(_report_html, m)?)?;
    m.add_function(wrap_pyfunction!(_method_details, m)?)?;
    m.add_function(wrap_pyfunction!(read_params, m)?)?;
    m.add_function(wrap_pyfunction!(_write_params, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("COLUMNS", COLUMNS.to_vec())?;
    Ok(())
}
