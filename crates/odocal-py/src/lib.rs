//! Python bindings of odocal: the native module `odocal._odocal`, wrapped
//! by the pure-Python package in `python/odocal` (`import odocal`).
//!
//! The bindings are a thin layer over the library, like the CLI:
//! - every drive made from arrays goes through [`odocal::DriveBuilder::build`],
//!   and every library error becomes `odocal.OdocalError` (a `ValueError`)
//!   with the library's message;
//! - keyword options are the library's calibration settings
//!   ([`odocal::settings::Settings`], the keys of a manifest's
//!   `[calibration]` and, in kebab case, the CLI's flags), read and mapped
//!   by the library ([`calibrate`]);
//! - reports leave as JSON ([`serde_json::Value`] → Python objects, and the
//!   CLI's pretty text), so `report.to_dict()` equals `odocal calibrate
//!   --json` (timing aside) without mirroring the report types here;
//! - numeric work runs with the GIL released ([`Python::detach`]); the
//!   progress callback is called only on the calling thread, with the GIL.

use std::sync::Arc;

use pyo3::prelude::*;

use odocal::sim::{NoiseOptions, SimOptions};

mod calibrate;
mod convert;
mod drive;
mod files;
mod history;
mod online;
mod report;
mod run;
mod stream;

use convert::{extract_theta, json, params_file_arg, to_py};
use drive::{Provenance, PyDrive, COLUMNS};
use report::report_from_json;
use run::with_threads;

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

/// `m` locked; `what` names its object in the error when a panic poisoned
/// it. The classes that hold their state behind a mutex (a call from
/// another thread waits for the running one) lock with this.
fn lock<'a, T>(m: &'a std::sync::Mutex<T>, what: &str) -> PyResult<std::sync::MutexGuard<'a, T>> {
    m.lock().map_err(|_| pyo3::exceptions::PyRuntimeError::new_err(format!("the {what} is poisoned by a panic")))
}

/// Mean position error Ē_p of θ on the validation segments of `drive`
/// (the CLI's `validate --json`): a dict with `theta`,
/// `mean_position_error_m`, `segments` and `per_segment_m`. The drive's
/// heading offset is re-estimated with θ held (`heading_offset_fit`) where
/// the calibration estimated one or θ is numbers, unless
/// `carry_heading_offset=True`. `drive_fit` holds θ fitted on the drive
/// and the verdict `fits`: θ's Ē_p is at most 1.6 times the fit's
/// (`fit_drive=False` skips it).
#[pyfunction]
#[pyo3(signature = (drive, theta, *, validation_length=None, threads=None, report_json=None, carry_heading_offset=false, params_node=None, fit_drive=true))]
// One argument per Python keyword: pyo3 maps them by name.
#[allow(clippy::too_many_arguments)]
fn validate<'py>(
    py: Python<'py>,
    drive: &Bound<'py, PyDrive>,
    theta: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = convert::opt_count)] validation_length: Option<usize>,
    #[pyo3(from_py_with = convert::opt_threads)] threads: Option<usize>,
    report_json: Option<&str>,
    carry_heading_offset: bool,
    params_node: Option<&str>,
    fit_drive: bool,
) -> PyResult<Bound<'py, PyAny>> {
    // A parameter file is read once: its θ (checked by `read`) and extrinsics.
    let file = params_file_arg(theta, params_node)?;
    if params_node.is_some() && file.is_none() {
        return Err(OdocalError::new_err(
            "params_node names a node of a parameter file, but theta is not the path of one",
        ));
    }
    let theta = match &file {
        Some(f) => odocal::Theta::try_from(f).map_err(lib_err)?,
        None => extract_theta(theta)?,
    };
    // A report's JSON as a value: its `wheel_scale` and its drives' fingerprints.
    let report_value = report_json.and_then(|j| serde_json::from_str::<serde_json::Value>(j).ok());
    // What θ's c_e is per (a report's `wheel_scale`, a parameter file's
    // provenance) against the drive's: warned about, as `odocal validate` does.
    let theta_scale = match (report_json, &file) {
        (Some(_), _) => {
            report_value.as_ref().and_then(|v| v.get("wheel_scale").and_then(|w| w.as_str()).map(str::to_string))
        }
        (None, Some(f)) => f.provenance.iter().find(|(k, _)| k == "wheel_scale").map(|(_, v)| v.clone()),
        (None, None) => None,
    };
    let prov = &drive.get().prov;
    let mut first = theta_scale.map(|w| ("θ's calibration".to_string(), w));
    let name = prov.source.as_deref().unwrap_or("the drive");
    if let Some(why) = odocal::wheel_scale_mismatch(&mut first, name, prov.wheel_scale.as_deref()) {
        files::warn_all(py, &[format!("{why}; θ is judged here as it stands")])?;
    }
    // A CalibrationReport as θ: its extrinsics, as a parameter file of it would carry them.
    // With the calibration drives' fingerprints, so that validation on one
    // of them holds the calibration's own heading offset for it.
    let file = match report_json {
        Some(j) => {
            let mut f = report_from_json(j)?.param_file("");
            if let Some(fp) = report_value.as_ref().and_then(files::calibration_fingerprints) {
                f.provenance.push(("fingerprint".into(), fp));
            }
            Some(f)
        }
        None => file,
    };
    let mut opts = odocal::ValidateOptions { fit_drive, ..odocal::ValidateOptions::default() };
    if let Some(k) = validation_length {
        opts.segments.length_steps = k;
        opts.segments.stride_steps = (k / 2).max(1);
    }
    // A manifest's [reference]: the drive's own mount (as `odocal validate`);
    // a parameter file's estimated extrinsics win (ValidateOptions::set_extrinsics).
    let stated = drive.get().prov.settings()?.and_then(|s| s.reference).map(|r| odocal::Extrinsics::from(&r));
    opts.set_extrinsics(file.as_ref(), stated.as_ref(), carry_heading_offset);
    let inner = Arc::clone(&drive.get().drive);
    let report =
        py.detach(|| with_threads(threads, || odocal::validate(&inner, &theta, &opts, None)))?.map_err(lib_err)?;
    let mut v = json(&report)?;
    if let Some(obj) = v.as_object_mut() {
        let entry = serde_json::json!({
            "role": "validation",
            "path": drive.get().prov.source,
            "fingerprint": py.detach(|| inner.fingerprint()),
        });
        obj.insert("drives".into(), serde_json::Value::Array(vec![entry]));
    }
    drive::with_import_warnings(&mut v, std::slice::from_ref(&drive.get().prov));
    with_schema_version(&mut v);
    to_py(py, &v)
}

/// Adds the `schema_version` that the CLI writes into every JSON report.
pub(crate) fn with_schema_version(v: &mut serde_json::Value) {
    if let Some(obj) = v.as_object_mut() {
        obj.insert("schema_version".into(), odocal::REPORT_SCHEMA_VERSION.into());
    }
}

/// Simulates a drive with known true θ (the CLI's `simulate`).
#[pyfunction]
#[pyo3(signature = (seed=0, length_km=24.0, noise="paper", *, theta=None, substeps=None))]
fn simulate(
    py: Python<'_>,
    #[pyo3(from_py_with = convert::seed)] seed: u64,
    #[pyo3(from_py_with = convert::real)] length_km: f64,
    noise: &str,
    theta: Option<&Bound<'_, PyAny>>,
    #[pyo3(from_py_with = convert::opt_count)] substeps: Option<usize>,
) -> PyResult<PyDrive> {
    let mut o = SimOptions {
        seed,
        length_km,
        noise: noise.parse::<NoiseOptions>().map_err(lib_err)?,
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
    m.add_class::<online::PyCalibrator>()?;
    m.add_class::<stream::PyRawStream>()?;
    m.add_class::<history::PyHistory>()?;
    m.add_function(wrap_pyfunction!(calibrate::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(validate, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    m.add_function(wrap_pyfunction!(drive::_drive_from_state, m)?)?;
    m.add_function(wrap_pyfunction!(report::_report_html, m)?)?;
    m.add_function(wrap_pyfunction!(report::_method_details, m)?)?;
    m.add_function(wrap_pyfunction!(report::read_params, m)?)?;
    m.add_function(wrap_pyfunction!(report::_write_params, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("COLUMNS", COLUMNS.to_vec())?;
    m.add("CALIBRATE_OPTIONS", pyo3::types::PyTuple::new(m.py(), calibrate::options())?)?;
    Ok(())
}
